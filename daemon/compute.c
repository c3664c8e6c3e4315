/* gazesplatd compute side: the model (load, reload, refcount), the worker
 * state (model context + thread pool) and the jobs: FIT, REDIRECT, SLEEP.
 *
 * Everything that touches the model API (gazesplat/model.h) and the face
 * pipeline (gazesplat/face.h: photo -> normalized face, paste-back) is
 * here. */
#define _GNU_SOURCE
#include <ctype.h>
#include <dirent.h>
#include <errno.h>
#include <fcntl.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <time.h>
#include <unistd.h>
#ifdef __GLIBC__
#include <malloc.h>
#endif

#include "gazesplat/clock.h"
#include "gazesplat/face.h"
#include "gazesplat/geom.h"
#include "gazesplat/image_io.h"
#include "gazesplat/pool.h"
#include "log.h"
#include "daemon.h"
#include "hash.h"
#include "model_ref.h"
#include "out.h"
#include "sink.h"
#include "store.h"
#include "gazesplat/model.h"
#include "gazesplat/redirect.h"

#define E(x) GAZESPLAT__ERROR_CODE__##x
#define T(x) GAZESPLAT__FRAME_TYPE__FRAME_##x
#define DEG (M_PI / 180.0)
#define GSD_RECENT_MAX 64

struct gsd_worker {
    gsd_server *srv;
    int index;
    gs_pool *pool;
    gs_face_detector *det; /* loaded at the first photo (one per thread) */
    gsd_model *model; /* the model ctx was made for (a reference) */
    gs_model_ctx *ctx;
    /* the subject of the last FIT, rendered once its reply is out so that
     * the context keeps its render for incremental REDIRECTs */
    int prime, prime_slot; /* prime_slot: a tuned slot, or -1 */
    gs_subject prime_subj;
    /* a fit or fine-tune ran: once the job is done, the allocator gives
     * the pages it freed back to the system (worker_release) */
    int release;
    /* Fine-tuned subjects render with clones of the model holding their
     * tuned tensors (gs_model_tuned_apply): tuned_subjects slots per
     * worker, each a clone and its context (sharing ctx's render
     * scratch), made at the first need, the least recently used one
     * switched to a subject no slot holds. */
    struct tuned_slot {
        gs_model *m;
        gs_model_ctx *ctx;
        int has;
        uint8_t key[GS_FRAME_KEY_SIZE];
        uint64_t sum;
        uint64_t used;
    } slots[GSD_TUNED_SLOTS_MAX];
    int nslots;
    uint64_t tick;
    /* keys of the subjects rendered lately (a ring, newest at recent_n - 1
     * modulo GSD_RECENT_MAX): the queue prefers giving their REDIRECTs to
     * this worker (work.c) */
    uint8_t recent[GSD_RECENT_MAX][GS_FRAME_KEY_SIZE];
    int recent_n, recent_cap;
};

/* ---- workers --------------------------------------------------------------- */

int gsd_pool_threads(const gsd_config *cfg)
{
    if (cfg->threads > 0)
        return cfg->threads;
    long cpus = sysconf(_SC_NPROCESSORS_ONLN);
    int threads = (int)(cpus > 0 ? cpus : 1) / cfg->workers;
    return threads < 1 ? 1 : threads;
}

gsd_worker *gsd_worker_create(gsd_server *s, int index)
{
    gsd_worker *w = calloc(1, sizeof *w);
    if (!w)
        return NULL;
    w->srv = s;
    w->index = index;
    int threads = gsd_pool_threads(&s->cfg);
    w->pool = threads > 1 ? gs_pool_create(threads) : NULL;
    w->recent_cap = s->cfg.sweep_subjects < 1 ? 1
                    : s->cfg.sweep_subjects > GSD_RECENT_MAX ? GSD_RECENT_MAX
                    : s->cfg.sweep_subjects;
    w->nslots = s->cfg.tuned_subjects < 1 ? 1
                : s->cfg.tuned_subjects > GSD_TUNED_SLOTS_MAX ? GSD_TUNED_SLOTS_MAX
                : s->cfg.tuned_subjects;
    return w;
}

static void worker_drop_model(gsd_worker *w)
{
    gs_model_ctx_destroy(w->ctx);
    w->ctx = NULL;
    for (int i = 0; i < GSD_TUNED_SLOTS_MAX; i++) {
        gs_model_ctx_destroy(w->slots[i].ctx);
        gs_model_destroy(w->slots[i].m);
        memset(&w->slots[i], 0, sizeof w->slots[i]);
    }
    gsd_model_unref(w->model);
    w->model = NULL;
}

void gsd_worker_destroy(gsd_worker *w)
{
    if (!w)
        return;
    worker_drop_model(w);
    gs_face_detector_destroy(w->det);
    gs_pool_destroy(w->pool);
    free(w);
}

static int key_zero(const uint8_t *k)
{
    for (int i = 0; i < GS_FRAME_KEY_SIZE; i++)
        if (k[i])
            return 0;
    return 1;
}

static int recent_find(const gsd_worker *w, const uint8_t *key)
{
    int n = w->recent_n < w->recent_cap ? w->recent_n : w->recent_cap;
    for (int i = 0; i < n; i++)
        if (!memcmp(w->recent[i], key, GS_FRAME_KEY_SIZE))
            return i;
    return -1;
}

int gsd_worker_prefers(const gsd_worker *w, const gsd_job *j)
{
    if (j->type != T(REDIRECT) || key_zero(j->key))
        return 0;
    const Gazesplat__RedirectRequest *r = (const Gazesplat__RedirectRequest *)j->req;
    return !r->image && recent_find(w, j->key) >= 0;
}

/* Why a job must stop now (0: go on). */
static int job_stop(gsd_job *j)
{
    int st = atomic_load(&j->stop);
    if (st)
        return st;
    return gs_clock_ms() > j->deadline_ms ? E(ERR_DEADLINE) : 0;
}

/* Before the next image of a REDIRECT: waits while the job's connection
 * has max_output_kb unsent, or the server's unsent output is over
 * output_budget_mb while this job has some of it, so a client that does
 * not read holds back its own renders, never the server's memory. Returns
 * 0, or the job's stop reason (CANCEL, deadline, stopping). */
static int wait_output(gsd_server *s, gsd_job *j)
{
    for (int waited = 0;; waited = 1) {
        int why = job_stop(j);
        if (why)
            return why;
        if (!atomic_load(&j->conn_paused) &&
            (atomic_load(&j->out_bytes) == 0 || atomic_load(&s->out_total) <= atomic_load(&s->out_budget)))
            return 0;
        if (!waited)
            atomic_fetch_add(&s->ctr.output_waits, 1);
        struct timespec ts = {0, 2 * 1000000L};
        nanosleep(&ts, NULL);
    }
}

/* The fit's and fine-tune's cancel callback (gs_fit_options.cancel):
 * polled every iteration, so CANCEL, a closed connection, the deadline
 * and a stopping server end a fit within one iteration. */
static int job_cancelled(void *arg)
{
    return job_stop(arg) != 0;
}

/* 1 for the codes a stopped job answers with (emit_stop). */
static int is_stop_code(int e)
{
    return e == E(ERR_CANCELLED) || e == E(ERR_DEADLINE) || e == E(ERR_SHUTTING_DOWN);
}

/* Ends a stopped job: its final error, counted in STATS. */
static void emit_stop(gsd_server *s, gsd_job *j, int why)
{
    atomic_fetch_add(why == E(ERR_DEADLINE) ? &s->ctr.deadline_exceeded : &s->ctr.cancelled, 1);
    gsd_emit_error(j, why, why == E(ERR_DEADLINE) ? "deadline passed"
                           : why == E(ERR_CANCELLED) ? "cancelled" : "server stopping");
}

/* Ends a job that failed with ErrorCode e (text msg): a stop code the way
 * emit_stop says it, any other with msg. */
static void emit_failure(gsd_server *s, gsd_job *j, int e, const char *msg)
{
    if (is_stop_code(e))
        emit_stop(s, j, e);
    else
        gsd_emit_error(j, e, "%s", msg);
}

static void run_sleep(gsd_server *s, gsd_job *j, int64_t t0)
{
    const Gazesplat__Sleep *r = (const Gazesplat__Sleep *)j->req;
    int64_t end = t0 + r->ms;
    while (gs_clock_ms() < end) {
        int why = job_stop(j);
        if (why) {
            emit_stop(s, j, why);
            return;
        }
        struct timespec ts = {0, 5 * 1000000L};
        nanosleep(&ts, NULL);
    }
    Gazesplat__Done d = GAZESPLAT__DONE__INIT;
    d.seconds = (double)(gs_clock_ms() - t0) / 1000.0;
    gsd_emit_done(j, T(SLEEP_OK), &d.base);
}

/* ---- model jobs ------------------------------------------------------------ */

/* Notes that this worker's context now keeps the render of `key`. */
static void recent_add(gsd_worker *w, const uint8_t *key)
{
    if (key_zero(key) || recent_find(w, key) >= 0)
        return;
    memcpy(w->recent[w->recent_n % w->recent_cap], key, GS_FRAME_KEY_SIZE);
    w->recent_n++;
}

/* Makes sure the worker's context belongs to the current model. */
static int worker_bind_model(gsd_worker *w)
{
    gsd_model *m = gsd_model_acquire(w->srv);
    if (!m)
        return -1;
    if (m == w->model) {
        gsd_model_unref(m);
        return 0;
    }
    worker_drop_model(w);
    w->model = m;
    w->ctx = gs_model_ctx_create(m->m);
    w->recent_n = 0; /* a new context keeps nothing */
    w->prime = 0;
    if (w->ctx)
        gs_model_ctx_set_sweep_cache(w->ctx, w->recent_cap, NULL);
    return w->ctx ? 0 : -1;
}

/* Decodes a request image (PNG, JPEG or raw) into 8-bit RGB. */
static int decode_image(gsd_job *j, const Gazesplat__Image *img, gs_io_image *out, char *msg, size_t cap)
{
    memset(out, 0, sizeof *out);
    if (img->format == GAZESPLAT__IMAGE_FORMAT__FORMAT_RAW_RGB8) {
        out->width = (int)img->width;
        out->height = (int)img->height;
        out->stride = (size_t)img->width * 3;
        out->data = malloc(out->stride * (size_t)out->height);
        if (!out->data) {
            snprintf(msg, cap, "out of memory");
            return E(ERR_INTERNAL);
        }
        for (int y = 0; y < out->height; y++)
            memcpy(out->data + (size_t)y * out->stride, img->data.data + (size_t)y * img->stride, out->stride);
        return 0;
    }
    gs_io_image_limits lim = {img->data.len, j->max_pixels, j->max_side};
    gs_error err;
    gs_error_clear(&err);
    int r = gs_io_image_decode(img->data.data, img->data.len, &lim, out, &err);
    if (r != GS_OK) {
        snprintf(msg, cap, "image: %s", err.msg);
        return r == GS_ERR_LIMIT ? E(ERR_IMAGE_TOO_LARGE) : E(ERR_BAD_IMAGE);
    }
    return 0;
}

_Static_assert((int)GAZESPLAT__FACE_REFUSAL__REFUSAL_HEAD_POSE == (int)GS_FACE_REFUSED_HEAD_POSE &&
                   (int)GAZESPLAT__FACE_REFUSAL__REFUSAL_EYES_CLOSED == (int)GS_FACE_REFUSED_EYES_CLOSED &&
                   (int)GAZESPLAT__FACE_REFUSAL__REFUSAL_FLAT == (int)GS_FACE_REFUSED_FLAT &&
                   (int)GAZESPLAT__FACE_REFUSAL__REFUSAL_NOISE == (int)GS_FACE_REFUSED_NOISE,
               "FaceRefusal follows gs_face_refusal");

/* The library's answer for a request's input as the daemon's error:
 * ERR_NO_FACE, ERR_FACE_REFUSED (the refusal in the Error's field),
 * bad_image for a normalized face of another size, ERR_INTERNAL when a
 * stage could not run. On success moves the normalized face to *face. */
static int input_verdict(gsd_job *j, int rc, const gs_error *err, gs_redirect_input *p, gs_io_image *face,
                         int bad_image, char *msg, size_t cap)
{
    if (rc == GS_OK) {
        *face = p->norm;
        memset(&p->norm, 0, sizeof p->norm);
        return 0;
    }
    snprintf(msg, cap, "%s", err->msg);
    if (rc != GS_ERR_ARG)
        return E(ERR_INTERNAL);
    if (p->gate.refusal == GS_FACE_REFUSED_NO_FACE)
        return E(ERR_NO_FACE);
    if (p->gate.refusal != GS_FACE_USABLE) {
        j->refusal = (int)p->gate.refusal;
        return E(ERR_FACE_REFUSED);
    }
    return bad_image ? E(ERR_BAD_IMAGE) : E(ERR_INTERNAL);
}

/* The request's image as the normalized face the model fits (through the
 * face gate when face_gate is on); a photo is kept in *p for the fit
 * options and paste-back. */
static int input_face(gsd_worker *w, gsd_job *j, const Gazesplat__Image *img, const Gazesplat__Intrinsics *k,
                      gs_redirect_input *p, gs_io_image *face, char *msg, size_t cap)
{
    gsd_server *s = w->srv;
    const gs_model_info *info = &w->model->info;
    gs_io_image in = {0};
    gs_error err;
    gs_error_clear(&err);
    memset(p, 0, sizeof *p);
    memset(face, 0, sizeof *face);
    int e = decode_image(j, img, &in, msg, cap);
    if (e)
        return e;
    if (img->kind != GAZESPLAT__IMAGE_KIND__KIND_PHOTO)
        return input_verdict(j, gs_redirect_input_face(info, &in, s->cfg.face_gate, p, &err), &err, p, face, 1,
                             msg, cap);
    if (!s->face_sp || (!w->det && gs_face_detector_load(s->face_cascade, &w->det, &err) != GS_OK)) {
        snprintf(msg, cap, "photo input unavailable: %s", s->face_sp ? err.msg : "no landmark model");
        gs_io_image_free(&in);
        return E(ERR_PHOTO_UNSUPPORTED);
    }
    gs_redirect_photo_opts o;
    gs_redirect_photo_opts_default(&o);
    o.gate = s->cfg.face_gate;
    if (k) {
        double kk[9] = {k->fx, 0, k->cx, 0, k->fy, k->cy, 0, 0, 1};
        o.use_k = 1;
        memcpy(o.k, kk, sizeof kk);
    }
    return input_verdict(j, gs_redirect_input_photo(w->det, s->face_sp, info, &in, &o, p, &err), &err, p, face,
                         0, msg, cap);
}

/* What a FIT (or an inline REDIRECT) asks to fine-tune. */
typedef struct gsd_finetune {
    uint32_t steps; /* 0: none */
    unsigned parts; /* GS_FT_* */
    uint32_t outline; /* gs_finetune_options.outline_px */
    uint32_t no_mirror; /* !gs_finetune_options.mirror */
    double lr;          /* gs_finetune_options.lr: the request's, or the server's */
} gsd_finetune;

static gsd_finetune finetune_of(const gsd_job *j, uint32_t steps, const char *parts,
                                uint32_t outline, int no_mirror, double lr)
{
    gsd_finetune f = {steps, GS_FT_DEFAULT, steps ? outline : 0, steps && no_mirror,
                      steps ? (lr > 0 ? lr : j->finetune_lr) : 0};
    if (steps && parts && parts[0] && gs_finetune_parts_parse(parts, &f.parts, NULL) != GS_OK)
        f.parts = GS_FT_DEFAULT; /* validated on the loop thread already */
    return f;
}

/* What the subject key of a FIT without a chosen key covers; bump it
 * when that changes (keys of another version never meet, so subjects
 * cached under an older one are fitted again).
 * Version 1 hashed the fine-tuning fields only when they were set.
 * Version 2 hashed every field in one fixed layout, and the image count
 * (after a tag) only for a FIT of several images.
 * Version 3 hashes the image count after the model id always, with no
 * tag: one layout for one image or several. */
#define SUBJECT_KEY_VERSION 3u

static void key_u32(hash128 *h, uint32_t v)
{
    uint8_t b[4] = {(uint8_t)v, (uint8_t)(v >> 8), (uint8_t)(v >> 16), (uint8_t)(v >> 24)};
    hash_bytes(h, b, 4);
}

static void key_f64(hash128 *h, double v)
{
    uint64_t u = 0;
    if (v != 0) /* -0 and +0 ask for the same fit */
        memcpy(&u, &v, 8);
    key_u32(h, (uint32_t)u);
    key_u32(h, (uint32_t)(u >> 32));
}

/* The key a FIT (or inline REDIRECT) without one gets: BLAKE2b-128 of
 * everything that decides the fit, in one fixed layout led by its
 * version: the model, the input's kind (a photo fits with the landmarks'
 * head pose and the face mask, a normalized face with neither), the
 * normalized pixels, the mask, the known labels and head pose, the
 * iterations and the fine-tuning. The same input asked the same way maps
 * to the same subject; anything else to another. */
static void key_image(hash128 *hp, int is_photo, const gs_io_image *face, const gs_fit_options *opt)
{
    key_u32(hp, (uint32_t)is_photo);
    key_u32(hp, (uint32_t)face->width);
    key_u32(hp, (uint32_t)face->height);
    for (int y = 0; y < face->height; y++)
        hash_bytes(hp, face->data + (size_t)y * face->stride, (size_t)face->width * 3);
    key_u32(hp, opt->mask != NULL);
    if (opt->mask)
        hash_bytes(hp, opt->mask, (size_t)face->width * face->height);
    key_u32(hp, (uint32_t)opt->known_gaze);
    if (opt->known_gaze) {
        key_f64(hp, opt->gaze_pitch);
        key_f64(hp, opt->gaze_yaw);
    }
    key_u32(hp, (uint32_t)opt->known_head);
    for (int k = 0; opt->known_head && k < 9; k++)
        key_f64(hp, opt->head_R[k]);
    for (int k = 0; opt->known_head && k < 3; k++)
        key_f64(hp, opt->head_t[k]);
}

/* The record: the version, the model, the image count (1 but for a
 * multi-image FIT), each image's record as above in order, then the
 * iterations and the fine-tuning; so keys of different counts never
 * meet. */
static void content_key(const gsd_model *m, int n, const int *is_photo, const gs_io_image *face,
                        const gs_fit_options *opt, const gsd_finetune *ft, uint8_t key[16])
{
    static const char tag[] = "gazesplatd subject";
    hash128 h;
    hash_init(&h);
    hash_bytes(&h, tag, sizeof tag);
    key_u32(&h, SUBJECT_KEY_VERSION);
    hash_bytes(&h, m->id, 32);
    key_u32(&h, (uint32_t)n);
    for (int i = 0; i < n; i++)
        key_image(&h, is_photo[i], &face[i], &opt[i]);
    key_u32(&h, (uint32_t)opt[0].max_iters);
    key_u32(&h, ft->steps);
    key_u32(&h, ft->parts);
    key_u32(&h, ft->outline);
    key_u32(&h, ft->no_mirror);
    key_f64(&h, ft->lr);
    hash_out(&h, key);
}


static void head_rotation(const Gazesplat__Angles *a, double R[9])
{
    gs_geom_rot_from_pitchyaw(a->pitch_deg * DEG, a->yaw_deg * DEG, 0.0, R);
}

/* The slot holding subject key with block checksum sum, or -1. */
static int slot_find(const gsd_worker *w, const uint8_t key[16], uint64_t sum)
{
    for (int i = 0; i < w->nslots; i++)
        if (w->slots[i].has && !memcmp(w->slots[i].key, key, 16) && w->slots[i].sum == sum)
            return i;
    return -1;
}

/* The slot to give another subject: one not made yet, else the least
 * recently used; made ready (clone and context) here. Returns the slot or
 * -1 with msg. */
static int slot_take(gsd_worker *w, char *msg, size_t cap)
{
    int v = 0;
    for (int i = 1; i < w->nslots; i++)
        if ((w->slots[v].m && !w->slots[i].m) || (w->slots[i].m && w->slots[i].used < w->slots[v].used))
            v = i;
    struct tuned_slot *sl = &w->slots[v];
    gs_error err;
    gs_error_clear(&err);
    if (!sl->m && gs_model_clone(w->model->m, &sl->m, &err) != GS_OK) {
        snprintf(msg, cap, "fine-tuned subjects: %s", err.msg);
        return -1;
    }
    if (!sl->ctx) {
        if (!(sl->ctx = gs_model_ctx_create(sl->m))) {
            snprintf(msg, cap, "fine-tuned subjects: out of memory");
            return -1;
        }
        /* One subject per slot: a switch drops every kept render anyway. */
        gs_model_ctx_set_sweep_cache(sl->ctx, 1, NULL);
        /* The worker runs one job at a time: its contexts take turns with
         * one render scratch (about 26 MB at the cpu model). */
        gs_model_ctx_share_scratch(sl->ctx, w->ctx);
    }
    sl->has = 0;
    sl->used = ++w->tick;
    return v;
}

/* The slot holding subject key's tuned block (checksum sum), switching
 * the least recently used one to it when none does. */
static int worker_use_tuned(gsd_worker *w, const uint8_t key[16], uint64_t sum, int *slot, char *msg,
                            size_t cap)
{
    int i = slot_find(w, key, sum);
    /* A slot still holding a subject whose block left the cache gives it
     * up too: every worker answers the same for it. */
    if (i >= 0 && gsd_cache_contains(w->srv->tuned, key)) {
        w->slots[i].used = ++w->tick;
        *slot = i;
        return 0;
    }
    if (i >= 0)
        w->slots[i].has = 0;
    uint8_t *blk = NULL;
    long n = gsd_cache_get_alloc(w->srv->tuned, key, &blk);
    char hex[33];
    gs_frame_key_hex(key, hex);
    if (n < 8 || memcmp(blk + n - 8, &sum, 8) != 0) {
        free(blk);
        snprintf(msg, cap,
                 "subject %s: its fine-tuned parameters are gone (evicted: tuned_cache_mb); fit it "
                 "again", hex);
        return E(ERR_UNKNOWN_SUBJECT);
    }
    if ((i = slot_take(w, msg, cap)) < 0) {
        free(blk);
        return E(ERR_INTERNAL);
    }
    struct tuned_slot *sl = &w->slots[i];
    gs_error err;
    gs_error_clear(&err);
    int r = gs_model_tuned_apply(sl->m, w->model->m, blk, (size_t)n, &err);
    free(blk);
    gs_model_ctx_reset(sl->ctx);
    if (r != GS_OK) {
        snprintf(msg, cap, "subject %s: %s", hex, err.msg);
        return E(ERR_INTERNAL);
    }
    sl->has = 1;
    memcpy(sl->key, key, 16);
    sl->sum = sum;
    atomic_fetch_add(&w->srv->ctr.tuned_swaps, 1);
    *slot = i;
    return 0;
}

/* Fine-tunes a slot's clone, from the shared model's parameters, on the
 * fitted face and keeps the block (s->tuned, disk); the slot then holds
 * the subject. *sum: the block's checksum. */
static int finetune_subject(gsd_worker *w, gsd_job *j, const gsd_finetune *ft, int n,
                            const gs_subject *subj, const gs_io_image *face, const gs_redirect_input *p,
                            gs_finetune_report *rep, uint64_t *sum, char *msg, size_t cap)
{
    int i = slot_take(w, msg, cap);
    if (i < 0)
        return E(ERR_INTERNAL);
    struct tuned_slot *sl = &w->slots[i];
    gs_error err;
    gs_error_clear(&err);
    gs_finetune_options fo;
    gs_redirect_finetune_options((int)ft->steps, &fo);
    fo.parts = ft->parts;
    fo.outline_px = (int)ft->outline;
    fo.mirror = !ft->no_mirror;
    fo.lr = ft->lr;
    /* No time budget: a fine-tune cut short is not the subject the key
     * names. The deadline, CANCEL and a stop end it through the callback,
     * and nothing is kept. */
    fo.cancel = job_cancelled;
    fo.cancel_arg = j;
    /* One tuned set over the n (subject, image) pairs of a multi-image
     * FIT; one pair is gs_model_finetune's. */
    gs_fit_image im[GSD_FIT_IMAGES_MAX];
    for (int q = 0; q < n; q++) {
        gs_fit_image_from_options(&im[q], face[q].data, face[q].stride, NULL);
        im[q].mask = p[q].mask;
    }
    /* From the shared model's parameters, in the slot's clone. */
    int r = gs_redirect_finetune(&sl->m, w->model->m, w->pool, subj, im, n, &fo, rep, &err);
    gs_model_ctx_reset(sl->ctx);
    if (r == GS_ERR_CANCELLED) {
        int why = job_stop(j);
        snprintf(msg, cap, "finetune stopped at step %d", rep->iters);
        return why ? why : E(ERR_CANCELLED);
    }
    if (r != GS_OK) {
        snprintf(msg, cap, "finetune: %s", err.msg);
        return gsd_status_error(r);
    }
    uint8_t *blk = NULL;
    size_t len = 0;
    if (gs_model_tuned_encode(sl->m, &blk, &len, &err) != GS_OK) {
        snprintf(msg, cap, "finetune: %s", err.msg);
        return E(ERR_INTERNAL);
    }
    memcpy(sum, blk + len - 8, 8);
    int e = gsd_store_put(w->srv, STORE_TUNED, j->key, blk, len, msg, cap);
    free(blk);
    if (e)
        return e;
    sl->has = 1;
    memcpy(sl->key, j->key, 16);
    sl->sum = *sum;
    atomic_fetch_add(&w->srv->ctr.finetunes, 1);
    return 0;
}

/* What obtain_subject found or made. */
typedef struct subject_out {
    gs_subject subj;       /* the subject (a multi-image fit's: image 0's) */
    int n_all;             /* a multi-image fit this request ran: its images, */
    gs_subject all[GSD_FIT_IMAGES_MAX]; /* and each one's subject */
    gs_fit_report fit;
    gs_finetune_report ft; /* ft.iters > 0 or psnr: this request fine-tuned */
    int cached, tuned, ft_ran;
    uint64_t sum;          /* tuned: the block's checksum */
    gs_io_image face;      /* the normalized input, when the caller asked for it */
    uint8_t *opening;      /* a kept input's eye opening (gsd_input_get), or NULL */
    gs_xfer_eyes eyes;     /* a kept input's eyes: that opening and its irises */
} subject_out;

/* How obtain_subject fits: the request's labels (FIT only), iterations,
 * fine-tuning, and whether the input is kept (keep_image) or handed back
 * in o->face (want_face: inline REDIRECT transfer). */
typedef struct subject_ask {
    const Gazesplat__FitRequest *fr;
    uint32_t max_iters;
    gsd_finetune ft;
    int keep_image, want_face;
} subject_ask;

/* The fit's options for a request: its labels (FIT only), the photo's
 * landmark head pose and face mask, the iterations. The subject key is
 * made from these (content_key), so they are built once, before both. */
static void fit_options_of(const gsd_worker *w, const subject_ask *a, const Gazesplat__Angles *gaze,
                           const Gazesplat__Angles *head, const gs_redirect_input *p, gs_fit_options *opt)
{
    /* The defaults, the mask and a photo's landmark head pose (redirect.h);
     * the request's labels over them. */
    gs_redirect_fit_options(p, opt);
    if (gaze) {
        opt->known_gaze = 1;
        opt->gaze_pitch = gaze->pitch_deg * DEG;
        opt->gaze_yaw = gaze->yaw_deg * DEG;
    }
    if (head) {
        double R[9];
        head_rotation(head, R);
        gs_redirect_fit_head(R, w->model->info.distance_mm, opt);
    }
    if (a->max_iters)
        opt->max_iters = (int)a->max_iters;
}

/* Runs the fit (and fine-tune) a new subject needs and caches it. Only a
 * whole fit is cached: one stopped by CANCEL, the deadline or a stopping
 * server answers that and leaves no trace. */
static int fit_subject(gsd_worker *w, gsd_job *j, const subject_ask *a, int n, const gs_fit_options *fit_opt,
                       const gs_redirect_input *p, const gs_io_image *face, subject_out *o, char *msg, size_t cap)
{
    gsd_server *s = w->srv;
    gs_subject *subj = &o->subj;
    gs_fit_options opt = *fit_opt;
    opt.cancel = job_cancelled;
    opt.cancel_arg = j;
    gs_error err;
    gs_error_clear(&err);
    int r;
    if (n == 1) {
        r = gs_model_fit(w->ctx, w->pool, face->data, face->stride, &opt, subj, &o->fit, &err);
    } else {
        /* One identity over the n images, each with its own labels and
         * mask; the subject renders from image 0's. */
        gs_fit_image im[GSD_FIT_IMAGES_MAX];
        for (int i = 0; i < n; i++)
            gs_fit_image_from_options(&im[i], face[i].data, face[i].stride, &fit_opt[i]);
        opt.known_gaze = opt.known_head = 0;
        opt.mask = NULL;
        r = gs_model_fit_images(w->ctx, w->pool, im, n, &opt, o->all, &o->fit, &err);
        if (r == GS_OK) {
            o->n_all = n;
            *subj = o->all[0];
        }
    }
    /* The worker's context renders between fits: the fit's gradients and
     * saved activations (about 110 MB at the cpu model) go until the next
     * fit (daemon/README.md, "Memory"). */
    gs_model_ctx_trim(w->ctx);
    w->release = 1;
    if (r == GS_ERR_CANCELLED) {
        int why = job_stop(j);
        snprintf(msg, cap, "fit stopped at iteration %d", o->fit.iters);
        return why ? why : E(ERR_CANCELLED);
    }
    if (r != GS_OK) {
        snprintf(msg, cap, "fit: %s", err.msg);
        return gsd_status_error(r);
    }
    atomic_fetch_add(&s->ctr.fits, 1);
    if (a->ft.steps) {
        int e = finetune_subject(w, j, &a->ft, n, n == 1 ? subj : o->all, face, p, &o->ft, &o->sum, msg,
                                 cap);
        if (e)
            return e;
        o->tuned = o->ft_ran = 1;
    }
    uint8_t blob[GS_SUBJECT_ENCODED_MAX + 12];
    size_t bn = gsd_subject_blob(subj, o->tuned ? &o->sum : NULL, blob, sizeof blob);
    /* Durable before the reply: a FIT_OK means the subject survives a crash. */
    if (bn == 0 || bn > sizeof blob || gsd_cache_put(s->cache, j->key, blob, bn) != 0) {
        snprintf(msg, cap, "subject cache refused %zu bytes", bn);
        return E(ERR_INTERNAL);
    }
    gsd_cache_persist(s);
    return 0;
}

/* Image i of a request: FitRequest.image (i = 0, or the inline REDIRECT's
 * img) or FitRequest.more_images[i - 1], with its labels. */
static void image_of(const subject_ask *a, const Gazesplat__Image *img, const Gazesplat__Intrinsics *k, int i,
                     const Gazesplat__Image **im, const Gazesplat__Intrinsics **ki,
                     const Gazesplat__Angles **gaze, const Gazesplat__Angles **head)
{
    const Gazesplat__FitRequest *fr = a->fr;
    if (i == 0) {
        *im = img;
        *ki = k;
        *gaze = fr ? fr->gaze : NULL;
        *head = fr ? fr->head : NULL;
        return;
    }
    const Gazesplat__FitImage *f = fr->more_images[i - 1];
    *im = f->image;
    *ki = f->intrinsics;
    *gaze = f->gaze;
    *head = f->head;
}

/* Fits (or finds) the subject of `img` (and of a FIT's more_images: one
 * subject from them all) as a asks; fills the key and *o, and *p for a
 * photo (image 0's: the caller frees it, and o->face when asked for).
 * Returns 0 or an ErrorCode with msg (naming the image when there are
 * several). */
static int obtain_subject(gsd_worker *w, gsd_job *j, const subject_ask *a, const Gazesplat__Image *img,
                          const Gazesplat__Intrinsics *k, gs_redirect_input *p, subject_out *o, char *msg,
                          size_t cap)
{
    gsd_server *s = w->srv;
    memset(o, 0, sizeof *o);
    const int n = 1 + (a->fr ? (int)a->fr->n_more_images : 0);
    gs_redirect_input ps[GSD_FIT_IMAGES_MAX];
    gs_io_image face[GSD_FIT_IMAGES_MAX];
    gs_fit_options opt[GSD_FIT_IMAGES_MAX];
    int is_photo[GSD_FIT_IMAGES_MAX];
    memset(ps, 0, sizeof ps);
    memset(face, 0, sizeof face);
    int e = 0, got = 0;
    for (; !e && got < n; got++) {
        const Gazesplat__Image *im;
        const Gazesplat__Intrinsics *ki;
        const Gazesplat__Angles *gaze, *head;
        image_of(a, img, k, got, &im, &ki, &gaze, &head);
        char why[360];
        e = input_face(w, j, im, ki, &ps[got], &face[got], why, sizeof why);
        if (e) {
            if (n > 1)
                snprintf(msg, cap, "image %d: %s", got, why);
            else
                snprintf(msg, cap, "%s", why);
            break;
        }
        fit_options_of(w, a, gaze, head, &ps[got], &opt[got]);
        is_photo[got] = ps[got].is_photo;
    }
    if (!e && key_zero(j->key))
        content_key(w->model, n, is_photo, face, opt, &a->ft, j->key);
    if (!e)
        o->cached = gsd_subject_lookup(s, j->key, &o->subj, &o->tuned, &o->sum) == 0;
    if (!e && o->cached && o->tuned && !gsd_cache_contains(s->tuned, j->key)) {
        /* Its tuned tensors were evicted: the subject cannot render, so
         * this FIT runs again (the error REDIRECT gives says so). */
        o->cached = o->tuned = 0;
    }
    if (!e && !o->cached)
        e = fit_subject(w, j, a, n, opt, ps, face, o, msg, cap);
    if (!e && a->keep_image) {
        gs_xfer_eyes pe = gs_redirect_eyes(&ps[0]);
        e = gsd_input_keep(s, j->key, &face[0], &pe, msg, cap);
    }
    if (!e && a->want_face)
        o->face = face[0];
    else
        gs_io_image_free(&face[0]);
    *p = ps[0];
    for (int i = 1; i < n; i++) {
        gs_io_image_free(&face[i]);
        gs_redirect_input_free(&ps[i]);
    }
    return e;
}

static void subject_angles(const gs_subject *subj, Gazesplat__Angles *gaze, Gazesplat__Angles *head)
{
    gaze->pitch_deg = subj->gaze_pitch / DEG;
    gaze->yaw_deg = subj->gaze_yaw / DEG;
    double p, y;
    gs_geom_head_pitchyaw(subj->head_R, &p, &y);
    head->pitch_deg = p / DEG;
    head->yaw_deg = y / DEG;
}

static void run_fit(gsd_worker *w, gsd_job *j, int64_t t0)
{
    gsd_server *s = w->srv;
    const Gazesplat__FitRequest *r = (const Gazesplat__FitRequest *)j->req;
    subject_out so;
    memset(&so, 0, sizeof so);
    char msg[400];
    gs_redirect_input photo;
    subject_ask a = {r, r->max_iters,
                     finetune_of(j, r->finetune_steps, r->finetune_parts, r->finetune_outline_px,
                                 r->finetune_no_mirror, r->finetune_lr),
                     r->keep_image, 0};
    int e = obtain_subject(w, j, &a, r->image, r->intrinsics, &photo, &so, msg, sizeof msg);
    gs_redirect_input_free(&photo);
    if (!e)
        e = job_stop(j);
    if (e) {
        emit_failure(s, j, e, msg);
        return;
    }
    if (so.cached)
        atomic_fetch_add(&s->ctr.fits_cached, 1);
    j->iters = so.fit.iters;
    j->ft_steps = so.ft_ran ? so.ft.iters : 0;
    j->cached = so.cached;
    /* After the reply (gsd_worker_run) the subject is rendered once, so
     * that its first REDIRECT here is incremental; a cached fine-tuned
     * subject first needs its block in the clone. */
    w->prime_slot = -1;
    w->prime = !so.tuned || worker_use_tuned(w, j->key, so.sum, &w->prime_slot, msg, sizeof msg) == 0;
    w->prime_subj = so.subj;
    recent_add(w, j->key);
    const gs_subject subj = so.subj;
    Gazesplat__Angles gaze = GAZESPLAT__ANGLES__INIT, head = GAZESPLAT__ANGLES__INIT;
    subject_angles(&subj, &gaze, &head);
    Gazesplat__FitResult m = GAZESPLAT__FIT_RESULT__INIT;
    m.subject_key.data = j->key;
    m.subject_key.len = 16;
    m.gaze = &gaze;
    m.head = &head;
    m.psnr = subj.fit_psnr;
    m.ssim = subj.fit_ssim;
    m.iters = (uint32_t)so.fit.iters;
    m.seconds = (double)(gs_clock_ms() - t0) / 1000.0;
    m.cached = so.cached;
    m.finetuned = so.tuned;
    m.image_kept = gsd_cache_contains(s->inputs, j->key);
    if (so.ft_ran) {
        m.finetune_steps = (uint32_t)so.ft.iters;
        m.finetune_psnr = so.ft.psnr_best;
        m.finetune_lr = a.ft.lr;
    }
    /* A multi-image fit this request ran: what it made of each image. */
    Gazesplat__FitImageResult res[GSD_FIT_IMAGES_MAX], *resp[GSD_FIT_IMAGES_MAX];
    Gazesplat__Angles rg[GSD_FIT_IMAGES_MAX], rh[GSD_FIT_IMAGES_MAX];
    for (int i = 0; i < so.n_all; i++) {
        gazesplat__fit_image_result__init(&res[i]);
        gazesplat__angles__init(&rg[i]);
        gazesplat__angles__init(&rh[i]);
        subject_angles(&so.all[i], &rg[i], &rh[i]);
        res[i].gaze = &rg[i];
        res[i].head = &rh[i];
        res[i].psnr = so.all[i].fit_psnr;
        res[i].ssim = so.all[i].fit_ssim;
        resp[i] = &res[i];
    }
    m.n_image_results = (size_t)so.n_all;
    m.image_results = so.n_all ? resp : NULL;
    gsd_emit_done(j, T(FIT_OK), &m.base);
}

/* Encodes img as the request asks and emits it as target i's image. */
static int emit_image(gsd_worker *w, gsd_job *j, const Gazesplat__RedirectRequest *r, size_t i,
                      const gs_io_image *img, const gs_face_quality *q, char *msg, size_t cap)
{
    Gazesplat__Image out = GAZESPLAT__IMAGE__INIT;
    Gazesplat__Quality qm = GAZESPLAT__QUALITY__INIT;
    Gazesplat__Angles asked = GAZESPLAT__ANGLES__INIT, seen = GAZESPLAT__ANGLES__INIT;
    if (q) {
        qm.score = q->score;
        qm.eyes = (uint32_t)q->eyes;
        asked.pitch_deg = q->commanded[0] / DEG;
        asked.yaw_deg = q->commanded[1] / DEG;
        qm.asked = &asked;
        if (q->eyes) {
            seen.pitch_deg = q->measured[0] / DEG;
            seen.yaw_deg = q->measured[1] / DEG;
            qm.seen = &seen;
            qm.gaze_error_deg = q->gaze_error_deg;
            qm.iris_delta_e = q->delta_e;
        }
        qm.eye_speckle = q->artifact;
        qm.reason = (char *)q->reason;
    }
    int drop = q && r->min_quality > 0 && q->score < r->min_quality;
    void *enc = NULL;
    size_t enc_len = 0;
    int fmt = r->output_format ? (int)r->output_format : GAZESPLAT__IMAGE_FORMAT__FORMAT_PNG;
    out.format = (Gazesplat__ImageFormat)fmt;
    if (drop) {
        /* dropped: no pixels */
    } else if (fmt == GAZESPLAT__IMAGE_FORMAT__FORMAT_RAW_RGB8) {
        out.data.data = img->data;
        out.data.len = img->stride * (size_t)img->height;
        out.width = (uint32_t)img->width;
        out.height = (uint32_t)img->height;
        out.stride = (uint32_t)img->stride;
    } else {
        gs_error err;
        gs_error_clear(&err);
        int jq = fmt == GAZESPLAT__IMAGE_FORMAT__FORMAT_JPEG ? (int)r->jpeg_quality : 0;
        if (gs_io_image_encode(img, fmt == GAZESPLAT__IMAGE_FORMAT__FORMAT_JPEG ? GS_IO_JPEG : GS_IO_PNG,
                               jq, &enc, &enc_len, &err) != GS_OK) {
            snprintf(msg, cap, "encode target %zu: %s", i, err.msg);
            return E(ERR_INTERNAL);
        }
        out.data.data = enc;
        out.data.len = enc_len;
    }
    Gazesplat__ImageResult m = GAZESPLAT__IMAGE_RESULT__INIT;
    m.index = (uint32_t)i;
    m.image = drop ? NULL : &out;
    m.target = r->targets[i];
    m.quality = q ? &qm : NULL;
    m.dropped = drop;
    int taken = gsd_emit_image(j, &m);
    free(enc);
    if (taken != 0) {
        snprintf(msg, cap, "out of memory");
        return E(ERR_INTERNAL);
    }
    if (drop) {
        atomic_fetch_add(&w->srv->ctr.images_dropped, 1);
        return 0;
    }
    j->images++;
    atomic_fetch_add(&w->srv->ctr.images_out, 1);
    return 0;
}

/* What the quality of a request's images is measured against (face.h):
 * the input face (normalized) with its landmarks, a photo's or found in
 * the face; NULL when the request does not ask for it (quality or
 * min_quality: it costs about 5 gaze-sweep renders an image), the input or its
 * landmarks are not at hand, or no target is gaze-only (a head change
 * carries no quality). */
static gs_face_quality_ref *quality_ref_of(const gsd_worker *w, const Gazesplat__RedirectRequest *r,
                                           const gs_io_image *face, const gs_redirect_input *p)
{
    size_t i = 0;
    while (i < r->n_targets && r->targets[i]->head)
        i++;
    if (!(r->quality || r->min_quality > 0) || !face->data || i == r->n_targets)
        return NULL;
    double uv[GS_FACE_LANDMARKS][2];
    if (p->is_photo)
        memcpy(uv, p->face.uv_n, sizeof uv);
    else if (!w->srv->face_sp || gs_face_normalized_landmarks(w->srv->face_sp, face, uv, NULL) != GS_OK)
        return NULL;
    gs_face_quality_opts qo;
    gs_face_quality_opts_default(&qo);
    qo.px_per_mm = w->model->info.focal / w->model->info.distance_mm;
    qo.shape = w->srv->face_sp;
    gs_face_quality_ref *q = NULL;
    return gs_face_quality_ref_create(face, (const double(*)[2])uv, &qo, &q, NULL) == GS_OK ? q : NULL;
}

static int paste_back(const gs_redirect_input *p, gs_redirect_paste_state *ps, int whole_face,
                      const gs_io_image *norm, char *msg, size_t cap)
{
    gs_error err;
    gs_error_clear(&err);
    if (gs_redirect_paste(p, ps, whole_face, norm, &err) != GS_OK) {
        snprintf(msg, cap, "%s", err.msg);
        return E(ERR_INTERNAL);
    }
    return 0;
}

/* Adds the last render's path to the STATS counters. */
static void count_render(gsd_worker *w, gs_model_ctx *ctx)
{
    gs_model_ctx_stats st;
    gs_model_ctx_get_stats(ctx, &st);
    atomic_fetch_add(st.last_incremental ? &w->srv->ctr.renders_incremental : &w->srv->ctr.renders_full, 1);
}

/* Renders target i into rgb (the normalized face; with input, by detail
 * transfer from it) and emits it, pasted back into the photo when the
 * request asks for it. */
static int render_target(gsd_worker *w, gs_model_ctx *ctx, gsd_job *j, const Gazesplat__RedirectRequest *r,
                         size_t i, const gs_subject *subj, const gs_io_image *input,
                         const gs_xfer_eyes *eyes, const gs_redirect_input *p,
                         const gs_face_quality_ref *qr, gs_redirect_paste_state *ps, uint8_t *rgb, char *msg,
                         size_t cap)
{
    const Gazesplat__Target *t = r->targets[i];
    int size = w->model->info.image_size;
    gs_view view;
    memset(&view, 0, sizeof view);
    view.gaze_pitch = t->gaze->pitch_deg * DEG;
    view.gaze_yaw = t->gaze->yaw_deg * DEG;
    if (t->head) {
        view.use_head = 1;
        head_rotation(t->head, view.head_R);
        memcpy(view.head_t, subj->head_t, sizeof view.head_t);
    }
    gs_error err;
    gs_error_clear(&err);
    int rc = gs_redirect_render(ctx, w->pool, subj, input ? input->data : NULL, input ? input->stride : 0,
                                eyes, &view, rgb, (size_t)size * 3, &err);
    if (rc != GS_OK) {
        snprintf(msg, cap, "render target %zu%s: %s", i, input ? " (transfer)" : "", err.msg);
        return gsd_status_error(rc);
    }
    count_render(w, ctx);
    if (input)
        atomic_fetch_add(&w->srv->ctr.renders_transfer, 1);
    gs_io_image norm = {size, size, (size_t)size * 3, rgb};
    gs_face_quality q;
    const gs_face_quality *qp = NULL;
    if (qr && !t->head) {
        /* The gaze only: the eyes stay where the input's landmarks put them. */
        if (gs_face_quality_measure(qr, &norm, subj->head_R, view.gaze_pitch - subj->gaze_pitch,
                                    view.gaze_yaw - subj->gaze_yaw, &q, &err) != GS_OK) {
            snprintf(msg, cap, "quality of target %zu: %s", i, err.msg);
            return E(ERR_INTERNAL);
        }
        qp = &q;
    }
    if (r->output_mode != GAZESPLAT__OUTPUT_MODE__OUTPUT_PASTE_BACK)
        return emit_image(w, j, r, i, &norm, qp, msg, cap);
    int e = paste_back(p, ps, t->head != NULL, &norm, msg, cap);
    return e ? e : emit_image(w, j, r, i, &ps->out, qp, msg, cap);
}

static void run_redirect(gsd_worker *w, gsd_job *j, int64_t t0)
{
    gsd_server *s = w->srv;
    const Gazesplat__RedirectRequest *r = (const Gazesplat__RedirectRequest *)j->req;
    subject_out so;
    memset(&so, 0, sizeof so);
    char msg[400];
    gs_redirect_input photo;
    memset(&photo, 0, sizeof photo);
    if (r->image) {
        subject_ask a = {NULL, r->max_iters,
                         finetune_of(j, r->finetune_steps, r->finetune_parts, r->finetune_outline_px,
                                     r->finetune_no_mirror, r->finetune_lr),
                         0, 1};
        int e = obtain_subject(w, j, &a, r->image, r->intrinsics, &photo, &so, msg, sizeof msg);
        if (e) {
            gs_redirect_input_free(&photo);
            emit_failure(s, j, e, msg);
            return;
        }
        j->iters = so.fit.iters;
        j->ft_steps = so.ft_ran ? so.ft.iters : 0;
        j->cached = so.cached;
    } else {
        char hex[33];
        gs_frame_key_hex(j->key, hex);
        if (gsd_subject_lookup(s, j->key, &so.subj, &so.tuned, &so.sum) != 0) {
            gsd_emit_error(j, E(ERR_UNKNOWN_SUBJECT), "no subject %s (never fitted or evicted)", hex);
            return;
        }
        if (gsd_input_get(s, j->key, w->model->info.image_size, &so.face, &so.opening, &so.eyes) != 0 &&
            r->transfer) {
            gsd_emit_error(j, E(ERR_UNKNOWN_SUBJECT),
                           "subject %s: no kept input for transfer (FIT it with keep_image, or it "
                           "was evicted: input_cache_mb); send the image inline or FIT again",
                           hex);
            return;
        }
    }
    int slot = -1;
    if (so.tuned) {
        int e = worker_use_tuned(w, j->key, so.sum, &slot, msg, sizeof msg);
        if (e) {
            gs_io_image_free(&so.face);
            free(so.opening);
            gs_redirect_input_free(&photo);
            gsd_emit_error(j, e, "%s", msg);
            return;
        }
    }
    gs_model_ctx *ctx = slot >= 0 ? w->slots[slot].ctx : w->ctx;
    const gs_subject subj = so.subj;
    /* The same request gives the same bytes whatever this worker rendered
     * before (the model's renders are a function of subject and view; a
     * transfer's would go on from the subject's last target). */
    if (r->transfer)
        gs_model_ctx_forget_transfer_targets(ctx);
    gs_face_quality_ref *qr = quality_ref_of(w, r, &so.face, &photo);
    recent_add(w, j->key);
    int size = w->model->info.image_size;
    uint8_t *rgb = malloc((size_t)size * size * 3);
    gs_redirect_paste_state ps;
    memset(&ps, 0, sizeof ps);
    /* The first failure ends the targets: a stop (stopped), or an error
     * with msg. The final result goes out after the clean-up. */
    int e = 0, stopped = 0;
    if (!rgb) {
        e = E(ERR_INTERNAL);
        snprintf(msg, sizeof msg, "out of memory");
    }
    gs_xfer_eyes eyes = photo.opening ? gs_redirect_eyes(&photo) : so.eyes;
    for (size_t i = 0; i < r->n_targets && !e; i++) {
        e = i > 0 ? wait_output(s, j) : job_stop(j);
        stopped = e != 0;
        if (!e)
            e = render_target(w, ctx, j, r, i, &subj, r->transfer ? &so.face : NULL, &eyes, &photo,
                              qr, &ps, rgb, msg, sizeof msg);
    }
    gs_face_quality_ref_destroy(qr);
    free(rgb);
    gs_io_image_free(&so.face);
    free(so.opening);
    gs_redirect_paste_free(&ps);
    gs_redirect_input_free(&photo);
    if (stopped) {
        emit_stop(s, j, e);
    } else if (e) {
        gsd_emit_error(j, e, "%s", msg);
    } else {
        Gazesplat__Done d = GAZESPLAT__DONE__INIT;
        d.count = (uint32_t)r->n_targets;
        d.seconds = (double)(gs_clock_ms() - t0) / 1000.0;
        gsd_emit_done(j, T(DONE), &d.base);
    }
}

static void run_model_job(gsd_worker *w, gsd_job *j, int64_t t0)
{
    if (worker_bind_model(w) != 0)
        gsd_emit_error(j, E(ERR_NO_MODEL), "no model loaded");
    else if (j->type == T(FIT))
        run_fit(w, j, t0);
    else
        run_redirect(w, j, t0);
}

/* Renders the last FIT's subject at its own gaze and pose (the image is
 * dropped): the context then keeps that render, and a REDIRECT of the
 * subject renders only the eyes' reach, even the first one. */
static void worker_prime(gsd_worker *w)
{
    if (!w->prime || !w->ctx)
        return;
    w->prime = 0;
    gs_model_ctx *ctx = w->prime_slot >= 0 ? w->slots[w->prime_slot].ctx : w->ctx;
    if (!ctx)
        return;
    int size = w->model->info.image_size;
    uint8_t *rgb = malloc((size_t)size * size * 3);
    gs_view v;
    memset(&v, 0, sizeof v);
    v.gaze_pitch = w->prime_subj.gaze_pitch;
    v.gaze_yaw = w->prime_subj.gaze_yaw;
    gs_error err;
    gs_error_clear(&err);
    if (rgb && gs_model_render(ctx, w->pool, &w->prime_subj, &v, rgb, (size_t)size * 3, &err) == GS_OK)
        count_render(w, ctx);
    else
        LOG_W("worker %d: render after FIT: %s", w->index, rgb ? err.msg : "out of memory");
    free(rgb);
}

/* A fit or fine-tune freed its working set (over 100 MB at the cpu model:
 * the fine-tune's own context, gradients and Adam moments). glibc keeps
 * freed memory in the thread's arena for later allocations, and a fit
 * done, the next one is far off: malloc_trim returns every free page of
 * every arena to the system (a few ms), so the resident size falls back
 * to what the worker keeps. */
static void worker_release(gsd_worker *w)
{
    if (!w->release)
        return;
    w->release = 0;
#ifdef __GLIBC__
    malloc_trim(0);
#endif
}

void gsd_worker_run(gsd_worker *w, gsd_job *j)
{
    gsd_server *s = w->srv;
    int64_t t0 = gs_clock_ms();
    j->started_ms = t0; /* the sink's run time */
    int why = job_stop(j);
    if (why)
        emit_stop(s, j, why);
    else if (j->type == T(SLEEP))
        run_sleep(s, j, t0);
    else
        run_model_job(w, j, t0);
    worker_prime(w); /* the job is its sink's now; only w is used */
    worker_release(w);
}
