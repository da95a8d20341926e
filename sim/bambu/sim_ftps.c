/*
 * sim_ftps.c - implicit FTPS with required TLS session reuse (sim_ftps.h).
 *
 * The command set is what Bambu clients send (BAMBU-LAN.md section 3,
 * OpenBambuAPI ftp.md): USER PASS TYPE PBSZ PROT PASV EPSV STOR SIZE DELE
 * CWD PWD SYST FEAT OPTS NOOP QUIT, and LIST (clients list the root to
 * check the connection and find files: "LIST", "LIST /", "LIST -a /"),
 * STRU F and MODE S, answered with vsFTPd's codes and texts.  LIST's data
 * connection follows the same rules as STOR's.  The
 * order of a transfer follows vsFTPd: the data connection's TCP is
 * accepted, "150" goes out, and only then does the data TLS handshake run
 * (clients such as curl start it after reading the 150); a handshake that
 * does not resume the control session's master secret gets "522 SSL
 * connection failed: session reuse required" (vsftpd's require_ssl_reuse,
 * on by default and what an X1 answers).
 *
 * Thread: one server thread, blocking sockets; the creator stops it by
 * setting `stop` and shutting the sockets down, which wakes every blocking
 * call.  The counters are guarded by `lock`.
 */
#include "sim_ftps.h"

#include <dirent.h>
#include <errno.h>
#include <fcntl.h>
#include <netinet/in.h>
#include <openssl/err.h>
#include <openssl/ssl.h>
#include <poll.h>
#include <pthread.h>
#include <stdarg.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <time.h>
#include <unistd.h>

#include "../../src/base/log.h"
#include "../../src/base/mem.h"

#define LINE_MAX_FTP 512 /* a command line; longer ones are refused */
#define FTPS_CLIENTS 8   /* control connections served at once (vsftpd forks per client) */

struct sim_ftps {
    struct sim_ftps_config c;
    char *cert, *key, *dir, *user, *pass; /* copies of the config strings */
    SSL_CTX *ctx;
    int listen_fd;
    int port;
    pthread_t thread;
    bool started;
    atomic_bool stop;
    pthread_mutex_t lock; /* guards stats and the live fds below */
    struct sim_ftps_stats stats;
    struct client {
        pthread_t thread;
        bool used, running;
        int live_fd[3]; /* control, pasv listener, data: shut down on stop */
    } clients[FTPS_CLIENTS];
};

struct session {
    struct sim_ftps *f;
    struct client *cl;
    int fd;
    SSL *ssl;
    char in[LINE_MAX_FTP * 2];
    size_t in_len;
    bool user_ok, logged_in, prot_p, pbsz;
    int pasv_fd;
    bool pasv_answered; /* pasv_early: the next PASV was answered already */
};

static void
set_live(struct session *s, int slot, int fd)
{
    pthread_mutex_lock(&s->f->lock);
    s->cl->live_fd[slot] = fd;
    pthread_mutex_unlock(&s->f->lock);
}

static void
count(struct sim_ftps *f, uint64_t *field)
{
    pthread_mutex_lock(&f->lock);
    (*field)++;
    pthread_mutex_unlock(&f->lock);
}

static int reply(struct session *s, const char *fmt, ...) __attribute__((format(printf, 2, 3)));

static int
reply(struct session *s, const char *fmt, ...)
{
    char line[600];
    va_list ap;
    va_start(ap, fmt);
    int n = vsnprintf(line, sizeof(line) - 2, fmt, ap);
    va_end(ap);
    if (n < 0)
        return -1;
    if ((size_t)n > sizeof(line) - 3)
        n = (int)sizeof(line) - 3;
    line[n++] = '\r';
    line[n++] = '\n';
    if (s->f->c.reply_delay_ms > 0) /* this client's own thread: sleeping blocks no one else */
        poll(NULL, 0, s->f->c.reply_delay_ms);
    return SSL_write(s->ssl, line, n) == n ? 0 : -1;
}

/* Next command line (CRLF stripped) into out; -1 at end or error. */
static int
read_line(struct session *s, char *out, size_t n)
{
    for (;;) {
        char *nl = memchr(s->in, '\n', s->in_len);
        if (nl) {
            size_t len = (size_t)(nl - s->in);
            size_t take = len;
            if (take && s->in[take - 1] == '\r')
                take--;
            if (take >= n)
                take = n - 1;
            memcpy(out, s->in, take);
            out[take] = '\0';
            memmove(s->in, nl + 1, s->in_len - len - 1);
            s->in_len -= len + 1;
            return 0;
        }
        if (s->in_len >= sizeof(s->in) - 1)
            return -1; /* a line longer than any command */
        int r = SSL_read(s->ssl, s->in + s->in_len, (int)(sizeof(s->in) - 1 - s->in_len));
        if (r <= 0)
            return -1;
        s->in_len += (size_t)r;
    }
}

static void
close_pasv(struct session *s)
{
    if (s->pasv_fd >= 0) {
        set_live(s, 1, -1);
        close(s->pasv_fd);
        s->pasv_fd = -1;
    }
}

static int
open_pasv(struct session *s, bool epsv)
{
    close_pasv(s);
    int fd = socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
    struct sockaddr_in a = { .sin_family = AF_INET, .sin_addr.s_addr = htonl(INADDR_LOOPBACK) };
    socklen_t al = sizeof(a);
    if (fd < 0 || bind(fd, (struct sockaddr *)&a, sizeof(a)) < 0 || listen(fd, 1) < 0 ||
        getsockname(fd, (struct sockaddr *)&a, &al) < 0) {
        if (fd >= 0)
            close(fd);
        return reply(s, "425 Can't open passive connection.");
    }
    s->pasv_fd = fd;
    set_live(s, 1, fd);
    int p = ntohs(a.sin_port);
    if (epsv)
        return reply(s, "229 Entering Extended Passive Mode (|||%d|)", p);
    return reply(s, "227 Entering Passive Mode (127,0,0,1,%d,%d).", p >> 8, p & 255);
}

/* Same master secret: the data handshake resumed the control session. */
static bool
resumed_control(SSL *ctrl, SSL *data)
{
    if (!SSL_session_reused(data))
        return false;
    unsigned char a[SSL_MAX_MASTER_KEY_LENGTH], b[SSL_MAX_MASTER_KEY_LENGTH];
    size_t na = SSL_SESSION_get_master_key(SSL_get_session(ctrl), a, sizeof(a));
    size_t nb = SSL_SESSION_get_master_key(SSL_get_session(data), b, sizeof(b));
    return na && na == nb && memcmp(a, b, na) == 0;
}

/* Safe storage name: no directories, no dot files, printable ASCII. */
static bool
name_ok(const char *n)
{
    if (*n == '/')
        n++;
    if (!*n || *n == '.' || strlen(n) > 200)
        return false;
    for (const char *p = n; *p; p++)
        if (*p == '/' || *p < 0x21 || *p > 0x7e)
            return false;
    return true;
}

/* Close a data connection from open_data(). */
static void
close_data(struct session *s, SSL *d, int dfd)
{
    if (d)
        SSL_free(d);
    set_live(s, 2, -1);
    close(dfd);
}

/*
 * The data connection of a transfer, as vsFTPd makes it: accept the PASV
 * connection, send prelim (the 150), then the TLS handshake, which must
 * resume the control session.  1 with *d and *dfd ready (close_data()
 * frees them); else the failure was answered: the command's result (0, or
 * -1 to end the session).
 */
static int
open_data(struct session *s, const char *prelim, SSL **d, int *dfd)
{
    struct sim_ftps *f = s->f;
    struct pollfd pfd = { .fd = s->pasv_fd, .events = POLLIN };
    if (poll(&pfd, 1, 10000) <= 0) {
        close_pasv(s);
        return reply(s, "425 Failed to establish connection.");
    }
    *dfd = accept4(s->pasv_fd, NULL, NULL, SOCK_CLOEXEC);
    close_pasv(s);
    if (*dfd < 0)
        return reply(s, "425 Failed to establish connection.");
    set_live(s, 2, *dfd);
    int rc = -1;
    *d = NULL;
    if (reply(s, "%s", prelim) < 0)
        goto fail;
    *d = SSL_new(f->ctx);
    if (!*d || SSL_set_fd(*d, *dfd) != 1 || SSL_accept(*d) != 1) {
        char e[160];
        ERR_error_string_n(ERR_get_error(), e, sizeof(e));
        log_info("sim-ftps", "data connection: TLS handshake failed: %s", e);
        rc = reply(s, "522 SSL connection failed; session reuse required?");
        goto fail;
    }
    if (!f->c.no_reuse_check && !resumed_control(s->ssl, *d)) {
        log_info("sim-ftps", "data connection did not resume the control session (resumed: %d)",
                 SSL_session_reused(*d));
        count(f, &f->stats.refused_reuse);
        rc = reply(s, "522 SSL connection failed: session reuse required");
        goto fail;
    }
    return 1;
fail:
    close_data(s, *d, *dfd);
    return rc;
}

/* One ls -l line as vsFTPd writes it (numeric owner, the date of the last change). */
static int
list_line(char *out, size_t n, const char *name, const struct stat *st)
{
    struct tm tm;
    char when[32];
    time_t mt = st->st_mtime;
    gmtime_r(&mt, &tm);
    bool recent = time(NULL) - mt < 182 * 24 * 3600;
    strftime(when, sizeof(when), recent ? "%b %d %H:%M" : "%b %d  %Y", &tm);
    return snprintf(out, n, "%s    1 0        0        %8lld %s %s\r\n",
                    S_ISDIR(st->st_mode) ? "drwxr-xr-x" : "-rw-r--r--", (long long)st->st_size,
                    when, name);
}

/* The listing of the printer's storage (flat: its root) into d; dot files only with -a. */
static void
send_listing(struct sim_ftps *f, SSL *d, const char *path, bool all)
{
    char line[512], full[1024];
    struct stat st;
    const char *name = *path == '/' ? path + 1 : path;
    if (*name) { /* LIST of one file: its line */
        snprintf(full, sizeof(full), "%s/%s", f->dir, name);
        if (stat(full, &st) == 0 && S_ISREG(st.st_mode)) {
            int k = list_line(line, sizeof(line), name, &st);
            SSL_write(d, line, k);
        }
        return;
    }
    DIR *dir = opendir(f->dir);
    struct dirent *e;
    while (dir && (e = readdir(dir)) != NULL) {
        if (strcmp(e->d_name, ".") == 0 || strcmp(e->d_name, "..") == 0 ||
            (e->d_name[0] == '.' && !all))
            continue;
        snprintf(full, sizeof(full), "%s/%s", f->dir, e->d_name);
        if (stat(full, &st) < 0)
            continue;
        int k = list_line(line, sizeof(line), e->d_name, &st);
        if (k > 0 && (size_t)k < sizeof(line) && SSL_write(d, line, k) != k)
            break;
    }
    if (dir)
        closedir(dir);
}

/*
 * LIST [-options] [path]: the root (path empty or "/") or one file, over a
 * data connection with the same rules as STOR.  A path that is neither
 * gets vsFTPd's empty listing and "226 Transfer done (but failed to open
 * directory).".
 */
static int
do_list(struct session *s, char *arg)
{
    struct sim_ftps *f = s->f;
    bool all = false;
    while (*arg == '-') { /* ls options: vsFTPd honours a (dot files), ignores the rest */
        for (; *arg && *arg != ' '; arg++)
            all |= *arg == 'a';
        while (*arg == ' ')
            arg++;
    }
    if (!s->prot_p)
        return reply(s, "522 Data connections must be encrypted.");
    if (s->pasv_fd < 0)
        return reply(s, "425 Use PORT or PASV first.");
    bool root = !*arg || strcmp(arg, "/") == 0;
    char full[1024];
    struct stat st;
    snprintf(full, sizeof(full), "%s/%s", f->dir, *arg == '/' ? arg + 1 : arg);
    bool found = root || (name_ok(arg) && stat(full, &st) == 0 && S_ISREG(st.st_mode));
    int dfd;
    SSL *d;
    int rc = open_data(s, "150 Here comes the directory listing.", &d, &dfd);
    if (rc != 1)
        return rc;
    if (found)
        send_listing(f, d, root ? "" : arg, all);
    SSL_shutdown(d);
    close_data(s, d, dfd);
    return reply(s, found ? "226 Directory send OK."
                          : "226 Transfer done (but failed to open directory).");
}

static int
do_stor(struct session *s, const char *arg)
{
    struct sim_ftps *f = s->f;
    if (!s->prot_p)
        return reply(s, "522 Data connections must be encrypted.");
    if (s->pasv_fd < 0)
        return reply(s, "425 Use PORT or PASV first.");
    if (!name_ok(arg)) {
        close_pasv(s);
        return reply(s, "553 Could not create file.");
    }
    if (f->c.storage_full) {
        close_pasv(s);
        return reply(s, "552 Requested file action aborted. Exceeded storage allocation.");
    }
    const char *name = *arg == '/' ? arg + 1 : arg;
    int dfd;
    SSL *d;
    int rc = open_data(s, "150 Ok to send data.", &d, &dfd);
    if (rc != 1)
        return rc;
    rc = 0;
    FILE *out = NULL;
    char part[1024], final[1024];
    snprintf(part, sizeof(part), "%s/%s.part", f->dir, name);
    snprintf(final, sizeof(final), "%s/%s", f->dir, name);
    out = fopen(part, "wb");
    if (!out) {
        rc = reply(s, "553 Could not create file.");
        goto done;
    }
    char buf[16384];
    int64_t got = 0;
    bool clean = false;
    for (;;) {
        int r = SSL_read(d, buf, sizeof(buf));
        if (r <= 0) {
            int e = SSL_get_error(d, r);
            /* close_notify, or a bare TCP close after the bytes (clients that skip the
               unwrap, BAMBU-LAN.md section 3): both end a transfer. */
            clean = e == SSL_ERROR_ZERO_RETURN || e == SSL_ERROR_SYSCALL;
            break;
        }
        if (f->c.drop_after > 0 && got + r > f->c.drop_after) {
            fwrite(buf, 1, (size_t)(f->c.drop_after - got), out);
            f->c.drop_after = 0; /* once: the next upload goes through (this thread's field) */
            clean = false;
            shutdown(dfd, SHUT_RDWR); /* the TLS stream dies mid-upload */
            break;
        }
        if (fwrite(buf, 1, (size_t)r, out) != (size_t)r) {
            clean = false;
            break;
        }
        got += r;
        if (f->c.read_delay_ms > 0) /* this client's own thread */
            poll(NULL, 0, f->c.read_delay_ms);
    }
    if (fclose(out) != 0)
        clean = false;
    out = NULL;
    if (!clean || atomic_load(&f->stop)) {
        unlink(part);
        rc = reply(s, "426 Failure writing network stream.");
        goto done;
    }
    if (rename(part, final) != 0) {
        unlink(part);
        rc = reply(s, "451 Failure writing to local file.");
        goto done;
    }
    count(f, &f->stats.uploads);
    SSL_shutdown(d);
    rc = reply(s, "226 Transfer complete.");
done:
    if (out)
        fclose(out);
    close_data(s, d, dfd);
    return rc;
}

/* One command; -1 ends the session. */
static int
command(struct session *s, char *line)
{
    char *arg = strchr(line, ' ');
    if (arg)
        *arg++ = '\0';
    else
        arg = line + strlen(line);
    const char *cmd = line;
    struct sim_ftps *f = s->f;
    if (strcasecmp(cmd, "QUIT") == 0) {
        reply(s, "221 Goodbye.");
        return -1;
    }
    if (strcasecmp(cmd, "USER") == 0) {
        s->user_ok = strcmp(arg, f->user) == 0;
        s->logged_in = false;
        return reply(s, "331 Please specify the password.");
    }
    if (strcasecmp(cmd, "PASS") == 0) {
        if (!s->user_ok || strcmp(arg, f->pass) != 0) {
            count(f, &f->stats.bad_logins);
            return reply(s, "530 Login incorrect.");
        }
        s->logged_in = true;
        count(f, &f->stats.logins);
        return reply(s, "230 Login successful.");
    }
    if (strcasecmp(cmd, "FEAT") == 0)
        return reply(s, "211-Features:\r\n EPSV\r\n PASV\r\n PBSZ\r\n PROT\r\n SIZE\r\n "
                        "UTF8\r\n211 End");
    if (strcasecmp(cmd, "SYST") == 0)
        return reply(s, "215 UNIX Type: L8");
    if (strcasecmp(cmd, "NOOP") == 0)
        return reply(s, "200 NOOP ok.");
    if (strcasecmp(cmd, "PBSZ") == 0) {
        s->pbsz = true;
        return reply(s, "200 PBSZ set to 0.");
    }
    if (strcasecmp(cmd, "PROT") == 0) {
        if (strcasecmp(arg, "P") == 0) {
            s->prot_p = true;
            return reply(s, "200 PROT now Private.");
        }
        return reply(s, "536 PROT %s not supported; data connections must be private.", arg);
    }
    if (!s->logged_in)
        return reply(s, "530 Please login with USER and PASS.");
    if (strcasecmp(cmd, "TYPE") == 0)
        return reply(s, "200 Switching to %s mode.", *arg == 'A' ? "ASCII" : "Binary");
    if (strcasecmp(cmd, "OPTS") == 0)
        return reply(s, "200 Always in UTF8 mode.");
    if (strcasecmp(cmd, "PWD") == 0) {
        if (reply(s, "257 \"/\" is the current directory") < 0)
            return -1;
        if (!f->c.pasv_early)
            return 0;
        s->pasv_answered = true;
        return open_pasv(s, false);
    }
    if (strcasecmp(cmd, "CWD") == 0)
        return reply(s, "250 Directory successfully changed.");
    if (strcasecmp(cmd, "PASV") == 0) {
        if (s->pasv_answered && s->pasv_fd >= 0) {
            s->pasv_answered = false;
            return 0; /* pasv_early: its 227 went out with the PWD reply */
        }
        return open_pasv(s, false);
    }
    if (strcasecmp(cmd, "EPSV") == 0)
        return open_pasv(s, true);
    if (strcasecmp(cmd, "STOR") == 0)
        return do_stor(s, arg);
    if (strcasecmp(cmd, "LIST") == 0)
        return do_list(s, arg);
    if (strcasecmp(cmd, "STRU") == 0)
        return reply(s, strcasecmp(arg, "F") == 0 ? "200 Structure set to F."
                                                  : "504 Bad STRU command.");
    if (strcasecmp(cmd, "MODE") == 0)
        return reply(s, strcasecmp(arg, "S") == 0 ? "200 Mode set to S." : "504 Bad MODE command.");
    if (strcasecmp(cmd, "SIZE") == 0 || strcasecmp(cmd, "DELE") == 0) {
        char path[1024];
        if (!name_ok(arg))
            return reply(s, "550 Could not get file size.");
        snprintf(path, sizeof(path), "%s/%s", f->dir, *arg == '/' ? arg + 1 : arg);
        FILE *fp = fopen(path, "rb");
        if (!fp)
            return reply(s, "550 Could not get file size.");
        fseek(fp, 0, SEEK_END);
        long sz = ftell(fp);
        fclose(fp);
        if (strcasecmp(cmd, "DELE") == 0)
            return reply(s, unlink(path) == 0 ? "250 Delete operation successful."
                                              : "550 Delete operation failed.");
        return reply(s, "213 %ld", sz);
    }
    return reply(s, "502 Command not implemented.");
}

struct client_arg {
    struct sim_ftps *f;
    struct client *cl;
    int fd;
};

static void *
serve_client(void *arg)
{
    struct client_arg a = *(struct client_arg *)arg;
    free(arg);
    struct session s = { .f = a.f, .cl = a.cl, .fd = a.fd, .pasv_fd = -1 };
    s.ssl = SSL_new(a.f->ctx);
    log_debug("sim-ftps", "client %d: accepted", a.fd);
    if (!s.ssl || SSL_set_fd(s.ssl, a.fd) != 1 || SSL_accept(s.ssl) != 1) {
        log_debug("sim-ftps", "client %d: TLS accept failed", a.fd);
        goto out; /* not TLS from the first byte: implicit FTPS drops it */
    }
    if (reply(&s, "220 (vsFTPd 3.0.3)") < 0)
        goto out;
    char line[LINE_MAX_FTP];
    while (!atomic_load(&a.f->stop) && read_line(&s, line, sizeof(line)) == 0) {
        log_debug("sim-ftps", "client %d: %.20s", a.fd, line);
        if (command(&s, line) < 0)
            break;
    }
    log_debug("sim-ftps", "client %d: done", a.fd);
    SSL_shutdown(s.ssl);
out:
    close_pasv(&s);
    SSL_free(s.ssl);
    ERR_clear_error();
    set_live(&s, 0, -1);
    close(a.fd);
    pthread_mutex_lock(&a.f->lock);
    a.cl->running = false;
    pthread_mutex_unlock(&a.f->lock);
    return NULL;
}

/* A free client slot (its old thread joined), or NULL when all are busy. */
static struct client *
free_slot(struct sim_ftps *f)
{
    for (int i = 0; i < FTPS_CLIENTS; i++) {
        struct client *c = &f->clients[i];
        pthread_mutex_lock(&f->lock);
        bool busy = c->running;
        pthread_mutex_unlock(&f->lock);
        if (busy)
            continue;
        if (c->used)
            pthread_join(c->thread, NULL);
        c->used = false;
        return c;
    }
    return NULL;
}

static void *
server_main(void *arg)
{
    struct sim_ftps *f = arg;
    while (!atomic_load(&f->stop)) {
        int fd = accept4(f->listen_fd, NULL, NULL, SOCK_CLOEXEC);
        if (fd < 0) {
            if (errno == EINTR || errno == ECONNABORTED)
                continue;
            break; /* shut down */
        }
        struct client *cl = free_slot(f);
        struct client_arg *a = cl ? malloc(sizeof(*a)) : NULL;
        if (!a) {
            close(fd); /* as vsftpd at max_clients */
            continue;
        }
        struct timeval tv = { .tv_sec = 30 };
        setsockopt(fd, SOL_SOCKET, SO_RCVTIMEO, &tv, sizeof(tv));
        *a = (struct client_arg){ f, cl, fd };
        pthread_mutex_lock(&f->lock);
        cl->live_fd[0] = fd;
        cl->live_fd[1] = cl->live_fd[2] = -1;
        cl->running = true;
        pthread_mutex_unlock(&f->lock);
        if (pthread_create(&cl->thread, NULL, serve_client, a) != 0) {
            cl->running = false;
            close(fd);
            free(a);
            continue;
        }
        cl->used = true;
    }
    return NULL;
}

struct sim_ftps *
sim_ftps_new(const struct sim_ftps_config *c, struct sf_err *err)
{
    struct sim_ftps *f = mem_calloc(1, sizeof(*f));
    if (!f) {
        sf_err_set(err, SF_ENOMEM, "ftps: out of memory");
        return NULL;
    }
    f->c = *c;
    f->listen_fd = -1;
    pthread_mutex_init(&f->lock, NULL);
    f->cert = mem_strdup(c->cert_file ? c->cert_file : "");
    f->key = mem_strdup(c->key_file ? c->key_file : "");
    f->dir = mem_strdup(c->storage_dir ? c->storage_dir : ".");
    f->user = mem_strdup(c->user ? c->user : "bblp");
    f->pass = mem_strdup(c->password ? c->password : "");
    if (!f->cert || !f->key || !f->dir || !f->user || !f->pass) {
        sf_err_set(err, SF_ENOMEM, "ftps: out of memory");
        goto fail;
    }
    f->ctx = SSL_CTX_new(TLS_server_method());
    if (!f->ctx) {
        sf_err_set(err, SF_ENOMEM, "ftps: no TLS context");
        goto fail;
    }
    /* An X1 speaks TLS 1.2 only; 1.3 also breaks vsftpd's session reuse. */
    SSL_CTX_set_min_proto_version(f->ctx, TLS1_2_VERSION);
    SSL_CTX_set_max_proto_version(f->ctx, TLS1_2_VERSION);
    SSL_CTX_set_session_cache_mode(f->ctx, SSL_SESS_CACHE_SERVER);
    SSL_CTX_set_session_id_context(f->ctx, (const unsigned char *)"sfsim-ftps", 10);
    if (SSL_CTX_use_certificate_chain_file(f->ctx, f->cert) != 1 ||
        SSL_CTX_use_PrivateKey_file(f->ctx, f->key, SSL_FILETYPE_PEM) != 1) {
        char e[120];
        ERR_error_string_n(ERR_get_error(), e, sizeof(e));
        sf_err_set(err, SF_EINVAL, "ftps: certificate '%s' / key '%s': %s", f->cert, f->key, e);
        goto fail;
    }
    f->listen_fd = socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
    int one = 1;
    setsockopt(f->listen_fd, SOL_SOCKET, SO_REUSEADDR, &one, sizeof(one));
    struct sockaddr_in a = { .sin_family = AF_INET,
                             .sin_port = htons((uint16_t)c->port),
                             .sin_addr.s_addr = htonl(INADDR_LOOPBACK) };
    socklen_t al = sizeof(a);
    if (f->listen_fd < 0 || bind(f->listen_fd, (struct sockaddr *)&a, sizeof(a)) < 0 ||
        listen(f->listen_fd, 4) < 0 || getsockname(f->listen_fd, (struct sockaddr *)&a, &al) < 0) {
        sf_err_sys(err, "ftps: cannot listen on 127.0.0.1:%d", c->port);
        goto fail;
    }
    f->port = ntohs(a.sin_port);
    if (pthread_create(&f->thread, NULL, server_main, f) != 0) {
        sf_err_set(err, SF_EIO, "ftps: cannot start the server thread");
        goto fail;
    }
    f->started = true;
    return f;
fail:
    sim_ftps_free(f);
    return NULL;
}

int
sim_ftps_port(const struct sim_ftps *f)
{
    return f->port;
}

void
sim_ftps_stats(struct sim_ftps *f, struct sim_ftps_stats *out)
{
    pthread_mutex_lock(&f->lock);
    *out = f->stats;
    pthread_mutex_unlock(&f->lock);
}

void
sim_ftps_free(struct sim_ftps *f)
{
    if (!f)
        return;
    atomic_store(&f->stop, true);
    if (f->listen_fd >= 0)
        shutdown(f->listen_fd, SHUT_RDWR);
    if (f->started)
        pthread_join(f->thread, NULL); /* no new clients after this */
    pthread_mutex_lock(&f->lock);
    for (int c = 0; c < FTPS_CLIENTS; c++)
        for (int i = 0; i < 3; i++)
            if (f->clients[c].running && f->clients[c].live_fd[i] >= 0)
                shutdown(f->clients[c].live_fd[i], SHUT_RDWR);
    pthread_mutex_unlock(&f->lock);
    for (int c = 0; c < FTPS_CLIENTS; c++)
        if (f->clients[c].used)
            pthread_join(f->clients[c].thread, NULL);
    if (f->listen_fd >= 0)
        close(f->listen_fd);
    SSL_CTX_free(f->ctx);
    pthread_mutex_destroy(&f->lock);
    free(f->cert);
    free(f->key);
    free(f->dir);
    free(f->user);
    free(f->pass);
    free(f);
}
