/* gazesplatd metrics: the STATS figures and per-request-type latency
 * histograms in Prometheus's text format (version 0.0.4), on their own
 * socket (`metrics = HOST:PORT`, loopback unless tcp_allow_remote, or
 * `metrics = unix:PATH`), so a stock scraper needs no client of the
 * daemon's protocol. Served by the event loop: one HTTP/1.x request per
 * connection, answered and closed; GET /metrics is 200, another path 404,
 * another method 405, a request over 4 KiB or slower than
 * header_timeout_ms is closed. */
#define _GNU_SOURCE
#include <errno.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <unistd.h>

#include "log.h"
#include "daemon.h"
#include "stats.h"

#define MCONN_MAX 16
#define MREQ_MAX 4096

struct gsd_mconn {
    ev_watch w;
    gsd_server *srv;
    struct gsd_mconn *next;
    int64_t opened_ms;
    size_t have;
    char in[MREQ_MAX];
    char *out;
    size_t out_len, out_off;
};

/* Upper bounds of the latency buckets, seconds (the last, +Inf, implied). */
static const double bucket_le[GSD_HIST_BUCKETS] = {0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5,
                                                   1,     2.5,  5,     10,   30,  60,   120};
static const char *const kind_names[GSD_REQ_KINDS] = {"fit", "redirect", "sleep"};

void gsd_metrics_observe(gsd_server *s, int kind, double seconds)
{
    if (kind < 0 || kind >= GSD_REQ_KINDS)
        return;
    gsd_hist *h = &s->hist[kind];
    int b = 0;
    while (b < GSD_HIST_BUCKETS && seconds > bucket_le[b])
        b++;
    if (b < GSD_HIST_BUCKETS)
        h->bucket[b]++;
    h->count++;
    h->sum_s += seconds;
}

/* A growing text buffer; on allocation failure it stays marked failed. */
typedef struct text {
    char *p;
    size_t len, cap;
    int failed;
} text;

static void tprintf(text *t, const char *fmt, ...) __attribute__((format(printf, 2, 3)));
static void tprintf(text *t, const char *fmt, ...)
{
    for (int tries = 0; tries < 2 && !t->failed; tries++) {
        va_list ap;
        va_start(ap, fmt);
        int n = vsnprintf(t->p ? t->p + t->len : NULL, t->p ? t->cap - t->len : 0, fmt, ap);
        va_end(ap);
        if (n < 0) {
            t->failed = 1;
            return;
        }
        if (t->p && (size_t)n < t->cap - t->len) {
            t->len += (size_t)n;
            return;
        }
        size_t cap = (t->cap ? t->cap : 8192);
        while (cap < t->len + (size_t)n + 1)
            cap *= 2;
        char *q = realloc(t->p, cap);
        if (!q) {
            t->failed = 1;
            return;
        }
        t->p = q;
        t->cap = cap;
    }
}

/* The exposition: every STATS figure (counters as NAME_total), the
 * latency histograms and an info series with the version and model id. */
static void render(gsd_server *s, text *t)
{
    gsd_stat st[GSD_STATS_MAX];
    size_t n = gsd_stats_collect(s, st, GSD_STATS_MAX);
    for (size_t i = 0; i < n; i++) {
        const char *suffix = st[i].gauge ? "" : "_total";
        tprintf(t, "# TYPE gazesplatd_%s%s %s\ngazesplatd_%s%s %llu\n", st[i].name, suffix,
                st[i].gauge ? "gauge" : "counter", st[i].name, suffix, (unsigned long long)st[i].value);
    }
    tprintf(t, "# HELP gazesplatd_request_duration_seconds Compute requests from queueing to "
               "their last frame, by type.\n"
               "# TYPE gazesplatd_request_duration_seconds histogram\n");
    for (int k = 0; k < GSD_REQ_KINDS; k++) {
        const gsd_hist *h = &s->hist[k];
        uint64_t cum = 0;
        for (int b = 0; b < GSD_HIST_BUCKETS; b++) {
            cum += h->bucket[b];
            tprintf(t, "gazesplatd_request_duration_seconds_bucket{type=\"%s\",le=\"%g\"} %llu\n",
                    kind_names[k], bucket_le[b], (unsigned long long)cum);
        }
        tprintf(t,
                "gazesplatd_request_duration_seconds_bucket{type=\"%s\",le=\"+Inf\"} %llu\n"
                "gazesplatd_request_duration_seconds_sum{type=\"%s\"} %.6f\n"
                "gazesplatd_request_duration_seconds_count{type=\"%s\"} %llu\n",
                kind_names[k], (unsigned long long)h->count, kind_names[k], h->sum_s, kind_names[k],
                (unsigned long long)h->count);
    }
    char id[33];
    gsd_model_image_size(s, id);
    tprintf(t, "# TYPE gazesplatd_info gauge\ngazesplatd_info{version=\"%s\",model_id=\"%s\"} 1\n",
            GSD_VERSION, id);
}

static void mconn_close(gsd_server *s, struct gsd_mconn *m)
{
    for (struct gsd_mconn **pp = &s->mconns; *pp; pp = &(*pp)->next)
        if (*pp == m) {
            *pp = m->next;
            break;
        }
    ev_del(s->loop, &m->w);
    close(m->w.fd);
    free(m->out);
    free(m);
    s->nmconns--;
}

static void mconn_respond(struct gsd_mconn *m)
{
    gsd_server *s = m->srv;
    text body = {0}, all = {0};
    const char *status = "200 OK";
    m->in[m->have < MREQ_MAX ? m->have : MREQ_MAX - 1] = '\0';
    int get = !strncmp(m->in, "GET ", 4), head = !strncmp(m->in, "HEAD ", 5);
    const char *path = m->in + (get ? 4 : 5);
    size_t plen = strcspn(path, " ?\r\n");
    if (!get && !head)
        status = "405 Method Not Allowed";
    else if (plen != 8 || strncmp(path, "/metrics", 8) != 0)
        status = "404 Not Found";
    if (status[0] == '2')
        render(s, &body);
    else
        tprintf(&body, "%s\n", status);
    tprintf(&all,
            "HTTP/1.0 %s\r\nContent-Type: %s\r\nContent-Length: %zu\r\nConnection: close\r\n%s\r\n",
            status, status[0] == '2' ? "text/plain; version=0.0.4; charset=utf-8" : "text/plain",
            body.len, status[0] == '4' && status[1] == '0' && status[2] == '5' ? "Allow: GET, HEAD\r\n" : "");
    if (!head && body.p)
        tprintf(&all, "%.*s", (int)body.len, body.p);
    free(body.p);
    if (body.failed || all.failed) {
        free(all.p);
        mconn_close(s, m);
        return;
    }
    m->out = all.p;
    m->out_len = all.len;
    ev_set(s->loop, &m->w, EV_WRITE);
}

static void on_mconn(ev_loop *loop, ev_watch *w, int events)
{
    (void)loop;
    struct gsd_mconn *m = w->ctx;
    gsd_server *s = m->srv;
    if (m->out) {
        while (m->out_off < m->out_len) {
            ssize_t n = send(w->fd, m->out + m->out_off, m->out_len - m->out_off, MSG_NOSIGNAL);
            if (n < 0 && errno == EINTR)
                continue;
            if (n < 0 && (errno == EAGAIN || errno == EWOULDBLOCK))
                return;
            if (n <= 0)
                break;
            m->out_off += (size_t)n;
        }
        mconn_close(s, m);
        return;
    }
    if (!(events & EV_READ)) {
        if (events & EV_HUP)
            mconn_close(s, m);
        return;
    }
    ssize_t n = recv(w->fd, m->in + m->have, MREQ_MAX - 1 - m->have, 0);
    if (n < 0 && (errno == EAGAIN || errno == EWOULDBLOCK || errno == EINTR))
        return;
    if (n <= 0) {
        mconn_close(s, m);
        return;
    }
    m->have += (size_t)n;
    m->in[m->have] = '\0';
    if (strstr(m->in, "\r\n\r\n") || strstr(m->in, "\n\n"))
        mconn_respond(m);
    else if (m->have >= MREQ_MAX - 1)
        mconn_close(s, m); /* a request head this long is not a scrape */
}

static void on_metrics_accept(ev_loop *loop, ev_watch *w, int events)
{
    (void)events;
    gsd_server *s = w->ctx;
    for (int i = 0; i < 16; i++) {
        int fd = accept4(w->fd, NULL, NULL, SOCK_NONBLOCK | SOCK_CLOEXEC);
        if (fd < 0)
            return;
        struct gsd_mconn *m = s->nmconns < MCONN_MAX ? calloc(1, sizeof *m) : NULL;
        if (!m) {
            close(fd);
            continue;
        }
        m->srv = s;
        m->opened_ms = ev_now_ms();
        if (ev_add(loop, &m->w, fd, EV_READ, on_mconn, m) != 0) {
            close(fd);
            free(m);
            continue;
        }
        m->next = s->mconns;
        s->mconns = m;
        s->nmconns++;
    }
}

int gsd_metrics_setup(gsd_server *s, char *msg, size_t cap)
{
    s->metrics_w.fd = -1;
    if (!s->cfg.metrics[0])
        return 0;
    int fd = gsd_listen_open(s->cfg.metrics, s->cfg.socket_mode, s->cfg.tcp_allow_remote, msg, cap);
    if (fd < 0)
        return -1;
    if (ev_add(s->loop, &s->metrics_w, fd, EV_READ, on_metrics_accept, s) != 0) {
        snprintf(msg, cap, "metrics: epoll: %s", strerror(errno));
        close(fd);
        return -1;
    }
    if (!strncmp(s->cfg.metrics, "unix:", 5))
        snprintf(s->metrics_path, sizeof s->metrics_path, "%s", s->cfg.metrics + 5);
    LOG_I("metrics on %s%s (GET /metrics)", strncmp(s->cfg.metrics, "unix:", 5) ? "http://" : "",
          s->cfg.metrics);
    return 0;
}

void gsd_metrics_tick(gsd_server *s, int64_t now)
{
    for (struct gsd_mconn *m = s->mconns, *n; m; m = n) {
        n = m->next;
        if (now - m->opened_ms > s->cfg.header_timeout_ms)
            mconn_close(s, m);
    }
}

void gsd_metrics_close(gsd_server *s)
{
    while (s->mconns)
        mconn_close(s, s->mconns);
    if (s->metrics_w.fd >= 0) {
        ev_del(s->loop, &s->metrics_w);
        close(s->metrics_w.fd);
        s->metrics_w.fd = -1;
        if (s->metrics_path[0])
            unlink(s->metrics_path);
        s->metrics_path[0] = '\0';
    }
}
