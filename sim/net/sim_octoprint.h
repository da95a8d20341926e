/*
 * sim_octoprint.h - `slimfarm-sim octoprint`: a simulated OctoPrint server
 * (its REST API as docs.octoprint.org documents it for 1.10/1.11) in front
 * of a sim_netprinter.
 *
 * Endpoints: GET /api/version, /api/server, /api/connection, /api/job,
 * /api/printer, /api/files/local/NAME; POST /api/files/local (multipart
 * upload: file, select, print), /api/files/local/NAME (select [+print]),
 * /api/job (start, cancel, restart, pause with action pause/resume/toggle),
 * /api/printer/command, /api/connection ("connect" leaves Error, as
 * reconnecting OctoPrint to its printer does); DELETE /api/files/local/NAME.  A missing or wrong
 * X-Api-Key is a 403, as OctoPrint answers.  Conflicts are 409 with
 * {"error": reason}.
 *
 * Faults (--fault), besides sim_http's and the firmware's:
 *   error-at=N       the printer fails ("Error") after N lines of a job, once
 *   cancel-at=N      every print is cancelled at the printer after N job lines
 *   busy=1           the printer reports itself busy: uploads do not start,
 *                    select+print and job start answer 409
 *
 * Thread: the loop thread.
 */
#ifndef SF_SIM_NET_SIM_OCTOPRINT_H
#define SF_SIM_NET_SIM_OCTOPRINT_H

/* `slimfarm-sim octoprint ...` (argv[1] is "octoprint"); the process exit status. */
int sim_octoprint_main(int argc, char **argv);

#endif
