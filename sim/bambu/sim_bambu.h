/*
 * sim_bambu.h - a simulated Bambu Lab printer in LAN mode, over the same
 * real components a printer uses: TLS, an MQTT broker, an FTPS server.
 *
 * The printer side of ../shared/BAMBU-LAN.md: it connects to a real MQTT
 * broker (Debian's mosquitto, started by the test with a TLS listener that
 * presents the printer's certificate, CN = serial, as a printer's built-in
 * broker does) as the printer, publishes device/SERIAL/report (X1 style:
 * the full print object each time; P1 style: only the fields that changed,
 * the full object on pushall) and answers device/SERIAL/request: pushall,
 * get_version, project_file, pause, resume, stop, gcode_line.  It serves
 * implicit FTPS (sim_ftps.h) with TLS session reuse enforced.  Clients
 * reach the broker through the printer's own MQTT port (sim_bambu_relay.h),
 * so that the printer's MQTT going away cuts them as on a printer.  A
 * project_file opens the uploaded .gcode.3mf, checks the package MD5 (when
 * the command gives one) and the plate_N.gcode.md5 sidecar, and runs the
 * G-code on the simulated machine, whose executed-command log is the
 * Marlin simulator's format.
 *
 * Faults (--fault, several allowed):
 *   unsigned          2025 firmware without Developer Mode: control commands are refused
 *                     (result "failed", reason "mqtt message verify failed", HMS
 *                     0500-0500-0001-0007); pushall and reports keep working
 *   storage-full      FTPS STOR answers 552
 *   ftps-drop=BYTES   the first upload's data connection dies after BYTES (once)
 *   no-reuse-check    accept data connections that do not resume the TLS session
 *   pasv-early        the FTPS server's 227 arrives with the reply before PASV (sim_ftps.h)
 *   ftps-slow=MS      every FTPS control reply comes MS late (a busy printer), and an
 *                     upload's data is taken in 16 kB per MS/20 ms (its SD card)
 *   hms=HEX16@PCT     the print fails at PCT percent with that HMS code
 *   stop-at=PCT       someone presses stop on the printer's screen at PCT percent
 *   mqtt-drop=N       after N reports sent while a job prints, the printer's MQTT service
 *                     goes away for 0.5 s: its own link, and every client's through its port
 *                     (sim_bambu_mqtt_port), which refuses until it is back; once
 *   ftps-wrong-cert   FTPS presents another printer's certificate (CN 01S00OTHER00000, the
 *                     same CA: DIR/other-printer.pem), as an address that leads elsewhere
 *
 * Thread: loop thread (the FTPS server has its own thread, see sim_ftps.h).
 * Owns its MQTT client, FTPS server, storage directory (when it made it),
 * machine and log.
 */
#ifndef SF_SIM_BAMBU_SIM_BAMBU_H
#define SF_SIM_BAMBU_SIM_BAMBU_H

#include <stdbool.h>
#include <stdint.h>

#include "../../src/base/err.h"
#include "../../src/base/loop.h"

struct sim_bambu_faults {
    bool unsigned_refused; /* refuse control commands (no Developer Mode) */
    bool storage_full;     /* FTPS 552 */
    int64_t ftps_drop;     /* > 0: the first upload dies after this many bytes */
    bool no_reuse_check;   /* lenient FTPS */
    bool pasv_early;       /* FTPS answers PASV before it is asked */
    int ftps_slow_ms;      /* FTPS control replies this late */
    char hms[17];          /* HMS code (16 hex digits) to fail with, "" none */
    double hms_at;         /* ... at this percent */
    double stop_at;        /* > 0: stopped at the screen at this percent */
    long mqtt_drop;        /* > 0: drop MQTT after this many reports sent while printing */
    bool ftps_wrong_cert;  /* FTPS shows other-printer.pem */
};

struct sim_bambu_config {
    const char *serial;      /* device id, e.g. 01S00C123456789 */
    const char *access_code; /* LAN access code (MQTT and FTPS password) */
    const char *mqtt_host;   /* broker address (IP); NULL: 127.0.0.1 */
    int mqtt_port;           /* broker TLS port */
    int ftps_port;           /* 0: any free port */
    const char *ca_dir;      /* ca.pem, printer.pem, printer.key */
    bool p1;                 /* P1-style delta reports (else X1 full objects) */
    double speed;            /* simulated machine time factor; 0: 1 */
    const char *log_path;    /* executed commands, or NULL */
    const char *storage_dir; /* uploads; NULL: a temporary directory, removed at free */
    int report_ms;           /* report period while printing; 0: 1000 */
    struct sim_bambu_faults faults;
};

struct sim_bambu_stats {
    uint64_t reports;       /* report messages published */
    uint64_t requests;      /* request messages received */
    uint64_t refused;       /* control commands refused (unsigned) */
    uint64_t jobs_started;  /* project_file accepted */
    uint64_t jobs_finished; /* gcode_state reached FINISH */
    uint64_t mqtt_connects; /* broker connections made */
    uint64_t uploads;       /* complete FTPS uploads */
    uint64_t refused_reuse; /* FTPS data connections refused for no session reuse */
    uint64_t executed;      /* commands the machine executed */
    uint64_t pushalls;      /* pushall requests received */
    uint64_t mqtt_drops;    /* times the mqtt-drop fault took MQTT away */
    uint64_t mqtt_clients;  /* client connections through the printer's MQTT port */
    int64_t pushall_gap_ms; /* shortest time between two of them (loop clock), -1 until two */
    char gcode_state[16];   /* current gcode_state */
};

void sim_bambu_config_init(struct sim_bambu_config *c);
/* Apply one --fault spec; SF_EINVAL naming it when bad. */
int sim_bambu_fault_parse(struct sim_bambu_faults *f, const char *spec, struct sf_err *err);

/* Start: FTPS listening, MQTT connecting.  NULL with err set. */
struct sim_bambu *sim_bambu_new(struct loop *l, const struct sim_bambu_config *c,
                                struct sf_err *err);
int sim_bambu_ftps_port(const struct sim_bambu *s);
/* The printer's MQTT port: the broker, as a printer's clients reach it (TLS, CN = serial). */
int sim_bambu_mqtt_port(const struct sim_bambu *s);
void sim_bambu_stats(const struct sim_bambu *s, struct sim_bambu_stats *out);
/* Stop everything and free.  NULL is fine. */
void sim_bambu_free(struct sim_bambu *s);

/*
 * `slimfarm-sim bambu ...` (argv[1] is "bambu"): prints "ftps://127.0.0.1:PORT"
 * on its first line, "mqtts://127.0.0.1:PORT" (the printer's MQTT port) on its second, serves until
 * SIGINT/SIGTERM, then prints one "stats:" line on stderr.  Returns the exit status.
 */
int sim_bambu_main(int argc, char **argv);

#endif
