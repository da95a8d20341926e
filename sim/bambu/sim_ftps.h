/*
 * sim_ftps.h - a small implicit-FTPS server with the manners of a Bambu
 * printer's vsFTPd, for the Bambu simulator.
 *
 * What it enforces, as an X1 does (../shared/BAMBU-LAN.md section 3): TLS
 * from the first byte (implicit, port 990 on a printer), TLS 1.2 at most,
 * login bblp / access code, PBSZ 0 + PROT P before any transfer, and the
 * data connection's TLS session must resume the control connection's
 * ("522 SSL connection failed: session reuse required" otherwise).  Uploads
 * (STOR) land in the storage directory, written to NAME.part and renamed
 * when complete, so a reader never sees half a file.
 *
 * Why our own and not Debian's vsftpd: vsftpd needs a system user, PAM and
 * root for its chroot, and a test cannot make it refuse storage or drop a
 * transfer half-way; this one is 500 lines of OpenSSL and does exactly the
 * protocol subset the printers use.
 *
 * Thread: it serves on a thread of its own with blocking I/O, one client at
 * a time (a printer takes one FTP client too); the only state shared with
 * the creator is the storage directory and the counters, read with
 * sim_ftps_stats.  sim_ftps_free stops the thread and closes everything.
 */
#ifndef SF_SIM_BAMBU_SIM_FTPS_H
#define SF_SIM_BAMBU_SIM_FTPS_H

#include <stdbool.h>
#include <stdint.h>

#include "../../src/base/err.h"

struct sim_ftps_config {
    int port;                /* 0: any free loopback port */
    const char *cert_file;   /* PEM certificate the server presents (CN = serial) */
    const char *key_file;    /* its private key */
    const char *storage_dir; /* where uploads go (exists) */
    const char *user;        /* "bblp" */
    const char *password;    /* the access code */
    bool storage_full;       /* STOR answers 552 (storage exceeded) */
    int64_t drop_after;      /* > 0: the first upload's data connection drops after this many
                                bytes (once; the uploads after it go through) */
    bool no_reuse_check;     /* accept data connections that do not resume (lenient firmware) */
    int reply_delay_ms;      /* > 0: every control reply waits this long (a busy printer) */
    int read_delay_ms;       /* > 0: each 16 kB block of an upload is taken in this late (its
                                SD card writing slowly) */
    bool pasv_early;         /* answer PASV before it is asked: the 227 rides on the PWD reply
                                (and the PASV that follows gets none), as a client sees a server
                                that answers faster than it looks; a client must then start the
                                data connection from what it already read */
};

struct sim_ftps_stats {
    uint64_t logins;        /* successful logins */
    uint64_t uploads;       /* complete STORs */
    uint64_t refused_reuse; /* data connections refused for not resuming the session */
    uint64_t bad_logins;    /* wrong user or password */
};

struct sim_ftps;

/* Listen and start serving.  NULL with err set. */
struct sim_ftps *sim_ftps_new(const struct sim_ftps_config *c, struct sf_err *err);
/* The port it listens on. */
int sim_ftps_port(const struct sim_ftps *f);
void sim_ftps_stats(struct sim_ftps *f, struct sim_ftps_stats *out);
/* Stop the thread, close every connection, free.  NULL is fine. */
void sim_ftps_free(struct sim_ftps *f);

#endif
