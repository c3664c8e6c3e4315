/* Cross-attention of a code vector over the pixels of a feature map
 * (GazeGaussian renderer), in the folded form described in nn.h:
 *   s = wk^T code / temp                      [C]
 *   att = softmax_p(x_p . s)                  [HW]   (bk . code cancels)
 *   xbar = sum_p att_p x_p                    [C]
 *   out_p = x_p + wv xbar + bv                [C,HW]
 * Backward, with dout [C,HW]:
 *   da = sum_p dout_p; dbv += da; dwv += da xbar^T; dxbar = wv^T da
 *   datt_p = x_p . dxbar; g_p = att_p (datt_p - sum_q att_q datt_q)
 *          (the sum is xbar . dxbar)
 *   dx_p += dout_p + att_p dxbar + g_p s;  ds = sum_p g_p x_p
 *   du = ds / temp (u = wk^T code): dwk += code du^T; dcode += wk du. */
#include "gazesplat/nn.h"
#include "nn_internal.h"

#include <math.h>

enum { BLOCK = 256 }; /* pixels per block of the backward pass */

size_t gs_nn_attention_scratch_size(int C)
{
    int t;
    return nn_mul(C, 5, &t) ? (size_t)t : 0;
}

static int attn_check(int C, int D, int HW, float temp, size_t scratch_len)
{
    int t;
    if (C < 1 || D < 1 || HW < 1 || !(temp > 0.0f) || !isfinite(temp))
        return GS_ERR_ARG;
    if (!nn_mul(C, HW, &t) || !nn_mul(C, C, &t) || !nn_mul(C, D, &t) ||
        !nn_mul(C, 5, &t))
        return GS_ERR_LIMIT;
    return scratch_len < (size_t)t ? GS_ERR_ARG : GS_OK;
}

/* s[C] = wk[D,C]^T code[D] / temp */
static void scaled_query(float *s, const float *wk, const float *code, int C,
                         int D, float temp)
{
    for (int c = 0; c < C; c++)
        s[c] = 0.0f;
    for (int d = 0; d < D; d++) {
        const float *row = wk + (size_t)d * (size_t)C;
        for (int c = 0; c < C; c++)
            s[c] += row[c] * code[d];
    }
    for (int c = 0; c < C; c++)
        s[c] /= temp;
}

/* xbar[C] = sum_p att[p] x[c,p] */
static void pooled(float *xbar, const float *x, const float *att, int C, int HW)
{
    for (int c = 0; c < C; c++) {
        const float *xc = x + (size_t)c * (size_t)HW;
        double acc = 0.0;
        for (int p = 0; p < HW; p++)
            acc += (double)att[p] * xc[p];
        xbar[c] = (float)acc;
    }
}

/* out[C,HW], att[HW] from x[C,HW], code[D], wk[D,C], bk[D] (unused),
 * wv[C,C], bv[C]; scratch 5C floats */
int gs_nn_attention_forward(float *out, float *att, const float *x,
                            const float *code, const float *wk,
                            const float *bk, const float *wv, const float *bv,
                            int C, int D, int HW, float temp, float *scratch,
                            size_t scratch_len)
{
    (void)bk; /* cancels in the softmax, see nn.h */
    int rc = attn_check(C, D, HW, temp, scratch_len);
    if (rc)
        return rc;
    if (!out || !att || !x || !code || !wk || !wv || !scratch)
        return GS_ERR_ARG;
    float *s = scratch, *xbar = s + C, *a = xbar + C;
    scaled_query(s, wk, code, C, D, temp);
    for (int p = 0; p < HW; p++)
        att[p] = 0.0f;
    for (int c = 0; c < C; c++) {
        const float *xc = x + (size_t)c * (size_t)HW;
        for (int p = 0; p < HW; p++)
            att[p] += xc[p] * s[c];
    }
    gs_nn_softmax_forward(att, att, HW);
    pooled(xbar, x, att, C, HW);
    for (int c = 0; c < C; c++) {
        const float *row = wv + (size_t)c * (size_t)C;
        float v = bv ? bv[c] : 0.0f;
        for (int k = 0; k < C; k++)
            v += row[k] * xbar[k];
        a[c] = v;
    }
    for (int c = 0; c < C; c++) {
        const float *xc = x + (size_t)c * (size_t)HW;
        float *oc = out + (size_t)c * (size_t)HW;
        for (int p = 0; p < HW; p++)
            oc[p] = xc[p] + a[c];
    }
    return GS_OK;
}

/* One block of pixels [p0, p0+n): adds to dx and accumulates ds. */
static void backward_block(float *dx, float *ds, const float *dout,
                           const float *x, const float *att, const float *s,
                           const float *dxbar, double S, int C, int HW, int p0,
                           int n)
{
    float g[BLOCK];
    for (int i = 0; i < n; i++)
        g[i] = 0.0f;
    for (int c = 0; c < C; c++) {
        const float *xc = x + (size_t)c * (size_t)HW + p0;
        for (int i = 0; i < n; i++)
            g[i] += xc[i] * dxbar[c];
    }
    for (int i = 0; i < n; i++)
        g[i] = att[p0 + i] * (float)((double)g[i] - S);
    for (int c = 0; c < C; c++) {
        size_t off = (size_t)c * (size_t)HW + (size_t)p0;
        const float *xc = x + off;
        double acc = 0.0;
        for (int i = 0; i < n; i++)
            acc += (double)g[i] * xc[i];
        ds[c] += (float)acc;
        if (!dx)
            continue;
        const float *gc = dout + off;
        float *dxc = dx + off;
        for (int i = 0; i < n; i++)
            dxc[i] += gc[i] + att[p0 + i] * dxbar[c] + g[i] * s[c];
    }
}

/* Gradients for x[C,HW], code[D], wk[D,C], bk[D] (zero), wv[C,C], bv[C]
 * from dout[C,HW]; att[HW] saved by forward; scratch 5C floats */
int gs_nn_attention_backward(float *dx, float *dcode, float *dwk, float *dbk,
                             float *dwv, float *dbv, const float *dout,
                             const float *x, const float *att,
                             const float *code, const float *wk,
                             const float *wv, int C, int D, int HW, float temp,
                             float *scratch, size_t scratch_len)
{
    (void)dbk; /* d(loss)/d(bk) is exactly zero: nothing to add */
    int rc = attn_check(C, D, HW, temp, scratch_len);
    if (rc)
        return rc;
    if (!dout || !x || !att || !code || !wk || !wv || !scratch)
        return GS_ERR_ARG;
    float *s = scratch, *xbar = s + C, *da = xbar + C, *dxbar = da + C,
          *ds = dxbar + C;
    scaled_query(s, wk, code, C, D, temp);
    pooled(xbar, x, att, C, HW);
    for (int c = 0; c < C; c++) {
        const float *gc = dout + (size_t)c * (size_t)HW;
        double acc = 0.0;
        for (int p = 0; p < HW; p++)
            acc += gc[p];
        da[c] = (float)acc;
        if (dbv)
            dbv[c] += da[c];
    }
    for (int c = 0; dwv && c < C; c++)
        for (int k = 0; k < C; k++)
            dwv[(size_t)c * (size_t)C + (size_t)k] += da[c] * xbar[k];
    double S = 0.0;
    for (int k = 0; k < C; k++) {
        float v = 0.0f;
        for (int c = 0; c < C; c++)
            v += wv[(size_t)c * (size_t)C + (size_t)k] * da[c];
        dxbar[k] = v;
        S += (double)xbar[k] * v;
        ds[k] = 0.0f;
    }
    for (int p0 = 0; p0 < HW; p0 += BLOCK) {
        int n = HW - p0 < BLOCK ? HW - p0 : BLOCK;
        backward_block(dx, ds, dout, x, att, s, dxbar, S, C, HW, p0, n);
    }
    /* ds -> du = ds / temp, then through u = wk^T code */
    for (int d = 0; d < D; d++) {
        const float *row = wk + (size_t)d * (size_t)C;
        float *drow = dwk ? dwk + (size_t)d * (size_t)C : NULL;
        float acc = 0.0f;
        for (int c = 0; c < C; c++) {
            float du = ds[c] / temp;
            if (drow)
                drow[c] += code[d] * du;
            acc += row[c] * du;
        }
        if (dcode)
            dcode[d] += acc;
    }
    return GS_OK;
}
