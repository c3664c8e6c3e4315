/* The eye-contact stage. The frame path (the pipeline's processing thread)
 * tracks, runs the policy, and blends the newest rendered eyes; one worker
 * thread fits the subject and renders eyes, always for the newest target,
 * so the ~100-200 ms model never sits on the frame path. */
#define _POSIX_C_SOURCE 200809L
#include <math.h>
#include <pthread.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "gazesplat/live.h"

#define DEG (3.14159265358979323846 / 180.0)
#define NSIG 5

struct gs_live_stage {
    gs_live_config cfg;
    gs_live_track *track;
    gs_live_engine eng;
    gs_cap_policy *policy;
    pthread_t worker;
    int worker_started;
    pthread_mutex_t lock;
    pthread_cond_t cv;

    /* ---- shared with the worker (lock) ---- */
    int stop;
    uint64_t generation;       /* bumped on refit: late results are dropped */
    int fit_wanted, fitting;
    uint8_t *fit_rgb;          /* the frame to fit (worker reads it while fitting) */
    size_t fit_cap;
    int fit_w, fit_h;
    gs_live_track_state fit_st;
    double fit_k[9];
    int ready;
    gs_live_subject subj;
    int want_render;
    double want_pitch, want_yaw;
    int64_t want_t;
    uint8_t *patch[2];         /* front: blended by the frame path; back: rendered */
    int front, have_patch;
    double patch_pitch, patch_yaw;
    int64_t patch_t;           /* capture time of the frame the patch was asked for */
    gs_live_status status;

    /* ---- frame path only ---- */
    int64_t last_t;
    uint64_t last_track;
    int good_frames;
    double sig_fit[NSIG], sig_ema[NSIG];
    int sig_n;
    float mismatch_s;
    uint8_t *mask;
    size_t mask_cap;
};

gs_live_config gs_live_config_default(void)
{
    gs_live_config c;
    memset(&c, 0, sizeof c);
    c.track = gs_live_track_config_default();
    c.fit_after = 5;
    c.fit_head_max_deg = 15.0f;
    c.stale_full_s = 0.15f;
    c.stale_max_s = 0.5f;
    c.stale_gaze_deg = 1.0f;
    c.feather_px = 3.0f;
    c.change_tol = 0.12f;
    c.change_s = 1.0f;
    return c;
}

static int config_ok(const gs_live_config *c)
{
    return c->fit_after >= 1 && c->fit_head_max_deg > 0 && c->stale_full_s >= 0 &&
           c->stale_max_s > c->stale_full_s && c->stale_gaze_deg >= 0 && c->feather_px >= 0 &&
           c->feather_px <= 50 && c->change_tol > 0 && c->change_s >= 0;
}

/* ---- worker ---- */

static void run_fit(gs_live_stage *s)
{
    uint64_t gen = s->generation;
    s->fit_wanted = 0;
    s->fitting = 1;
    s->status.fitting = 1;
    gs_io_image img = {s->fit_w, s->fit_h, 3 * (size_t)s->fit_w, s->fit_rgb};
    gs_live_track_state st = s->fit_st;
    double k[9];
    memcpy(k, s->fit_k, sizeof k);
    pthread_mutex_unlock(&s->lock);
    gs_live_subject subj;
    memset(&subj, 0, sizeof subj);
    gs_error e = {0};
    struct timespec t0, t1;
    clock_gettime(CLOCK_MONOTONIC, &t0);
    int r = s->eng.fit(s->eng.ctx, &img, &st, k, &subj, &e);
    clock_gettime(CLOCK_MONOTONIC, &t1);
    pthread_mutex_lock(&s->lock);
    s->fitting = 0;
    s->status.fitting = 0;
    s->status.last_fit_s = (double)(t1.tv_sec - t0.tv_sec) + (double)(t1.tv_nsec - t0.tv_nsec) / 1e9;
    if (r != GS_OK) {
        s->status.fit_failures++;
        return;
    }
    if (gen != s->generation)
        return;
    s->subj = subj;
    s->ready = 1;
    s->have_patch = 0;
    s->status.fits++;
}

static void run_render(gs_live_stage *s)
{
    uint64_t gen = s->generation;
    double pitch = s->want_pitch, yaw = s->want_yaw;
    int64_t t = s->want_t;
    s->want_render = 0;
    gs_live_subject subj = s->subj;
    uint8_t *back = s->patch[1 - s->front];
    pthread_mutex_unlock(&s->lock);
    gs_error e = {0};
    int r = s->eng.render(s->eng.ctx, &subj, pitch, yaw, back, &e);
    pthread_mutex_lock(&s->lock);
    if (r != GS_OK || gen != s->generation || !s->ready)
        return;
    s->front = 1 - s->front;
    s->have_patch = 1;
    s->patch_pitch = pitch;
    s->patch_yaw = yaw;
    s->patch_t = t;
    s->status.renders++;
}

static void *worker_main(void *arg)
{
    gs_live_stage *s = arg;
    pthread_mutex_lock(&s->lock);
    while (!s->stop) {
        if (s->fit_wanted)
            run_fit(s);
        else if (s->want_render && s->ready)
            run_render(s);
        else
            pthread_cond_wait(&s->cv, &s->lock);
    }
    pthread_mutex_unlock(&s->lock);
    return NULL;
}

/* ---- lifecycle ---- */

int gs_live_stage_create(const gs_live_config *cfg, const gs_live_track_ops *ops,
                         const gs_live_engine *engine, gs_cap_policy *policy,
                         gs_live_stage **out, gs_error *err)
{
    gs_live_config c = cfg ? *cfg : gs_live_config_default();
    if (!config_ok(&c))
        return gs_error_set(err, GS_ERR_ARG, "live: bad stage configuration");
    if (!engine || !engine->fit || !engine->render || engine->image_size < 8 ||
        engine->image_size > 4096 || !policy || !out)
        return gs_error_set(err, GS_ERR_ARG, "live: engine and policy needed");
    gs_live_stage *s = calloc(1, sizeof *s);
    if (!s)
        return gs_error_set(err, GS_ERR_NOMEM, "live: out of memory");
    s->cfg = c;
    s->eng = *engine;
    s->policy = policy;
    s->last_t = -1;
    size_t psz = 3 * (size_t)engine->image_size * (size_t)engine->image_size;
    s->patch[0] = malloc(psz);
    s->patch[1] = malloc(psz);
    int r = gs_live_track_create(&c.track, ops, &s->track, err);
    if (r == GS_OK && (!s->patch[0] || !s->patch[1]))
        r = gs_error_set(err, GS_ERR_NOMEM, "live: out of memory");
    if (r != GS_OK) {
        gs_live_track_destroy(s->track);
        free(s->patch[0]);
        free(s->patch[1]);
        free(s);
        return r;
    }
    pthread_mutex_init(&s->lock, NULL);
    pthread_cond_init(&s->cv, NULL);
    s->status.patch_age_s = -1;
    if (pthread_create(&s->worker, NULL, worker_main, s) != 0) {
        gs_live_stage_destroy(s);
        return gs_error_set(err, GS_ERR_NOMEM, "live: cannot start the worker");
    }
    s->worker_started = 1;
    *out = s;
    return GS_OK;
}

void gs_live_stage_destroy(gs_live_stage *s)
{
    if (!s)
        return;
    pthread_mutex_lock(&s->lock);
    s->stop = 1;
    pthread_cond_signal(&s->cv);
    pthread_mutex_unlock(&s->lock);
    if (s->worker_started)
        pthread_join(s->worker, NULL);
    pthread_cond_destroy(&s->cv);
    pthread_mutex_destroy(&s->lock);
    gs_live_track_destroy(s->track);
    free(s->patch[0]);
    free(s->patch[1]);
    free(s->fit_rgb);
    free(s->mask);
    free(s);
}

void gs_live_stage_get_status(gs_live_stage *s, gs_live_status *st)
{
    pthread_mutex_lock(&s->lock);
    *st = s->status;
    st->subject_ready = s->ready;
    pthread_mutex_unlock(&s->lock);
}

/* Caller holds the lock. */
static void drop_subject(gs_live_stage *s)
{
    s->generation++;
    s->ready = 0;
    s->have_patch = 0;
    s->fit_wanted = 0;
    s->good_frames = 0;
    s->sig_n = 0;
    s->mismatch_s = 0;
}

void gs_live_stage_refit(gs_live_stage *s)
{
    pthread_mutex_lock(&s->lock);
    drop_subject(s);
    pthread_mutex_unlock(&s->lock);
}

/* ---- person change: a landmark-shape signature ---- */

static double d2(const double uv[][2], int a, int b)
{
    return hypot(uv[a][0] - uv[b][0], uv[a][1] - uv[b][1]);
}

/* Ratios of the face's rigid proportions to the outer eye-corner distance
 * (jaw width, nose bridge, nose width, eye width, brow span): fairly stable
 * under expression and near-frontal pose, different between people. */
static int signature(const double uv[][2], double sig[NSIG])
{
    double iod = d2(uv, 36, 45);
    if (!(iod > 1.0))
        return 0;
    sig[0] = d2(uv, 0, 16) / iod;
    sig[1] = d2(uv, 27, 30) / iod;
    sig[2] = d2(uv, 31, 35) / iod;
    sig[3] = 0.5 * (d2(uv, 36, 39) + d2(uv, 42, 45)) / iod;
    sig[4] = d2(uv, 17, 26) / iod;
    return 1;
}

static double sig_distance(const double a[NSIG], const double b[NSIG])
{
    double m = 0;
    for (int i = 0; i < NSIG; i++)
        m = fmax(m, fabs(a[i] - b[i]) / fmax(fabs(b[i]), 1e-6));
    return m;
}

/* ---- the frame path ---- */

static int good_frame(const gs_live_stage *s, const gs_live_track_state *st)
{
    double lim = s->cfg.fit_head_max_deg * DEG;
    return st->face && fabs(st->pose.pitch) <= lim && fabs(st->pose.yaw) <= lim &&
           st->openness >= 0.5;
}

/* Caller holds the lock. Queues a fit of this frame. */
static int post_fit(gs_live_stage *s, const uint8_t *rgb, size_t stride, int w, int h,
                    const gs_live_track_state *st, const double k[9])
{
    size_t need = 3 * (size_t)w * (size_t)h;
    if (need > s->fit_cap) {
        uint8_t *q = realloc(s->fit_rgb, need);
        if (!q)
            return GS_ERR_NOMEM;
        s->fit_rgb = q;
        s->fit_cap = need;
    }
    for (int y = 0; y < h; y++)
        memcpy(s->fit_rgb + (size_t)y * 3 * (size_t)w, rgb + (size_t)y * stride, 3 * (size_t)w);
    s->fit_w = w;
    s->fit_h = h;
    s->fit_st = *st;
    memcpy(s->fit_k, k, sizeof s->fit_k);
    s->fit_wanted = 1;
    pthread_cond_signal(&s->cv);
    return GS_OK;
}

/* Caller holds the lock. First fit after fit_after good frames; a refit
 * when the shape signature stays off the fitted one for change_s. */
static int schedule_fit(gs_live_stage *s, const uint8_t *rgb, size_t stride, int w, int h,
                        const gs_live_track_state *st, const double k[9], float dt)
{
    double sig[NSIG];
    int good = good_frame(s, st) && signature((const double(*)[2])st->uv, sig);
    if (!st->face || st->track_id != s->last_track) {
        s->good_frames = 0;
        s->sig_n = 0; /* a new track: the person may have changed */
    }
    if (!s->ready) {
        if (s->fitting || s->fit_wanted)
            return GS_OK;
        s->good_frames = good ? s->good_frames + 1 : 0;
        if (s->good_frames < s->cfg.fit_after)
            return GS_OK;
        memcpy(s->sig_fit, sig, sizeof sig);
        s->good_frames = 0;
        return post_fit(s, rgb, stride, w, h, st, k);
    }
    if (!good)
        return GS_OK;
    double a = s->sig_n ? 1.0 - exp(-dt / 0.3) : 1.0; /* 0.3 s smoothing */
    for (int i = 0; i < NSIG; i++)
        s->sig_ema[i] += a * (sig[i] - s->sig_ema[i]);
    s->sig_n++;
    s->mismatch_s = sig_distance(s->sig_ema, s->sig_fit) > s->cfg.change_tol ? s->mismatch_s + dt : 0;
    if (s->mismatch_s > s->cfg.change_s || (s->cfg.change_s == 0 && s->mismatch_s > 0)) {
        drop_subject(s);
        s->status.refits++;
    }
    return GS_OK;
}

static float ramp_down(float x, float full, float none)
{
    return x <= full ? 1.0f : x >= none ? 0.0f : (none - x) / (none - full);
}

/* Blends one eye (first landmark i0 = 36 or 42) of the front patch. */
static int blend_eye(gs_live_stage *s, uint8_t *rgb, size_t stride, int w, int h,
                     const gs_live_track_state *st, int eye, float alpha, gs_error *err)
{
    int i0 = eye ? 42 : 36;
    double m[4];
    if (gs_live_similarity(st->uv[i0], st->uv[i0 + 3], s->subj.corners_n[2 * eye],
                           s->subj.corners_n[2 * eye + 1], m) != GS_OK)
        return GS_OK;
    double ew = d2((const double(*)[2])st->uv, i0, i0 + 3);
    double x0 = st->uv[i0][0], x1 = x0, y0 = st->uv[i0][1], y1 = y0;
    for (int i = i0 + 1; i < i0 + 6; i++) {
        x0 = fmin(x0, st->uv[i][0]);
        x1 = fmax(x1, st->uv[i][0]);
        y0 = fmin(y0, st->uv[i][1]);
        y1 = fmax(y1, st->uv[i][1]);
    }
    double pad = 0.5 * ew + s->cfg.feather_px + 4.0; /* the mask grows eyes by 30% + feather */
    int bx0 = (int)floor(x0 - pad), by0 = (int)floor(y0 - pad);
    int bx1 = (int)ceil(x1 + pad), by1 = (int)ceil(y1 + pad);
    bx0 = bx0 < 0 ? 0 : bx0;
    by0 = by0 < 0 ? 0 : by0;
    bx1 = bx1 > w ? w : bx1;
    by1 = by1 > h ? h : by1;
    if (bx1 - bx0 < 2 || by1 - by0 < 2)
        return GS_OK;
    size_t need = (size_t)(bx1 - bx0) * (size_t)(by1 - by0);
    if (need > s->mask_cap) {
        uint8_t *q = realloc(s->mask, need);
        if (!q)
            return gs_error_set(err, GS_ERR_NOMEM, "live: out of memory");
        s->mask = q;
        s->mask_cap = need;
    }
    double uv[GS_FACE_LANDMARKS][2];
    for (int i = 0; i < GS_FACE_LANDMARKS; i++) {
        uv[i][0] = st->uv[i][0] - bx0;
        uv[i][1] = st->uv[i][1] - by0;
    }
    int r = gs_face_mask((const double(*)[2])uv, eye ? GS_FACE_MASK_LEFT_EYE : GS_FACE_MASK_RIGHT_EYE,
                         1.0, s->cfg.feather_px, bx1 - bx0, by1 - by0, s->mask, err);
    if (r != GS_OK)
        return r;
    int n = s->eng.image_size;
    gs_live_blend_patch(rgb, stride, w, h, bx0, by0, bx1, by1, s->mask, s->patch[s->front],
                        3 * (size_t)n, n, n, m, alpha);
    return GS_OK;
}

static float clampf(double v, double lim)
{
    return (float)(v > lim ? lim : v < -lim ? -lim : v);
}

/* Caller holds the lock. Asks for a render of the current target unless
 * the newest patch already shows it. */
static void want_render(gs_live_stage *s, float pitch, float yaw, int64_t t)
{
    double tol = 0.5 * s->cfg.stale_gaze_deg * DEG;
    if (s->have_patch && fabs(pitch - s->patch_pitch) <= tol && fabs(yaw - s->patch_yaw) <= tol)
        return;
    s->want_pitch = pitch;
    s->want_yaw = yaw;
    s->want_t = t;
    s->want_render = 1;
    pthread_cond_signal(&s->cv);
}

/* How much of the front patch to blend: 1 while it shows the current
 * target (within stale_gaze_deg), else fading with its age. Lock held. */
static float freshness(gs_live_stage *s, float pitch, float yaw, int64_t t, float *age)
{
    *age = (float)((double)(t - s->patch_t) / 1e9);
    double tol = s->cfg.stale_gaze_deg * DEG;
    if (fabs(pitch - s->patch_pitch) <= tol && fabs(yaw - s->patch_yaw) <= tol)
        return 1.0f;
    return ramp_down(*age, s->cfg.stale_full_s, s->cfg.stale_max_s);
}

int gs_live_stage_process(gs_live_stage *s, uint8_t *rgb, size_t stride, int width, int height,
                          int64_t t, gs_error *err)
{
    gs_io_image img = {width, height, stride, rgb};
    double k[9];
    if (s->cfg.use_k)
        memcpy(k, s->cfg.k, sizeof k);
    else
        gs_face_default_intrinsics(width, height, k);
    gs_live_track_state st;
    int r = gs_live_track_update(s->track, &img, k, &st, err);
    if (r != GS_OK)
        memset(&st, 0, sizeof st); /* a failing frame counts as no face */
    float dt = s->last_t >= 0 && t > s->last_t ? (float)((double)(t - s->last_t) / 1e9) : 0.0f;
    s->last_t = t;
    double tp = 0, ty = 0;
    int face = st.face && gs_live_camera_gaze(st.pose.R, st.pose.t, &tp, &ty) == GS_OK;
    /* The gaze the policy sees is the correction the eyes would need: the
     * camera direction in the head frame (the stage has no eye tracker and
     * assumes the eyes look where the face points, at the screen). */
    gs_cap_policy_input in = {face, (float)tp, (float)ty, (float)st.pose.pitch,
                              (float)st.pose.yaw, (float)st.openness, dt};
    gs_cap_policy_output po;
    gs_cap_policy_update(s->policy, &in, &po);
    float pitch = clampf(tp, GS_MODEL_MAX_GAZE_PITCH), yaw = clampf(ty, GS_MODEL_MAX_GAZE_YAW);

    pthread_mutex_lock(&s->lock);
    int fr = schedule_fit(s, rgb, stride, width, height, &st, k, dt);
    s->last_track = st.track_id;
    if (face && s->ready)
        want_render(s, pitch, yaw, t);
    float age = -1, alpha = 0;
    /* A blink shows the real eyes; the policy holds its weight meanwhile so
     * the correction comes back at once, not after a new fade-in. */
    if (face && s->ready && s->have_patch && !po.held && po.weight > 0)
        alpha = po.weight * freshness(s, pitch, yaw, t, &age);
    for (int eye = 0; eye < 2 && alpha > 0 && r == GS_OK; eye++)
        r = blend_eye(s, rgb, stride, width, height, &st, eye, alpha, err);
    gs_live_status *S = &s->status;
    S->frames++;
    S->faces += (uint64_t)face;
    S->detections += (uint64_t)st.detected;
    S->losses += (uint64_t)(!st.face && S->face);
    S->face = face;
    S->weight = alpha;
    S->policy_weight = po.weight;
    S->head_pitch = (float)st.pose.pitch;
    S->head_yaw = (float)st.pose.yaw;
    S->target_pitch = pitch;
    S->target_yaw = yaw;
    S->patch_age_s = alpha > 0 ? age : -1;
    S->openness = (float)st.openness;
    pthread_mutex_unlock(&s->lock);
    if (fr != GS_OK && r == GS_OK)
        r = gs_error_set(err, fr, "live: cannot queue a fit");
    return r;
}

static int stage_cb(void *ctx, uint8_t *rgb, size_t stride, int w, int h, int64_t t,
                    gs_error *err)
{
    return gs_live_stage_process(ctx, rgb, stride, w, h, t, err);
}

gs_cap_stage gs_live_stage_as_cap(gs_live_stage *s)
{
    gs_cap_stage c = {s, stage_cb};
    return c;
}
