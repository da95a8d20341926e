/*
 * simlog.h - reading a simulated printer's executed-command log beside the
 * G-code file that was streamed to it: the judge of the Marlin tests and
 * of `make soak` (tests/unit/test_marlin.c, tests/bench/bench_soak.c).
 *
 * Pure reading; thread-safe.
 */
#ifndef SF_SIM_SIMLOG_H
#define SF_SIM_SIMLOG_H

#include <stdbool.h>
#include <stddef.h>

/*
 * The commands of a G-code file or of a printer's log, one malloc'd string
 * each (comments, blank lines and line numbers stripped), *n of them; NULL
 * with *n = 0 when the file cannot be read.  simlog_free() releases them.
 */
char **simlog_commands(const char *path, size_t *n);
void simlog_free(char **v, size_t n);

/*
 * A line the driver adds itself, not the job's: the handshake (M110,
 * M115), temperature polls and probes (M105; one garbled on the wire that
 * still runs as M105, "M105g", is one), auto-report (M155), renumbering
 * (M110 N<m>) and the final M400.
 */
bool simlog_host_line(const char *cmd);

#endif
