/*
 * sim_marlin_cmd.c - the simulated Marlin's command interpreter and its
 * machine model (sim_marlin_int.h).
 *
 * What: runs the queue head as Marlin would, one command family at a time
 * (moves into the planner, waits for homing, probing, dwell and heat-ups
 * with their busy and temperature reports, settings, reports, M115's
 * capabilities), logs what it executes, fires the faults that count
 * executed commands, and advances the planner and heaters in simulated
 * time.
 *
 * Thread: loop thread only.
 */
#include "sim_marlin_int.h"

#include <fcntl.h>
#include <math.h>
#include <stdio.h>
#include <string.h>
#include <unistd.h>

#include "../../src/base/gcode.h"

#define KEEPALIVE_MS   2000 /* Marlin's DEFAULT_KEEPALIVE_INTERVAL */
#define HOLD_LOOK_MS   50   /* faults.hold_path: how often its file is looked at */
#define WAIT_REPORT_MS 1000 /* M109/M190 print temperatures every second */
#define G29_S          45.0 /* bed levelling: a 3x3 probe grid, simulated seconds */

int
sim_planner_free(const struct sim_marlin *s)
{
    return s->cfg.planner_blocks - s->pl_len;
}

static void
sync_planner(struct sim_marlin *s)
{
    s->starve_armed = false;
}

static void
push_block(struct sim_marlin *s, double dur_s)
{
    if (s->pl_len == 0 && s->starve_armed) {
        s->st.starved++;
        s->st.starved_s += s->sim_s - s->starve_since_s;
        s->starve_armed = false;
    }
    int i = (s->pl_head + s->pl_len) % s->cfg.planner_blocks;
    s->planner[i].dur_s = dur_s;
    if (s->pl_len == 0)
        s->pl_left_s = dur_s;
    s->pl_len++;
}

void
sim_advance_planner(struct sim_marlin *s, double dt_s)
{
    while (s->pl_len > 0 && dt_s > 0) {
        double use = dt_s < s->pl_left_s ? dt_s : s->pl_left_s;
        s->pl_left_s -= use;
        dt_s -= use;
        if (s->pl_left_s <= 1e-12) {
            s->pl_head = (s->pl_head + 1) % s->cfg.planner_blocks;
            s->pl_len--;
            if (s->pl_len > 0) {
                s->pl_left_s = s->planner[s->pl_head].dur_s;
            } else {
                s->starve_armed = true;
                s->starve_since_s = s->sim_s - dt_s;
            }
        }
    }
}

static double
approach(double t, double target, double heat_c_s, double dt_s)
{
    double floor_c = target > AMBIENT_C ? target : AMBIENT_C;
    if (target > t)
        return fmin(target, t + heat_c_s * dt_s);
    double cool = fmax(0.5, (t - AMBIENT_C) / 40.0) * dt_s;
    return fmax(floor_c, t - cool);
}

void
sim_advance_heaters(struct sim_marlin *s, double dt_s)
{
    s->t_noz = approach(s->t_noz, s->t_noz_target, 4.0, dt_s);
    s->t_bed = approach(s->t_bed, s->t_bed_target, 1.5, dt_s);
}

static double
move_len(struct sim_marlin *s, const struct gcode_line *g, double *target)
{
    static const char axes[4] = { 'X', 'Y', 'Z', 'E' };
    for (int a = 0; a < 4; a++) {
        double v;
        target[a] = s->pos[a];
        if (gcode_get(g, axes[a], &v) && !isnan(v))
            target[a] = (a < 3 ? s->rel_xyz : s->rel_e) ? s->pos[a] + v : v;
    }
    double dx = target[0] - s->pos[0], dy = target[1] - s->pos[1], dz = target[2] - s->pos[2];
    double d = sqrt(dx * dx + dy * dy + dz * dz);
    if (gcode_is(g, 'G', 2) || gcode_is(g, 'G', 3)) {
        double i = 0, j = 0;
        gcode_get(g, 'I', &i);
        gcode_get(g, 'J', &j);
        double cx = s->pos[0] + (isnan(i) ? 0 : i), cy = s->pos[1] + (isnan(j) ? 0 : j);
        double r = hypot(s->pos[0] - cx, s->pos[1] - cy);
        double a0 = atan2(s->pos[1] - cy, s->pos[0] - cx);
        double a1 = atan2(target[1] - cy, target[0] - cx);
        double sweep = gcode_is(g, 'G', 2) ? a0 - a1 : a1 - a0;
        while (sweep <= 1e-9)
            sweep += 2 * M_PI;
        d = hypot(r * sweep, dz);
    }
    return d > 0 ? d : fabs(target[3] - s->pos[3]);
}

/* What running a command came to. */
enum run {
    RUN_DONE,    /* done: "ok" follows */
    RUN_OWN_OK,  /* done, and it printed its own ok (M105) */
    RUN_BLOCKED, /* not yet: planner full, heating, dwell */
    RUN_UNKNOWN, /* not a command this printer knows */
};

/* G0-G3: a block into the planner, once it has room. */
static enum run
run_move(struct sim_marlin *s, const struct gcode_line *g)
{
    double v;
    if (gcode_get(g, 'F', &v) && v > 0)
        s->feed_mm_s = v / 60.0;
    if (sim_planner_free(s) == 0)
        return RUN_BLOCKED;
    double target[4];
    double d = move_len(s, g, target);
    if (d > 0)
        push_block(s, d / s->feed_mm_s);
    memcpy(s->pos, target, sizeof(target));
    return RUN_DONE;
}

/* G4, G28, G29: wait for the planner, then for the dwell, homing or probing. */
static enum run
run_wait(struct sim_marlin *s, const struct gcode_line *g, int64_t now)
{
    double v;
    if (s->pl_len > 0)
        return RUN_BLOCKED;
    sync_planner(s);
    if (s->dwell_s < 0) {
        double secs = 0;
        if (g->code == 28)
            secs = 3.0;
        else if (g->code == 29)
            secs = G29_S;
        else if (gcode_get(g, 'P', &v) && !isnan(v))
            secs = v / 1000.0;
        else if (gcode_get(g, 'S', &v) && !isnan(v))
            secs = v;
        s->dwell_s = s->sim_s + secs;
    }
    if (s->sim_s < s->dwell_s) {
        if (g->code >= 28 && !s->cfg.no_keepalive && now >= s->keepalive_ms) {
            sim_emit(s, "echo:busy: processing");
            s->keepalive_ms = now + KEEPALIVE_MS;
        }
        return RUN_BLOCKED;
    }
    s->dwell_s = -1;
    if (g->code == 28) {
        /* G28 X Y homes those axes only (a resume must not home Z into the part) */
        bool any = gcode_get(g, 'X', NULL) || gcode_get(g, 'Y', NULL) || gcode_get(g, 'Z', NULL);
        for (int a = 0; a < 3; a++)
            if (!any || gcode_get(g, "XYZ"[a], NULL))
                s->pos[a] = 0;
    }
    return RUN_DONE;
}

static enum run
run_g(struct sim_marlin *s, const struct gcode_line *g, int64_t now)
{
    double v;
    switch (g->code) {
    case 0:
    case 1:
    case 2:
    case 3:
        return run_move(s, g);
    case 4:
    case 28:
    case 29:
        return run_wait(s, g, now);
    case 90:
        s->rel_xyz = s->rel_e = false;
        return RUN_DONE;
    case 91:
        s->rel_xyz = s->rel_e = true;
        return RUN_DONE;
    case 92: {
        static const char axes[4] = { 'X', 'Y', 'Z', 'E' };
        for (int a = 0; a < 4; a++)
            if (gcode_get(g, axes[a], &v))
                s->pos[a] = isnan(v) ? 0 : v;
        return RUN_DONE;
    }
    case 20:
    case 21:
        return RUN_DONE;
    default:
        return RUN_UNKNOWN;
    }
}

/* M109, M190: set the target when the wait starts, report until it is reached (or M108). */
static enum run
run_heat_wait(struct sim_marlin *s, const struct gcode_line *g, int64_t now)
{
    double v;
    double *t = g->code == 109 ? &s->t_noz : &s->t_bed;
    double *tt = g->code == 109 ? &s->t_noz_target : &s->t_bed_target;
    bool both = false;
    if (!s->head_started || s->head_since_ms == now) {
        if (gcode_get(g, 'S', &v) && !isnan(v))
            *tt = v;
        else if (gcode_get(g, 'R', &v) && !isnan(v))
            *tt = v;
    }
    both = gcode_get(g, 'R', NULL);
    bool reached = both ? fabs(*t - *tt) <= 1.0 : *t >= *tt - 1.0;
    if (!reached && !s->wait_heat_interrupted) {
        if (now >= s->keepalive_ms) {
            sim_emit_temps(s, " ", true);
            s->keepalive_ms = now + WAIT_REPORT_MS;
        }
        return RUN_BLOCKED;
    }
    s->wait_heat_interrupted = false;
    return RUN_DONE;
}

/* M115: the firmware and its capabilities. */
static void
report_firmware(struct sim_marlin *s)
{
    sim_emit(s, "FIRMWARE_NAME:Marlin 2.1.2.1 (slimfarm-sim) SOURCE_CODE_URL:"
                "github.com/MarlinFirmware/Marlin PROTOCOL_VERSION:1.0 "
                "MACHINE_TYPE:slimfarm-sim EXTRUDER_COUNT:1 "
                "UUID:cede2a2f-41a2-4748-9b12-c55c62f367ff");
    sim_emit(s, "Cap:SERIAL_XON_XOFF:0");
    sim_emit(s, "Cap:EEPROM:0");
    sim_emit(s, "Cap:AUTOREPORT_TEMP:1");
    sim_emit(s, "Cap:PROGRESS:0");
    sim_emit(s, "Cap:PRINT_JOB:1");
    sim_emit(s, "Cap:EMERGENCY_PARSER:1");
    sim_emit(s, "Cap:HOST_ACTION_COMMANDS:1");
    sim_emit(s, "Cap:THERMAL_PROTECTION:1");
    sim_emit(s, "Cap:ARCS:1");
    sim_emit(s, "Cap:ADVANCED_OK:%d", s->cfg.advanced_ok ? 1 : 0);
}

/* Reports: M105 (its own ok), M114, M115, M118. */
static enum run
run_report(struct sim_marlin *s, const struct gcode_line *g)
{
    switch (g->code) {
    case 105:
        if (s->faults.okt_plain)
            return RUN_DONE; /* fault okt=plain: the ok alone */
        sim_emit_temps(s, "ok ", false);
        return RUN_OWN_OK; /* M105 prints its own ok */
    case 114:
        sim_emit(s, "X:%.2f Y:%.2f Z:%.2f E:%.2f Count X:%ld Y:%ld Z:%ld", s->pos[0], s->pos[1],
                 s->pos[2], s->pos[3], lround(s->pos[0] * 80), lround(s->pos[1] * 80),
                 lround(s->pos[2] * 400));
        return RUN_DONE;
    case 115:
        report_firmware(s);
        return RUN_DONE;
    default: { /* 118: A1, E1 and Pn are parsed off the front, up to three (M118.cpp) */
        const char *t = g->text ? g->text : "";
        size_t n = g->text ? g->text_len : 0;
        bool e = false, a = false;
        for (int k = 0; k < 3 && n >= 2; k++) {
            if (!(((t[0] == 'A' || t[0] == 'E') && t[1] == '1') ||
                  (t[0] == 'P' && t[1] >= '0' && t[1] <= '9')))
                break;
            e |= t[0] == 'E';
            a |= t[0] == 'A';
            for (t += 2, n -= 2; n && *t == ' '; t++, n--)
                ;
        }
        /* without E1 the text goes out raw: a host reads "ok" or "Resend: 1" as a reply */
        sim_emit(s, "%s%s%.*s", e ? "echo:" : "", a ? "//" : "", (int)n, t);
        return RUN_DONE;
    }
    }
}

/*
 * Waits for a person: M0/M1 (no S or P), M600 (the filament change's
 * "press to continue"): "busy: paused for user" every 2 s until M108 (the
 * emergency parser clears wait_for_user as it clears wait_for_heatup), as
 * Marlin does with no LCD.  M226 (a pin's state) never changes in the sim:
 * it waits for good, "busy: processing", as Marlin's loop does (M108 does
 * not break it).
 */
static enum run
run_wait_user(struct sim_marlin *s, const struct gcode_line *g, int64_t now)
{
    bool pin = g->code == 226;
    if (s->pl_len > 0)
        return RUN_BLOCKED; /* planner.synchronize() first */
    sync_planner(s);
    if (!pin && s->wait_heat_interrupted) {
        s->wait_heat_interrupted = false;
        return RUN_DONE;
    }
    if (!s->cfg.no_keepalive && now >= s->keepalive_ms) {
        sim_emit(s, pin ? "echo:busy: processing" : "echo:busy: paused for user");
        s->keepalive_ms = now + KEEPALIVE_MS;
    }
    return RUN_BLOCKED;
}

/*
 * The rest of the policy's rows (drivers/gpolicy.h) as Marlin runs them:
 * M111 sets the debug flags and says which (with ECHO on, every command is
 * echoed back), M502 loads the defaults, M997 reboots into the bootloader
 * (after this command's ok is lost), M999 asks the host to resend from
 * last_n + 1 and empties the queue, M25 asks the host to pause (its
 * ACTION_ON_PAUSE).
 */
static enum run
run_policy_row(struct sim_marlin *s, const struct gcode_line *g)
{
    double v;
    switch (g->code) {
    case 111: {
        static const char *const names[] = { "ECHO",   "INFO",          "ERRORS",
                                             "DRYRUN", "COMMUNICATION", "LEVELING" };
        if (gcode_get(g, 'S', &v) && !isnan(v))
            s->debug_flags = (int)v & 63;
        char buf[96] = "";
        for (size_t i = 0, n = 0; i < 6; i++)
            if (s->debug_flags & (1 << i))
                n += (size_t)snprintf(buf + n, sizeof(buf) - n, "%s%s", n ? "," : "", names[i]);
        sim_emit(s, "echo:DEBUG:%s", buf[0] ? buf : "None");
        return RUN_DONE;
    }
    case 502:
        sim_emit(s, "echo:Hardcoded Default Settings Loaded");
        return RUN_DONE;
    case 997:
        s->reset_pending = true;
        return RUN_OWN_OK;
    case 999:
        s->halted = false;
        s->q_len = 1; /* flush_and_request_resend: the queue is emptied (this head popped next) */
        sim_emit(s, "Resend: %ld", s->last_n + 1);
        sim_emit(s, "ok");
        return RUN_OWN_OK;
    default: /* 25 */
        sim_emit(s, "//action:pause");
        return RUN_DONE;
    }
}

static enum run
run_m(struct sim_marlin *s, const struct gcode_line *g, int64_t now)
{
    double v;
    switch (g->code) {
    case 82:
        s->rel_e = false;
        return RUN_DONE;
    case 83:
        s->rel_e = true;
        return RUN_DONE;
    case 104:
    case 140:
        if (gcode_get(g, 'S', &v) && !isnan(v))
            *(g->code == 104 ? &s->t_noz_target : &s->t_bed_target) = v;
        return RUN_DONE;
    case 109:
    case 190:
        return run_heat_wait(s, g, now);
    case 105:
    case 114:
    case 115:
    case 118:
        return run_report(s, g);
    case 0:
    case 1:
        if (gcode_get(g, 'S', NULL) || gcode_get(g, 'P', NULL))
            return run_wait(s, g, now); /* a timed wait, as G4 */
        return run_wait_user(s, g, now);
    case 226:
    case 600:
        return run_wait_user(s, g, now);
    case 25:
    case 111:
    case 502:
    case 997:
    case 999:
        return run_policy_row(s, g);
    case 400:
        if (s->pl_len > 0)
            return RUN_BLOCKED;
        sync_planner(s);
        return RUN_DONE;
    case 110:
        if (gcode_get(g, 'N', &v) && !isnan(v))
            s->last_n = (long)v;
        return RUN_DONE;
    case 155:
        if (gcode_get(g, 'S', &v) && !isnan(v) && v >= 0 && v <= 60) {
            s->autoreport_s = (int)v;
            s->autoreport_ms = now + (int64_t)v * 1000;
        }
        return RUN_DONE;
    case 17:
    case 18:
    case 84:
    case 106:
    case 107:
    case 108:
    case 112:
    case 117:
    case 73:
    case 75:
    case 76:
    case 77:
    case 201:
    case 203:
    case 204:
    case 205:
    case 220:
    case 221:
    case 410:
    case 900:
        return RUN_DONE;
    default:
        return RUN_UNKNOWN;
    }
}

/* Run the queue head; false while it blocks (planner full, heating, dwell). */
static bool
run_command(struct sim_marlin *s, const char *raw, const char *cmd, struct gcode_line *g)
{
    int64_t now = loop_now_ms(s->loop);
    enum run rc = RUN_UNKNOWN;
    if (g->letter == 'G') {
        rc = run_g(s, g, now);
    } else if (g->letter == 'M') {
        rc = run_m(s, g, now);
    } else if (g->letter == 'T') {
        /* one extruder: T0 only */
        if (g->code != 0)
            sim_emit(s, "echo:Invalid extruder %d", g->code);
        rc = RUN_DONE;
    }
    if (rc == RUN_BLOCKED)
        return false;
    if (rc == RUN_OWN_OK)
        return true;
    if (rc == RUN_UNKNOWN)
        sim_emit(s, "echo:Unknown command: \"%s\"", cmd);
    else if (s->debug_flags & 1)
        sim_emit(s, "echo:%s", cmd); /* M111 S1: DEBUG_ECHO echoes each command */
    sim_send_ok(s, raw);
    return true;
}

/* Commands this printer runs; anything else is "Unknown command" and not logged. */
static bool
known(const struct gcode_line *g)
{
    static const int g_codes[] = { 0, 1, 2, 3, 4, 20, 21, 28, 29, 90, 91, 92 };
    static const int m_codes[] = { 0,   1,   17,  18,  25,  73,  75,  76,  77,  82,  83,
                                   84,  104, 105, 106, 107, 108, 109, 110, 111, 112, 114,
                                   115, 117, 118, 140, 155, 190, 201, 203, 204, 205, 220,
                                   221, 226, 400, 410, 502, 600, 900, 997, 999 };
    if (g->letter == 'T')
        return true;
    const int *v = g->letter == 'G' ? g_codes : g->letter == 'M' ? m_codes : NULL;
    size_t n = g->letter == 'G' ? sizeof(g_codes) / sizeof(int) : sizeof(m_codes) / sizeof(int);
    for (size_t i = 0; v && i < n; i++)
        if (v[i] == g->code)
            return true;
    return false;
}

static void
check_fault_triggers(struct sim_marlin *s)
{
    uint64_t n = s->st.executed;
    if (s->faults.runaway_after && n == (uint64_t)s->faults.runaway_after) {
        sim_emit(s, "Error:Thermal Runaway, system stopped! Heater_ID: 0");
        sim_emit(s, "Error:Printer halted. kill() called!");
        s->halted = true;
    }
    if (s->faults.reset_after && n == (uint64_t)s->faults.reset_after)
        sim_firmware_reset(s, true);
    if (s->faults.stuck_after && n == (uint64_t)s->faults.stuck_after)
        s->stuck = true;
    if (s->faults.disconnect_after && n == (uint64_t)s->faults.disconnect_after)
        sim_drop_link(s);
    if (s->cfg.deaf_after && n == (uint64_t)s->cfg.deaf_after)
        s->deaf = true;
    if (s->cfg.hang_after && n == (uint64_t)s->cfg.hang_after) {
        s->hung = true; /* what it was about to send is lost with it */
        sim_free_out(s);
        buf_reset(&s->tx);
    }
}

/* faults.hold_path exists (looked at every HOLD_LOOK_MS at most). */
static bool
hold_armed(struct sim_marlin *s, int64_t now)
{
    if (!s->faults.hold_path[0])
        return false;
    if (now >= s->hold_look_ms) {
        s->hold_on = access(s->faults.hold_path, F_OK) == 0;
        s->hold_look_ms = now + HOLD_LOOK_MS;
    }
    return s->hold_on;
}

/* A move that prints: G0-G3 with E and X or Y (not a travel, a retraction or a park). */
static bool
printing_move(const struct gcode_line *g)
{
    double v;
    return g->letter == 'G' && g->code >= 0 && g->code <= 3 && gcode_get(g, 'E', &v) &&
           (gcode_get(g, 'X', &v) || gcode_get(g, 'Y', &v));
}

/* Hold the head (a printing move, not yet run): tell the hold's file what waits. */
static void
hold(struct sim_marlin *s, const char *cmd, int64_t now)
{
    s->held = true;
    s->head_started = false; /* it starts, fresh, once released */
    s->keepalive_ms = now + KEEPALIVE_MS;
    int fd = open(s->faults.hold_path, O_WRONLY | O_APPEND | O_CLOEXEC); /* never created */
    if (fd < 0)
        return; /* removed meanwhile: the next look releases it */
    char note[MAX_CMD_SIZE + 16];
    int n = snprintf(note, sizeof(note), "held: %s\n", cmd);
    if (write(fd, note, (size_t)n) < 0) {
        /* a note lost: the hold itself stands */
    }
    close(fd);
}

void
sim_run_queue(struct sim_marlin *s)
{
    int64_t now0 = loop_now_ms(s->loop);
    if (s->held && !hold_armed(s, now0))
        s->held = false;
    if (s->stuck || s->held) { /* the command at the head does not end: keepalives only */
        if (s->q_len > 0 && !s->cfg.no_keepalive && now0 >= s->keepalive_ms) {
            sim_emit(s, "echo:busy: processing");
            s->keepalive_ms = now0 + KEEPALIVE_MS;
        }
        return;
    }
    for (int guard = 0; guard < 64 && s->q_len > 0 && !s->halted && !s->hung; guard++) {
        const char *raw = s->queue[s->q_head];
        char cmd[MAX_CMD_SIZE];
        size_t n = gcode_strip(raw, strlen(raw), cmd, sizeof(cmd), NULL);
        struct gcode_line g;
        struct sf_err err;
        int64_t now = loop_now_ms(s->loop);
        bool fresh = !s->head_started;
        if (fresh) {
            s->head_started = true;
            s->head_since_ms = now;
            s->keepalive_ms = now + KEEPALIVE_MS;
            s->dwell_s = -1;
        }
        bool done;
        if (gcode_parse(cmd, n, &g, &err) < 0) {
            sim_emit(s, "echo:Unknown command: \"%s\"", cmd);
            sim_send_ok(s, raw);
            done = true;
        } else {
            if (fresh && printing_move(&g) && hold_armed(s, now)) {
                hold(s, cmd, now);
                return;
            }
            if (fresh && known(&g)) {
                s->st.executed++;
                /* the command as Marlin reads it: "M00105" runs as M105 */
                size_t z = 1;
                while (cmd[0] == 'M' && cmd[z] == '0' && cmd[z + 1] >= '0' && cmd[z + 1] <= '9')
                    z++;
                if (s->log && n > 0)
                    fprintf(s->log, "%c%s\n", cmd[0], cmd + z);
            }
            done = run_command(s, raw, cmd, &g);
        }
        if (!done)
            return;
        s->head_started = false;
        s->q_head = (s->q_head + 1) % s->cfg.bufsize;
        s->q_len--;
        check_fault_triggers(s);
        if (s->reset_pending) { /* M997: the bootloader, then "start" */
            s->reset_pending = false;
            sim_firmware_reset(s, true);
            return;
        }
        if (s->fd < 0 && s->kind == LINK_TCP)
            return;
    }
}
