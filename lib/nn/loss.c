/* Losses: masked L1 and SSIM (see nn.h for the exact definitions). */
#include "gazesplat/nn.h"
#include "nn_internal.h"

#include <math.h>
#include <stdint.h>
#include <string.h>

#include "gazesplat/pool.h"

/* loss = sum_{c,p} m_p |a - b| / (C*HW) for a, b [C,HW], mask [HW] or NULL */
int gs_nn_l1_forward(float *loss, const float *a, const float *b,
                     const float *mask, int C, int HW)
{
    int n;
    if (!loss || !a || !b || C < 1 || HW < 1)
        return GS_ERR_ARG;
    if (!nn_mul(C, HW, &n))
        return GS_ERR_LIMIT;
    double sum = 0.0;
    for (int c = 0; c < C; c++) {
        const float *ac = a + (size_t)c * (size_t)HW;
        const float *bc = b + (size_t)c * (size_t)HW;
        for (int p = 0; p < HW; p++) {
            double d = fabs((double)ac[p] - bc[p]);
            sum += mask ? mask[p] * d : d;
        }
    }
    *loss = (float)(sum / n);
    return GS_OK;
}

/* da[C,HW] += dloss * m_p * sign(a - b) / (C*HW) */
int gs_nn_l1_backward(float *da, float dloss, const float *a, const float *b,
                      const float *mask, int C, int HW)
{
    int n;
    if (!da || !a || !b || C < 1 || HW < 1 || !isfinite(dloss))
        return GS_ERR_ARG;
    if (!nn_mul(C, HW, &n))
        return GS_ERR_LIMIT;
    float k = (float)((double)dloss / n);
    for (int c = 0; c < C; c++) {
        size_t off = (size_t)c * (size_t)HW;
        for (int p = 0; p < HW; p++) {
            float d = a[off + p] - b[off + p];
            float g = d > 0.0f ? k : (d < 0.0f ? -k : 0.0f);
            da[off + p] += mask ? mask[p] * g : g;
        }
    }
    return GS_OK;
}

/* ---- SSIM ---------------------------------------------------------------
 * Per channel, five window statistics (mx, my, Exx, Eyy, Exy) come from a
 * separable Gaussian filter: a horizontal pass over every row into [H,Wo],
 * then a vertical pass into [Ho,Wo]. Out-of-image taps read zero (only
 * with GS_NN_SSIM_ZERO). The backward pass applies the adjoint passes to
 * the three gradient maps d/dmx, d/dExx, d/dExy. */

enum { WIN = 11, NSTAT = 5 };
#define SSIM_C1 (0.01f * 0.01f)
#define SSIM_C2 (0.03f * 0.03f)

typedef struct {
    int H, W, Ho, Wo, pad;
    float g[WIN];
    float *hmap;  /* NSTAT x [H,Wo] */
    float *vmap;  /* NSTAT x [Ho,Wo] */
} ssim_ctx;

/* Output size and padding, GS_ERR_ARG when the window does not fit. */
static int ssim_geometry(ssim_ctx *s, int H, int W, int padding)
{
    int t;
    if (padding != GS_NN_SSIM_VALID && padding != GS_NN_SSIM_ZERO)
        return GS_ERR_ARG;
    if (H < 1 || W < 1 || H > INT_MAX - WIN || W > INT_MAX - WIN)
        return GS_ERR_ARG;
    s->pad = padding == GS_NN_SSIM_ZERO ? WIN / 2 : 0;
    s->H = H;
    s->W = W;
    s->Ho = H + 2 * s->pad - (WIN - 1);
    s->Wo = W + 2 * s->pad - (WIN - 1);
    if (s->Ho < 1 || s->Wo < 1)
        return GS_ERR_ARG;
    if (!nn_mul(H, W, &t) || !nn_mul(H, s->Wo, &t) || !nn_mul(t, NSTAT, &t) ||
        !nn_mul(s->Ho, s->Wo, &t) || !nn_mul(t, NSTAT, &t))
        return GS_ERR_LIMIT;
    return GS_OK;
}

size_t gs_nn_ssim_scratch_size(int H, int W, int padding)
{
    ssim_ctx s;
    if (ssim_geometry(&s, H, W, padding) != GS_OK)
        return 0;
    return (size_t)NSTAT * ((size_t)H * (size_t)s.Wo + (size_t)s.Ho * (size_t)s.Wo);
}

static int ssim_setup(ssim_ctx *s, int C, int H, int W, int padding,
                      float *scratch, size_t scratch_len)
{
    int rc = ssim_geometry(s, H, W, padding);
    if (rc)
        return rc;
    if (C < 1 || !scratch || scratch_len < gs_nn_ssim_scratch_size(H, W, padding))
        return GS_ERR_ARG;
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

/* The passes below work on a range of rows of one channel, so that the
 * single-threaded entry points and the pooled one run the same code: hmap
 * and vmap are the channel's NSTAT slots (strides H*Wo and Ho*Wo). Each
 * output element is computed by the same operations in the same order
 * whichever range it falls in. */

/* Four lanes (GCC's generic vectors: one SSE register on x86-64, one NEON
 * register on arm64). Each lane does what the scalar loop does for its
 * element, in the same order, and the build never contracts a * b + c into
 * one rounding (-std=c11: -ffp-contract=off), so the vector and scalar
 * paths give the same bits. Loads and stores go through memcpy (any
 * alignment). */
typedef float vf __attribute__((vector_size(16)));
enum { VL = 4 };

static inline vf v_load(const float *p)
{
    vf v;
    memcpy(&v, p, sizeof v);
    return v;
}

static inline void v_store(float *p, vf v)
{
    memcpy(p, &v, sizeof v);
}

/* The five horizontal statistics at position xo of a row, taps outside
 * the row skipped; out[q * hsz]. */
static void stats_h_at(const ssim_ctx *s, const float *xr, const float *yr, int xo, float *out,
                       size_t hsz)
{
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
    for (int q = 0; q < NSTAT; q++)
        out[q * hsz] = acc[q];
}

/* Horizontal pass: hmap rows [r0, r1) from rows of x, y [H,W]. Positions
 * whose window lies inside the row ([pad, Wo - pad)) go four at a time,
 * the ones at the edges one at a time. */
static void stats_h_rows(const ssim_ctx *s, const float *x, const float *y, float *hmap, int r0,
                         int r1)
{
    size_t hsz = (size_t)s->H * (size_t)s->Wo;
    int in0 = s->pad, in1 = s->Wo - s->pad;
    for (int r = r0; r < r1; r++) {
        const float *xr = x + (size_t)r * (size_t)s->W;
        const float *yr = y + (size_t)r * (size_t)s->W;
        float *hr = hmap + (size_t)r * (size_t)s->Wo;
        int xo = 0;
        for (; xo < in0 && xo < s->Wo; xo++)
            stats_h_at(s, xr, yr, xo, hr + xo, hsz);
        for (; xo + VL <= in1; xo += VL) {
            vf acc[NSTAT] = {{0}};
            for (int k = 0; k < WIN; k++) {
                vf a = v_load(xr + xo + k - s->pad), b = v_load(yr + xo + k - s->pad);
                float g = s->g[k];
                acc[0] += g * a;
                acc[1] += g * b;
                acc[2] += g * a * a;
                acc[3] += g * b * b;
                acc[4] += g * a * b;
            }
            for (int q = 0; q < NSTAT; q++)
                v_store(hr + q * hsz + xo, acc[q]);
        }
        for (; xo < s->Wo; xo++)
            stats_h_at(s, xr, yr, xo, hr + xo, hsz);
    }
}

/* dst[0, n) = sum over the taps, in order, of g[t] src[t][0, n): from 0,
 * as the scalar "dst = 0; dst += g src" loops add. */
static void taps_sum(float *dst, const float *const *src, const float *g, int ntaps, int n)
{
    int i = 0;
    for (; i + 4 * VL <= n; i += 4 * VL) { /* four independent sums in flight */
        vf a0 = {0}, a1 = {0}, a2 = {0}, a3 = {0};
        for (int t = 0; t < ntaps; t++) {
            const float *p = src[t] + i;
            float w = g[t];
            a0 += w * v_load(p);
            a1 += w * v_load(p + VL);
            a2 += w * v_load(p + 2 * VL);
            a3 += w * v_load(p + 3 * VL);
        }
        v_store(dst + i, a0);
        v_store(dst + i + VL, a1);
        v_store(dst + i + 2 * VL, a2);
        v_store(dst + i + 3 * VL, a3);
    }
    for (; i + VL <= n; i += VL) {
        vf acc = {0};
        for (int t = 0; t < ntaps; t++)
            acc += g[t] * v_load(src[t] + i);
        v_store(dst + i, acc);
    }
    for (; i < n; i++) {
        float acc = 0.0f;
        for (int t = 0; t < ntaps; t++)
            acc += g[t] * src[t][i];
        dst[i] = acc;
    }
}

/* Vertical pass: vmap rows [y0, y1) from hmap. */
static void stats_v_rows(const ssim_ctx *s, const float *hmap, float *vmap, int y0, int y1)
{
    size_t hsz = (size_t)s->H * (size_t)s->Wo, vsz = (size_t)s->Ho * (size_t)s->Wo;
    for (int q = 0; q < NSTAT; q++) {
        const float *h = hmap + q * hsz;
        float *v = vmap + q * vsz;
        for (int yo = y0; yo < y1; yo++) {
            const float *src[WIN];
            float g[WIN];
            int n = 0;
            for (int k = 0; k < WIN; k++) {
                int r = yo + k - s->pad;
                if (r < 0 || r >= s->H)
                    continue;
                src[n] = h + (size_t)r * (size_t)s->Wo;
                g[n++] = s->g[k];
            }
            taps_sum(v + (size_t)yo * (size_t)s->Wo, src, g, n, s->Wo);
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

/* SSIM at one position, in double: the loss's summand. */
static double ssim_value(const ssim_terms *t)
{
    return (double)(t->a1 * t->a2) / (double)(t->b1 * t->b2);
}

/* Rows [y0, y1) of vmap: each position's SSIM into val (when not NULL),
 * and, when grad, vmap slots 0, 2, 4 overwritten with w dS/dmx, w dS/dExx,
 * w dS/dExy. */
static void ssim_rows(const ssim_ctx *s, float *vmap, double *val, int grad, float w, int y0,
                      int y1)
{
    size_t vsz = (size_t)s->Ho * (size_t)s->Wo;
    float *v = vmap;
    for (size_t i = (size_t)y0 * (size_t)s->Wo; i < (size_t)y1 * (size_t)s->Wo; i++) {
        float mx = v[i], my = v[vsz + i];
        ssim_terms t = ssim_at(mx, my, v[2 * vsz + i], v[3 * vsz + i], v[4 * vsz + i]);
        if (val)
            val[i] = ssim_value(&t);
        if (grad) {
            float den = t.b1 * t.b2, S = t.a1 * t.a2 / den;
            v[i] = w * (2.0f * my * (t.a2 - t.a1) / den +
                        2.0f * mx * S * (1.0f / t.b2 - 1.0f / t.b1));
            v[2 * vsz + i] = w * (-S / t.b2);
            v[4 * vsz + i] = w * (2.0f * t.a1 / den);
        }
    }
}

/* dr[c] += the horizontal adjoint at column c of one row, taps outside the
 * positions skipped. */
static void adjoint_h_at(const ssim_ctx *s, const float *gm, const float *gxx, const float *gxy,
                         const float *xr, const float *yr, int c, float *dr)
{
    float t1 = 0.0f, t2 = 0.0f, t3 = 0.0f;
    for (int k = 0; k < WIN; k++) {
        int xo = c - k + s->pad;
        if (xo < 0 || xo >= s->Wo)
            continue;
        t1 += s->g[k] * gm[xo];
        t2 += s->g[k] * gxx[xo];
        t3 += s->g[k] * gxy[xo];
    }
    dr[c] += t1 + 2.0f * xr[c] * t2 + yr[c] * t3;
}

/* Backward, rows [r0, r1) of the channel: hmap slots 0, 2, 4 take the
 * vertical adjoint of vmap's gradient maps (gathered per row: the sum runs
 * over yo ascending, the order the scatter form adds in), then
 * dx += the horizontal adjoint of (Gmx + 2x GExx + y GExy). */
static void adjoint_rows(const ssim_ctx *s, const float *vmap, float *hmap, float *dx,
                         const float *x, const float *y, int r0, int r1)
{
    size_t hsz = (size_t)s->H * (size_t)s->Wo, vsz = (size_t)s->Ho * (size_t)s->Wo;
    for (int r = r0; r < r1; r++) {
        size_t hrow = (size_t)r * (size_t)s->Wo;
        int ylo = r + s->pad - (WIN - 1), yhi = r + s->pad;
        if (ylo < 0)
            ylo = 0;
        if (yhi > s->Ho - 1)
            yhi = s->Ho - 1;
        for (int q = 0; q <= 4; q += 2) {
            const float *src[WIN];
            float g[WIN];
            int n = 0;
            for (int yo = ylo; yo <= yhi; yo++) {
                src[n] = vmap + q * vsz + (size_t)yo * (size_t)s->Wo;
                g[n++] = s->g[r - yo + s->pad];
            }
            taps_sum(hmap + q * hsz + hrow, src, g, n, s->Wo);
        }
        const float *gm = hmap + hrow, *gxx = hmap + 2 * hsz + hrow, *gxy = hmap + 4 * hsz + hrow;
        size_t row = (size_t)r * (size_t)s->W;
        const float *xr = x + row, *yr = y + row;
        float *dr = dx + row;
        /* columns whose taps all fall on positions, [WIN - 1 - pad, Wo - pad),
         * four at a time; the ones at the edges one at a time */
        int in0 = WIN - 1 - s->pad, in1 = s->Wo - s->pad, c = 0;
        for (; c < in0 && c < s->W; c++)
            adjoint_h_at(s, gm, gxx, gxy, xr, yr, c, dr);
        for (; c + VL <= in1; c += VL) {
            vf t1 = {0}, t2 = {0}, t3 = {0};
            for (int k = 0; k < WIN; k++) {
                int xo = c - k + s->pad;
                float g = s->g[k];
                t1 += g * v_load(gm + xo);
                t2 += g * v_load(gxx + xo);
                t3 += g * v_load(gxy + xo);
            }
            vf d = v_load(dr + c);
            d += t1 + 2.0f * v_load(xr + c) * t2 + v_load(yr + c) * t3;
            v_store(dr + c, d);
        }
        for (; c < s->W; c++)
            adjoint_h_at(s, gm, gxx, gxy, xr, yr, c, dr);
    }
}

/* loss = 1 - mean SSIM of x vs y [C,H,W] */
int gs_nn_ssim_loss_forward(float *loss, const float *x, const float *y,
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
        stats_h_rows(&s, x + (size_t)c * hw, y + (size_t)c * hw, s.hmap, 0, s.H);
        stats_v_rows(&s, s.hmap, s.vmap, 0, s.Ho);
        const float *v = s.vmap;
        for (size_t i = 0; i < vsz; i++) {
            ssim_terms t = ssim_at(v[i], v[vsz + i], v[2 * vsz + i],
                                   v[3 * vsz + i], v[4 * vsz + i]);
            sum += ssim_value(&t);
        }
    }
    *loss = (float)(1.0 - sum / ((double)C * (double)vsz));
    return GS_OK;
}

/* dx[C,H,W] += dloss * d(1 - mean SSIM)/dx */
int gs_nn_ssim_loss_backward(float *dx, float dloss, const float *x,
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
        stats_h_rows(&s, xc, yc, s.hmap, 0, s.H);
        stats_v_rows(&s, s.hmap, s.vmap, 0, s.Ho);
        ssim_rows(&s, s.vmap, NULL, 1, w, 0, s.Ho);
        adjoint_rows(&s, s.vmap, s.hmap, dx + (size_t)c * hw, xc, yc, 0, s.H);
    }
    return GS_OK;
}

/* ---- SSIM on a pool: channel by channel, in bands of rows --------------- */

enum { SSIM_BAND = 8 }; /* rows per task: a fixed partition, whatever the thread count */

size_t gs_nn_ssim_fused_scratch_size(int C, int H, int W, int padding)
{
    size_t one = gs_nn_ssim_scratch_size(H, W, padding);
    ssim_ctx s;
    if (!one || C < 1 || ssim_geometry(&s, H, W, padding) != GS_OK)
        return 0;
    size_t vsz = (size_t)s.Ho * (size_t)s.Wo;
    /* one channel's maps (the channels take turns: they stay in cache),
     * then its SSIM values as doubles (+1: alignment) */
    return one + 2 * vsz + 1;
}

typedef struct {
    const ssim_ctx *s;
    const float *x, *y; /* this channel's */
    float *dx;
    float w;
    int grad;
    float *hmap, *vmap;
    double *val; /* [Ho*Wo] */
} ssim_job;

static void band(int b, int n, int *r0, int *r1)
{
    *r0 = b * SSIM_BAND;
    *r1 = *r0 + SSIM_BAND < n ? *r0 + SSIM_BAND : n;
}

static void ssim_h_task(void *ctx, int task, int worker)
{
    (void)worker;
    const ssim_job *j = ctx;
    int r0, r1;
    band(task, j->s->H, &r0, &r1);
    stats_h_rows(j->s, j->x, j->y, j->hmap, r0, r1);
}

static void ssim_v_task(void *ctx, int task, int worker)
{
    (void)worker;
    const ssim_job *j = ctx;
    int y0, y1;
    band(task, j->s->Ho, &y0, &y1);
    stats_v_rows(j->s, j->hmap, j->vmap, y0, y1);
    ssim_rows(j->s, j->vmap, j->val, j->grad, j->w, y0, y1);
}

static void ssim_adjoint_task(void *ctx, int task, int worker)
{
    (void)worker;
    const ssim_job *j = ctx;
    int r0, r1;
    band(task, j->s->H, &r0, &r1);
    adjoint_rows(j->s, j->vmap, j->hmap, j->dx, j->x, j->y, r0, r1);
}

int gs_nn_ssim_loss_fused(struct gs_pool *pool, float *loss, float *dx, float dloss,
                          const float *x, const float *y, int C, int H, int W, int padding,
                          float *scratch, size_t scratch_len)
{
    ssim_ctx s;
    int rc = ssim_geometry(&s, H, W, padding);
    if (rc)
        return rc;
    size_t need = gs_nn_ssim_fused_scratch_size(C, H, W, padding);
    if (!need || !scratch || scratch_len < need || !loss || !x || !y ||
        (dx && !isfinite(dloss)))
        return GS_ERR_ARG;
    /* the window and the maps, as ssim_setup makes them */
    rc = ssim_setup(&s, 1, H, W, padding, scratch, scratch_len);
    if (rc)
        return rc;
    size_t hw = (size_t)H * (size_t)W, vsz = (size_t)s.Ho * (size_t)s.Wo;
    uintptr_t at = (uintptr_t)(s.vmap + (size_t)NSTAT * vsz);
    at = (at + sizeof(double) - 1) & ~(uintptr_t)(sizeof(double) - 1);
    ssim_job j = {&s, NULL, NULL, NULL, 0.0f, dx != NULL, s.hmap, s.vmap, (double *)at};
    if (dx)
        j.w = (float)(-(double)dloss / ((double)C * s.Ho * s.Wo));
    int hb = (H + SSIM_BAND - 1) / SSIM_BAND, vb = (s.Ho + SSIM_BAND - 1) / SSIM_BAND;
    /* the sum in the single-threaded order: channel by channel, position by position */
    double sum = 0.0;
    for (int c = 0; c < C; c++) {
        j.x = x + (size_t)c * hw;
        j.y = y + (size_t)c * hw;
        j.dx = dx ? dx + (size_t)c * hw : NULL;
        gs_pool_for(pool, hb, ssim_h_task, &j);
        gs_pool_for(pool, vb, ssim_v_task, &j);
        for (size_t i = 0; i < vsz; i++)
            sum += j.val[i];
        if (dx)
            gs_pool_for(pool, hb, ssim_adjoint_task, &j);
    }
    *loss = (float)(1.0 - sum / ((double)C * (double)vsz));
    return GS_OK;
}
