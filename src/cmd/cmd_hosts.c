/*
 * cmd_hosts.c - `slimfarm hosts`: the hosts that share a store (issue 32),
 * read from the store itself, not through a daemon: a host that lost its
 * lease may have no daemon left to ask.  Each with its state (live: its
 * lease runs and was not reaped; expired), its lease's age (since its last
 * heartbeat), the printers it owns and the jobs it holds.
 *
 * Thread: main thread.  Opens the store read-only beside its daemons
 * (store_open_view): no lock, nothing written.
 */
#include <getopt.h>
#include <jansson.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "../base/clock.h"
#include "../farm/sqldb.h"
#include "../farm/store_host.h"
#include "cmd.h"

#define USAGE "hosts (--store URL | --data DIR) [--json]"

/* The printers of h as a JSON array (its list cut with "..." loses the tail). */
static json_t *
printers_json(const struct store_host_row *h)
{
    json_t *a = json_array();
    char list[sizeof(h->printers)];
    snprintf(list, sizeof(list), "%s", h->printers);
    for (char *p = list, *end; p && *p; p = end ? end + 1 : NULL) {
        end = strchr(p, ',');
        if (end)
            *end = '\0';
        if (strcmp(p, "...") != 0)
            json_array_append_new(a, json_string(p));
    }
    return a;
}

static void
print_json(const struct store_host_row *rows, size_t n, int64_t now_ms)
{
    json_t *a = json_array();
    for (size_t i = 0; i < n; i++) {
        const struct store_host_row *h = &rows[i];
        json_array_append_new(
            a, json_pack("{s:s, s:s, s:f, s:f, s:I, s:I, s:i, s:I, s:i, s:o, s:i}", "name", h->name,
                         "state", h->live ? "live" : "expired", "lease_age_s",
                         (double)(now_ms - h->heartbeat_ms) / 1000, "lease_left_s",
                         (double)(h->lease_until_ms - now_ms) / 1000, "pid", (json_int_t)h->pid,
                         "token", (json_int_t)h->token, "version", h->version, "started_ms",
                         (json_int_t)h->started_ms, "n_printers", h->n_printers, "printers",
                         printers_json(h), "jobs_claimed", h->n_claimed));
    }
    char *s = json_dumps(a, JSON_INDENT(2));
    if (s)
        puts(s);
    free(s);
    json_decref(a);
}

static void
print_table(const struct store_host_row *rows, size_t n, int64_t now_ms)
{
    if (n == 0) {
        printf("no hosts have joined this store\n");
        return;
    }
    printf("%-20s %-8s %10s %8s %6s %6s  %s\n", "HOST", "STATE", "LEASE AGE", "PID", "TOKEN",
           "JOBS", "PRINTERS");
    for (size_t i = 0; i < n; i++) {
        const struct store_host_row *h = &rows[i];
        char age[24];
        snprintf(age, sizeof(age), "%.1f s", (double)(now_ms - h->heartbeat_ms) / 1000);
        printf("%-20s %-8s %10s %8lld %6lld %6d  %s\n", h->name, h->live ? "live" : "expired", age,
               (long long)h->pid, (long long)h->token, h->n_claimed,
               h->n_printers ? h->printers : "-");
    }
}

static int
run_hosts(int argc, char **argv)
{
    static const struct option longopts[] = {
        { "store", required_argument, NULL, 's' },
        { "data", required_argument, NULL, 'd' },
        { "json", no_argument, NULL, 'j' },
        { NULL, 0, NULL, 0 },
    };
    const char *target = NULL;
    bool json = false;
    int c;
    optind = 1;
    while ((c = cmd_getopt("hosts", argc, argv, "", longopts, NULL, 0)) != -1) {
        switch (c) {
        case 's':
        case 'd':
            if (target) {
                fprintf(stderr, "slimfarm hosts: give one of --store and --data\n");
                return 2;
            }
            if (c == 's' && !sqldb_is_url(optarg)) {
                fprintf(stderr, "slimfarm hosts: --store wants a postgresql:// URL, got '%s'\n",
                        optarg);
                return 2;
            }
            target = optarg;
            break;
        case 'j':
            json = true;
            break;
        default:
            return cmd_opt_error(c, USAGE);
        }
    }
    if (!target || optind < argc)
        return cmd_usage(USAGE);
    struct sf_err err;
    struct store *s = store_open_view(target, &err);
    struct store_host_row *rows = NULL;
    size_t n = 0;
    int64_t now = 0; /* the database's clock: the leases' (store_clock_ms) */
    if (!s || store_host_list(s, clock_wall_ms(), &rows, &n, &err) || !(now = store_clock_ms(s))) {
        fprintf(stderr, "slimfarm hosts: %s\n", err.msg);
        store_close(s);
        return 1;
    }
    store_close(s);
    if (json)
        print_json(rows, n, now);
    else
        print_table(rows, n, now);
    free(rows);
    return 0;
}

CMD_REGISTER(hosts, "hosts", USAGE,
             "list the hosts sharing a store: lease age, live or expired, printers, jobs held",
             run_hosts)
