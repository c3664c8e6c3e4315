/* gs_nn_ssim_loss_fused: the SSIM loss and gradient in one pass on a pool.
 * Its contract is the bytes of gs_nn_ssim_loss_forward followed by
 * gs_nn_ssim_loss_backward (themselves checked against finite differences
 * and PyTorch) for any thread count and any size, the loss alone when no
 * gradient is asked for, and refusals that write nothing. Both are also
 * checked byte for byte against the scalar code they replaced
 * (bench/nn/ssim_scalar.h), so no figure made before moves. A finite
 * difference check of its own gradient guards the chain end to end. */
#include "gazesplat/nn.h"
#include "gazesplat/pool.h"
#include "gs_test.h"
#include "nn_test_util.h"
#include "ssim_scalar.h"

#include <math.h>

/* One size and padding: the pooled runs against the separate ones. */
static void same_bytes(nn_rng *r, gs_pool **pools, int npools, int C, int H, int W, int pad)
{
    size_t n = (size_t)C * H * W;
    float *x = nn_alloc(n), *y = nn_alloc(n), *dx0 = nn_alloc(n), *dx1 = nn_alloc(n);
    nn_fill(r, x, n, -0.1f, 1.1f);
    nn_fill(r, y, n, 0.0f, 1.0f);
    nn_fill(r, dx0, n, -1.0f, 1.0f); /* the gradient adds to what is there */
    size_t ns = gs_nn_ssim_scratch_size(H, W, pad);
    float *s0 = nn_alloc(ns), l0 = 0;
    CHECK_EQ_INT(gs_nn_ssim_loss_forward(&l0, x, y, C, H, W, pad, s0, ns), GS_OK);
    float *start = nn_alloc(n);
    memcpy(start, dx0, n * sizeof *dx0);
    CHECK_EQ_INT(gs_nn_ssim_loss_backward(dx0, 0.3f, x, y, C, H, W, pad, s0, ns), GS_OK);
    { /* the scalar code before: the same loss and gradient bytes */
        float ls = -1, *dxs = nn_alloc(n);
        memcpy(dxs, start, n * sizeof *dxs);
        CHECK_EQ_INT(scalar_ssim_forward(&ls, x, y, C, H, W, pad, s0, ns), GS_OK);
        CHECK_EQ_INT(scalar_ssim_backward(dxs, 0.3f, x, y, C, H, W, pad, s0, ns), GS_OK);
        CHECK_MSG(memcmp(&ls, &l0, sizeof l0) == 0 && memcmp(dxs, dx0, n * sizeof *dxs) == 0,
                  "%dx%dx%d pad %d: vector passes != the scalar code", C, H, W, pad);
        free(dxs);
    }
    size_t nf = gs_nn_ssim_fused_scratch_size(C, H, W, pad);
    CHECK(nf > 0);
    float *sf = nn_alloc(nf);
    for (int p = 0; p < npools; p++) {
        float l1 = -1, l2 = -1;
        memcpy(dx1, start, n * sizeof *dx1);
        CHECK_EQ_INT(gs_nn_ssim_loss_fused(pools[p], &l1, dx1, 0.3f, x, y, C, H, W, pad, sf, nf),
                     GS_OK);
        CHECK_MSG(memcmp(&l1, &l0, sizeof l0) == 0, "%dx%dx%d pad %d, %d threads: loss %.9g vs %.9g",
                  C, H, W, pad, gs_pool_threads(pools[p]), l1, l0);
        CHECK_MSG(memcmp(dx1, dx0, n * sizeof *dx0) == 0, "%dx%dx%d pad %d, %d threads: gradient",
                  C, H, W, pad, gs_pool_threads(pools[p]));
        /* the loss alone: the same value, no gradient written anywhere */
        memcpy(dx1, start, n * sizeof *dx1);
        CHECK_EQ_INT(gs_nn_ssim_loss_fused(pools[p], &l2, NULL, NAN, x, y, C, H, W, pad, sf, nf),
                     GS_OK);
        CHECK(memcmp(&l2, &l0, sizeof l0) == 0);
    }
    free(x); free(y); free(dx0); free(dx1); free(s0); free(sf); free(start);
}

/* Central differences of the fused loss against its gradient. */
static void finite_differences(nn_rng *r, gs_pool *pool)
{
    enum { C = 2, H = 13, W = 17 };
    size_t n = (size_t)C * H * W;
    float *x = nn_alloc(n), *y = nn_alloc(n), *dx = nn_alloc(n);
    nn_fill(r, x, n, 0.1f, 0.9f);
    nn_fill(r, y, n, 0.1f, 0.9f);
    size_t nf = gs_nn_ssim_fused_scratch_size(C, H, W, GS_NN_SSIM_ZERO);
    float *sf = nn_alloc(nf), l;
    CHECK_EQ_INT(gs_nn_ssim_loss_fused(pool, &l, dx, 1.0f, x, y, C, H, W, GS_NN_SSIM_ZERO, sf, nf),
                 GS_OK);
    double worst = 0;
    for (size_t i = 0; i < n; i += 7) {
        float keep = x[i], lp, lm;
        const float h = 1e-2f;
        x[i] = keep + h;
        gs_nn_ssim_loss_fused(pool, &lp, NULL, 0, x, y, C, H, W, GS_NN_SSIM_ZERO, sf, nf);
        x[i] = keep - h;
        gs_nn_ssim_loss_fused(pool, &lm, NULL, 0, x, y, C, H, W, GS_NN_SSIM_ZERO, sf, nf);
        x[i] = keep;
        double fd = ((double)lp - lm) / (2.0 * h), err = fabs(fd - dx[i]);
        double tol = 2e-5 + 2e-2 * fabs(fd);
        if (err / tol > worst)
            worst = err / tol;
        CHECK_MSG(err <= tol, "dx[%zu] %.6g, finite differences %.6g", i, dx[i], fd);
    }
    printf("finite differences: worst error %.2f of the tolerance\n", worst);
    free(x); free(y); free(dx); free(sf);
}

static void refusals(gs_pool *pool)
{
    enum { C = 3, H = 16, W = 16 };
    size_t n = (size_t)C * H * W;
    float *x = nn_alloc(n), *y = nn_alloc(n), *dx = nn_alloc(n);
    size_t nf = gs_nn_ssim_fused_scratch_size(C, H, W, GS_NN_SSIM_ZERO);
    float *sf = nn_alloc(nf), l = 7.0f;
    CHECK_EQ_INT(gs_nn_ssim_loss_fused(pool, &l, dx, 1, x, y, C, H, W, GS_NN_SSIM_ZERO, sf, nf - 1),
                 GS_ERR_ARG);
    CHECK_EQ_INT(gs_nn_ssim_loss_fused(pool, &l, dx, 1, x, y, C, H, W, GS_NN_SSIM_ZERO, NULL, nf),
                 GS_ERR_ARG);
    CHECK_EQ_INT(gs_nn_ssim_loss_fused(pool, &l, dx, NAN, x, y, C, H, W, GS_NN_SSIM_ZERO, sf, nf),
                 GS_ERR_ARG);
    CHECK_EQ_INT(gs_nn_ssim_loss_fused(pool, &l, dx, INFINITY, x, y, C, H, W, GS_NN_SSIM_ZERO, sf,
                                       nf), GS_ERR_ARG);
    CHECK_EQ_INT(gs_nn_ssim_loss_fused(pool, NULL, dx, 1, x, y, C, H, W, GS_NN_SSIM_ZERO, sf, nf),
                 GS_ERR_ARG);
    CHECK_EQ_INT(gs_nn_ssim_loss_fused(pool, &l, dx, 1, NULL, y, C, H, W, GS_NN_SSIM_ZERO, sf, nf),
                 GS_ERR_ARG);
    CHECK_EQ_INT(gs_nn_ssim_loss_fused(pool, &l, dx, 1, x, y, 0, H, W, GS_NN_SSIM_ZERO, sf, nf),
                 GS_ERR_ARG);
    CHECK_EQ_INT(gs_nn_ssim_loss_fused(pool, &l, dx, 1, x, y, C, H, W, 7, sf, nf), GS_ERR_ARG);
    /* a window that does not fit the valid positions */
    CHECK_EQ_INT(gs_nn_ssim_loss_fused(pool, &l, dx, 1, x, y, C, 10, W, GS_NN_SSIM_VALID, sf, nf),
                 GS_ERR_ARG);
    CHECK(l == 7.0f);
    for (size_t i = 0; i < n; i++)
        CHECK(dx[i] == 0.0f);
    CHECK(gs_nn_ssim_fused_scratch_size(0, H, W, GS_NN_SSIM_ZERO) == 0);
    CHECK(gs_nn_ssim_fused_scratch_size(C, 10, 10, GS_NN_SSIM_VALID) == 0);
    /* the channels take turns in one channel's scratch */
    CHECK(gs_nn_ssim_fused_scratch_size(1 << 20, 64, 64, GS_NN_SSIM_ZERO) ==
          gs_nn_ssim_fused_scratch_size(1, 64, 64, GS_NN_SSIM_ZERO));
    free(x); free(y); free(dx); free(sf);
}

int main(void)
{
    gs_nn_blas_set_threads(1);
    gs_pool *pools[5] = {NULL, gs_pool_create(1), gs_pool_create(2), gs_pool_create(3),
                         gs_pool_create(4)};
    for (int i = 1; i < 5; i++)
        CHECK(pools[i] != NULL);
    nn_rng r = {42};
    /* odd sizes, fewer rows than a band, a band and one, both paddings */
    const int sizes[][3] = {{3, 256, 256}, {3, 37, 61}, {1, 11, 11}, {2, 7, 30}, {3, 9, 12},
                            {2, 64, 17}, {4, 33, 40}};
    for (size_t i = 0; i < sizeof sizes / sizeof sizes[0]; i++)
        for (int pad = GS_NN_SSIM_VALID; pad <= GS_NN_SSIM_ZERO; pad++) {
            if (pad == GS_NN_SSIM_VALID && (sizes[i][1] < 11 || sizes[i][2] < 11))
                continue;
            same_bytes(&r, pools, 5, sizes[i][0], sizes[i][1], sizes[i][2], pad);
        }
    finite_differences(&r, pools[2]);
    refusals(pools[2]);
    for (int i = 1; i < 5; i++)
        gs_pool_destroy(pools[i]);
    GS_TEST_END();
}
