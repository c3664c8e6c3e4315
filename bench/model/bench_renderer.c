/* Renderer benchmark: forward and forward+backward milliseconds of the
 * expression-guided renderer at 64^2 -> 256^2 (the CPU default) and
 * 128^2 -> 512^2 (the paper's size), C = 32, D = 144, each guidance mode,
 * on the calling thread and on a gs_pool of 2 threads (OpenBLAS pinned to
 * one thread: the pool splits the passes).
 *
 *   bench_renderer [--quick] [--reps N] [--blas-as-installed]
 *
 * Like the programs, it selects OpenBLAS's AVX kernels on CPUs that OpenBLAS
 * does not recognise (gs_nn_blas_select_kernels); --blas-as-installed keeps
 * the kernels OpenBLAS picked itself, for the comparison.
 *
 * Prints a Markdown table; experiments/bench/README.md records its output. Times are
 * medians over reps; the configurations run interleaved rep by rep. */
#define _POSIX_C_SOURCE 200809L
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "../bench_util.h"
#include "gazesplat/nn.h"
#include "gazesplat/pool.h"
#include "renderer.h"

enum { NCASES = 12, MAX_REPS = 101 };

typedef struct {
    gs_renderer_config cfg;
    int H, W, threads;
    gs_pool *pool;
    size_t np, na, nx, nout;
    float *params, *grads, *acts, *x, *tau, *out, *dout, *dx, *dtau;
    gs_renderer_params p, dp;
    double fwd[MAX_REPS], both[MAX_REPS], cpu_fwd[MAX_REPS], cpu_both[MAX_REPS];
} bench_case;

static float *alloc_fill(size_t n, uint32_t seed)
{
    float *a = malloc((n ? n : 1) * sizeof *a);
    if (!a) {
        fprintf(stderr, "out of memory\n");
        exit(2);
    }
    uint32_t s = seed;
    for (size_t i = 0; i < n; i++) {
        s = s * 1664525u + 1013904223u;
        a[i] = (float)(s >> 8) * (2.0f / 16777216.0f) - 1.0f;
    }
    return a;
}

static void setup(bench_case *b, int guidance, int side, int threads)
{
    b->threads = threads;
    b->pool = threads > 1 ? gs_pool_create(threads) : NULL;
    if (threads > 1 && !b->pool) {
        fprintf(stderr, "cannot create a pool\n");
        exit(2);
    }
    b->cfg = (gs_renderer_config){32, 144, guidance, 2, 0};
    b->H = b->W = side;
    b->np = gs_renderer_param_count(&b->cfg);
    b->na = gs_renderer_act_size(&b->cfg, side, side);
    b->nx = (size_t)32 * side * side, b->nout = (size_t)48 * side * side;
    b->params = alloc_fill(b->np, 1), b->grads = alloc_fill(b->np, 2);
    b->acts = alloc_fill(b->na, 3), b->x = alloc_fill(b->nx, 4);
    b->tau = alloc_fill(144, 5), b->out = alloc_fill(b->nout, 6);
    b->dout = alloc_fill(b->nout, 7), b->dx = alloc_fill(b->nx, 8);
    b->dtau = alloc_fill(144, 9);
    gs_renderer_init(&b->cfg, b->params, b->np, 11);
    gs_renderer_bind(&b->cfg, b->params, b->np, &b->p);
    gs_renderer_bind(&b->cfg, b->grads, b->np, &b->dp);
    if (guidance != GS_GUIDE_NONE) /* a live guidance, as after training */
        for (int i = 0; i < 32 * 32; i++)
            b->p.value_w[i] = 0.01f * b->x[i];
}

static void run_once(bench_case *b, int rep)
{
    double t0 = now_ms(), c0 = cpu_ms();
    int rc = gs_renderer_forward(&b->cfg, &b->p, b->x, b->tau, b->H, b->W,
                                 b->acts, b->na, b->out, b->pool);
    double t1 = now_ms(), c1 = cpu_ms();
    rc = rc ? rc : gs_renderer_backward(&b->cfg, &b->p, b->acts, b->na, b->x,
                                        b->tau, b->dout, b->H, b->W, &b->dp,
                                        b->dx, b->dtau, b->pool);
    double t2 = now_ms(), c2 = cpu_ms();
    if (rc) {
        fprintf(stderr, "renderer failed: %d\n", rc);
        exit(1);
    }
    b->fwd[rep] = t1 - t0;
    b->both[rep] = t2 - t0;
    b->cpu_fwd[rep] = c1 - c0;
    b->cpu_both[rep] = c2 - c0;
}

int main(int argc, char **argv)
{
    int reps = 9, quick = 0, as_installed = 0;
    for (int i = 1; i < argc; i++)
        as_installed |= !strcmp(argv[i], "--blas-as-installed");
    if (!as_installed)
        gs_nn_blas_select_kernels(argv);
    for (int i = 1; i < argc; i++) {
        if (!strcmp(argv[i], "--quick"))
            quick = 1;
        else if (!strcmp(argv[i], "--blas-as-installed"))
            continue;
        else if (!strcmp(argv[i], "--reps") && i + 1 < argc)
            reps = atoi(argv[++i]);
        else {
            fprintf(stderr, "usage: bench_renderer [--quick] [--reps N] [--blas-as-installed]\n");
            return 2;
        }
    }
    if (quick)
        reps = 1;
    if (reps < 1 || reps > MAX_REPS) {
        fprintf(stderr, "reps must be in 1..%d\n", MAX_REPS);
        return 2;
    }
    gs_nn_blas_set_threads(1);
    static const char *const names[3] = {"none", "additive", "multiplicative"};
    bench_case *cases = calloc(NCASES, sizeof *cases);
    if (!cases)
        return 2;
    int ncases = quick ? 6 : NCASES;
    for (int i = 0; i < ncases; i++) /* modes, then threads, then sizes */
        setup(&cases[i], i % 3, i < 6 ? 64 : 128, (i / 3) % 2 ? 2 : 1);
    for (int i = 0; i < ncases; i++) /* warm-up: page in the buffers */
        run_once(&cases[i], 0);
    for (int r = 0; r < reps; r++)
        for (int i = 0; i < ncases; i++)
            run_once(&cases[i], r);
    printf("OpenBLAS kernels: %s\n\n", gs_nn_blas_core());
    printf("| features -> image | guidance | threads | fwd ms | fwd+bwd ms | "
           "fwd CPU ms | fwd+bwd CPU ms | activations MB |\n");
    printf("|---|---|---|---|---|---|---|---|\n");
    for (int i = 0; i < ncases; i++) {
        bench_case *b = &cases[i];
        printf("| %d^2 -> %d^2 | %s | %d | %.2f | %.2f | %.2f | %.2f | %.1f |\n",
               b->H, 4 * b->H, names[i % 3], b->threads, median(b->fwd, reps),
               median(b->both, reps), median(b->cpu_fwd, reps),
               median(b->cpu_both, reps), (double)b->na * 4.0 / 1e6);
    }
    for (int i = 0; i < ncases; i++)
        gs_pool_destroy(cases[i].pool);
    return 0;
}
