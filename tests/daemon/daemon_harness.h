/* Starts and stops a real gazesplatd for the tests, and small helpers
 * around gs_client. Header-only: each test program includes it once. */
#ifndef GSD_HARNESS_H
#define GSD_HARNESS_H

#ifndef _GNU_SOURCE
#define _GNU_SOURCE
#endif
#include <errno.h>
#include <fcntl.h>
#include <signal.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/resource.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>

#include "gs_client.h"
#include "gs_test.h"

#define T(x) GAZESPLAT__FRAME_TYPE__FRAME_##x
#define E(x) GAZESPLAT__ERROR_CODE__##x

typedef struct daemon_proc {
    pid_t pid;
    char dir[64];
    char sock[128];
    char log[128];
    long nofile; /* > 0: the daemon's RLIMIT_NOFILE, soft and hard */
} daemon_proc;

static long long h_now_ms(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (long long)ts.tv_sec * 1000 + ts.tv_nsec / 1000000;
}

static void h_sleep_ms(int ms)
{
    struct timespec ts = {ms / 1000, (long)(ms % 1000) * 1000000L};
    nanosleep(&ts, NULL);
}

/* Prints the daemon's log (on failures). */
static inline void daemon_dump_log(const daemon_proc *d)
{
    FILE *f = fopen(d->log, "r");
    char line[1024];
    fprintf(stderr, "---- gazesplatd log ----\n");
    while (f && fgets(line, sizeof line, f))
        fputs(line, stderr);
    fprintf(stderr, "------------------------\n");
    if (f)
        fclose(f);
}

/* Runs BIN --socket DIR/s.sock ARGS... (NULL-terminated) with stderr to
 * DIR/log; waits until the socket answers. dir: reuse when non-empty. */
static int daemon_start_v(daemon_proc *d, const char *bin, const char *const *args)
{
    if (!d->dir[0]) {
        snprintf(d->dir, sizeof d->dir, "/tmp/gsd_test_XXXXXX");
        if (!mkdtemp(d->dir))
            return -1;
    }
    snprintf(d->sock, sizeof d->sock, "%s/s.sock", d->dir);
    snprintf(d->log, sizeof d->log, "%s/log", d->dir);
    const char *argv[64];
    int n = 0;
    argv[n++] = bin;
    argv[n++] = "--socket";
    argv[n++] = d->sock;
    for (int i = 0; args && args[i] && n < 62; i++)
        argv[n++] = args[i];
    argv[n] = NULL;
    d->pid = fork();
    if (d->pid == 0) {
        int fd = open(d->log, O_WRONLY | O_CREAT | O_APPEND, 0600);
        dup2(fd, 2);
        if (d->nofile > 0) {
            struct rlimit rl = {(rlim_t)d->nofile, (rlim_t)d->nofile};
            setrlimit(RLIMIT_NOFILE, &rl);
        }
        execv(bin, (char *const *)argv);
        _exit(127);
    }
    for (int i = 0; i < 200; i++) {
        gs_client *c;
        if (gs_client_connect(d->sock, 1000, &c, NULL) == GS_OK) {
            gs_client_close(c);
            return 0;
        }
        int st;
        if (waitpid(d->pid, &st, WNOHANG) == d->pid) {
            d->pid = 0;
            return -1;
        }
        h_sleep_ms(25);
    }
    return -1;
}

/* Sends sig and waits for the exit; returns the exit status or -1. */
static inline int daemon_stop(daemon_proc *d, int sig, int timeout_ms)
{
    if (d->pid <= 0)
        return -1;
    kill(d->pid, sig);
    long long end = h_now_ms() + timeout_ms;
    int st;
    while (h_now_ms() < end) {
        if (waitpid(d->pid, &st, WNOHANG) == d->pid) {
            d->pid = 0;
            return WIFEXITED(st) ? WEXITSTATUS(st) : 128 + WTERMSIG(st);
        }
        h_sleep_ms(10);
    }
    kill(d->pid, SIGKILL);
    waitpid(d->pid, &st, 0);
    d->pid = 0;
    return -1;
}

static gs_client *h_connect(const char *addr)
{
    gs_client *c = NULL;
    gs_error err;
    if (gs_client_connect(addr, 2000, &c, &err) != GS_OK) {
        fprintf(stderr, "connect %s: %s\n", addr, err.msg);
        return NULL;
    }
    return c;
}

static gs_client *h_hello(const char *addr)
{
    gs_client *c = h_connect(addr);
    gs_error err;
    if (c && gs_client_hello(c, "test", NULL, 3000, NULL, &err) != GS_OK) {
        fprintf(stderr, "hello: %s\n", err.msg);
        gs_client_close(c);
        return NULL;
    }
    return c;
}

/* HEALTH on c answers HEALTH_OK. */
static inline int h_health_on(gs_client *c, uint32_t id)
{
    Gazesplat__HealthRequest req = GAZESPLAT__HEALTH_REQUEST__INIT;
    gs_client_frame f;
    gs_error err;
    if (gs_client_call(c, T(HEALTH), NULL, id, &req.base, 3000, &f, &err) != GS_OK)
        return 0;
    int ok = f.header.type == T(HEALTH_OK) && f.header.request_id == id;
    gs_client_frame_free(&f);
    return ok;
}

/* A fresh connection gets through HELLO and HEALTH. */
static inline int h_server_answers(const char *addr)
{
    gs_client *c = h_hello(addr);
    int ok = c && h_health_on(c, 4242);
    gs_client_close(c);
    return ok;
}

/* Waits for a frame; -1 on timeout/close, else its type; code gets the
 * ERROR code (0 otherwise). */
static inline int h_recv(gs_client *c, int timeout_ms, int *code, uint32_t *id, ProtobufCMessage **msg)
{
    gs_client_frame f;
    gs_error err;
    *code = 0;
    if (gs_client_recv(c, timeout_ms, &f, &err) != GS_OK)
        return -1;
    if (f.header.type == T(ERROR))
        *code = ((Gazesplat__Error *)f.msg)->code;
    if (id)
        *id = f.header.request_id;
    int type = f.header.type;
    if (msg)
        *msg = f.msg;
    else
        gs_client_frame_free(&f);
    return type;
}

/* The peer closed (recv sees EOF) within timeout_ms. */
static inline int h_closed(gs_client *c, int timeout_ms)
{
    gs_client_frame f;
    gs_error err;
    int r = gs_client_recv(c, timeout_ms, &f, &err);
    if (r == GS_OK)
        gs_client_frame_free(&f);
    return r != GS_OK && strcmp(err.msg, "closed") == 0;
}

static inline size_t h_frame(uint8_t *buf, uint16_t version, uint16_t type, uint32_t len, uint32_t id)
{
    gs_frame_header h;
    memset(&h, 0, sizeof h);
    h.version = version;
    h.type = type;
    h.payload_len = len;
    h.request_id = id;
    gs_frame_header_pack(&h, buf);
    return GS_FRAME_HEADER_SIZE;
}

#endif
