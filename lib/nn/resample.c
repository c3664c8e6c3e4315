/* Pixel shuffle, bilinear 2x upsampling and the fixed [1,2,1] blur.
 * Backward passes scatter-add in a fixed loop order (deterministic). */
#include "gazesplat/nn.h"
#include "nn_internal.h"

/* Sizes for an x2 resample of in[C,H,W]: *hw = H*W and the output of 4 H*W
 * pixels per channel must fit an int. */
static int check2x(int C, int H, int W, int *hw)
{
    int t;
    if (C < 1 || H < 1 || W < 1)
        return GS_ERR_ARG;
    if (!nn_mul(H, W, hw) || !nn_mul(*hw, 4, &t) || !nn_mul(t, C, &t))
        return GS_ERR_LIMIT;
    return GS_OK;
}

/* out[C,2H,2W][c, 2h+i, 2w+j] = in[4C,H,W][4c+2i+j, h, w] */
int gs_nn_pixel_shuffle_forward(float *out, const float *in, int C, int H,
                                int W)
{
    int hw, rc = check2x(C, H, W, &hw);
    if (rc)
        return rc;
    if (!out || !in)
        return GS_ERR_ARG;
    size_t W2 = 2 * (size_t)W;
    for (int c = 0; c < C; c++)
        for (int k = 0; k < 4; k++) {
            const float *src = in + (size_t)(4 * c + k) * (size_t)hw;
            float *dst = out + (size_t)c * 4 * (size_t)hw + (size_t)(k >> 1) * W2 + (size_t)(k & 1);
            for (int h = 0; h < H; h++)
                for (int w = 0; w < W; w++)
                    dst[(size_t)h * 2 * W2 + 2 * (size_t)w] = src[(size_t)h * (size_t)W + (size_t)w];
        }
    return GS_OK;
}

/* dinp[4C,H,W][4c+2i+j, h, w] += dout[C,2H,2W][c, 2h+i, 2w+j] */
int gs_nn_pixel_shuffle_backward(float *dinp, const float *dout, int C, int H,
                                 int W)
{
    int hw, rc = check2x(C, H, W, &hw);
    if (rc)
        return rc;
    if (!dinp || !dout)
        return GS_ERR_ARG;
    size_t W2 = 2 * (size_t)W;
    for (int c = 0; c < C; c++)
        for (int k = 0; k < 4; k++) {
            float *dst = dinp + (size_t)(4 * c + k) * (size_t)hw;
            const float *src = dout + (size_t)c * 4 * (size_t)hw + (size_t)(k >> 1) * W2 + (size_t)(k & 1);
            for (int h = 0; h < H; h++)
                for (int w = 0; w < W; w++)
                    dst[(size_t)h * (size_t)W + (size_t)w] += src[(size_t)h * 2 * W2 + 2 * (size_t)w];
        }
    return GS_OK;
}

/* Source taps of output index o along an axis of n input samples, as
 * PyTorch's area_pixel_compute_source_index + linear weights with scale 1/2
 * (float arithmetic, so the weights are 1, 0.75 or 0.25 exactly). */
typedef struct { int i0, i1; float l0, l1; } taps;

static taps taps2x(int o, int n)
{
    taps t;
    float src = 0.5f * ((float)o + 0.5f) - 0.5f;
    if (src < 0.0f)
        src = 0.0f;
    t.i0 = (int)src;
    t.i1 = t.i0 + (t.i0 < n - 1 ? 1 : 0);
    t.l1 = src - (float)t.i0;
    t.l0 = 1.0f - t.l1;
    return t;
}

/* out[C,2H,2W] = bilinear x2 of in[C,H,W], align_corners=False */
int gs_nn_upsample2x_forward(float *out, const float *in, int C, int H, int W)
{
    return gs_nn_upsample2x_forward_rows(out, in, C, H, W, 0, 2 * H);
}

int gs_nn_upsample2x_forward_rows(float *out, const float *in, int C, int H,
                                  int W, int oy0, int oy1)
{
    int hw, rc = check2x(C, H, W, &hw);
    if (rc)
        return rc;
    if (!out || !in || oy0 < 0 || oy1 > 2 * H || oy0 > oy1)
        return GS_ERR_ARG;
    int W2 = 2 * W;
    for (int c = 0; c < C; c++) {
        const float *src = in + (size_t)c * (size_t)hw;
        float *dst = out + (size_t)c * 4 * (size_t)hw;
        for (int oy = oy0; oy < oy1; oy++) {
            taps ty = taps2x(oy, H);
            const float *r0 = src + (size_t)ty.i0 * (size_t)W;
            const float *r1 = src + (size_t)ty.i1 * (size_t)W;
            float *d = dst + (size_t)oy * (size_t)W2;
            for (int ox = 0; ox < W2; ox++) {
                taps tx = taps2x(ox, W);
                d[ox] = ty.l0 * (tx.l0 * r0[tx.i0] + tx.l1 * r0[tx.i1]) +
                        ty.l1 * (tx.l0 * r1[tx.i0] + tx.l1 * r1[tx.i1]);
            }
        }
    }
    return GS_OK;
}

/* Taps of output index o of n_out along an axis of n input samples for
 * any ratio, as PyTorch's bilinear interpolate(size=...) with
 * align_corners=False computes them in float: scale = n / n_out. With
 * n_out = 2n these are taps2x's exactly. */
static taps taps_any(int o, int n, float scale)
{
    taps t;
    float src = scale * ((float)o + 0.5f) - 0.5f;
    if (src < 0.0f)
        src = 0.0f;
    t.i0 = (int)src;
    if (t.i0 > n - 1)
        t.i0 = n - 1;
    t.i1 = t.i0 + (t.i0 < n - 1 ? 1 : 0);
    t.l1 = src - (float)t.i0;
    t.l0 = 1.0f - t.l1;
    return t;
}

/* out[C,OH,OW] = bilinear resize of in[C,H,W], align_corners=False */
int gs_nn_resize_bilinear_forward(float *out, const float *in, int C, int H,
                                  int W, int OH, int OW)
{
    if (!out || !in || C < 1 || H < 1 || W < 1 || OH < 1 || OW < 1 ||
        (long long)C * OH * OW > INT_MAX || (long long)C * H * W > INT_MAX)
        return GS_ERR_ARG;
    float sy = (float)H / (float)OH, sx = (float)W / (float)OW;
    for (int c = 0; c < C; c++) {
        const float *src = in + (size_t)c * H * W;
        float *dst = out + (size_t)c * OH * OW;
        for (int oy = 0; oy < OH; oy++) {
            taps ty = taps_any(oy, H, sy);
            const float *r0 = src + (size_t)ty.i0 * (size_t)W;
            const float *r1 = src + (size_t)ty.i1 * (size_t)W;
            float *d = dst + (size_t)oy * (size_t)OW;
            for (int ox = 0; ox < OW; ox++) {
                taps tx = taps_any(ox, W, sx);
                d[ox] = ty.l0 * (tx.l0 * r0[tx.i0] + tx.l1 * r0[tx.i1]) +
                        ty.l1 * (tx.l0 * r1[tx.i0] + tx.l1 * r1[tx.i1]);
            }
        }
    }
    return GS_OK;
}

/* dinp[C,H,W] += the adjoint of the forward interpolation applied to
 * dout[C,2H,2W] */
int gs_nn_upsample2x_backward(float *dinp, const float *dout, int C, int H,
                              int W)
{
    int hw, rc = check2x(C, H, W, &hw);
    if (rc)
        return rc;
    if (!dinp || !dout)
        return GS_ERR_ARG;
    int H2 = 2 * H, W2 = 2 * W;
    for (int c = 0; c < C; c++) {
        float *dst = dinp + (size_t)c * (size_t)hw;
        const float *src = dout + (size_t)c * 4 * (size_t)hw;
        for (int oy = 0; oy < H2; oy++) {
            taps ty = taps2x(oy, H);
            float *r0 = dst + (size_t)ty.i0 * (size_t)W;
            float *r1 = dst + (size_t)ty.i1 * (size_t)W;
            const float *g = src + (size_t)oy * (size_t)W2;
            for (int ox = 0; ox < W2; ox++) {
                taps tx = taps2x(ox, W);
                float g0 = ty.l0 * g[ox], g1 = ty.l1 * g[ox];
                r0[tx.i0] += tx.l0 * g0;
                r0[tx.i1] += tx.l1 * g0;
                r1[tx.i0] += tx.l0 * g1;
                r1[tx.i1] += tx.l1 * g1;
            }
        }
    }
    return GS_OK;
}

/* Reflect index i in [-1, n] into [0, n) as PyTorch 'reflect' padding. */
static int reflect(int i, int n)
{
    return i < 0 ? -i : (i >= n ? 2 * n - 2 - i : i);
}

static int blur_check(int C, int H, int W, int *hw)
{
    int t;
    if (C < 1 || H < 2 || W < 2)
        return GS_ERR_ARG;
    if (!nn_mul(H, W, hw) || !nn_mul(*hw, C, &t))
        return GS_ERR_LIMIT;
    return GS_OK;
}

/* out[C,H,W] = ([1,2,1] x [1,2,1] / 16) * in[C,H,W], reflect border */
int gs_nn_blur_forward(float *out, const float *in, int C, int H, int W)
{
    int hw, rc = blur_check(C, H, W, &hw);
    if (rc)
        return rc;
    if (!out || !in)
        return GS_ERR_ARG;
    for (int c = 0; c < C; c++) {
        const float *src = in + (size_t)c * (size_t)hw;
        float *dst = out + (size_t)c * (size_t)hw;
        for (int y = 0; y < H; y++) {
            const float *rows[3];
            for (int k = 0; k < 3; k++)
                rows[k] = src + (size_t)reflect(y + k - 1, H) * (size_t)W;
            for (int x = 0; x < W; x++) {
                int xm = reflect(x - 1, W), xp = reflect(x + 1, W);
                float s = 0.0f;
                for (int k = 0; k < 3; k++) {
                    float r = rows[k][xm] + 2.0f * rows[k][x] + rows[k][xp];
                    s += (k == 1 ? 2.0f : 1.0f) * r;
                }
                dst[(size_t)y * (size_t)W + (size_t)x] = s * (1.0f / 16.0f);
            }
        }
    }
    return GS_OK;
}

/* dinp[C,H,W] += the adjoint of the blur (not the blur itself: reflection
 * makes the operator non-symmetric at the border) applied to dout[C,H,W] */
int gs_nn_blur_backward(float *dinp, const float *dout, int C, int H, int W)
{
    int hw, rc = blur_check(C, H, W, &hw);
    if (rc)
        return rc;
    if (!dinp || !dout)
        return GS_ERR_ARG;
    static const float wt[3] = {1.0f / 16.0f, 2.0f / 16.0f, 1.0f / 16.0f};
    for (int c = 0; c < C; c++) {
        const float *g = dout + (size_t)c * (size_t)hw;
        float *dst = dinp + (size_t)c * (size_t)hw;
        for (int y = 0; y < H; y++)
            for (int ky = 0; ky < 3; ky++) {
                float *row = dst + (size_t)reflect(y + ky - 1, H) * (size_t)W;
                const float *gy = g + (size_t)y * (size_t)W;
                for (int x = 0; x < W; x++) {
                    float gv = wt[ky] * gy[x];
                    row[reflect(x - 1, W)] += gv;
                    row[x] += 2.0f * gv;
                    row[reflect(x + 1, W)] += gv;
                }
            }
    }
    return GS_OK;
}
