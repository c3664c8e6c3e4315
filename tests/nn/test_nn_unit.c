/* Unit tests for gs_nn: argument checking, exact small cases of each
 * kernel's semantics, backward accumulation, and Adam (a hand-computed
 * two-step example, clipping, refusal of non-finite gradients). */
#include "gazesplat/nn.h"
#include "gazesplat/pool.h"
#include "gs_test.h"
#include "nn_test_util.h"

#include <limits.h>

static float g_buf[4096];   /* a valid pointer for argument tests */

static void test_bad_args(void)
{
    float *p = g_buf;
    float loss;
    /* NULL required pointers */
    CHECK_EQ_INT(gs_nn_linear_forward(NULL, p, p, p, 1, 1, 1), GS_ERR_ARG);
    CHECK_EQ_INT(gs_nn_linear_forward(p, NULL, p, p, 1, 1, 1), GS_ERR_ARG);
    CHECK_EQ_INT(gs_nn_linear_backward(p, p, p, NULL, p, p, 1, 1, 1), GS_ERR_ARG);
    CHECK_EQ_INT(gs_nn_linear_backward(p, NULL, NULL, p, p, NULL, 1, 1, 1), GS_ERR_ARG);
    CHECK_EQ_INT(gs_nn_conv1x1_forward(p, p, NULL, p, 1, 1, 1), GS_ERR_ARG);
    CHECK_EQ_INT(gs_nn_relu_forward(NULL, p, 1), GS_ERR_ARG);
    CHECK_EQ_INT(gs_nn_tanh_backward(p, NULL, p, 1), GS_ERR_ARG);
    CHECK_EQ_INT(gs_nn_softmax_forward(p, NULL, 3), GS_ERR_ARG);
    CHECK_EQ_INT(gs_nn_pixel_shuffle_forward(NULL, p, 1, 1, 1), GS_ERR_ARG);
    CHECK_EQ_INT(gs_nn_upsample2x_backward(p, NULL, 1, 1, 1), GS_ERR_ARG);
    CHECK_EQ_INT(gs_nn_blur_forward(p, NULL, 1, 2, 2), GS_ERR_ARG);
    CHECK_EQ_INT(gs_nn_l1_forward(NULL, p, p, NULL, 1, 1), GS_ERR_ARG);
    /* zero and negative sizes */
    CHECK_EQ_INT(gs_nn_linear_forward(p, p, p, p, 0, 1, 1), GS_ERR_ARG);
    CHECK_EQ_INT(gs_nn_linear_forward(p, p, p, p, 1, -1, 1), GS_ERR_ARG);
    CHECK_EQ_INT(gs_nn_conv1x1_backward(p, p, p, p, p, p, 1, 0, 1), GS_ERR_ARG);
    CHECK_EQ_INT(gs_nn_relu_forward(p, p, 0), GS_ERR_ARG);
    CHECK_EQ_INT(gs_nn_sigmoid_forward(p, p, 0), GS_ERR_ARG);
    CHECK_EQ_INT(gs_nn_softmax_backward(p, p, p, 0), GS_ERR_ARG);
    CHECK_EQ_INT(gs_nn_pixel_shuffle_backward(p, p, 0, 1, 1), GS_ERR_ARG);
    CHECK_EQ_INT(gs_nn_upsample2x_forward(p, p, 1, 0, 1), GS_ERR_ARG);
    CHECK_EQ_INT(gs_nn_blur_forward(p, p, 1, 1, 4), GS_ERR_ARG); /* reflect needs 2 */
    CHECK_EQ_INT(gs_nn_blur_backward(p, p, 1, 4, 1), GS_ERR_ARG);
    CHECK_EQ_INT(gs_nn_l1_backward(p, 1.0f, p, p, NULL, 0, 4), GS_ERR_ARG);
    CHECK_EQ_INT(gs_nn_leaky_relu_forward(p, p, NAN, 4), GS_ERR_ARG);
    /* sizes whose products overflow BLAS ints: refused before any access */
    CHECK_EQ_INT(gs_nn_linear_forward(p, p, p, p, INT_MAX, 2, 1), GS_ERR_LIMIT);
    CHECK_EQ_INT(gs_nn_conv1x1_forward(p, p, p, p, 1, 65536, 65536), GS_ERR_LIMIT);
    CHECK_EQ_INT(gs_nn_upsample2x_forward(p, p, 1, 65536, 65536), GS_ERR_LIMIT);
    CHECK_EQ_INT(gs_nn_conv3x3_forward(p, p, p, p, INT_MAX / 4, 1, 1, 1, p, 1),
                 GS_ERR_LIMIT);
    /* scratch sizes and short scratch */
    CHECK(gs_nn_conv3x3_scratch_size(0, 4, 4) == 0);
    CHECK(gs_nn_conv3x3_scratch_size(2, 4, 4) == 2 * 9 * 16);
    CHECK_EQ_INT(gs_nn_conv3x3_forward(p, p, p, p, 2, 1, 4, 4, p, 2 * 9 * 16 - 1),
                 GS_ERR_ARG);
    CHECK_EQ_INT(gs_nn_conv3x3_forward(p, p, p, p, 2, 1, 4, 4, NULL, 4096),
                 GS_ERR_ARG);
    CHECK_EQ_INT(gs_nn_conv3x3_backward(NULL, NULL, p, p, p, p, 2, 1, 4, 4, NULL, 0),
                 GS_OK); /* db alone needs no scratch */
    CHECK(gs_nn_attention_scratch_size(0) == 0);
    CHECK(gs_nn_attention_scratch_size(3) == 15);
    CHECK_EQ_INT(gs_nn_attention_forward(p, p, p, p, p, p, p, p, 3, 2, 4, 1.0f, p, 14),
                 GS_ERR_ARG);
    CHECK_EQ_INT(gs_nn_attention_forward(p, p, p, p, p, p, p, p, 3, 2, 4, 0.0f, p, 15),
                 GS_ERR_ARG);
    CHECK_EQ_INT(gs_nn_attention_forward(p, p, p, p, p, p, p, p, 3, 2, 4, INFINITY, p, 15),
                 GS_ERR_ARG);
    CHECK_EQ_INT(gs_nn_attention_backward(p, p, p, p, p, p, p, p, NULL, p, p, p, 3, 2,
                                          4, 1.0f, p, 15), GS_ERR_ARG);
    CHECK(gs_nn_ssim_scratch_size(10, 20, GS_NN_SSIM_VALID) == 0); /* < 11 rows */
    CHECK(gs_nn_ssim_scratch_size(11, 12, GS_NN_SSIM_VALID) == 5 * (11 * 2 + 1 * 2));
    CHECK(gs_nn_ssim_scratch_size(3, 4, GS_NN_SSIM_ZERO) == 5 * (3 * 4 + 3 * 4));
    CHECK(gs_nn_ssim_scratch_size(11, 12, 7) == 0);
    CHECK_EQ_INT(gs_nn_ssim_loss_forward(&loss, p, p, 1, 10, 20, GS_NN_SSIM_VALID, p, 4096),
                 GS_ERR_ARG);
    CHECK_EQ_INT(gs_nn_ssim_loss_forward(&loss, p, p, 1, 11, 12, 2, p, 4096), GS_ERR_ARG);
    CHECK_EQ_INT(gs_nn_ssim_loss_forward(&loss, p, p, 1, 11, 12, GS_NN_SSIM_VALID, p, 47),
                 GS_ERR_ARG);
    CHECK_EQ_INT(gs_nn_ssim_loss_backward(p, NAN, p, p, 1, 11, 12, GS_NN_SSIM_VALID, p, 48),
                 GS_ERR_ARG);
}

/* Every gradient pointer of a backward may be NULL; each is skipped. */
static void test_null_grads(void)
{
    float *p = g_buf, s[64];
    memset(g_buf, 0, sizeof g_buf);
    CHECK_EQ_INT(gs_nn_linear_backward(NULL, NULL, NULL, p, NULL, NULL, 2, 3, 4), GS_OK);
    CHECK_EQ_INT(gs_nn_conv1x1_backward(NULL, NULL, NULL, p, NULL, NULL, 2, 3, 4), GS_OK);
    CHECK_EQ_INT(gs_nn_conv3x3_backward(NULL, p, NULL, p + 1024, p + 2048, NULL, 2, 3,
                                        4, 4, s, 64), GS_ERR_ARG); /* scratch 2*9*16 */
    CHECK_EQ_INT(gs_nn_attention_backward(NULL, NULL, NULL, NULL, NULL, NULL, p, p,
                                          p, p, p, p, 3, 2, 4, 1.0f, s, 15), GS_OK);
}

/* out[c, 2h+i, 2w+j] = in[4c+2i+j, h, w], and backward is the inverse. */
static void test_pixel_shuffle(void)
{
    enum { C = 2, H = 2, W = 3 };
    float in[4 * C * H * W], out[4 * C * H * W], back[4 * C * H * W] = {0};
    for (int i = 0; i < 4 * C * H * W; i++)
        in[i] = (float)i;
    CHECK_EQ_INT(gs_nn_pixel_shuffle_forward(out, in, C, H, W), GS_OK);
    int bad = 0;
    for (int c = 0; c < C; c++)
        for (int h = 0; h < H; h++)
            for (int w = 0; w < W; w++)
                for (int i = 0; i < 2; i++)
                    for (int j = 0; j < 2; j++) {
                        float want = in[((4 * c + 2 * i + j) * H + h) * W + w];
                        float got = out[(c * 2 * H + 2 * h + i) * 2 * W + 2 * w + j];
                        bad += got != want;
                    }
    CHECK_EQ_INT(bad, 0);
    CHECK_EQ_INT(gs_nn_pixel_shuffle_backward(back, out, C, H, W), GS_OK);
    CHECK(memcmp(back, in, sizeof in) == 0);
}

/* align_corners=False: [a, b] -> [a, .75a+.25b, .25a+.75b, b]; an input of
 * one pixel is replicated. */
static void test_upsample(void)
{
    float in[2] = {1.0f, 5.0f}, out[8];
    CHECK_EQ_INT(gs_nn_upsample2x_forward(out, in, 1, 1, 2), GS_OK);
    float want[4] = {1.0f, 2.0f, 4.0f, 5.0f};
    for (int r = 0; r < 2; r++)
        gs_check_arrays("upsample row", out + 4 * r, want, 4, 0, 0);
    float one = 3.0f, four[4];
    CHECK_EQ_INT(gs_nn_upsample2x_forward(four, &one, 1, 1, 1), GS_OK);
    CHECK(four[0] == 3.0f && four[1] == 3.0f && four[2] == 3.0f && four[3] == 3.0f);
    /* the adjoint of a partition of unity conserves the sum */
    float g[8] = {1, 1, 1, 1, 1, 1, 1, 1}, din[2] = {0, 0};
    CHECK_EQ_INT(gs_nn_upsample2x_backward(din, g, 1, 1, 2), GS_OK);
    CHECK_CLOSE(din[0] + din[1], 8.0, 0, 1e-6);
}

/* Reflect border: a unit impulse at (1,1) gives 4/16 at the corner (0,0)
 * (zero padding would give 1/16); a constant image is unchanged. */
static void test_blur(void)
{
    float in[16] = {0}, out[16];
    in[1 * 4 + 1] = 1.0f;
    CHECK_EQ_INT(gs_nn_blur_forward(out, in, 1, 4, 4), GS_OK);
    CHECK_CLOSE(out[0], 0.25, 0, 1e-7);
    CHECK_CLOSE(out[1 * 4 + 1], 4.0 / 16, 0, 1e-7);
    CHECK_CLOSE(out[1 * 4 + 2], 2.0 / 16, 0, 1e-7);
    for (int i = 0; i < 16; i++)
        in[i] = 0.7f;
    CHECK_EQ_INT(gs_nn_blur_forward(out, in, 1, 4, 4), GS_OK);
    for (int i = 0; i < 16; i++)
        CHECK_CLOSE(out[i], 0.7, 0, 1e-6);
}

static void test_activations(void)
{
    float in[6] = {-1000.0f, -100.0f, -1.0f, 0.0f, 100.0f, 1000.0f}, out[6];
    CHECK_EQ_INT(gs_nn_sigmoid_forward(out, in, 6), GS_OK);
    CHECK(out[0] == 0.0f && out[5] == 1.0f && out[3] == 0.5f);
    CHECK(out[1] >= 0.0f && out[1] < 1e-40f);
    CHECK_EQ_INT(gs_nn_softmax_forward(out, in, 6), GS_OK);
    double sum = 0.0;
    for (int i = 0; i < 6; i++) {
        CHECK(isfinite(out[i]));
        sum += out[i];
    }
    CHECK(out[5] == 1.0f);
    CHECK_CLOSE(sum, 1.0, 1e-7, 0);
    /* in place */
    float x[3] = {-2.0f, 0.0f, 3.0f};
    CHECK_EQ_INT(gs_nn_leaky_relu_forward(x, x, 0.01f, 3), GS_OK);
    CHECK(x[0] == -0.02f && x[1] == 0.0f && x[2] == 3.0f);
    /* gradients at the kinks: relu 0, leaky relu slope (as PyTorch) */
    float z = 0.0f, one = 1.0f, d1 = 0.0f, d2 = 0.0f;
    gs_nn_relu_backward(&d1, &one, &z, 1);
    gs_nn_leaky_relu_backward(&d2, &one, &z, 0.2f, 1);
    CHECK(d1 == 0.0f && d2 == 0.2f);
}

/* Backward adds: two calls give twice one call (here for linear and blur). */
static void test_accumulates(void)
{
    nn_rng r = {7};
    float in[6], w[6], dout[4], d1[6] = {0}, d2[6] = {0}, dw1[6] = {0}, dw2[6] = {0};
    nn_fill(&r, in, 6, -1, 1);
    nn_fill(&r, w, 6, -1, 1);
    nn_fill(&r, dout, 4, -1, 1);
    gs_nn_linear_backward(d1, dw1, NULL, dout, in, w, 2, 3, 2);
    gs_nn_linear_backward(d2, dw2, NULL, dout, in, w, 2, 3, 2);
    gs_nn_linear_backward(d2, dw2, NULL, dout, in, w, 2, 3, 2);
    for (int i = 0; i < 6; i++) {
        d1[i] *= 2.0f;
        dw1[i] *= 2.0f;
    }
    gs_check_arrays("linear dinp x2", d2, d1, 6, 1e-6, 0);
    gs_check_arrays("linear dw x2", dw2, dw1, 6, 1e-6, 0);
    float img[12], g[12] = {0}, g2[12] = {0}, dimg[12];
    nn_fill(&r, img, 12, -1, 1);
    nn_fill(&r, dimg, 12, -1, 1);
    gs_nn_blur_backward(g, dimg, 1, 3, 4);
    gs_nn_blur_backward(g2, dimg, 1, 3, 4);
    gs_nn_blur_backward(g2, dimg, 1, 3, 4);
    for (int i = 0; i < 12; i++)
        g[i] *= 2.0f;
    gs_check_arrays("blur dinp x2", g2, g, 12, 1e-6, 0);
}

/* Direct 3x3 convolution in double. */
static double conv_at(const float *in, const float *w, const float *b, int IC,
                      int H, int W, int oc, int y, int x)
{
    double s = b[oc];
    for (int ic = 0; ic < IC; ic++)
        for (int ky = 0; ky < 3; ky++)
            for (int kx = 0; kx < 3; kx++) {
                int sy = y + ky - 1, sx = x + kx - 1;
                if (sy >= 0 && sy < H && sx >= 0 && sx < W)
                    s += (double)w[((oc * IC + ic) * 3 + ky) * 3 + kx] *
                         in[((size_t)ic * H + sy) * W + sx];
            }
    return s;
}

/* A width that splits the image into bands of rows (two bands of 2 and 1
 * rows) against the direct convolution; the weight gradient against
 * dw = sum_p dout_p im2col_p. */
static void test_conv3x3_bands(void)
{
    enum { IC = 2, OC = 2, H = 3, W = 4100 };
    nn_rng r = {99};
    size_t hw = (size_t)H * W, ns = gs_nn_conv3x3_scratch_size(IC, H, W);
    CHECK(ns < (size_t)IC * 9 * hw); /* banded */
    float *in = nn_alloc(IC * hw), *out = nn_alloc(OC * hw), *want = nn_alloc(OC * hw);
    float *dout = nn_alloc(OC * hw), *s = nn_alloc(ns), w[OC * IC * 9], b[OC];
    float dw[OC * IC * 9] = {0}, dw_want[OC * IC * 9];
    nn_fill(&r, in, IC * hw, -1, 1);
    nn_fill(&r, dout, OC * hw, -1, 1);
    nn_fill(&r, w, OC * IC * 9, -1, 1);
    nn_fill(&r, b, OC, -1, 1);
    CHECK_EQ_INT(gs_nn_conv3x3_forward(out, in, w, b, IC, OC, H, W, s, ns), GS_OK);
    for (int oc = 0; oc < OC; oc++)
        for (int y = 0; y < H; y++)
            for (int x = 0; x < W; x++)
                want[(oc * H + y) * W + x] = (float)conv_at(in, w, b, IC, H, W, oc, y, x);
    gs_check_arrays("conv3x3 banded out", out, want, OC * hw, 1e-5, 1e-5);
    CHECK_EQ_INT(gs_nn_conv3x3_backward(NULL, dw, NULL, dout, in, w, IC, OC, H, W, s, ns),
                 GS_OK);
    for (int oc = 0; oc < OC; oc++)
        for (int ic = 0; ic < IC; ic++)
            for (int k = 0; k < 9; k++) {
                double acc = 0.0;
                for (int y = 0; y < H; y++)
                    for (int x = 0; x < W; x++) {
                        int sy = y + k / 3 - 1, sx = x + k % 3 - 1;
                        if (sy >= 0 && sy < H && sx >= 0 && sx < W)
                            acc += (double)dout[(oc * H + y) * W + x] *
                                   in[((size_t)ic * H + sy) * W + sx];
                    }
                dw_want[(oc * IC + ic) * 9 + k] = (float)acc;
            }
    gs_check_arrays("conv3x3 banded dw", dw, dw_want, OC * IC * 9, 1e-3, 1e-4);
    free(in); free(out); free(want); free(dout); free(s);
}

/* code = 0 gives uniform attention: out = x + wv mean(x) + bv; bk changes
 * nothing. */
static void test_attention_uniform(void)
{
    enum { C = 3, D = 2, HW = 5 };
    nn_rng r = {5};
    float x[C * HW], code[D] = {0, 0}, wk[D * C], bk[D], wv[C * C], bv[C];
    float out[C * HW], out2[C * HW], att[HW], s[5 * C];
    nn_fill(&r, x, C * HW, -1, 1);
    nn_fill(&r, wk, D * C, -1, 1);
    nn_fill(&r, bk, D, -1, 1);
    nn_fill(&r, wv, C * C, -1, 1);
    nn_fill(&r, bv, C, -1, 1);
    CHECK_EQ_INT(gs_nn_attention_forward(out, att, x, code, wk, bk, wv, bv, C, D, HW,
                                         12.0f, s, 5 * C), GS_OK);
    for (int p = 0; p < HW; p++)
        CHECK_CLOSE(att[p], 1.0 / HW, 1e-7, 0);
    for (int c = 0; c < C; c++) {
        double a = bv[c];
        for (int k = 0; k < C; k++) {
            double mean = 0.0;
            for (int p = 0; p < HW; p++)
                mean += x[k * HW + p] / (double)HW;
            a += wv[c * C + k] * mean;
        }
        for (int p = 0; p < HW; p++)
            CHECK_CLOSE(out[c * HW + p], x[c * HW + p] + a, 1e-6, 1e-6);
    }
    code[0] = 0.5f;
    code[1] = -1.0f;
    gs_nn_attention_forward(out, att, x, code, wk, bk, wv, bv, C, D, HW, 12.0f, s, 5 * C);
    gs_nn_attention_forward(out2, att, x, code, wk, NULL, wv, bv, C, D, HW, 12.0f, s, 5 * C);
    CHECK(memcmp(out, out2, sizeof out) == 0);
}

static void test_l1(void)
{
    float a[6] = {1, 2, 3, 4, 5, 6}, b[6] = {0, 2, 5, 4, 5, 9};
    float ones[3] = {1, 1, 1}, zeros[3] = {0, 0, 0}, half[3] = {1, 0, 0};
    float l0, l1, l2, l3;
    gs_nn_l1_forward(&l0, a, b, NULL, 2, 3);
    gs_nn_l1_forward(&l1, a, b, ones, 2, 3);
    gs_nn_l1_forward(&l2, a, b, zeros, 2, 3);
    gs_nn_l1_forward(&l3, a, b, half, 2, 3);
    CHECK_CLOSE(l0, (1 + 0 + 2 + 0 + 0 + 3) / 6.0, 0, 1e-7);
    CHECK(l0 == l1);
    CHECK(l2 == 0.0f);
    CHECK_CLOSE(l3, (1 + 0) / 6.0, 0, 1e-7); /* masked pixel 0 only, still / 6 */
    float da[6] = {0};
    gs_nn_l1_backward(da, 6.0f, a, b, half, 2, 3);
    float want[6] = {1, 0, 0, 0, 0, 0}; /* sign(0) = 0 at pixel 0 channel 1 */
    gs_check_arrays("l1 da", da, want, 6, 0, 0);
}

static void test_ssim_identity(void)
{
    enum { C = 2, H = 12, W = 13 };
    nn_rng r = {3};
    float x[C * H * W], dx[C * H * W] = {0}, loss = -1.0f;
    nn_fill(&r, x, C * H * W, 0, 1);
    size_t ns = gs_nn_ssim_scratch_size(H, W, GS_NN_SSIM_ZERO);
    float *s = nn_alloc(ns);
    CHECK_EQ_INT(gs_nn_ssim_loss_forward(&loss, x, x, C, H, W, GS_NN_SSIM_ZERO, s, ns), GS_OK);
    CHECK_CLOSE(loss, 0.0, 1e-6, 0);
    CHECK_EQ_INT(gs_nn_ssim_loss_backward(dx, 1.0f, x, x, C, H, W, GS_NN_SSIM_ZERO, s, ns),
                 GS_OK);
    double mx = 0.0;
    for (int i = 0; i < C * H * W; i++)
        mx = fabs(dx[i]) > mx ? fabs(dx[i]) : mx;
    CHECK_MSG(mx < 1e-6, "max |dx| at the optimum = %g", mx);
    free(s);
}

/* ---- Adam ---------------------------------------------------------------- */

/* Two groups (lr_mult 1 and 0.5), p = 1, grads 0.5 then -0.25, lr 0.1:
 *   t=1: m = 0.05, v = 0.00025, m^ = 0.5, v^ = 0.25,
 *        p = 1 - 0.1 * 0.5 / (0.5 + 1e-8) = 0.900000002
 *   t=2: m = 0.9*0.05 - 0.1*0.25 = 0.02, v = 0.999*0.00025 + 0.001*0.0625
 *        = 0.00031225, m^ = 0.02/0.19 = 0.1052631579,
 *        v^ = 0.00031225/0.001999 = 0.1562031016,
 *        p = 0.900000002 - 0.1 * 0.1052631579 / (0.3952253809 + 1e-8)
 *          = 0.8733662987
 *   group 2 moves half as far: 0.950000001, then 0.9366831494. */
static void test_adam_two_steps(void)
{
    float p[2] = {1.0f, 1.0f}, g[2];
    gs_nn_param_group groups[2] = {{&p[0], &g[0], 1, 1.0f}, {&p[1], &g[1], 1, 0.5f}};
    gs_nn_adam *adam = NULL;
    CHECK_EQ_INT(gs_nn_adam_create(&adam, groups, 2, NULL, NULL), GS_OK);
    if (!adam)
        return;
    g[0] = g[1] = 0.5f;
    double norm;
    CHECK_EQ_INT(gs_nn_adam_step(adam, 0.1, &norm), GS_OK);
    CHECK_CLOSE(norm, sqrt(0.5), 0, 1e-7);
    CHECK_CLOSE(p[0], 0.900000002, 0, 2e-7);
    CHECK_CLOSE(p[1], 0.950000001, 0, 2e-7);
    float *m, *v;
    CHECK_EQ_INT(gs_nn_adam_moments(adam, 0, &m, &v), GS_OK);
    CHECK_CLOSE(m[0], 0.05, 0, 1e-6);
    CHECK_CLOSE(v[0], 0.00025, 0, 1e-6);
    g[0] = g[1] = -0.25f;
    CHECK_EQ_INT(gs_nn_adam_step(adam, 0.1f, NULL), GS_OK);
    CHECK_CLOSE(m[0], 0.02, 0, 1e-6);
    CHECK_CLOSE(v[0], 0.00031225, 0, 1e-6);
    CHECK_CLOSE(p[0], 0.8733662987, 0, 2e-7);
    CHECK_CLOSE(p[1], 0.9366831494, 0, 2e-7);
    CHECK_EQ_INT(gs_nn_adam_steps(adam), 2);
    gs_nn_adam_zero_grad(adam);
    CHECK(g[0] == 0.0f && g[1] == 0.0f);
    CHECK_EQ_INT(gs_nn_adam_moments(adam, 2, &m, &v), GS_ERR_ARG);
    gs_nn_adam_destroy(adam);
}

/* Clipping scales the gradient seen by the moments (not the grad buffer)
 * by max_norm / (norm + 1e-6); below the threshold nothing is scaled. */
static void test_adam_clip(void)
{
    float p[2] = {0, 0}, g[2] = {3.0f, 4.0f};
    gs_nn_param_group grp = {p, g, 2, 1.0f};
    gs_nn_adam_config cfg = gs_nn_adam_default_config();
    cfg.max_grad_norm = 1.0;
    gs_nn_adam *adam = NULL;
    CHECK_EQ_INT(gs_nn_adam_create(&adam, &grp, 1, &cfg, NULL), GS_OK);
    if (!adam)
        return;
    double norm;
    float *m;
    CHECK_EQ_INT(gs_nn_adam_step(adam, 1e-3f, &norm), GS_OK);
    CHECK_CLOSE(norm, 5.0, 0, 1e-7);
    gs_nn_adam_moments(adam, 0, &m, NULL);
    double k = 1.0 / (5.0 + 1e-6);
    CHECK_CLOSE(m[0], 0.1 * 3.0 * k, 0, 1e-6);
    CHECK_CLOSE(m[1], 0.1 * 4.0 * k, 0, 1e-6);
    CHECK(g[0] == 3.0f && g[1] == 4.0f);
    g[0] = 0.3f;
    g[1] = 0.4f; /* norm 0.5 < 1: unclipped */
    CHECK_EQ_INT(gs_nn_adam_step(adam, 1e-3f, &norm), GS_OK);
    CHECK_CLOSE(m[0], 0.9 * 0.1 * 3.0 * k + 0.1 * 0.3, 0, 1e-6);
    gs_nn_adam_destroy(adam);
}

/* The step on a pool: groups that span several chunks (and end inside
 * one), with clipping on, give the same bytes (parameters, moments, norm)
 * on no pool, a pool of 2 and a pool of 3, and the norm is the double sum
 * of the squares to 1e-12. A NaN in a late chunk is refused on a pool too,
 * changing nothing. */
static void test_adam_pool(void)
{
    enum { NA = 100003, NB = 7, NC = 32768 * 2 };
    size_t ns[3] = {NA, NB, NC};
    float *p[3][3], *g[3];
    uint32_t r = 12345;
    for (int i = 0; i < 3; i++) {
        g[i] = malloc(ns[i] * sizeof(float));
        for (int run = 0; run < 3; run++)
            p[run][i] = malloc(ns[i] * sizeof(float));
    }
    gs_pool *pools[3] = {NULL, gs_pool_create(2), gs_pool_create(3)};
    gs_nn_adam *adam[3] = {NULL, NULL, NULL};
    double norms[3][3];
    gs_nn_adam_config cfg = gs_nn_adam_default_config();
    cfg.max_grad_norm = 50.0;
    for (int run = 0; run < 3; run++) {
        for (int i = 0; i < 3; i++)
            for (size_t j = 0; j < ns[i]; j++)
                p[run][i][j] = (float)j / (float)ns[i] - 0.5f;
        gs_nn_param_group groups[3];
        for (int i = 0; i < 3; i++) {
            groups[i].param = p[run][i];
            groups[i].grad = g[i];
            groups[i].n = ns[i];
            groups[i].lr_mult = 1.0 + i;
        }
        CHECK_EQ_INT(gs_nn_adam_create(&adam[run], groups, 3, &cfg, NULL), GS_OK);
    }
    for (int step = 0; step < 3; step++) {
        double want = 0;
        r = 12345u + (uint32_t)step;
        for (int i = 0; i < 3; i++)
            for (size_t j = 0; j < ns[i]; j++) {
                r = r * 1664525u + 1013904223u;
                g[i][j] = ((float)(r >> 8) / 16777216.0f - 0.5f) * (step == 1 ? 2.0f : 0.2f);
                want += (double)g[i][j] * g[i][j];
            }
        for (int run = 0; run < 3 && adam[run]; run++) {
            CHECK_EQ_INT(gs_nn_adam_step_pool(adam[run], pools[run], 1e-3, &norms[run][step]),
                         GS_OK);
        }
        CHECK_CLOSE(norms[0][step], sqrt(want), 0, 1e-12);
        CHECK(norms[1][step] == norms[0][step] && norms[2][step] == norms[0][step]);
    }
    CHECK_MSG(norms[0][1] > 50.0 && norms[0][0] < 50.0, "the clip was not reached once: %g %g",
              norms[0][0], norms[0][1]);
    for (int run = 1; run < 3; run++) {
        for (int i = 0; i < 3; i++) {
            CHECK_MSG(memcmp(p[run][i], p[0][i], ns[i] * sizeof(float)) == 0,
                      "pool run %d: group %d's parameters differ", run, i);
            float *m0, *v0, *m1, *v1;
            gs_nn_adam_moments(adam[0], i, &m0, &v0);
            gs_nn_adam_moments(adam[run], i, &m1, &v1);
            CHECK(memcmp(m0, m1, ns[i] * sizeof(float)) == 0 &&
                  memcmp(v0, v1, ns[i] * sizeof(float)) == 0);
        }
    }
    /* a NaN in group C's last chunk: refused, nothing changes */
    float keep = p[1][2][NC - 1];
    g[2][NC - 3] = NAN;
    double norm = 0;
    CHECK_EQ_INT(gs_nn_adam_step_pool(adam[1], pools[1], 1e-3, &norm), GS_ERR_NONFINITE);
    CHECK(!isfinite(norm) && p[1][2][NC - 1] == keep && gs_nn_adam_steps(adam[1]) == 3);
    for (int run = 0; run < 3; run++) {
        gs_nn_adam_destroy(adam[run]);
        gs_pool_destroy(pools[run]);
        for (int i = 0; i < 3; i++)
            free(p[run][i]);
    }
    for (int i = 0; i < 3; i++)
        free(g[i]);
}

/* A NaN or Inf gradient is refused: no parameter, moment or count changes. */
static void test_adam_nonfinite(void)
{
    float p[3] = {1, 2, 3}, g[3] = {0.1f, NAN, 0.2f}, q[1] = {4}, h[1] = {0.5f};
    gs_nn_param_group groups[2] = {{p, g, 3, 1.0f}, {q, h, 1, 1.0f}};
    gs_nn_adam *adam = NULL;
    CHECK_EQ_INT(gs_nn_adam_create(&adam, groups, 2, NULL, NULL), GS_OK);
    if (!adam)
        return;
    double norm = 0.0;
    float *m, *v;
    CHECK_EQ_INT(gs_nn_adam_step(adam, 0.1f, &norm), GS_ERR_NONFINITE);
    CHECK(isnan(norm));
    g[1] = INFINITY;
    CHECK_EQ_INT(gs_nn_adam_step(adam, 0.1f, &norm), GS_ERR_NONFINITE);
    g[1] = 0.1f;
    h[0] = -INFINITY;
    CHECK_EQ_INT(gs_nn_adam_step(adam, 0.1f, NULL), GS_ERR_NONFINITE);
    CHECK(p[0] == 1 && p[1] == 2 && p[2] == 3 && q[0] == 4);
    CHECK_EQ_INT(gs_nn_adam_steps(adam), 0);
    gs_nn_adam_moments(adam, 1, &m, &v);
    CHECK(m[0] == 0.0f && v[0] == 0.0f);
    h[0] = 0.5f;
    CHECK_EQ_INT(gs_nn_adam_step(adam, 0.1f, NULL), GS_OK);
    CHECK_EQ_INT(gs_nn_adam_steps(adam), 1);
    CHECK(p[0] < 1 && q[0] < 4);
    CHECK_EQ_INT(gs_nn_adam_step(adam, NAN, NULL), GS_ERR_ARG);
    CHECK_EQ_INT(gs_nn_adam_step(adam, -1.0f, NULL), GS_ERR_ARG);
    gs_nn_adam_destroy(adam);
}

static void test_adam_bad_config(void)
{
    float p[1], g[1];
    gs_nn_param_group ok = {p, g, 1, 1.0f};
    gs_nn_adam *adam = (gs_nn_adam *)1;
    gs_error err;
    CHECK_EQ_INT(gs_nn_adam_create(&adam, NULL, 1, NULL, &err), GS_ERR_ARG);
    CHECK(adam == NULL);
    CHECK(err.code == GS_ERR_ARG && err.msg[0] != '\0');
    CHECK_EQ_INT(gs_nn_adam_create(&adam, &ok, 0, NULL, NULL), GS_ERR_ARG);
    CHECK_EQ_INT(gs_nn_adam_create(NULL, &ok, 1, NULL, NULL), GS_ERR_ARG);
    gs_nn_param_group bad = ok;
    bad.n = 0;
    CHECK_EQ_INT(gs_nn_adam_create(&adam, &bad, 1, NULL, NULL), GS_ERR_ARG);
    bad = ok;
    bad.grad = NULL;
    CHECK_EQ_INT(gs_nn_adam_create(&adam, &bad, 1, NULL, NULL), GS_ERR_ARG);
    bad = ok;
    bad.lr_mult = -0.1f;
    CHECK_EQ_INT(gs_nn_adam_create(&adam, &bad, 1, NULL, &err), GS_ERR_ARG);
    printf("refused: %s\n", err.msg);
    gs_nn_adam_config cfg = gs_nn_adam_default_config();
    cfg.beta2 = 1.0;
    CHECK_EQ_INT(gs_nn_adam_create(&adam, &ok, 1, &cfg, NULL), GS_ERR_ARG);
    cfg = gs_nn_adam_default_config();
    cfg.eps = 0.0;
    CHECK_EQ_INT(gs_nn_adam_create(&adam, &ok, 1, &cfg, NULL), GS_ERR_ARG);
    CHECK_EQ_INT(gs_nn_adam_step(NULL, 0.1f, NULL), GS_ERR_ARG);
    CHECK_EQ_INT(gs_nn_adam_set_steps(NULL, 1), GS_ERR_ARG);
    gs_nn_adam_destroy(NULL);
}

/* 2x2 pooling: window means, odd or too small sizes refused. */
static void test_avgpool(void)
{
    float in[2 * 2 * 4] = {1, 2, 3, 4, 5, 6, 7, 8, -1, -1, 0, 0, 1, 1, 2, 6};
    float out[2 * 1 * 2], din[16] = {0}, dout[4] = {4, 8, -4, 0};
    CHECK_EQ_INT(gs_nn_avgpool2x_forward(out, in, 2, 2, 4), GS_OK);
    CHECK_CLOSE(out[0], 3.5, 0, 0);
    CHECK_CLOSE(out[1], 5.5, 0, 0);
    CHECK_CLOSE(out[2], 0.0, 0, 0);
    CHECK_CLOSE(out[3], 2.0, 0, 0);
    CHECK_EQ_INT(gs_nn_avgpool2x_backward(din, dout, 2, 2, 4), GS_OK);
    CHECK_CLOSE(din[0], 1.0, 0, 0);
    CHECK_CLOSE(din[6], 2.0, 0, 0);
    CHECK_CLOSE(din[9], -1.0, 0, 0);
    CHECK_EQ_INT(gs_nn_avgpool2x_forward(out, in, 2, 3, 4), GS_ERR_ARG);
    CHECK_EQ_INT(gs_nn_avgpool2x_forward(out, in, 2, 2, 1), GS_ERR_ARG);
    CHECK_EQ_INT(gs_nn_avgpool2x_backward(NULL, dout, 2, 2, 4), GS_ERR_ARG);
}

int main(void)
{
    test_bad_args();
    test_null_grads();
    test_pixel_shuffle();
    test_upsample();
    test_blur();
    test_avgpool();
    test_activations();
    test_accumulates();
    test_conv3x3_bands();
    test_attention_uniform();
    test_l1();
    test_ssim_identity();
    test_adam_two_steps();
    test_adam_clip();
    test_adam_pool();
    test_adam_nonfinite();
    test_adam_bad_config();
    GS_TEST_END();
}
