/* The renderer's passes on a gs_pool: see renderer_ops.h.
 *
 * The maths is that of gs_nn (conv1x1, blur, pixel shuffle, LeakyReLU,
 * attention), arranged for this network: 1x1 convolutions over fixed bands
 * of pixels (one sgemm each, bias and activation fused in one pass), a
 * separable row-by-row blur with the reflected border outside the inner
 * loops, a LeakyReLU that vectorises, backward passes that write instead of
 * zeroing and adding, and double reductions split into four partial sums.
 * Rounding differs from the gs_nn kernels in the last bits; the PyTorch
 * test of the renderer covers it. */
#include "renderer_ops.h"

#include <cblas.h>
#include <stdint.h>
#include <string.h>

#include "gazesplat/nn.h"

enum {
    BAND_MIN = 2048, /* pixels per band at least (sgemm stays efficient) */
    FWD_BAND_FLOATS = 16384, /* a forward band's output floats at most */
    MAX_BANDS = 64,  /* bands per map at most (bounds the partials) */
    CHUNK = 65536,   /* elements per task of the elementwise passes */
    /* Elementwise loops run in blocks of VEC_BLOCK elements through
     * restrict pointers, then a scalar remainder: GCC at -O2 vectorises
     * only a loop that needs no alias check and no remainder of its own,
     * and these need both. Each element's arithmetic is unchanged, so the
     * bytes are too. */
    VEC_BLOCK = 8
};

/* ---- Partition -------------------------------------------------------- */

/* Band length for a map of hw pixels: a function of hw only, a multiple of
 * 64 so that every band but the last starts vector-aligned. */
static size_t band_len(size_t hw)
{
    size_t b = (hw + MAX_BANDS - 1) / MAX_BANDS;
    b = b < BAND_MIN ? BAND_MIN : b;
    return (b + 63) / 64 * 64;
}

static int band_count(size_t hw)
{
    size_t b = band_len(hw);
    return (int)((hw + b - 1) / b);
}

/* A forward band: its output (OC x band floats) small enough to stay in
 * the core's L2 cache between the sgemm and the bias pass. */
static size_t fwd_band_len(size_t hw, int OC)
{
    size_t b = FWD_BAND_FLOATS / (size_t)(OC > 0 ? OC : 1);
    b = b < 64 ? 64 : b / 64 * 64;
    return b < hw ? b : hw;
}

static int chunk_count(size_t n)
{
    return (int)((n + CHUNK - 1) / CHUNK);
}

/* Elements [*i0, *i1) of chunk t of n. */
static void chunk_range(int t, size_t n, size_t *i0, size_t *i1)
{
    *i0 = (size_t)t * CHUNK;
    *i1 = *i0 + CHUNK < n ? *i0 + CHUNK : n;
}

size_t gs_rop_part_size(int C)
{
    size_t Cs = (size_t)C;
    return MAX_BANDS * (8 * Cs * Cs + 4 * Cs); /* conv_b: OC IC + OC */
}

size_t gs_rop_rows_size(int C, size_t widest)
{
    size_t tasks = (size_t)(C > 3 ? C : 3);
    return tasks * 4 * widest;
}

/* ---- Small helpers ------------------------------------------------------ */

/* key > 0 ? a : b, "key > 0" tested on the bits as a signed integer (true
 * exactly for positive floats, and for NaNs with the sign clear) and the
 * choice made as a bitwise blend: GCC keeps a float compare as a branch
 * here, which random signs make mispredict half the time, while this form
 * vectorises. At key == 0 it picks b: the LeakyReLU gradient at 0 is the
 * slope, as in PyTorch and gs_nn. */
static inline float select_pos(float key, float a, float b)
{
    int32_t k, ia, ib, r;
    memcpy(&k, &key, sizeof k);
    memcpy(&ia, &a, sizeof ia);
    memcpy(&ib, &b, sizeof ib);
    int32_t m = -(int32_t)(k > 0);
    r = (ia & m) | (ib & ~m);
    float out;
    memcpy(&out, &r, sizeof out);
    return out;
}

/* sum of x[n] in double, four interleaved partial sums (a fixed order) to
 * break the dependency chain of one accumulator. */
static double sum_double(const float *x, size_t n)
{
    double s[4] = {0.0, 0.0, 0.0, 0.0};
    size_t i = 0;
    for (; i + 4 <= n; i += 4)
        for (int k = 0; k < 4; k++)
            s[k] += x[i + (size_t)k];
    for (; i < n; i++)
        s[0] += x[i];
    return (s[0] + s[1]) + (s[2] + s[3]);
}

/* sum of x[i] y[i] over n in double, as sum_double. */
static double dot_double(const float *x, const float *y, size_t n)
{
    double s[4] = {0.0, 0.0, 0.0, 0.0};
    size_t i = 0;
    for (; i + 4 <= n; i += 4)
        for (int k = 0; k < 4; k++)
            s[k] += (double)x[i + (size_t)k] * y[i + (size_t)k];
    for (; i < n; i++)
        s[0] += (double)x[i] * y[i];
    return (s[0] + s[1]) + (s[2] + s[3]);
}

/* ---- 1x1 convolution ---------------------------------------------------- */

typedef struct {
    float *out, *dinp, *dw, *db, *part;
    const float *in, *w, *b, *dout;
    int IC, OC, HW, lrelu, add_dinp;
    size_t band;
} conv_job;

/* Band t: out[:, band] = act(w in[:, band] + b) */
static void conv_forward_task(void *ctx, int t, int worker)
{
    (void)worker;
    const conv_job *j = ctx;
    size_t p0 = (size_t)t * j->band, HW = (size_t)j->HW;
    int n = (int)(HW - p0 < j->band ? HW - p0 : j->band);
    cblas_sgemm(CblasRowMajor, CblasNoTrans, CblasNoTrans, j->OC, n, j->IC,
                1.0f, j->w, j->IC, j->in + p0, j->HW, 0.0f, j->out + p0, j->HW);
    for (int o = 0; o < j->OC; o++) {
        float *restrict row = j->out + (size_t)o * HW + p0;
        const float bias = j->b[o];
        int p = 0;
        if (j->lrelu) {
            for (; p + VEC_BLOCK <= n; p += VEC_BLOCK)
                for (int q = p; q < p + VEC_BLOCK; q++) {
                    float v = row[q] + bias;
                    row[q] = select_pos(v, v, GS_ROP_LRELU_SLOPE * v);
                }
            for (; p < n; p++) {
                float v = row[p] + bias;
                row[p] = select_pos(v, v, GS_ROP_LRELU_SLOPE * v);
            }
        } else {
            for (; p + VEC_BLOCK <= n; p += VEC_BLOCK)
                for (int q = p; q < p + VEC_BLOCK; q++)
                    row[q] += bias;
            for (; p < n; p++)
                row[p] += bias;
        }
    }
}

void gs_rop_conv_forward(const gs_rop_ctx *x, float *out, const float *in,
                         const float *w, const float *b, int IC, int OC,
                         int HW, int lrelu)
{
    size_t band = fwd_band_len((size_t)HW, OC);
    conv_job j = {.out = out, .in = in, .w = w, .b = b, .IC = IC, .OC = OC,
                  .HW = HW, .lrelu = lrelu, .band = band};
    gs_pool_for(x->pool, (int)(((size_t)HW + band - 1) / band), conv_forward_task, &j);
}

/* Band t: dinp[:, band] (= or +=) w^T dout[:, band]; the band's weight and
 * bias gradients into part + t (OC IC + OC). */
static void conv_backward_task(void *ctx, int t, int worker)
{
    (void)worker;
    const conv_job *j = ctx;
    size_t p0 = (size_t)t * j->band, HW = (size_t)j->HW;
    int n = (int)(HW - p0 < j->band ? HW - p0 : j->band);
    const float *g = j->dout + p0;
    if (j->dinp)
        cblas_sgemm(CblasRowMajor, CblasTrans, CblasNoTrans, j->IC, n, j->OC,
                    1.0f, j->w, j->IC, g, j->HW, j->add_dinp ? 1.0f : 0.0f,
                    j->dinp + p0, j->HW);
    if (!j->dw)
        return;
    float *pw = j->part + (size_t)t * ((size_t)j->OC * (size_t)j->IC + (size_t)j->OC);
    float *pb = pw + (size_t)j->OC * (size_t)j->IC;
    cblas_sgemm(CblasRowMajor, CblasNoTrans, CblasTrans, j->OC, j->IC, n, 1.0f,
                g, j->HW, j->in + p0, j->HW, 0.0f, pw, j->IC);
    for (int o = 0; o < j->OC; o++)
        pb[o] = (float)sum_double(g + (size_t)o * HW, (size_t)n);
}

/* Row o of dw and db: the band partials summed in band order (double). */
static void conv_reduce_task(void *ctx, int o, int worker)
{
    (void)worker;
    const conv_job *j = ctx;
    int nb = band_count((size_t)j->HW);
    size_t stride = (size_t)j->OC * (size_t)j->IC + (size_t)j->OC;
    for (int i = 0; i < j->IC; i++) {
        double acc = 0.0;
        for (int t = 0; t < nb; t++)
            acc += j->part[(size_t)t * stride + (size_t)o * (size_t)j->IC + (size_t)i];
        j->dw[(size_t)o * (size_t)j->IC + (size_t)i] += (float)acc;
    }
    double acc = 0.0;
    for (int t = 0; t < nb; t++)
        acc += j->part[(size_t)t * stride + (size_t)j->OC * (size_t)j->IC + (size_t)o];
    j->db[o] += (float)acc;
}

void gs_rop_conv_backward(const gs_rop_ctx *x, float *dinp, int add_dinp,
                          float *dw, float *db, const float *dout,
                          const float *in, const float *w, int IC, int OC,
                          int HW)
{
    conv_job j = {.dinp = dinp, .dw = dw, .db = db, .part = x->part,
                  .in = in, .w = w, .dout = dout, .IC = IC, .OC = OC, .HW = HW,
                  .add_dinp = add_dinp, .band = band_len((size_t)HW)};
    gs_pool_for(x->pool, band_count((size_t)HW), conv_backward_task, &j);
    if (dw)
        gs_pool_for(x->pool, OC, conv_reduce_task, &j);
}

/* ---- Blur (one task per channel) ---------------------------------------- */

/* Reflect index i in [-1, n] into [0, n) (PyTorch 'reflect', n >= 2). */
static int reflect(int i, int n)
{
    return i < 0 ? -i : (i >= n ? 2 * n - 2 - i : i);
}

/* o[W] = ([1,2,1] vertically of rows a, b, d, then horizontally) / 16,
 * with reflected ends (W >= 2); v[W] is scratch. As blur_forward_task's
 * vertical pass and row_blur, element by element. */
static void blur_row3(float *restrict o, float *restrict v, const float *restrict a,
                      const float *restrict b, const float *restrict d, size_t W)
{
    size_t i = 0;
    for (; i + VEC_BLOCK <= W; i += VEC_BLOCK)
        for (size_t q = i; q < i + VEC_BLOCK; q++)
            v[q] = a[q] + 2.0f * b[q] + d[q];
    for (; i < W; i++)
        v[i] = a[i] + 2.0f * b[i] + d[i];
    const float scale = 1.0f / 16.0f;
    o[0] = (2.0f * v[1] + 2.0f * v[0]) * scale;
    size_t x = 1;
    for (; x + VEC_BLOCK <= W - 1; x += VEC_BLOCK)
        for (size_t q = x; q < x + VEC_BLOCK; q++)
            o[q] = (v[q - 1] + 2.0f * v[q] + v[q + 1]) * scale;
    for (; x < W - 1; x++)
        o[x] = (v[x - 1] + 2.0f * v[x] + v[x + 1]) * scale;
    o[W - 1] = (2.0f * v[W - 2] + 2.0f * v[W - 1]) * scale;
}

/* The adjoint of blur_row3's horizontal pass without the scale: e[W] from g[W] (W >= 2). The
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

typedef struct {
    const gs_rop_ctx *x;
    float *out;
    const float *in;
    int H, W;
} blur_job;

/* Channel c: vertical [1,2,1] into a row, then the horizontal pass. */
static void blur_forward_task(void *ctx, int c, int worker)
{
    (void)worker;
    const blur_job *j = ctx;
    int H = j->H, W = j->W;
    size_t hw = (size_t)H * (size_t)W, Ws = (size_t)W;
    const float *src = j->in + (size_t)c * hw;
    float *v = j->x->rows + (size_t)c * 4 * j->x->widest;
    for (int y = 0; y < H; y++) {
        const float *a = src + (size_t)reflect(y - 1, H) * Ws;
        const float *b = src + (size_t)y * Ws;
        const float *d = src + (size_t)reflect(y + 1, H) * Ws;
        blur_row3(j->out + (size_t)c * hw + (size_t)y * Ws, v, a, b, d, Ws);
    }
}

void gs_rop_blur_forward(const gs_rop_ctx *x, float *out, const float *in,
                         int C, int H, int W)
{
    blur_job j = {x, out, in, H, W};
    gs_pool_for(x->pool, C, blur_forward_task, &j);
}

/* Channel c: the rows' adjoints, then the columns' in place: row k gets
 * e[k-1] + 2 e[k] + e[k+1] (zero outside) plus the reflected taps (e[0]
 * into row 1, e[H-1] into row H-2); prev keeps the original e[k-1]. */
static void blur_backward_task(void *ctx, int c, int worker)
{
    (void)worker;
    const blur_job *j = ctx;
    int H = j->H, W = j->W;
    size_t hw = (size_t)H * (size_t)W, Ws = (size_t)W;
    float *d = j->out + (size_t)c * hw;
    float *prev = j->x->rows + (size_t)c * 4 * j->x->widest, *cur = prev + Ws;
    for (int y = 0; y < H; y++)
        row_blur_adjoint(d + (size_t)y * Ws, j->in + (size_t)c * hw + (size_t)y * Ws, W);
    memset(prev, 0, Ws * sizeof *prev); /* row -1: weight 0, but finite */
    for (int k = 0; k < H; k++) {
        float *row = d + (size_t)k * Ws;
        const float *next = k + 1 < H ? row + Ws : row; /* weight 0 at H-1 */
        float wu = (k > 0 ? 1.0f : 0.0f) + (k == 1 ? 1.0f : 0.0f);
        float wd = (k + 1 < H ? 1.0f : 0.0f) + (k == H - 2 ? 1.0f : 0.0f);
        memcpy(cur, row, Ws * sizeof *cur);
        for (int i = 0; i < W; i++)
            row[i] = (wu * prev[i] + 2.0f * cur[i] + wd * next[i]) * (1.0f / 16.0f);
        float *t = prev;
        prev = cur, cur = t;
    }
}

void gs_rop_blur_backward(const gs_rop_ctx *x, float *din, const float *dout,
                          int C, int H, int W)
{
    blur_job j = {x, din, dout, H, W};
    gs_pool_for(x->pool, C, blur_backward_task, &j);
}

/* ---- Pixel shuffle with the tiled skip ---------------------------------- */

typedef struct {
    const gs_rop_ctx *x;
    float *out, *dx;
    const float *y, *xin;
    int C, H, W;
} shuffle_job;

/* Row Y of output channel c of the shuffle with the tiled skip, into
 * dst[2W]: y channel 4c+k lands on the pixels (2h + k/2, 2w + k%2) of the
 * output plane, plus the skip's channel (4c+k) mod C. */
static void shuffle_row(float *dst, const shuffle_job *j, int c, int Y)
{
    size_t hw = (size_t)j->H * (size_t)j->W, row = (size_t)(Y >> 1) * (size_t)j->W;
    int k = 2 * (Y & 1);
    const float *restrict s0 = j->y + (size_t)(4 * c + k) * hw + row;
    const float *restrict s1 = s0 + hw;
    const float *restrict t0 = j->xin + (size_t)((4 * c + k) % j->C) * hw + row;
    const float *restrict t1 = j->xin + (size_t)((4 * c + k + 1) % j->C) * hw + row;
    float *restrict d = dst;
    size_t W = (size_t)j->W, w = 0;
    for (; w + VEC_BLOCK <= W; w += VEC_BLOCK)
        for (size_t q = w; q < w + VEC_BLOCK; q++) {
            d[2 * q] = s0[q] + t0[q];
            d[2 * q + 1] = s1[q] + t1[q];
        }
    for (; w < W; w++) {
        d[2 * w] = s0[w] + t0[w];
        d[2 * w + 1] = s1[w] + t1[w];
    }
}

/* Channel c: the blur of the shuffled plane, each of its rows made once,
 * into row buffer r % 3, one row ahead of the blur: the taps of row y are
 * rows y - 1, y and y + 1 (reflected at the ends, 1 and H2 - 2, rows made
 * already). The arithmetic of shuffle then blur, so the same values. */
static void shuffle_blur_task(void *ctx, int c, int worker)
{
    (void)worker;
    const shuffle_job *j = ctx;
    int H2 = 2 * j->H;
    size_t Ws = 2 * (size_t)j->W;
    float *base = j->x->rows + (size_t)c * 4 * j->x->widest;
    float *slot[3] = {base, base + Ws, base + 2 * Ws}, *v = base + 3 * Ws;
    shuffle_row(slot[0], j, c, 0);
    for (int y = 0; y < H2; y++) {
        if (y + 1 < H2)
            shuffle_row(slot[(y + 1) % 3], j, c, y + 1);
        blur_row3(j->out + (size_t)c * (size_t)H2 * Ws + (size_t)y * Ws, v,
                  slot[reflect(y - 1, H2) % 3], slot[y % 3], slot[reflect(y + 1, H2) % 3], Ws);
    }
}

void gs_rop_shuffle_tile_blur_forward(const gs_rop_ctx *x, float *out,
                                      const float *y, const float *xin, int C,
                                      int H, int W)
{
    shuffle_job j = {.x = x, .out = out, .y = y, .xin = xin, .C = C, .H = H, .W = W};
    gs_pool_for(x->pool, C, shuffle_blur_task, &j);
}

/* Gathers dout's plane k of channel c into dst[H,W] (= or +=). */
static void gather_plane(float *dst, const float *dout, int c, int k, int H,
                         int W, int add)
{
    size_t hw = (size_t)H * (size_t)W, W2 = 2 * (size_t)W;
    const float *src = dout + (size_t)c * 4 * hw + (size_t)(k >> 1) * W2 + (size_t)(k & 1);
    for (int h = 0; h < H; h++) {
        const float *g = src + (size_t)h * 2 * W2;
        float *a = dst + (size_t)h * (size_t)W;
        if (add)
            for (int w = 0; w < W; w++)
                a[w] += g[2 * (size_t)w];
        else
            for (int w = 0; w < W; w++)
                a[w] = g[2 * (size_t)w];
    }
}

/* dy channels 4c..4c+3 (written) */
static void shuffle_backward_dy_task(void *ctx, int c, int worker)
{
    (void)worker;
    const shuffle_job *j = ctx;
    size_t hw = (size_t)j->H * (size_t)j->W;
    for (int k = 0; k < 4; k++)
        gather_plane(j->out + (size_t)(4 * c + k) * hw, j->y, c, k, j->H, j->W, 0);
}

/* dx channel t += every plane (c, k) with (4c+k) mod C == t, in the order
 * of c then k (the order does not depend on the thread count). */
static void shuffle_backward_dx_task(void *ctx, int t, int worker)
{
    (void)worker;
    const shuffle_job *j = ctx;
    size_t hw = (size_t)j->H * (size_t)j->W;
    for (int c = 0; c < j->C; c++)
        for (int k = 0; k < 4; k++)
            if ((4 * c + k) % j->C == t)
                gather_plane(j->dx + (size_t)t * hw, j->y, c, k, j->H, j->W, 1);
}

void gs_rop_shuffle_tile_backward(const gs_rop_ctx *x, float *dy, float *dx,
                                  const float *dout, int C, int H, int W)
{
    shuffle_job j = {.out = dy, .dx = dx, .y = dout, .C = C, .H = H, .W = W};
    gs_pool_for(x->pool, C, shuffle_backward_dy_task, &j);
    if (dx)
        gs_pool_for(x->pool, C, shuffle_backward_dx_task, &j);
}

/* ---- Elementwise -------------------------------------------------------- */

typedef struct {
    float *d;
    const float *y;
    size_t n;
} ew_job;

static void lrelu_backward_task(void *ctx, int t, int worker)
{
    (void)worker;
    const ew_job *j = ctx;
    size_t i0, i1;
    chunk_range(t, j->n, &i0, &i1);
    float *restrict d = j->d;
    const float *restrict y = j->y;
    size_t i = i0;
    for (; i + VEC_BLOCK <= i1; i += VEC_BLOCK)
        for (size_t k = i; k < i + VEC_BLOCK; k++)
            d[k] = select_pos(y[k], d[k], GS_ROP_LRELU_SLOPE * d[k]);
    for (; i < i1; i++)
        d[i] = select_pos(y[i], d[i], GS_ROP_LRELU_SLOPE * d[i]);
}

void gs_rop_lrelu_backward(const gs_rop_ctx *x, float *d, const float *y,
                           size_t n)
{
    ew_job j = {d, y, n};
    gs_pool_for(x->pool, chunk_count(n), lrelu_backward_task, &j);
}

static void zero_task(void *ctx, int t, int worker)
{
    (void)worker;
    const ew_job *j = ctx;
    size_t i0, i1;
    chunk_range(t, j->n, &i0, &i1);
    memset(j->d + i0, 0, (i1 - i0) * sizeof *j->d);
}

void gs_rop_zero(const gs_rop_ctx *x, float *d, size_t n)
{
    ew_job j = {d, NULL, n};
    gs_pool_for(x->pool, chunk_count(n), zero_task, &j);
}

typedef struct {
    float *out;
    const float *in;
    int C, H, W, per; /* per: row chunks per channel */
} up_job;

enum { UP_ROWS = 32 }; /* output rows per task of the x2 upsampling */

static void upsample_task(void *ctx, int t, int worker)
{
    (void)worker;
    const up_job *j = ctx;
    int c = t / j->per, oy0 = t % j->per * UP_ROWS, H2 = 2 * j->H;
    int oy1 = oy0 + UP_ROWS < H2 ? oy0 + UP_ROWS : H2;
    size_t hw = (size_t)j->H * (size_t)j->W;
    gs_nn_upsample2x_forward_rows(j->out + (size_t)c * 4 * hw, j->in + (size_t)c * hw, 1,
                                  j->H, j->W, oy0, oy1);
}

void gs_rop_upsample2x_forward(const gs_rop_ctx *x, float *out, const float *in,
                               int C, int H, int W)
{
    up_job j = {out, in, C, H, W, (2 * H + UP_ROWS - 1) / UP_ROWS};
    gs_pool_for(x->pool, C * j.per, upsample_task, &j);
}

typedef struct {
    float *acc, *out, *copy;
    const float *add;
    size_t n;
} addsig_job;

static void add_sigmoid_task(void *ctx, int t, int worker)
{
    (void)worker;
    const addsig_job *j = ctx;
    size_t i0, i1;
    chunk_range(t, j->n, &i0, &i1);
    float *restrict a = j->acc;
    const float *restrict b = j->add;
    for (size_t i = i0; i < i1; i++)
        a[i] += b[i];
    if (!j->out)
        return;
    gs_nn_sigmoid_forward(j->out + i0, a + i0, i1 - i0);
    if (j->copy)
        memcpy(j->copy + i0, j->out + i0, (i1 - i0) * sizeof *j->copy);
}

void gs_rop_add_sigmoid(const gs_rop_ctx *x, float *acc, const float *add,
                        float *out, float *copy, size_t n)
{
    addsig_job j = {acc, out, copy, add, n};
    gs_pool_for(x->pool, chunk_count(n), add_sigmoid_task, &j);
}

/* ---- Guidance ------------------------------------------------------------
 * Two halves, so that the guidance vector can come from another map than
 * the one it is applied to (renderer.h, guide sources):
 *   vector: s = wk^T tau / temp, att = softmax_p(src_p . s),
 *           xbar = sum_p att_p src_p, a = wv xbar + bv
 *   apply:  g_p = u_p + a (additive) or u_p + u_p * a (multiplicative)
 * Backward of apply, with gain = 1 + a (multiplicative) or 1 (additive):
 *   du_p = dg_p * gain;  da_c = sum_p dg_cp u_cp (mult.) or sum_p dg_cp
 * Backward of vector from da:
 *   dbv += da; dwv += da xbar^T; dxbar = wv^T da; S = xbar . dxbar
 *   r_p = att_p (src_p . dxbar - S)               (softmax backward)
 *   dsrc_p += att_p dxbar + r_p s
 *   ds = sum_p r_p src_p; dwk += tau ds^T / temp; dtau += wk ds / temp
 * (the additive case with src = u is gs_nn_attention's maths). */

typedef struct {
    const gs_rop_guide *gd;
    float *g, *att_out, *du, *r; /* att_out: forward only */
    const float *att, *u, *src, *dg, *s, *a, *dxbar;
    float *xbar, *da, *ds;
    size_t hw, band;
    double S;
} guide_job;

/* s[C] = wk[D,C]^T tau[D] / temp */
static void guide_query(float *s, const gs_rop_guide *gd, const float *tau)
{
    for (int c = 0; c < gd->C; c++)
        s[c] = 0.0f;
    for (int d = 0; d < gd->D; d++) {
        const float *row = gd->wk + (size_t)d * (size_t)gd->C;
        for (int c = 0; c < gd->C; c++)
            s[c] += row[c] * tau[d];
    }
    for (int c = 0; c < gd->C; c++)
        s[c] /= gd->temp;
}

/* out[p] = src_p . v over band t of pixels; returns its first pixel and
 * sets *n to its length. */
static size_t band_dot(const guide_job *j, int t, const float *v, float *out,
                       size_t *n)
{
    size_t p0 = (size_t)t * j->band;
    *n = j->hw - p0 < j->band ? j->hw - p0 : j->band;
    for (size_t i = 0; i < *n; i++)
        out[p0 + i] = 0.0f;
    for (int c = 0; c < j->gd->C; c++) {
        const float *sc = j->src + (size_t)c * j->hw + p0;
        for (size_t i = 0; i < *n; i++)
            out[p0 + i] += sc[i] * v[c];
    }
    return p0;
}

/* Band t of pixels: att_p = src_p . s (the logits) */
static void logits_task(void *ctx, int t, int worker)
{
    (void)worker;
    const guide_job *j = ctx;
    size_t n;
    band_dot(j, t, j->s, j->att_out, &n);
}

static void pool_task(void *ctx, int c, int worker)
{
    (void)worker;
    const guide_job *j = ctx;
    j->xbar[c] = (float)dot_double(j->att, j->src + (size_t)c * j->hw, j->hw);
}

/* a[C] = wv xbar + bv */
static void value_project(const gs_rop_guide *gd, const float *xbar, float *a)
{
    for (int c = 0; c < gd->C; c++) {
        const float *row = gd->wv + (size_t)c * (size_t)gd->C;
        float v = gd->bv[c];
        for (int k = 0; k < gd->C; k++)
            v += row[k] * xbar[k];
        a[c] = v;
    }
}

void gs_rop_guide_vector(const gs_rop_ctx *x, const gs_rop_guide *gd,
                         float *a, float *att, const float *src,
                         const float *tau, size_t hw, float *scratch)
{
    float *s = scratch, *xbar = s + gd->C;
    guide_job j = {.gd = gd, .att_out = att, .att = att, .src = src, .s = s,
                   .xbar = xbar, .hw = hw, .band = band_len(hw)};
    guide_query(s, gd, tau);
    gs_pool_for(x->pool, band_count(hw), logits_task, &j);
    gs_nn_softmax_forward(att, att, (int)hw);
    gs_pool_for(x->pool, gd->C, pool_task, &j);
    value_project(gd, xbar, a);
}

static void apply_task(void *ctx, int c, int worker)
{
    (void)worker;
    const guide_job *j = ctx;
    const float *restrict uc = j->u + (size_t)c * j->hw;
    float *restrict gc = j->g + (size_t)c * j->hw;
    float a = j->a[c];
    size_t n = j->hw, q = 0;
    if (j->gd->mult) {
        for (; q + VEC_BLOCK <= n; q += VEC_BLOCK)
            for (size_t k = q; k < q + VEC_BLOCK; k++)
                gc[k] = uc[k] + uc[k] * a;
        for (; q < n; q++)
            gc[q] = uc[q] + uc[q] * a;
    } else {
        for (; q + VEC_BLOCK <= n; q += VEC_BLOCK)
            for (size_t k = q; k < q + VEC_BLOCK; k++)
                gc[k] = uc[k] + a;
        for (; q < n; q++)
            gc[q] = uc[q] + a;
    }
}

void gs_rop_guide_apply(const gs_rop_ctx *x, const gs_rop_guide *gd, float *g,
                        const float *u, const float *a, size_t hw)
{
    guide_job j = {.gd = gd, .g = g, .u = u, .a = a, .hw = hw};
    gs_pool_for(x->pool, gd->C, apply_task, &j);
}

/* Channel c: du_c = dg_c gain; da_c as above */
static void apply_back_task(void *ctx, int c, int worker)
{
    (void)worker;
    const guide_job *j = ctx;
    size_t off = (size_t)c * j->hw;
    const float *restrict gc = j->dg + off, *uc = j->u + off;
    float *restrict duc = j->du + off;
    float gain = j->gd->mult ? 1.0f + j->a[c] : 1.0f;
    size_t n = j->hw, q = 0;
    for (; q + VEC_BLOCK <= n; q += VEC_BLOCK)
        for (size_t k = q; k < q + VEC_BLOCK; k++)
            duc[k] = gc[k] * gain;
    for (; q < n; q++)
        duc[q] = gc[q] * gain;
    j->da[c] = (float)(j->gd->mult ? dot_double(gc, uc, j->hw)
                                   : sum_double(gc, j->hw));
}

void gs_rop_guide_apply_backward(const gs_rop_ctx *x, const gs_rop_guide *gd,
                                 float *du, float *da, const float *dg,
                                 const float *u, const float *a, size_t hw)
{
    guide_job j = {.gd = gd, .du = du, .da = da, .dg = dg, .u = u, .a = a,
                   .hw = hw};
    gs_pool_for(x->pool, gd->C, apply_back_task, &j);
}

/* Band t of pixels: r_p = att_p (src_p . dxbar - S) */
static void r_task(void *ctx, int t, int worker)
{
    (void)worker;
    const guide_job *j = ctx;
    size_t n, p0 = band_dot(j, t, j->dxbar, j->r, &n);
    float *r = j->r + p0;
    for (size_t i = 0; i < n; i++)
        r[i] = j->att[p0 + i] * (float)((double)r[i] - j->S);
}

/* Channel c: dsrc_c += att dxbar_c + r s_c; ds_c = r . src_c */
static void dsrc_task(void *ctx, int c, int worker)
{
    (void)worker;
    const guide_job *j = ctx;
    size_t off = (size_t)c * j->hw;
    const float *sc = j->src + off, *att = j->att, *r = j->r;
    float dxb = j->dxbar[c], qc = j->s[c];
    if (j->du) {
        float *d = j->du + off;
        for (size_t q = 0; q < j->hw; q++)
            d[q] = d[q] + att[q] * dxb + r[q] * qc;
    }
    j->ds[c] = (float)dot_double(r, sc, j->hw);
}

void gs_rop_guide_vector_backward(const gs_rop_ctx *x, const gs_rop_guide *gd,
                                  float *dsrc, float *dtau, const float *da,
                                  const float *src, const float *att,
                                  const float *tau, size_t hw, float *scratch)
{
    int C = gd->C;
    float *s = scratch, *xbar = s + C, *dxbar = xbar + C, *ds = dxbar + C;
    guide_job j = {.gd = gd, .att = att, .du = dsrc, .r = x->r, .src = src,
                   .s = s, .dxbar = dxbar, .xbar = xbar, .ds = ds, .hw = hw,
                   .band = band_len(hw)};
    guide_query(s, gd, tau);
    gs_pool_for(x->pool, C, pool_task, &j); /* xbar from the saved att */
    for (int c = 0; gd->dbv && c < C; c++) { /* NULL: no weight gradients */
        gd->dbv[c] += da[c];
        for (int k = 0; k < C; k++)
            gd->dwv[(size_t)c * (size_t)C + (size_t)k] += da[c] * xbar[k];
    }
    double S = 0.0;
    for (int k = 0; k < C; k++) {
        float v = 0.0f;
        for (int c = 0; c < C; c++)
            v += gd->wv[(size_t)c * (size_t)C + (size_t)k] * da[c];
        dxbar[k] = v;
        S += (double)xbar[k] * v;
    }
    j.S = S;
    gs_pool_for(x->pool, band_count(hw), r_task, &j);
    gs_pool_for(x->pool, C, dsrc_task, &j);
    for (int d = 0; d < gd->D; d++) {
        const float *row = gd->wk + (size_t)d * (size_t)C;
        float *drow = gd->dwk ? gd->dwk + (size_t)d * (size_t)C : NULL;
        float acc = 0.0f;
        for (int c = 0; c < C; c++) {
            float dq = ds[c] / gd->temp;
            if (drow)
                drow[c] += tau[d] * dq;
            acc += row[c] * dq;
        }
        if (dtau)
            dtau[d] += acc;
    }
}

void gs_rop_guide_forward(const gs_rop_ctx *x, const gs_rop_guide *gd,
                          float *g, float *att, const float *u,
                          const float *tau, size_t hw, float *scratch)
{
    float *a = scratch + 2 * gd->C;
    gs_rop_guide_vector(x, gd, a, att, u, tau, hw, scratch);
    gs_rop_guide_apply(x, gd, g, u, a, hw);
}

void gs_rop_guide_backward(const gs_rop_ctx *x, const gs_rop_guide *gd,
                           float *du, float *dtau, const float *dg,
                           const float *u, const float *att, const float *tau,
                           size_t hw, float *scratch)
{
    int C = gd->C;
    float *a = scratch, *da = a + C, *vs = da + C;
    /* a again from the saved att (no softmax) */
    guide_job j = {.gd = gd, .att = att, .src = u, .xbar = vs, .hw = hw};
    gs_pool_for(x->pool, C, pool_task, &j);
    value_project(gd, vs, a);
    gs_rop_guide_apply_backward(x, gd, du, da, dg, u, a, hw);
    gs_rop_guide_vector_backward(x, gd, du, dtau, da, u, att, tau, hw, vs);
}
