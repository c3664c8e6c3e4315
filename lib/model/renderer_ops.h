/* The renderer's passes (internal to lib/model/renderer.c), each run on an
 * optional gs_pool.
 *
 * Determinism: work is split by a partition fixed by the sizes alone (bands
 * of pixels, channels), never by the thread count; every task writes only
 * its own outputs, and sums over bands are added in band order. So the
 * bytes do not depend on the pool (NULL runs every task inline), provided
 * OpenBLAS runs one thread (gazesplat/nn.h).
 *
 * Maps are CHW float32 with HW pixels per channel. Backward passes WRITE
 * the gradient of their map input unless a function says it adds (every
 * such buffer in the renderer is fresh, which saves a zeroing pass), and
 * ADD into parameter gradients. */
#ifndef GS_MODEL_RENDERER_OPS_H
#define GS_MODEL_RENDERER_OPS_H

#include <stddef.h>

#include "gazesplat/pool.h"

#define GS_ROP_LRELU_SLOPE 0.2f

/* Where the passes may write besides their outputs. */
typedef struct gs_rop_ctx {
    gs_pool *pool;  /* may be NULL */
    float *part;    /* gs_rop_part_size(C) floats: conv weight-gradient partials */
    float *rows;    /* gs_rop_rows_size(C, widest) floats: blur rows (4 per task) */
    size_t widest;  /* widest map row (W) any blur of the call will see */
    float *r;       /* [HW] of the largest map: guidance backward */
} gs_rop_ctx;

size_t gs_rop_part_size(int C);
size_t gs_rop_rows_size(int C, size_t widest);

/* out[OC,HW] = act(w[OC,IC] in[IC,HW] + b[OC]), act LeakyReLU if lrelu. */
void gs_rop_conv_forward(const gs_rop_ctx *x, float *out, const float *in,
                         const float *w, const float *b, int IC, int OC,
                         int HW, int lrelu);
/* dinp[IC,HW] = w^T dout (or += when add_dinp; skipped when NULL);
 * dw[OC,IC] += dout in^T; db[OC] += sum_p dout (dw and db both NULL:
 * skipped). */
void gs_rop_conv_backward(const gs_rop_ctx *x, float *dinp, int add_dinp,
                          float *dw, float *db, const float *dout,
                          const float *in, const float *w, int IC, int OC,
                          int HW);

/* out[C,H,W] = ([1,2,1] x [1,2,1] / 16) * in, reflect border, H, W >= 2,
 * W <= x->widest; backward: din = blur^T dout. */
void gs_rop_blur_forward(const gs_rop_ctx *x, float *out, const float *in,
                         int C, int H, int W);
void gs_rop_blur_backward(const gs_rop_ctx *x, float *din, const float *dout,
                          int C, int H, int W);

/* shuffle_tile(y, xin)[C,2H,2W][c, 2h+i, 2w+j] = y[4C,H,W][4c+2i+j, h, w]
 *                              + xin[C,H,W][(4c+2i+j) mod C, h, w].
 * Backward: dy = the inverse permutation of dout; dx += (dx may be NULL). */
void gs_rop_shuffle_tile_backward(const gs_rop_ctx *x, float *dy, float *dx,
                                  const float *dout, int C, int H, int W);
/* out[C,2H,2W] = blur(shuffle_tile(y, xin)) as gs_rop_blur_forward would
 * blur it, without the shuffled map in memory (2W <= x->widest). */
void gs_rop_shuffle_tile_blur_forward(const gs_rop_ctx *x, float *out,
                                      const float *y, const float *xin, int C,
                                      int H, int W);

/* d[n] *= lrelu'(in), from the saved OUTPUT y = lrelu(in): with a positive
 * slope, y > 0 exactly when in > 0. */
void gs_rop_lrelu_backward(const gs_rop_ctx *x, float *d, const float *y,
                           size_t n);
void gs_rop_zero(const gs_rop_ctx *x, float *d, size_t n);

/* out[C,2H,2W] = bilinear x2 of in[C,H,W] (gs_nn_upsample2x_forward's
 * values, split by channel and rows). */
void gs_rop_upsample2x_forward(const gs_rop_ctx *x, float *out, const float *in,
                               int C, int H, int W);
/* acc[n] += add; then, when out is not NULL, out = sigmoid(acc)
 * (gs_nn_sigmoid_forward's values) and, when copy is not NULL, copy = out. */
void gs_rop_add_sigmoid(const gs_rop_ctx *x, float *acc, const float *add,
                        float *out, float *copy, size_t n);

/* Guidance of tau [D] (renderer.h, renderer_ops.c for the maths):
 *   vector: s = wk^T tau / temp, att = softmax_p(src_p . s),
 *           a = wv (sum_p att_p src_p) + bv                   [C]
 *   apply:  g_p = u_p + a (additive) or u_p + u_p * a (multiplicative)
 * att [HW] is saved for the backward. */
typedef struct gs_rop_guide {
    const float *wk, *wv, *bv; /* [D,C], [C,C], [C] */
    float *dwk, *dwv, *dbv;    /* gradients (backward), added to; NULL: none */
    int C, D, mult;
    float temp;
} gs_rop_guide;

/* a[C], att[HW] from src [C,HW] and tau; scratch 2C floats. */
void gs_rop_guide_vector(const gs_rop_ctx *x, const gs_rop_guide *gd,
                         float *a, float *att, const float *src,
                         const float *tau, size_t hw, float *scratch);
/* g[C,HW] from u[C,HW] and a[C]. */
void gs_rop_guide_apply(const gs_rop_ctx *x, const gs_rop_guide *gd, float *g,
                        const float *u, const float *a, size_t hw);
/* du[C,HW] (written) and da[C] (written) from dg[C,HW]. */
void gs_rop_guide_apply_backward(const gs_rop_ctx *x, const gs_rop_guide *gd,
                                 float *du, float *da, const float *dg,
                                 const float *u, const float *a, size_t hw);
/* From da[C]: adds into dsrc[C,HW] (NULL: skipped), dtau (may be NULL),
 * dwk, dwv, dbv; needs x->r [HW]; scratch 4C floats. */
void gs_rop_guide_vector_backward(const gs_rop_ctx *x, const gs_rop_guide *gd,
                                  float *dsrc, float *dtau, const float *da,
                                  const float *src, const float *att,
                                  const float *tau, size_t hw, float *scratch);

/* Both halves with src = u: scratch 3C floats. */
void gs_rop_guide_forward(const gs_rop_ctx *x, const gs_rop_guide *gd,
                          float *g, float *att, const float *u,
                          const float *tau, size_t hw, float *scratch);
/* du[C,HW] = the adjoint of dg[C,HW] (written); dwk, dwv, dbv and dtau
 * (may be NULL) added to; scratch 6C floats. */
void gs_rop_guide_backward(const gs_rop_ctx *x, const gs_rop_guide *gd,
                           float *du, float *dtau, const float *dg,
                           const float *u, const float *att, const float *tau,
                           size_t hw, float *scratch);

#endif
