/* gazesplatd internals shared by its files: the server's, connections',
 * jobs' and frames' types, and what each file offers the others (server.c,
 * the event loop side, out.c, frames out, and sink.c, a job's results,
 * have headers of their own: server.h, out.h and sink.h).
 *
 * Threads: one loop thread owns connections, listeners and every
 * gsd_conn / gsd_job field marked (loop). Workers own a job while running
 * it and talk back only through its sink (sink.h); the server's sink hands
 * frames to the loop through its post queue (a locked list + ev_wake). A job
 * is created and freed by the loop thread, which frees it when its final
 * frame comes back, so a worker never races with a closing connection. */
#ifndef GSD_DAEMON_H
#define GSD_DAEMON_H

#include <pthread.h>
#include <stdatomic.h>
#include <stddef.h>
#include <stdint.h>

#include "cache.h"
#include "config.h"
#include "ev.h"
#include "gs_msg.h"
#include "sd.h"
#include "sink.h"

#ifndef GSD_VERSION /* the project's version (CMakeLists.txt) */
#define GSD_VERSION "0.1.0"
#endif

typedef struct gsd_server gsd_server;
typedef struct gsd_conn gsd_conn;
typedef struct gsd_live gsd_live;

/* Health.State values. */
enum { GSD_LOADING = 0, GSD_READY = 1, GSD_FAILED = 2, GSD_DRAINING = 3 };

/* Counters reported by STATS; names in server.c. Atomic: workers add too. */
typedef struct gsd_counters {
    atomic_ullong conn_accepted, conn_rejected, conn_closed;
    atomic_ullong frames_in, frames_out, bytes_in, bytes_out;
    atomic_ullong protocol_errors, request_errors, timeouts;
    atomic_ullong req_hello, req_health, req_stats, req_fit, req_redirect, req_cancel, req_sleep;
    atomic_ullong busy, cancelled, deadline_exceeded;
    atomic_ullong fits, fits_cached, images_out, images_dropped, jobs_done;
    atomic_ullong renders_full, renders_incremental;
    atomic_ullong model_loads, model_load_failures, reloads, cache_saves, cache_save_failures;
    atomic_ullong finetunes, tuned_swaps, tuned_saves, tuned_save_failures;
    atomic_ullong renders_transfer, input_saves, input_save_failures;
    atomic_ullong output_waits; /* renders held back by unread output */
} gsd_counters;

/* A unit of compute work. */
typedef struct gsd_job {
    struct gsd_job *qnext;       /* work queue link (queue lock) */
    struct gsd_job *cnext;       /* connection's in-flight list (loop) */
    gsd_conn *conn;              /* (loop) NULL once the connection closed */
    uint16_t type;               /* FRAME_FIT, FRAME_REDIRECT, FRAME_SLEEP */
    uint16_t version;
    uint32_t request_id;
    uint8_t key[GS_FRAME_KEY_SIZE];
    int64_t deadline_ms;         /* monotonic */
    int64_t enqueued_ms;
    int64_t started_ms;          /* monotonic, when a worker took it; 0 before */
    int skips;                   /* times a later job was taken first (queue lock) */
    atomic_int stop;             /* 0, or ERR_CANCELLED / ERR_DEADLINE / ERR_SHUTTING_DOWN */
    gsd_server *srv;
    uint32_t est_ms;             /* estimated run time, for BUSY hints (work.c) */
    uint32_t targets;            /* REDIRECT: targets; for the per-target cost */
    int inline_fit;              /* REDIRECT with an image: fits first */
    /* Output pacing (wait_output, compute.c): bytes of this job's frames not yet
     * written to the peer, and whether its connection's output is over
     * max_output_kb (set by the loop). */
    atomic_size_t out_bytes;
    atomic_int conn_paused;
    /* For the request's log line (set by the worker before its final
     * frame; read by the loop after it): the result (0 or an ErrorCode),
     * fit iterations, fine-tuning steps, images sent, answered from the
     * cache; and who asked. */
    int result, iters, ft_steps, images, cached;
    int refusal;                 /* ERR_FACE_REFUSED: the gs_face_refusal */
    char peer[64];
    int max_side;                /* image limits when the job was accepted */
    size_t max_pixels;
    double finetune_lr;          /* the server's finetune_lr when the job was accepted */
    ProtobufCMessage *req;       /* unpacked request, owned */
    gsd_sink sink;               /* where its results go (set when it is made) */
} gsd_job;

/* A frame on its way out; a connection's output queue is a list of these. */
typedef struct gsd_out {
    struct gsd_out *next;
    gsd_job *job;   /* the job it belongs to, or NULL */
    int final;      /* last frame of job: the loop frees the job */
    uint64_t job_ms; /* final only: run time, for retry-after estimates */
    int request_error; /* an ERROR ending a request: counted in request_errors when queued */
    size_t len;
    uint8_t data[];
} gsd_out;

/* Work queue + workers (work.c). */
typedef struct gsd_work {
    pthread_mutex_t mu;
    pthread_cond_t cv;
    gsd_job *head, *tail;
    int length, depth;
    int running;      /* jobs being run */
    int stopping;
    int nworkers;
    int planned;                 /* workers started (set before the first) */
    pthread_t *threads;
    /* per worker: the running job's start and estimate (start 0: idle) */
    int64_t run_start[64];
    uint32_t run_est[64];
} gsd_work;

/* A loaded model with its identity; refcounted so a SIGHUP reload can swap
 * it while workers finish with the old one (compute.c). */
typedef struct gsd_model gsd_model;

typedef struct gsd_listener {
    ev_watch w;
    gsd_server *srv;
    int fd;
    int is_tcp;
    int owned;        /* we bound it: unlink the path at exit */
    char path[108];
} gsd_listener;

/* One figure of STATS (and of the metrics endpoint). */
typedef struct gsd_stat {
    const char *name;
    uint64_t value;
    int gauge; /* 1: a level now; 0: a count that only grows */
} gsd_stat;
#define GSD_STATS_MAX 96

/* Request types the latency histograms keep (metrics.c). */
enum { GSD_REQ_FIT, GSD_REQ_REDIRECT, GSD_REQ_SLEEP, GSD_REQ_KINDS };
#define GSD_HIST_BUCKETS 14
typedef struct gsd_hist {
    uint64_t bucket[GSD_HIST_BUCKETS]; /* counts at or under each bound (not cumulative) */
    uint64_t count;
    double sum_s;
} gsd_hist;

struct gsd_server {
    gsd_config cfg;           /* (loop) current configuration */
    ev_loop *loop;
    gsd_counters ctr;
    int64_t started_ms;

    gsd_listener listeners[GSD_MAX_LISTEN + 2];
    int nlisteners;
    ev_watch sig_watch;       /* read end of the signal pipe */
    int sig_wr;
    gsd_conn *conns;          /* (loop) list of open connections */
    gsd_conn *dead;           /* (loop) closed, freed after the batch */
    int nconns;
    uint64_t next_conn_id;

    atomic_int state;         /* GSD_LOADING .. */
    int reloading;            /* (loop) a model reload is running */
    int ready_sent;           /* (loop) READY=1 sent */
    char detail[256];         /* (loop) health detail */
    double job_ms_avg;        /* (loop) moving average of job time */
    /* (loop) moving averages of what jobs cost, for BUSY hints: a FIT, one
     * target of a REDIRECT by key */
    double cost_fit_ms, cost_target_ms;
    /* Output frames alive (queued in workers' posts and connections) and
     * the budget (output_budget_mb) over which renders wait. */
    atomic_size_t out_total;
    atomic_size_t out_budget;
    int64_t drain_deadline;   /* (loop) */
    int exit_code;

    /* worker -> loop frames */
    pthread_mutex_t post_mu;
    gsd_out *post_head, *post_tail;

    gsd_work work;
    gsd_cache *cache;
    gsd_cache *tuned;         /* fine-tuned parameter blocks by subject key */
    gsd_cache *inputs;        /* kept FIT inputs (keep_image) by subject key */
    pthread_mutex_t persist_mu; /* one writer of the cache file at a time */
    char state_dir[GSD_STR_MAX];

    /* model (compute.c) */
    pthread_mutex_t model_mu;
    gsd_model *model;         /* current, or NULL */
    pthread_t loader;
    int loader_running;       /* (loop) */
    atomic_int load_done;     /* set by the loader thread */
    int load_status;          /* loader result (read after load_done) */
    char load_msg[1024];
    gsd_model *loaded;        /* loader result */

    /* photo input (compute.c): the landmark model, loaded once with the
     * first model; detectors are per worker (not re-entrant) */
    struct gs_face_shape_model *face_sp;
    atomic_int photo_state;   /* 0 not known yet, 1 available, -1 not */
    char photo_msg[300];      /* why not (loop thread) */
    char face_cascade[GSD_STR_MAX]; /* fixed at start */

    gsd_live *live;           /* the hosted live pipeline (live.c), or NULL */

    /* metrics endpoint (metrics.c; loop thread) */
    ev_watch metrics_w;
    struct gsd_mconn *mconns;
    int nmconns;
    char metrics_path[GSD_STR_MAX]; /* unix: the socket file to unlink */
    gsd_hist hist[GSD_REQ_KINDS];

    void (*on_sighup)(gsd_server *s); /* set by main: re-reads the config */
    ev_fn on_accept;          /* listeners' callback (server.c) */
    void *app;
    uint64_t watchdog_usec;
    int64_t next_watchdog, next_extend;
};

/* ---- work.c ---- */
int gsd_work_start(gsd_server *s, int nworkers, int depth);
/* Queues a job; -1 when the queue is full (caller answers BUSY). */
int gsd_work_push(gsd_server *s, gsd_job *job);
void gsd_work_lengths(gsd_server *s, int *length, int *running);
/* Estimated milliseconds of work now (queued jobs' est_ms plus what the
 * running ones have left): *first until the first running job ends (a
 * queue slot opens), *total until everything is done. */
void gsd_work_backlog(gsd_server *s, int64_t now_ms, double *first, double *total);
void gsd_work_set_depth(gsd_server *s, int depth);
/* Stops and joins the workers; queued jobs are answered SHUTTING_DOWN. */
void gsd_work_stop(gsd_server *s);

/* ---- compute.c ---- */
/* Per-worker state (model context, thread pool). */
typedef struct gsd_worker gsd_worker;
gsd_worker *gsd_worker_create(gsd_server *s, int index);
/* Threads of each worker's pool: `threads`, or the CPUs over the workers. */
int gsd_pool_threads(const gsd_config *cfg);
void gsd_worker_destroy(gsd_worker *w);
/* Runs a job, emitting its results through job->sink; the last one is
 * final. */
void gsd_worker_run(gsd_worker *w, gsd_job *job);
/* 1 when the worker rendered the job's subject lately (its renders are
 * kept: REDIRECT renders incrementally there). Called under the queue
 * lock; reads only the worker's own recent keys and the job's key. */
int gsd_worker_prefers(const gsd_worker *w, const gsd_job *job);

/* Starts loading cfg.model in a background thread. Returns the Health
 * state the server takes now (LOADING until done, READY while a reload
 * runs, FAILED without a model) with its detail, or -1 when a load is
 * already running (nothing changes). */
int gsd_model_start_load(gsd_server *s, char *detail, size_t cap);
/* Called by the loop when load_done is set: installs the model. Returns
 * the state to take and its detail; *installed is 1 when a new model is
 * in (the live stage attaches to it). */
int gsd_model_finish_load(gsd_server *s, char *detail, size_t cap, int *installed);
void gsd_model_release_all(gsd_server *s);
/* Normalized face size of the current model, 0 when none; its id. */
int gsd_model_image_size(gsd_server *s, char id[33]);
/* Loads the cache file for the current model id (model_ref.c owns ids). */
void gsd_cache_restore(gsd_server *s);
/* Saves the cache file; 0 or -1 (logged). */
int gsd_cache_persist(gsd_server *s);

/* A reference to the current model for a long-lived user (the live
 * stage): NULL when none is loaded. Release with gsd_model_put. */
struct gs_model;
const struct gs_model *gsd_model_get(gsd_server *s, gsd_model **ref);
void gsd_model_put(gsd_model *ref);

/* ---- live.c: the live pipeline, when live.device is set ---- */
/* Starts capture -> pass-through -> loopback; 0 or -1 with msg. */
int gsd_live_start(gsd_server *s, char *msg, size_t cap);
/* The first model is in: attaches the eye-contact stage (loop thread). */
void gsd_live_model_ready(gsd_server *s);
void gsd_live_stop(gsd_server *s);
/* LIVE_POLICY: 0 with *out filled, or an ErrorCode with a message. */
int gsd_live_policy(gsd_server *s, const Gazesplat__LivePolicyRequest *r, Gazesplat__LivePolicy *out,
                    char *msg, size_t cap);
/* LIVE_STATUS; pol, head and corr are storage for the sub-messages. */
void gsd_live_status(gsd_server *s, Gazesplat__LiveStatus *m, Gazesplat__LivePolicy *pol,
                     Gazesplat__Angles *head, Gazesplat__Angles *corr);

/* ---- validate.c: 0 or an ErrorCode with a message in msg ---- */
int gsd_check_image(const gsd_server *s, const Gazesplat__Image *img, char *msg, size_t cap);
/* Width and height that a PNG (IHDR) or JPEG (first SOF) declares, found
 * by the data's own signature whatever the declared format: 0, or -1 when
 * there is no such header (the decoder then says what is wrong). */
int gsd_image_probe(const uint8_t *p, size_t n, uint32_t *w, uint32_t *h);
/* 1 when s[0..n) is strict UTF-8: no overlong forms, surrogates or code
 * points over U+10FFFF. */
int gsd_utf8_valid(const char *s, size_t n);
int gsd_check_deadline(const gsd_server *s, uint32_t ms, char *msg, size_t cap);
/* Images of one FIT (FitRequest.image and more_images): GS_FIT_IMAGES_MAX. */
#define GSD_FIT_IMAGES_MAX 16
int gsd_check_fit(const gsd_server *s, const Gazesplat__FitRequest *r, char *msg, size_t cap);
int gsd_check_redirect(const gsd_server *s, const gs_frame_header *h,
                       const Gazesplat__RedirectRequest *r, char *msg, size_t cap);

/* ---- metrics.c: the Prometheus endpoint (config `metrics`) ---- */
int gsd_metrics_setup(gsd_server *s, char *msg, size_t cap);
void gsd_metrics_close(gsd_server *s);
/* Closes scrapes older than header_timeout_ms (loop tick). */
void gsd_metrics_tick(gsd_server *s, int64_t now);
/* A finished compute request of kind GSD_REQ_* that took `seconds`. */
void gsd_metrics_observe(gsd_server *s, int kind, double seconds);

/* ---- listen.c ---- */
int gsd_listen_setup(gsd_server *s, char *msg, size_t cap);
/* A listening socket for addr, "unix:PATH" (file mode `mode`) or
 * "HOST:PORT" (loopback unless allow_remote): the fd, or -1 with msg. */
int gsd_listen_open(const char *addr, int mode, int allow_remote, char *msg, size_t cap);
/* Closes the listeners; unlinks only sockets this process bound. */
void gsd_listen_close(gsd_server *s);

#endif
