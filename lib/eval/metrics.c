/* Image metrics of the evaluation: PSNR and SSIM over a mask, regions. */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "gazesplat/eval.h"

double gs_eval_psnr(const uint8_t *a, size_t sa, const uint8_t *b, size_t sb,
                    int w, int h, const uint8_t *mask)
{
    double se = 0;
    size_t n = 0;
    for (int y = 0; y < h; y++)
        for (int x = 0; x < w; x++) {
            if (mask && !mask[(size_t)y * w + x])
                continue;
            const uint8_t *pa = a + (size_t)y * sa + 3 * (size_t)x;
            const uint8_t *pb = b + (size_t)y * sb + 3 * (size_t)x;
            for (int c = 0; c < 3; c++) {
                double d = (double)pa[c] - pb[c];
                se += d * d;
            }
            n += 3;
        }
    if (n == 0)
        return NAN;
    double mse = se / (double)n;
    return mse > 0 ? 10.0 * log10(255.0 * 255.0 / mse) : 100.0;
}

#define SSIM_R 5 /* 11 taps */

/* Separable Gaussian blur of a w x h plane with the window renormalised
 * over the pixels inside the image.
 *   in, out: [h, w]; tmp: [h, w] */
static void blur(const float *in, float *out, float *tmp, int w, int h,
                 const float g[2 * SSIM_R + 1])
{
    for (int y = 0; y < h; y++)
        for (int x = 0; x < w; x++) {
            float s = 0, ws = 0;
            for (int k = -SSIM_R; k <= SSIM_R; k++) {
                int xx = x + k;
                if (xx < 0 || xx >= w)
                    continue;
                s += g[k + SSIM_R] * in[(size_t)y * w + xx];
                ws += g[k + SSIM_R];
            }
            tmp[(size_t)y * w + x] = s / ws;
        }
    for (int y = 0; y < h; y++)
        for (int x = 0; x < w; x++) {
            float s = 0, ws = 0;
            for (int k = -SSIM_R; k <= SSIM_R; k++) {
                int yy = y + k;
                if (yy < 0 || yy >= h)
                    continue;
                s += g[k + SSIM_R] * tmp[(size_t)yy * w + x];
                ws += g[k + SSIM_R];
            }
            out[(size_t)y * w + x] = s / ws;
        }
}

/* Sum of the SSIM map of channel c over the mask.
 * buf: 8 planes of [h, w] */
static double ssim_channel(const uint8_t *a, size_t sa, const uint8_t *b,
                           size_t sb, int w, int h, int c,
                           const uint8_t *mask, float *buf,
                           const float g[2 * SSIM_R + 1])
{
    size_t n = (size_t)w * h;
    float *x = buf, *yv = buf + n, *mx = buf + 2 * n, *my = buf + 3 * n;
    float *sxx = buf + 4 * n, *syy = buf + 5 * n, *sxy = buf + 6 * n;
    float *tmp = buf + 7 * n;
    for (int yy = 0; yy < h; yy++)
        for (int xx = 0; xx < w; xx++) {
            x[(size_t)yy * w + xx] = a[(size_t)yy * sa + 3 * xx + c] / 255.0f;
            yv[(size_t)yy * w + xx] = b[(size_t)yy * sb + 3 * xx + c] / 255.0f;
        }
    blur(x, mx, tmp, w, h, g);
    blur(yv, my, tmp, w, h, g);
    /* Second moments: square in place into the (now free) planes. */
    for (size_t i = 0; i < n; i++) {
        sxx[i] = x[i] * x[i];
        syy[i] = yv[i] * yv[i];
        sxy[i] = x[i] * yv[i];
    }
    blur(sxx, x, tmp, w, h, g);
    blur(syy, sxx, tmp, w, h, g);
    blur(sxy, syy, tmp, w, h, g);
    /* x = E[x^2], sxx = E[y^2], syy = E[xy] */
    const double c1 = 0.01 * 0.01, c2 = 0.03 * 0.03;
    double sum = 0;
    for (size_t i = 0; i < n; i++) {
        if (mask && !mask[i])
            continue;
        double ux = mx[i], uy = my[i];
        double vx = x[i] - ux * ux, vy = sxx[i] - uy * uy;
        double cxy = syy[i] - ux * uy;
        sum += (2 * ux * uy + c1) * (2 * cxy + c2) /
               ((ux * ux + uy * uy + c1) * (vx + vy + c2));
    }
    return sum;
}

double gs_eval_ssim(const uint8_t *a, size_t sa, const uint8_t *b, size_t sb,
                    int w, int h, const uint8_t *mask, gs_error *err)
{
    size_t n = mask ? gs_eval_mask_count(mask, w, h) : (size_t)w * h;
    if (n == 0)
        return NAN;
    float *buf = malloc(8 * (size_t)w * h * sizeof(float));
    if (!buf) {
        gs_error_set(err, GS_ERR_NOMEM, "eval: out of memory");
        return NAN;
    }
    float g[2 * SSIM_R + 1];
    for (int k = -SSIM_R; k <= SSIM_R; k++)
        g[k + SSIM_R] = expf(-(float)(k * k) / (2 * 1.5f * 1.5f));
    double s = 0;
    for (int c = 0; c < 3; c++)
        s += ssim_channel(a, sa, b, sb, w, h, c, mask, buf, g);
    free(buf);
    return s / (3.0 * (double)n);
}

int gs_eval_mask_dilate(const uint8_t *in, int w, int h, int r, uint8_t *out)
{
    /* Rows then columns: a (2r+1)^2 square. */
    uint8_t *row = malloc((size_t)w * h);
    if (!row)
        return GS_ERR_NOMEM;
    for (int y = 0; y < h; y++)
        for (int x = 0; x < w; x++) {
            uint8_t v = 0;
            for (int k = -r; k <= r && !v; k++) {
                int xx = x + k;
                v = xx >= 0 && xx < w && in[(size_t)y * w + xx];
            }
            row[(size_t)y * w + x] = v ? 255 : 0;
        }
    for (int y = 0; y < h; y++)
        for (int x = 0; x < w; x++) {
            uint8_t v = 0;
            for (int k = -r; k <= r && !v; k++) {
                int yy = y + k;
                v = yy >= 0 && yy < h && row[(size_t)yy * w + x];
            }
            out[(size_t)y * w + x] = v ? 255 : 0;
        }
    free(row);
    return GS_OK;
}

size_t gs_eval_mask_count(const uint8_t *m, int w, int h)
{
    size_t n = 0;
    for (size_t i = 0; i < (size_t)w * h; i++)
        n += m[i] != 0;
    return n;
}

int gs_eval_regions(const gs_synth_sample *gt, uint8_t *eye, uint8_t *face)
{
    int w = gt->width, h = gt->height;
    size_t n = (size_t)w * h;
    const uint8_t *le = gs_synth_sample_mask(gt, GS_SYNTH_MASK_LEFT_EYE);
    const uint8_t *re = gs_synth_sample_mask(gt, GS_SYNTH_MASK_RIGHT_EYE);
    const uint8_t *fm = gs_synth_sample_mask(gt, GS_SYNTH_MASK_FACE);
    for (size_t i = 0; i < n; i++)
        face[i] = le[i] || re[i] ? 255 : 0; /* scratch: both eyeballs */
    int r = w / 64 > 1 ? w / 64 : 1;
    int rc = gs_eval_mask_dilate(face, w, h, r, eye);
    if (rc)
        return rc;
    for (size_t i = 0; i < n; i++)
        face[i] = fm[i] && !eye[i] ? 255 : 0;
    return GS_OK;
}
