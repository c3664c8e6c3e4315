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
 * The passes themselves (and their split over a gs_pool) are in
 * renderer_ops.c; this file holds the layouts and the order of the passes.
 * tile(xin): shuffled channel c at (2h+i, 2w+j) adds xin channel
 * (4c+2i+j) mod C, i.e. xin.repeat(1,4,1,1) before the shuffle. */
#include "renderer.h"

#include <limits.h>
#include <math.h>
#include <stdio.h>
#include <string.h>

#include "gazesplat/nn.h"
#include "renderer_ops.h"

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
    if (cfg->guide_source != GS_GUIDE_SRC_BLOCK &&
        cfg->guide_source != GS_GUIDE_SRC_SOURCE)
        return gs_error_set(err, GS_ERR_ARG, "renderer: unknown guide source %d",
                            cfg->guide_source);
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
    float *att; /* [HWo]      attention weights; NULL unless BLOCK guidance */
} block_acts;

typedef struct {
    int C, D, H, W;
    size_t hw0, hw1, hw2;
    block_acts blk[GS_RENDERER_BLOCKS];
    float *out;          /* [3, HW2] saved sigmoid output */
    float *satt;         /* [HW0] source attention (SOURCE guidance) */
    float *gvec;         /* [C] the guidance vector (SOURCE guidance) */
    float *gda;          /* [C] its gradient (scratch) */
    float *bufP, *bufQ;  /* [C, HW2] scratch */
    float *bufX;         /* [C, HW1] scratch */
    float *rgb2a, *rgb2b; /* [3, HW2] scratch */
    float *rgb1a, *rgb1b; /* [3, HW1] scratch */
    float *rgb0;         /* [3, HW0] scratch */
    float *gscr;         /* [GUIDE_SCRATCH C] scratch */
    float *rows;         /* blur rows, gs_rop_rows_size(C, 4W) */
    float *part;         /* conv partials, gs_rop_part_size(C) */
    float *rbuf;         /* [HW2] guidance backward */
    size_t total;        /* floats */
} act_layout;

enum { GUIDE_SCRATCH = 6 }; /* floats per channel for the guidance passes */

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

/* SOURCE guidance in use: one vector for both blocks. */
static int source_guided(const gs_renderer_config *cfg)
{
    return cfg->guidance != GS_GUIDE_NONE &&
           cfg->guide_source == GS_GUIDE_SRC_SOURCE;
}

/* The full layout keeps every map the backward reads. The forward-only
 * one (lean) keeps none: each block's maps go to two ping-pong buffers A
 * and B of [C, HW2] floats (the largest block map), with block 0's output
 * g0 [C, HW1] in a third (block 1 reads it twice); conv_a A, conv_b B,
 * shuffle and blur A, conv_c B, guidance A (block 0: g0). Every pass reads
 * and writes what it does in the full layout, so the output is the same
 * bytes; no pass runs in place. */
static void layout_make(act_layout *L, const gs_renderer_config *cfg, int H,
                        int W, int lean, float *base)
{
    int C = cfg->channels, guided = cfg->guidance != GS_GUIDE_NONE,
        src = source_guided(cfg);
    memset(L, 0, sizeof *L);
    L->C = C, L->D = cfg->code_dim, L->H = H, L->W = W;
    L->hw0 = (size_t)H * (size_t)W, L->hw1 = 4 * L->hw0, L->hw2 = 16 * L->hw0;
    size_t Cs = (size_t)C;
    if (lean) {
        float *A = carve(L, base, Cs * L->hw2), *B = carve(L, base, Cs * L->hw2);
        float *g0 = carve(L, base, Cs * L->hw1);
        float *att = guided && !src ? carve(L, base, L->hw2) : NULL;
        for (int b = 0; b < GS_RENDERER_BLOCKS; b++) {
            block_acts *a = &L->blk[b];
            a->ya = A, a->yb = B, a->z = A, a->att = att;
            if (b == 0) {
                a->u = guided ? B : g0;
                a->g = g0;
            } else {
                a->u = B;
                a->g = guided ? A : B;
            }
        }
    }
    for (int b = 0; !lean && b < GS_RENDERER_BLOCKS; b++) {
        size_t hwi = b == 0 ? L->hw0 : L->hw1, hwo = 4 * hwi;
        block_acts *a = &L->blk[b];
        a->ya = carve(L, base, 2 * Cs * hwi);
        a->yb = carve(L, base, 4 * Cs * hwi);
        a->z = carve(L, base, Cs * hwo);
        a->u = carve(L, base, Cs * hwo);
        a->g = guided ? carve(L, base, Cs * hwo) : a->u;
        a->att = guided && !src ? carve(L, base, hwo) : NULL;
    }
    L->out = carve(L, base, 3 * L->hw2);
    L->satt = src ? carve(L, base, L->hw0) : NULL;
    L->gvec = src ? carve(L, base, Cs) : NULL;
    L->gda = src ? carve(L, base, Cs) : NULL;
    if (!lean) {
        L->bufP = carve(L, base, Cs * L->hw2);
        L->bufQ = carve(L, base, Cs * L->hw2);
        L->bufX = carve(L, base, Cs * L->hw1);
    }
    L->rgb2a = carve(L, base, 3 * L->hw2);
    L->rgb2b = carve(L, base, 3 * L->hw2);
    L->rgb1a = carve(L, base, 3 * L->hw1);
    L->rgb1b = carve(L, base, 3 * L->hw1);
    L->rgb0 = carve(L, base, 3 * L->hw0);
    L->gscr = carve(L, base, GUIDE_SCRATCH * Cs);
    L->rows = carve(L, base, gs_rop_rows_size(C, 4 * (size_t)W));
    L->part = carve(L, base, gs_rop_part_size(C));
    L->rbuf = guided ? carve(L, base, L->hw2) : NULL;
}

static size_t act_size(const gs_renderer_config *cfg, int H, int W, int lean)
{
    if (gs_renderer_config_validate(cfg, NULL) != GS_OK ||
        check_sizes(cfg->channels, H, W) != GS_OK)
        return 0;
    act_layout L;
    layout_make(&L, cfg, H, W, lean, NULL);
    return L.total;
}

size_t gs_renderer_act_size(const gs_renderer_config *cfg, int H, int W)
{
    return act_size(cfg, H, W, 0);
}

size_t gs_renderer_fwd_size(const gs_renderer_config *cfg, int H, int W)
{
    return act_size(cfg, H, W, 1);
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

/* Shared checks of forward and backward; fills *L on success. A forward
 * (fwd) takes the full layout when acts_len holds it, else the lean one;
 * a backward needs the full one. */
static int check_call(const gs_renderer_config *cfg, const gs_renderer_params *p,
                      const float *x, const float *tau, int H, int W,
                      float *acts, size_t acts_len, int fwd, act_layout *L)
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
    int lean = 0;
    layout_make(L, cfg, H, W, 0, NULL);
    if (acts_len < L->total && fwd) {
        lean = 1;
        layout_make(L, cfg, H, W, 1, NULL);
    }
    if (acts_len < L->total)
        return GS_ERR_ARG;
    layout_make(L, cfg, H, W, lean, acts);
    return GS_OK;
}

/* ---- Passes ---------------------------------------------------------- */

static gs_rop_ctx rop_ctx(const act_layout *L, gs_pool *pool)
{
    gs_rop_ctx x = {pool, L->part, L->rows, 4 * (size_t)L->W, L->rbuf};
    return x;
}

static gs_rop_guide rop_guide(const gs_renderer_config *cfg,
                              const act_layout *L, const gs_renderer_params *p,
                              const gs_renderer_params *dp)
{
    gs_rop_guide gd = {p->key_w, p->value_w, p->value_b,
                       dp ? dp->key_w : NULL, dp ? dp->value_w : NULL,
                       dp ? dp->value_b : NULL, L->C, L->D,
                       cfg->guidance == GS_GUIDE_MULTIPLICATIVE,
                       sqrtf((float)L->D)};
    return gd;
}

static void add_into(float *dst, const float *src, size_t n)
{
    for (size_t i = 0; i < n; i++)
        dst[i] += src[i];
}

/* ---- Blocks -------------------------------------------------------------- */

/* Block b: xin [C,Hi,Wi] -> a->g [C,2Hi,2Wi]. */
static void block_forward(const gs_renderer_config *cfg, const act_layout *L,
                          const gs_rop_ctx *x, int b,
                          const gs_renderer_params *p, const float *xin,
                          const float *tau, int Hi, int Wi)
{
    const block_acts *a = &L->blk[b];
    int C = L->C, hwi = Hi * Wi, hwo = 4 * hwi;
    gs_rop_conv_forward(x, a->ya, xin, p->block[b].a.w, p->block[b].a.b, C,
                        2 * C, hwi, 1);
    gs_rop_conv_forward(x, a->yb, a->ya, p->block[b].b.w, p->block[b].b.b,
                        2 * C, 4 * C, hwi, 1);
    gs_rop_shuffle_tile_blur_forward(x, a->z, a->yb, xin, C, Hi, Wi);
    gs_rop_conv_forward(x, a->u, a->z, p->block[b].c.w, p->block[b].c.b, C, C,
                        hwo, 1);
    if (cfg->guidance == GS_GUIDE_NONE)
        return;
    gs_rop_guide gd = rop_guide(cfg, L, p, NULL);
    if (source_guided(cfg))
        gs_rop_guide_apply(x, &gd, a->g, a->u, L->gvec, (size_t)hwo);
    else
        gs_rop_guide_forward(x, &gd, a->g, a->att, a->u, tau, (size_t)hwo,
                             L->gscr);
}

/* A conv's weight and bias gradients in dp, or NULL when dp is NULL (the
 * input gradients alone). */
#define DW(dp, conv) ((dp) ? (dp)->conv.w : NULL)
#define DB(dp, conv) ((dp) ? (dp)->conv.b : NULL)

/* Block b backward. dg [C,HWo] (consumed) and work [>= C HWo] are two
 * ping-pong buffers; adds into dxin [C,HWi] (may be NULL), dp, dtau. */
static void block_backward(const gs_renderer_config *cfg, const act_layout *L,
                           const gs_rop_ctx *x, int b,
                           const gs_renderer_params *p,
                           const gs_renderer_params *dp, const float *xin,
                           const float *tau, int Hi, int Wi, float *dg,
                           float *work, float *dxin, float *dtau)
{
    const block_acts *a = &L->blk[b];
    int C = L->C, hwi = Hi * Wi, hwo = 4 * hwi;
    size_t ni = (size_t)hwi, no = (size_t)hwo, Cs = (size_t)C;
    float *cur = dg, *other = work, *t;
    if (cfg->guidance != GS_GUIDE_NONE) { /* du = guide^T dg */
        gs_rop_guide gd = rop_guide(cfg, L, p, dp);
        if (source_guided(cfg)) { /* da of this block added to L->gda */
            float *da = L->gscr;
            gs_rop_guide_apply_backward(x, &gd, other, da, cur, a->u, L->gvec,
                                        no);
            add_into(L->gda, da, Cs);
        } else {
            gs_rop_guide_backward(x, &gd, other, dtau, cur, a->u, a->att, tau,
                                  no, L->gscr);
        }
        t = cur, cur = other, other = t;
    }
    gs_rop_lrelu_backward(x, cur, a->u, Cs * no); /* d(conv_c out) */
    gs_rop_conv_backward(x, other, 0, DW(dp, block[b].c), DB(dp, block[b].c), cur,
                         a->z, p->block[b].c.w, C, C, hwo); /* dz */
    t = cur, cur = other, other = t;
    gs_rop_blur_backward(x, other, cur, C, 2 * Hi, 2 * Wi); /* d(shuffle+tile) */
    t = cur, cur = other, other = t;
    gs_rop_shuffle_tile_backward(x, other, dxin, cur, C, Hi, Wi); /* dyb */
    t = cur, cur = other, other = t;
    gs_rop_lrelu_backward(x, cur, a->yb, 4 * Cs * ni);
    gs_rop_conv_backward(x, other, 0, DW(dp, block[b].b), DB(dp, block[b].b), cur,
                         a->ya, p->block[b].b.w, 2 * C, 4 * C, hwi); /* dya */
    t = cur, cur = other, other = t;
    gs_rop_lrelu_backward(x, cur, a->ya, 2 * Cs * ni);
    /* dxin accumulates: the caller's dx, or the skip term added above */
    gs_rop_conv_backward(x, dxin, 1, DW(dp, block[b].a), DB(dp, block[b].a), cur,
                         xin, p->block[b].a.w, C, 2 * C, hwi);
}

/* ---- Forward and backward ------------------------------------------------ */

/* dst[3,HW] += conv_rgb(g): the 3-channel projection into a temporary;
 * then, when out is not NULL, out = sigmoid(dst) and copy = out. */
static void rgb_add(const gs_rop_ctx *x, float *dst, float *tmp,
                    const gs_renderer_conv *conv, const float *g, int C,
                    size_t hw, float *out, float *copy)
{
    gs_rop_conv_forward(x, tmp, g, conv->w, conv->b, C, 3, (int)hw, 0);
    gs_rop_add_sigmoid(x, dst, tmp, out, copy, 3 * hw);
}

/* The passes after the guidance vector (if any) is in place. */
static int forward_core(const gs_renderer_config *cfg, const act_layout *L,
                        const gs_rop_ctx *ox, const gs_renderer_params *p,
                        const float *x, const float *tau, float *out_rgb)
{
    int C = L->C, H = L->H, W = L->W, H1 = 2 * H, W1 = 2 * W;
    /* rgb = blur(up2x(conv_rgb0(x))) in rgb1a */
    gs_rop_conv_forward(ox, L->rgb0, x, p->rgb0.w, p->rgb0.b, C, 3, (int)L->hw0, 0);
    gs_rop_upsample2x_forward(ox, L->rgb1b, L->rgb0, 3, H, W);
    gs_rop_blur_forward(ox, L->rgb1a, L->rgb1b, 3, H1, W1);
    block_forward(cfg, L, ox, 0, p, x, tau, H, W);
    rgb_add(ox, L->rgb1a, L->rgb1b, &p->block[0].rgb, L->blk[0].g, C, L->hw1,
            NULL, NULL);
    /* rgb = blur(up2x(rgb)) in rgb2a */
    gs_rop_upsample2x_forward(ox, L->rgb2b, L->rgb1a, 3, H1, W1);
    gs_rop_blur_forward(ox, L->rgb2a, L->rgb2b, 3, 2 * H1, 2 * W1);
    block_forward(cfg, L, ox, 1, p, L->blk[0].g, tau, H1, W1);
    rgb_add(ox, L->rgb2a, L->rgb2b, &p->block[1].rgb, L->blk[1].g, C, L->hw2,
            L->out, out_rgb);
    return GS_OK;
}

int gs_renderer_forward_src(const gs_renderer_config *cfg,
                            const gs_renderer_params *p, const float *x,
                            const float *tau, const float *src, int H, int W,
                            float *acts, size_t acts_len, float *out_rgb,
                            gs_pool *pool)
{
    act_layout L;
    int rc = check_call(cfg, p, x, tau, H, W, acts, acts_len, 1, &L);
    if (rc)
        return rc;
    if (!out_rgb)
        return GS_ERR_ARG;
    gs_rop_ctx ox = rop_ctx(&L, pool);
    if (source_guided(cfg)) {
        gs_rop_guide gd = rop_guide(cfg, &L, p, NULL);
        gs_rop_guide_vector(&ox, &gd, L.gvec, L.satt, src ? src : x, tau,
                            L.hw0, L.gscr);
    }
    return forward_core(cfg, &L, &ox, p, x, tau, out_rgb);
}

int gs_renderer_forward(const gs_renderer_config *cfg,
                        const gs_renderer_params *p, const float *x,
                        const float *tau, int H, int W, float *acts,
                        size_t acts_len, float *out_rgb, gs_pool *pool)
{
    return gs_renderer_forward_src(cfg, p, x, tau, NULL, H, W, acts, acts_len,
                                   out_rgb, pool);
}

int gs_renderer_guide_vector(const gs_renderer_config *cfg,
                             const gs_renderer_params *p, const float *src,
                             const float *tau, int H, int W, float *acts,
                             size_t acts_len, float *a, gs_pool *pool)
{
    act_layout L;
    int rc = check_call(cfg, p, src, tau, H, W, acts, acts_len, 1, &L);
    if (rc)
        return rc;
    if (!a || !source_guided(cfg))
        return GS_ERR_ARG;
    gs_rop_ctx ox = rop_ctx(&L, pool);
    gs_rop_guide gd = rop_guide(cfg, &L, p, NULL);
    gs_rop_guide_vector(&ox, &gd, L.gvec, L.satt, src, tau, L.hw0, L.gscr);
    memcpy(a, L.gvec, (size_t)L.C * sizeof *a);
    return GS_OK;
}

int gs_renderer_forward_vec(const gs_renderer_config *cfg,
                            const gs_renderer_params *p, const float *x,
                            const float *a, int H, int W, float *acts,
                            size_t acts_len, float *out_rgb, gs_pool *pool)
{
    act_layout L;
    int guided = cfg && cfg->guidance != GS_GUIDE_NONE;
    if (guided && (!source_guided(cfg) || !a))
        return GS_ERR_ARG;
    /* check_call wants a tau for guided configs; the blocks never read it
     * here, so the vector stands in. */
    int rc = check_call(cfg, p, x, a, H, W, acts, acts_len, 1, &L);
    if (rc)
        return rc;
    if (!out_rgb)
        return GS_ERR_ARG;
    gs_rop_ctx ox = rop_ctx(&L, pool);
    if (guided)
        memcpy(L.gvec, a, (size_t)L.C * sizeof *a);
    return forward_core(cfg, &L, &ox, p, x, NULL, out_rgb);
}

int gs_renderer_backward_src(const gs_renderer_config *cfg,
                             const gs_renderer_params *p, float *acts,
                             size_t acts_len, const float *x,
                             const float *tau, const float *src,
                             const float *dout_rgb, int H, int W,
                             const gs_renderer_params *dparams, float *dx,
                             float *dsrc, float *dtau, gs_pool *pool)
{
    act_layout L;
    int rc = check_call(cfg, p, x, tau, H, W, acts, acts_len, 0, &L);
    if (rc)
        return rc;
    if (!dout_rgb || (dparams && !params_ok(cfg, dparams)))
        return GS_ERR_ARG;
    gs_rop_ctx ox = rop_ctx(&L, pool);
    int C = L.C, H1 = 2 * H, W1 = 2 * W;
    const gs_renderer_params *dp = dparams;
    if (source_guided(cfg))
        memset(L.gda, 0, (size_t)C * sizeof *L.gda);
    /* d(rgb before the sigmoid) in rgb2a; block 1's rgb: dg1 in bufP */
    memset(L.rgb2a, 0, 3 * L.hw2 * sizeof *L.rgb2a);
    rc = gs_nn_sigmoid_backward(L.rgb2a, dout_rgb, L.out, 3 * L.hw2);
    if (rc)
        return rc;
    gs_rop_conv_backward(&ox, L.bufP, 0, DW(dp, block[1].rgb), DB(dp, block[1].rgb),
                         L.rgb2a, L.blk[1].g, p->block[1].rgb.w, C, 3,
                         (int)L.hw2);
    /* through rgb = blur(up2x(rgb)): d(rgb after block 0) in rgb1a */
    gs_rop_blur_backward(&ox, L.rgb2b, L.rgb2a, 3, 2 * H1, 2 * W1);
    memset(L.rgb1a, 0, 3 * L.hw1 * sizeof *L.rgb1a);
    rc = gs_nn_upsample2x_backward(L.rgb1a, L.rgb2b, 3, H1, W1);
    if (rc)
        return rc;
    /* block 1 (its dx in bufX), then block 0's rgb: d(g0) in bufX */
    gs_rop_zero(&ox, L.bufX, (size_t)C * L.hw1);
    block_backward(cfg, &L, &ox, 1, p, dp, L.blk[0].g, tau, H1, W1, L.bufP,
                   L.bufQ, L.bufX, dtau);
    gs_rop_conv_backward(&ox, L.bufX, 1, DW(dp, block[0].rgb), DB(dp, block[0].rgb),
                         L.rgb1a, L.blk[0].g, p->block[0].rgb.w, C, 3,
                         (int)L.hw1);
    /* the first rgb: blur(up2x(conv_rgb0(x))) */
    gs_rop_blur_backward(&ox, L.rgb1b, L.rgb1a, 3, H1, W1);
    memset(L.rgb0, 0, 3 * L.hw0 * sizeof *L.rgb0);
    rc = gs_nn_upsample2x_backward(L.rgb0, L.rgb1b, 3, H, W);
    if (rc)
        return rc;
    gs_rop_conv_backward(&ox, dx, 1, DW(dp, rgb0), DB(dp, rgb0), L.rgb0, x,
                         p->rgb0.w, C, 3, (int)L.hw0);
    block_backward(cfg, &L, &ox, 0, p, dp, x, tau, H, W, L.bufX, L.bufP, dx,
                   dtau);
    if (source_guided(cfg)) { /* the vector's backward, once for both blocks */
        gs_rop_guide gd = rop_guide(cfg, &L, p, dp);
        gs_rop_guide_vector_backward(&ox, &gd, src ? dsrc : dx, dtau, L.gda,
                                     src ? src : x, L.satt, tau, L.hw0,
                                     L.gscr + C);
    }
    return GS_OK;
}

int gs_renderer_backward(const gs_renderer_config *cfg,
                         const gs_renderer_params *p, float *acts,
                         size_t acts_len, const float *x, const float *tau,
                         const float *dout_rgb, int H, int W,
                         const gs_renderer_params *dparams, float *dx,
                         float *dtau, gs_pool *pool)
{
    return gs_renderer_backward_src(cfg, p, acts, acts_len, x, tau, NULL,
                                    dout_rgb, H, W, dparams, dx, NULL, dtau,
                                    pool);
}
