/*
 * tproxy.h - a unit test's loopback TCP proxy (tests/tools/tcpproxy) to a
 * server's port, driven through its stdin/stdout: it prints "port N" once
 * listening, then answers each command line ("cut", "refuse", "freeze",
 * "pass"...: tests/tools/tcpproxy.c) with "ok ..." once it is in effect.
 *
 *     struct proxy p;
 *     if (proxy_start(&p, getenv("..._PROXY"), getenv("..._PORT"))) ... proxy_stop(&p);
 *
 * Header-only, as tstore.h.  One thread.
 */
#ifndef SF_TESTS_TPROXY_H
#define SF_TESTS_TPROXY_H

#include <spawn.h>
#include <stdbool.h>
#include <stdio.h>
#include <string.h>
#include <sys/types.h>
#include <sys/wait.h>
#include <unistd.h>

extern char **environ;

/* A proxy to a server's TCP port: its pid and command pipes, the port it listens on. */
struct proxy {
    pid_t pid;
    FILE *cmd, *out;
    int port;
};

/* Start the proxy program prog toward port (a decimal string); false if it did not start. */
static inline bool
proxy_start(struct proxy *p, const char *prog, const char *port)
{
    int in[2], out[2];
    if (!prog || !port || pipe(in))
        return false;
    if (pipe(out)) {
        close(in[0]);
        close(in[1]);
        return false;
    }
    posix_spawn_file_actions_t fa;
    posix_spawn_file_actions_init(&fa);
    posix_spawn_file_actions_adddup2(&fa, in[0], 0);
    posix_spawn_file_actions_adddup2(&fa, out[1], 1);
    posix_spawn_file_actions_addclose(&fa, in[1]);
    posix_spawn_file_actions_addclose(&fa, out[0]);
    char *argv[] = { (char *)prog, (char *)port, NULL };
    int rc = posix_spawn(&p->pid, argv[0], &fa, NULL, argv, environ);
    posix_spawn_file_actions_destroy(&fa);
    close(in[0]);
    close(out[1]);
    p->cmd = fdopen(in[1], "w");
    p->out = fdopen(out[0], "r");
    char line[64];
    return rc == 0 && p->cmd && p->out && fgets(line, sizeof(line), p->out) &&
           sscanf(line, "port %d", &p->port) == 1;
}

/* Send cmd and wait for its "ok" (the cut is made when this returns). */
static inline bool
proxy_cmd(struct proxy *p, const char *cmd)
{
    char line[128];
    fprintf(p->cmd, "%s\n", cmd);
    fflush(p->cmd);
    return fgets(line, sizeof(line), p->out) && strncmp(line, "ok ", 3) == 0;
}

static inline void
proxy_stop(struct proxy *p)
{
    fclose(p->cmd); /* end of its stdin ends it */
    fclose(p->out);
    waitpid(p->pid, NULL, 0);
}

#endif
