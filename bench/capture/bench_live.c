/* bench_live: the whole live pipeline with eye contact on: the tests' fake
 * 30 fps V4L2 camera (real clock) -> the eye-contact stage (real face
 * detector and landmark model, the real model) -> the fake loopback. Each
 * frame's pixels are replaced by one of a few pre-rendered synthetic heads
 * turning slowly (a memcpy, counted in the stage time), so the tracker
 * follows motion and the gaze target keeps changing.
 *
 * Phase 1 runs until the background fit is done (not measured); phase 2
 * restarts the pipeline with the fitted stage and measures `seconds`:
 * output fps, added latency (frame timestamp -> written) p50/p99, CPU use,
 * eye renders per second and the blend weight.
 *
 * --still keeps the head frontal and still: the patch stays exact, no
 * renders are needed after the first.
 *
 * usage: bench_live --model M [--seconds S] [--fit-budget S] [--still] */
#define _GNU_SOURCE
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/resource.h>
#include <time.h>

#include "fake_v4l2.h"
#include "gazesplat/live.h"
#include "gazesplat/synth.h"

#define W 640
#define H 480
#define NPOSE 9

static double now_s(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + (double)ts.tv_nsec / 1e9;
}

static double cpu_s(void)
{
    struct rusage ru;
    getrusage(RUSAGE_SELF, &ru);
    return (double)ru.ru_utime.tv_sec + (double)ru.ru_utime.tv_usec / 1e6 +
           (double)ru.ru_stime.tv_sec + (double)ru.ru_stime.tv_usec / 1e6;
}

#define MAXS 4096
typedef struct scene {
    uint8_t *frames[NPOSE]; /* head yaw -4..4 deg */
    int n, still;           /* still: always the frontal head */
    gs_live_stage *stage;
    /* CPU time (this thread's, so load on the machine does not count) */
    double stage_cpu[MAXS];
    int nstage;
    gs_live_engine inner;   /* the real engine, wrapped to time renders */
    double render_cpu, render_wall;
    int nrender;
} scene;

static double thread_cpu_s(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
    return (double)ts.tv_sec + (double)ts.tv_nsec / 1e9;
}

static int cmp_d(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

static int timed_fit(void *ctx, const gs_io_image *f, const gs_live_track_state *st,
                     const double k[9], gs_live_subject *out, gs_error *err)
{
    scene *s = ctx;
    return s->inner.fit(s->inner.ctx, f, st, k, out, err);
}

static int timed_render(void *ctx, const gs_live_subject *subj, double p, double y, uint8_t *rgb,
                        gs_error *err)
{
    scene *s = ctx;
    double c0 = thread_cpu_s(), t0 = now_s();
    int r = s->inner.render(s->inner.ctx, subj, p, y, rgb, err);
    s->render_cpu += thread_cpu_s() - c0;
    s->render_wall += now_s() - t0;
    s->nrender++;
    return r;
}

/* Paints the next synthetic head (back and forth, one pose step every 3
 * frames: about 10 deg/s), then runs the eye-contact stage. */
static int bench_stage(void *ctx, uint8_t *rgb, size_t stride, int w, int h, int64_t t,
                       gs_error *err)
{
    scene *s = ctx;
    int k = (s->n++ / 3) % (2 * NPOSE - 2);
    int i = s->still ? NPOSE / 2 : k < NPOSE ? k : 2 * NPOSE - 2 - k;
    for (int y = 0; y < h; y++)
        memcpy(rgb + (size_t)y * stride, s->frames[i] + (size_t)y * 3 * W, 3 * (size_t)w);
    double c0 = thread_cpu_s();
    int r = gs_live_stage_process(s->stage, rgb, stride, w, h, t, err);
    if (s->nstage < MAXS)
        s->stage_cpu[s->nstage++] = thread_cpu_s() - c0;
    return r;
}

static int render_heads(scene *s, gs_error *e)
{
    gs_synth_camera cam;
    memset(&cam, 0, sizeof cam);
    gs_face_default_intrinsics(W, H, cam.K);
    gs_geom_mat3_identity(cam.R);
    cam.width = W;
    cam.height = H;
    for (int i = 0; i < NPOSE; i++) {
        gs_synth_scene sc;
        gs_synth_scene_default(&sc, 600.0);
        gs_geom_rot_from_pitchyaw(0.0, (i - NPOSE / 2) * 0.0175, 0.0, sc.head_R);
        sc.gaze_pitch = -0.15; /* looking at a screen below the camera */
        gs_synth_sample smp;
        int r = gs_synth_sample_alloc(&smp, W, H, e);
        if (r == GS_OK)
            r = gs_synth_render(&sc, &cam, NULL, NULL, &smp, e);
        if (r != GS_OK) {
            gs_synth_sample_free(&smp);
            return r;
        }
        s->frames[i] = malloc(3 * (size_t)W * H);
        for (int y = 0; y < H && s->frames[i]; y++)
            memcpy(s->frames[i] + (size_t)y * 3 * W, smp.rgb + (size_t)y * smp.stride, 3 * W);
        gs_synth_sample_free(&smp);
        if (!s->frames[i])
            return GS_ERR_NOMEM;
    }
    return GS_OK;
}

typedef struct rig {
    fake_v4l2 cam, out;
    gs_cap *cap;
    gs_cap_out *o;
    gs_cap_pipe *p;
} rig;

static int rig_start(rig *r, scene *s, gs_error *e)
{
    fake_init(&r->cam);
    fake_init(&r->out);
    r->cam.real_clock = r->out.real_clock = 1;
    r->cam.auto_produce = 1;
    r->cam.max_fps = 240;
    gs_cap_config c = gs_cap_config_default("synthetic");
    c.width = W;
    c.height = H;
    c.fps = 30;
    c.ops = &r->cam.ops;
    int rc = gs_cap_create(&c, &r->cap, e);
    if (rc == GS_OK)
        rc = gs_cap_out_create("loopback", W, H, 30, &r->out.ops, &r->o, e);
    gs_cap_pipe_config pc = {r->cap, {s, bench_stage}, r->o, 2, NULL, NULL, NULL, -1};
    if (rc == GS_OK)
        rc = gs_cap_pipe_start(&pc, &r->p, e);
    return rc;
}

static void rig_stop(rig *r)
{
    gs_cap_pipe_stop(r->p);
    gs_cap_out_destroy(r->o);
    gs_cap_destroy(r->cap);
    fake_free(&r->cam);
    fake_free(&r->out);
}

static void sleep_s(double s)
{
    struct timespec ts = {(time_t)s, (long)((s - (double)(time_t)s) * 1e9)};
    nanosleep(&ts, NULL);
}

int main(int argc, char **argv)
{
    const char *model_path = NULL;
    double seconds = 10, budget = 20;
    int still = 0;
    for (int i = 1; i < argc; i++)
        if (!strcmp(argv[i], "--still")) { /* a flag: drop it from the pairs */
            still = 1;
            for (int j = i; j + 1 < argc; j++)
                argv[j] = argv[j + 1];
            argc--;
        }
    for (int i = 1; i + 1 < argc; i += 2) {
        if (!strcmp(argv[i], "--model"))
            model_path = argv[i + 1];
        else if (!strcmp(argv[i], "--seconds"))
            seconds = atof(argv[i + 1]);
        else if (!strcmp(argv[i], "--fit-budget"))
            budget = atof(argv[i + 1]);
    }
    if (!model_path) {
        fprintf(stderr, "usage: bench_live --model M [--seconds S] [--fit-budget S] [--still]\n");
        return 2;
    }
    gs_error e = {0};
    scene s;
    memset(&s, 0, sizeof s);
    s.still = still;
    gs_model *m = NULL;
    gs_face_shape_model *sp = NULL;
    gs_face_detector *det = NULL;
    gs_cap_policy *pol = NULL;
    gs_live_engine eng = {0};
    gs_live_face_models fm;
    int r = render_heads(&s, &e);
    if (r == GS_OK)
        r = gs_model_load(model_path, &m, &e);
    if (r == GS_OK)
        r = gs_face_shape_model_load(NULL, &sp, &e);
    if (r == GS_OK)
        r = gs_face_detector_load(NULL, &det, &e);
    if (r == GS_OK)
        r = gs_cap_policy_create(NULL, &pol, &e);
    if (r == GS_OK)
        r = gs_live_engine_model(m, NULL, budget, &eng, &e);
    fm.det = det;
    fm.sp = sp;
    gs_live_track_ops ops = gs_live_track_ops_face(&fm);
    s.inner = eng;
    gs_live_engine timed = {&s, eng.image_size, timed_fit, timed_render};
    if (r == GS_OK)
        r = gs_live_stage_create(NULL, &ops, &timed, pol, &s.stage, &e);
    if (r != GS_OK) {
        fprintf(stderr, "bench_live: %s\n", e.msg);
        return 1;
    }
    /* Phase 1: until the subject is fitted (pass-through meanwhile). */
    rig a;
    memset(&a, 0, sizeof a);
    double t0 = now_s();
    if (rig_start(&a, &s, &e) != GS_OK) {
        fprintf(stderr, "bench_live: %s\n", e.msg);
        return 1;
    }
    gs_live_status st;
    do {
        sleep_s(0.5);
        gs_live_stage_get_status(s.stage, &st);
    } while (!st.subject_ready && now_s() - t0 < budget + 60 && st.fit_failures < 3);
    gs_cap_pipe_stats ps;
    gs_cap_pipe_get_stats(a.p, &ps);
    rig_stop(&a);
    printf("phase 1 (pass-through while fitting): %.1f s, subject %s after %.1f s fit, "
           "stage p50 %.2f ms p99 %.2f ms, faces %llu of %llu frames, detections %llu\n",
           now_s() - t0, st.subject_ready ? "ready" : "NOT ready", st.last_fit_s,
           ps.process.p50_ms, ps.process.p99_ms, (unsigned long long)st.faces,
           (unsigned long long)st.frames, (unsigned long long)st.detections);
    /* Phase 2: measured. */
    gs_live_status s0 = st;
    rig b;
    memset(&b, 0, sizeof b);
    if (rig_start(&b, &s, &e) != GS_OK) {
        fprintf(stderr, "bench_live: %s\n", e.msg);
        return 1;
    }
    double t1 = now_s(), c1 = cpu_s();
    s.nstage = 0;
    s.render_cpu = s.render_wall = 0;
    s.nrender = 0;
    double wsum = 0;
    int wn = 0;
    while (now_s() - t1 < seconds) { /* sample the blend weight */
        sleep_s(0.1);
        gs_live_stage_get_status(s.stage, &st);
        wsum += st.weight;
        wn++;
    }
    gs_cap_pipe_get_stats(b.p, &ps);
    gs_live_stage_get_status(s.stage, &st);
    double t2 = now_s(), c2 = cpu_s();
    rig_stop(&b);
    double dt = t2 - t1;
    printf("phase 2: synthetic %dx%d at 30 fps, eye contact on, head %s, %.1f s\n", W, H,
           still ? "still" : "turning +-4 deg at 10 deg/s", dt);
    printf("fps out %.1f (in %.1f), ring drops %llu\n", (double)ps.out / dt, (double)ps.in / dt,
           (unsigned long long)ps.ring_drops);
    printf("added latency ms (frame timestamp -> written): p50 %.2f p99 %.2f max %.2f\n",
           ps.total.p50_ms, ps.total.p99_ms, ps.total.max_ms);
    printf("  stage (track + policy + blend) p50 %.2f p99 %.2f max %.2f\n", ps.process.p50_ms,
           ps.process.p99_ms, ps.process.max_ms);
    printf("eye renders %.1f/s (%llu), faces %llu of %llu frames, last weight %.2f\n",
           (double)(st.renders - s0.renders) / dt, (unsigned long long)(st.renders - s0.renders),
           (unsigned long long)(st.faces - s0.faces), (unsigned long long)(st.frames - s0.frames),
           (double)st.weight);
    qsort(s.stage_cpu, (size_t)s.nstage, sizeof(double), cmp_d);
    if (s.nstage)
        printf("stage CPU per frame (thread time, load-independent) p50 %.2f ms p99 %.2f ms; "
               "render CPU %.1f ms (wall %.1f ms) per render; mean blend weight %.2f\n",
               1e3 * s.stage_cpu[s.nstage / 2], 1e3 * s.stage_cpu[(s.nstage - 1) * 99 / 100],
               s.nrender ? 1e3 * s.render_cpu / s.nrender : 0.0,
               s.nrender ? 1e3 * s.render_wall / s.nrender : 0.0, wn ? wsum / wn : 0.0);
    double la[3] = {0, 0, 0};
    FILE *lf = fopen("/proc/loadavg", "r");
    if (lf) {
        if (fscanf(lf, "%lf %lf %lf", &la[0], &la[1], &la[2]) != 3)
            la[0] = 0;
        fclose(lf);
    }
    printf("machine load average %.1f during the run\n", la[0]);
    printf("cpu %.0f%% of one core (%.2f s over %.2f s; the render worker included)\n",
           100.0 * (c2 - c1) / dt, c2 - c1, dt);
    gs_live_stage_destroy(s.stage);
    gs_live_engine_model_free(&eng);
    gs_cap_policy_destroy(pol);
    gs_face_detector_destroy(det);
    gs_face_shape_model_destroy(sp);
    gs_model_destroy(m);
    for (int i = 0; i < NPOSE; i++)
        free(s.frames[i]);
    return 0;
}
