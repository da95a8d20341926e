/*
 * tcpproxy.c - a loopback TCP proxy for partition tests: forwards
 * 127.0.0.1:LISTEN to 127.0.0.1:TARGET, and on command cuts every
 * connection through it, as a network that parts would.
 *
 *     tcpproxy TARGET_PORT [LISTEN_PORT]
 *
 * LISTEN_PORT 0 (the default) lets the kernel pick; the first line on
 * stdout is "port N".  Commands come one a line on stdin, each answered
 * "ok COMMAND" on stdout once it has taken effect (so a test knows the cut
 * is made before it goes on):
 *   drop       close every connection through it, and close each new one
 *              at once (a refused peer: the client fails fast)
 *   blackhole  close every connection, and hold each new one open without
 *              forwarding a byte (a silent network: the client's timeouts
 *              decide)
 *   freeze     keep every connection open but forward nothing either way, and
 *              hold each new one (a partition: neither end sees a close; the
 *              server's session waits as if its client were silent)
 *   heal       forward again (frozen connections go on where they stood)
 *   count      "ok count N": connections forwarded now
 * End of stdin ends it, so it never outlives the test that started it.
 *
 * One thread, one poll loop; sockets blocking, so a write waits for its
 * peer to read (fine for request-reply protocols on loopback; it is a test
 * tool, not a network element).
 */
#include <arpa/inet.h>
#include <errno.h>
#include <netinet/in.h>
#include <poll.h>
#include <signal.h>
#include <stdbool.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <unistd.h>

#define PAIRS_MAX 64 /* connections at once: a test opens a few */
#define HELD_MAX  64 /* blackholed connections held open */

enum mode { FORWARD, DROP, BLACKHOLE, FREEZE };

static int pairs[PAIRS_MAX][2]; /* client, server; -1 when free */
static int held[HELD_MAX];      /* blackholed clients; -1 when free */

static void
close_all(void)
{
    for (int i = 0; i < PAIRS_MAX; i++)
        for (int k = 0; k < 2; k++)
            if (pairs[i][k] >= 0) {
                close(pairs[i][k]);
                pairs[i][k] = -1;
            }
    for (int i = 0; i < HELD_MAX; i++)
        if (held[i] >= 0) {
            close(held[i]);
            held[i] = -1;
        }
}

/* A socket connected to 127.0.0.1:port, or -1. */
static int
dial(int port)
{
    int fd = socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
    struct sockaddr_in a = { .sin_family = AF_INET, .sin_port = htons((uint16_t)port) };
    a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    if (fd >= 0 && connect(fd, (struct sockaddr *)&a, sizeof(a)) != 0) {
        close(fd);
        return -1;
    }
    return fd;
}

/* Keep fd in the first free slot of set (n slots); close it if there is none. */
static void
keep(int *set, int n, int fd)
{
    for (int i = 0; i < n; i++)
        if (set[i] < 0) {
            set[i] = fd;
            return;
        }
    close(fd);
}

static void
take(int lfd, enum mode mode, int target)
{
    int c = accept4(lfd, NULL, NULL, SOCK_CLOEXEC);
    if (c < 0)
        return;
    if (mode == DROP) {
        close(c);
        return;
    }
    if (mode == BLACKHOLE || mode == FREEZE) {
        keep(held, HELD_MAX, c);
        return;
    }
    int s = dial(target);
    for (int i = 0; s >= 0 && i < PAIRS_MAX; i++)
        if (pairs[i][0] < 0) {
            pairs[i][0] = c;
            pairs[i][1] = s;
            return;
        }
    close(c);
    if (s >= 0)
        close(s);
}

/* Copy what from holds to to; false when either side is done (both then closed). */
static bool
pump(int from, int to)
{
    char buf[16384];
    ssize_t n = read(from, buf, sizeof(buf));
    if (n <= 0)
        return false;
    for (ssize_t off = 0; off < n;) {
        ssize_t w = write(to, buf + off, (size_t)(n - off));
        if (w <= 0)
            return false;
        off += w;
    }
    return true;
}

/* Run one command line; false on an unknown one. */
static bool
command(const char *line, enum mode *mode)
{
    int n = 0;
    if (strcmp(line, "drop") == 0 || strcmp(line, "blackhole") == 0) {
        close_all();
        *mode = line[0] == 'd' ? DROP : BLACKHOLE;
    } else if (strcmp(line, "freeze") == 0) {
        *mode = FREEZE;
    } else if (strcmp(line, "heal") == 0) {
        *mode = FORWARD;
    } else if (strcmp(line, "count") == 0) {
        for (int i = 0; i < PAIRS_MAX; i++)
            n += pairs[i][0] >= 0;
        printf("ok count %d\n", n);
        return true;
    } else {
        return false;
    }
    printf("ok %s\n", line);
    return true;
}

/* Read stdin's commands; false at its end. */
static bool
commands(enum mode *mode)
{
    static char line[256];
    static size_t len;
    ssize_t n = read(0, line + len, sizeof(line) - 1 - len);
    if (n <= 0)
        return false;
    len += (size_t)n;
    for (char *nl; (nl = memchr(line, '\n', len));) {
        *nl = '\0';
        if (!command(line, mode))
            printf("error: unknown command '%s' (drop, blackhole, freeze, heal, count)\n", line);
        len -= (size_t)(nl + 1 - line);
        memmove(line, nl + 1, len);
    }
    if (len == sizeof(line) - 1)
        len = 0; /* a line too long for any command */
    fflush(stdout);
    return true;
}

static int
listen_on(int port)
{
    int fd = socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0), one = 1;
    struct sockaddr_in a = { .sin_family = AF_INET, .sin_port = htons((uint16_t)port) };
    a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    socklen_t alen = sizeof(a);
    if (fd < 0 || setsockopt(fd, SOL_SOCKET, SO_REUSEADDR, &one, sizeof(one)) ||
        bind(fd, (struct sockaddr *)&a, sizeof(a)) || listen(fd, 16) ||
        getsockname(fd, (struct sockaddr *)&a, &alen))
        return -1;
    printf("port %d\n", ntohs(a.sin_port));
    fflush(stdout);
    return fd;
}

int
main(int argc, char **argv)
{
    int target = argc > 1 ? (int)strtol(argv[1], NULL, 10) : 0;
    int port = argc > 2 ? (int)strtol(argv[2], NULL, 10) : 0;
    if (target < 1 || target > 65535 || port < 0 || port > 65535) {
        fprintf(stderr, "usage: tcpproxy TARGET_PORT [LISTEN_PORT]\n");
        return 2;
    }
    signal(SIGPIPE, SIG_IGN);
    memset(pairs, -1, sizeof(pairs));
    memset(held, -1, sizeof(held));
    int lfd = listen_on(port);
    if (lfd < 0) {
        fprintf(stderr, "tcpproxy: cannot listen on 127.0.0.1:%d: %s\n", port, strerror(errno));
        return 1;
    }
    enum mode mode = FORWARD;
    for (;;) {
        struct pollfd pfd[2 + 2 * PAIRS_MAX] = { { .fd = 0, .events = POLLIN },
                                                 { .fd = lfd, .events = POLLIN } };
        for (int i = 0; i < PAIRS_MAX; i++)
            for (int k = 0; k < 2; k++)
                pfd[2 + 2 * i + k] =
                    (struct pollfd){ .fd = mode == FREEZE ? -1 : pairs[i][k], .events = POLLIN };
        if (poll(pfd, 2 + 2 * PAIRS_MAX, -1) < 0 && errno != EINTR)
            return 1;
        if (pfd[0].revents && !commands(&mode))
            return 0;
        if (pfd[1].revents)
            take(lfd, mode, target);
        for (int i = 0; i < PAIRS_MAX; i++)
            for (int k = 0; k < 2; k++)
                if (pairs[i][k] >= 0 && pfd[2 + 2 * i + k].revents &&
                    pfd[2 + 2 * i + k].fd == pairs[i][k] && !pump(pairs[i][k], pairs[i][!k])) {
                    close(pairs[i][0]);
                    close(pairs[i][1]);
                    pairs[i][0] = pairs[i][1] = -1;
                }
    }
}
