/* The eye-contact stage behind fakes: tracking seeded from the previous
 * landmarks (no detection while tracking), loss and re-detection, eye
 * openness, the camera gaze, the similarity warp and masked blend, and the
 * asynchronous stage with a slow fake renderer (frames never wait for it,
 * stale patches fade, blinks show the real eyes, a changed person refits).
 * Landmarks come from the synthetic head's exact labels. */
#define _POSIX_C_SOURCE 200809L
#include <math.h>
#include <pthread.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "gazesplat/live.h"
#include "gazesplat/synth.h"
#include "gs_test.h"

#define W 640
#define H 480
#define DEG (3.14159265358979323846 / 180.0)

/* ---- a fake face: landmarks of the synthetic head ---- */

typedef struct fake_face {
    int present;
    double uv[GS_FACE_LANDMARKS][2];
    const uint8_t *base;       /* the full frame (to place crops) */
    int detects, crop_detects, predicts;
    pthread_mutex_t mu;
} fake_face;

static void synth_landmarks(double pitch_deg, double yaw_deg, double dx, double uv[][2])
{
    gs_synth_scene sc;
    gs_synth_scene_default(&sc, 600.0);
    gs_geom_rot_from_pitchyaw(pitch_deg * DEG, yaw_deg * DEG, 0.0, sc.head_R);
    gs_synth_camera cam;
    memset(&cam, 0, sizeof cam);
    gs_face_default_intrinsics(W, H, cam.K);
    gs_geom_mat3_identity(cam.R);
    cam.width = W;
    cam.height = H;
    gs_synth_labels lab;
    CHECK_EQ_INT(gs_synth_labels_compute(&sc, &cam, &lab, NULL), GS_OK);
    for (int i = 0; i < GS_FACE_LANDMARKS; i++) {
        uv[i][0] = lab.lm2d[i][0] + dx;
        uv[i][1] = lab.lm2d[i][1];
    }
}

static void bounds(const double uv[][2], double *cx, double *cy, double *side)
{
    double x0 = 1e9, x1 = -1e9, y0 = 1e9, y1 = -1e9;
    for (int i = 0; i < GS_FACE_LANDMARKS; i++) {
        x0 = fmin(x0, uv[i][0]);
        x1 = fmax(x1, uv[i][0]);
        y0 = fmin(y0, uv[i][1]);
        y1 = fmax(y1, uv[i][1]);
    }
    *cx = (x0 + x1) / 2;
    *cy = (y0 + y1) / 2;
    *side = fmax(x1 - x0, y1 - y0);
}

static int fake_detect(void *ctx, const gs_io_image *img, int min_size, gs_face_box *box,
                       int *found, gs_error *err)
{
    (void)err;
    fake_face *f = ctx;
    pthread_mutex_lock(&f->mu);
    size_t off = (size_t)(img->data - f->base);
    int ox = (int)(off % img->stride) / 3, oy = (int)(off / img->stride);
    if (ox || oy || img->width != W)
        f->crop_detects++;
    else
        f->detects++;
    double cx, cy, side;
    bounds((const double(*)[2])f->uv, &cx, &cy, &side);
    /* A box 1.2x the landmarks, a little lower (like dlib's). */
    int s = (int)lround(1.2 * side);
    box->left = (int)lround(cx - s / 2.0) - ox;
    box->top = (int)lround(cy - s / 2.0 + 0.05 * side) - oy;
    box->right = box->left + s - 1;
    box->bottom = box->top + s - 1;
    *found = f->present && s >= min_size && box->left >= 0 && box->top >= 0 &&
             box->right < img->width && box->bottom < img->height;
    pthread_mutex_unlock(&f->mu);
    return GS_OK;
}

/* Like a regression-tree predictor: the true points when the box covers
 * the face, else a face-shaped guess that follows the box (here: the
 * true shape squeezed into the box's middle). */
static int fake_landmarks(void *ctx, const gs_io_image *img, gs_face_box b, double uv[][2],
                          gs_error *err)
{
    (void)img, (void)err;
    fake_face *f = ctx;
    pthread_mutex_lock(&f->mu);
    f->predicts++;
    double cx, cy, side;
    bounds((const double(*)[2])f->uv, &cx, &cy, &side);
    double bcx = (b.left + b.right) / 2.0 + 0.5, bcy = (b.top + b.bottom) / 2.0 + 0.5;
    int covers = f->present && fabs(bcx - cx) < 0.25 * side && fabs(bcy - cy) < 0.3 * side;
    double sc = covers ? 1.0 : 0.8 * (b.right - b.left + 1) / 1.2 / side;
    for (int i = 0; i < GS_FACE_LANDMARKS; i++) {
        uv[i][0] = covers ? f->uv[i][0] : bcx + sc * (f->uv[i][0] - cx);
        uv[i][1] = covers ? f->uv[i][1] : bcy + sc * (f->uv[i][1] - cy);
    }
    pthread_mutex_unlock(&f->mu);
    return GS_OK;
}

static gs_live_track_ops fake_ops(fake_face *f)
{
    gs_live_track_ops o = {f, fake_detect, fake_landmarks};
    return o;
}

static void fake_init(fake_face *f, const uint8_t *base)
{
    memset(f, 0, sizeof *f);
    pthread_mutex_init(&f->mu, NULL);
    f->base = base;
    f->present = 1;
    synth_landmarks(0, 0, 0, f->uv);
}

static void fake_move(fake_face *f, double pitch, double yaw, double dx)
{
    pthread_mutex_lock(&f->mu);
    synth_landmarks(pitch, yaw, dx, f->uv);
    pthread_mutex_unlock(&f->mu);
}

/* ---- tracking ---- */

static void test_tracking(void)
{
    static uint8_t frame[W * H * 3];
    fake_face f;
    fake_init(&f, frame);
    gs_live_track_ops ops = fake_ops(&f);
    gs_live_track_config tc = gs_live_track_config_default();
    tc.verify_every = 4;
    gs_live_track *t = NULL;
    CHECK_EQ_INT(gs_live_track_create(&tc, &ops, &t, NULL), GS_OK);
    gs_io_image img = {W, H, 3 * W, frame};
    double k[9];
    gs_face_default_intrinsics(W, H, k);
    gs_live_track_state st;

    CHECK_EQ_INT(gs_live_track_update(t, &img, k, &st, NULL), GS_OK);
    CHECK(st.face && st.detected && st.track_id == 1);
    CHECK_EQ_INT(f.detects, 1);
    /* The seeded box reproduces the detector's framing of the same face. */
    gs_face_box seed = gs_live_track_seed_box(t, (const double(*)[2])st.uv);
    CHECK_MSG(abs(seed.left - st.box.left) <= 1 && abs(seed.top - st.box.top) <= 1 &&
                  abs(seed.right - st.box.right) <= 1,
              "seed box %d,%d,%d vs detector %d,%d,%d", seed.left, seed.top, seed.right,
              st.box.left, st.box.top, st.box.right);
    /* Smooth motion: followed from the previous landmarks, no full detection. */
    for (int i = 1; i <= 12; i++) {
        fake_move(&f, 0, i, 4.0 * i);
        CHECK_EQ_INT(gs_live_track_update(t, &img, k, &st, NULL), GS_OK);
        CHECK_MSG(st.face && !st.detected, "frame %d: face %d detected %d", i, st.face,
                  st.detected);
        CHECK_CLOSE(st.uv[30][0], f.uv[30][0], 1e-9, 0);
    }
    CHECK_EQ_INT(f.detects, 1);
    CHECK_MSG(f.crop_detects == 3, "confirming detections %d (expected 12/4)", f.crop_detects);
    /* PnP of the generic 6-point model on this head is rough (docs/face.md):
     * only the direction is checked. */
    CHECK_MSG(st.pose.yaw > 5 * DEG, "head yaw %g deg for 12", st.pose.yaw / DEG);
    CHECK(st.openness > 0.5);
    /* A jump the seeded box cannot follow: the predictor still returns a
     * face-shaped guess in the old box, the confirming detection on its
     * crop finds nothing, and the full detector re-acquires in that frame. */
    fake_move(&f, 0, 0, -150);
    int found_after = -1;
    for (int i = 1; i <= 4 && found_after < 0; i++) {
        CHECK_EQ_INT(gs_live_track_update(t, &img, k, &st, NULL), GS_OK);
        if (st.detected)
            found_after = i;
    }
    CHECK_MSG(found_after >= 1 && st.face && st.track_id == 2,
              "re-detected after %d frames, face %d track %llu", found_after, st.face,
              (unsigned long long)st.track_id);
    CHECK_EQ_INT(f.detects, 2);
    CHECK_CLOSE(st.uv[30][0], f.uv[30][0], 1e-9, 0);
    /* The face leaves: the landmarks still look like a face in the old box,
     * so only the confirming detection notices, within verify_every frames. */
    f.present = 0;
    int lost_after = -1;
    for (int i = 1; i <= 6 && lost_after < 0; i++) {
        CHECK_EQ_INT(gs_live_track_update(t, &img, k, &st, NULL), GS_OK);
        if (!st.face)
            lost_after = i;
    }
    CHECK_MSG(lost_after >= 1 && lost_after <= 4, "lost after %d frames", lost_after);
    CHECK(st.detected);
    /* Comes back: acquired with a new track id. */
    f.present = 1;
    CHECK_EQ_INT(gs_live_track_update(t, &img, k, &st, NULL), GS_OK);
    CHECK(st.face && st.track_id == 3);
    gs_live_track_destroy(t);
    pthread_mutex_destroy(&f.mu);
}

static void test_measures(void)
{
    double uv[GS_FACE_LANDMARKS][2];
    synth_landmarks(0, 0, 0, uv);
    double open = gs_live_eye_openness((const double(*)[2])uv);
    for (int i = 36; i < 48; i++) /* close the lids: squash toward the corner line */
        uv[i][1] = 0.5 * (uv[i < 42 ? 36 : 42][1] + uv[i < 42 ? 39 : 45][1]);
    double closed = gs_live_eye_openness((const double(*)[2])uv);
    CHECK_MSG(open > 0.6 && closed < 0.05, "openness open %g closed %g", open, closed);

    double R[9], t[3] = {0, 0, 600}, p, y;
    gs_geom_mat3_identity(R);
    CHECK_EQ_INT(gs_live_camera_gaze(R, t, &p, &y), GS_OK);
    CHECK_CLOSE(y, 0.0, 0.2 * DEG, 0);
    CHECK_MSG(p < 0 && p > -5 * DEG, "frontal head: camera gaze pitch %g deg", p / DEG);
    gs_geom_rot_from_pitchyaw(0, 20 * DEG, 0, R);
    CHECK_EQ_INT(gs_live_camera_gaze(R, t, &p, &y), GS_OK);
    CHECK_CLOSE(y, -20 * DEG, 1 * DEG, 0);
    gs_geom_rot_from_pitchyaw(10 * DEG, 0, 0, R);
    CHECK_EQ_INT(gs_live_camera_gaze(R, t, &p, &y), GS_OK);
    CHECK_CLOSE(p, -10 * DEG, 4 * DEG, 0);
}

/* ---- warp ---- */

static void test_warp(void)
{
    double d0[2] = {10, 20}, d1[2] = {40, 24}, m[4];
    double a = 0.7 * cos(0.3), b = 0.7 * sin(0.3);
    double s0[2] = {a * d0[0] - b * d0[1] + 5, b * d0[0] + a * d0[1] - 3};
    double s1[2] = {a * d1[0] - b * d1[1] + 5, b * d1[0] + a * d1[1] - 3};
    CHECK_EQ_INT(gs_live_similarity(d0, d1, s0, s1, m), GS_OK);
    CHECK_CLOSE(m[0], a, 1e-12, 0);
    CHECK_CLOSE(m[1], b, 1e-12, 0);
    CHECK_CLOSE(m[2], 5, 1e-9, 0);
    CHECK_CLOSE(m[3], -3, 1e-9, 0);
    CHECK_EQ_INT(gs_live_similarity(d0, d0, s0, s1, m), GS_ERR_ARG);

    /* Patch: a horizontal ramp 0..252; frame grey 100. Translation by (+8,
     * +2): frame pixel x samples patch column x+8. */
    enum { PW = 64, FW = 32, FH = 16 };
    static uint8_t patch[PW * PW * 3], frame[FW * FH * 3], mask[FW * FH];
    for (int y = 0; y < PW; y++)
        for (int x = 0; x < PW; x++)
            memset(patch + 3 * (y * PW + x), 4 * x, 3);
    memset(frame, 100, sizeof frame);
    memset(mask, 255, sizeof mask);
    mask[0] = 0;
    double mt[4] = {1, 0, 8, 2};
    gs_live_blend_patch(frame, 3 * FW, FW, FH, 0, 0, FW, FH, mask, patch, 3 * PW, PW, PW, mt,
                        0.5f);
    CHECK_EQ_INT(frame[0], 100); /* mask 0 */
    int bad = 0;
    for (int x = 1; x < FW; x++) {
        int want = (int)lround(100 + 0.5 * (4 * (x + 8) - 100));
        bad += abs(frame[3 * x] - want) > 1;
    }
    CHECK_MSG(bad == 0, "%d blended pixels off", bad);
    /* A transform pointing outside the patch leaves the frame alone. */
    memset(frame, 100, sizeof frame);
    double far[4] = {1, 0, 500, 0};
    gs_live_blend_patch(frame, 3 * FW, FW, FH, 0, 0, FW, FH, mask, patch, 3 * PW, PW, PW, far,
                        1.0f);
    CHECK_EQ_INT(frame[3 * 5], 100);
}

/* ---- the stage with a slow fake engine ---- */

typedef struct fake_engine {
    pthread_mutex_t mu;
    int fits, renders;
    int frozen;            /* renders fail while set (a stalled worker) */
    int busy;              /* a render is in its 150 ms */
    unsigned started;      /* renders started */
    double fit_jaw;        /* jaw width of the fitted face (person check) */
} fake_engine;

static void sleep_ms(int ms)
{
    struct timespec ts = {ms / 1000, (long)(ms % 1000) * 1000000L};
    nanosleep(&ts, NULL);
}

static int fe_fit(void *ctx, const gs_io_image *frame, const gs_live_track_state *st,
                  const double k[9], gs_live_subject *out, gs_error *err)
{
    (void)frame, (void)k, (void)err;
    fake_engine *e = ctx;
    sleep_ms(40);
    memset(out, 0, sizeof *out);
    /* The render's eye corners: the frame's, scaled into 128 px. */
    static const int idx[4] = {36, 39, 42, 45};
    for (int i = 0; i < 4; i++) {
        out->corners_n[i][0] = (st->uv[idx[i]][0] - 320) * 0.5 + 64;
        out->corners_n[i][1] = (st->uv[idx[i]][1] - 240) * 0.5 + 64;
    }
    pthread_mutex_lock(&e->mu);
    e->fits++;
    pthread_mutex_unlock(&e->mu);
    return GS_OK;
}

static int fe_render(void *ctx, const gs_live_subject *s, double pitch, double yaw,
                     uint8_t *rgb, gs_error *err)
{
    (void)s, (void)pitch, (void)yaw;
    fake_engine *e = ctx;
    pthread_mutex_lock(&e->mu);
    e->busy = 1;
    e->started++;
    pthread_mutex_unlock(&e->mu);
    sleep_ms(150);
    pthread_mutex_lock(&e->mu);
    e->busy = 0;
    int frozen = e->frozen;
    if (!frozen)
        e->renders++;
    pthread_mutex_unlock(&e->mu);
    if (frozen)
        return gs_error_set(err, GS_ERR_IO, "frozen");
    memset(rgb, 250, 128 * 128 * 3);
    return GS_OK;
}

static double mono_ms(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return ts.tv_sec * 1e3 + ts.tv_nsec / 1e6;
}

typedef struct rig {
    uint8_t *frame;
    fake_face face;
    fake_engine eng;
    gs_cap_policy *policy;
    gs_live_stage *stage;
    int64_t t;
    double max_ms;
    int during;   /* frames begun and finished inside one render */
} rig;

/* Whether a render is running, and which one. */
static void render_state(fake_engine *e, int *busy, unsigned *which)
{
    pthread_mutex_lock(&e->mu);
    *busy = e->busy;
    *which = e->started;
    pthread_mutex_unlock(&e->mu);
}

/* One frame 33 ms after the previous (capture clock); the wall clock
 * advances too so the worker gets time. Returns the frame's eye pixel. */
static int step(rig *r, int sleep)
{
    memset(r->frame, 60, (size_t)W * H * 3);
    r->t += 33333333;
    int b0, b1;
    unsigned n0, n1;
    render_state(&r->eng, &b0, &n0);
    double t0 = mono_ms();
    CHECK_EQ_INT(gs_live_stage_process(r->stage, r->frame, 3 * W, W, H, r->t, NULL), GS_OK);
    double ms = mono_ms() - t0;
    render_state(&r->eng, &b1, &n1);
    r->during += b0 && b1 && n0 == n1;
    r->max_ms = ms > r->max_ms ? ms : r->max_ms;
    if (sleep)
        sleep_ms(30);
    /* the right eye's centre */
    int x = (int)((r->face.uv[36][0] + r->face.uv[39][0]) / 2);
    int y = (int)((r->face.uv[37][1] + r->face.uv[41][1]) / 2);
    return r->frame[(size_t)y * 3 * W + 3 * (size_t)x];
}

static void test_stage(void)
{
    rig r;
    memset(&r, 0, sizeof r);
    r.frame = calloc((size_t)W * H * 3, 1);
    fake_init(&r.face, r.frame);
    pthread_mutex_init(&r.eng.mu, NULL);
    gs_live_engine eng = {&r.eng, 128, fe_fit, fe_render};
    gs_cap_policy_config pc = gs_cap_policy_config_default();
    pc.smooth_s = 0.0f;
    CHECK_EQ_INT(gs_cap_policy_create(&pc, &r.policy, NULL), GS_OK);
    gs_live_config c = gs_live_config_default();
    gs_live_track_ops ops = fake_ops(&r.face);
    CHECK_EQ_INT(gs_live_stage_create(&c, &ops, &eng, r.policy, &r.stage, NULL), GS_OK);

    /* Pass-through until fitted and rendered. */
    int v = step(&r, 1);
    CHECK_EQ_INT(v, 60);
    gs_live_status s;
    int frames = 1;
    for (; frames < 60; frames++) {
        v = step(&r, 1);
        gs_live_stage_get_status(r.stage, &s);
        if (v != 60)
            break;
    }
    CHECK_MSG(v > 200, "eye pixel %d after %d frames (fits %llu renders %llu)", v, frames,
              (unsigned long long)s.fits, (unsigned long long)s.renders);
    CHECK(s.subject_ready && s.fits == 1 && s.face);
    /* Frames ran while a 150 ms render was in flight, never waiting for it. */
    for (int i = 0; i < 20; i++) {
        fake_move(&r.face, 0, 0.2 * i, 0); /* small head motion: new targets */
        step(&r, 1);
    }
    for (int i = 0; i < 12; i++) /* still: the newest patch catches up */
        step(&r, 1);
    gs_live_stage_get_status(r.stage, &s);
    /* Evidence without a clock bound (timings vary with the machine's
     * load and sanitizers): frames began and finished while one render was
     * in flight, which a frame path that waited for renders cannot do. */
    CHECK_MSG(r.during >= 3, "only %d frames ran inside a render (slowest frame "
              "%.1f ms, render 150 ms)", r.during, r.max_ms);
    CHECK_MSG(s.renders >= 2 && s.renders < s.frames / 3,
              "renders %llu for %llu frames (asynchronous, newest only)",
              (unsigned long long)s.renders, (unsigned long long)s.frames);

    /* Blink: the real eyes show (weight 0), the correction returns after. */
    double open_uv[GS_FACE_LANDMARKS][2];
    memcpy(open_uv, r.face.uv, sizeof open_uv);
    for (int i = 36; i < 48; i++)
        r.face.uv[i][1] = 0.5 * (open_uv[i < 42 ? 36 : 42][1] + open_uv[i < 42 ? 39 : 45][1]);
    v = step(&r, 0);
    CHECK_MSG(v == 60, "eye pixel %d during a blink", v);
    memcpy(r.face.uv, open_uv, sizeof open_uv);
    v = step(&r, 0);
    CHECK_MSG(v > 200, "eye pixel %d right after the blink", v);

    /* Stalled renders and a new target: the patch fades with its age. */
    pthread_mutex_lock(&r.eng.mu);
    r.eng.frozen = 1;
    pthread_mutex_unlock(&r.eng.mu);
    fake_move(&r.face, 0, 8, 0);
    float last_w = 1;
    for (int i = 0; i < 25; i++) {
        step(&r, 0);
        gs_live_stage_get_status(r.stage, &s);
        CHECK_MSG(s.weight <= last_w + 1e-6, "weight rose %g -> %g while stale", last_w, s.weight);
        last_w = s.weight;
    }
    CHECK_MSG(s.weight == 0.0f, "stale patch still blended at %g", s.weight);

    /* Another person (wider jaw, kept for change_s): refit. */
    pthread_mutex_lock(&r.eng.mu);
    r.eng.frozen = 0;
    pthread_mutex_unlock(&r.eng.mu);
    fake_move(&r.face, 0, 0, 0);
    for (int i = 0; i <= 16; i++)
        r.face.uv[i][0] = r.face.uv[30][0] + 1.3 * (r.face.uv[i][0] - r.face.uv[30][0]);
    for (int i = 0; i < 60; i++) {
        step(&r, 1);
        gs_live_stage_get_status(r.stage, &s);
        if (s.fits == 2)
            break;
    }
    CHECK_MSG(s.refits == 1 && s.fits == 2, "refits %llu fits %llu", (unsigned long long)s.refits,
              (unsigned long long)s.fits);

    /* Off: the policy fades the correction out. */
    pc.enabled = 0;
    CHECK_EQ_INT(gs_cap_policy_set(r.policy, &pc, NULL), GS_OK);
    v = step(&r, 0);
    CHECK_EQ_INT(v, 60);

    gs_live_stage_destroy(r.stage);
    gs_cap_policy_destroy(r.policy);
    pthread_mutex_destroy(&r.eng.mu);
    pthread_mutex_destroy(&r.face.mu);
    free(r.frame);
}

int main(void)
{
    test_tracking();
    test_measures();
    test_warp();
    test_stage();
    GS_TEST_END();
}
