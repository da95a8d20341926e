/*
 * linewin.c - line numbers, checksums and the resend window (linewin.h).
 *
 * Why pure: the protocol's hard cases (repeated resends, lost and extra
 * oks, garbled numbers) are easiest to get right and to fuzz when the
 * bookkeeping is separate from bytes and timers.  Design: a ring of
 * formatted lines indexed by number; `next` walks forward as lines are
 * sent and back on a rewind.  Counts are clamped so no reply sequence,
 * however garbled, can drive them out of range (the fuzzer checks this).
 *
 * Thread: whoever owns the struct.
 */
#include "linewin.h"

#include <string.h>

#include "../src/base/gcode.h"
#include "../src/base/mem.h"

int
linewin_init(struct linewin *w, long cap, int window)
{
    memset(w, 0, sizeof(*w));
    if (cap < 2 || window < 1 || window >= cap)
        return SF_EINVAL;
    w->ring = mem_calloc((size_t)cap, sizeof(*w->ring));
    if (!w->ring)
        return SF_ENOMEM;
    w->cap = cap;
    w->window = window;
    linewin_reset(w, 0);
    return SF_OK;
}

void
linewin_release(struct linewin *w)
{
    free(w->ring);
    w->ring = NULL;
}

void
linewin_reset(struct linewin *w, long last)
{
    w->high = w->acked = w->recv = last;
    w->synced = false;
    w->next = last + 1;
    w->in_flight = 0;
    w->swallow_ok = false;
    w->rewound_to = 0;
    w->stale = 0;
}

static struct linewin_entry *
entry(const struct linewin *w, long n)
{
    return &w->ring[n % w->cap];
}

static bool
held(const struct linewin *w, long n)
{
    return n >= 1 && n <= w->high && n > w->high - w->cap;
}

long
linewin_push(struct linewin *w, const char *cmd, long tag, struct sf_err *err)
{
    if (w->high - w->acked >= w->cap - 1)
        return SF_EAGAIN;
    if (w->high >= 2147483646L)
        return sf_err_set(err, SF_EINVAL, "line numbers exhausted; send M110 first");
    long n = w->high + 1;
    struct linewin_entry *e = entry(w, n);
    size_t len = gcode_number_line(n, cmd, e->text, sizeof(e->text));
    if (len == 0)
        return sf_err_set(err, SF_EINVAL,
                          "command '%.40s...' is too long for Marlin (%d bytes with line number "
                          "and checksum)",
                          cmd, LINEWIN_LINE_MAX - 1);
    e->len = (uint8_t)len;
    e->tag = tag;
    w->high = n;
    return n;
}

const struct linewin_entry *
linewin_peek(const struct linewin *w)
{
    if (w->next > w->high || w->in_flight >= w->window || !held(w, w->next))
        return NULL;
    return entry(w, w->next);
}

void
linewin_sent(struct linewin *w)
{
    if (w->next <= w->high) {
        w->next++;
        w->in_flight++;
    }
}

long
linewin_on_ok(struct linewin *w, bool has_n, long n)
{
    if (w->swallow_ok) {
        /* Marlin's "Resend: k" is followed by the rejected line's ok, which
           has no N; an ok with N means that one was lost on the wire. */
        w->swallow_ok = false;
        if (!(w->advanced && has_n))
            return 0;
    }
    long before = w->acked;
    if (w->advanced) {
        if (!has_n)
            return 0; /* M105's own ok, or a rejection's */
        if (n <= w->acked || n >= w->next)
            return n <= w->acked && n > w->acked - w->window ? 0 : -1;
        w->acked = n;
        if (n > w->recv)
            w->recv = n;
        /* After a resync more than a window may be unanswered: what is in
           flight is what the window allows, never more. */
        long f = w->next - 1 - w->recv;
        w->in_flight = f < 0 ? 0 : f > w->window ? w->window : (int)f;
        if (n >= w->rewound_to)
            w->stale = 0;
    } else {
        if (w->in_flight > 0)
            w->in_flight--;
        if (w->acked < w->next - 1)
            w->acked++;
        if (w->acked > w->recv)
            w->recv = w->acked;
    }
    w->synced = false;
    return w->acked - before;
}

int
linewin_on_resend(struct linewin *w, long k)
{
    if (k > w->high + 1 || k < 1)
        return 2; /* asks for a line never pushed: garbled */
    if (k == w->rewound_to && w->stale > 0) {
        w->stale--;
        w->swallow_ok = true;
        return 1;
    }
    if (!held(w, k) && k != w->high + 1)
        return SF_ENOTFOUND;
    /* Lines k+1 .. next-1 were in flight: each may repeat this request. */
    w->stale = w->next - 1 - k;
    if (w->stale < 0)
        w->stale = 0;
    /* The printer has every line before k.  After an answered probe it has
       also run them; otherwise their oks are still to come. */
    if (w->synced && w->acked < k - 1)
        w->acked = k - 1;
    w->synced = false;
    w->next = k;
    w->recv = k - 1;
    if (w->acked > k - 1)
        w->acked = k - 1;
    w->in_flight = 0;
    w->rewound_to = k;
    w->swallow_ok = true;
    w->rewinds++;
    return SF_OK;
}

void
linewin_resync(struct linewin *w)
{
    w->in_flight = 0;
    w->stale = 0;
    w->swallow_ok = false;
    w->synced = true;
    if (w->next - 1 > w->acked && held(w, w->next - 1)) {
        w->next--;
        if (w->recv > w->next - 1)
            w->recv = w->next - 1;
    }
}

long
linewin_tag(const struct linewin *w, long n)
{
    return held(w, n) ? entry(w, n)->tag : -1;
}

bool
linewin_idle(const struct linewin *w)
{
    return w->acked >= w->high;
}
