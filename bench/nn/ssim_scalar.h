/* The SSIM loss as the library computed it before the one-pass pooled
 * version (gs_nn_ssim_loss_fused): scalar, one channel at a time, the
 * window statistics computed once for the forward and again for the
 * backward. Kept as the reference the vector passes must match bit for bit
 * (test_nn_ssim_fused) and the baseline bench_ssim measures against. */
#ifndef BENCH_SSIM_SCALAR_H
#define BENCH_SSIM_SCALAR_H

#include <math.h>

#include "gazesplat/nn.h"

enum { WIN = 11, NSTAT = 5 };
#define SSIM_C1 (0.01f * 0.01f)
#define SSIM_C2 (0.03f * 0.03f)

typedef struct {
    int H, W, Ho, Wo, pad;
    float g[WIN];
    float *hmap;  /* NSTAT x [H,Wo] */
    float *vmap;  /* NSTAT x [Ho,Wo] */
} ssim_ctx;

/* The geometry, the window and the maps in scratch (sized by the library's
 * gs_nn_ssim_scratch_size: the layout has not changed); GS_ERR_ARG when
 * the window does not fit or scratch is short. */
static int ssim_setup(ssim_ctx *s, int C, int H, int W, int padding,
                      float *scratch, size_t scratch_len)
{
    size_t need = gs_nn_ssim_scratch_size(H, W, padding);
    if (C < 1 || !need || !scratch || scratch_len < need)
        return GS_ERR_ARG;
    s->pad = padding == GS_NN_SSIM_ZERO ? WIN / 2 : 0;
    s->H = H;
    s->W = W;
    s->Ho = H + 2 * s->pad - (WIN - 1);
    s->Wo = W + 2 * s->pad - (WIN - 1);
    float sum = 0.0f;
    for (int k = 0; k < WIN; k++) {
        float d = (float)(k - WIN / 2);
        s->g[k] = expf(-(d * d) / (2.0f * 1.5f * 1.5f));
        sum += s->g[k];
    }
    for (int k = 0; k < WIN; k++)
        s->g[k] /= sum;
    s->hmap = scratch;
    s->vmap = scratch + (size_t)NSTAT * (size_t)H * (size_t)s->Wo;
    return GS_OK;
}

/* Window statistics of one channel x, y [H,W] into vmap. */
static void ssim_stats(ssim_ctx *s, const float *x, const float *y)
{
    size_t hsz = (size_t)s->H * (size_t)s->Wo, vsz = (size_t)s->Ho * (size_t)s->Wo;
    for (int r = 0; r < s->H; r++) {
        const float *xr = x + (size_t)r * (size_t)s->W;
        const float *yr = y + (size_t)r * (size_t)s->W;
        for (int xo = 0; xo < s->Wo; xo++) {
            float acc[NSTAT] = {0};
            for (int k = 0; k < WIN; k++) {
                int c = xo + k - s->pad;
                if (c < 0 || c >= s->W)
                    continue;
                float a = xr[c], b = yr[c], g = s->g[k];
                acc[0] += g * a;
                acc[1] += g * b;
                acc[2] += g * a * a;
                acc[3] += g * b * b;
                acc[4] += g * a * b;
            }
            size_t at = (size_t)r * (size_t)s->Wo + (size_t)xo;
            for (int q = 0; q < NSTAT; q++)
                s->hmap[q * hsz + at] = acc[q];
        }
    }
    for (int q = 0; q < NSTAT; q++) {
        const float *h = s->hmap + q * hsz;
        float *v = s->vmap + q * vsz;
        for (int yo = 0; yo < s->Ho; yo++) {
            float *vr = v + (size_t)yo * (size_t)s->Wo;
            for (int xo = 0; xo < s->Wo; xo++)
                vr[xo] = 0.0f;
            for (int k = 0; k < WIN; k++) {
                int r = yo + k - s->pad;
                if (r < 0 || r >= s->H)
                    continue;
                const float *hr = h + (size_t)r * (size_t)s->Wo;
                for (int xo = 0; xo < s->Wo; xo++)
                    vr[xo] += s->g[k] * hr[xo];
            }
        }
    }
}

/* The SSIM terms at one position from its five statistics. */
typedef struct { float a1, a2, b1, b2; } ssim_terms;

static ssim_terms ssim_at(float mx, float my, float exx, float eyy, float exy)
{
    ssim_terms t;
    t.a1 = 2.0f * mx * my + SSIM_C1;
    t.a2 = 2.0f * (exy - mx * my) + SSIM_C2;
    t.b1 = mx * mx + my * my + SSIM_C1;
    t.b2 = (exx - mx * mx) + (eyy - my * my) + SSIM_C2;
    return t;
}

/* loss = 1 - mean SSIM of x vs y [C,H,W] */
static int scalar_ssim_forward(float *loss, const float *x, const float *y,
                            int C, int H, int W, int padding, float *scratch,
                            size_t scratch_len)
{
    ssim_ctx s;
    int rc = ssim_setup(&s, C, H, W, padding, scratch, scratch_len);
    if (rc)
        return rc;
    if (!loss || !x || !y)
        return GS_ERR_ARG;
    size_t hw = (size_t)H * (size_t)W, vsz = (size_t)s.Ho * (size_t)s.Wo;
    double sum = 0.0;
    for (int c = 0; c < C; c++) {
        ssim_stats(&s, x + (size_t)c * hw, y + (size_t)c * hw);
        const float *v = s.vmap;
        for (size_t i = 0; i < vsz; i++) {
            ssim_terms t = ssim_at(v[i], v[vsz + i], v[2 * vsz + i],
                                   v[3 * vsz + i], v[4 * vsz + i]);
            sum += (double)(t.a1 * t.a2) / (double)(t.b1 * t.b2);
        }
    }
    *loss = (float)(1.0 - sum / ((double)C * (double)vsz));
    return GS_OK;
}

/* Overwrites vmap slots 0, 2, 4 with w dS/dmx, w dS/dExx, w dS/dExy. */
static void ssim_grad_maps(ssim_ctx *s, float w)
{
    size_t vsz = (size_t)s->Ho * (size_t)s->Wo;
    float *v = s->vmap;
    for (size_t i = 0; i < vsz; i++) {
        float mx = v[i], my = v[vsz + i];
        ssim_terms t = ssim_at(mx, my, v[2 * vsz + i], v[3 * vsz + i],
                               v[4 * vsz + i]);
        float den = t.b1 * t.b2, S = t.a1 * t.a2 / den;
        v[i] = w * (2.0f * my * (t.a2 - t.a1) / den +
                    2.0f * mx * S * (1.0f / t.b2 - 1.0f / t.b1));
        v[2 * vsz + i] = w * (-S / t.b2);
        v[4 * vsz + i] = w * (2.0f * t.a1 / den);
    }
}

/* hmap slot q [H,Wo] = vertical adjoint of vmap slot q [Ho,Wo]. */
static void ssim_vertical_adjoint(ssim_ctx *s, int q)
{
    size_t hsz = (size_t)s->H * (size_t)s->Wo, vsz = (size_t)s->Ho * (size_t)s->Wo;
    float *h = s->hmap + q * hsz;
    const float *v = s->vmap + q * vsz;
    for (size_t i = 0; i < hsz; i++)
        h[i] = 0.0f;
    for (int yo = 0; yo < s->Ho; yo++) {
        const float *vr = v + (size_t)yo * (size_t)s->Wo;
        for (int k = 0; k < WIN; k++) {
            int r = yo + k - s->pad;
            if (r < 0 || r >= s->H)
                continue;
            float *hr = h + (size_t)r * (size_t)s->Wo;
            for (int xo = 0; xo < s->Wo; xo++)
                hr[xo] += s->g[k] * vr[xo];
        }
    }
}

/* dx[c] += horizontal adjoint of (Gmx + 2x GExx + y GExy). */
static void ssim_horizontal_adjoint(ssim_ctx *s, float *dx, const float *x,
                                    const float *y)
{
    size_t hsz = (size_t)s->H * (size_t)s->Wo;
    const float *gm = s->hmap, *gxx = s->hmap + 2 * hsz, *gxy = s->hmap + 4 * hsz;
    for (int r = 0; r < s->H; r++) {
        size_t row = (size_t)r * (size_t)s->W, hrow = (size_t)r * (size_t)s->Wo;
        for (int c = 0; c < s->W; c++) {
            float t1 = 0.0f, t2 = 0.0f, t3 = 0.0f;
            for (int k = 0; k < WIN; k++) {
                int xo = c - k + s->pad;
                if (xo < 0 || xo >= s->Wo)
                    continue;
                t1 += s->g[k] * gm[hrow + (size_t)xo];
                t2 += s->g[k] * gxx[hrow + (size_t)xo];
                t3 += s->g[k] * gxy[hrow + (size_t)xo];
            }
            dx[row + (size_t)c] += t1 + 2.0f * x[row + (size_t)c] * t2 +
                                   y[row + (size_t)c] * t3;
        }
    }
}

/* dx[C,H,W] += dloss * d(1 - mean SSIM)/dx */
static int scalar_ssim_backward(float *dx, float dloss, const float *x,
                             const float *y, int C, int H, int W, int padding,
                             float *scratch, size_t scratch_len)
{
    ssim_ctx s;
    int rc = ssim_setup(&s, C, H, W, padding, scratch, scratch_len);
    if (rc)
        return rc;
    if (!dx || !x || !y || !isfinite(dloss))
        return GS_ERR_ARG;
    size_t hw = (size_t)H * (size_t)W;
    float w = (float)(-(double)dloss / ((double)C * s.Ho * s.Wo));
    for (int c = 0; c < C; c++) {
        const float *xc = x + (size_t)c * hw, *yc = y + (size_t)c * hw;
        ssim_stats(&s, xc, yc);
        ssim_grad_maps(&s, w);
        ssim_vertical_adjoint(&s, 0);
        ssim_vertical_adjoint(&s, 2);
        ssim_vertical_adjoint(&s, 4);
        ssim_horizontal_adjoint(&s, dx + (size_t)c * hw, xc, yc);
    }
    return GS_OK;
}

#endif
