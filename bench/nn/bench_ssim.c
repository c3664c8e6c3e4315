/* The SSIM loss of the fit and of training (3 x 256 x 256, zero padding),
 * side by side in one run: the scalar forward then backward the fit ran
 * before (ssim_scalar.h), the library's forward then backward now (the
 * same passes, four lanes at a time), and the one-pass pooled version on
 * 1 and 2 threads (what the fit, fine-tuning and training run). Each round runs every variant once, in turn, so that a busy
 * moment of a shared machine hits them alike; medians, and ratios to the
 * first.
 *
 *   build/bench/nn/bench_ssim [--reps N] [--size S]
 */
#define _POSIX_C_SOURCE 200809L
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "../bench_util.h"
#include "gazesplat/nn.h"
#include "gazesplat/pool.h"
#include "ssim_scalar.h"

enum { C = 3, NV = 4 };

int main(int argc, char **argv)
{
    int reps = 31, S = 256;
    for (int i = 1; i < argc; i++) {
        if (!strcmp(argv[i], "--reps") && i + 1 < argc)
            reps = atoi(argv[++i]);
        else if (!strcmp(argv[i], "--size") && i + 1 < argc)
            S = atoi(argv[++i]);
        else {
            fprintf(stderr, "usage: bench_ssim [--reps N] [--size S]\n");
            return 2;
        }
    }
    if (reps < 1 || S < 16 || S > 4096) {
        fprintf(stderr, "bench_ssim: --reps >= 1, --size 16..4096\n");
        return 2;
    }
    gs_nn_blas_set_threads(1);
    size_t n = (size_t)C * S * S;
    float *x = malloc(n * sizeof *x), *y = malloc(n * sizeof *y), *dx = calloc(n, sizeof *dx);
    size_t ns = gs_nn_ssim_scratch_size(S, S, GS_NN_SSIM_ZERO);
    size_t nf = gs_nn_ssim_fused_scratch_size(C, S, S, GS_NN_SSIM_ZERO);
    float *s1 = malloc(ns * sizeof *s1), *sf = malloc(nf * sizeof *sf);
    gs_pool *p1 = gs_pool_create(1), *p2 = gs_pool_create(2);
    if (!x || !y || !dx || !s1 || !sf || !p1 || !p2) {
        fprintf(stderr, "bench_ssim: out of memory\n");
        return 1;
    }
    uint64_t r = 1;
    for (size_t i = 0; i < n; i++) { /* an image and a close target */
        r = r * 6364136223846793005ull + 1442695040888963407ull;
        x[i] = (float)((r >> 40) & 0xffff) / 65535.0f;
        y[i] = x[i] * 0.9f + 0.05f;
    }
    const char *name[NV] = {"scalar forward + backward, 1 thread (before)",
                            "forward + backward, 1 thread", "one pass, pool of 1",
                            "one pass, pool of 2"};
    float *dxs[NV];
    for (int v = 0; v < NV; v++)
        dxs[v] = calloc(n, sizeof *dx);
    double *t = malloc((size_t)NV * reps * sizeof *t);
    float loss[NV];
    for (int k = 0; k < reps; k++)
        for (int v = 0; v < NV; v++) {
            double t0 = now_ms();
            memset(dxs[v], 0, n * sizeof *dx);
            if (v == 0) {
                scalar_ssim_forward(&loss[v], x, y, C, S, S, GS_NN_SSIM_ZERO, s1, ns);
                scalar_ssim_backward(dxs[v], 0.1f, x, y, C, S, S, GS_NN_SSIM_ZERO, s1, ns);
            } else if (v == 1) {
                gs_nn_ssim_loss_forward(&loss[v], x, y, C, S, S, GS_NN_SSIM_ZERO, s1, ns);
                gs_nn_ssim_loss_backward(dxs[v], 0.1f, x, y, C, S, S, GS_NN_SSIM_ZERO, s1, ns);
            } else {
                gs_nn_ssim_loss_fused(v == 2 ? p1 : p2, &loss[v], dxs[v], 0.1f, x, y, C, S, S,
                                      GS_NN_SSIM_ZERO, sf, nf);
            }
            t[v * reps + k] = now_ms() - t0;
        }
    printf("SSIM loss and gradient, %d x %d x %d, zero padding, %d rounds (median ms)\n\n", C, S, S,
           reps);
    printf("| variant | ms | vs before |\n|---|---:|---:|\n");
    double base = 0;
    for (int v = 0; v < NV; v++) {
        double m = median(t + v * reps, reps);
        if (v == 0)
            base = m;
        printf("| %s | %.2f | %.2fx |\n", name[v], m, base / m);
    }
    int same = 1;
    for (int v = 1; v < NV; v++)
        same &= !memcmp(&loss[0], &loss[v], sizeof loss[0]) && !memcmp(dxs[0], dxs[v], n * sizeof *dx);
    printf("\nlosses and gradients %s (loss %.7f)\n", same ? "bit-identical" : "DIFFER", loss[0]);
    for (int v = 0; v < NV; v++)
        free(dxs[v]);
    gs_pool_destroy(p1);
    gs_pool_destroy(p2);
    free(x); free(y); free(dx); free(s1); free(sf); free(t);
    return same ? 0 : 1;
}
