/*
 * faults.c - parsing fault specs and rolling the fault dice (faults.h).
 *
 * Why: every simulated printer injects the same kinds of trouble, and the
 * integration tests must be reproducible, so the dice are a seeded
 * xorshift64 rather than rand() or /dev/urandom.  Values are parsed with
 * strtod/strtol and fully checked: a typo in a test's fault list is an
 * error, not a silently fault-free run.
 *
 * Thread: whoever owns the struct.
 */
#include "faults.h"

#include <errno.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

void
faults_init(struct faults *f)
{
    memset(f, 0, sizeof(*f));
    f->rng = 1;
}

static int
parse_rate(const char *spec, const char *v, double *out, struct sf_err *err)
{
    char *end;
    errno = 0;
    double d = strtod(v, &end);
    if (errno || end == v || *end || !isfinite(d) || d < 0 || d > 1)
        return sf_err_set(err, SF_EINVAL, "fault '%s': rate must be a number from 0 to 1", spec);
    *out = d;
    return SF_OK;
}

static int
parse_count(const char *spec, const char *v, long max, long *out, struct sf_err *err)
{
    char *end;
    errno = 0;
    long n = strtol(v, &end, 10);
    if (errno || end == v || *end || n < 0 || n > max)
        return sf_err_set(err, SF_EINVAL, "fault '%s': expected a whole number from 0 to %ld", spec,
                          max);
    *out = n;
    return SF_OK;
}

static const char *const hit_names[] = {
    "", "ok", "okn", "okt", "resend", "error", "busy", "temp"
};

int
faults_hit_kind(const char *line)
{
    if (strcmp(line, "ok") == 0)
        return FAULT_HIT_OK;
    if (strncmp(line, "ok N", 4) == 0)
        return FAULT_HIT_OKN;
    if (strncmp(line, "ok T:", 5) == 0)
        return FAULT_HIT_OKT;
    if (strncmp(line, "Resend:", 7) == 0)
        return FAULT_HIT_RESEND;
    if (strncmp(line, "Error:", 6) == 0)
        return FAULT_HIT_ERROR;
    if (strncmp(line, "echo:busy", 9) == 0)
        return FAULT_HIT_BUSY;
    if (strncmp(line, " T:", 3) == 0 && strstr(line, " W:"))
        return FAULT_HIT_TEMP;
    return FAULT_HIT_NONE;
}

/* "KIND:LINE:POS:BYTE" */
static int
parse_hit(struct faults *f, const char *spec, const char *v, struct sf_err *err)
{
    const char *c = strchr(v, ':');
    int kind = 0;
    for (int i = 1; c && i < (int)(sizeof(hit_names) / sizeof(hit_names[0])); i++)
        if ((size_t)(c - v) == strlen(hit_names[i]) &&
            strncmp(v, hit_names[i], (size_t)(c - v)) == 0)
            kind = i;
    long n[3];
    const char *p = c ? c + 1 : NULL;
    for (int i = 0; i < 3 && p; i++) {
        char *end;
        errno = 0;
        n[i] = strtol(p, &end, 10);
        if (errno || end == p || (i < 2 ? *end != ':' : *end != '\0'))
            p = NULL;
        else
            p = end + 1;
    }
    if (!kind || !p || n[0] < 0 || n[1] < 0 || n[1] > 511 || n[2] < 0 || n[2] > 256)
        return sf_err_set(
            err, SF_EINVAL,
            "fault '%s': expected hit=KIND:LINE:POS:BYTE, KIND ok, okn, okt, "
            "resend, error, busy or temp, POS 0-511, BYTE 0-255 (256: flip its low bit)",
            spec);
    f->hit_kind = kind;
    f->hit_line = n[0];
    f->hit_pos = (int)n[1];
    f->hit_byte = (int)n[2];
    return SF_OK;
}

int
faults_parse(struct faults *f, const char *spec, struct sf_err *err)
{
    const char *eq = strchr(spec, '=');
    if (!eq)
        return sf_err_set(err, SF_EINVAL, "fault '%s': expected name=value", spec);
    size_t n = (size_t)(eq - spec);
    const char *v = eq + 1;
    long c;
    int rc;
#define NAME_IS(s) (n == strlen(s) && strncmp(spec, s, n) == 0)
    if (NAME_IS("corrupt")) {
        rc = parse_rate(spec, v, &f->corrupt_rx, err);
        f->corrupt_tx = f->corrupt_rx;
        return rc;
    }
    if (NAME_IS("corrupt-rx"))
        return parse_rate(spec, v, &f->corrupt_rx, err);
    if (NAME_IS("corrupt-tx"))
        return parse_rate(spec, v, &f->corrupt_tx, err);
    if (NAME_IS("drop-ok"))
        return parse_rate(spec, v, &f->drop_ok, err);
    if (NAME_IS("drop-oks")) {
        char *end;
        errno = 0;
        long line = strtol(v, &end, 10);
        long count = -1;
        if (!errno && end != v && *end == ':') {
            const char *q = end + 1;
            count = strtol(q, &end, 10);
            if (errno || end == q || *end)
                count = -1;
        }
        if (line < 0 || count < 1 || count > 1000000)
            return sf_err_set(err, SF_EINVAL,
                              "fault '%s': expected drop-oks=LINE:N, LINE >= 0, N 1-1000000", spec);
        f->drop_oks_line = line;
        f->drop_oks = count;
        return SF_OK;
    }
    if (NAME_IS("garbage"))
        return parse_rate(spec, v, &f->garbage, err);
    if (NAME_IS("slow")) {
        rc = parse_count(spec, v, 60000, &c, err);
        f->slow_ms = (int)c;
        return rc;
    }
    if (NAME_IS("reset"))
        return parse_count(spec, v, 1L << 40, &f->reset_after, err);
    if (NAME_IS("disconnect"))
        return parse_count(spec, v, 1L << 40, &f->disconnect_after, err);
    if (NAME_IS("runaway"))
        return parse_count(spec, v, 1L << 40, &f->runaway_after, err);
    if (NAME_IS("stuck"))
        return parse_count(spec, v, 1L << 40, &f->stuck_after, err);
    if (NAME_IS("dup"))
        return parse_rate(spec, v, &f->dup, err);
    if (NAME_IS("merge"))
        return parse_rate(spec, v, &f->merge, err);
    if (NAME_IS("bad-line"))
        return parse_count(spec, v, 1L << 40, &f->bad_line, err);
    if (NAME_IS("hit"))
        return parse_hit(f, spec, v, err);
    if (NAME_IS("okt")) {
        f->okt_plain = strcmp(v, "plain") == 0;
        return f->okt_plain ? SF_OK
                            : sf_err_set(err, SF_EINVAL, "fault '%s': expected okt=plain", spec);
    }
    if (NAME_IS("hit-rx")) {
        long num[3];
        const char *p = v;
        for (int i = 0; i < 3 && p; i++) {
            char *end;
            errno = 0;
            num[i] = strtol(p, &end, 10);
            if (errno || end == p || (i < 2 ? *end != ':' : *end != '\0'))
                p = NULL;
            else
                p = end + 1;
        }
        if (!p || num[0] < 0 || num[1] < 0 || num[1] > 95 || num[2] < 1 || num[2] > 255)
            return sf_err_set(err, SF_EINVAL,
                              "fault '%s': expected hit-rx=LINE:POS:BYTE, LINE >= 0, POS 0-95, "
                              "BYTE 1-255",
                              spec);
        f->hit_rx = true;
        f->hit_rx_line = num[0];
        f->hit_rx_pos = (int)num[1];
        f->hit_rx_byte = (int)num[2];
        return SF_OK;
    }
    if (NAME_IS("hold")) {
        if (!*v || strlen(v) >= sizeof(f->hold_path))
            return sf_err_set(err, SF_EINVAL, "fault '%s': expected hold=PATH (1-%zu bytes)", spec,
                              sizeof(f->hold_path) - 1);
        memcpy(f->hold_path, v, strlen(v) + 1);
        return SF_OK;
    }
    if (NAME_IS("seed")) {
        rc = parse_count(spec, v, 1L << 40, &c, err);
        f->rng = (uint64_t)c * 0x9E3779B97F4A7C15ull + 1;
        return rc;
    }
#undef NAME_IS
    return sf_err_set(err, SF_EINVAL,
                      "fault '%s': unknown; expected corrupt, corrupt-rx, corrupt-tx, drop-ok, "
                      "drop-oks, garbage, dup, merge, bad-line, hit, hit-rx, okt, slow, reset, "
                      "disconnect, runaway, stuck, hold or "
                      "seed",
                      spec);
}

static uint64_t
next(struct faults *f)
{
    uint64_t x = f->rng;
    x ^= x << 13;
    x ^= x >> 7;
    x ^= x << 17;
    f->rng = x;
    return x;
}

bool
faults_roll(struct faults *f, double p)
{
    if (p <= 0)
        return false;
    return (double)(next(f) >> 11) * (1.0 / 9007199254740992.0) < p;
}

uint8_t
faults_byte(struct faults *f, uint8_t not )
{
    uint8_t b;
    do
        b = (uint8_t)(next(f) >> 32);
    while (b == not );
    return b;
}
