/* Gaze-sweep benchmark of gs_model_render: full renders against
 * incremental ones (same subject and head pose, only the gaze changes: the
 * eye stream's tiles are re-rasterized and the renderer re-runs over their
 * reach), on the calling thread and on a gs_pool of 2 threads.
 *
 *   bench_model_render [--model FILE] [--reps N] [--quick] [--threads N]
 *                      [--only full|inc] [--prune K] [--feature-scale S]
 *
 * --threads N times pools of 1 and N threads (default 2); --only runs one
 * path (for a profiler: `perf record` or callgrind over the loop alone).
 * --prune K renders with the K most important face Gaussians
 * (gs_model_prune) and --feature-scale S with the feature map rasterized at
 * S x its size (gs_model_ctx_set_render_options; off 1 the "incremental"
 * column renders in full too), for the render side of the speed grid.
 * Without --model, a cpu-preset model as initialised (the timing does not
 * depend on training). A model
 * trained with BLOCK guidance renders in full either way; the bench then
 * switches it to the face-stream source to time the incremental path.
 * Prints a Markdown table: median ms per image over reps of a 5 x 5 gaze
 * grid, images/s, the speed-up, and the largest 8-bit difference between
 * the incremental and the full image of the same view (the error side of
 * the trade: it should be 0 or 1). The configurations run interleaved. */
#define _POSIX_C_SOURCE 200809L
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "../bench_util.h"
#include "bench_model.h"
#include "gazesplat/geom.h"
#include "gazesplat/model.h"
#include "gazesplat/nn.h"
#include "gazesplat/pool.h"
#include "gazesplat/train.h"

#define BENCH_PI 3.14159265358979323846

enum { GRID = 5, NVIEW = GRID * GRID, MAX_REPS = 64 };

static void die(const char *what, const gs_error *err)
{
    fprintf(stderr, "bench_model_render: %s: %s\n", what, err ? err->msg : "");
    exit(1);
}

/* One pass over the gaze grid. full: a fresh head offset per view so that
 * nothing is reused; otherwise one pose for the whole grid. Returns ms per
 * image; images go to out[NVIEW][...] when out is not NULL. */
static double pass(gs_model_ctx *c, gs_pool *pool, const gs_subject *s,
                   int full, int S, uint8_t *out, int *rep_no, double *cpu)
{
    gs_error err = {0, ""};
    double t0 = now_ms(), c0 = cpu_ms();
    for (int k = 0; k < NVIEW; k++) {
        gs_view v = {0};
        v.gaze_pitch = (-20.0 + 10.0 * (k / GRID)) * BENCH_PI / 180;
        v.gaze_yaw = (-30.0 + 15.0 * (k % GRID)) * BENCH_PI / 180;
        v.use_head = 1;
        memcpy(v.head_R, s->head_R, sizeof v.head_R);
        memcpy(v.head_t, s->head_t, sizeof v.head_t);
        if (full) /* a different pose each time: nothing to reuse */
            v.head_t[0] += 1e-3 * (1 + (*rep_no)++ % 1000);
        uint8_t *dst = out ? out + (size_t)k * 3 * S * S : NULL;
        static uint8_t *scratch;
        if (!dst) {
            if (!scratch)
                scratch = malloc(3 * (size_t)S * S);
            dst = scratch;
        }
        if (gs_model_render(c, pool, s, &v, dst, 3 * (size_t)S, &err))
            die("render", &err);
    }
    if (cpu)
        *cpu = (cpu_ms() - c0) / NVIEW;
    return (now_ms() - t0) / NVIEW;
}

int main(int argc, char **argv)
{
    const char *path = NULL, *only = NULL;
    int reps = 9, nthreads = 2, prune = 0;
    gs_model_render_options ro;
    gs_model_render_options_default(&ro);
    for (int i = 1; i < argc; i++) {
        if (!strcmp(argv[i], "--model") && i + 1 < argc)
            path = argv[++i];
        else if (!strcmp(argv[i], "--reps") && i + 1 < argc)
            reps = atoi(argv[++i]);
        else if (!strcmp(argv[i], "--quick"))
            reps = 3;
        else if (!strcmp(argv[i], "--threads") && i + 1 < argc)
            nthreads = atoi(argv[++i]);
        else if (!strcmp(argv[i], "--only") && i + 1 < argc)
            only = argv[++i];
        else if (!strcmp(argv[i], "--prune") && i + 1 < argc)
            prune = atoi(argv[++i]);
        else if (!strcmp(argv[i], "--feature-scale") && i + 1 < argc)
            ro.feature_scale = atof(argv[++i]);
        else {
            fprintf(stderr, "usage: bench_model_render [--model FILE] "
                            "[--reps N] [--quick] [--threads N] "
                            "[--only full|inc] [--prune K] "
                            "[--feature-scale S]\n");
            return 2;
        }
    }
    reps = reps < 1 ? 1 : reps > MAX_REPS ? MAX_REPS : reps;
    gs_nn_blas_select_kernels(argv); /* as the daemon and the CLI do */
    gs_nn_blas_set_threads(1);
    gs_error err = {0, ""};
    gs_model *m = NULL;
    if (bench_model_open(path, &m, &err))
        die(path ? path : "model", &err);
    if (path)
        gs_model_set_guide_source(m, 1, NULL);
    if (prune > 0) {
        gs_model *pm = NULL;
        if (gs_model_prune(m, NULL, prune, &pm, &err))
            die("prune", &err);
        gs_model_destroy(m);
        m = pm;
    }
    gs_model_info info;
    gs_model_get_info(m, &info);
    int S = info.image_size;
    gs_subject s;
    bench_subject(&info, 0.1, -0.15, &s);
    nthreads = nthreads < 1 ? 1 : nthreads > 64 ? 64 : nthreads;
    gs_pool *pool2 = nthreads > 1 ? gs_pool_create(nthreads) : NULL;
    gs_model_ctx *c = gs_model_ctx_create(m);
    if ((nthreads > 1 && !pool2) || !c)
        die("setup", NULL);
    if (gs_model_ctx_set_render_options(c, &ro, &err))
        die("--feature-scale", &err);
    int rep_no = 0;
    if (only) { /* one path on the calling thread, for a profiler */
        int full = !strcmp(only, "full");
        for (int r = 0; r < reps; r++) {
            double cpu, ms = pass(c, pool2, &s, full, S, NULL, &rep_no, &cpu);
            printf("%s: %.1f ms/img, CPU %.1f ms/img\n",
                   full ? "full" : "incremental", ms, cpu);
        }
        gs_model_ctx_destroy(c);
        gs_pool_destroy(pool2);
        gs_model_destroy(m);
        return 0;
    }
    /* the error side: incremental against full images of the same views */
    size_t isz = 3 * (size_t)S * S;
    uint8_t *inc = malloc(NVIEW * isz), *ful = malloc(NVIEW * isz);
    pass(c, pool2, &s, 0, S, inc, &rep_no, NULL);
    int maxd = 0;
    for (int k = 0; k < NVIEW; k++) {
        gs_model_ctx *f = gs_model_ctx_create(m);
        if (!f || gs_model_ctx_set_render_options(f, &ro, &err))
            die("setup", &err);
        gs_view v = {0};
        v.gaze_pitch = (-20.0 + 10.0 * (k / GRID)) * BENCH_PI / 180;
        v.gaze_yaw = (-30.0 + 15.0 * (k % GRID)) * BENCH_PI / 180;
        if (gs_model_render(f, pool2, &s, &v, ful + k * isz, 3 * (size_t)S, &err))
            die("render", &err);
        gs_model_ctx_destroy(f);
    }
    for (size_t i = 0; i < NVIEW * isz; i++) {
        int d = abs((int)inc[i] - (int)ful[i]);
        maxd = d > maxd ? d : maxd;
    }
    double t[4][MAX_REPS], u[4][MAX_REPS];
    for (int r = 0; r < reps; r++) /* interleaved: full/inc x 1/N threads */
        for (int k = 0; k < 4; k++)
            t[k][r] = pass(c, k & 2 ? pool2 : NULL, &s, !(k & 1), S, NULL,
                           &rep_no, &u[k][r]);
    double med[4], cpu[4];
    for (int k = 0; k < 4; k++) {
        med[k] = median(t[k], reps);
        cpu[k] = median(u[k], reps);
    }
    printf("gs_model_render, %s, %d^2 features -> %d^2, %d + %d Gaussians, "
           "feature scale %g, %d x %d gaze grid, median of %d\n\n",
           path ? path : "cpu preset, as initialised", info.feat_size, S,
           info.n_face, info.n_eye, ro.feature_scale, GRID, GRID, reps);
    printf("| threads | full ms/img | incremental ms/img | speed-up | "
           "incremental img/s | full CPU ms/img | incremental CPU ms/img | "
           "CPU speed-up | max 8-bit diff |\n"
           "|---|---|---|---|---|---|---|---|---|\n");
    for (int th = 0; th < 2; th++)
        printf("| %d | %.1f | %.1f | %.2fx | %.1f | %.1f | %.1f | %.2fx | %d |\n",
               th ? nthreads : 1, med[2 * th], med[2 * th + 1],
               med[2 * th] / med[2 * th + 1], 1000.0 / med[2 * th + 1],
               cpu[2 * th], cpu[2 * th + 1], cpu[2 * th] / cpu[2 * th + 1],
               maxd);
    free(inc);
    free(ful);
    gs_model_ctx_destroy(c);
    gs_pool_destroy(pool2);
    gs_model_destroy(m);
    return 0;
}
