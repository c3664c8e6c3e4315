/* Fast compositing: tiles in parallel, each tile walked Gaussian by Gaussian
 * (front to back, or back to front in the backward pass) over the groups of
 * pixels (4 x 2 or 4 x 4 blocks, one pixel per vector lane) that the
 * Gaussian's alpha >= 1/255 ellipse can reach. Built once per instruction
 * set (GS_KERNELS names the table): GCC vector extensions map to AVX-512,
 * AVX2 or SSE2.
 *
 * The per-pixel arithmetic is the same as the scalar path's except for the
 * exponential, a polynomial accurate to a few ulp; the fast backward replays
 * exactly the alphas its forward computed. */
#define _POSIX_C_SOURCE 200809L /* posix_memalign */
#include <math.h>
#include <stdatomic.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "raster_internal.h"

#ifndef GS_KERNELS
#define GS_KERNELS gs_raster_kernels_generic
#endif

#ifndef GS_LANES
#define GS_LANES 8
#endif
#define L GS_LANES /* lanes: 8 (AVX2, SSE2, plain C) or 16 (AVX-512) */
#if L != 8 && L != 16
#error "GS_LANES must be 8 or 16"
#endif
#define TS GS_RASTER_TILE
#define TPIX (TS * TS)
/* A group is GW x GH pixels of a tile, one per lane, row-major in the
 * vector: 4 x 4 with 16 lanes, 4 x 2 with 8. Splats of a few pixels'
 * radius cover compact blocks in fewer groups, with more of each group's
 * lanes contributing, than runs of a row (16 x 1: about 3 of 16 lanes;
 * experiments/bench/README.md has the figures). */
#ifndef GS_GROUP_W
#define GS_GROUP_W 4
#endif
#define GW GS_GROUP_W
#define GH (L / GW)
#if GW * GH != L || TS % GW || TS % GH
#error "GS_GROUP_W must divide the lanes and the tile"
#endif
#define GX (TS / GW)      /* groups per row of groups */
#define GY (TS / GH)      /* rows of groups per tile */
#define NGROUPS (TPIX / L) /* groups per tile */
#define GROUP_BITS (L == 8 ? 5 : 4) /* log2(NGROUPS) */
/* Records (raster_internal.h): header pair << GROUP_BITS | group; exp(-sigma)
 * of the group's lanes, -1 in the lanes that did not contribute. */
#define REC_MAX_PAIRS ((uint32_t)1 << (32 - GROUP_BITS))

typedef float vf __attribute__((vector_size(4 * L), aligned(4 * L)));
typedef int32_t vi __attribute__((vector_size(4 * L), aligned(4 * L)));

static inline vf splat(float x)
{
#if L == 8
    return (vf){x, x, x, x, x, x, x, x};
#else
    return (vf){x, x, x, x, x, x, x, x, x, x, x, x, x, x, x, x};
#endif
}

#if defined(__AVX2__) || defined(__SSE2__)
#include <immintrin.h>
#endif

/* m ? a : b per lane (C has no vector ?:); m lanes are 0 or -1. */
static inline vf vsel(vi m, vf a, vf b)
{
#if L == 8 && defined(__AVX2__)
    return (vf)_mm256_blendv_ps((__m256)b, (__m256)a, (__m256)m);
#else
    return (vf)(((vi)a & m) | ((vi)b & ~m));
#endif
}

static inline vi vseli(vi m, vi a, vi b)
{
    return (a & m) | (b & ~m);
}

static inline vf vmin(vf a, vf b)
{
    return vsel(a < b, a, b);
}

static inline vf vmax(vf a, vf b)
{
    return vsel(a > b, a, b);
}

#if L == 16 && defined(__AVX512DQ__)
static inline int mask_bits(vi m)
{
    return (int)_mm512_movepi32_mask((__m512i)m);
}
#elif L == 8 && defined(__AVX2__)
static inline int mask_bits(vi m)
{
    return _mm256_movemask_ps((__m256)m);
}
#else
static inline int mask_bits(vi m)
{
    int r = 0;
    for (int j = 0; j < L; j++)
        r |= (m[j] < 0) << j;
    return r;
}
#endif

static inline int any(vi m)
{
    return mask_bits(m) != 0;
}

typedef float vf4 __attribute__((vector_size(16)));
typedef float vf8 __attribute__((vector_size(32)));

/* Lane sum of 8 in a fixed order (pairwise), the same on every path:
 * ((v0 + v4) + (v2 + v6)) + ((v1 + v5) + (v3 + v7)), as three shuffles and
 * three adds. */
static inline float hsum8(vf8 v)
{
    vf4 h = __builtin_shufflevector(v, v, 0, 1, 2, 3) + __builtin_shufflevector(v, v, 4, 5, 6, 7);
    h = h + __builtin_shufflevector(h, h, 2, 3, 0, 1);
    return h[0] + h[1];
}

/* 16 lanes: the two halves added lane by lane first, then as above. */
static inline float hsum(vf v)
{
#if L == 8
    return hsum8(v);
#else
    return hsum8(__builtin_shufflevector(v, v, 0, 1, 2, 3, 4, 5, 6, 7) +
                 __builtin_shufflevector(v, v, 8, 9, 10, 11, 12, 13, 14, 15));
#endif
}

/* exp(x) for x in [-87, 88] into `out`: Cody-Waite reduction x = n ln2 +
 * r, degree-6 minimax polynomial for exp(r) on |r| <= ln2/2, scaling by
 * 2^n through the exponent bits. The one body of both exponentials
 * (vexp_neg here, vexp_any in raster_proj.c); a macro, so that each
 * expands under its own file's contraction rule (raster_proj.c compiles
 * without fused multiply-adds) and neither's bytes change. */
#define VEXP_REDUCED(x, out)                                                    \
    do {                                                                        \
        vf fx_ = (x) * splat(1.44269504088896341f) + splat(0.5f);               \
        vi n_ = __builtin_convertvector(fx_, vi); /* truncates toward zero */    \
        vf nf_ = __builtin_convertvector(n_, vf);                               \
        n_ += (vi)(nf_ > fx_); /* -> floor (true is -1) */                      \
        nf_ = __builtin_convertvector(n_, vf);                                  \
        vf r_ = (x) - nf_ * splat(0.693359375f) - nf_ * splat(-2.12194440e-4f); \
        vf r2_ = r_ * r_;                                                       \
        vf p_ = splat(1.9875691500e-4f);                                        \
        p_ = p_ * r_ + splat(1.3981999507e-3f);                                 \
        p_ = p_ * r_ + splat(8.3334519073e-3f);                                 \
        p_ = p_ * r_ + splat(4.1665795894e-2f);                                 \
        p_ = p_ * r_ + splat(1.6666665459e-1f);                                 \
        p_ = p_ * r_ + splat(5.0000001201e-1f);                                 \
        p_ = p_ * r2_ + r_ + splat(1.0f);                                       \
        vi bits_ = (n_ + 127) << 23;                                            \
        vf scale_;                                                              \
        memcpy(&scale_, &bits_, sizeof scale_);                                 \
        (out) = p_ * scale_;                                                    \
    } while (0)

/* exp(x) for x <= 0. Below -87 returns 0 (alpha < 1/255 there anyway). */
static inline vf vexp_neg(vf x)
{
    vi tiny = x < splat(-87.0f);
    x = vmax(x, splat(-87.0f));
    vf e;
    VEXP_REDUCED(x, e);
    return vsel(tiny, splat(0.0f), e);
}

/* Pixel centres of a group's lanes relative to its corner: lane j is
 * column j % GW, row j / GW. */
#define LX(j) ((float)((j) % GW) + 0.5f)
#define LY(j) ((float)((j) / GW) + 0.5f)
#if L == 8
#define LANES8(F) F(0), F(1), F(2), F(3), F(4), F(5), F(6), F(7)
#define LANES(F) LANES8(F)
#else
#define LANES(F)                                                                             \
    F(0), F(1), F(2), F(3), F(4), F(5), F(6), F(7), F(8), F(9), F(10), F(11), F(12), F(13),  \
        F(14), F(15)
#endif
static const vf lane_cx = {LANES(LX)};
static const vf lane_cy = {LANES(LY)};

/* Per-lane dy of group row by for a splat at tile-relative my: the lane's
 * pixel row plus 0.5 is exact, so this is one rounding, as in the scalar
 * path. */
static inline vf group_dy(float my, int by)
{
    return splat(my) - (splat((float)(by * GH)) + lane_cy);
}

typedef struct {
    int x0, y0, w, h;      /* tile origin and size inside the image */
    uint32_t s, e;         /* its list */
} tile_info;

static tile_info get_tile(const gs_raster *r, int t)
{
    tile_info ti;
    int tx = t % r->tiles_x, ty = t / r->tiles_x;
    ti.x0 = tx * TS;
    ti.y0 = ty * TS;
    ti.w = r->cam.width - ti.x0 < TS ? r->cam.width - ti.x0 : TS;
    ti.h = r->cam.height - ti.y0 < TS ? r->cam.height - ti.y0 : TS;
    ti.s = r->tile_off[t];
    ti.e = r->tile_off[t + 1];
    return ti;
}

/* Rows of groups [*r0, *r1] and columns of groups [*g0, *g1] of the tile
 * that splat sp's ellipse can reach; returns 0 when none. */
static int splat_window(const gs_splat *sp, const tile_info *ti, int *r0, int *r1, int *g0,
                        int *g1)
{
    /* Clamped to the tile before rounding, so the conversions are exact and
     * no rounding call is needed: ceil(x) for x in [0, 16] is (int)x plus
     * one when x has a fraction. */
    float mx = sp->mx - (float)ti->x0 - 0.5f, my = sp->my - (float)ti->y0 - 0.5f;
    float hx = (float)(ti->w - 1), hy = (float)(ti->h - 1);
    float y0 = my - sp->ey, y1 = my + sp->ey, x0 = mx - sp->ex, x1 = mx + sp->ex;
    if (!(y1 >= 0 && x1 >= 0 && y0 <= hy && x0 <= hx))
        return 0;
    y0 = y0 > 0 ? y0 : 0, x0 = x0 > 0 ? x0 : 0;
    y1 = y1 < hy ? y1 : hy, x1 = x1 < hx ? x1 : hx;
    int iy0 = (int)y0, ix0 = (int)x0;
    int p0 = iy0 + ((float)iy0 < y0), p1 = (int)y1;
    int c0 = ix0 + ((float)ix0 < x0), c1 = (int)x1;
    *r0 = p0 / GH;
    *r1 = p1 / GH;
    *g0 = c0 / GW;
    *g1 = c1 / GW;
    return p0 <= p1 && c0 <= c1;
}

/* Pairs ahead of the one being composited whose data is fetched early: the
 * ids in a tile's list are in depth order, so their records and features
 * are scattered over memory. */
#define PREFETCH_AHEAD 6

static inline void prefetch_pair(const gs_raster *r, uint32_t k, uint32_t s, uint32_t e)
{
    if (k < s || k >= e)
        return;
    uint32_t i = r->isect[k];
    size_t C = (size_t)r->g.channels;
    const float *f = r->g.features + i * C;
    __builtin_prefetch(r->splats + i);
    for (size_t o = 0; o < C; o += 16)
        __builtin_prefetch(f + o);
    __builtin_prefetch(f + C - 1);
}

/* A vector's lanes as scalars, for the per-pixel loops. */
typedef union {
    vf v;
    float f[L];
} lanes;

/* Per-lane sigma, exp(-sigma) and alpha of one splat on one group. */
typedef struct {
    vf dx, sigma, vis, alpha;
    vi ok; /* sigma >= 0 and alpha >= 1/255 */
} group_eval;

/* sigma first: a group where no lane has sigma <= thr (the splat's widened
 * ln(255 opacity)) cannot pass the alpha test, so the exponential is
 * skipped there without changing any decision. */
static inline int group_sigma(group_eval *g, float mx, vf dy, float a, float b, float c,
                              float thr, float gx, vi alive)
{
    g->dx = splat(mx - gx) - lane_cx;
    g->sigma = splat(0.5f) * (splat(a) * g->dx * g->dx + splat(c) * dy * dy) +
               splat(b) * dy * g->dx;
    return any(alive & (g->sigma <= splat(thr)));
}

static inline void group_alpha(group_eval *g, float op)
{
    g->vis = vexp_neg(-g->sigma);
    g->alpha = vmin(splat(GS_RASTER_MAX_ALPHA), splat(op) * g->vis);
    g->ok = (g->sigma >= splat(0.0f)) & (g->alpha >= splat(GS_RASTER_MIN_ALPHA));
}

/* a[c] += f[c] w for c < nv, written out so that a constant nv leaves
 * straight-line code (GCC does not unroll the loop at -O2). */
static inline __attribute__((always_inline)) void axpy_nv(vf *a, const vf *f, vf w, const int nv)
{
    switch (nv) {
    default: a[7] += f[7] * w; /* fallthrough */
    case 7: a[6] += f[6] * w; /* fallthrough */
    case 6: a[5] += f[5] * w; /* fallthrough */
    case 5: a[4] += f[4] * w; /* fallthrough */
    case 4: a[3] += f[3] * w; /* fallthrough */
    case 3: a[2] += f[2] * w; /* fallthrough */
    case 2: a[1] += f[1] * w; /* fallthrough */
    case 1: a[0] += f[0] * w;
    }
}

/* One channel block of the backward's per-pixel work (see tile_backward_nv). */
#define BWD_BLOCK(c)                                                                     \
    do {                                                                                 \
        vf b_ = buf[p + (c)], vp_ = vpix[p + (c)];                                       \
        sf += fv[c] * vp_;                                                               \
        sb += b_ * vp_;                                                                  \
        buf[p + (c)] = b_ + fv[c] * facj;                                                \
        pf[c] += facj * vp_;                                                             \
    } while (0)

/* ---- pixel-major channel blocks ----------------------------------------- */

/* Channels are kept pixel-major inside a tile, nv vectors of 8 channels per
 * pixel, so that a contributing (pixel, Gaussian) pair costs nv vector
 * operations with the Gaussian's features held in registers, whatever the
 * number of other pixels in its group. The image planes are C x H x W, so
 * tiles are transposed on the way in and out, 8 x 8 at a time. */
#define MAX_NV (GS_RASTER_MAX_CHANNELS / L)

/* The first n <= 8 floats at p, zeros after them. A whole vector is the
 * common case; a constant-size memcpy compiles to one unaligned load. */
static inline vf load_n(const float *p, int n)
{
    vf v = splat(0.0f);
    if (n == L)
        memcpy(&v, p, sizeof v);
    else
        for (int j = 0; j < n; j++)
            v[j] = p[j];
    return v;
}

#if GH == 1
/* The same for the per-pixel contributor counts (row-run groups only). */
static inline vi load_ni(const uint32_t *p, int n)
{
    vi v = {0};
    if (n == L)
        memcpy(&v, p, sizeof v);
    else
        for (int j = 0; j < n; j++)
            v[j] = (int32_t)p[j];
    return v;
}

static inline void store_ni(uint32_t *p, vi v, int n)
{
    if (n == L)
        memcpy(p, &v, sizeof v);
    else
        for (int j = 0; j < n; j++)
            p[j] = (uint32_t)v[j];
}
#endif

/* Stores the first n <= 8 lanes of v at p. */
static inline void store_n(float *p, vf v, int n)
{
    if (n == L)
        memcpy(p, &v, sizeof v);
    else
        for (int j = 0; j < n; j++)
            p[j] = v[j];
}

/* A group of an image plane with row stride W, its corner at p: nw <= GW
 * columns of nh <= GH rows (fewer at the image's edges), zeros elsewhere. */
static inline vf load_grp(const float *p, size_t W, int nw, int nh)
{
#if GH == 1
    (void)W, (void)nh;
    return load_n(p, nw);
#else
    lanes u = {splat(0.0f)};
    for (int y = 0; y < nh; y++)
        if (nw == GW)
            memcpy(u.f + y * GW, p + (size_t)y * W, GW * sizeof(float));
        else
            for (int x = 0; x < nw; x++)
                u.f[y * GW + x] = p[(size_t)y * W + (size_t)x];
    return u.v;
#endif
}

static inline void store_grp(float *p, size_t W, vf v, int nw, int nh)
{
#if GH == 1
    (void)W, (void)nh;
    store_n(p, v, nw);
#else
    lanes u = {v};
    for (int y = 0; y < nh; y++)
        if (nw == GW)
            memcpy(p + (size_t)y * W, u.f + y * GW, GW * sizeof(float));
        else
            for (int x = 0; x < nw; x++)
                p[(size_t)y * W + (size_t)x] = u.f[y * GW + x];
#endif
}

/* The same for the per-pixel contributor counts. */
static inline vi load_grp_i(const uint32_t *p, size_t W, int nw, int nh)
{
#if GH == 1
    (void)W, (void)nh;
    return load_ni(p, nw);
#else
    vi v = {0};
    for (int y = 0; y < nh; y++)
        for (int x = 0; x < nw; x++)
            v[y * GW + x] = (int32_t)p[(size_t)y * W + (size_t)x];
    return v;
#endif
}

static inline void store_grp_i(uint32_t *p, size_t W, vi v, int nw, int nh)
{
#if GH == 1
    (void)W, (void)nh;
    store_ni(p, v, nw);
#else
    for (int y = 0; y < nh; y++)
        for (int x = 0; x < nw; x++)
            p[(size_t)y * W + (size_t)x] = (uint32_t)v[y * GW + x];
#endif
}

/* Features of one Gaussian as nv vectors, zero past channel C. */
static inline void load_features(const float *f, int C, int nv, vf *fv)
{
    for (int c = 0; c < nv; c++)
        fv[c] = load_n(f + c * L, C - c * L < L ? C - c * L : L);
}

/* In-place transpose of 8 vectors of 8 (rows) into 8 vectors (columns). */
static inline __attribute__((always_inline)) void transpose8x8(vf8 m[8])
{
    vf8 t[8], u[8];
#pragma GCC unroll 16
    for (int k = 0; k < 8; k += 2) {
        t[k] = __builtin_shufflevector(m[k], m[k + 1], 0, 8, 1, 9, 4, 12, 5, 13);
        t[k + 1] = __builtin_shufflevector(m[k], m[k + 1], 2, 10, 3, 11, 6, 14, 7, 15);
    }
#pragma GCC unroll 16
    for (int k = 0; k < 8; k += 4)
    #pragma GCC unroll 16
        for (int h = 0; h < 2; h++) {
            u[k + 2 * h] =
                __builtin_shufflevector(t[k + h], t[k + h + 2], 0, 1, 8, 9, 4, 5, 12, 13);
            u[k + 2 * h + 1] =
                __builtin_shufflevector(t[k + h], t[k + h + 2], 2, 3, 10, 11, 6, 7, 14, 15);
        }
#pragma GCC unroll 16
    for (int k = 0; k < 4; k++) {
        m[k] = __builtin_shufflevector(u[k], u[k + 4], 0, 1, 2, 3, 8, 9, 10, 11);
        m[k + 4] = __builtin_shufflevector(u[k], u[k + 4], 4, 5, 6, 7, 12, 13, 14, 15);
    }
}

/* In-place transpose of L vectors (rows) into L vectors (columns). */
static inline __attribute__((always_inline)) void transpose(vf m[L])
{
#if L == 8
    vf8 a[8];
#pragma GCC unroll 16
    for (int k = 0; k < 8; k++)
        a[k] = m[k];
    transpose8x8(a);
#pragma GCC unroll 16
    for (int k = 0; k < 8; k++)
        m[k] = a[k];
#else
    /* Interleave pairs of rows, then pairs of pairs: u[4i + j] holds, in
     * its 128-bit block b, rows 4i..4i+3 of column 4b + j. */
    vf t[16], u[16];
#pragma GCC unroll 16
    for (int k = 0; k < 16; k += 2) {
        t[k] = __builtin_shufflevector(m[k], m[k + 1], 0, 16, 1, 17, 4, 20, 5, 21, 8, 24, 9, 25,
                                       12, 28, 13, 29);
        t[k + 1] = __builtin_shufflevector(m[k], m[k + 1], 2, 18, 3, 19, 6, 22, 7, 23, 10, 26, 11,
                                           27, 14, 30, 15, 31);
    }
#pragma GCC unroll 16
    for (int k = 0; k < 16; k += 4)
    #pragma GCC unroll 16
        for (int h = 0; h < 2; h++) {
            u[k + 2 * h] = __builtin_shufflevector(t[k + h], t[k + h + 2], 0, 1, 16, 17, 4, 5, 20,
                                                   21, 8, 9, 24, 25, 12, 13, 28, 29);
            u[k + 2 * h + 1] = __builtin_shufflevector(t[k + h], t[k + h + 2], 2, 3, 18, 19, 6, 7,
                                                       22, 23, 10, 11, 26, 27, 14, 15, 30, 31);
        }
    /* Then gather the blocks: row 4b + j is u[j], u[4+j], u[8+j], u[12+j]'s
     * block b. */
#pragma GCC unroll 16
    for (int j = 0; j < 4; j++) {
        vf w0 = __builtin_shufflevector(u[j], u[4 + j], 0, 1, 2, 3, 16, 17, 18, 19, 8, 9, 10, 11,
                                        24, 25, 26, 27);
        vf w1 = __builtin_shufflevector(u[j], u[4 + j], 4, 5, 6, 7, 20, 21, 22, 23, 12, 13, 14,
                                        15, 28, 29, 30, 31);
        vf x0 = __builtin_shufflevector(u[8 + j], u[12 + j], 0, 1, 2, 3, 16, 17, 18, 19, 8, 9, 10,
                                        11, 24, 25, 26, 27);
        vf x1 = __builtin_shufflevector(u[8 + j], u[12 + j], 4, 5, 6, 7, 20, 21, 22, 23, 12, 13,
                                        14, 15, 28, 29, 30, 31);
        m[j] = __builtin_shufflevector(w0, x0, 0, 1, 2, 3, 4, 5, 6, 7, 16, 17, 18, 19, 20, 21, 22,
                                       23);
        m[8 + j] = __builtin_shufflevector(w0, x0, 8, 9, 10, 11, 12, 13, 14, 15, 24, 25, 26, 27,
                                           28, 29, 30, 31);
        m[4 + j] = __builtin_shufflevector(w1, x1, 0, 1, 2, 3, 4, 5, 6, 7, 16, 17, 18, 19, 20, 21,
                                           22, 23);
        m[12 + j] = __builtin_shufflevector(w1, x1, 8, 9, 10, 11, 12, 13, 14, 15, 24, 25, 26, 27,
                                            28, 29, 30, 31);
    }
#endif
}

/* ---- forward ------------------------------------------------------------ */

typedef struct {
    gs_raster *r;
    const float *bg;
    float *out_f, *out_alpha, *out_depth;
    size_t per_worker; /* floats of scratch per worker */
    size_t rec_cap;    /* records per worker arena at most */
    _Atomic size_t contributions; /* integer sum: order-independent */
} fwd_ctx;

/* Room for one more record in arena a, growing it up to cap records;
 * returns 0 when there is none (the tile is then not recorded). */
static __attribute__((noinline)) int rec_room(gs_rec_arena *a, size_t cap)
{
    if (a->n < a->cap)
        return 1;
    size_t want = a->cap ? 2 * a->cap : 4096;
    want = want < cap ? want : cap;
    if (want <= a->n)
        return 0;
    uint32_t *h = realloc(a->hdr, want * sizeof *h);
    if (!h)
        return 0;
    a->hdr = h;
    float *v = realloc(a->vis, want * L * sizeof *v);
    if (!v)
        return 0;
    a->vis = v;
    a->cap = want;
    return 1;
}

/* Group vectors of a tile's pixel state, each TPIX / L long. */
typedef struct {
    vf *T, *dep;
    vi *last, *alive;
} fwd_state;

/* Writes the tile: acc (TPIX x nv, pixel-major) plus T times the
 * background into the C planes, then alpha, T, last and depth. */
static inline __attribute__((always_inline)) void
write_tile(fwd_ctx *ctx, const tile_info *ti, const vf *acc, const fwd_state *st, const int nv)
{
    gs_raster *r = ctx->r;
    const int C = r->g.channels, W = r->cam.width;
    const size_t HW = (size_t)W * (size_t)r->cam.height;
    for (int by = 0; by * GH < ti->h; by++)
        for (int gi = 0; gi * GW < ti->w; gi++) {
            int v = by * GX + gi;
            int nw = ti->w - gi * GW < GW ? ti->w - gi * GW : GW;
            int nh = ti->h - by * GH < GH ? ti->h - by * GH : GH;
            size_t pix0 = (size_t)(ti->y0 + by * GH) * W + (size_t)(ti->x0 + gi * GW);
            vf T = st->T[v];
            for (int cb = 0; cb < nv; cb++) {
                vf m[L];
#pragma GCC unroll 16
                for (int j = 0; j < L; j++)
                    m[j] = acc[(size_t)(v * L + j) * nv + cb];
                transpose(m);
                for (int k = 0; k < L && cb * L + k < C; k++) {
                    size_t off = (size_t)(cb * L + k) * HW + pix0;
                    vf o = m[k];
                    if (ctx->bg)
                        o += T * load_grp(ctx->bg + off, (size_t)W, nw, nh);
                    store_grp(ctx->out_f + off, (size_t)W, o, nw, nh);
                }
            }
            vf alpha = splat(1.0f) - T;
            store_grp(ctx->out_alpha + pix0, (size_t)W, alpha, nw, nh);
            store_grp(r->t_final + pix0, (size_t)W, T, nw, nh);
            store_grp_i(r->last + pix0, (size_t)W, st->last[v], nw, nh);
            if (ctx->out_depth)
                store_grp(ctx->out_depth + pix0, (size_t)W, st->dep[v], nw, nh);
        }
}

/* Long on purpose (the compositing loop, per pixel and Gaussian): one
 * inlined body specialized per vector count, its state in registers. */
static inline __attribute__((always_inline)) void
tile_forward_nv(fwd_ctx *ctx, int t, int worker, const int nv)
{
    gs_raster *r = ctx->r;
    const int C = r->g.channels;
    int tile = (int)r->tile_order[t];
    tile_info ti = get_tile(r, tile);
    gs_rec_arena *ar = r->arenas + worker;
    size_t rec0 = ar->n;
    int rec = ctx->rec_cap > 0 && ti.e - ti.s < REC_MAX_PAIRS;
    /* The arena's fields in locals: through ar they would be reloaded after
     * every store to the tile's buffers. */
    size_t rn = ar->n, rcap = ar->cap;
    uint32_t *rhdr = ar->hdr;
    float *rvis = ar->vis;

    float *scratch = (float *)r->scratch + (size_t)worker * ctx->per_worker;
    vf *acc = (vf *)scratch; /* TPIX x nv */
    fwd_state st;
    st.T = acc + (size_t)nv * TPIX;
    st.dep = st.T + TPIX / L;
    st.last = (void *)(st.dep + TPIX / L);
    st.alive = st.last + TPIX / L;
    int row_alive[GY]; /* pixels still compositing per row of groups */
    int tile_alive = 0;
    size_t contributions = 0;
    memset(acc, 0, (size_t)nv * TPIX * sizeof(vf));
    for (int by = 0; by < GY; by++) {
        row_alive[by] = 0;
        for (int gi = 0; gi < GX; gi++) {
            int v = by * GX + gi;
            st.T[v] = splat(1.0f);
            st.dep[v] = splat(0.0f);
            st.last[v] = (vi){0};
            for (int j = 0; j < L; j++) {
                int in = gi * GW + j % GW < ti.w && by * GH + j / GW < ti.h;
                st.alive[v][j] = in ? -1 : 0;
                row_alive[by] += in;
            }
        }
        tile_alive += row_alive[by];
    }

    for (uint32_t k = ti.s; k < ti.s + PREFETCH_AHEAD; k++)
        prefetch_pair(r, k, ti.s, ti.e);
    for (uint32_t k = ti.s; k < ti.e && tile_alive > 0; k++) {
        prefetch_pair(r, k + PREFETCH_AHEAD, ti.s, ti.e);
        uint32_t i = r->isect[k];
        const gs_splat *sp = r->splats + i;
        int r0, r1, g0, g1;
        if (!splat_window(sp, &ti, &r0, &r1, &g0, &g1))
            continue;
        const float q[3] = {sp->a, sp->b, sp->c};
        float mx = sp->mx - (float)ti.x0, op = sp->op, z = sp->z, thr = sp->thr;
        float my = sp->my - (float)ti.y0;
        vf fv[MAX_NV];
        load_features(r->g.features + (size_t)i * C, C, nv, fv);
        vi pos = (vi){0} + (int32_t)(k - ti.s + 1);
        for (int by = r0; by <= r1; by++) {
            if (!row_alive[by])
                continue;
            vf dy = group_dy(my, by);
            for (int gi = g0; gi <= g1; gi++) {
                int v = by * GX + gi;
                vi alive = st.alive[v];
                if (!any(alive))
                    continue; /* every pixel here has stopped */
                group_eval ge;
                if (!group_sigma(&ge, mx, dy, q[0], q[1], q[2], thr, (float)(gi * GW), alive))
                    continue;
                group_alpha(&ge, op);
                vi valid = ge.ok & alive;
                if (!any(valid))
                    continue;
                vf T = st.T[v];
                vf next_T = T * (splat(1.0f) - ge.alpha);
                vi stop = valid & (next_T <= splat(GS_RASTER_T_EPS));
                if (any(stop)) {
                    st.alive[v] &= ~stop;
                    valid &= ~stop;
                    int n = __builtin_popcount((unsigned)mask_bits(stop));
                    row_alive[by] -= n;
                    tile_alive -= n;
                }
                unsigned bits = (unsigned)mask_bits(valid);
                contributions += (size_t)__builtin_popcount(bits);
                if (bits && rec) {
                    if (rn == rcap) {
                        ar->n = rn;
                        rec = rec_room(ar, ctx->rec_cap);
                        rcap = ar->cap, rhdr = ar->hdr, rvis = ar->vis;
                    }
                    if (rec) {
                        vf rv = vsel(valid, ge.vis, splat(-1.0f));
                        rhdr[rn] = (k - ti.s) << GROUP_BITS | (uint32_t)v;
                        memcpy(rvis + rn * L, &rv, sizeof rv);
                        rn++;
                    }
                }
                vf w = vsel(valid, ge.alpha * T, splat(0.0f));
                st.T[v] = vsel(valid, next_T, T);
                st.last[v] = vseli(valid, pos, st.last[v]);
                st.dep[v] += splat(z) * w;
                lanes wl = {w};
                vf *a = acc + (size_t)v * L * nv;
                while (bits) {
                    int j = __builtin_ctz(bits);
                    bits &= bits - 1;
                    axpy_nv(a + j * nv, fv, splat(wl.f[j]), nv);
                }
            }
        }
    }

    atomic_fetch_add_explicit(&ctx->contributions, contributions, memory_order_relaxed);
    gs_tile_rec *tr = r->tile_rec + tile;
    tr->worker = (uint32_t)worker;
    tr->off = rec0;
    tr->n = rec ? (uint32_t)(rn - rec0) : GS_REC_NONE;
    ar->n = rec ? rn : rec0;
    write_tile(ctx, &ti, acc, &st, nv);
}

/* One instance per channel-vector count, so the features stay in registers. */
static void tile_forward(void *vctx, int t, int worker)
{
    fwd_ctx *ctx = vctx;
    switch ((ctx->r->g.channels + L - 1) / L) {
    case 1: tile_forward_nv(ctx, t, worker, 1); break;
    case 2: tile_forward_nv(ctx, t, worker, 2); break;
    case 3: tile_forward_nv(ctx, t, worker, 3); break;
    case 4: tile_forward_nv(ctx, t, worker, 4); break;
#if MAX_NV > 4
    case 5: tile_forward_nv(ctx, t, worker, 5); break;
    case 6: tile_forward_nv(ctx, t, worker, 6); break;
    case 7: tile_forward_nv(ctx, t, worker, 7); break;
#endif
    default: tile_forward_nv(ctx, t, worker, MAX_NV); break;
    }
}

static size_t padded_channels(int C)
{
    return (size_t)(C + L - 1) / L * L;
}

static size_t fwd_scratch_floats(int C)
{
    return (padded_channels(C) + 4) * TPIX;
}

static size_t bwd_scratch_floats(int C)
{
    /* buf, vpix: TPIX x padded C each; T, tfin, vA-bgdot, vD, bufd, last:
     * TPIX each; partial sums: GS_SLOT_HEAD vectors */
    return (2 * padded_channels(C) + 6) * TPIX + (size_t)GS_SLOT_HEAD * L;
}

/* Scratch is aligned for the vectors: realloc is not, so grow by hand. */
static int reserve_scratch(gs_raster *r, gs_pool *pool, size_t per_worker)
{
    size_t want = (size_t)gs_pool_threads(pool) * per_worker * sizeof(float);
    if (want <= r->cap_scratch)
        return GS_OK;
    void *p = NULL;
    if (posix_memalign(&p, 64, want))
        return GS_ERR_NOMEM;
    free(r->scratch);
    r->scratch = p;
    r->cap_scratch = want;
    return GS_OK;
}

static size_t scratch_per_worker(int C)
{
    size_t per = fwd_scratch_floats(C);
    if (bwd_scratch_floats(C) > per)
        per = bwd_scratch_floats(C);
    return (per + 15) / 16 * 16; /* keep each worker's block 64-byte aligned */
}

static int cmp_u64(const void *a, const void *b)
{
    uint64_t x = *(const uint64_t *)a, y = *(const uint64_t *)b;
    return (x > y) - (x < y);
}

/* Tiles [t0, t1) into r->tile_order, longest list first (ties by index), so
 * the pool's workers take the heavy tiles early and finish together. Which
 * worker composites a tile never changes its result. */
static int order_tiles(gs_raster *r, int t0, int t1, uint32_t from, int *count)
{
    size_t n = (size_t)(t1 - t0);
    if (gs_raster_reserve((void **)&r->tile_order, &r->cap_tile_order, n ? n : 1,
                          sizeof(uint32_t)) ||
        gs_raster_reserve((void **)&r->tile_keys, &r->cap_tile_keys, n ? n : 1,
                          sizeof(uint64_t)))
        return GS_ERR_NOMEM;
    /* Keys (UINT32_MAX - length, tile) sort ascending into that order. */
    uint64_t *key = r->tile_keys;
    const uint32_t *off = r->tile_off;
    size_t kept = 0;
    for (size_t a = 0; a < n; a++) {
        uint32_t t = (uint32_t)t0 + (uint32_t)a;
        int take = from == 0;
        for (uint32_t k = off[t]; !take && k < off[t + 1]; k++)
            take = r->isect[k] >= from;
        if (take)
            key[kept++] = ((uint64_t)(UINT32_MAX - (off[t + 1] - off[t])) << 32) | t;
    }
    n = kept;
    if (count)
        *count = (int)n;
    qsort(key, n, sizeof *key, cmp_u64);
    for (size_t a = 0; a < n; a++)
        r->tile_order[a] = (uint32_t)key[a];
    return GS_OK;
}

/* Per-tile record entries and one empty arena per worker (arenas keep their
 * memory across calls). */
static int reserve_records(gs_raster *r, gs_pool *pool, int ntiles)
{
    if (gs_raster_reserve((void **)&r->tile_rec, &r->cap_tile_rec,
                          (size_t)(ntiles ? ntiles : 1), sizeof(gs_tile_rec)))
        return GS_ERR_NOMEM;
    int threads = gs_pool_threads(pool);
    if (threads > r->n_arenas) {
        gs_rec_arena *a = realloc(r->arenas, (size_t)threads * sizeof *a);
        if (!a)
            return GS_ERR_NOMEM;
        memset(a + r->n_arenas, 0, (size_t)(threads - r->n_arenas) * sizeof *a);
        r->arenas = a;
        r->n_arenas = threads;
    }
    for (int w = 0; w < r->n_arenas; w++)
        r->arenas[w].n = 0;
    return GS_OK;
}

static int fast_forward(gs_raster *r, gs_pool *pool, const float *bg, float *out_f,
                        float *out_alpha, float *out_depth)
{
    size_t per = scratch_per_worker(r->g.channels);
    if (reserve_scratch(r, pool, per))
        return GS_ERR_NOMEM;
    int ntiles = r->tiles_x * r->tiles_y;
    int composite = ntiles; /* tiles in tile_order (gs_raster_options.changed_from) */
    if (order_tiles(r, 0, ntiles, (uint32_t)r->opt.changed_from, &composite) ||
        reserve_records(r, pool, ntiles))
        return GS_ERR_NOMEM;
    int threads = gs_pool_threads(pool);
    size_t budget = r->rec_budget ? r->rec_budget : GS_RASTER_REC_BUDGET;
    size_t rec_cap = r->no_records ? 0
                     : budget / (sizeof(uint32_t) + L * sizeof(float)) / (size_t)threads;
    fwd_ctx ctx = {r, bg, out_f, out_alpha, out_depth, per, rec_cap, 0};
    gs_pool_for(pool, composite, tile_forward, &ctx);
    r->contributions = atomic_load(&ctx.contributions);
    return GS_OK;
}

/* ---- backward ----------------------------------------------------------- */

typedef struct {
    gs_raster *r;
    size_t slot0, per_worker; /* slot0: slot of the batch's first pair */
    const float *v_f, *v_alpha, *v_depth;
    float *v_bg;
} bwd_ctx;

/* Group vectors of a tile's backward pixel state, each TPIX / L long. */
typedef struct {
    vf *T, *tfin, *vres, *vdep, *bufd; /* vres: v_alpha - <bg, v_pix> */
    vi *last;
} bwd_state;

/* Loads the tile's upstream gradient pixel-major into vpix (TPIX x nv) and
 * the per-pixel state; adds T_final v_pix into v_bg. */
static inline __attribute__((always_inline)) void
load_tile(bwd_ctx *ctx, const tile_info *ti, vf *vpix, const bwd_state *st, const int nv)
{
    gs_raster *r = ctx->r;
    const int C = r->g.channels, W = r->cam.width;
    const size_t HW = (size_t)W * (size_t)r->cam.height;
    const float *bg = r->background;
    for (int by = 0; by * GH < ti->h; by++)
        for (int gi = 0; gi * GW < ti->w; gi++) {
            int v = by * GX + gi;
            int nw = ti->w - gi * GW < GW ? ti->w - gi * GW : GW;
            int nh = ti->h - by * GH < GH ? ti->h - by * GH : GH;
            size_t pix0 = (size_t)(ti->y0 + by * GH) * W + (size_t)(ti->x0 + gi * GW);
            vf T = load_grp(r->t_final + pix0, (size_t)W, nw, nh);
            st->T[v] = st->tfin[v] = T;
            st->vdep[v] =
                ctx->v_depth ? load_grp(ctx->v_depth + pix0, (size_t)W, nw, nh) : splat(0.0f);
            st->last[v] = load_grp_i(r->last + pix0, (size_t)W, nw, nh);
            vf bg_dot = splat(0.0f);
            for (int cb = 0; cb < nv; cb++) {
                vf m[L];
                for (int k = 0; k < L; k++) {
                    int ch = cb * L + k;
                    m[k] = splat(0.0f);
                    if (ch >= C)
                        continue;
                    size_t off = (size_t)ch * HW + pix0;
                    m[k] = load_grp(ctx->v_f + off, (size_t)W, nw, nh);
                    if (bg)
                        bg_dot += load_grp(bg + off, (size_t)W, nw, nh) * m[k];
                    if (ctx->v_bg) {
                        vf vb = load_grp(ctx->v_bg + off, (size_t)W, nw, nh);
                        store_grp(ctx->v_bg + off, (size_t)W, vb + T * m[k], nw, nh);
                    }
                }
                transpose(m);
#pragma GCC unroll 16
                for (int j = 0; j < L; j++)
                    vpix[(size_t)(v * L + j) * nv + cb] = m[j];
            }
            vf va = ctx->v_alpha ? load_grp(ctx->v_alpha + pix0, (size_t)W, nw, nh) : splat(0.0f);
            st->vres[v] = va - bg_dot;
        }
}

/* What one (tile, Gaussian) pair of the backward works with. */
typedef struct {
    vf fv[MAX_NV], pf[MAX_NV]; /* features; their gradient */
    vf part[GS_SLOT_HEAD];     /* partial sums of the slot's head */
    float q[3], mx, my, op, z, thr;
} bwd_pair;

static inline __attribute__((always_inline)) void
pair_begin(bwd_pair *bp, const gs_splat *sp, const float *f, int C, float x0, float y0,
           const int nv)
{
    bp->q[0] = sp->a, bp->q[1] = sp->b, bp->q[2] = sp->c;
    bp->mx = sp->mx - x0, bp->my = sp->my - y0;
    bp->op = sp->op, bp->z = sp->z, bp->thr = sp->thr;
    load_features(f, C, nv, bp->fv);
    for (int c = 0; c < nv; c++)
        bp->pf[c] = splat(0.0f);
    for (int h = 0; h < GS_SLOT_HEAD; h++)
        bp->part[h] = splat(0.0f);
}

/* The pair's slot: the head's sums, a 1 in its last element (the gather
 * skips slots without it), the feature gradient. */
static inline __attribute__((always_inline)) void
pair_end(const bwd_pair *bp, float *slot, int C, const int nv)
{
    for (int h = 0; h < GS_SLOT_HEAD - 1; h++)
        slot[h] = hsum(bp->part[h]);
    slot[GS_SLOT_HEAD - 1] = 1.0f;
    for (int c = 0; c < nv; c++)
        store_n(slot + GS_SLOT_HEAD + c * L, bp->pf[c], C - c * L < L ? C - c * L : L);
}

/* Gradients of one group v (lanes' dy) whose pixels in valid took part, with
 * ge's dx, vis and alpha: undoes the group's step of the forward in the
 * pixel state, adds into the pair's sums. */
static inline __attribute__((always_inline)) void
group_grad(bwd_pair *bp, const bwd_state *st, vf *buf, const vf *vpix, int v, vf dy,
           const group_eval *ge, vi valid, const int nv)
{
    const float *q = bp->q;
    vf *pf = bp->pf, *part = bp->part;
    const vf *fv = bp->fv;
    vf ra = splat(1.0f) / vmax(splat(1.0f) - ge->alpha, splat(GS_RASTER_ONE_MINUS_ALPHA_FLOOR));
    ra = vsel(valid, ra, splat(1.0f));
    vf T = st->T[v] * ra;
    st->T[v] = T;
    vf fac = vsel(valid, ge->alpha * T, splat(0.0f));
    /* Channels of each contributing pixel: the feature part of the alpha
     * gradient, the running sums behind it and the Gaussian's feature
     * gradient. */
    lanes Tl = {T}, ral = {ra}, facl = {fac}, val = {splat(0.0f)};
    unsigned bits = (unsigned)mask_bits(valid);
    while (bits) {
        int j = __builtin_ctz(bits);
        bits &= bits - 1;
        size_t p = ((size_t)v * L + (size_t)j) * (size_t)nv;
        vf facj = splat(facl.f[j]), sf = splat(0.0f), sb = splat(0.0f);
        switch (nv) {
        default: BWD_BLOCK(7); /* fallthrough */
        case 7: BWD_BLOCK(6); /* fallthrough */
        case 6: BWD_BLOCK(5); /* fallthrough */
        case 5: BWD_BLOCK(4); /* fallthrough */
        case 4: BWD_BLOCK(3); /* fallthrough */
        case 3: BWD_BLOCK(2); /* fallthrough */
        case 2: BWD_BLOCK(1); /* fallthrough */
        case 1: BWD_BLOCK(0);
        }
        /* sum_ch (f T - buf ra) v_pix */
        val.f[j] = hsum(splat(Tl.f[j]) * sf - splat(ral.f[j]) * sb);
    }
    vf z = splat(bp->z);
    vf va = val.v + st->tfin[v] * ra * st->vres[v] + st->vdep[v] * (z * T - st->bufd[v] * ra);
    st->bufd[v] += z * fac;
    part[6] += fac * st->vdep[v];
    vi grad_ok = valid & (splat(bp->op) * ge->vis <= splat(GS_RASTER_MAX_ALPHA));
    va = vsel(grad_ok, va, splat(0.0f));
    vf vsig = -ge->alpha * va;
    vf dx = ge->dx, vdy = dy;
    part[0] += vsig * (splat(q[0]) * dx + splat(q[1]) * vdy);
    part[1] += vsig * (splat(q[1]) * dx + splat(q[2]) * vdy);
    part[2] += splat(0.5f) * vsig * dx * dx;
    part[3] += vsig * dx * vdy;
    part[4] += splat(0.5f) * vsig * vdy * vdy;
    part[5] += ge->vis * va;
}

/* The gradients of pair sp (features f) from its records (hdr: group in the
 * low GROUP_BITS; vis: L exponentials each, -1 in lanes that did not
 * contribute), in the forward's group order, into
 * its slot. Everything of the pair lives in locals: through pointers it
 * could alias the tile buffers and be reloaded at every store. */
static inline __attribute__((always_inline)) void
pair_grad_nv(const gs_splat *sp, const float *f, int C, float x0, float y0,
             const bwd_state *state, vf *buf, const vf *vpix, const uint32_t *hdr,
             const float *vis, size_t nrec, float *slot, const int nv)
{
    bwd_pair p;
    bwd_state st = *state;
    pair_begin(&p, sp, f, C, x0, y0, nv);
    for (size_t e = 0; e < nrec; e++) {
        int v = (int)(hdr[e] & (NGROUPS - 1));
        vf dy = group_dy(p.my, v / GX);
        vf ex;
        memcpy(&ex, vis + e * L, sizeof ex);
        /* sigma and ok are not needed here (the lanes are known) */
        group_eval ge = {.dx = splat(p.mx - (float)(v % GX * GW)) - lane_cx,
                         .sigma = splat(0.0f),
                         .vis = ex,
                         .alpha = vmin(splat(GS_RASTER_MAX_ALPHA), splat(p.op) * ex),
                         .ok = {0}};
        group_grad(&p, &st, buf, vpix, v, dy, &ge, ex >= splat(0.0f), nv);
    }
    pair_end(&p, slot, C, nv);
}

/* One out-of-line copy for both ways of finding the records, so that the
 * compiler cannot round them differently (fused multiply-adds). */
static __attribute__((noinline)) void
pair_grad(const gs_splat *sp, const float *f, int C, float x0, float y0, const bwd_state *st,
          vf *buf, const vf *vpix, const uint32_t *hdr, const float *vis, size_t nrec,
          float *slot, int nv)
{
#define PAIR_GRAD(n) pair_grad_nv(sp, f, C, x0, y0, st, buf, vpix, hdr, vis, nrec, slot, n)
    switch (nv) {
    case 1: PAIR_GRAD(1); break;
    case 2: PAIR_GRAD(2); break;
    case 3: PAIR_GRAD(3); break;
    case 4: PAIR_GRAD(4); break;
#if MAX_NV > 4
    case 5: PAIR_GRAD(5); break;
    case 6: PAIR_GRAD(6); break;
    case 7: PAIR_GRAD(7); break;
#endif
    default: PAIR_GRAD(MAX_NV); break;
    }
#undef PAIR_GRAD
}

/* Pairs [ti.s, ti.e) back to front, replaying the forward's records of the
 * tile: only the groups where a pixel took part, with their exponentials. */
static inline __attribute__((always_inline)) void
replay_pairs(bwd_ctx *ctx, const tile_info *ti, const gs_tile_rec *tr, const bwd_state *st,
             vf *buf, const vf *vpix, const int nv)
{
    gs_raster *r = ctx->r;
    const int C = r->g.channels;
    const size_t stride = GS_SLOT_HEAD + (size_t)C;
    const gs_rec_arena *ar = r->arenas + tr->worker;
    const uint32_t *hdr = ar->hdr + tr->off;
    const float *vis = ar->vis + tr->off * L;
    size_t end = tr->n;
    for (uint32_t k = ti->e; k-- > ti->s && k + PREFETCH_AHEAD >= ti->e;)
        prefetch_pair(r, k, ti->s, ti->e);
    for (uint32_t k = ti->e; k-- > ti->s;) {
        prefetch_pair(r, k - PREFETCH_AHEAD, ti->s, ti->e);
        float *slot = r->slots + (k - ctx->slot0) * stride;
        uint32_t pl = k - ti->s;
        size_t beg = end;
        while (beg > 0 && hdr[beg - 1] >> GROUP_BITS == pl)
            beg--;
        if (beg == end) {
            slot[GS_SLOT_HEAD - 1] = 0.0f; /* untouched */
            continue;
        }
        uint32_t i = r->isect[k];
        pair_grad(r->splats + i, r->g.features + (size_t)i * (size_t)C, C, (float)ti->x0,
                  (float)ti->y0, st, buf, vpix, hdr + beg, vis + beg * L, end - beg, slot, nv);
        end = beg;
    }
}

/* The same for a tile without records: each pair's window is evaluated
 * again (the forward's code, so the same groups and exponentials) into
 * records of the pair, which then take the replay's way. */
static inline __attribute__((always_inline)) void
evaluate_pairs(bwd_ctx *ctx, const tile_info *ti, const bwd_state *st, vf *buf, const vf *vpix,
               const int nv)
{
    gs_raster *r = ctx->r;
    const int C = r->g.channels;
    const size_t stride = GS_SLOT_HEAD + (size_t)C;
    uint32_t hdr[NGROUPS];
    float vis[TPIX] __attribute__((aligned(64)));
    for (uint32_t k = ti->e; k-- > ti->s && k + PREFETCH_AHEAD >= ti->e;)
        prefetch_pair(r, k, ti->s, ti->e);
    for (uint32_t k = ti->e; k-- > ti->s;) {
        prefetch_pair(r, k - PREFETCH_AHEAD, ti->s, ti->e);
        uint32_t i = r->isect[k];
        const gs_splat *sp = r->splats + i;
        float *slot = r->slots + (k - ctx->slot0) * stride;
        slot[GS_SLOT_HEAD - 1] = 0.0f;
        int r0, r1, g0, g1;
        if (!splat_window(sp, ti, &r0, &r1, &g0, &g1))
            continue;
        float mx = sp->mx - (float)ti->x0, my = sp->my - (float)ti->y0;
        vi pos = (vi){0} + (int32_t)(k - ti->s);
        size_t nrec = 0;
        for (int by = r0; by <= r1; by++) {
            vf dy = group_dy(my, by);
            for (int gi = g0; gi <= g1; gi++) {
                int v = by * GX + gi;
                vi before_last = pos < st->last[v];
                if (!any(before_last))
                    continue; /* behind every pixel's last contributor */
                group_eval ge;
                if (!group_sigma(&ge, mx, dy, sp->a, sp->b, sp->c, sp->thr, (float)(gi * GW),
                                 before_last))
                    continue;
                group_alpha(&ge, sp->op);
                vi valid = ge.ok & before_last;
                if (!any(valid))
                    continue;
                vf rv = vsel(valid, ge.vis, splat(-1.0f));
                hdr[nrec] = (uint32_t)v;
                memcpy(vis + nrec * L, &rv, sizeof rv);
                nrec++;
            }
        }
        if (!nrec)
            continue;
        pair_grad(sp, r->g.features + (size_t)i * (size_t)C, C, (float)ti->x0, (float)ti->y0,
                  st, buf, vpix, hdr, vis, nrec, slot, nv);
    }
}

static inline __attribute__((always_inline)) void
tile_backward_nv(bwd_ctx *ctx, int task, int worker, const int nv)
{
    gs_raster *r = ctx->r;
    const int NV = TPIX / L;
    int tile = (int)r->tile_order[task];
    tile_info ti = get_tile(r, tile);

    vf *buf = (vf *)((float *)r->scratch + (size_t)worker * ctx->per_worker); /* TPIX x nv */
    vf *vpix = buf + (size_t)nv * TPIX;                                       /* TPIX x nv */
    bwd_state st;
    st.T = vpix + (size_t)nv * TPIX;
    st.tfin = st.T + NV;
    st.vres = st.tfin + NV;
    st.vdep = st.vres + NV;
    st.bufd = st.vdep + NV;
    st.last = (void *)(st.bufd + NV);

    /* vpix needs no clearing: load_tile fills every pixel of the image and
     * pixels outside it are never valid (their last contributor is 0). */
    memset(buf, 0, (size_t)nv * TPIX * sizeof(vf));
    for (int v = 0; v < NV; v++) {
        st.T[v] = st.tfin[v] = st.vres[v] = st.vdep[v] = st.bufd[v] = splat(0.0f);
        st.last[v] = (vi){0};
    }
    load_tile(ctx, &ti, vpix, &st, nv);
    const gs_tile_rec *tr = r->tile_rec + tile;
    if (tr->n != GS_REC_NONE)
        replay_pairs(ctx, &ti, tr, &st, buf, vpix, nv);
    else
        evaluate_pairs(ctx, &ti, &st, buf, vpix, nv);
}

static void tile_backward(void *vctx, int task, int worker)
{
    bwd_ctx *ctx = vctx;
    switch ((ctx->r->g.channels + L - 1) / L) {
    case 1: tile_backward_nv(ctx, task, worker, 1); break;
    case 2: tile_backward_nv(ctx, task, worker, 2); break;
    case 3: tile_backward_nv(ctx, task, worker, 3); break;
    case 4: tile_backward_nv(ctx, task, worker, 4); break;
#if MAX_NV > 4
    case 5: tile_backward_nv(ctx, task, worker, 5); break;
    case 6: tile_backward_nv(ctx, task, worker, 6); break;
    case 7: tile_backward_nv(ctx, task, worker, 7); break;
#endif
    default: tile_backward_nv(ctx, task, worker, MAX_NV); break;
    }
}

static int fast_backward(gs_raster *r, gs_pool *pool, int t0, int t1, size_t slot0,
                         const float *v_f, const float *v_alpha, const float *v_depth,
                         float *v_bg)
{
    size_t per = scratch_per_worker(r->g.channels);
    if (reserve_scratch(r, pool, per)) /* the pool may differ from the forward's */
        return GS_ERR_NOMEM;
    if (order_tiles(r, t0, t1, 0, NULL))
        return GS_ERR_NOMEM;
    bwd_ctx ctx = {r, slot0, per, v_f, v_alpha, v_depth, v_bg};
    gs_pool_for(pool, t1 - t0, tile_backward, &ctx);
    return GS_OK;
}

/* 1 when every value is finite. x * 0 is 0 for finite x and NaN otherwise;
 * four vectors of running sums keep the loop vectorized and the adds
 * independent (one chain would wait on the add's latency every vector:
 * this runs before every forward, over every parameter and feature). */
static int all_finite(const float *x, size_t n)
{
    vf acc[4] = {splat(0.0f), splat(0.0f), splat(0.0f), splat(0.0f)};
    size_t i = 0;
    for (; i + 4 * L <= n; i += 4 * L)
        for (int k = 0; k < 4; k++) {
            vf v;
            memcpy(&v, x + i + (size_t)k * L, sizeof v);
            acc[k] += v * splat(0.0f);
        }
    for (; i + L <= n; i += L) {
        vf v;
        memcpy(&v, x + i, sizeof v);
        acc[0] += v * splat(0.0f);
    }
    float s = hsum((acc[0] + acc[1]) + (acc[2] + acc[3]));
    for (; i < n; i++)
        s += x[i] * 0.0f;
    return s == 0.0f;
}

#include "raster_proj.c"

#if L == 16
#define KERNELS_NAME "avx512"
#elif defined(__AVX2__)
#define KERNELS_NAME "avx2"
#else
#define KERNELS_NAME "generic"
#endif

const gs_raster_kernels GS_KERNELS = {KERNELS_NAME, fast_forward, fast_backward, all_finite, project_fast,
                                      project_backward_fast};
