/* The live pipeline: capture thread -> ring -> processing thread -> ring ->
 * output thread. Frames live in a fixed pool; a ring that is full drops its
 * oldest frame, so a slow stage costs frames, never latency. */
#define _POSIX_C_SOURCE 200809L
#include <pthread.h>
#include <stdatomic.h>
#include <time.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "gazesplat/capture.h"

#define MAX_RING 8
/* Two rings, one frame in each of the three threads, one spare. */
#define MAX_FRAMES (2 * MAX_RING + 4)

typedef struct pframe {
    uint8_t *rgb;
    size_t cap;
    int width, height;
    int64_t t_capture, t_proc0;
} pframe;

typedef struct ring {
    pframe *slot[MAX_RING];
    int head, count, size;
} ring;

typedef struct window {
    double ms[GS_CAP_PIPE_WINDOW];
    int n, next;
} window;

struct gs_cap_pipe {
    gs_cap_pipe_config cfg;
    const gs_cap_ops *ops;       /* the clock */
    pthread_mutex_t lock;
    pthread_cond_t to_proc, to_out;
    pframe frames[MAX_FRAMES];
    pframe *free_list[MAX_FRAMES];
    int nfree;
    ring r_proc, r_out;          /* capture -> processing, processing -> output */
    atomic_int stop;
    uint64_t in, out, drops;     /* guarded by lock */
    uint64_t placeholders;       /* guarded by lock */
    gs_cap_stats cap_stats;      /* guarded by lock */
    window w_capture, w_process, w_output, w_total;
    pthread_t threads[3];
    int nthreads;
};

static int passthrough(void *ctx, uint8_t *rgb, size_t stride, int w, int h, int64_t t,
                       gs_error *err)
{
    (void)ctx, (void)rgb, (void)stride, (void)w, (void)h, (void)t, (void)err;
    return GS_OK;
}

gs_cap_stage gs_cap_stage_passthrough(void)
{
    gs_cap_stage s = {NULL, passthrough};
    return s;
}

static int64_t now(const gs_cap_pipe *p)
{
    return p->ops->now_ns(p->ops->ctx);
}

static void record(window *w, int64_t ns)
{
    w->ms[w->next] = (double)ns / 1e6;
    w->next = (w->next + 1) % GS_CAP_PIPE_WINDOW;
    if (w->n < GS_CAP_PIPE_WINDOW)
        w->n++;
}

/* Caller holds the lock. A full ring hands back its oldest frame. */
static pframe *ring_push(ring *r, pframe *f)
{
    pframe *dropped = NULL;
    if (r->count == r->size) {
        dropped = r->slot[r->head];
        r->head = (r->head + 1) % r->size;
        r->count--;
    }
    r->slot[(r->head + r->count) % r->size] = f;
    r->count++;
    return dropped;
}

static pframe *ring_pop(ring *r)
{
    if (!r->count)
        return NULL;
    pframe *f = r->slot[r->head];
    r->head = (r->head + 1) % r->size;
    r->count--;
    return f;
}

/* Caller holds the lock. */
static void release(gs_cap_pipe *p, pframe *f)
{
    p->free_list[p->nfree++] = f;
}

static void push_locked(gs_cap_pipe *p, ring *r, pthread_cond_t *cv, pframe *f)
{
    pframe *dropped = ring_push(r, f);
    if (dropped) {
        release(p, dropped);
        p->drops++;
    }
    pthread_cond_signal(cv);
}

/* Waits for a frame in r; NULL when stopping. */
static pframe *wait_pop(gs_cap_pipe *p, ring *r, pthread_cond_t *cv)
{
    pthread_mutex_lock(&p->lock);
    pframe *f;
    while (!(f = ring_pop(r)) && !atomic_load(&p->stop))
        pthread_cond_wait(cv, &p->lock);
    pthread_mutex_unlock(&p->lock);
    return f;
}

static void logf_(gs_cap_pipe *p, gs_cap_pipe_event ev, const char *msg)
{
    if (p->cfg.log)
        p->cfg.log(p->cfg.log_user, ev, msg);
}

static int fill(pframe *f, const gs_cap_frame *src)
{
    size_t need = (size_t)src->height * src->stride;
    if (need > f->cap) {
        uint8_t *q = realloc(f->rgb, need);
        if (!q)
            return -1;
        f->rgb = q;
        f->cap = need;
    }
    memcpy(f->rgb, src->rgb, need);
    f->width = src->width;
    f->height = src->height;
    f->t_capture = src->t_capture_ns;
    return 0;
}

static void streaming_message(gs_cap_pipe *p)
{
    gs_cap_format fmt;
    gs_cap_stats st;
    char msg[200];
    if (gs_cap_get_format(p->cfg.cap, &fmt) != GS_OK)
        return;
    gs_cap_get_stats(p->cfg.cap, &st);
    snprintf(msg, sizeof msg,
             "streaming %dx%d %s at %d/%d fps, %d buffers, first frame %.1f ms after open",
             fmt.width, fmt.height, fmt.pixfmt == GS_CAP_PIX_MJPEG ? "MJPEG" : "YUYV",
             fmt.fps_num, fmt.fps_den ? fmt.fps_den : 1, fmt.nbuffers,
             (double)st.first_frame_ns / 1e6);
    logf_(p, GS_CAP_EV_STREAMING, msg);
}

static void *capture_thread(void *arg)
{
    gs_cap_pipe *p = arg;
    int up = -1; /* unknown: the first failure is reported too */
    while (!atomic_load(&p->stop)) {
        gs_cap_frame cf;
        gs_error e = {0};
        if (gs_cap_grab(p->cfg.cap, &cf, &e) != GS_OK) {
            if (up != 0)
                logf_(p, GS_CAP_EV_LOST, e.msg);
            up = 0;
            continue;
        }
        if (up != 1)
            streaming_message(p);
        up = 1;
        pthread_mutex_lock(&p->lock);
        pframe *f = p->nfree ? p->free_list[--p->nfree] : NULL;
        pthread_mutex_unlock(&p->lock);
        if (!f)
            continue; /* cannot happen with the pool sized as above */
        int ok = fill(f, &cf) == 0;
        int64_t t = now(p);
        pthread_mutex_lock(&p->lock);
        gs_cap_get_stats(p->cfg.cap, &p->cap_stats);
        if (ok) {
            p->in++;
            record(&p->w_capture, t - f->t_capture);
            push_locked(p, &p->r_proc, &p->to_proc, f);
        } else {
            release(p, f);
        }
        pthread_mutex_unlock(&p->lock);
    }
    return NULL;
}

static void *process_thread(void *arg)
{
    gs_cap_pipe *p = arg;
    pframe *f;
    while ((f = wait_pop(p, &p->r_proc, &p->to_proc))) {
        f->t_proc0 = now(p);
        gs_error e = {0};
        if (p->cfg.stage.process(p->cfg.stage.ctx, f->rgb, 3 * (size_t)f->width, f->width,
                                 f->height, f->t_capture, &e) != GS_OK)
            logf_(p, GS_CAP_EV_STAGE_ERROR, e.msg);
        int64_t t = now(p);
        pthread_mutex_lock(&p->lock);
        record(&p->w_process, t - f->t_proc0);
        push_locked(p, &p->r_out, &p->to_out, f);
        pthread_mutex_unlock(&p->lock);
    }
    return NULL;
}

/* Like wait_pop, but gives up after ms milliseconds (*timed_out set). */
static pframe *wait_pop_for(gs_cap_pipe *p, ring *r, pthread_cond_t *cv, int ms, int *timed_out)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    ts.tv_sec += ms / 1000;
    ts.tv_nsec += (long)(ms % 1000) * 1000000L;
    if (ts.tv_nsec >= 1000000000L) {
        ts.tv_sec++;
        ts.tv_nsec -= 1000000000L;
    }
    *timed_out = 0;
    pthread_mutex_lock(&p->lock);
    pframe *f;
    while (!(f = ring_pop(r)) && !atomic_load(&p->stop))
        if (pthread_cond_timedwait(cv, &p->lock, &ts) != 0) {
            *timed_out = 1;
            break;
        }
    pthread_mutex_unlock(&p->lock);
    return f;
}

/* No frame for placeholder_ms (the camera is gone, or reopening): keep the
 * loopback alive with the "no video" frame, about 10 per second. */
static void write_placeholder(gs_cap_pipe *p)
{
    gs_error e = {0};
    if (gs_cap_out_write_placeholder(p->cfg.out, &e) != GS_OK)
        return;
    pthread_mutex_lock(&p->lock);
    p->placeholders++;
    pthread_mutex_unlock(&p->lock);
}

static void *output_thread(void *arg)
{
    gs_cap_pipe *p = arg;
    pframe *f;
    int failing = 0, idle_ms = 0;
    int hold = p->cfg.placeholder_ms ? p->cfg.placeholder_ms : 500;
    for (;;) {
        int timed_out = 0;
        if (p->cfg.out && hold > 0)
            f = wait_pop_for(p, &p->r_out, &p->to_out, idle_ms >= hold ? 100 : hold - idle_ms,
                             &timed_out);
        else
            f = wait_pop(p, &p->r_out, &p->to_out);
        if (timed_out) {
            idle_ms = idle_ms >= hold ? idle_ms + 100 : hold;
            write_placeholder(p);
            continue;
        }
        if (!f)
            break;
        idle_ms = 0;
        int64_t t0 = now(p);
        gs_error e = {0};
        int r = p->cfg.out ? gs_cap_out_write(p->cfg.out, f->rgb, 3 * (size_t)f->width,
                                              f->width, f->height, &e)
                           : GS_OK;
        if (r != GS_OK && !failing)
            logf_(p, GS_CAP_EV_OUT_ERROR, e.msg);
        failing = r != GS_OK;
        int64_t t = now(p);
        pthread_mutex_lock(&p->lock);
        if (r == GS_OK) {
            p->out++;
            record(&p->w_output, t - t0);
            record(&p->w_total, t - f->t_capture);
        }
        release(p, f);
        pthread_mutex_unlock(&p->lock);
    }
    return NULL;
}

void gs_cap_pipe_stop(gs_cap_pipe *p)
{
    if (!p)
        return;
    pthread_mutex_lock(&p->lock);
    atomic_store(&p->stop, 1);
    pthread_cond_broadcast(&p->to_proc);
    pthread_cond_broadcast(&p->to_out);
    pthread_mutex_unlock(&p->lock);
    for (int i = 0; i < p->nthreads; i++)
        pthread_join(p->threads[i], NULL);
    for (int i = 0; i < MAX_FRAMES; i++)
        free(p->frames[i].rgb);
    pthread_cond_destroy(&p->to_proc);
    pthread_cond_destroy(&p->to_out);
    pthread_mutex_destroy(&p->lock);
    free(p);
}

int gs_cap_pipe_start(const gs_cap_pipe_config *cfg, gs_cap_pipe **out, gs_error *err)
{
    if (!cfg || !out || !cfg->cap || !cfg->stage.process)
        return gs_error_set(err, GS_ERR_ARG, "pipeline: capture and stage needed");
    int size = cfg->ring ? cfg->ring : 2;
    if (cfg->placeholder_ms > 60000)
        return gs_error_set(err, GS_ERR_ARG, "pipeline: placeholder_ms over 60000");
    if (size < 1 || size > MAX_RING)
        return gs_error_set(err, GS_ERR_ARG, "pipeline: ring %d outside 1..%d", size, MAX_RING);
    gs_cap_pipe *p = calloc(1, sizeof *p);
    if (!p)
        return gs_error_set(err, GS_ERR_NOMEM, "pipeline: out of memory");
    p->cfg = *cfg;
    p->ops = cfg->clock ? cfg->clock : gs_cap_ops_system();
    p->r_proc.size = p->r_out.size = size;
    for (int i = 0; i < 2 * size + 4; i++)
        p->free_list[p->nfree++] = &p->frames[i];
    atomic_init(&p->stop, 0);
    pthread_mutex_init(&p->lock, NULL);
    pthread_cond_init(&p->to_proc, NULL);
    pthread_condattr_t ca; /* timed waits on the monotonic clock */
    pthread_condattr_init(&ca);
    pthread_condattr_setclock(&ca, CLOCK_MONOTONIC);
    pthread_cond_init(&p->to_out, &ca);
    pthread_condattr_destroy(&ca);
    void *(*fns[3])(void *) = {output_thread, process_thread, capture_thread};
    for (int i = 0; i < 3; i++) {
        if (pthread_create(&p->threads[i], NULL, fns[i], p) != 0) {
            gs_cap_pipe_stop(p);
            return gs_error_set(err, GS_ERR_NOMEM, "pipeline: cannot start threads");
        }
        p->nthreads++;
    }
    *out = p;
    return GS_OK;
}

static int cmp_double(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

/* Nearest-rank percentiles of the window (sorted copy in tmp). */
static gs_cap_latency summarize(const window *w, double *tmp)
{
    gs_cap_latency l = {0, 0, 0};
    if (!w->n)
        return l;
    memcpy(tmp, w->ms, (size_t)w->n * sizeof *tmp);
    qsort(tmp, (size_t)w->n, sizeof *tmp, cmp_double);
    l.p50_ms = tmp[(w->n - 1) * 50 / 100];
    l.p99_ms = tmp[(w->n - 1) * 99 / 100];
    l.max_ms = tmp[w->n - 1];
    return l;
}

void gs_cap_pipe_get_stats(gs_cap_pipe *p, gs_cap_pipe_stats *s)
{
    static const gs_cap_latency zero;
    window *copy = malloc(4 * sizeof *copy);
    double *tmp = malloc(GS_CAP_PIPE_WINDOW * sizeof *tmp);
    pthread_mutex_lock(&p->lock);
    s->in = p->in;
    s->out = p->out;
    s->ring_drops = p->drops;
    s->placeholders = p->placeholders;
    s->cap = p->cap_stats;
    if (copy) {
        copy[0] = p->w_capture;
        copy[1] = p->w_process;
        copy[2] = p->w_output;
        copy[3] = p->w_total;
    }
    pthread_mutex_unlock(&p->lock);
    int ok = copy && tmp;
    s->capture = ok ? summarize(&copy[0], tmp) : zero;
    s->process = ok ? summarize(&copy[1], tmp) : zero;
    s->output = ok ? summarize(&copy[2], tmp) : zero;
    s->total = ok ? summarize(&copy[3], tmp) : zero;
    free(copy);
    free(tmp);
}
