/* Fast compositing: tiles in parallel, each tile walked Gaussian by Gaussian
 * (front to back, or back to front in the backward pass) over the rows and
 * 8-pixel groups that the Gaussian's alpha >= 1/255 ellipse can reach, with
 * 8 pixels per vector. Built once per instruction set (GS_KERNELS names the
 * table): GCC vector extensions map to AVX2 or SSE2.
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

#define L 8 /* lanes */
#define TS GS_RASTER_TILE
#define TPIX (TS * TS)
#define GROUPS (TS / L)

typedef float vf __attribute__((vector_size(32), aligned(32)));
typedef int32_t vi __attribute__((vector_size(32), aligned(32)));

static inline vf splat(float x)
{
    return (vf){x, x, x, x, x, x, x, x};
}

/* m ? a : b per lane (C has no vector ?:). */
static inline vf vsel(vi m, vf a, vf b)
{
    return (vf)(((vi)a & m) | ((vi)b & ~m));
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

#ifdef __AVX2__
#include <immintrin.h>
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

/* Lane sum in a fixed order (pairwise), the same on every path. */
static inline float hsum(vf v)
{
    return ((v[0] + v[4]) + (v[2] + v[6])) + ((v[1] + v[5]) + (v[3] + v[7]));
}

/* exp(x) for x <= 0: Cody-Waite reduction x = n ln2 + r, degree-6 minimax
 * polynomial for exp(r) on |r| <= ln2/2, scaling by 2^n through the
 * exponent bits. Below -87 returns 0 (alpha < 1/255 there anyway). */
static inline vf vexp_neg(vf x)
{
    vi tiny = x < splat(-87.0f);
    x = vmax(x, splat(-87.0f));
    vf fx = x * splat(1.44269504088896341f) + splat(0.5f);
    vi n = __builtin_convertvector(fx, vi); /* truncates toward zero */
    vf nf = __builtin_convertvector(n, vf);
    n += (vi)(nf > fx);                    /* -> floor (true is -1) */
    nf = __builtin_convertvector(n, vf);
    vf r = x - nf * splat(0.693359375f) - nf * splat(-2.12194440e-4f);
    vf r2 = r * r;
    vf p = splat(1.9875691500e-4f);
    p = p * r + splat(1.3981999507e-3f);
    p = p * r + splat(8.3334519073e-3f);
    p = p * r + splat(4.1665795894e-2f);
    p = p * r + splat(1.6666665459e-1f);
    p = p * r + splat(5.0000001201e-1f);
    p = p * r2 + r + splat(1.0f);
    vi bits = (n + 127) << 23;
    vf scale;
    memcpy(&scale, &bits, sizeof scale);
    return vsel(tiny, splat(0.0f), p * scale);
}

/* Lane offsets 0.5, 1.5, ... 7.5: pixel centres of a group. */
static const vf lane_centre = {0.5f, 1.5f, 2.5f, 3.5f, 4.5f, 5.5f, 6.5f, 7.5f};

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

/* Rows [*r0, *r1] and groups [*g0, *g1] of the tile that Gaussian i's
 * ellipse can reach; returns 0 when none. */
static int splat_window(const gs_proj *P, uint32_t i, const tile_info *ti, int *r0, int *r1,
                        int *g0, int *g1)
{
    float mx = P->mean2d[2 * i] - (float)ti->x0 - 0.5f;
    float my = P->mean2d[2 * i + 1] - (float)ti->y0 - 0.5f;
    float ex = P->extent[2 * i], ey = P->extent[2 * i + 1];
    float fy0 = ceilf(my - ey), fy1 = floorf(my + ey);
    float fx0 = ceilf(mx - ex), fx1 = floorf(mx + ex);
    if (fy1 < 0 || fx1 < 0 || fy0 > (float)(ti->h - 1) || fx0 > (float)(ti->w - 1))
        return 0;
    *r0 = fy0 > 0 ? (int)fy0 : 0;
    *r1 = fy1 < (float)(ti->h - 1) ? (int)fy1 : ti->h - 1;
    int c0 = fx0 > 0 ? (int)fx0 : 0;
    int c1 = fx1 < (float)(ti->w - 1) ? (int)fx1 : ti->w - 1;
    *g0 = c0 / L;
    *g1 = c1 / L;
    return *r0 <= *r1 && c0 <= c1;
}

/* Per-lane sigma, exp(-sigma) and alpha of one splat on one group. */
typedef struct {
    vf dx, sigma, vis, alpha;
    vi ok; /* sigma >= 0 and alpha >= 1/255 */
} group_eval;

static inline group_eval eval_group(float mx, float dy, float a, float b, float c, float op,
                                    float gx)
{
    group_eval g;
    g.dx = splat(mx - gx) - lane_centre;
    g.sigma = splat(0.5f) * (splat(a) * g.dx * g.dx + splat(c * dy * dy)) + splat(b * dy) * g.dx;
    g.vis = vexp_neg(-g.sigma);
    g.alpha = vmin(splat(GS_RASTER_MAX_ALPHA), splat(op) * g.vis);
    g.ok = (g.sigma >= splat(0.0f)) & (g.alpha >= splat(GS_RASTER_MIN_ALPHA));
    return g;
}

/* ---- forward ------------------------------------------------------------ */

typedef struct {
    gs_raster *r;
    const float *bg;
    float *out_f, *out_alpha, *out_depth;
    size_t per_worker; /* floats of scratch per worker */
    _Atomic size_t contributions; /* integer sum: order-independent */
} fwd_ctx;

static void tile_forward(void *vctx, int t, int worker)
{
    fwd_ctx *ctx = vctx;
    gs_raster *r = ctx->r;
    const gs_proj *P = &r->proj;
    const int C = r->g.channels, W = r->cam.width;
    const size_t HW = (size_t)W * (size_t)r->cam.height;
    tile_info ti = get_tile(r, t);

    float *scratch = (float *)r->scratch + (size_t)worker * ctx->per_worker;
    vf *acc = (vf *)scratch;              /* C x TPIX */
    vf *Tv = acc + (size_t)C * TPIX / L;  /* TPIX */
    vf *dep = Tv + TPIX / L;              /* TPIX */
    vi *last = (void *)(dep + TPIX / L);  /* TPIX */
    vi *alive = last + TPIX / L;          /* TPIX */
    int row_alive[TS];
    int tile_alive = 0;
    size_t contributions = 0;
    memset(acc, 0, (size_t)C * TPIX * sizeof(float));
    for (int row = 0; row < TS; row++) {
        row_alive[row] = row < ti.h ? ti.w : 0;
        tile_alive += row_alive[row];
        for (int gi = 0; gi < GROUPS; gi++) {
            int v = row * GROUPS + gi;
            Tv[v] = splat(1.0f);
            dep[v] = splat(0.0f);
            last[v] = (vi){0};
            for (int j = 0; j < L; j++)
                alive[v][j] = (row < ti.h && gi * L + j < ti.w) ? -1 : 0;
        }
    }

    for (uint32_t k = ti.s; k < ti.e && tile_alive > 0; k++) {
        uint32_t i = r->isect[k];
        int r0, r1, g0, g1;
        if (!splat_window(P, i, &ti, &r0, &r1, &g0, &g1))
            continue;
        const float *q = P->conic + 3 * i, *f = r->g.features + (size_t)i * C;
        float mx = P->mean2d[2 * i] - (float)ti.x0, op = P->opacity[i], z = P->depth[i];
        float my = P->mean2d[2 * i + 1] - (float)ti.y0;
        vi pos = (vi){0} + (int32_t)(k - ti.s + 1);
        for (int row = r0; row <= r1; row++) {
            if (!row_alive[row])
                continue;
            float dy = my - ((float)row + 0.5f);
            for (int gi = g0; gi <= g1; gi++) {
                int v = row * GROUPS + gi;
                if (!any(alive[v]))
                    continue; /* every pixel here has stopped */
                group_eval ge = eval_group(mx, dy, q[0], q[1], q[2], op, (float)(gi * L));
                vi valid = ge.ok & alive[v];
                if (!any(valid))
                    continue;
                vf T = Tv[v];
                vf next_T = T * (splat(1.0f) - ge.alpha);
                vi stop = valid & (next_T <= splat(GS_RASTER_T_EPS));
                if (any(stop)) {
                    alive[v] &= ~stop;
                    valid &= ~stop;
                    int n = __builtin_popcount((unsigned)mask_bits(stop));
                    row_alive[row] -= n;
                    tile_alive -= n;
                }
                contributions += (size_t)__builtin_popcount((unsigned)mask_bits(valid));
                vf w = vsel(valid, ge.alpha * T, splat(0.0f));
                Tv[v] = vsel(valid, next_T, T);
                last[v] = vseli(valid, pos, last[v]);
                dep[v] += splat(z) * w;
                for (int ch = 0; ch < C; ch++)
                    acc[(size_t)ch * (TPIX / L) + v] += splat(f[ch]) * w;
            }
        }
    }

    atomic_fetch_add_explicit(&ctx->contributions, contributions, memory_order_relaxed);
    /* Write out row by row: acc holds each channel as a 16 x 16 block. */
    const float *bg = ctx->bg;
    const float *accf = (const float *)acc, *Tf = (const float *)Tv;
    const float *depf = (const float *)dep;
    const int32_t *lastf = (const int32_t *)last;
    for (int row = 0; row < ti.h; row++) {
        size_t pix0 = (size_t)(ti.y0 + row) * W + (size_t)ti.x0;
        const float *Trow = Tf + row * TS;
        for (int ch = 0; ch < C; ch++) {
            const float *a = accf + (size_t)ch * TPIX + row * TS;
            float *o = ctx->out_f + ch * HW + pix0;
            if (bg) {
                const float *b = bg + ch * HW + pix0;
                for (int col = 0; col < ti.w; col++)
                    o[col] = a[col] + Trow[col] * b[col];
            } else {
                memcpy(o, a, (size_t)ti.w * sizeof *o);
            }
        }
        for (int col = 0; col < ti.w; col++) {
            ctx->out_alpha[pix0 + col] = 1.0f - Trow[col];
            r->t_final[pix0 + col] = Trow[col];
            r->last[pix0 + col] = (uint32_t)lastf[row * TS + col];
        }
        if (ctx->out_depth)
            memcpy(ctx->out_depth + pix0, depf + row * TS, (size_t)ti.w * sizeof(float));
    }
}

static size_t fwd_scratch_floats(int C)
{
    return (size_t)(C + 4) * TPIX;
}

static size_t bwd_scratch_floats(int C)
{
    /* buf, vpix: C x TPIX each; T, tfin, vA-bgdot, vD, bufd, last: TPIX each;
     * partial sums: (GS_SLOT_HEAD + C) vectors */
    return (size_t)(2 * C + 6) * TPIX + (size_t)(GS_SLOT_HEAD + C) * L;
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

static int fast_forward(gs_raster *r, gs_pool *pool, const float *bg, float *out_f,
                        float *out_alpha, float *out_depth)
{
    size_t per = scratch_per_worker(r->g.channels);
    if (reserve_scratch(r, pool, per))
        return GS_ERR_NOMEM;
    fwd_ctx ctx = {r, bg, out_f, out_alpha, out_depth, per, 0};
    gs_pool_for(pool, r->tiles_x * r->tiles_y, tile_forward, &ctx);
    r->contributions = atomic_load(&ctx.contributions);
    return GS_OK;
}

/* ---- backward ----------------------------------------------------------- */

typedef struct {
    gs_raster *r;
    int t0;
    size_t slot0, per_worker;
    const float *v_f, *v_alpha, *v_depth;
    float *v_bg;
} bwd_ctx;

static void tile_backward(void *vctx, int task, int worker)
{
    bwd_ctx *ctx = vctx;
    gs_raster *r = ctx->r;
    const gs_proj *P = &r->proj;
    const int C = r->g.channels, W = r->cam.width;
    const size_t HW = (size_t)W * (size_t)r->cam.height, stride = GS_SLOT_HEAD + (size_t)C;
    const int NV = TPIX / L;
    tile_info ti = get_tile(r, ctx->t0 + task);

    vf *buf = (vf *)((float *)r->scratch + (size_t)worker * ctx->per_worker); /* C x NV */
    vf *vpix = buf + (size_t)C * NV;      /* C x NV */
    vf *Tv = vpix + (size_t)C * NV;       /* NV */
    vf *tfin = Tv + NV;
    vf *vres = tfin + NV;                 /* v_alpha - <bg, v_pix> */
    vf *vdep = vres + NV;
    vf *bufd = vdep + NV;
    vi *last = (void *)(bufd + NV);
    vf *part = (void *)(last + NV);       /* GS_SLOT_HEAD + C partial sums */

    memset(buf, 0, (size_t)C * TPIX * sizeof(float));
    memset(vpix, 0, (size_t)C * TPIX * sizeof(float));
    for (int v = 0; v < NV; v++) {
        Tv[v] = tfin[v] = vres[v] = vdep[v] = bufd[v] = splat(0.0f);
        last[v] = (vi){0};
    }
    /* Load the tile row by row; vpix holds each channel as a 16 x 16 block. */
    const float *bg = r->background;
    float *vpf = (float *)vpix, *Tf = (float *)Tv, *tff = (float *)tfin;
    float *vrf = (float *)vres, *vdf = (float *)vdep;
    int32_t *lastf = (int32_t *)last;
    for (int row = 0; row < ti.h; row++) {
        size_t pix0 = (size_t)(ti.y0 + row) * W + (size_t)ti.x0;
        float bg_dot[TS] = {0};
        for (int col = 0; col < ti.w; col++) {
            float T = r->t_final[pix0 + col];
            Tf[row * TS + col] = tff[row * TS + col] = T;
            vdf[row * TS + col] = ctx->v_depth ? ctx->v_depth[pix0 + col] : 0.0f;
            lastf[row * TS + col] = (int32_t)r->last[pix0 + col];
        }
        for (int ch = 0; ch < C; ch++) {
            const float *g = ctx->v_f + ch * HW + pix0;
            memcpy(vpf + (size_t)ch * TPIX + row * TS, g, (size_t)ti.w * sizeof *g);
            if (bg)
                for (int col = 0; col < ti.w; col++)
                    bg_dot[col] += bg[ch * HW + pix0 + col] * g[col];
            if (ctx->v_bg)
                for (int col = 0; col < ti.w; col++)
                    ctx->v_bg[ch * HW + pix0 + col] += Tf[row * TS + col] * g[col];
        }
        for (int col = 0; col < ti.w; col++)
            vrf[row * TS + col] = (ctx->v_alpha ? ctx->v_alpha[pix0 + col] : 0.0f) - bg_dot[col];
    }

    for (uint32_t k = ti.e; k-- > ti.s;) {
        uint32_t i = r->isect[k];
        float *slot = r->slots + (k - ctx->slot0) * stride;
        memset(slot, 0, stride * sizeof(float));
        int r0, r1, g0, g1;
        if (!splat_window(P, i, &ti, &r0, &r1, &g0, &g1))
            continue;
        const float *q = P->conic + 3 * i, *f = r->g.features + (size_t)i * C;
        float mx = P->mean2d[2 * i] - (float)ti.x0, op = P->opacity[i], z = P->depth[i];
        float my = P->mean2d[2 * i + 1] - (float)ti.y0;
        vi pos = (vi){0} + (int32_t)(k - ti.s);
        int touched = 0;
        for (size_t h = 0; h < stride; h++)
            part[h] = splat(0.0f);
        for (int row = r0; row <= r1; row++) {
            float dy = my - ((float)row + 0.5f);
            for (int gi = g0; gi <= g1; gi++) {
                int v = row * GROUPS + gi;
                vi before_last = pos < last[v];
                if (!any(before_last))
                    continue; /* behind every pixel's last contributor */
                group_eval ge = eval_group(mx, dy, q[0], q[1], q[2], op, (float)(gi * L));
                vi valid = ge.ok & before_last;
                if (!any(valid))
                    continue;
                touched = 1;
                vf ra = splat(1.0f) /
                        vmax(splat(1.0f) - ge.alpha, splat(GS_RASTER_ONE_MINUS_ALPHA_FLOOR));
                ra = vsel(valid, ra, splat(1.0f));
                vf T = Tv[v] * ra;
                Tv[v] = T;
                vf fac = vsel(valid, ge.alpha * T, splat(0.0f));
                /* Four running sums break the dependency chain over channels. */
                vf va4[4] = {splat(0.0f), splat(0.0f), splat(0.0f), splat(0.0f)};
                for (int ch = 0; ch < C; ch++) {
                    vf fc = splat(f[ch]), vp = vpix[(size_t)ch * NV + v];
                    vf *bc = &buf[(size_t)ch * NV + v];
                    va4[ch & 3] += (fc * T - *bc * ra) * vp;
                    *bc += fc * fac;
                    part[GS_SLOT_HEAD + ch] += fac * vp;
                }
                vf va = (va4[0] + va4[1]) + (va4[2] + va4[3]);
                va += tfin[v] * ra * vres[v] + vdep[v] * (splat(z) * T - bufd[v] * ra);
                bufd[v] += splat(z) * fac;
                part[6] += fac * vdep[v];
                vi grad_ok = valid & (splat(op) * ge.vis <= splat(GS_RASTER_MAX_ALPHA));
                va = vsel(grad_ok, va, splat(0.0f));
                vf vsig = -ge.alpha * va;
                vf dx = ge.dx, vdy = splat(dy);
                part[0] += vsig * (splat(q[0]) * dx + splat(q[1] * dy));
                part[1] += vsig * (splat(q[1]) * dx + splat(q[2] * dy));
                part[2] += splat(0.5f) * vsig * dx * dx;
                part[3] += vsig * dx * vdy;
                part[4] += splat(0.5f) * vsig * vdy * vdy;
                part[5] += ge.vis * va;
            }
        }
        if (touched)
            for (size_t h = 0; h < stride; h++)
                slot[h] = hsum(part[h]);
    }
}

static int fast_backward(gs_raster *r, gs_pool *pool, int t0, int t1, size_t slot0,
                         const float *v_f, const float *v_alpha, const float *v_depth,
                         float *v_bg)
{
    size_t per = scratch_per_worker(r->g.channels);
    if (reserve_scratch(r, pool, per)) /* the pool may differ from the forward's */
        return GS_ERR_NOMEM;
    bwd_ctx ctx = {r, t0, slot0, per, v_f, v_alpha, v_depth, v_bg};
    gs_pool_for(pool, t1 - t0, tile_backward, &ctx);
    return GS_OK;
}

/* 1 when every value is finite. x * 0 is 0 for finite x and NaN otherwise;
 * eight running sums keep the loop vectorizable. */
static int all_finite(const float *x, size_t n)
{
    vf acc = splat(0.0f);
    size_t i = 0;
    for (; i + L <= n; i += L) {
        vf v;
        memcpy(&v, x + i, sizeof v);
        acc += v * splat(0.0f);
    }
    float s = hsum(acc);
    for (; i < n; i++)
        s += x[i] * 0.0f;
    return s == 0.0f;
}

const gs_raster_kernels GS_KERNELS = {fast_forward, fast_backward, all_finite};
