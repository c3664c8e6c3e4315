/* gazesplatd: the event-loop side. Listeners, connections (incremental
 * frame parser, output queues with caps), request dispatch, timeouts,
 * completions from workers, signals, drain. */
#define _GNU_SOURCE
#include "server.h"
#include "out.h"
#include "stats.h"

#include <arpa/inet.h>
#include <errno.h>
#include <fcntl.h>
#include <math.h>
#include <netdb.h>
#include <netinet/in.h>
#include <signal.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/resource.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <sys/uio.h>
#include <sys/un.h>
#include <time.h>
#include <unistd.h>

#include "gazesplat/nn.h"
#include "log.h"

#define TICK_MS 50
#define READ_BUDGET (1u << 20)   /* bytes read from one peer per event */
#define WRITE_BUDGET (4u << 20)  /* bytes written to one peer per event */
#define MIN_BODY_RATE 65536      /* bytes/s a frame body must sustain */
#define FD_MARGIN 64             /* open files besides connections: listeners, epoll, wake-up,
                                  * signal pipe, state files, model and face files, live devices */
#define CLIENT_NAME_MAX 64       /* Hello.client_name, bytes */

struct gsd_conn {
    ev_watch w;
    gsd_server *srv;
    uint64_t id;
    int is_tcp;
    char peer[64];
    int hello_done;
    uint16_t version;
    gs_frame_parser parser;
    gsd_out *whead, *wtail;
    size_t woff, wbytes;
    int closing;          /* protocol error: close once the output is flushed */
    int eof;              /* peer closed its side: finish in-flight work */
    int paused;           /* reading stopped: output over its cap */
    int64_t opened_ms, last_ms, frame_start_ms, closing_ms; /* last_ms: last byte either way */
    uint64_t rng;         /* per-client jitter of BUSY hints */
    gsd_job *inflight;
    int ninflight;
    gsd_conn *prev, *next;
};

#define E(x) GAZESPLAT__ERROR_CODE__##x
#define T(x) GAZESPLAT__FRAME_TYPE__FRAME_##x

static void conn_close(gsd_conn *c, const char *why);
static void conn_update_interest(gsd_conn *c);


static void bump(atomic_ullong *c, unsigned long long n)
{
    atomic_fetch_add(c, n);
}

/* ---- frames out ---------------------------------------------------------- */

/* Frames of job j (all jobs: NULL) still queued on c forget it: the job
 * is about to be freed, or cancelled with its connection. */
static void out_detach(gsd_conn *c, const gsd_job *j)
{
    for (gsd_out *o = c->whead; o; o = o->next)
        if (o->job && (!j || o->job == j))
            o->job = NULL;
}

static size_t output_cap(const gsd_conn *c)
{
    return (size_t)c->srv->cfg.max_output_kb * 1024;
}

static void conn_queue(gsd_conn *c, gsd_out *o)
{
    o->next = NULL;
    if (c->wtail)
        c->wtail->next = o;
    else
        c->whead = o;
    c->wtail = o;
    c->wbytes += o->len;
    bump(&c->srv->ctr.frames_out, 1);
    if (o->request_error) /* a worker's ERROR ending a request; reply_error counts its own */
        bump(&c->srv->ctr.request_errors, 1);
    conn_update_interest(c);
}

/* A reply built on the loop thread for the frame h. */
static void reply(gsd_conn *c, const gs_frame_header *req, uint16_t type, const ProtobufCMessage *msg)
{
    gs_frame_header h = *req;
    h.version = c->version;
    h.type = type;
    gsd_out *o = gsd_out_pack(c->srv, &h, msg);
    if (!o) {
        conn_close(c, "out of memory");
        return;
    }
    conn_queue(c, o);
}

/* A request error: the connection stays open. */
static void reply_error(gsd_conn *c, const gs_frame_header *req, int code, const char *fmt, ...)
    __attribute__((format(printf, 4, 5)));
static void reply_error(gsd_conn *c, const gs_frame_header *req, int code, const char *fmt, ...)
{
    char text[512];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(text, sizeof text, fmt, ap);
    va_end(ap);
    bump(&c->srv->ctr.request_errors, 1);
    LOG_D("%s: request %u: %s: %s", c->peer, req->request_id, gs_msg_error_name(code), text);
    gs_frame_header h = *req;
    h.version = c->version;
    gsd_out *o = gsd_out_error(c->srv, &h, code, text);
    if (o)
        conn_queue(c, o);
    else
        conn_close(c, "out of memory");
}

/* A protocol error: ERROR frame, stop reading, close after the flush. */
static void conn_fail(gsd_conn *c, int code, uint32_t request_id, const char *fmt, ...)
    __attribute__((format(printf, 4, 5)));
static void conn_fail(gsd_conn *c, int code, uint32_t request_id, const char *fmt, ...)
{
    char text[512], esc[200];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(text, sizeof text, fmt, ap);
    va_end(ap);
    gsd_log_escape(c->parser.hbuf, c->parser.state == 0 ? c->parser.have : GS_FRAME_HEADER_SIZE,
                   esc, sizeof esc);
    LOG_W("%s: %s: %s (header bytes \"%s\"); closing", c->peer, gs_msg_error_name(code), text, esc);
    bump(code == E(ERR_TIMEOUT) ? &c->srv->ctr.timeouts : &c->srv->ctr.protocol_errors, 1);
    gs_frame_header h;
    memset(&h, 0, sizeof h);
    h.request_id = request_id;
    h.version = c->version;
    gsd_out *o = gsd_out_error(c->srv, &h, code, text);
    c->closing = 1;
    c->closing_ms = ev_now_ms();
    if (o)
        conn_queue(c, o);
    conn_update_interest(c);
}

/* ---- connections ----------------------------------------------------------- */

static int prehello_type_ok(uint16_t type)
{
    return gs_msg_is_request(type);
}

static void set_limits(gsd_conn *c)
{
    gs_frame_limits lim = {GS_FRAME_MAX_PAYLOAD_PREHELLO, GS_PROTO_VERSION_MIN, GS_PROTO_VERSION_MAX,
                           prehello_type_ok};
    if (c->hello_done) {
        lim.max_payload = (uint32_t)c->srv->cfg.max_payload;
        lim.version_min = lim.version_max = c->version;
    }
    c->parser.limits = lim;
}

static void conn_update_interest(gsd_conn *c)
{
    if (c->w.mask < 0)
        return;
    size_t cap = output_cap(c);
    int was = c->paused;
    if (!c->paused && c->wbytes > cap)
        c->paused = 1;
    else if (c->paused && c->wbytes <= cap / 2)
        c->paused = 0;
    if (c->paused != was) /* the connection's renders wait while it is over */
        for (gsd_job *j = c->inflight; j; j = j->cnext)
            atomic_store(&j->conn_paused, c->paused);
    int mask = (c->closing || c->eof || c->paused ? 0 : EV_READ) | (c->wbytes ? EV_WRITE : 0);
    ev_set(c->srv->loop, &c->w, mask);
}

static void conn_free(gsd_conn *c)
{
    for (gsd_out *o = c->whead, *n; o; o = n) {
        n = o->next;
        gsd_out_free(c->srv, o);
    }
    gs_frame_parser_free(&c->parser);
    free(c);
}

static void conn_close(gsd_conn *c, const char *why)
{
    if (c->w.fd < 0)
        return;
    gsd_server *s = c->srv;
    LOG_D("%s: closed (%s)", c->peer, why);
    ev_del(s->loop, &c->w);
    close(c->w.fd);
    c->w.fd = -1;
    c->w.mask = -1;
    /* Jobs still running lose their connection; their frames are dropped
     * (the queued ones now, in conn_free, without touching the jobs). */
    out_detach(c, NULL);
    for (gsd_job *j = c->inflight; j; j = j->cnext) {
        j->conn = NULL;
        atomic_store(&j->stop, E(ERR_CANCELLED));
    }
    c->inflight = NULL;
    if (c->prev)
        c->prev->next = c->next;
    else
        s->conns = c->next;
    if (c->next)
        c->next->prev = c->prev;
    c->next = s->dead;
    s->dead = c;
    s->nconns--;
    bump(&s->ctr.conn_closed, 1);
}

static void free_dead(ev_loop *loop, void *ctx)
{
    (void)loop;
    gsd_server *s = ctx;
    while (s->dead) {
        gsd_conn *c = s->dead;
        s->dead = c->next;
        conn_free(c);
    }
}

static void conn_flush(gsd_conn *c)
{
    size_t budget = WRITE_BUDGET;
    while (c->whead && budget > 0) {
        struct iovec iov[16];
        int n = 0;
        size_t off = c->woff;
        for (gsd_out *o = c->whead; o && n < 16; o = o->next, off = 0) {
            iov[n].iov_base = o->data + off;
            iov[n].iov_len = o->len - off;
            n++;
        }
        ssize_t w = writev(c->w.fd, iov, n);
        if (w < 0 && errno == EINTR)
            continue;
        if (w < 0 && (errno == EAGAIN || errno == EWOULDBLOCK))
            break;
        if (w <= 0) {
            conn_close(c, "write failed");
            return;
        }
        bump(&c->srv->ctr.bytes_out, (unsigned long long)w);
        c->last_ms = ev_now_ms();
        c->wbytes -= (size_t)w;
        budget = (size_t)w >= budget ? 0 : budget - (size_t)w;
        size_t left = (size_t)w;
        while (left > 0) {
            gsd_out *o = c->whead;
            size_t rest = o->len - c->woff;
            if (left < rest) {
                c->woff += left;
                break;
            }
            left -= rest;
            c->woff = 0;
            c->whead = o->next;
            if (!c->whead)
                c->wtail = NULL;
            gsd_out_free(c->srv, o);
        }
    }
    if (!c->whead && (c->closing || (c->eof && !c->inflight))) {
        conn_close(c, c->closing ? "after error" : "peer closed");
        return;
    }
    conn_update_interest(c);
}

/* ---- handlers ------------------------------------------------------------- */

/* Constant-time comparison: time does not depend on where they differ. */
static int token_equal(const uint8_t *a, size_t alen, const char *b)
{
    size_t blen = strlen(b);
    unsigned diff = (unsigned)(alen ^ blen);
    for (size_t i = 0; i < blen; i++)
        diff |= (unsigned)(b[i] ^ (i < alen ? a[i] : 0));
    return diff == 0;
}

static void handle_hello(gsd_conn *c, const gs_frame_header *h, const Gazesplat__Hello *m)
{
    gsd_server *s = c->srv;
    bump(&s->ctr.req_hello, 1);
    if (c->hello_done) {
        conn_fail(c, E(ERR_HELLO_REQUIRED), h->request_id, "second HELLO");
        return;
    }
    /* An absent bound is 0: min_version 0 means 1, max_version 0 no upper
     * bound, so an empty HELLO gets the server's highest version. */
    uint32_t lo = m->min_version ? m->min_version : 1;
    uint32_t hi = m->max_version ? m->max_version : UINT32_MAX;
    uint32_t v = hi < GS_PROTO_VERSION_MAX ? hi : GS_PROTO_VERSION_MAX;
    if (hi < lo || v < lo || v < GS_PROTO_VERSION_MIN) {
        char his[16] = "any";
        if (m->max_version)
            snprintf(his, sizeof his, "%u", hi);
        conn_fail(c, E(ERR_BAD_VERSION), h->request_id, "client speaks %u..%s, server %d..%d", lo, his,
                  GS_PROTO_VERSION_MIN, GS_PROTO_VERSION_MAX);
        return;
    }
    size_t name_len = strlen(m->client_name);
    if (name_len > CLIENT_NAME_MAX) {
        conn_fail(c, E(ERR_INVALID_ARGUMENT), h->request_id, "client_name is %zu bytes, over %d",
                  name_len, CLIENT_NAME_MAX);
        return;
    }
    /* protobuf-c does not check that a string is UTF-8; proto3 says it
     * must be, so a name that is not makes the HELLO malformed. */
    if (!gsd_utf8_valid(m->client_name, name_len)) {
        conn_fail(c, E(ERR_MALFORMED), h->request_id, "client_name is not valid UTF-8");
        return;
    }
    if (c->is_tcp && s->cfg.token[0] && !token_equal(m->token.data, m->token.len, s->cfg.token)) {
        conn_fail(c, E(ERR_AUTH), h->request_id, "token missing or wrong");
        return;
    }
    char name[4 * CLIENT_NAME_MAX + 1];
    gsd_log_escape(m->client_name, name_len, name, sizeof name);
    LOG_D("%s: HELLO from '%s', version %u", c->peer, name, v);
    c->hello_done = 1;
    c->version = (uint16_t)v;
    set_limits(c);
    Gazesplat__Limits lim = GAZESPLAT__LIMITS__INIT;
    lim.max_payload = (uint32_t)s->cfg.max_payload;
    lim.max_targets = (uint32_t)s->cfg.max_targets;
    lim.max_inflight = (uint32_t)s->cfg.max_inflight;
    lim.max_image_side = (uint32_t)s->cfg.max_image_side;
    lim.max_image_pixels = (uint64_t)s->cfg.max_image_mpix << 20;
    lim.queue_depth = (uint32_t)s->cfg.queue_depth;
    lim.idle_timeout_ms = (uint32_t)s->cfg.idle_timeout_ms;
    lim.max_deadline_ms = (uint32_t)s->cfg.max_deadline_ms;
    Gazesplat__HelloOk ok = GAZESPLAT__HELLO_OK__INIT;
    ok.version = v;
    ok.server = "gazesplatd " GSD_VERSION;
    ok.limits = &lim;
    char id[33];
    ok.image_size = (uint32_t)gsd_model_image_size(s, id);
    ok.photo_input = atomic_load(&s->photo_state) > 0;
    reply(c, h, T(HELLO_OK), &ok.base);
}

/* Most keys one HEALTH lists (18 bytes each on the wire: 1.2 MB). */
#define HEALTH_MAX_KEYS 65536

static void handle_health(gsd_conn *c, const gs_frame_header *h, const Gazesplat__HealthRequest *r)
{
    gsd_server *s = c->srv;
    bump(&s->ctr.req_health, 1);
    int len, running;
    gsd_work_lengths(s, &len, &running);
    char id[33];
    Gazesplat__Health m = GAZESPLAT__HEALTH__INIT;
    m.state = (Gazesplat__Health__State)atomic_load(&s->state);
    m.detail = s->detail;
    m.queue_length = (uint32_t)len;
    m.queue_depth = (uint32_t)s->cfg.queue_depth;
    m.workers = (uint32_t)s->work.nworkers;
    m.image_size = (uint32_t)gsd_model_image_size(s, id);
    m.model_id = id;
    int photo = atomic_load(&s->photo_state);
    m.photo_input = photo > 0;
    m.photo_detail = photo < 0 ? s->photo_msg : photo == 0 ? "face models not loaded yet" : "";
    /* The subjects held, for routers that prefer a warm daemon. */
    uint8_t digest[GSD_CACHE_KEY];
    size_t max = r->list_subjects ? HEALTH_MAX_KEYS : 0;
    size_t held = gsd_cache_keys(s->cache, NULL, 0, digest);
    uint8_t *keys = NULL;
    ProtobufCBinaryData *list = NULL;
    if (max && held) {
        size_t want = held < max ? held : max;
        keys = malloc(want * GSD_CACHE_KEY);
        list = malloc(want * sizeof *list);
        if (!keys || !list) {
            free(keys);
            free(list);
            reply_error(c, h, E(ERR_INTERNAL), "out of memory listing %zu subjects", want);
            return;
        }
        held = gsd_cache_keys(s->cache, keys, want, digest);
        size_t n = held < want ? held : want; /* the cache may have shrunk since */
        for (size_t i = 0; i < n; i++)
            list[i] = (ProtobufCBinaryData){GSD_CACHE_KEY, keys + i * GSD_CACHE_KEY};
        m.n_subject_keys = n;
        m.subject_keys = list;
    }
    m.subjects = (uint32_t)held;
    m.subjects_digest = (ProtobufCBinaryData){GSD_CACHE_KEY, digest};
    reply(c, h, T(HEALTH_OK), &m.base);
    free(keys);
    free(list);
}

static void handle_stats(gsd_conn *c, const gs_frame_header *h)
{
    gsd_server *s = c->srv;
    bump(&s->ctr.req_stats, 1);
    gsd_stat st[GSD_STATS_MAX];
    size_t n = gsd_stats_collect(s, st, GSD_STATS_MAX);
    Gazesplat__Counter cs[GSD_STATS_MAX];
    Gazesplat__Counter *ptrs[GSD_STATS_MAX];
    for (size_t i = 0; i < n; i++) {
        gazesplat__counter__init(&cs[i]);
        cs[i].name = (char *)st[i].name;
        cs[i].value = st[i].value;
        ptrs[i] = &cs[i];
    }
    Gazesplat__Stats m = GAZESPLAT__STATS__INIT;
    m.n_counters = n;
    m.counters = ptrs;
    reply(c, h, T(STATS_OK), &m.base);
}

static void handle_cancel(gsd_conn *c, const gs_frame_header *h, const Gazesplat__Cancel *m)
{
    (void)h;
    bump(&c->srv->ctr.req_cancel, 1);
    for (gsd_job *j = c->inflight; j; j = j->cnext)
        if (j->request_id == m->request_id) {
            int expected = 0;
            atomic_compare_exchange_strong(&j->stop, &expected, E(ERR_CANCELLED));
            LOG_D("%s: cancel request %u", c->peer, m->request_id);
        }
}

/* A job's estimated run time from what jobs of its kind cost lately. */
static uint32_t job_estimate_ms(const gsd_server *s, uint16_t type, const ProtobufCMessage *m)
{
    double ms;
    if (type == T(SLEEP)) {
        ms = ((const Gazesplat__Sleep *)m)->ms;
    } else if (type == T(FIT)) {
        ms = s->cost_fit_ms;
    } else {
        const Gazesplat__RedirectRequest *r = (const Gazesplat__RedirectRequest *)m;
        ms = (r->image ? s->cost_fit_ms : 0) + s->cost_target_ms * (double)r->n_targets;
    }
    return ms < 1 ? 1 : ms > 3.6e6 ? 3600000u : (uint32_t)ms;
}

/* xorshift64*: the jitter of one client's BUSY hints. */
static double conn_uniform(gsd_conn *c)
{
    uint64_t x = c->rng;
    x ^= x >> 12;
    x ^= x << 25;
    x ^= x >> 27;
    c->rng = x;
    return (double)((x * 0x2545F4914F6CDD1Dull) >> 11) / 9007199254740992.0;
}

/* BUSY's retry_after_ms: a queue slot opens when the first running job
 * ends, and the queue is through after its whole backlog (estimated per
 * job: gsd_work_backlog) over the workers. Each refused client is told a
 * time drawn uniformly between the two, so refused clients come back
 * spread over the window in which slots open, not all at once. */
static uint32_t retry_after_ms(gsd_conn *c)
{
    gsd_server *s = c->srv;
    double first, total;
    gsd_work_backlog(s, ev_now_ms(), &first, &total);
    double all = total / (s->work.nworkers > 0 ? s->work.nworkers : 1);
    double ms = first + (all > first ? conn_uniform(c) * (all - first) : 0);
    if (ms < 10)
        ms = 10;
    if (ms > 60000)
        ms = 60000;
    return (uint32_t)ms;
}

/* FIT, REDIRECT and SLEEP: validate here, then queue for a worker. The
 * message `m` is handed to the job on success. */
static int submit(gsd_conn *c, const gs_frame_header *h, ProtobufCMessage *m)
{
    gsd_server *s = c->srv;
    char msg[300];
    int e = 0;
    uint32_t deadline = 0;
    if (h->type == T(FIT)) {
        bump(&s->ctr.req_fit, 1);
        e = gsd_check_fit(s, (const Gazesplat__FitRequest *)m, msg, sizeof msg);
        deadline = ((const Gazesplat__FitRequest *)m)->deadline_ms;
    } else if (h->type == T(REDIRECT)) {
        bump(&s->ctr.req_redirect, 1);
        e = gsd_check_redirect(s, h, (const Gazesplat__RedirectRequest *)m, msg, sizeof msg);
        deadline = ((const Gazesplat__RedirectRequest *)m)->deadline_ms;
    } else {
        bump(&s->ctr.req_sleep, 1);
        const Gazesplat__Sleep *sl = (const Gazesplat__Sleep *)m;
        deadline = sl->deadline_ms;
        e = gsd_check_deadline(s, deadline, msg, sizeof msg);
        if (!e && sl->ms > 60000) {
            snprintf(msg, sizeof msg, "sleep %u ms over 60000", sl->ms);
            e = E(ERR_INVALID_ARGUMENT);
        }
    }
    int state = atomic_load(&s->state);
    if (!e && state == GSD_DRAINING) {
        e = E(ERR_SHUTTING_DOWN);
        snprintf(msg, sizeof msg, "server is shutting down");
    }
    if (!e && h->type != T(SLEEP) && state != GSD_READY) {
        e = state == GSD_LOADING ? E(ERR_LOADING) : E(ERR_NO_MODEL);
        snprintf(msg, sizeof msg, "%s", s->detail);
    }
    for (gsd_job *j = c->inflight; !e && j; j = j->cnext)
        if (j->request_id == h->request_id) {
            e = E(ERR_DUPLICATE_ID);
            snprintf(msg, sizeof msg, "request %u already in flight", h->request_id);
        }
    if (!e && c->ninflight >= s->cfg.max_inflight) {
        e = E(ERR_TOO_MANY_INFLIGHT);
        snprintf(msg, sizeof msg, "%d requests in flight (max_inflight)", c->ninflight);
    }
    if (e) {
        LOG_I("%s: %s %u refused: %s: %s", c->peer, gs_msg_type_name(h->type), h->request_id,
              gs_msg_error_name(e), msg);
        reply_error(c, h, e, "%s", msg);
        return -1;
    }
    gsd_job *j = calloc(1, sizeof *j);
    if (!j) {
        reply_error(c, h, E(ERR_INTERNAL), "out of memory");
        return -1;
    }
    j->conn = c;
    j->srv = s;
    j->sink = gsd_frame_sink(s);
    snprintf(j->peer, sizeof j->peer, "%s", c->peer);
    j->type = h->type;
    j->est_ms = job_estimate_ms(s, h->type, m);
    if (h->type == T(REDIRECT)) {
        const Gazesplat__RedirectRequest *r = (const Gazesplat__RedirectRequest *)m;
        j->targets = (uint32_t)r->n_targets;
        j->inline_fit = r->image != NULL;
    }
    atomic_store(&j->conn_paused, c->paused);
    j->version = c->version;
    j->request_id = h->request_id;
    memcpy(j->key, h->key, GS_FRAME_KEY_SIZE);
    j->enqueued_ms = ev_now_ms();
    j->deadline_ms = j->enqueued_ms + (deadline ? deadline : (uint32_t)s->cfg.request_timeout_ms);
    j->max_side = s->cfg.max_image_side;
    j->max_pixels = (size_t)s->cfg.max_image_mpix << 20;
    j->finetune_lr = s->cfg.finetune_lr; /* a reload may change it meanwhile */
    j->req = m;
    if (gsd_work_push(s, j) != 0) {
        bump(&s->ctr.busy, 1);
        Gazesplat__Busy b = GAZESPLAT__BUSY__INIT;
        int qlen, running;
        gsd_work_lengths(s, &qlen, &running);
        b.retry_after_ms = retry_after_ms(c);
        b.queue_length = (uint32_t)qlen;
        LOG_I("%s: %s %u refused: BUSY (%d queued), retry after %u ms", c->peer,
              gs_msg_type_name(h->type), h->request_id, qlen, b.retry_after_ms);
        reply(c, h, T(BUSY), &b.base);
        free(j);
        return -1;
    }
    j->cnext = c->inflight;
    c->inflight = j;
    c->ninflight++;
    return 0;
}

static void handle_live_policy(gsd_conn *c, const gs_frame_header *h,
                               const Gazesplat__LivePolicyRequest *m)
{
    Gazesplat__LivePolicy p = GAZESPLAT__LIVE_POLICY__INIT;
    char msg[256];
    int code = gsd_live_policy(c->srv, m, &p, msg, sizeof msg);
    if (code)
        reply_error(c, h, code, "%s", msg);
    else
        reply(c, h, T(LIVE_POLICY_OK), &p.base);
}

static void handle_live_status(gsd_conn *c, const gs_frame_header *h)
{
    Gazesplat__LiveStatus m = GAZESPLAT__LIVE_STATUS__INIT;
    Gazesplat__LivePolicy p = GAZESPLAT__LIVE_POLICY__INIT;
    Gazesplat__Angles head = GAZESPLAT__ANGLES__INIT, corr = GAZESPLAT__ANGLES__INIT;
    gsd_live_status(c->srv, &m, &p, &head, &corr);
    reply(c, h, T(LIVE_STATUS_OK), &m.base);
}

static int frame_is_job(uint16_t type)
{
    return type == T(FIT) || type == T(REDIRECT) || type == T(SLEEP);
}

/* One whole frame from the parser. */
static void dispatch(gsd_conn *c)
{
    gsd_server *s = c->srv;
    gs_frame_header h = *gs_frame_parser_header(&c->parser);
    const uint8_t *payload = gs_frame_parser_payload(&c->parser);
    bump(&s->ctr.frames_in, 1);
    c->last_ms = ev_now_ms();
    if (!c->hello_done && h.type != T(HELLO)) {
        conn_fail(c, E(ERR_HELLO_REQUIRED), h.request_id, "%s before HELLO", gs_msg_type_name(h.type));
        return;
    }
    if (h.type == T(SLEEP) && !s->cfg.debug_requests) {
        conn_fail(c, E(ERR_BAD_TYPE), h.request_id, "SLEEP needs debug_requests = yes");
        return;
    }
    ProtobufCMessage *m = gs_msg_unpack(h.type, payload, h.payload_len);
    if (!m) {
        if (h.type == T(HELLO)) {
            conn_fail(c, E(ERR_MALFORMED), h.request_id, "HELLO payload is not a Hello message");
        } else if (h.type == T(CANCEL)) {
            /* CANCEL is never answered, not even a malformed one: its frame's
             * request_id is not used and may be the very request it meant
             * to cancel, whose end an ERROR would then seem to be. */
            bump(&s->ctr.req_cancel, 1);
            bump(&s->ctr.request_errors, 1);
            LOG_D("%s: %u-byte payload is not a valid CANCEL message; ignored", c->peer, h.payload_len);
        } else {
            reply_error(c, &h, E(ERR_MALFORMED), "%u-byte payload is not a valid %s message",
                        h.payload_len, gs_msg_type_name(h.type));
        }
        return;
    }
    if (frame_is_job(h.type)) {
        if (submit(c, &h, m) == 0)
            return; /* the job owns m */
    } else if (h.type == T(HELLO)) {
        handle_hello(c, &h, (const Gazesplat__Hello *)m);
    } else if (h.type == T(HEALTH)) {
        handle_health(c, &h, (const Gazesplat__HealthRequest *)m);
    } else if (h.type == T(STATS)) {
        handle_stats(c, &h);
    } else if (h.type == T(CANCEL)) {
        handle_cancel(c, &h, (const Gazesplat__Cancel *)m);
    } else if (h.type == T(LIVE_POLICY)) {
        handle_live_policy(c, &h, (const Gazesplat__LivePolicyRequest *)m);
    } else if (h.type == T(LIVE_STATUS)) {
        handle_live_status(c, &h);
    }
    protobuf_c_message_free_unpacked(m, NULL);
}

static void parser_error(gsd_conn *c, int r)
{
    const gs_frame_header *h = &c->parser.header;
    switch (r) {
    case GS_FRAME_ERR_MAGIC:
        conn_fail(c, E(ERR_BAD_MAGIC), 0, "bad magic");
        break;
    case GS_FRAME_ERR_VERSION:
        conn_fail(c, E(ERR_BAD_VERSION), h->request_id, "frame version %u, want %u..%u", h->version,
                  c->parser.limits.version_min, c->parser.limits.version_max);
        break;
    case GS_FRAME_ERR_TYPE:
        conn_fail(c, E(ERR_BAD_TYPE), h->request_id, "frame type %u is not a request", h->type);
        break;
    case GS_FRAME_ERR_TOO_LARGE:
        conn_fail(c, E(ERR_TOO_LARGE), h->request_id, "payload %u bytes over the limit %u%s",
                  h->payload_len, c->parser.limits.max_payload, c->hello_done ? "" : " before HELLO");
        break;
    default:
        conn_fail(c, E(ERR_INTERNAL), h->request_id, "out of memory");
    }
}

static void conn_read(gsd_conn *c)
{
    size_t budget = READ_BUDGET;
    while (budget > 0 && !c->closing && !c->paused && c->w.fd >= 0) {
        uint8_t *dst;
        size_t want;
        gs_frame_parser_want(&c->parser, &dst, &want);
        if (!gs_frame_parser_partial(&c->parser) && c->parser.have == 0)
            c->frame_start_ms = 0;
        ssize_t n = recv(c->w.fd, dst, want, 0);
        if (n < 0 && errno == EINTR)
            continue;
        if (n < 0 && (errno == EAGAIN || errno == EWOULDBLOCK))
            break;
        if (n <= 0) {
            if (n == 0 && !gs_frame_parser_partial(&c->parser) && (c->inflight || c->wbytes)) {
                c->eof = 1; /* half-closed: finish the work, then close */
                conn_update_interest(c);
            } else {
                conn_close(c, n == 0 ? "peer closed" : "read error");
            }
            return;
        }
        c->last_ms = ev_now_ms();
        if (c->frame_start_ms == 0)
            c->frame_start_ms = c->last_ms;
        bump(&c->srv->ctr.bytes_in, (unsigned long long)n);
        budget = (size_t)n >= budget ? 0 : budget - (size_t)n;
        int r = gs_frame_parser_advance(&c->parser, (size_t)n);
        if (r < 0) {
            parser_error(c, r);
            return;
        }
        if (r == GS_FRAME_READY) {
            dispatch(c);
            if (c->w.fd >= 0)
                gs_frame_parser_next(&c->parser);
            c->frame_start_ms = 0;
        }
    }
}

static void on_conn(ev_loop *loop, ev_watch *w, int events)
{
    (void)loop;
    gsd_conn *c = w->ctx;
    if (events & EV_HUP && !(events & EV_READ)) {
        conn_close(c, "hang-up");
        return;
    }
    if (events & EV_READ)
        conn_read(c);
    if (c->w.fd >= 0 && (events & EV_WRITE || c->wbytes))
        conn_flush(c);
    if (c->w.fd >= 0 && events & EV_HUP && !(events & EV_READ))
        conn_close(c, "hang-up");
}

static void peer_name(int fd, int is_tcp, char *out, size_t cap)
{
    struct sockaddr_storage ss;
    socklen_t len = sizeof ss;
    if (is_tcp && getpeername(fd, (struct sockaddr *)&ss, &len) == 0) {
        char host[INET6_ADDRSTRLEN] = "?", port[8] = "?";
        getnameinfo((struct sockaddr *)&ss, len, host, sizeof host, port, sizeof port,
                    NI_NUMERICHOST | NI_NUMERICSERV);
        snprintf(out, cap, "tcp:%s:%s", host, port);
        return;
    }
    struct ucred cr;
    len = sizeof cr;
    if (!is_tcp && getsockopt(fd, SOL_SOCKET, SO_PEERCRED, &cr, &len) == 0)
        snprintf(out, cap, "unix:pid=%d,uid=%u", (int)cr.pid, (unsigned)cr.uid);
    else
        snprintf(out, cap, "fd%d", fd);
}

/* A connection refused at accept: one ERROR frame (request id 0) written
 * without waiting, then the close. A fresh socket's buffer takes the
 * frame; input already there is read away first, so that a TCP close does
 * not turn into a reset that could discard the ERROR at the peer. */
static void refuse_conn(gsd_server *s, int fd, int code, const char *text)
{
    gs_frame_header h;
    memset(&h, 0, sizeof h);
    h.version = GS_PROTO_VERSION_MIN;
    gsd_out *o = gsd_out_error(s, &h, code, text);
    if (o) {
        ssize_t w = send(fd, o->data, o->len, MSG_NOSIGNAL | MSG_DONTWAIT);
        if (w > 0)
            bump(&s->ctr.bytes_out, (unsigned long long)w);
        if (w == (ssize_t)o->len)
            bump(&s->ctr.frames_out, 1);
        gsd_out_free(s, o);
    }
    char junk[512];
    for (int i = 0; i < 8 && recv(fd, junk, sizeof junk, MSG_DONTWAIT) > 0; i++)
        ;
    LOG_D("connection refused: %s", text);
    bump(&s->ctr.conn_rejected, 1);
    close(fd);
}

static void on_accept(ev_loop *loop, ev_watch *w, int events)
{
    (void)events;
    gsd_listener *l = w->ctx;
    gsd_server *s = l->srv;
    for (int i = 0; i < 64; i++) {
        int fd = accept4(l->fd, NULL, NULL, SOCK_NONBLOCK | SOCK_CLOEXEC);
        if (fd < 0) {
            if (errno != EAGAIN && errno != EWOULDBLOCK && errno != EINTR && errno != ECONNABORTED)
                LOG_W("accept: %s", strerror(errno));
            return;
        }
        if (atomic_load(&s->state) == GSD_DRAINING) {
            refuse_conn(s, fd, E(ERR_SHUTTING_DOWN), "server is shutting down");
            continue;
        }
        if (s->nconns >= s->cfg.max_connections) {
            char text[96];
            snprintf(text, sizeof text, "too many connections (max_connections %d); retry later",
                     s->cfg.max_connections);
            refuse_conn(s, fd, E(ERR_TOO_MANY_CONNECTIONS), text);
            continue;
        }
        gsd_conn *c = calloc(1, sizeof *c);
        if (!c) {
            close(fd);
            continue;
        }
        c->srv = s;
        c->id = ++s->next_conn_id;
        c->is_tcp = l->is_tcp;
        c->version = GS_PROTO_VERSION_MIN;
        c->opened_ms = c->last_ms = ev_now_ms();
        c->rng = (c->id * 0x9E3779B97F4A7C15ull) ^ (uint64_t)c->opened_ms ^ 0xD1B54A32D192ED03ull;
        if (!c->rng)
            c->rng = 1;
        peer_name(fd, l->is_tcp, c->peer, sizeof c->peer);
        gs_frame_limits lim = {0};
        gs_frame_parser_init(&c->parser, &lim);
        set_limits(c);
        if (ev_add(loop, &c->w, fd, EV_READ, on_conn, c) != 0) {
            close(fd);
            conn_free(c);
            continue;
        }
        c->next = s->conns;
        if (s->conns)
            s->conns->prev = c;
        s->conns = c;
        s->nconns++;
        bump(&s->ctr.conn_accepted, 1);
        LOG_D("%s: connected", c->peer);
    }
}

/* ---- completions, ticks, signals ------------------------------------------ */

/* What a finished job teaches the BUSY estimates: the run time of a
 * FIT, or of one target of a REDIRECT by key (inline REDIRECTs mix both
 * and SLEEPs say their own; failures and stops teach nothing). */
static void learn_cost(gsd_server *s, const gsd_job *j, uint64_t ms)
{
    double *avg = NULL, v = (double)ms;
    if (j->type == T(FIT)) {
        avg = &s->cost_fit_ms;
    } else if (j->type == T(REDIRECT) && !j->inline_fit && j->targets) {
        avg = &s->cost_target_ms;
        v /= j->targets;
    }
    if (avg)
        *avg = 0.7 * *avg + 0.3 * v;
}

/* One info line per compute request: who, what, which subject, how it
 * ended, how long it took from queueing, and the work it did. */
static void log_request(const gsd_job *j, int64_t total_ms)
{
    char hex[33], work[96] = "";
    gs_frame_key_hex(j->key, hex);
    if (j->type == T(FIT) || (j->type == T(REDIRECT) && j->inline_fit))
        snprintf(work, sizeof work, "%s%d iterations, %d fine-tuning steps", j->cached ? "cached, " : "",
                 j->iters, j->ft_steps);
    if (j->type == T(REDIRECT))
        snprintf(work + strlen(work), sizeof work - strlen(work), "%s%d of %u images", work[0] ? ", " : "",
                 j->images, j->targets);
    LOG_I("%s: %s %u subject %.16s: %s in %lld ms%s%s", j->peer, gs_msg_type_name(j->type), j->request_id,
          hex, j->result ? gs_msg_error_name(j->result) : "ok", (long long)total_ms, work[0] ? ", " : "",
          work);
}

static void job_finished(gsd_server *s, gsd_job *j, uint64_t ms, int ok)
{
    gsd_conn *c = j->conn;
    int64_t total = ev_now_ms() - j->enqueued_ms;
    if (ok)
        learn_cost(s, j, ms);
    log_request(j, total);
    gsd_metrics_observe(s, j->type == T(FIT) ? GSD_REQ_FIT : j->type == T(REDIRECT) ? GSD_REQ_REDIRECT
                                                                                     : GSD_REQ_SLEEP,
                        (double)total / 1000.0);
    if (c) {
        out_detach(c, j);
        c->last_ms = ev_now_ms();
        for (gsd_job **pp = &c->inflight; *pp; pp = &(*pp)->cnext)
            if (*pp == j) {
                *pp = j->cnext;
                c->ninflight--;
                break;
            }
    }
    s->job_ms_avg = s->job_ms_avg == 0 ? (double)ms : 0.8 * s->job_ms_avg + 0.2 * (double)ms;
    bump(&s->ctr.jobs_done, 1);
    if (j->req)
        protobuf_c_message_free_unpacked(j->req, NULL);
    free(j);
    if (c && c->eof && !c->inflight && !c->wbytes)
        conn_close(c, "peer closed");
}

/* Model loads (compute.c) report the state they leave the server in; the
 * loop sets it and attaches the live stage to a new model. */
static void model_start(gsd_server *s)
{
    char detail[GSD_STR_MAX + 320];
    int st = gsd_model_start_load(s, detail, sizeof detail);
    if (st >= 0)
        gsd_server_set_state(s, st, detail);
}

static void model_finish(gsd_server *s)
{
    char detail[GSD_STR_MAX + 320];
    int installed = 0;
    int st = gsd_model_finish_load(s, detail, sizeof detail, &installed);
    gsd_server_set_state(s, st, detail);
    if (installed)
        gsd_live_model_ready(s);
}

static void on_wake(ev_loop *loop, void *ctx)
{
    (void)loop;
    gsd_server *s = ctx;
    pthread_mutex_lock(&s->post_mu);
    gsd_out *list = s->post_head;
    s->post_head = s->post_tail = NULL;
    pthread_mutex_unlock(&s->post_mu);
    while (list) {
        gsd_out *o = list;
        list = o->next;
        gsd_job *j = o->job;
        int final = o->final;
        uint64_t ms = o->job_ms;
        int ok = (o->data[6] | o->data[7] << 8) != T(ERROR);
        if (j && j->conn && j->conn->w.fd >= 0) {
            conn_queue(j->conn, o);
            conn_flush(j->conn);
        } else {
            gsd_out_free(s, o);
        }
        if (final && j)
            job_finished(s, j, ms, ok);
    }
    if (atomic_load(&s->load_done))
        model_finish(s);
}

static void set_status(gsd_server *s)
{
    static const char *const words[] = {"loading", "ready", "no model", "draining"};
    gsd_notifyf("STATUS=%s: %s", words[atomic_load(&s->state)], s->detail);
}

static void conn_timeouts(gsd_server *s, int64_t now)
{
    for (gsd_conn *c = s->conns, *n; c; c = n) {
        n = c->next;
        int64_t frame_limit = s->cfg.header_timeout_ms;
        if (c->parser.state == 1) /* payload: allow a slow but steady body */
            frame_limit += (int64_t)c->parser.header.payload_len * 1000 / MIN_BODY_RATE;
        if (c->closing) {
            if (now - c->closing_ms > s->cfg.header_timeout_ms)
                conn_close(c, "peer not reading the error");
        } else if (!c->hello_done && now - c->opened_ms > s->cfg.header_timeout_ms) {
            conn_fail(c, E(ERR_TIMEOUT), 0, "no HELLO within %d ms", s->cfg.header_timeout_ms);
        } else if (c->frame_start_ms && now - c->frame_start_ms > frame_limit) {
            conn_fail(c, E(ERR_TIMEOUT), 0, "frame incomplete after %lld ms",
                      (long long)(now - c->frame_start_ms));
        } else if (s->cfg.idle_timeout_ms && !c->inflight && !c->wbytes && !c->frame_start_ms &&
                   now - c->last_ms > s->cfg.idle_timeout_ms) {
            conn_fail(c, E(ERR_TIMEOUT), 0, "idle for %d ms", s->cfg.idle_timeout_ms);
        }
    }
}

static int drained(gsd_server *s)
{
    int len, running;
    gsd_work_lengths(s, &len, &running);
    if (len || running)
        return 0;
    for (gsd_conn *c = s->conns; c; c = c->next)
        if (c->wbytes || c->inflight)
            return 0;
    return 1;
}

static void on_tick(ev_loop *loop, void *ctx)
{
    gsd_server *s = ctx;
    int64_t now = ev_now_ms();
    conn_timeouts(s, now);
    gsd_metrics_tick(s, now);
    if (s->watchdog_usec && now >= s->next_watchdog) {
        gsd_notify("WATCHDOG=1");
        s->next_watchdog = now + (int64_t)(s->watchdog_usec / 2000);
    }
    if (!s->ready_sent && now >= s->next_extend) {
        /* A long model load: ask systemd for more start-up time. */
        gsd_notify("EXTEND_TIMEOUT_USEC=20000000");
        s->next_extend = now + 5000;
    }
    if (atomic_load(&s->state) == GSD_DRAINING && (drained(s) || now >= s->drain_deadline)) {
        if (!drained(s))
            LOG_W("drain timeout: stopping with work in flight");
        ev_stop(loop);
    }
}

/* Open files: max_connections plus FD_MARGIN must fit RLIMIT_NOFILE. The
 * soft limit (often 1024, the default max_connections) is raised toward
 * the hard one; when even that is too low, max_connections is lowered to
 * what fits, so a full server refuses connections with an ERROR instead of
 * failing accept() with EMFILE. */
static void fit_fd_limit(gsd_server *s)
{
    struct rlimit rl;
    if (getrlimit(RLIMIT_NOFILE, &rl) != 0) {
        LOG_W("getrlimit(RLIMIT_NOFILE): %s; max_connections %d unchecked", strerror(errno),
              s->cfg.max_connections);
        return;
    }
    rlim_t need = (rlim_t)s->cfg.max_connections + FD_MARGIN;
    if (rl.rlim_cur != RLIM_INFINITY && rl.rlim_cur < need) {
        struct rlimit nr = rl;
        nr.rlim_cur = rl.rlim_max != RLIM_INFINITY && rl.rlim_max < need ? rl.rlim_max : need;
        if (nr.rlim_cur > rl.rlim_cur && setrlimit(RLIMIT_NOFILE, &nr) == 0) {
            LOG_I("open files limit raised from %llu to %llu", (unsigned long long)rl.rlim_cur,
                  (unsigned long long)nr.rlim_cur);
            rl.rlim_cur = nr.rlim_cur;
        } else if (nr.rlim_cur > rl.rlim_cur) {
            LOG_W("cannot raise the open files limit to %llu: %s", (unsigned long long)nr.rlim_cur,
                  strerror(errno));
        }
    }
    if (rl.rlim_cur != RLIM_INFINITY && rl.rlim_cur < need) {
        int fit = rl.rlim_cur > FD_MARGIN ? (int)(rl.rlim_cur - FD_MARGIN) : 1;
        LOG_W("max_connections %d needs %llu open files but the limit is %llu (hard %llu): "
              "max_connections %d in force; raise LimitNOFILE= or ulimit -n",
              s->cfg.max_connections, (unsigned long long)need, (unsigned long long)rl.rlim_cur,
              (unsigned long long)rl.rlim_max, fit);
        s->cfg.max_connections = fit;
    }
}

/* The state directory is checked at start, so that a typo is an error
 * then and not failed saves after the first fit. A missing directory
 * whose parent exists is created (0700, as systemd's StateDirectory=
 * would); one that cannot be created, a non-directory or a directory this
 * process cannot write is refused. */
static int check_state_dir(const char *dir, char *msg, size_t cap)
{
    struct stat st;
    if (stat(dir, &st) != 0) {
        if (errno != ENOENT) {
            snprintf(msg, cap, "state_dir %s: %s", dir, strerror(errno));
            return -1;
        }
        if (mkdir(dir, 0700) != 0) {
            snprintf(msg, cap, "state_dir %s does not exist and cannot be created (%s; its parent "
                     "must exist)", dir, strerror(errno));
            return -1;
        }
        LOG_I("state_dir %s created", dir);
        return 0;
    }
    if (!S_ISDIR(st.st_mode)) {
        snprintf(msg, cap, "state_dir %s is not a directory", dir);
        return -1;
    }
    if (access(dir, W_OK | X_OK) != 0) {
        snprintf(msg, cap, "state_dir %s is not writable: %s", dir, strerror(errno));
        return -1;
    }
    return 0;
}

void gsd_server_reconfigure(gsd_server *s, const gsd_config *cfg)
{
    gsd_config old = s->cfg;
    s->cfg = *cfg;
    /* Fixed at start: sockets, workers, state directory. */
    memcpy(s->cfg.socket, old.socket, sizeof old.socket);
    memcpy(s->cfg.tcp, old.tcp, sizeof old.tcp);
    memcpy(s->cfg.state_dir, old.state_dir, sizeof old.state_dir);
    s->cfg.socket_mode = old.socket_mode;
    s->cfg.workers = old.workers;
    s->cfg.threads = old.threads;
    s->cfg.tuned_subjects = old.tuned_subjects;
    fit_fd_limit(s);
    if (strcmp(old.socket, cfg->socket) || strcmp(old.tcp, cfg->tcp) || old.workers != cfg->workers ||
        old.threads != cfg->threads || strcmp(old.state_dir, cfg->state_dir) ||
        old.tuned_subjects != cfg->tuned_subjects)
        LOG_W("reload: socket, tcp, workers, threads, state_dir and tuned_subjects need a restart; "
              "kept");
    if (strcmp(old.live_device, cfg->live_device) || strcmp(old.live_output, cfg->live_output) ||
        old.live_width != cfg->live_width || old.live_height != cfg->live_height ||
        old.live_fps != cfg->live_fps || old.live_fit_budget_s != cfg->live_fit_budget_s)
        LOG_W("reload: live.* keys need a restart; the live pipeline keeps its settings");
    gsd_log_set_level(s->cfg.log_level);
    gsd_work_set_depth(s, s->cfg.queue_depth);
    gsd_cache_set_budget(s->cache, (size_t)s->cfg.cache_mb << 20);
    gsd_cache_set_budget(s->tuned, (size_t)s->cfg.tuned_cache_mb << 20);
    gsd_cache_set_budget(s->inputs, (size_t)s->cfg.input_cache_mb << 20);
    atomic_store(&s->out_budget, (size_t)s->cfg.output_budget_mb << 20);
    for (gsd_conn *c = s->conns; c; c = c->next)
        if (c->parser.state == 0 && c->parser.have == 0)
            set_limits(c);
    bump(&s->ctr.reloads, 1);
}

static void start_drain(gsd_server *s)
{
    if (atomic_load(&s->state) == GSD_DRAINING) {
        LOG_W("second stop signal: stopping now");
        ev_stop(s->loop);
        return;
    }
    LOG_I("draining: no new connections or requests, %d ms to finish", s->cfg.drain_timeout_ms);
    gsd_notify("STOPPING=1");
    atomic_store(&s->state, GSD_DRAINING);
    snprintf(s->detail, sizeof s->detail, "shutting down");
    set_status(s);
    gsd_listen_close(s);
    s->drain_deadline = ev_now_ms() + s->cfg.drain_timeout_ms;
}

/* Signals arrive through a self-pipe: the handler may run on any thread
 * (libraries such as OpenBLAS start threads before main can block
 * signals), and only writes the signal number. Program state, not
 * library state: one daemon per process. */
static int signal_pipe_wr = -1;

static void on_signal_handler(int sig)
{
    int saved = errno;
    unsigned char b = (unsigned char)sig;
    ssize_t r = write(signal_pipe_wr, &b, 1);
    (void)r;
    errno = saved;
}

static int install_signals(int wr)
{
    signal_pipe_wr = wr;
    struct sigaction sa;
    memset(&sa, 0, sizeof sa);
    sa.sa_handler = on_signal_handler;
    sa.sa_flags = SA_RESTART;
    sigemptyset(&sa.sa_mask);
    return sigaction(SIGTERM, &sa, NULL) | sigaction(SIGINT, &sa, NULL) | sigaction(SIGHUP, &sa, NULL);
}

static void on_signal(ev_loop *loop, ev_watch *w, int events)
{
    (void)loop;
    (void)events;
    gsd_server *s = w->ctx;
    unsigned char sig;
    while (read(w->fd, &sig, 1) == 1) {
        if (sig == SIGHUP) {
            LOG_I("SIGHUP: reloading configuration and model");
            /* MONOTONIC_USEC: systemd 253's Type=notify-reload wants it with
             * RELOADING=1; older managers ignore it. */
            struct timespec ts;
            clock_gettime(CLOCK_MONOTONIC, &ts);
            gsd_notifyf("RELOADING=1\nMONOTONIC_USEC=%llu",
                        (unsigned long long)ts.tv_sec * 1000000ull + (unsigned long long)ts.tv_nsec / 1000u);
            if (s->on_sighup)
                s->on_sighup(s);
            if (atomic_load(&s->state) != GSD_DRAINING)
                model_start(s);
            /* systemd waits for READY=1 to end the reload; a model load
             * sends it when it finishes. */
            if (!s->loader_running)
                gsd_notify("READY=1");
        } else {
            start_drain(s);
        }
    }
}

/* ---- life cycle ----------------------------------------------------------- */

int gsd_server_init(gsd_server *s, const gsd_config *cfg, char *msg, size_t cap)
{
    memset(s, 0, sizeof *s);
    s->metrics_w.fd = -1;
    s->cfg = *cfg;
    s->started_ms = ev_now_ms();
    s->exit_code = 0;
    pthread_mutex_init(&s->post_mu, NULL);
    pthread_mutex_init(&s->model_mu, NULL);
    pthread_mutex_init(&s->persist_mu, NULL);
    atomic_store(&s->state, GSD_LOADING);
    snprintf(s->detail, sizeof s->detail, "starting");
    atomic_store(&s->out_budget, (size_t)cfg->output_budget_mb << 20);
    /* Before any job has finished: a guess at each kind's cost. */
    s->cost_fit_ms = 2000;
    s->cost_target_ms = 20;
    s->loop = ev_create(on_wake, s);
    s->cache = gsd_cache_create((size_t)cfg->cache_mb << 20);
    /* A block can be as large as the budget (every part of a big model). */
    s->tuned = gsd_cache_create_sized((size_t)cfg->tuned_cache_mb << 20,
                                      (size_t)cfg->tuned_cache_mb << 20);
    s->inputs = gsd_cache_create_sized((size_t)cfg->input_cache_mb << 20, GSD_INPUT_MAX_BLOB);
    if (!s->loop || !s->cache || !s->tuned || !s->inputs) {
        snprintf(msg, cap, "out of memory or epoll failure");
        return -1;
    }
    const char *sd = getenv("STATE_DIRECTORY");
    if (cfg->state_dir[0])
        snprintf(s->state_dir, sizeof s->state_dir, "%s", cfg->state_dir);
    else if (sd && *sd)
        snprintf(s->state_dir, sizeof s->state_dir, "%.*s", (int)strcspn(sd, ":"), sd);
    if (s->state_dir[0] && check_state_dir(s->state_dir, msg, cap) != 0)
        return -1;
    fit_fd_limit(s);
    int pfd[2];
    if (pipe2(pfd, O_NONBLOCK | O_CLOEXEC) != 0 ||
        ev_add(s->loop, &s->sig_watch, pfd[0], EV_READ, on_signal, s) != 0 || install_signals(pfd[1]) != 0) {
        snprintf(msg, cap, "signal pipe: %s", strerror(errno));
        return -1;
    }
    s->sig_wr = pfd[1];
    s->on_accept = on_accept;
    if (gsd_listen_setup(s, msg, cap) != 0 || gsd_metrics_setup(s, msg, cap) != 0)
        return -1;
    if (gsd_work_start(s, cfg->workers, cfg->queue_depth) != 0) {
        snprintf(msg, cap, "cannot start %d workers", cfg->workers);
        return -1;
    }
    if (gsd_live_start(s, msg, cap) != 0)
        return -1;
    ev_set_tick(s->loop, TICK_MS, on_tick, s);
    ev_set_after(s->loop, free_dead, s);
    s->watchdog_usec = gsd_watchdog_usec();
    if (s->watchdog_usec)
        LOG_I("watchdog every %llu ms", (unsigned long long)(s->watchdog_usec / 1000));
    return 0;
}

int gsd_server_run(gsd_server *s)
{
    model_start(s);
    int r = ev_run(s->loop);
    if (r != 0)
        LOG_E("event loop: %s", strerror(errno));
    gsd_notify("STOPPING=1");
    return r;
}

void gsd_server_free(gsd_server *s)
{
    gsd_listen_close(s);
    gsd_metrics_close(s);
    /* Running jobs end at their next check; the queue is answered. */
    for (gsd_conn *c = s->conns; c; c = c->next)
        for (gsd_job *j = c->inflight; j; j = j->cnext)
            atomic_store(&j->stop, E(ERR_SHUTTING_DOWN));
    gsd_work_stop(s);
    on_wake(s->loop, s); /* frees the jobs' final frames */
    while (s->conns)
        conn_close(s->conns, "shutdown");
    free_dead(s->loop, s);
    if (s->loader_running)
        pthread_join(s->loader, NULL);
    if (atomic_load(&s->load_done))
        model_finish(s);
    gsd_cache_persist(s);
    gsd_live_stop(s); /* holds a model reference and borrows the landmark model */
    gsd_model_release_all(s);
    gsd_cache_destroy(s->cache);
    gsd_cache_destroy(s->tuned);
    gsd_cache_destroy(s->inputs);
    if (s->sig_watch.fd > 0) {
        signal(SIGTERM, SIG_DFL);
        signal(SIGINT, SIG_DFL);
        signal(SIGHUP, SIG_DFL);
        close(s->sig_watch.fd);
        close(s->sig_wr);
    }
    ev_destroy(s->loop);
    pthread_mutex_destroy(&s->post_mu);
    pthread_mutex_destroy(&s->model_mu);
    pthread_mutex_destroy(&s->persist_mu);
}

void gsd_server_set_state(gsd_server *s, int state, const char *detail)
{
    if (atomic_load(&s->state) != GSD_DRAINING)
        atomic_store(&s->state, state);
    snprintf(s->detail, sizeof s->detail, "%s", detail);
    if (!s->ready_sent && state != GSD_LOADING) {
        gsd_notify("READY=1");
        s->ready_sent = 1;
    }
    set_status(s);
}
