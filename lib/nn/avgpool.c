/* 2x2 average pooling, stride 2: the downsampling of the gaze estimator. */
#include "gazesplat/nn.h"
#include "nn_internal.h"

/* Sizes of a 2x2 pool over in[C,H,W]: H, W even and C*H*W fits an int. */
static int pool_check(int C, int H, int W)
{
    int hw, t;
    if (C < 1 || H < 2 || W < 2 || (H & 1) || (W & 1))
        return GS_ERR_ARG;
    if (!nn_mul(H, W, &hw) || !nn_mul(hw, C, &t))
        return GS_ERR_LIMIT;
    return GS_OK;
}

/* out[C,H/2,W/2] = mean of each 2x2 window of in[C,H,W] */
int gs_nn_avgpool2x_forward(float *out, const float *in, int C, int H, int W)
{
    int rc = pool_check(C, H, W);
    if (rc)
        return rc;
    if (!out || !in)
        return GS_ERR_ARG;
    int Ho = H / 2, Wo = W / 2;
    for (int c = 0; c < C; c++) {
        const float *src = in + (size_t)c * (size_t)H * (size_t)W;
        float *dst = out + (size_t)c * (size_t)Ho * (size_t)Wo;
        for (int y = 0; y < Ho; y++) {
            const float *r0 = src + (size_t)(2 * y) * (size_t)W;
            const float *r1 = r0 + W;
            float *d = dst + (size_t)y * (size_t)Wo;
            for (int x = 0; x < Wo; x++)
                d[x] = 0.25f * ((r0[2 * x] + r0[2 * x + 1]) +
                                (r1[2 * x] + r1[2 * x + 1]));
        }
    }
    return GS_OK;
}

/* dinp[C,H,W] += dout[C,H/2,W/2] / 4 on each pixel of its window */
int gs_nn_avgpool2x_backward(float *dinp, const float *dout, int C, int H,
                             int W)
{
    int rc = pool_check(C, H, W);
    if (rc)
        return rc;
    if (!dinp || !dout)
        return GS_ERR_ARG;
    int Ho = H / 2, Wo = W / 2;
    for (int c = 0; c < C; c++) {
        float *dst = dinp + (size_t)c * (size_t)H * (size_t)W;
        const float *src = dout + (size_t)c * (size_t)Ho * (size_t)Wo;
        for (int y = 0; y < Ho; y++) {
            float *r0 = dst + (size_t)(2 * y) * (size_t)W;
            float *r1 = r0 + W;
            const float *s = src + (size_t)y * (size_t)Wo;
            for (int x = 0; x < Wo; x++) {
                float g = 0.25f * s[x];
                r0[2 * x] += g;
                r0[2 * x + 1] += g;
                r1[2 * x] += g;
                r1[2 * x + 1] += g;
            }
        }
    }
    return GS_OK;
}
