/* 3x3 convolution, stride 1, zero padding 1, as im2col + sgemm.
 *
 * The image is processed in bands of rows so the column buffer stays small
 * (IC*9 rows of band pixels). The band height depends on W only: the weight
 * gradient sums band by band, and a fixed band keeps that order, hence the
 * bits, independent of the scratch the caller happens to pass. */
#include "gazesplat/nn.h"
#include "nn_internal.h"

#include <cblas.h>
#include <string.h>

enum { BAND_PIXELS = 8192 }; /* target pixels per band */

static int band_rows(int H, int W)
{
    int rows = (BAND_PIXELS + W - 1) / W;
    return rows < 1 ? 1 : (rows > H ? H : rows);
}

/* Validates sizes; *K = IC*9, *HW = H*W, *bandpix = band rows * W. */
static int conv_check(int IC, int OC, int H, int W, int *K, int *HW,
                      int *bandpix)
{
    int t;
    if (IC < 1 || OC < 1 || H < 1 || W < 1)
        return GS_ERR_ARG;
    if (!nn_mul(IC, 9, K) || !nn_mul(H, W, HW) ||
        !nn_mul(band_rows(H, W), W, bandpix) || !nn_mul(*K, *bandpix, &t) ||
        !nn_mul(OC, *K, &t) || !nn_mul(OC, *HW, &t))
        return GS_ERR_LIMIT;
    return GS_OK;
}

size_t gs_nn_conv3x3_scratch_size(int IC, int H, int W)
{
    int K, HW, bandpix;
    if (conv_check(IC, 1, H, W, &K, &HW, &bandpix) != GS_OK)
        return 0;
    return (size_t)K * (size_t)bandpix;
}

/* col[IC*9, (y1-y0)*W]: row (ic*3+ky)*3+kx holds in[ic, y+ky-1, x+kx-1]
 * for the band's pixels (y, x), zero outside the image. */
static void im2col(float *col, const float *in, int IC, int H, int W, int y0,
                   int y1)
{
    size_t n = (size_t)(y1 - y0) * (size_t)W;
    for (int ic = 0; ic < IC; ic++) {
        const float *plane = in + (size_t)ic * (size_t)H * (size_t)W;
        for (int k = 0; k < 9; k++) {
            int ky = k / 3, kx = k % 3;
            float *dst = col + ((size_t)ic * 9 + (size_t)k) * n;
            for (int y = y0; y < y1; y++) {
                float *d = dst + (size_t)(y - y0) * (size_t)W;
                int sy = y + ky - 1;
                if (sy < 0 || sy >= H) {
                    memset(d, 0, (size_t)W * sizeof *d);
                    continue;
                }
                const float *row = plane + (size_t)sy * (size_t)W;
                for (int x = 0; x < W; x++) {
                    int sx = x + kx - 1;
                    d[x] = (sx >= 0 && sx < W) ? row[sx] : 0.0f;
                }
            }
        }
    }
}

/* The adjoint of im2col: dinp[ic, y+ky-1, x+kx-1] += dcol[...], in a fixed
 * order. */
static void col2im_add(float *dinp, const float *dcol, int IC, int H, int W,
                       int y0, int y1)
{
    size_t n = (size_t)(y1 - y0) * (size_t)W;
    for (int ic = 0; ic < IC; ic++) {
        float *plane = dinp + (size_t)ic * (size_t)H * (size_t)W;
        for (int k = 0; k < 9; k++) {
            int ky = k / 3, kx = k % 3;
            const float *src = dcol + ((size_t)ic * 9 + (size_t)k) * n;
            for (int y = y0; y < y1; y++) {
                int sy = y + ky - 1;
                if (sy < 0 || sy >= H)
                    continue;
                const float *s = src + (size_t)(y - y0) * (size_t)W;
                float *row = plane + (size_t)sy * (size_t)W;
                for (int x = 0; x < W; x++) {
                    int sx = x + kx - 1;
                    if (sx >= 0 && sx < W)
                        row[sx] += s[x];
                }
            }
        }
    }
}

/* out[OC,H,W] = conv3x3(in[IC,H,W], w[OC,IC,3,3]) + b[OC]
 * scratch: gs_nn_conv3x3_scratch_size(IC, H, W) floats */
int gs_nn_conv3x3_forward(float *out, const float *in, const float *w,
                          const float *b, int IC, int OC, int H, int W,
                          float *scratch, size_t scratch_len)
{
    int K, HW, bandpix;
    int rc = conv_check(IC, OC, H, W, &K, &HW, &bandpix);
    if (rc)
        return rc;
    if (!out || !in || !w || !scratch ||
        scratch_len < (size_t)K * (size_t)bandpix)
        return GS_ERR_ARG;
    for (int oc = 0; oc < OC; oc++) {
        float *o = out + (size_t)oc * (size_t)HW;
        float v = b ? b[oc] : 0.0f;
        for (int p = 0; p < HW; p++)
            o[p] = v;
    }
    int rows = band_rows(H, W);
    for (int y0 = 0; y0 < H; y0 += rows) {
        int y1 = y0 + rows < H ? y0 + rows : H;
        int n = (y1 - y0) * W;
        im2col(scratch, in, IC, H, W, y0, y1);
        cblas_sgemm(CblasRowMajor, CblasNoTrans, CblasNoTrans, OC, n, K, 1.0f,
                    w, K, scratch, n, 1.0f, out + (size_t)y0 * (size_t)W, HW);
    }
    return GS_OK;
}

/* dinp[IC,H,W] += conv^T(dout[OC,H,W]); dw[OC,IC*9] += dout . im2col(in)^T;
 * db[OC] += sum_p dout[oc,p]. scratch as forward. */
int gs_nn_conv3x3_backward(float *dinp, float *dw, float *db,
                           const float *dout, const float *in, const float *w,
                           int IC, int OC, int H, int W, float *scratch,
                           size_t scratch_len)
{
    int K, HW, bandpix;
    int rc = conv_check(IC, OC, H, W, &K, &HW, &bandpix);
    if (rc)
        return rc;
    if (!dout || (dinp && !w) || (dw && !in))
        return GS_ERR_ARG;
    if ((dinp || dw) && (!scratch || scratch_len < (size_t)K * (size_t)bandpix))
        return GS_ERR_ARG;
    int rows = band_rows(H, W);
    for (int y0 = 0; (dinp || dw) && y0 < H; y0 += rows) {
        int y1 = y0 + rows < H ? y0 + rows : H;
        int n = (y1 - y0) * W;
        const float *dband = dout + (size_t)y0 * (size_t)W;
        if (dw) {
            im2col(scratch, in, IC, H, W, y0, y1);
            cblas_sgemm(CblasRowMajor, CblasNoTrans, CblasTrans, OC, K, n, 1.0f,
                        dband, HW, scratch, n, 1.0f, dw, K);
        }
        if (dinp) {
            cblas_sgemm(CblasRowMajor, CblasTrans, CblasNoTrans, K, n, OC, 1.0f,
                        w, K, dband, HW, 0.0f, scratch, n);
            col2im_add(dinp, scratch, IC, H, W, y0, y1);
        }
    }
    for (int oc = 0; db && oc < OC; oc++) {
        const float *d = dout + (size_t)oc * (size_t)HW;
        double s = 0.0;
        for (int p = 0; p < HW; p++)
            s += d[p];
        db[oc] += (float)s;
    }
    return GS_OK;
}
