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

#include <stdio.h>
#include <string.h>

#include "../../src/base/eparser.h"
#include "../../src/base/gcode.h"
#include "../../src/base/mem.h"

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
    e->after_ok = false;
    e->heats = false;
    w->high = n;
    return n;
}

void
linewin_set_cost(struct linewin *w, long n, int32_t exec_ms, bool after_ok, bool heats)
{
    if (held(w, n)) {
        entry(w, n)->exec_ms = exec_ms < 0 ? 0 : exec_ms;
        entry(w, n)->after_ok = after_ok;
        entry(w, n)->heats = heats;
    }
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
linewin_cost(const struct linewin *w, long first, long last, int32_t cap_ms, int32_t heat_cap_ms)
{
    int64_t ms = 0;
    for (long n = first < 1 ? 1 : first; n <= last; n++) {
        if (!held(w, n))
            continue;
        int32_t cap = entry(w, n)->heats && heat_cap_ms < cap_ms ? heat_cap_ms : cap_ms;
        ms += entry(w, n)->exec_ms < cap ? entry(w, n)->exec_ms : cap;
    }
    return ms;
}

int64_t
linewin_cost_after_ok(const struct linewin *w, long first, long last, int32_t cap_ms)
{
    int64_t ms = 0;
    for (long n = first < 1 ? 1 : first; n <= last; n++)
        if (held(w, n) && entry(w, n)->after_ok)
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

void
linewin_rewind(struct linewin *w, long k)
{
    if (k < 1 || k > w->next)
        return;
    if (w->acked < k - 1)
        w->acked = k - 1;
    w->next = k;
    w->swallow = 0;
    w->stale = 0;
    w->extra = 0;
    settle_counts(w);
}

/* ---- Marlin's emergency parser ------------------------------------------ */

static bool
ep_eol(unsigned char c)
{
    return c == '\n' || c == '\r';
}

/* One byte; *fired when it ends a line that acts.  The states are
   eparser.h's; a line end after ACT acts, and either final state starts
   the next line over. */
static enum eparser_state
ep_step(enum eparser_state s, unsigned char c, bool *fired)
{
    if (s != EPARSER_ACT && s != EPARSER_IGNORE)
        return eparser_step(s, c);
    if (!ep_eol(c))
        return s;
    if (s == EPARSER_ACT)
        *fired = true;
    return EPARSER_RESET;
}

/* Run bytes from state s; true if a line among them acts.  Ends early once
   the rest of a line is ignored and no line end follows. */
static bool
ep_run(enum eparser_state s, const unsigned char *b, size_t len)
{
    bool fired = false;
    size_t last_eol = 0; /* one past the last line end */
    for (size_t i = len; i > 0 && !last_eol; i--)
        if (ep_eol(b[i - 1]))
            last_eol = i;
    for (size_t i = 0; i < len && !fired; i++) {
        if (s == EPARSER_IGNORE && i >= last_eol)
            return false;
        s = ep_step(s, b[i], &fired);
    }
    return fired || s == EPARSER_ACT; /* a line still open that acts when it ends */
}

/* True when line acts as written (it is M108, M112 or M410). */
static bool
ep_acts(const char *line, size_t len)
{
    unsigned char b[LINEWIN_LINE_MAX + 2];
    if (len > LINEWIN_LINE_MAX)
        return false;
    memcpy(b, line, len);
    b[len] = '\n';
    return ep_run(EPARSER_RESET, b, len + 1);
}

bool
linewin_ep_hazard(const char *line, size_t len)
{
    unsigned char b[LINEWIN_LINE_MAX + 2];
    if (len > LINEWIN_LINE_MAX)
        return true; /* longer than we send: not vouched for */
    if (ep_acts(line, len))
        return true;
    memcpy(b, line, len);
    b[len] = '\n';
    size_t n = len + 1;
    /* Each byte replaced by each other value: the prefix's state, the new
       byte, then the rest as written.  A line that came in ignored (the one
       before it lost its newline) is ignored whatever its bytes. */
    enum eparser_state s = EPARSER_RESET;
    bool fired = false;
    /* The parser tells apart only these bytes; X and Y stand for all others. */
    static const char tell[] = " NM0123456789-\n\rXY";
    for (size_t i = 0; i < n; i++) {
        for (const char *pc = tell; *pc; pc++) {
            unsigned char c = (unsigned char)*pc;
            if (c == b[i])
                continue;
            if (s == EPARSER_IGNORE && !ep_eol(c))
                continue; /* ignored before and after: only a new line end matters */
            bool f = false;
            enum eparser_state t = ep_step(s, c, &f);
            if (f || ep_run(t, b + i + 1, n - i - 1))
                return true;
        }
        s = ep_step(s, b[i], &fired);
    }
    return false;
}

bool
linewin_number_ok(long n)
{
    char text[LINEWIN_LINE_MAX];
    size_t len = gcode_number_line(n, "G0", text, sizeof(text));
    return len > 0 && !linewin_ep_hazard(text, len);
}

bool
linewin_ep_safe_form(long n, const char *cmd, char *out, size_t cap)
{
    char form[LINEWIN_LINE_MAX], text[LINEWIN_LINE_MAX];
    for (int zeros = 0; zeros <= 2; zeros++) {
        if (zeros > 0 && !(cmd[0] == 'M' && cmd[1] >= '0' && cmd[1] <= '9'))
            break;
        int k = snprintf(form, sizeof(form), "%c%.*s%s", cmd[0], zeros, "00", cmd + 1);
        if (k < 0 || (size_t)k >= sizeof(form) || (size_t)k >= cap)
            break;
        size_t len = gcode_number_line(n, form, text, sizeof(text));
        if (len > 0 && zeros == 0 && ep_acts(text, len))
            break; /* M108, M112, M410 meant to act: as they are */
        if (len > 0 && !linewin_ep_hazard(text, len)) {
            memcpy(out, form, (size_t)k + 1);
            return true;
        }
    }
    snprintf(out, cap, "%s", cmd);
    return false;
}
