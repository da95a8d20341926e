/*
 * sim_marlin_serial.c - the simulated Marlin's serial line protocol
 * (sim_marlin_int.h).
 *
 * What: assembles RX bytes into lines as Marlin's get_serial_commands()
 * does, checks line numbers and checksums (the error, RX flush, "Resend:"
 * and "ok" Marlin answers a bad line with), queues good lines, answers
 * "ok" (ADVANCED_OK's N, P and B), and acts as Marlin's emergency parser
 * (eparser.h) on every byte before any checksum: M108, M112, M410.
 *
 * Thread: loop thread only.
 */
#include "sim_marlin_int.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "../../src/base/eparser.h"
#include "../../src/base/gcode.h"

void
sim_send_ok(struct sim_marlin *s, const char *line)
{
    if (!s->cfg.advanced_ok) {
        sim_emit(s, "ok");
        return;
    }
    /* Marlin echoes the N word of the acknowledged line, if it had one. */
    char n[24] = "";
    const char *p = line;
    while (*p == ' ')
        p++;
    if (*p == 'N') {
        int k = 0;
        n[k++] = ' ';
        n[k++] = *p++;
        while ((*p == '-' || (*p >= '0' && *p <= '9')) && k < 22)
            n[k++] = *p++;
        n[k] = '\0';
    }
    sim_emit(s, "ok%s P%d B%d", n, sim_planner_free(s), s->cfg.bufsize - s->q_len);
}

static void
line_error(struct sim_marlin *s, const char *what)
{
    sim_emit(s, "Error:%s%ld", what, s->last_n);
    s->rx_len = 0; /* Marlin empties its RX buffer on a line error */
    s->emerg_len = 0;
    sim_emit(s, "Resend: %ld", s->last_n + 1);
    sim_emit(s, "ok");
    s->st.resends++;
}

/* A complete line arrived (Marlin's get_serial_commands()). */
static void
line_done(struct sim_marlin *s)
{
    s->line[s->line_len] = '\0';
    s->line_len = 0;
    s->line_eol = false;
    char *cmd = s->line;
    while (*cmd == ' ')
        cmd++;
    if (!*cmd)
        return;
    if (*cmd == 'N') {
        char *npos = cmd;
        bool m110 = strstr(cmd, "M110") != NULL;
        if (m110) {
            char *n2 = strchr(cmd + 4, 'N');
            if (n2)
                npos = n2;
        }
        long n = strtol(npos + 1, NULL, 10);
        if (n != s->last_n + 1 && !m110) {
            line_error(s, "Line Number is not Last Line Number+1, Last Line: ");
            return;
        }
        char *star = strrchr(cmd, '*');
        if (!star) {
            line_error(s, "No Checksum with line number, Last Line: ");
            return;
        }
        uint8_t cs = gcode_checksum(cmd, (size_t)(star - cmd));
        bool bad = n == s->faults.bad_line && !m110 && !s->bad_done;
        s->bad_done |= bad;
        if (s->hit_rx_bad && strtol(cmd + 1, NULL, 10) == s->faults.hit_rx_line) {
            bad = true; /* garbled on the way in (hit-rx): one byte off, the checksum fails */
            s->hit_rx_bad = false;
        }
        if (strtol(star + 1, NULL, 10) != cs || bad) {
            line_error(s, "checksum mismatch, Last Line: ");
            return;
        }
        s->last_n = n;
    } else if (strchr(cmd, '*')) {
        /* Marlin 1.1's rule: a checksum without a line number is the tail of
           a line whose head an RX flush ate; drop it, no resend, no ok.
           (2.x dropped this check and can run such a tail: see the README.) */
        sim_emit(s, "Error:No Line Number with checksum, Last Line: %ld", s->last_n);
        return;
    }
    int i = (s->q_head + s->q_len) % s->cfg.bufsize;
    snprintf(s->queue[i], MAX_CMD_SIZE, "%s", cmd);
    s->q_len++;
}

/* The state a line's bytes leave it in (its end not included). */
static enum eparser_state
ep_line(enum eparser_state st, const char *b, int len)
{
    for (int i = 0; i < len && st != EPARSER_IGNORE && st != EPARSER_ACT; i++)
        st = eparser_step(st, (unsigned char)b[i]);
    return st;
}

/*
 * Would one byte of this line, replaced by any other (a newline included:
 * what follows it is a line of its own), make the parser act?  The judge
 * of the driver's line numbers, written apart from the driver's own check.
 */
static bool
ep_one_byte_away(const char *b, int len)
{
    enum eparser_state pre = EPARSER_RESET;
    for (int i = 0; i < len; i++) {
        for (int c = 1; c < 256; c++) {
            /* the parser tells apart spaces, N, M, digits, '-' and line
               ends; one other byte stands for the rest */
            if (c == (unsigned char)b[i] ||
                (c != 'X' && c != 'Y' && !strchr(" NM-\n\r", c) && !(c >= '0' && c <= '9')))
                continue;
            if (c == '\n' || c == '\r') {
                if (pre == EPARSER_ACT ||
                    (pre == EPARSER_RESET &&
                     ep_line(EPARSER_RESET, b + i + 1, len - i - 1) == EPARSER_ACT))
                    return true;
                continue;
            }
            if (pre == EPARSER_IGNORE)
                break;
            if (ep_line(eparser_step(pre, (unsigned char)c), b + i + 1, len - i - 1) == EPARSER_ACT)
                return true;
        }
        pre = eparser_step(pre, (unsigned char)b[i]);
    }
    /* its newline garbled: the line runs on into the next */
    return pre == EPARSER_ACT;
}

/* A line ended: act as Marlin's emergency parser would on its bytes. */
static void
emergency_line(struct sim_marlin *s)
{
    int len = s->emerg_len;
    s->emerg_len = 0;
    bool intact = !s->emerg_garbled;
    s->emerg_garbled = false;
    const char *b = s->emerg;
    if (s->faults.hit_rx && !s->hit_rx_done && len > 1 && b[0] == 'N' &&
        strtol(b + 1, NULL, 10) == s->faults.hit_rx_line && s->faults.hit_rx_pos < len) {
        s->hit_rx_done = true;
        s->hit_rx_bad = true;
        s->emerg[s->faults.hit_rx_pos] = (char)s->faults.hit_rx_byte;
        s->st.hits++;
    } else if (intact && len > 1 && b[0] == 'N' && b[1] >= '1' && b[1] <= '9' &&
               ep_line(EPARSER_RESET, b, len) != EPARSER_ACT && ep_one_byte_away(b, len)) {
        s->st.ep_near++; /* the stream's lines as sent (the handshake's are N0 or unnumbered) */
    }
    if (ep_line(EPARSER_RESET, b, len) != EPARSER_ACT)
        return;
    s->st.ep_acted++;
    while (*b == ' ' || *b == 'N' || *b == '-' || (*b >= '0' && *b <= '9'))
        b++;
    while (*b == 'M' || *b == ' ')
        b++;
    if (b[0] == '1' && b[1] == '1') {
        sim_emit(s, "Error:Printer halted. kill() called!");
        s->halted = true;
    } else if (b[0] == '1') {
        s->wait_heat_interrupted = true; /* M108 */
    } else {
        s->pl_len = 0; /* M410: quickstop */
    }
}

void
sim_emergency_byte(struct sim_marlin *s, char c)
{
    if (c != '\n' && c != '\r') {
        if (s->emerg_len < (int)sizeof(s->emerg) - 1)
            s->emerg[s->emerg_len++] = c;
        return;
    }
    emergency_line(s);
}

/*
 * Move RX bytes into lines while the queue has room (get_serial_commands).
 * Marlin 2 calls it from loop() and from idle() (manage_inactivity() calls
 * queue.get_available_commands() first thing), and every blocking wait
 * (planner full, M109/M190, G28/G29 moves, G4, M400) runs idle(): the ring
 * drains into the queue while a command blocks, until the queue is full.
 */
void
sim_assemble_lines(struct sim_marlin *s)
{
    int i = 0;
    while (i < s->rx_len && s->q_len < s->cfg.bufsize) {
        char c = s->rx[i++];
        if (c == '\n' || c == '\r') {
            int before = s->rx_len;
            line_done(s);
            if (s->rx_len != before) { /* a line error emptied the buffer */
                i = 0;
                break;
            }
            continue;
        }
        if (s->line_eol)
            continue;
        if (c == ';') {
            s->line_eol = true;
            continue;
        }
        s->line[s->line_len++] = c;
        if (s->line_len >= MAX_CMD_SIZE - 1)
            s->line_eol = true;
    }
    memmove(s->rx, s->rx + i, (size_t)(s->rx_len - i));
    s->rx_len -= i;
}
