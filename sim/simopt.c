/*
 * simopt.c - option and loop helpers shared by the simulators' mains
 * (simopt.h).
 *
 * Thread: main thread.
 */
#include "simopt.h"

#include <errno.h>
#include <math.h>
#include <signal.h>
#include <stdbool.h>
#include <stdio.h>
#include <stdlib.h>

int
simopt_num(const char *prog, const char *opt, const char *v, double lo, double hi, bool whole,
           double *out)
{
    char *end = NULL;
    errno = 0;
    double d = v ? strtod(v, &end) : NAN;
    if (!v || errno || end == v || *end || !(d >= lo && d <= hi) || (whole && d != floor(d))) {
        fprintf(stderr, "%s: %s expects a %snumber from %.10g to %.10g\n", prog, opt,
                whole ? "whole " : "", lo, hi);
        return -1;
    }
    *out = d;
    return 0;
}

const char *
simopt_stats_head(int index, int count)
{
    static char head[48];
    if (count > 1)
        snprintf(head, sizeof(head), "stats: printer=%d ", index);
    else
        snprintf(head, sizeof(head), "stats: ");
    return head;
}

static void
on_stop(struct loop *l, int signo, void *ud)
{
    (void)signo;
    (void)ud;
    loop_stop(l);
}

struct loop *
simopt_loop(const char *prog)
{
    struct sf_err err;
    struct loop *l = loop_new(&err);
    if (!l) {
        fprintf(stderr, "%s: %s\n", prog, err.msg);
        return NULL;
    }
    if (loop_add_signal(l, SIGINT, on_stop, NULL, &err) < 0 ||
        loop_add_signal(l, SIGTERM, on_stop, NULL, &err) < 0) {
        fprintf(stderr, "%s: %s\n", prog, err.msg);
        loop_free(l);
        return NULL;
    }
    signal(SIGPIPE, SIG_IGN);
    return l;
}
