/*
 * test_sched.c - the scheduler's rules one by one: priority then FIFO,
 * idle only, bed-clear gate, material/bed/target/group matching, the prepared-for key and
 * re-slicing, best fit, retry avoidance, reasons for jobs left waiting, and a randomized check that
 * no plan ever breaks a rule.
 */
#include <stdlib.h>

#include "../../src/farm/sched.h"
#include "../t.h"

static struct sched_printer
printer(const char *name, const char *material, double nozzle, double x, double y, double z)
{
    struct sched_printer p = { name,        PRINTER_IDLE, true,  material, nozzle,
                               { x, y, z }, "",           "gen", 45,       NULL };
    return p;
}

static struct sched_job
job(int64_t id, int prio, const char *material, double x, double y, double z)
{
    struct sched_job j = { id,   JOB_READY,   prio, material, "",    "",
                           NULL, { x, y, z }, NULL, 0,        false, 0 };
    return j;
}

/* Keys for the printers of a test, and a job prepared for one of them. */
static char keys[8][SCHED_KEY_MAX];

static void
prepared_for(struct sched_job *j, const struct sched_printer *p, size_t n, size_t which)
{
    for (size_t i = 0; i < n; i++)
        sched_key(&p[i], j->overhang_deg, keys[i]);
    j->key = keys[which];
}

T_CASE(sched_priority_then_fifo)
{
    struct sched_printer p[] = { printer("a", "PLA", 0.4, 200, 200, 200) };
    struct sched_job j[] = { job(3, 0, "", 10, 10, 10), job(1, 0, "", 10, 10, 10),
                             job(2, 5, "", 10, 10, 10) };
    struct sched_assign out[3];
    char why[3][SCHED_REASON_MAX];
    T_EQ_INT(sched_plan(j, 3, p, 1, out, why), 1);
    T_EQ_INT(j[out[0].job].id, 2); /* highest priority */
    j[2].priority = 0;
    T_EQ_INT(sched_plan(j, 3, p, 1, out, why), 1);
    T_EQ_INT(j[out[0].job].id, 1); /* then the oldest */
    T_EQ_STR(why[0], "waits for a printer: a is taken by a job before it");
    T_EQ_STR(why[1], "");
    /* the queue's order within a priority (the operator moved job 3 up) beats the id */
    j[0].order = 1;
    j[1].order = 2;
    j[2].order = 3;
    T_EQ_INT(sched_plan(j, 3, p, 1, out, why), 1);
    T_EQ_INT(j[out[0].job].id, 3);
}

T_CASE(sched_only_idle_enabled_printers)
{
    struct sched_printer p[] = { printer("busy", "PLA", 0.4, 200, 200, 200),
                                 printer("full", "PLA", 0.4, 200, 200, 200),
                                 printer("off", "PLA", 0.4, 200, 200, 200),
                                 printer("disabled", "PLA", 0.4, 200, 200, 200) };
    p[0].state = PRINTER_PRINTING;
    p[1].state = PRINTER_AWAITING_CLEAR;
    p[2].state = PRINTER_OFFLINE;
    p[3].enabled = false;
    struct sched_job j[] = { job(1, 0, "", 10, 10, 10) };
    struct sched_assign out[1];
    char why[1][SCHED_REASON_MAX];
    T_EQ_INT(sched_plan(j, 1, p, 4, out, why), 0);
    T_EQ_STR(why[0], "waits for a printer: busy is printing; full is awaiting-clear; off is "
                     "offline");
    /* the bed cleared: the job goes */
    p[1].state = PRINTER_IDLE;
    T_EQ_INT(sched_plan(j, 1, p, 4, out, why), 1);
    T_EQ_INT(out[0].printer, 1);
}

T_CASE(sched_material_bed_must_match)
{
    struct sched_printer p[] = { printer("pla", "PLA", 0.4, 200, 200, 200),
                                 printer("petg06", "PETG", 0.6, 200, 200, 200),
                                 printer("small", "PETG", 0.4, 100, 100, 100) };
    struct sched_job j[] = { job(1, 0, "PETG", 150, 50, 50) };
    struct sched_assign out[1];
    char why[1][SCHED_REASON_MAX];
    p[1].state = PRINTER_PRINTING;
    T_EQ_INT(sched_plan(j, 1, p, 3, out, why), 0);
    T_EQ_STR(why[0], "waits for a printer: petg06 is printing");
    p[1].state = PRINTER_OFFLINE;
    p[1].enabled = false;
    T_EQ_INT(sched_plan(j, 1, p, 3, out, why), 0);
    T_EQ_STR(why[0], "fits no printer: pla: material PETG not loaded (has PLA); petg06: disabled; "
                     "small: part 150x50x50 mm does not fit bed 100x100x100 mm");
    p[1].state = PRINTER_IDLE;
    p[1].enabled = true;
    prepared_for(&j[0], p, 3, 1);
    T_EQ_INT(sched_plan(j, 1, p, 3, out, why), 1);
    T_EQ_INT(out[0].printer, 1);
    T_TRUE(!out[0].reslice);
    /* no material asked: any material; best fit among the printers of its key */
    j[0].material = "";
    j[0].size_mm[0] = 50;
    prepared_for(&j[0], p, 3, 2);
    T_EQ_INT(sched_plan(j, 1, p, 3, out, why), 1);
    T_EQ_INT(out[0].printer, 2); /* the smallest bed that holds it */
    T_TRUE(!out[0].reslice);
}

/*
 * The farm's bug (issue 15): G-code sliced for a 300x300 bed started on an
 * idle 180x180 printer with the same nozzle.  A ready job runs only on a
 * printer of its key; one that waits for a busy printer of its key while
 * another printer idles is given that printer to be sliced again for.
 */
T_CASE(sched_ready_job_runs_only_on_its_key_else_is_resliced)
{
    struct sched_printer p[] = { printer("wide", "PLA", 0.4, 300, 300, 250),
                                 printer("small", "PLA", 0.4, 180, 180, 180) };
    p[1].profile = "other";
    struct sched_job j[] = { job(1, 0, "", 80, 80, 5), job(2, 0, "", 80, 80, 5) };
    prepared_for(&j[0], p, 2, 0);
    prepared_for(&j[1], p, 2, 0);
    T_TRUE(!sched_runs_on(&j[0], &p[1])); /* not its key, though the nozzle and bed fit */
    T_TRUE(sched_runs_on(&j[0], &p[0]));
    struct sched_assign out[2];
    char why[2][SCHED_REASON_MAX];
    /* both idle: job 1 starts on wide (its key, though small is the better fit);
       job 2 waits for wide, so it is sliced again for small */
    T_EQ_INT(sched_plan(j, 2, p, 2, out, why), 2);
    T_EQ_INT(out[0].job, 0);
    T_EQ_INT(out[0].printer, 0);
    T_TRUE(!out[0].reslice);
    T_EQ_INT(out[1].job, 1);
    T_EQ_INT(out[1].printer, 1);
    T_TRUE(out[1].reslice);
    /* wide busy: the only job goes to small to be sliced again */
    p[0].state = PRINTER_PRINTING;
    T_EQ_INT(sched_plan(j, 1, p, 2, out, why), 1);
    T_EQ_INT(out[0].printer, 1);
    T_TRUE(out[0].reslice);
    /* sliced for small now: it starts there */
    prepared_for(&j[0], p, 2, 1);
    T_EQ_INT(sched_plan(j, 1, p, 2, out, why), 1);
    T_TRUE(!out[0].reslice);
    /* the job's own angle is part of the key */
    j[0].overhang_deg = 60;
    T_TRUE(!sched_runs_on(&j[0], &p[1]));
    prepared_for(&j[0], p, 2, 1);
    T_TRUE(sched_runs_on(&j[0], &p[1]));
    /* not prepared (no key): never started, only sliced */
    j[0].key = NULL;
    T_EQ_INT(sched_plan(j, 1, p, 2, out, why), 1);
    T_TRUE(out[0].reslice);
}

/*
 * Issue 31: a job naming no material took the only PETG printer (the best
 * fit) while a PETG job waited; it takes the PLA printer no one else needs,
 * is prepared for it, and is sliced again for it rather than start its
 * PETG-sliced G-code on the needed printer.
 */
T_CASE(sched_materialless_job_leaves_needed_printer)
{
    struct sched_printer p[] = { printer("petg", "PETG", 0.4, 200, 200, 200),
                                 printer("pla", "PLA", 0.4, 250, 250, 250) };
    struct sched_job j[] = { job(1, 0, "", 10, 10, 10), job(2, 0, "PETG", 10, 10, 10) };
    j[1].state = JOB_QUEUED;
    struct sched_assign out[2];
    char why[2][SCHED_REASON_MAX];
    T_EQ_INT(sched_plan(j, 2, p, 2, out, why), 1);
    T_EQ_INT(out[0].job, 0);
    T_EQ_INT(out[0].printer, 1);
    T_EQ_INT(sched_prepare_for(j, 2, 0, p, 2), 1);
    T_EQ_INT(sched_prepare_for(j, 2, 1, p, 2), 0);
    /* already sliced for the PETG printer: sliced again for the free one */
    prepared_for(&j[0], p, 2, 0);
    T_EQ_INT(sched_plan(j, 2, p, 2, out, why), 1);
    T_EQ_INT(out[0].printer, 1);
    T_TRUE(out[0].reslice);
    /* it cannot be sliced again now (the pool is full, or slicing it failed): it prints on the
       PETG printer rather than wait beside it for a slicing that does not come (review) */
    j[0].stalled = true;
    T_EQ_INT(sched_plan(j, 2, p, 2, out, why), 1);
    T_EQ_INT(out[0].printer, 0);
    T_TRUE(!out[0].reslice);
    j[0].stalled = false;
    /* PLA busy: it waits in line, and takes the PETG printer as FIFO says */
    p[1].state = PRINTER_PRINTING;
    T_EQ_INT(sched_prepare_for(j, 2, 0, p, 2), 0);
    T_EQ_INT(sched_plan(j, 2, p, 2, out, why), 1);
    T_EQ_INT(out[0].printer, 0);
    /* no job needs PETG any more: best fit again */
    p[1].state = PRINTER_IDLE;
    j[1].state = JOB_DONE;
    j[0].key = NULL;
    T_EQ_INT(sched_plan(j, 2, p, 2, out, why), 1);
    T_EQ_INT(out[0].printer, 0);
}

/*
 * Issue 31 finding 5: job 2, submitted after job 1, was ready first and
 * printed first.  Job 1, still being prepared, holds the idle printer.
 */
T_CASE(sched_first_come_first_served_while_preparing)
{
    struct sched_printer p[] = { printer("a", "PLA", 0.4, 200, 200, 200),
                                 printer("b", "PLA", 0.4, 200, 200, 200) };
    p[1].state = PRINTER_PRINTING;
    struct sched_job j[] = { job(1, 0, "", 10, 10, 10), job(2, 0, "", 10, 10, 10) };
    j[0].state = JOB_PREPARING;
    prepared_for(&j[1], p, 2, 0);
    struct sched_assign out[2];
    char why[2][SCHED_REASON_MAX];
    T_EQ_INT(sched_plan(j, 2, p, 2, out, why), 0);
    T_EQ_STR(why[1], "waits for a printer: a is taken by a job before it; b is printing");
    j[0].state = JOB_QUEUED;
    T_EQ_INT(sched_plan(j, 2, p, 2, out, why), 0);
    /* a queued job that cannot be prepared now (the pool is full) holds no printer idle */
    j[0].stalled = true;
    T_EQ_INT(sched_plan(j, 2, p, 2, out, why), 1);
    T_EQ_INT(out[0].job, 1);
    j[0].stalled = false;
    /* a higher priority still goes first */
    j[1].priority = 1;
    T_EQ_INT(sched_plan(j, 2, p, 2, out, why), 1);
    T_EQ_INT(out[0].job, 1);
    /* b free too: both the held printer and the later job are served */
    j[1].priority = 0;
    p[1].state = PRINTER_IDLE;
    T_EQ_INT(sched_plan(j, 2, p, 2, out, why), 1);
    T_EQ_INT(out[0].job, 1);
    T_EQ_INT(out[0].printer, 1);
    T_TRUE(!out[0].reslice); /* a and b share a key */
}

T_CASE(sched_bed_fit_turns_part)
{
    double bed[3] = { 250, 210, 200 };
    double a[3] = { 240, 200, 200 }, b[3] = { 200, 240, 10 }, c[3] = { 240, 240, 10 },
           d[3] = { 10, 10, 201 };
    T_TRUE(sched_fits_bed(a, bed));
    T_TRUE(sched_fits_bed(b, bed));
    T_TRUE(!sched_fits_bed(c, bed));
    T_TRUE(!sched_fits_bed(d, bed));
}

T_CASE(sched_targets_printer_and_group)
{
    struct sched_printer p[] = { printer("a", "PLA", 0.4, 200, 200, 200),
                                 printer("b", "PLA", 0.4, 300, 300, 300),
                                 printer("c", "PLA", 0.4, 300, 300, 300) };
    p[1].group = "big";
    p[2].group = "big";
    struct sched_job j[] = { job(1, 0, "", 10, 10, 10), job(2, 0, "", 10, 10, 10) };
    j[0].printer = "c";
    j[1].group = "big";
    struct sched_assign out[2];
    char why[2][SCHED_REASON_MAX];
    T_EQ_INT(sched_plan(j, 2, p, 3, out, why), 2);
    T_EQ_INT(out[0].printer, 2);
    T_EQ_INT(out[1].printer, 1);
    j[0].printer = "nosuch";
    T_EQ_INT(sched_plan(j, 2, p, 3, out, why), 1);
    T_TRUE(strstr(why[0], "fits no printer: a: not the target printer nosuch") == why[0]);
    j[1].group = "tiny";
    T_EQ_INT(sched_plan(j, 2, p, 3, out, why), 0);
    T_TRUE(strstr(why[1], "b: not in group tiny") != NULL);
}

T_CASE(sched_retry_avoids_failing_printer)
{
    struct sched_printer p[] = { printer("a", "PLA", 0.4, 200, 200, 200),
                                 printer("b", "PLA", 0.4, 250, 250, 250) };
    struct sched_job j[] = { job(1, 0, "", 10, 10, 10) };
    j[0].avoid = "a";
    struct sched_assign out[1];
    T_EQ_INT(sched_plan(j, 1, p, 2, out, NULL), 1);
    T_EQ_INT(out[0].printer, 1); /* b, although a is the better fit */
    /* b busy: wait for it rather than go back to a */
    p[1].state = PRINTER_PRINTING;
    T_EQ_INT(sched_plan(j, 1, p, 2, out, NULL), 0);
    /* only a could ever take it: use a */
    p[1].enabled = false;
    T_EQ_INT(sched_plan(j, 1, p, 2, out, NULL), 1);
    T_EQ_INT(out[0].printer, 0);
}

T_CASE(sched_queued_jobs_only_get_reasons)
{
    struct sched_printer p[] = { printer("a", "PLA", 0.4, 200, 200, 200) };
    struct sched_job j[] = { job(1, 0, "ABS", 0, 0, 0), job(2, 0, "PLA", 0, 0, 0),
                             job(3, 0, "ABS", 0, 0, 0) };
    j[0].state = JOB_QUEUED;
    j[1].state = JOB_QUEUED;
    j[2].state = JOB_DONE;
    struct sched_assign out[1];
    char why[3][SCHED_REASON_MAX];
    T_EQ_INT(sched_plan(j, 3, p, 1, out, why), 0);
    T_EQ_STR(why[0], "fits no printer: a: material ABS not loaded (has PLA)");
    T_EQ_STR(why[1], "");
    T_EQ_STR(why[2], "");
    T_EQ_INT(sched_plan(j, 3, NULL, 0, out, why), 0);
    T_EQ_STR(why[0], "fits no printer (none configured)");
}

T_CASE(sched_reason_is_capped)
{
    struct sched_printer p[40];
    char names[40][16];
    for (int i = 0; i < 40; i++) {
        snprintf(names[i], sizeof(names[i]), "printer-%02d", i);
        p[i] = printer(names[i], "PLA", 0.4, 100, 100, 100);
    }
    struct sched_job j[] = { job(1, 0, "", 500, 500, 500) };
    char why[1][SCHED_REASON_MAX];
    struct sched_assign out[1];
    T_EQ_INT(sched_plan(j, 1, p, 40, out, why), 0);
    T_EQ_INT(strlen(why[0]), SCHED_REASON_MAX - 1);
    T_TRUE(strcmp(why[0] + SCHED_REASON_MAX - 4, "...") == 0);
}

T_CASE(sched_random_plans_keep_every_rule)
{
    static const char *const mats[] = { "PLA", "PETG", "" };
    static const char *const names[] = { "p0", "p1", "p2", "p3", "p4", "p5" };
    srand(7);
    for (int round = 0; round < 2000; round++) {
        struct sched_printer p[6];
        struct sched_job j[12];
        char pkeys[6][SCHED_KEY_MAX];
        size_t np = (size_t)(rand() % 7), nj = (size_t)(rand() % 13);
        for (size_t i = 0; i < np; i++) {
            p[i] = printer(names[i], mats[rand() % 2], rand() % 2 ? 0.4 : 0.6, 100 + rand() % 200,
                           100 + rand() % 200, 100 + rand() % 200);
            p[i].state = (enum printer_state)(rand() % PRINTER_STATE_COUNT);
            p[i].enabled = rand() % 5 != 0;
            p[i].profile = rand() % 2 ? "gen" : "mk3";
            sched_key(&p[i], 0, pkeys[i]);
        }
        for (size_t i = 0; i < nj; i++) {
            j[i] = job((int64_t)i + 1, rand() % 3, mats[rand() % 3], rand() % 300, rand() % 300,
                       rand() % 300);
            j[i].state = (enum job_state)(rand() % JOB_STATE_COUNT);
            j[i].key = np && rand() % 4 ? pkeys[rand() % np] : NULL;
        }
        struct sched_assign out[12];
        char why[12][SCHED_REASON_MAX];
        size_t n = sched_plan(j, nj, p, np, out, why);
        bool used_p[6] = { false }, used_j[12] = { false };
        for (size_t k = 0; k < n; k++) {
            const struct sched_job *a = &j[out[k].job];
            const struct sched_printer *b = &p[out[k].printer];
            T_TRUE(!used_p[out[k].printer] && !used_j[out[k].job]);
            used_p[out[k].printer] = used_j[out[k].job] = true;
            T_EQ_INT(a->state, JOB_READY);
            T_EQ_INT(b->state, PRINTER_IDLE);
            T_TRUE(sched_compatible(a, b, NULL, 0));
            /* G-code starts only where its key says; a re-slice only elsewhere */
            T_EQ_INT(sched_runs_on(a, b), !out[k].reslice);
            T_EQ_STR(why[out[k].job], "");
        }
        /* maximality in priority order: an unplaced ready job has no free
           compatible idle printer left */
        for (size_t i = 0; i < nj; i++) {
            if (used_j[i] || j[i].state != JOB_READY)
                continue;
            T_TRUE(why[i][0] != '\0');
            for (size_t q = 0; q < np; q++) {
                /* or it is held for a job before it still being prepared */
                bool held = false;
                for (size_t e = 0; e < nj; e++)
                    held |= (j[e].state == JOB_QUEUED || j[e].state == JOB_PREPARING) &&
                            (j[e].priority > j[i].priority ||
                             (j[e].priority == j[i].priority && j[e].id < j[i].id)) &&
                            sched_compatible(&j[e], &p[q], NULL, 0);
                T_TRUE(used_p[q] || held || p[q].state != PRINTER_IDLE ||
                       !sched_compatible(&j[i], &p[q], NULL, 0));
            }
        }
        /* no placed job is outranked by an unplaced one that could have
           used the same printer */
        for (size_t k = 0; k < n; k++)
            for (size_t i = 0; i < nj; i++) {
                if (used_j[i] || j[i].state != JOB_READY)
                    continue;
                const struct sched_job *a = &j[out[k].job];
                bool before = j[i].priority > a->priority ||
                              (j[i].priority == a->priority && j[i].id < a->id);
                const struct sched_printer *q = &p[out[k].printer];
                T_TRUE(!(before && sched_compatible(&j[i], q, NULL, 0) &&
                         (out[k].reslice || sched_runs_on(&j[i], q))));
            }
    }
}
