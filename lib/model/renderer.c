/* Expression-guided neural renderer: see renderer.h and docs/model.md.
 *
 * Forward, for x [C,H,W] and tau [D] (C2 = 2C, C4 = 4C):
 *   rgb = blur(up2x(conv_rgb0(x)))                          [3, 2H, 2W]
 *   for b in 0, 1 (block input xin [C,Hi,Wi], output [C,2Hi,2Wi]):
 *     ya = lrelu(conv_a(xin))                               [C2, Hi, Wi]
 *     yb = lrelu(conv_b(ya))                                [C4, Hi, Wi]
 *     z  = blur(shuffle(yb) + tile(xin))                    [C, 2Hi, 2Wi]
 *     u  = lrelu(conv_c(z));  g = guide(u, tau)             [C, 2Hi, 2Wi]
 *     rgb += conv_rgb_b(g);  if b == 0: rgb = blur(up2x(rgb))
 *   out = sigmoid(rgb)                                      [3, 4H, 4W]
 * lrelu has slope 0.2. Its backward reads the saved OUTPUT: with a positive
 * slope, out > 0 exactly when in > 0, so the gradient is the same.
 * tile(xin): shuffled channel c at (2h+i, 2w+j) adds xin channel
 * (4c+2i+j) mod C, i.e. xin.repeat(1,4,1,1) before the shuffle. */
#include "renderer.h"

#include <limits.h>
#include <math.h>
#include <stdio.h>
#include <string.h>

#include <cblas.h>

#include "gazesplat/nn.h"

#define LRELU_SLOPE 0.2f

/* ---- Configuration ------------------------------------------------------ */

int gs_renderer_config_validate(const gs_renderer_config *cfg, gs_error *err)
{
    if (!cfg)
        return gs_error_set(err, GS_ERR_ARG, "renderer: no config");
    if (cfg->channels < 1 || cfg->channels > GS_RENDERER_MAX_CHANNELS)
        return gs_error_set(err, GS_ERR_ARG, "renderer: channels %d not in 1..%d",
                            cfg->channels, GS_RENDERER_MAX_CHANNELS);
    if (cfg->code_dim < 1 || cfg->code_dim > GS_RENDERER_MAX_CODE)
        return gs_error_set(err, GS_ERR_ARG, "renderer: code_dim %d not in 1..%d",
                            cfg->code_dim, GS_RENDERER_MAX_CODE);
    if (cfg->guidance != GS_GUIDE_NONE && cfg->guidance != GS_GUIDE_ADDITIVE &&
        cfg->guidance != GS_GUIDE_MULTIPLICATIVE)
        return gs_error_set(err, GS_ERR_ARG, "renderer: unknown guidance %d",
                            cfg->guidance);
    if (cfg->blocks != GS_RENDERER_BLOCKS)
        return gs_error_set(err, GS_ERR_ARG, "renderer: blocks %d, only %d supported",
                            cfg->blocks, GS_RENDERER_BLOCKS);
    return GS_OK;
}

/* ---- Parameter layout ----------------------------------------------------
 * One walk over the tensors, in file order, serves the count, the table and
 * the binding, so the three can never disagree. */

typedef struct {
    size_t offset;           /* floats so far */
    int count;               /* tensors so far */
    gs_renderer_tensor *tab; /* may be NULL */
    int cap;
    float *base;             /* may be NULL */
} layout_walk;

static void walk_add(layout_walk *lw, const char *name, int out, int in,
                     float **slot)
{
    size_t n = (size_t)out * (size_t)(in > 0 ? in : 1);
    if (lw->tab && lw->count < lw->cap) {
        gs_renderer_tensor *t = &lw->tab[lw->count];
        snprintf(t->name, sizeof t->name, "%s", name);
        t->rank = in > 0 ? 2 : 1;
        t->shape[0] = out;
        t->shape[1] = in > 0 ? in : 1;
        t->offset = lw->offset;
        t->count = n;
    }
    if (slot)
        *slot = lw->base ? lw->base + lw->offset : NULL;
    lw->offset += n;
    lw->count++;
}

/* Weight [out, in] and bias [out] of the 1x1 convolution prefix.*. */
static void walk_conv(layout_walk *lw, const char *prefix, int out, int in,
                      gs_renderer_conv *conv)
{
    char name[GS_RENDERER_NAME_MAX];
    snprintf(name, sizeof name, "%s.weight", prefix);
    walk_add(lw, name, out, in, conv ? &conv->w : NULL);
    snprintf(name, sizeof name, "%s.bias", prefix);
    walk_add(lw, name, out, 0, conv ? &conv->b : NULL);
}

static void walk_all(layout_walk *lw, const gs_renderer_config *cfg,
                     gs_renderer_params *p)
{
    int C = cfg->channels, D = cfg->code_dim;
    walk_conv(lw, "renderer.conv_rgb", 3, C, p ? &p->rgb0 : NULL);
    for (int b = 0; b < GS_RENDERER_BLOCKS; b++) {
        static const char *const conv[4] = {"conv_a", "conv_b", "conv_c",
                                            "conv_rgb"};
        const int out[4] = {2 * C, 4 * C, C, 3}, in[4] = {C, 2 * C, C, C};
        gs_renderer_conv *slot[4] = {NULL, NULL, NULL, NULL};
        if (p) {
            slot[0] = &p->block[b].a, slot[1] = &p->block[b].b;
            slot[2] = &p->block[b].c, slot[3] = &p->block[b].rgb;
        }
        for (int k = 0; k < 4; k++) {
            char prefix[GS_RENDERER_NAME_MAX];
            snprintf(prefix, sizeof prefix, "renderer.block%d.%s", b, conv[k]);
            walk_conv(lw, prefix, out[k], in[k], slot[k]);
        }
    }
    if (p)
        p->key_w = p->value_w = p->value_b = NULL;
    if (cfg->guidance == GS_GUIDE_NONE)
        return;
    walk_add(lw, "renderer.guide.key.weight", D, C, p ? &p->key_w : NULL);
    walk_add(lw, "renderer.guide.value.weight", C, C, p ? &p->value_w : NULL);
    walk_add(lw, "renderer.guide.value.bias", C, 0, p ? &p->value_b : NULL);
}

size_t gs_renderer_param_count(const gs_renderer_config *cfg)
{
    if (gs_renderer_config_validate(cfg, NULL) != GS_OK)
        return 0;
    layout_walk lw = {0, 0, NULL, 0, NULL};
    walk_all(&lw, cfg, NULL);
    return lw.offset;
}

int gs_renderer_layout(const gs_renderer_config *cfg,
                       gs_renderer_tensor *table, int cap, int *count)
{
    int rc = gs_renderer_config_validate(cfg, NULL);
    if (rc)
        return rc;
    if (!table || !count || cap < 1)
        return GS_ERR_ARG;
    layout_walk lw = {0, 0, table, cap, NULL};
    walk_all(&lw, cfg, NULL);
    if (lw.count > cap)
        return GS_ERR_ARG;
    *count = lw.count;
    return GS_OK;
}

int gs_renderer_bind(const gs_renderer_config *cfg, float *base, size_t n,
                     gs_renderer_params *p)
{
    size_t need = gs_renderer_param_count(cfg);
    if (need == 0 || !base || !p || n < need)
        return GS_ERR_ARG;
    layout_walk lw = {0, 0, NULL, 0, base};
    walk_all(&lw, cfg, p);
    return GS_OK;
}

/* splitmix64, uniform in [-bound, bound) with 24 random bits. */
static float init_uniform(uint64_t *state, float bound)
{
    uint64_t z = (*state += 0x9E3779B97F4A7C15ull);
    z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
    z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
    z ^= z >> 31;
    float u = (float)(z >> 40) * (1.0f / 16777216.0f);
    return bound * (2.0f * u - 1.0f);
}

/* Every tensor gets PyTorch's default Conv2d bound 1/sqrt(fan_in) for its
 * weight and bias, except the guidance value projection (wv, bv), which
 * starts at zero: then a = 0 and g = u in both guidance modes, so a freshly
 * initialised renderer equals the plain one and the guidance grows from
 * the identity as training moves wv and bv. (The key gradient is zero until
 * wv is non-zero; the key is still drawn at random so the attention is not
 * uniform once it starts.) */
int gs_renderer_init(const gs_renderer_config *cfg, float *base, size_t n,
                     uint64_t seed)
{
    gs_renderer_tensor tab[GS_RENDERER_MAX_TENSORS];
    int count = 0, rc = gs_renderer_layout(cfg, tab, GS_RENDERER_MAX_TENSORS, &count);
    if (rc)
        return rc;
    if (!base || n < gs_renderer_param_count(cfg))
        return GS_ERR_ARG;
    uint64_t state = seed;
    int fan_in = 1;
    for (int i = 0; i < count; i++) {
        const gs_renderer_tensor *t = &tab[i];
        float *dst = base + t->offset;
        if (t->rank == 2)
            fan_in = t->shape[1]; /* the bias that follows shares it */
        if (strncmp(t->name, "renderer.guide.value.", 21) == 0) {
            memset(dst, 0, t->count * sizeof *dst);
            continue;
        }
        float bound = 1.0f / sqrtf((float)fan_in);
        for (size_t k = 0; k < t->count; k++)
            dst[k] = init_uniform(&state, bound);
    }
    return GS_OK;
}

/* ---- Activation buffer ---------------------------------------------------
 * Saved part (read by backward), then scratch (forward temporaries and the
 * backward's gradients). HW0 = H W, HW1 = 4 HW0, HW2 = 16 HW0. */

typedef struct {
    float *ya;  /* [2C, HWi]  lrelu(conv_a(xin)) */
    float *yb;  /* [4C, HWi]  lrelu(conv_b(ya)) */
    float *z;   /* [C, HWo]   blur(shuffle(yb) + tile(xin)) */
    float *u;   /* [C, HWo]   lrelu(conv_c(z)) */
    float *g;   /* [C, HWo]   guide(u); == u without guidance */
    float *att; /* [HWo]      attention weights; NULL without guidance */
} block_acts;

typedef struct {
    int C, D, H, W;
    size_t hw0, hw1, hw2;
    block_acts blk[GS_RENDERER_BLOCKS];
    float *out;          /* [3, HW2] saved sigmoid output */
    float *bufP, *bufQ;  /* [C, HW2] scratch */
    float *bufX;         /* [C, HW1] scratch */
    float *rgb2a, *rgb2b; /* [3, HW2] scratch */
    float *rgb1a, *rgb1b; /* [3, HW1] scratch */
    float *rgb0;         /* [3, HW0] scratch */
    float *gscr;         /* [GUIDE_SCRATCH C] scratch */
    float *rows;         /* [2 * 4W] scratch rows of the blurs */
    size_t total;        /* floats */
} act_layout;

enum { GUIDE_SCRATCH = 8 }; /* floats per channel for the guidance kernels */

static float *carve(act_layout *L, float *base, size_t n)
{
    float *p = base ? base + L->total : NULL;
    L->total += n;
    return p;
}

/* Sizes of an H x W call: GS_ERR_ARG below 1, GS_ERR_LIMIT when a map of
 * the image would not fit the int dimensions of BLAS. */
static int check_sizes(int C, int H, int W)
{
    if (H < 1 || W < 1)
        return GS_ERR_ARG;
    if (H > GS_RENDERER_MAX_SIDE || W > GS_RENDERER_MAX_SIDE)
        return GS_ERR_LIMIT;
    size_t big = (size_t)C * 16u * (size_t)H * (size_t)W;
    return big > (size_t)INT_MAX ? GS_ERR_LIMIT : GS_OK;
}

static void layout_make(act_layout *L, const gs_renderer_config *cfg, int H,
                        int W, float *base)
{
    int C = cfg->channels, guided = cfg->guidance != GS_GUIDE_NONE;
    memset(L, 0, sizeof *L);
    L->C = C, L->D = cfg->code_dim, L->H = H, L->W = W;
    L->hw0 = (size_t)H * (size_t)W, L->hw1 = 4 * L->hw0, L->hw2 = 16 * L->hw0;
    size_t Cs = (size_t)C;
    for (int b = 0; b < GS_RENDERER_BLOCKS; b++) {
        size_t hwi = b == 0 ? L->hw0 : L->hw1, hwo = 4 * hwi;
        block_acts *a = &L->blk[b];
        a->ya = carve(L, base, 2 * Cs * hwi);
        a->yb = carve(L, base, 4 * Cs * hwi);
        a->z = carve(L, base, Cs * hwo);
        a->u = carve(L, base, Cs * hwo);
        a->g = guided ? carve(L, base, Cs * hwo) : a->u;
        a->att = guided ? carve(L, base, hwo) : NULL;
    }
    L->out = carve(L, base, 3 * L->hw2);
    L->bufP = carve(L, base, Cs * L->hw2);
    L->bufQ = carve(L, base, Cs * L->hw2);
    L->bufX = carve(L, base, Cs * L->hw1);
    L->rgb2a = carve(L, base, 3 * L->hw2);
    L->rgb2b = carve(L, base, 3 * L->hw2);
    L->rgb1a = carve(L, base, 3 * L->hw1);
    L->rgb1b = carve(L, base, 3 * L->hw1);
    L->rgb0 = carve(L, base, 3 * L->hw0);
    L->gscr = carve(L, base, GUIDE_SCRATCH * Cs);
    L->rows = carve(L, base, 8 * (size_t)W);
}

size_t gs_renderer_act_size(const gs_renderer_config *cfg, int H, int W)
{
    if (gs_renderer_config_validate(cfg, NULL) != GS_OK ||
        check_sizes(cfg->channels, H, W) != GS_OK)
        return 0;
    act_layout L;
    layout_make(&L, cfg, H, W, NULL);
    return L.total;
}

/* Every pointer the config uses is set. */
static int params_ok(const gs_renderer_config *cfg, const gs_renderer_params *p)
{
    if (!p || !p->rgb0.w || !p->rgb0.b)
        return 0;
    for (int b = 0; b < GS_RENDERER_BLOCKS; b++) {
        const gs_renderer_conv *c[4] = {&p->block[b].a, &p->block[b].b,
                                        &p->block[b].c, &p->block[b].rgb};
        for (int k = 0; k < 4; k++)
            if (!c[k]->w || !c[k]->b)
                return 0;
    }
    return cfg->guidance == GS_GUIDE_NONE ||
           (p->key_w && p->value_w && p->value_b);
}

/* Shared checks of forward and backward; fills *L on success. */
static int check_call(const gs_renderer_config *cfg, const gs_renderer_params *p,
                      const float *x, const float *tau, int H, int W,
                      float *acts, size_t acts_len, act_layout *L)
{
    int rc = gs_renderer_config_validate(cfg, NULL);
    if (rc)
        return rc;
    rc = check_sizes(cfg->channels, H, W);
    if (rc)
        return rc;
    if (!x || !acts || !params_ok(cfg, p) ||
        (cfg->guidance != GS_GUIDE_NONE && !tau))
        return GS_ERR_ARG;
    layout_make(L, cfg, H, W, NULL);
    if (acts_len < L->total)
        return GS_ERR_ARG;
    layout_make(L, cfg, H, W, acts);
    return GS_OK;
}

/* ---- Small kernels ------------------------------------------------------- */

static void zero(float *x, size_t n)
{
    memset(x, 0, n * sizeof *x);
}

static void add_into(float *dst, const float *src, size_t n)
{
    for (size_t i = 0; i < n; i++)
        dst[i] += src[i];
}

/* y[n] = lrelu(y) in place, as gs_nn_leaky_relu_forward; written as a
 * select of the factor so that it vectorises (random signs make a branch
 * mispredict half the time). */
static void lrelu_forward_inplace(float *y, size_t n)
{
    for (size_t i = 0; i < n; i++)
        y[i] *= y[i] > 0.0f ? 1.0f : LRELU_SLOPE;
}

/* d[n] *= lrelu'(in), from the saved output y = lrelu(in) (see top). */
static void lrelu_backward_inplace(float *d, const float *y, size_t n)
{
    for (size_t i = 0; i < n; i++)
        d[i] *= y[i] > 0.0f ? 1.0f : LRELU_SLOPE;
}

/* out[C,2H,2W]: out[c, 2h+i, 2w+j] = y[4c+2i+j, h, w] + x[(4c+2i+j) % C, h, w]
 * for y [4C,H,W], x [C,H,W]. */
static void shuffle_tile_forward(float *out, const float *y, const float *x,
                                 int C, int H, int W)
{
    size_t hw = (size_t)H * (size_t)W, W2 = 2 * (size_t)W;
    for (int c = 0; c < C; c++)
        for (int k = 0; k < 4; k++) {
            const float *src = y + (size_t)(4 * c + k) * hw;
            const float *skip = x + (size_t)((4 * c + k) % C) * hw;
            float *dst = out + (size_t)c * 4 * hw + (size_t)(k >> 1) * W2 + (size_t)(k & 1);
            for (int h = 0; h < H; h++) {
                const float *s = src + (size_t)h * (size_t)W;
                const float *t = skip + (size_t)h * (size_t)W;
                float *d = dst + (size_t)h * 2 * W2;
                for (int w = 0; w < W; w++)
                    d[2 * (size_t)w] = s[w] + t[w];
            }
        }
}

/* The adjoint: dy[4C,H,W] = (written) and dx[C,H,W] += (dx may be NULL)
 * from dout[C,2H,2W]. */
static void shuffle_tile_backward(float *dy, float *dx, const float *dout,
                                  int C, int H, int W)
{
    size_t hw = (size_t)H * (size_t)W, W2 = 2 * (size_t)W;
    for (int c = 0; c < C; c++)
        for (int k = 0; k < 4; k++) {
            float *ddst = dy + (size_t)(4 * c + k) * hw;
            float *dskip = dx ? dx + (size_t)((4 * c + k) % C) * hw : NULL;
            const float *src = dout + (size_t)c * 4 * hw + (size_t)(k >> 1) * W2 + (size_t)(k & 1);
            for (int h = 0; h < H; h++) {
                const float *g = src + (size_t)h * 2 * W2;
                float *a = ddst + (size_t)h * (size_t)W;
                for (int w = 0; w < W; w++)
                    a[w] = g[2 * (size_t)w];
                if (!dskip)
                    continue;
                float *s = dskip + (size_t)h * (size_t)W;
                for (int w = 0; w < W; w++)
                    s[w] += g[2 * (size_t)w];
            }
        }
}

/* ---- Blur and 1x1 convolution backward, renderer-shaped ------------------
 * The same maths as gs_nn_blur_* and gs_nn_conv1x1_backward, arranged for
 * this network: the blur is separable and runs row by row with the
 * reflected border handled outside the inner loops (which vectorise), and
 * the backward passes WRITE their input gradient (every such buffer here is
 * fresh), which saves a zeroing pass over each. Rounding differs from the
 * gs_nn kernels in the last bits; the PyTorch test covers both. */

/* Reflect index i in [-1, n] into [0, n) (PyTorch 'reflect', n >= 2). */
static int reflect(int i, int n)
{
    return i < 0 ? -i : (i >= n ? 2 * n - 2 - i : i);
}

/* o[W] = [1,2,1] * v[W] with reflected ends, times scale (W >= 2). */
static void row_blur(float *o, const float *v, int W, float scale)
{
    o[0] = (2.0f * v[1] + 2.0f * v[0]) * scale;
    for (int x = 1; x < W - 1; x++)
        o[x] = (v[x - 1] + 2.0f * v[x] + v[x + 1]) * scale;
    o[W - 1] = (2.0f * v[W - 2] + 2.0f * v[W - 1]) * scale;
}

/* The adjoint of row_blur without the scale: e[W] from g[W] (W >= 2). The
 * reflected taps y[0] <- x[1] and y[W-1] <- x[W-2] send g[0] to e[1] and
 * g[W-1] to e[W-2]. */
static void row_blur_adjoint(float *e, const float *g, int W)
{
    e[0] = 2.0f * g[0] + g[1];
    for (int x = 1; x < W - 1; x++)
        e[x] = g[x - 1] + 2.0f * g[x] + g[x + 1];
    e[W - 1] = g[W - 2] + 2.0f * g[W - 1];
    e[1] += g[0];
    e[W - 2] += g[W - 1];
}

/* out[C,H,W] = ([1,2,1] x [1,2,1] / 16) * in, reflect border (H, W >= 2);
 * row scratch v[W]. */
static void blur_forward(float *out, const float *in, int C, int H, int W,
                         float *v)
{
    size_t hw = (size_t)H * (size_t)W;
    for (int c = 0; c < C; c++)
        for (int y = 0; y < H; y++) {
            const float *src = in + (size_t)c * hw;
            const float *a = src + (size_t)reflect(y - 1, H) * (size_t)W;
            const float *b = src + (size_t)y * (size_t)W;
            const float *d = src + (size_t)reflect(y + 1, H) * (size_t)W;
            for (int x = 0; x < W; x++)
                v[x] = a[x] + 2.0f * b[x] + d[x];
            row_blur(out + (size_t)c * hw + (size_t)y * (size_t)W, v, W,
                     1.0f / 16.0f);
        }
}

/* din[C,H,W] = blur^T dout (written, not added); row scratch 2W floats. */
static void blur_backward(float *din, const float *dout, int C, int H, int W,
                          float *scratch)
{
    size_t hw = (size_t)H * (size_t)W, Ws = (size_t)W;
    float *prev = scratch, *cur = scratch + W;
    for (int c = 0; c < C; c++) {
        float *d = din + (size_t)c * hw;
        memset(prev, 0, Ws * sizeof *prev); /* row -1: weight 0, but finite */
        for (int y = 0; y < H; y++) /* rows: e = row adjoint of dout */
            row_blur_adjoint(d + (size_t)y * Ws, dout + (size_t)c * hw + (size_t)y * Ws, W);
        /* columns, in place: row k gets e[k-1] + 2 e[k] + e[k+1] (zero
         * outside), plus the reflected taps e[0] -> row 1, e[H-1] -> row
         * H-2; prev keeps the original e[k-1] */
        for (int k = 0; k < H; k++) {
            float *row = d + (size_t)k * Ws;
            const float *next = k + 1 < H ? row + Ws : row; /* unused at H-1 */
            float wu = (k > 0 ? 1.0f : 0.0f) + (k == 1 ? 1.0f : 0.0f);
            float wd = (k + 1 < H ? 1.0f : 0.0f) + (k == H - 2 ? 1.0f : 0.0f);
            memcpy(cur, row, Ws * sizeof *cur);
            for (int x = 0; x < W; x++)
                row[x] = (wu * prev[x] + 2.0f * cur[x] + wd * next[x]) *
                         (1.0f / 16.0f);
            float *t = prev;
            prev = cur, cur = t;
        }
    }
}

/* dinp[IC,HW] = w^T dout (written; skipped when NULL); dw[OC,IC] += dout
 * in^T; db[OC] += row sums of dout (double accumulators). */
static void conv_backward(float *dinp, float *dw, float *db, const float *dout,
                          const float *in, const float *w, int IC, int OC,
                          int HW)
{
    if (dinp)
        cblas_sgemm(CblasRowMajor, CblasTrans, CblasNoTrans, IC, HW, OC, 1.0f,
                    w, IC, dout, HW, 0.0f, dinp, HW);
    cblas_sgemm(CblasRowMajor, CblasNoTrans, CblasTrans, OC, IC, HW, 1.0f, dout,
                HW, in, HW, 1.0f, dw, IC);
    for (int o = 0; o < OC; o++) {
        const float *row = dout + (size_t)o * (size_t)HW;
        double acc = 0.0;
        for (int p = 0; p < HW; p++)
            acc += row[p];
        db[o] += (float)acc;
    }
}

/* ---- Multiplicative guidance ---------------------------------------------
 * g_p = u_p + u_p * a, a = wv xbar + bv, xbar = sum_p att_p u_p,
 * att = softmax_p(u_p . s), s = wk^T tau / temp. Backward with dg [C,HW]:
 *   da_c = sum_p dg_cp u_cp; dbv += da; dwv += da xbar^T; dxbar = wv^T da
 *   du_p += dg_p * (1 + a) + att_p dxbar + r_p s,
 *     r_p = att_p (u_p . dxbar - xbar . dxbar)      (softmax backward)
 *   ds = sum_p r_p u_p; dwk += tau ds^T / temp; dtau += wk ds / temp.
 * The additive mode is gs_nn_attention (same maths with da_c = sum_p dg_cp
 * and du_p += dg_p + ...). */

/* s[C] = wk[D,C]^T tau[D] / temp */
static void guide_query(float *s, const float *wk, const float *tau, int C,
                        int D, float temp)
{
    for (int c = 0; c < C; c++)
        s[c] = 0.0f;
    for (int d = 0; d < D; d++) {
        const float *row = wk + (size_t)d * (size_t)C;
        for (int c = 0; c < C; c++)
            s[c] += row[c] * tau[d];
    }
    for (int c = 0; c < C; c++)
        s[c] /= temp;
}

/* xbar[C] = sum_p att_p u[c,p] (double accumulators) */
static void guide_pool(float *xbar, const float *u, const float *att, int C,
                       size_t hw)
{
    for (int c = 0; c < C; c++) {
        const float *uc = u + (size_t)c * hw;
        double acc = 0.0;
        for (size_t p = 0; p < hw; p++)
            acc += (double)att[p] * uc[p];
        xbar[c] = (float)acc;
    }
}

/* a[C] = wv[C,C] xbar + bv */
static void guide_value(float *a, const float *wv, const float *bv,
                        const float *xbar, int C)
{
    for (int c = 0; c < C; c++) {
        const float *row = wv + (size_t)c * (size_t)C;
        float v = bv[c];
        for (int k = 0; k < C; k++)
            v += row[k] * xbar[k];
        a[c] = v;
    }
}

/* att[HW] = softmax_p(u_p . s) and a[C]; scratch sq, xbar [C] each */
static void guide_attend(float *att, float *a, float *sq, float *xbar,
                         const float *u, const float *tau,
                         const gs_renderer_params *p, int C, int D, size_t hw,
                         float temp)
{
    guide_query(sq, p->key_w, tau, C, D, temp);
    zero(att, hw);
    for (int c = 0; c < C; c++) {
        const float *uc = u + (size_t)c * hw;
        for (size_t q = 0; q < hw; q++)
            att[q] += uc[q] * sq[c];
    }
    gs_nn_softmax_forward(att, att, (int)hw);
    guide_pool(xbar, u, att, C, hw);
    guide_value(a, p->value_w, p->value_b, xbar, C);
}

/* g[C,HW], att[HW] from u[C,HW]; scratch 3C floats */
static void guide_mul_forward(float *g, float *att, const float *u,
                              const float *tau, const gs_renderer_params *p,
                              int C, int D, size_t hw, float temp,
                              float *scratch)
{
    float *sq = scratch, *xbar = sq + C, *a = xbar + C;
    guide_attend(att, a, sq, xbar, u, tau, p, C, D, hw, temp);
    for (int c = 0; c < C; c++) {
        const float *uc = u + (size_t)c * hw;
        float *gc = g + (size_t)c * hw;
        for (size_t q = 0; q < hw; q++)
            gc[q] = uc[q] + uc[q] * a[c];
    }
}

/* du[C,HW] += ..., guidance gradients into dp, dtau (may be NULL) from
 * dg[C,HW]; u, att saved by forward; scratch 6C floats */
static void guide_mul_backward(float *du, float *dtau,
                               const gs_renderer_params *dp, const float *dg,
                               const float *u, const float *att,
                               const float *tau, const gs_renderer_params *p,
                               int C, int D, size_t hw, float temp,
                               float *scratch)
{
    float *sq = scratch, *xbar = sq + C, *a = xbar + C, *da = a + C,
          *dxbar = da + C, *ds = dxbar + C;
    guide_query(sq, p->key_w, tau, C, D, temp);
    guide_pool(xbar, u, att, C, hw);
    guide_value(a, p->value_w, p->value_b, xbar, C);
    for (int c = 0; c < C; c++) {
        const float *uc = u + (size_t)c * hw, *gc = dg + (size_t)c * hw;
        double acc = 0.0;
        for (size_t q = 0; q < hw; q++)
            acc += (double)gc[q] * uc[q];
        da[c] = (float)acc;
        dp->value_b[c] += da[c];
        for (int k = 0; k < C; k++)
            dp->value_w[(size_t)c * (size_t)C + (size_t)k] += da[c] * xbar[k];
    }
    double S = 0.0;
    for (int k = 0; k < C; k++) {
        float v = 0.0f;
        for (int c = 0; c < C; c++)
            v += p->value_w[(size_t)c * (size_t)C + (size_t)k] * da[c];
        dxbar[k] = v;
        S += (double)xbar[k] * v;
    }
    /* r_p per block of pixels: one sweep over the channels for the dot
     * product u_p . dxbar, a second for the updates and ds. */
    for (int c = 0; c < C; c++)
        ds[c] = 0.0f;
    enum { BLOCK = 256 };
    float r[BLOCK];
    for (size_t p0 = 0; p0 < hw; p0 += BLOCK) {
        size_t n = hw - p0 < BLOCK ? hw - p0 : BLOCK;
        for (size_t i = 0; i < n; i++)
            r[i] = 0.0f;
        for (int c = 0; c < C; c++) {
            const float *uc = u + (size_t)c * hw + p0;
            for (size_t i = 0; i < n; i++)
                r[i] += uc[i] * dxbar[c];
        }
        for (size_t i = 0; i < n; i++)
            r[i] = att[p0 + i] * (float)((double)r[i] - S);
        for (int c = 0; c < C; c++) {
            size_t off = (size_t)c * hw + p0;
            const float *uc = u + off, *gc = dg + off;
            float *duc = du + off, gain = 1.0f + a[c];
            double acc = 0.0;
            for (size_t i = 0; i < n; i++) {
                acc += (double)r[i] * uc[i];
                duc[i] += gc[i] * gain + att[p0 + i] * dxbar[c] + r[i] * sq[c];
            }
            ds[c] += (float)acc;
        }
    }
    for (int d = 0; d < D; d++) {
        const float *row = p->key_w + (size_t)d * (size_t)C;
        float *drow = dp->key_w + (size_t)d * (size_t)C, acc = 0.0f;
        for (int c = 0; c < C; c++) {
            float dq = ds[c] / temp;
            drow[c] += tau[d] * dq;
            acc += row[c] * dq;
        }
        if (dtau)
            dtau[d] += acc;
    }
}

static float guide_temp(int D)
{
    return sqrtf((float)D);
}

/* g = guide(u); writes att. Nothing for GS_GUIDE_NONE (g aliases u). */
static int guide_forward(const gs_renderer_config *cfg, const act_layout *L,
                         const block_acts *a, const gs_renderer_params *p,
                         const float *tau, size_t hw)
{
    int C = L->C, D = L->D;
    float temp = guide_temp(D);
    if (cfg->guidance == GS_GUIDE_ADDITIVE)
        return gs_nn_attention_forward(a->g, a->att, a->u, tau, p->key_w, NULL,
                                       p->value_w, p->value_b, C, D, (int)hw,
                                       temp, L->gscr,
                                       GUIDE_SCRATCH * (size_t)C);
    if (cfg->guidance == GS_GUIDE_MULTIPLICATIVE)
        guide_mul_forward(a->g, a->att, a->u, tau, p, C, D, hw, temp, L->gscr);
    return GS_OK;
}

/* du[C,HW] += the guidance's adjoint of dg; parameter and tau gradients. */
static int guide_backward(const gs_renderer_config *cfg, const act_layout *L,
                          const block_acts *a, const gs_renderer_params *p,
                          const gs_renderer_params *dp, const float *tau,
                          float *dtau, const float *dg, float *du, size_t hw)
{
    int C = L->C, D = L->D;
    float temp = guide_temp(D);
    if (cfg->guidance == GS_GUIDE_ADDITIVE)
        return gs_nn_attention_backward(du, dtau, dp->key_w, NULL, dp->value_w,
                                        dp->value_b, dg, a->u, a->att, tau,
                                        p->key_w, p->value_w, C, D, (int)hw,
                                        temp, L->gscr,
                                        GUIDE_SCRATCH * (size_t)C);
    guide_mul_backward(du, dtau, dp, dg, a->u, a->att, tau, p, C, D, hw, temp,
                       L->gscr);
    return GS_OK;
}

/* ---- Blocks -------------------------------------------------------------- */

/* Block b: xin [C,Hi,Wi] -> a->g [C,2Hi,2Wi]; bufP is the temporary. */
static int block_forward(const gs_renderer_config *cfg, const act_layout *L,
                         int b, const gs_renderer_params *p, const float *xin,
                         const float *tau, int Hi, int Wi)
{
    const block_acts *a = &L->blk[b];
    int C = L->C, hwi = Hi * Wi, hwo = 4 * hwi;
    size_t ni = (size_t)hwi, no = (size_t)hwo, Cs = (size_t)C;
    int rc = gs_nn_conv1x1_forward(a->ya, xin, p->block[b].a.w, p->block[b].a.b,
                                   C, 2 * C, hwi);
    if (!rc)
        lrelu_forward_inplace(a->ya, 2 * Cs * ni);
    rc = rc ? rc : gs_nn_conv1x1_forward(a->yb, a->ya, p->block[b].b.w,
                                         p->block[b].b.b, 2 * C, 4 * C, hwi);
    if (rc)
        return rc;
    lrelu_forward_inplace(a->yb, 4 * Cs * ni);
    shuffle_tile_forward(L->bufP, a->yb, xin, C, Hi, Wi);
    blur_forward(a->z, L->bufP, C, 2 * Hi, 2 * Wi, L->rows);
    rc = gs_nn_conv1x1_forward(a->u, a->z, p->block[b].c.w,
                                         p->block[b].c.b, C, C, hwo);
    if (rc)
        return rc;
    lrelu_forward_inplace(a->u, Cs * no);
    return guide_forward(cfg, L, a, p, tau, no);
}

/* Block b backward. dg [C,HWo] (consumed) and work [>= C HWo] are two
 * ping-pong buffers; adds into dxin [C,HWi] (may be NULL), dp, dtau. */
static int block_backward(const gs_renderer_config *cfg, const act_layout *L,
                          int b, const gs_renderer_params *p,
                          const gs_renderer_params *dp, const float *xin,
                          const float *tau, int Hi, int Wi, float *dg,
                          float *work, float *dxin, float *dtau)
{
    const block_acts *a = &L->blk[b];
    int C = L->C, hwi = Hi * Wi, hwo = 4 * hwi;
    size_t ni = (size_t)hwi, no = (size_t)hwo, Cs = (size_t)C;
    float *cur = dg, *other = work, *t;
    if (cfg->guidance != GS_GUIDE_NONE) { /* du = guide^T dg */
        zero(other, Cs * no);
        int rc = guide_backward(cfg, L, a, p, dp, tau, dtau, cur, other, no);
        if (rc)
            return rc;
        t = cur, cur = other, other = t;
    }
    lrelu_backward_inplace(cur, a->u, Cs * no); /* d(conv_c out) */
    conv_backward(other, dp->block[b].c.w, dp->block[b].c.b, cur, a->z,
                  p->block[b].c.w, C, C, hwo); /* dz */
    t = cur, cur = other, other = t;
    blur_backward(other, cur, C, 2 * Hi, 2 * Wi, L->rows); /* d(shuffle+tile) */
    t = cur, cur = other, other = t;
    shuffle_tile_backward(other, dxin, cur, C, Hi, Wi); /* dyb, dxin += */
    t = cur, cur = other, other = t;
    lrelu_backward_inplace(cur, a->yb, 4 * Cs * ni);
    conv_backward(other, dp->block[b].b.w, dp->block[b].b.b, cur, a->ya,
                  p->block[b].b.w, 2 * C, 4 * C, hwi); /* dya */
    t = cur, cur = other, other = t;
    lrelu_backward_inplace(cur, a->ya, 2 * Cs * ni);
    /* dxin accumulates (the caller's dx, or the skip term added above) */
    return gs_nn_conv1x1_backward(dxin, dp->block[b].a.w, dp->block[b].a.b, cur,
                                  xin, p->block[b].a.w, C, 2 * C, hwi);
}

/* ---- Forward and backward ------------------------------------------------ */

/* dst[3,HW] += conv_rgb(g): the 3-channel projection into a temporary. */
static int rgb_add(float *dst, float *tmp, const gs_renderer_conv *conv,
                   const float *g, int C, size_t hw)
{
    int rc = gs_nn_conv1x1_forward(tmp, g, conv->w, conv->b, C, 3, (int)hw);
    if (!rc)
        add_into(dst, tmp, 3 * hw);
    return rc;
}

int gs_renderer_forward(const gs_renderer_config *cfg,
                        const gs_renderer_params *p, const float *x,
                        const float *tau, int H, int W, float *acts,
                        size_t acts_len, float *out_rgb)
{
    act_layout L;
    int rc = check_call(cfg, p, x, tau, H, W, acts, acts_len, &L);
    if (rc)
        return rc;
    if (!out_rgb)
        return GS_ERR_ARG;
    int C = L.C, H1 = 2 * H, W1 = 2 * W;
    /* rgb = blur(up2x(conv_rgb0(x))) in rgb1a */
    rc = gs_nn_conv1x1_forward(L.rgb0, x, p->rgb0.w, p->rgb0.b, C, 3, (int)L.hw0);
    rc = rc ? rc : gs_nn_upsample2x_forward(L.rgb1b, L.rgb0, 3, H, W);
    if (rc)
        return rc;
    blur_forward(L.rgb1a, L.rgb1b, 3, H1, W1, L.rows);
    rc = block_forward(cfg, &L, 0, p, x, tau, H, W);
    rc = rc ? rc : rgb_add(L.rgb1a, L.rgb1b, &p->block[0].rgb, L.blk[0].g, C, L.hw1);
    /* rgb = blur(up2x(rgb)) in rgb2a */
    rc = rc ? rc : gs_nn_upsample2x_forward(L.rgb2b, L.rgb1a, 3, H1, W1);
    if (rc)
        return rc;
    blur_forward(L.rgb2a, L.rgb2b, 3, 2 * H1, 2 * W1, L.rows);
    rc = block_forward(cfg, &L, 1, p, L.blk[0].g, tau, H1, W1);
    rc = rc ? rc : rgb_add(L.rgb2a, L.rgb2b, &p->block[1].rgb, L.blk[1].g, C, L.hw2);
    rc = rc ? rc : gs_nn_sigmoid_forward(L.out, L.rgb2a, 3 * L.hw2);
    if (rc)
        return rc;
    memcpy(out_rgb, L.out, 3 * L.hw2 * sizeof *out_rgb);
    return GS_OK;
}

int gs_renderer_backward(const gs_renderer_config *cfg,
                         const gs_renderer_params *p, float *acts,
                         size_t acts_len, const float *x, const float *tau,
                         const float *dout_rgb, int H, int W,
                         const gs_renderer_params *dparams, float *dx,
                         float *dtau)
{
    act_layout L;
    int rc = check_call(cfg, p, x, tau, H, W, acts, acts_len, &L);
    if (rc)
        return rc;
    if (!dout_rgb || !params_ok(cfg, dparams))
        return GS_ERR_ARG;
    int C = L.C, H1 = 2 * H, W1 = 2 * W;
    const gs_renderer_params *dp = dparams;
    /* d(rgb before the sigmoid) in rgb2a; block 1's rgb: dg1 in bufP */
    zero(L.rgb2a, 3 * L.hw2);
    rc = gs_nn_sigmoid_backward(L.rgb2a, dout_rgb, L.out, 3 * L.hw2);
    if (rc)
        return rc;
    conv_backward(L.bufP, dp->block[1].rgb.w, dp->block[1].rgb.b, L.rgb2a,
                  L.blk[1].g, p->block[1].rgb.w, C, 3, (int)L.hw2);
    /* through rgb = blur(up2x(rgb)): d(rgb after block 0) in rgb1a */
    blur_backward(L.rgb2b, L.rgb2a, 3, 2 * H1, 2 * W1, L.rows);
    zero(L.rgb1a, 3 * L.hw1);
    rc = gs_nn_upsample2x_backward(L.rgb1a, L.rgb2b, 3, H1, W1);
    /* block 1 (its dx in bufX), then block 0's rgb: d(g0) in bufX */
    zero(L.bufX, (size_t)C * L.hw1);
    rc = rc ? rc : block_backward(cfg, &L, 1, p, dp, L.blk[0].g, tau, H1, W1,
                                  L.bufP, L.bufQ, L.bufX, dtau);
    rc = rc ? rc : gs_nn_conv1x1_backward(L.bufX, dp->block[0].rgb.w,
                                          dp->block[0].rgb.b, L.rgb1a,
                                          L.blk[0].g, p->block[0].rgb.w, C, 3,
                                          (int)L.hw1);
    if (rc)
        return rc;
    /* the first rgb: blur(up2x(conv_rgb0(x))) */
    blur_backward(L.rgb1b, L.rgb1a, 3, H1, W1, L.rows);
    zero(L.rgb0, 3 * L.hw0);
    rc = gs_nn_upsample2x_backward(L.rgb0, L.rgb1b, 3, H, W);
    rc = rc ? rc : gs_nn_conv1x1_backward(dx, dp->rgb0.w, dp->rgb0.b, L.rgb0, x,
                                          p->rgb0.w, C, 3, (int)L.hw0);
    return rc ? rc : block_backward(cfg, &L, 0, p, dp, x, tau, H, W, L.bufX,
                                    L.bufP, dx, dtau);
}
