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
    w->high = w->acked = last;
    w->next = last + 1;
    w->in_flight = 0;
    w->extra = 0;
    w->swallow = 0;
    w->rewound_to = 0;
    w->stale = 0;
    w->doubted = 0;
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

/* in_flight follows next and acked; acked never passes the last line sent. */
static void
settle_counts(struct linewin *w)
{
    if (w->acked > w->next - 1)
        w->acked = w->next - 1;
    long f = w->next - 1 - w->acked;
    w->in_flight = f < 0 ? 0 : f > w->cap ? (int)w->cap : (int)f;
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
    e->exec_ms = 0;
    w->high = n;
    return n;
}

void
linewin_set_cost(struct linewin *w, long n, int32_t exec_ms)
{
    if (held(w, n))
        entry(w, n)->exec_ms = exec_ms < 0 ? 0 : exec_ms;
}

const struct linewin_entry *
linewin_peek(const struct linewin *w)
{
    if (w->next > w->high || !held(w, w->next))
        return NULL;
    const struct linewin_entry *e = entry(w, w->next);
    if (w->in_flight == 0 || w->extra > 0)
        return e;
    if (w->in_flight >= w->window)
        return NULL;
    if (w->rx_bytes > 0) {
        /* The oldest line in flight is being read or run; the rest and this
           one may have to wait in the RX ring meanwhile. */
        long bytes = e->len + 1;
        for (long n = w->acked + 2; n < w->next; n++)
            bytes += held(w, n) ? entry(w, n)->len + 1 : LINEWIN_LINE_MAX;
        if (bytes > w->rx_bytes - 1)
            return NULL;
    }
    return e;
}

void
linewin_sent(struct linewin *w)
{
    if (w->next <= w->high) {
        if (w->extra > 0 && w->in_flight > 0)
            w->extra--;
        w->next++;
        settle_counts(w);
    }
}

void
linewin_force(struct linewin *w)
{
    w->extra = 1;
}

long
linewin_on_ok(struct linewin *w, bool has_n, long n, long barrier_tag)
{
    if (w->swallow > 0 && !(w->advanced && has_n)) {
        /* The ok Marlin sends after each Resend belongs to the rejected line.
           (An ok with N is a processed line's: the rejection's ok was lost.) */
        w->swallow--;
        return 0;
    }
    long before = w->acked;
    if (w->advanced) {
        if (!has_n)
            return 0; /* a rejection's ok whose Resend was lost, or M105's own */
        if (n <= w->acked)
            return n > w->acked - w->window - 1 ? 0 : -1;
        if (n >= w->next)
            return -1;
        w->acked = n;
    } else {
        if (w->acked >= w->next - 1)
            return 0; /* nothing in flight: a duplicate */
        if (held(w, w->acked + 1) && entry(w, w->acked + 1)->tag == barrier_tag)
            return -1; /* only its own answer acknowledges a probe */
        w->acked++;
    }
    settle_counts(w);
    return w->acked - before;
}

int
linewin_on_resend(struct linewin *w, long k)
{
    if (k > w->high + 1 || k < 1)
        return 2; /* asks for a line never pushed: garbled */
    if (k == w->rewound_to && w->stale > 0 && k < w->next) {
        w->stale--;
        w->swallow++;
        return 1;
    }
    if (!held(w, k) && k != w->high + 1)
        return SF_ENOTFOUND;
    /* Marlin never asks for a line it acknowledged: with ADVANCED_OK's
       exact count such a request is a garbled number, and without it only
       a few lines' worth of miscounted oks can explain one. */
    if (k <= w->acked && (w->advanced || k < w->acked - w->window) && k != w->doubted) {
        w->doubted = k; /* a garbled number does not repeat; a real request does */
        return 2;
    }
    w->doubted = 0;
    w->swallow++; /* the rejected line's ok follows */
    if (k == w->next) {
        /* The printer has every line sent so far: it rejected a copy. */
        w->stale = 0;
        return 1;
    }
    /* Lines k+1 .. next-1 were in flight behind k: each may repeat this
       request (those still in the RX ring are flushed without a reply). */
    w->stale = k < w->next ? w->next - 1 - k : 0;
    /* Lines before k were received; those not acknowledged are still in
       the printer's queue and their oks still to come.  A k beyond next
       (the printer has lines we rewound over) moves next forward. */
    if (w->acked > k - 1)
        w->acked = k - 1;
    w->next = k;
    w->extra = 0;
    settle_counts(w);
    w->rewound_to = k;
    w->rewinds++;
    return SF_OK;
}

long
linewin_barrier(struct linewin *w, long n)
{
    if (n < 1 || n >= w->next)
        return 0;
    long before = w->acked;
    /* Every reply to the lines up to n has arrived: no rejection's ok and no
       stale Resend from them is still to come. */
    w->acked = n;
    w->swallow = 0;
    w->stale = 0;
    settle_counts(w);
    return w->acked > before ? w->acked - before : 0;
}

void
linewin_resync(struct linewin *w)
{
    w->acked = w->next - 1;
    w->swallow = 0;
    w->stale = 0;
    w->extra = 0;
    settle_counts(w);
}

int64_t
linewin_cost(const struct linewin *w, long first, long last, int32_t cap_ms)
{
    int64_t ms = 0;
    for (long n = first < 1 ? 1 : first; n <= last; n++)
        if (held(w, n))
            ms += entry(w, n)->exec_ms < cap_ms ? entry(w, n)->exec_ms : cap_ms;
    return ms;
}

void
linewin_set_tag(struct linewin *w, long n, long tag)
{
    if (held(w, n))
        entry(w, n)->tag = tag;
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
