/* Rasterizer front end: argument checks, projection and its gradient, depth
 * sort, tile binning, and the dispatch to the compositing paths. */
#define _POSIX_C_SOURCE 200809L /* clock_gettime */
#include <math.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "gazesplat/clock.h"
#include "raster_internal.h"

/* Upper bound on (tile, Gaussian) pairs in one render: 16M ids (64 MB). */
#define GS_RASTER_MAX_ISECT ((size_t)1 << 24)
/* Fast backward scratch is processed in batches of at most this many floats. */
#define GS_RASTER_SLOT_BUDGET ((size_t)1 << 22)

int gs_raster_reserve(void **buf, size_t *cap, size_t want, size_t elem)
{
    if (want <= *cap)
        return GS_OK;
    size_t n = *cap ? *cap : 64;
    while (n < want)
        n = n > SIZE_MAX / 2 ? want : n * 2;
    if (n > SIZE_MAX / elem)
        return GS_ERR_NOMEM;
    void *p = realloc(*buf, n * elem);
    if (!p)
        return GS_ERR_NOMEM;
    *buf = p;
    *cap = n;
    return GS_OK;
}

/* The fast path's kernel sets, best first, and whether this CPU runs each. */
static int kernels_supported(const gs_raster_kernels *k)
{
#if defined(__x86_64__) || defined(__i386__)
    if (k == &gs_raster_kernels_avx512)
        return __builtin_cpu_supports("avx512f") && __builtin_cpu_supports("avx512vl") &&
               __builtin_cpu_supports("avx512dq") && __builtin_cpu_supports("avx512bw") &&
               __builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma");
    if (k == &gs_raster_kernels_avx2)
        return __builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma");
#else
    if (k != &gs_raster_kernels_generic)
        return 0;
#endif
    return 1;
}

static const gs_raster_kernels *const all_kernels[] = {
    &gs_raster_kernels_avx512, &gs_raster_kernels_avx2, &gs_raster_kernels_generic};
#define N_KERNELS (sizeof all_kernels / sizeof *all_kernels)

static const gs_raster_kernels *best_kernels(void)
{
    for (size_t k = 0; k < N_KERNELS; k++)
        if (kernels_supported(all_kernels[k]))
            return all_kernels[k];
    return &gs_raster_kernels_generic;
}

/* The set called name ("auto": the best this CPU runs), or NULL when there
 * is none; the caller checks kernels_supported. */
static const gs_raster_kernels *kernels_named(const char *name)
{
    if (!strcmp(name, "auto"))
        return best_kernels();
    for (size_t k = 0; k < N_KERNELS; k++)
        if (!strcmp(name, all_kernels[k]->name))
            return all_kernels[k];
    return NULL;
}

gs_raster *gs_raster_create(void)
{
    gs_raster *r = calloc(1, sizeof(gs_raster));
    if (!r)
        return NULL;
    r->kern = best_kernels();
    const char *env = getenv("GS_RASTER_ISA");
    if (env && *env) {
        const gs_raster_kernels *k = kernels_named(env);
        if (k && kernels_supported(k))
            r->kern = k;
        else
            snprintf(r->isa_error, sizeof r->isa_error, "%.40s", env);
    }
    return r;
}

int gs_raster_set_isa(gs_raster *r, const char *isa, gs_error *err)
{
    if (!r || !isa)
        return gs_error_set(err, GS_ERR_ARG, "raster: no workspace or instruction set");
    const gs_raster_kernels *k = kernels_named(isa);
    if (!k)
        return gs_error_set(err, GS_ERR_ARG,
                            "raster: unknown instruction set '%s' (avx512, avx2, generic, auto)",
                            isa);
    if (!kernels_supported(k))
        return gs_error_set(err, GS_ERR_UNSUPPORTED,
                            "raster: this CPU cannot run instruction set '%s'", isa);
    r->kern = k;
    r->isa_error[0] = '\0';
    return GS_OK;
}

const char *gs_raster_isa(const gs_raster *r)
{
    return r ? r->kern->name : best_kernels()->name;
}

int gs_raster_set_frustum(gs_raster *r, const gs_camera *frustum,
                          gs_error *err)
{
    if (!r)
        return gs_error_set(err, GS_ERR_ARG, "raster: no workspace");
    r->has_frustum = 0;
    if (!frustum)
        return GS_OK;
    if (!(frustum->fx > 0.0f && frustum->fy > 0.0f && isfinite(frustum->fx) &&
          isfinite(frustum->fy) && isfinite(frustum->cx) && isfinite(frustum->cy)) ||
        frustum->width < 1 || frustum->height < 1 || frustum->width > GS_RASTER_MAX_SIZE ||
        frustum->height > GS_RASTER_MAX_SIZE)
        return gs_error_set(err, GS_ERR_ARG, "raster: bad frustum camera");
    r->frustum = *frustum;
    r->has_frustum = 1;
    return GS_OK;
}

void gs_raster_set_records(gs_raster *r, int on)
{
    if (r)
        r->no_records = !on;
}

void gs_raster_trim(gs_raster *r)
{
    if (!r)
        return;
    for (int w = 0; w < r->n_arenas; w++) {
        free(r->arenas[w].hdr);
        free(r->arenas[w].vis);
        memset(&r->arenas[w], 0, sizeof r->arenas[w]);
    }
    /* the last forward's tiles: not recorded, a backward evaluates them */
    for (size_t t = 0; r->tile_rec && t < r->cap_tile_rec; t++)
        r->tile_rec[t].n = GS_REC_NONE;
    free(r->slots);
    r->slots = NULL;
    r->cap_slots = 0;
}

void gs_raster_destroy(gs_raster *r)
{
    if (!r)
        return;
    free(r->n_block);
    free(r->splats);
    free(r->bin_counts);
    free(r->order);
    free(r->order_tmp);
    free(r->keys);
    free(r->keys_tmp);
    free(r->tile_off);
    free(r->tile_order);
    free(r->tile_keys);
    free(r->isect);
    free(r->t_final);
    free(r->last);
    free(r->slots);
    free(r->scratch);
    for (int w = 0; w < r->n_arenas; w++) {
        free(r->arenas[w].hdr);
        free(r->arenas[w].vis);
    }
    free(r->arenas);
    free(r->tile_rec);
    free(r);
}

void gs_raster_get_stats(const gs_raster *r, gs_raster_stats *s)
{
    s->visible = r ? r->visible : 0;
    s->intersections = r ? r->n_isect : 0;
    s->contributions = r ? r->contributions : 0;
    s->ms_project = r ? r->ms_phase[0] : 0.0;
    s->ms_sort = r ? r->ms_phase[1] : 0.0;
    s->ms_bin = r ? r->ms_phase[2] : 0.0;
    s->ms_composite = r ? r->ms_phase[3] : 0.0;
}

/* fmaxf and fminf are library calls on x86 (their NaN rules have no single
 * instruction). These take the second argument when either is NaN, and the
 * callers pass a constant or an ordered value second. */
static inline float max_f(float x, float lo)
{
    return x > lo ? x : lo;
}

static inline float min_f(float x, float hi)
{
    return x < hi ? x : hi;
}

/* ---- argument checks ---------------------------------------------------- */

static int finite_array(const float *x, size_t n)
{
    return best_kernels()->all_finite(x, n); /* the same answer with every set */
}

/* The finiteness check of the inputs in blocks over the pool: for 20k
 * Gaussians of 32 channels it reads 3.4 MB, serial time worth sharing. The
 * answer (which array first holds a non-finite value) does not depend on
 * the split. */
#define FINITE_BLOCK ((size_t)1 << 16)
#define FINITE_ARRAYS 6
#define FINITE_TASKS 256

typedef struct {
    const float *p[FINITE_ARRAYS];
    size_t len[FINITE_ARRAYS];
    int task0[FINITE_ARRAYS + 1]; /* first task of each array */
    unsigned char bad[FINITE_TASKS];
} finite_ctx;

static void finite_task(void *vctx, int task, int worker)
{
    (void)worker;
    finite_ctx *c = vctx;
    int a = 0;
    while (task >= c->task0[a + 1])
        a++;
    size_t nb = (size_t)(c->task0[a + 1] - c->task0[a]), b = (size_t)(task - c->task0[a]);
    size_t blk = (c->len[a] + nb - 1) / nb;
    size_t lo = b * blk, hi = lo + blk < c->len[a] ? lo + blk : c->len[a];
    c->bad[task] = lo < hi && !finite_array(c->p[a] + lo, hi - lo);
}

static int check_inputs(const gs_camera *cam, const gs_gaussians *g,
                        const float *bg, gs_pool *pool, gs_error *err)
{
    if (!cam || !g)
        return gs_error_set(err, GS_ERR_ARG, "raster: camera and Gaussians are required");
    if (cam->width < 1 || cam->height < 1 || cam->width > GS_RASTER_MAX_SIZE ||
        cam->height > GS_RASTER_MAX_SIZE)
        return gs_error_set(err, GS_ERR_ARG, "raster: image size %dx%d outside 1..%d",
                            cam->width, cam->height, GS_RASTER_MAX_SIZE);
    if (g->channels < 1 || g->channels > GS_RASTER_MAX_CHANNELS)
        return gs_error_set(err, GS_ERR_ARG, "raster: %d channels outside 1..%d",
                            g->channels, GS_RASTER_MAX_CHANNELS);
    if (g->n < 0)
        return gs_error_set(err, GS_ERR_ARG, "raster: negative Gaussian count %d", g->n);
    if (g->n > 0 && (!g->means || !g->log_scales || !g->quats || !g->opacity_logits ||
                     !g->features))
        return gs_error_set(err, GS_ERR_ARG, "raster: a Gaussian parameter array is NULL");
    float camv[16] = {cam->fx, cam->fy, cam->cx, cam->cy};
    memcpy(camv + 4, cam->viewmat, sizeof cam->viewmat);
    if (!finite_array(camv, 16))
        return gs_error_set(err, GS_ERR_NONFINITE, "raster: non-finite camera value");
    if (!(cam->fx > 0) || !(cam->fy > 0))
        return gs_error_set(err, GS_ERR_ARG, "raster: focal lengths must be > 0 (fx %g, fy %g)",
                            cam->fx, cam->fy);
    size_t n = (size_t)g->n, C = (size_t)g->channels;
    struct { const float *p; size_t len; const char *name; } arrays[] = {
        {g->means, n * 3, "means"},
        {g->log_scales, n * 3, "log_scales"},
        {g->quats, n * 4, "quats"},
        {g->opacity_logits, n, "opacity_logits"},
        {g->features, n * C, "features"},
        {bg, bg ? C * (size_t)cam->width * (size_t)cam->height : 0, "background"},
    };
    _Static_assert(sizeof arrays / sizeof arrays[0] == FINITE_ARRAYS, "one task range per array");
    finite_ctx fc;
    int tasks = 0;
    size_t total = 0;
    for (int a = 0; a < FINITE_ARRAYS; a++) {
        fc.p[a] = arrays[a].p, fc.len[a] = arrays[a].len, fc.task0[a] = tasks;
        size_t nb = (arrays[a].len + FINITE_BLOCK - 1) / FINITE_BLOCK;
        tasks += (int)(nb < FINITE_TASKS / FINITE_ARRAYS ? nb : FINITE_TASKS / FINITE_ARRAYS);
        total += arrays[a].len;
    }
    fc.task0[FINITE_ARRAYS] = tasks;
    /* A small scene's few blocks cost less than waking the pool. */
    gs_pool_for(total > 2 * FINITE_BLOCK ? pool : NULL, tasks, finite_task, &fc);
    for (int a = 0; a < FINITE_ARRAYS; a++)
        for (int t = fc.task0[a]; t < fc.task0[a + 1]; t++)
            if (fc.bad[t])
                return gs_error_set(err, GS_ERR_NONFINITE, "raster: non-finite value in %s",
                                    arrays[a].name);
    return GS_OK;
}

/* ---- projection --------------------------------------------------------- */

static void quat_to_rot(const float q[4], float R[9], float qn[4])
{
    /* Divide by the largest component first, so the sum of squares neither
     * overflows (|q| > 1.8e19) nor loses bits to denormals (|q| < 1e-19). */
    float m = max_f(max_f(fabsf(q[0]), fabsf(q[1])), max_f(fabsf(q[2]), fabsf(q[3])));
    float w = 1.0f, x = 0.0f, y = 0.0f, z = 0.0f;
    if (m > 0.0f) {
        w = q[0] / m, x = q[1] / m, y = q[2] / m, z = q[3] / m;
        float inv = 1.0f / sqrtf(w * w + x * x + y * y + z * z);
        w *= inv, x *= inv, y *= inv, z *= inv;
    }
    qn[0] = w, qn[1] = x, qn[2] = y, qn[3] = z;
    R[0] = 1 - 2 * (y * y + z * z), R[1] = 2 * (x * y - w * z), R[2] = 2 * (x * z + w * y);
    R[3] = 2 * (x * y + w * z), R[4] = 1 - 2 * (x * x + z * z), R[5] = 2 * (y * z - w * x);
    R[6] = 2 * (x * z - w * y), R[7] = 2 * (y * z + w * x), R[8] = 1 - 2 * (x * x + y * y);
}

/* Camera-frame covariance Sigma_c = W R S S^T R^T W^T (symmetric 3x3). */
static void camera_covariance(const float *V, const float R[9], const float s[3],
                              float Sc[9])
{
    float M[9], WM[9];
#pragma GCC unroll 9
    for (int i = 0; i < 3; i++)
#pragma GCC unroll 9
        for (int j = 0; j < 3; j++)
            M[i * 3 + j] = R[i * 3 + j] * s[j];
#pragma GCC unroll 9
    for (int i = 0; i < 3; i++)
#pragma GCC unroll 9
        for (int j = 0; j < 3; j++)
            WM[i * 3 + j] = V[i * 4 + 0] * M[0 + j] + V[i * 4 + 1] * M[3 + j] +
                            V[i * 4 + 2] * M[6 + j];
#pragma GCC unroll 9
    for (int i = 0; i < 3; i++)
#pragma GCC unroll 9
        for (int j = 0; j < 3; j++)
            Sc[i * 3 + j] = WM[i * 3 + 0] * WM[j * 3 + 0] + WM[i * 3 + 1] * WM[j * 3 + 1] +
                            WM[i * 3 + 2] * WM[j * 3 + 2];
}

/* Clamped perspective Jacobian rows (J00, J02, J11, J12); reports clamping. */
typedef struct {
    float j00, j02, j11, j12;
    float tx, ty;
    int clamp_x, clamp_y;
} jacobian;

/* Limits of x/z and y/z for the Jacobian clamp: the image extent widened by
 * the margin, (+x, -x, +y, -y). Once per render: they are divisions. */
static void clamp_limits(const gs_camera *cam, float lim[4])
{
    float W = (float)cam->width, H = (float)cam->height;
    lim[0] = (W - cam->cx) / cam->fx + GS_RASTER_CLAMP_MARGIN * W / cam->fx;
    lim[1] = cam->cx / cam->fx + GS_RASTER_CLAMP_MARGIN * W / cam->fx;
    lim[2] = (H - cam->cy) / cam->fy + GS_RASTER_CLAMP_MARGIN * H / cam->fy;
    lim[3] = cam->cy / cam->fy + GS_RASTER_CLAMP_MARGIN * H / cam->fy;
}

static jacobian persp_jacobian(const gs_camera *cam, const float lim[4], float x, float y,
                               float z)
{
    jacobian J;
    float lim_xp = lim[0], lim_xn = lim[1], lim_yp = lim[2], lim_yn = lim[3];
    float u = x / z, v = y / z;
    J.clamp_x = u < -lim_xn || u > lim_xp;
    J.clamp_y = v < -lim_yn || v > lim_yp;
    J.tx = z * min_f(max_f(u, -lim_xn), lim_xp);
    J.ty = z * min_f(max_f(v, -lim_yn), lim_yp);
    float rz = 1.0f / z, rz2 = rz * rz;
    J.j00 = cam->fx * rz;
    J.j02 = -cam->fx * J.tx * rz2;
    J.j11 = cam->fy * rz;
    J.j12 = -cam->fy * J.ty * rz2;
    return J;
}

/* Gaussian i in the camera frame: mean, rotation, scales, covariance and
 * the clamped Jacobian, shared by the projection and its gradient. Returns 0
 * (leaving the rest unset) when the mean is outside the near/far range. */
typedef struct {
    float x, y, z;
    float R[9], qn[4], s[3], Sc[9];
    jacobian J;
} camera_gaussian;

static int to_camera(const gs_raster *r, int i, camera_gaussian *cg)
{
    const float *V = r->cam.viewmat, *p = r->g.means + 3 * (size_t)i;
    cg->x = V[0] * p[0] + V[1] * p[1] + V[2] * p[2] + V[3];
    cg->y = V[4] * p[0] + V[5] * p[1] + V[6] * p[2] + V[7];
    cg->z = V[8] * p[0] + V[9] * p[1] + V[10] * p[2] + V[11];
    if (!(cg->z >= GS_RASTER_NEAR) || !(cg->z <= GS_RASTER_FAR))
        return 0;
    quat_to_rot(r->g.quats + 4 * (size_t)i, cg->R, cg->qn);
#pragma GCC unroll 9
    for (int k = 0; k < 3; k++)
        cg->s[k] = expf(r->g.log_scales[3 * (size_t)i + k]);
    camera_covariance(V, cg->R, cg->s, cg->Sc);
    cg->J = persp_jacobian(&r->cam, r->clamp_lim, cg->x, cg->y, cg->z);
    return 1;
}

typedef struct {
    gs_raster *r;
    int fast;
} proj_ctx;

#define PROJ_CHUNK 1024

/* The scalar path's projection of Gaussian i (the fast path's, 8 at a time
 * with the same formulas, is in raster_proj.c). */
static void project_one(gs_raster *r, int i)
{
    const gs_camera *cam = &r->cam;
    const gs_gaussians *g = &r->g;
    gs_proj *P = &r->proj;
    P->radius[i] = 0.0f;
    camera_gaussian cg;
    if (!to_camera(r, i, &cg))
        return;
    float x = cg.x, y = cg.y, z = cg.z;
    const float *Sc = cg.Sc;
    jacobian J = cg.J;
    /* Sigma2 = J Sc J^T with J = [[j00, 0, j02], [0, j11, j12]]. */
    float s00 = J.j00 * J.j00 * Sc[0] + 2 * J.j00 * J.j02 * Sc[2] + J.j02 * J.j02 * Sc[8];
    float s11 = J.j11 * J.j11 * Sc[4] + 2 * J.j11 * J.j12 * Sc[5] + J.j12 * J.j12 * Sc[8];
    float s01 = J.j00 * J.j11 * Sc[1] + J.j00 * J.j12 * Sc[2] + J.j02 * J.j11 * Sc[7] +
                J.j02 * J.j12 * Sc[8];
    float det0 = s00 * s11 - s01 * s01;
    s00 += GS_RASTER_EPS2D;
    s11 += GS_RASTER_EPS2D;
    float det = s00 * s11 - s01 * s01;
    if (!(det > 0.0f) || !isfinite(det))
        return;
    float inv = 1.0f / det;
    float a = s11 * inv, b = -s01 * inv, c = s00 * inv;
    float mx = cam->fx * x / z + cam->cx, my = cam->fy * y / z + cam->cy;
    float half = 0.5f * (s00 + s11);
    float lam = half + sqrtf(max_f(half * half - det, 0.01f));
    float rad = ceilf(3.0f * sqrtf(lam));
    if (!isfinite(rad) || !isfinite(mx) || !isfinite(my) || !isfinite(a) || !isfinite(b) ||
        !isfinite(c))
        return;
    if (mx + rad <= 0 || mx - rad >= (float)cam->width || my + rad <= 0 ||
        my - rad >= (float)cam->height)
        return;
    float comp = sqrtf(max_f(det0 * inv, 0.0f));
    float lo = g->opacity_logits[i];
    float op = 1.0f / (1.0f + expf(-lo));
    if (r->opt.antialiased)
        op *= comp;
    P->mean2d[2 * i] = mx;
    P->mean2d[2 * i + 1] = my;
    P->conic[3 * i] = a;
    P->conic[3 * i + 1] = b;
    P->conic[3 * i + 2] = c;
    P->depth[i] = z;
    P->opacity[i] = op;
    P->comp[i] = comp;
    P->radius[i] = rad;
}

static void project_chunk(void *vctx, int task, int worker)
{
    (void)worker;
    proj_ctx *ctx = vctx;
    int i0 = task * PROJ_CHUNK, i1 = i0 + PROJ_CHUNK;
    if (i1 > ctx->r->g.n)
        i1 = ctx->r->g.n;
    if (ctx->fast) {
        ctx->r->kern->project(ctx->r, i0, i1);
        return;
    }
    for (int i = i0; i < i1; i++)
        project_one(ctx->r, i);
}

/* ---- sorting and binning ------------------------------------------------ */

/* Stable LSD radix sort of visible ids by the bits of their (positive)
 * depth: ties keep id order, so the order never depends on threads. */
static void sort_by_depth(gs_raster *r, int m)
{
    uint32_t *ord = r->order, *ot = r->order_tmp, *key = r->keys, *kt = r->keys_tmp;
    /* The four bytes' histograms in one read of the keys: a pass only
     * moves the keys, which keep their bytes. */
    uint32_t hist[4][257];
    memset(hist, 0, sizeof hist);
    for (int i = 0; i < m; i++) {
        uint32_t k = key[i];
        hist[0][(k & 0xff) + 1]++;
        hist[1][((k >> 8) & 0xff) + 1]++;
        hist[2][((k >> 16) & 0xff) + 1]++;
        hist[3][(k >> 24) + 1]++;
    }
    for (int pass = 0; pass < 4; pass++) {
        int shift = pass * 8;
        uint32_t *count = hist[pass];
        if (count[((key[0] >> shift) & 0xff) + 1] == (uint32_t)m)
            continue; /* every key shares this byte */
        for (int b = 0; b < 256; b++)
            count[b + 1] += count[b];
        for (int i = 0; i < m; i++) {
            uint32_t d = count[(key[i] >> shift) & 0xff]++;
            ot[d] = ord[i];
            kt[d] = key[i];
        }
        uint32_t *t = ord; ord = ot; ot = t;
        t = key; key = kt; kt = t;
    }
    if (ord != r->order)
        memcpy(r->order, ord, (size_t)m * sizeof *ord);
}

/* Tile range [x0, x1) x [y0, y1) of the radius box, as gsplat bins it. */
static void tile_range(const gs_raster *r, int i, int32_t t[4])
{
    const float *m = r->proj.mean2d + 2 * i;
    float rad = r->proj.radius[i], T = (float)GS_RASTER_TILE;
    float x0 = floorf((m[0] - rad) / T), x1 = ceilf((m[0] + rad) / T);
    float y0 = floorf((m[1] - rad) / T), y1 = ceilf((m[1] + rad) / T);
    float tx = (float)r->tiles_x, ty = (float)r->tiles_y;
    t[0] = (int32_t)min_f(max_f(x0, 0.0f), tx);
    t[1] = (int32_t)min_f(max_f(x1, 0.0f), tx);
    t[2] = (int32_t)min_f(max_f(y0, 0.0f), ty);
    t[3] = (int32_t)min_f(max_f(y1, 0.0f), ty);
}

/* Tiles [lo, hi) whose pixel centres [16 t + 0.49, 16 t + 15.51] meet
 * [x0, x1], within [lo, hi). */
static void centre_range(float x0, float x1, int32_t *lo, int32_t *hi)
{
    const float T = (float)GS_RASTER_TILE;
    float f0 = min_f(max_f((x0 + 0.49f) * (1.0f / T) - 1.0f, (float)*lo), (float)*hi);
    float f1 = min_f(max_f((x1 - 0.49f) * (1.0f / T) + 1.0f, f0), (float)*hi);
    int32_t i0 = (int32_t)f0, i1 = (int32_t)f1;
    *lo = i0 + ((float)i0 < f0);
    *hi = i1 > *lo ? i1 : *lo;
}

/* Fast path only: tiles [*a, *b) of tile row ty whose pixel centres the
 * splat's sigma <= thr ellipse reaches, within the radius box [tx0, tx1).
 * The ellipse cut to the row's band of pixel centres is convex, so it meets
 * a tile's box of centres exactly when its x-extent meets the box's x-range;
 * that extent ends at the ellipse's own left and right extremes, or where
 * they fall outside the band, on the band's nearer edge. Boxes are widened
 * by 0.01 px against rounding, so only tiles that cannot be reached go. */
static void band_tiles(const gs_raster *r, const gs_splat *sp, int ty, int tx0, int tx1, int *a,
                       int *b)
{
    const float T = (float)GS_RASTER_TILE;
    float py0 = (float)ty * T + 0.49f;
    float py1 = min_f((float)(ty + 1) * T, (float)r->cam.height) - 0.49f;
    float dy0 = sp->my - py1, dy1 = sp->my - py0; /* d = mean - pixel centre */
    *a = *b = tx0;
    if (dy0 > sp->ey || dy1 < -sp->ey)
        return;
    float qa = sp->a, qb = sp->b, qc = sp->c, det = qa * qc - qb * qb, thr = sp->thr;
    /* The extremes of dx lie at dy = -+ b ex / c with ex = sqrt(2 thr c / det). */
    float ex = sqrtf(max_f(2.0f * thr * qc / det, 0.0f));
    float dyr = min_f(max_f(-qb * ex / qc, dy0), dy1);
    float dyl = min_f(max_f(qb * ex / qc, dy0), dy1);
    float dxmax = (-qb * dyr + sqrtf(max_f(2.0f * qa * thr - det * dyr * dyr, 0.0f))) / qa;
    float dxmin = (-qb * dyl - sqrtf(max_f(2.0f * qa * thr - det * dyl * dyl, 0.0f))) / qa;
    int32_t lo = tx0, hi = tx1;
    centre_range(sp->mx - dxmax - 0.01f, sp->mx - dxmin + 0.01f, &lo, &hi);
    *a = lo, *b = hi;
}

/* The visible Gaussians, in depth order, are split into chunks, one task
 * each. The count pass tallies each chunk's pairs per tile; a prefix sum
 * over (tile, chunk) then gives every chunk its own run inside each tile's
 * list, which the fill pass writes in the chunk's order. Chunks are
 * consecutive in depth, so every list comes out sorted whatever the chunk
 * count, and no two tasks write the same element. */
typedef struct {
    gs_raster *r;
    int m, fast, chunk, fill, ntiles;
    uint32_t *counts;     /* tasks x tiles: pairs per (chunk, tile); fill: cursors */
    _Atomic size_t total; /* count pass: pairs so far (for the limit) */
} bin_ctx;

#define BIN_PREFETCH 12

static void bin_chunk(void *vctx, int task, int worker)
{
    (void)worker;
    bin_ctx *ctx = vctx;
    gs_raster *r = ctx->r;
    int k0 = task * ctx->chunk, k1 = k0 + ctx->chunk < ctx->m ? k0 + ctx->chunk : ctx->m;
    uint32_t *count = ctx->counts + (size_t)task * (size_t)ctx->ntiles;
    size_t local = 0;
    for (int k = k0; k < k1; k++) {
        uint32_t i = r->order[k];
        /* The splats are read in depth order, scattered over the array:
         * without a prefetch, each costs a cache miss that dominates. */
        if (ctx->fast && k + BIN_PREFETCH < k1)
            __builtin_prefetch(r->splats + r->order[k + BIN_PREFETCH]);
        int32_t box[4];
        const int32_t *t = box;
        if (ctx->fast)
            t = r->splats[i].tiles;
        else
            tile_range(r, (int)i, box);
        for (int ty = t[2]; ty < t[3]; ty++) {
            int a = t[0], b = t[1];
            if (ctx->fast && b - a > 2 && t[3] - t[2] > 2)
                band_tiles(r, r->splats + i, ty, t[0], t[1], &a, &b);
            size_t row = (size_t)ty * r->tiles_x;
            if (ctx->fill) {
                for (int tx = a; tx < b; tx++)
                    r->isect[count[row + tx]++] = i;
            } else {
                for (int tx = a; tx < b; tx++)
                    count[row + tx]++;
                local += (size_t)(b - a);
            }
        }
        /* Publish now and then, so an absurd scene stops early. */
        if (local > 4096) {
            if (atomic_fetch_add(&ctx->total, local) + local > GS_RASTER_MAX_ISECT)
                return;
            local = 0;
        }
    }
    if (!ctx->fill)
        atomic_fetch_add(&ctx->total, local);
}

static int bin_tiles(gs_raster *r, gs_pool *pool, int m, int fast, gs_error *err)
{
    size_t ntiles = (size_t)r->tiles_x * (size_t)r->tiles_y;
    int threads = fast ? gs_pool_threads(pool) : 1;
    /* A few chunks per thread: Gaussians differ in how many tiles they
     * reach, and the pool hands chunks out as workers come free. */
    int tasks = threads > 1 ? 4 * threads : 1;
    int chunk = m > 0 ? (m + tasks - 1) / tasks : 1;
    tasks = m > 0 ? (m + chunk - 1) / chunk : 0;
    if (gs_raster_reserve((void **)&r->tile_off, &r->cap_tiles, ntiles + 1, sizeof(uint32_t)) ||
        gs_raster_reserve((void **)&r->bin_counts, &r->cap_bin_counts,
                          (size_t)(tasks ? tasks : 1) * ntiles, sizeof(uint32_t)))
        return gs_error_set(err, GS_ERR_NOMEM, "raster: out of memory for tiles");
    uint32_t *off = r->tile_off, *counts = r->bin_counts;
    memset(counts, 0, (size_t)tasks * ntiles * sizeof *counts);
    bin_ctx ctx = {r, m, fast, chunk, 0, (int)ntiles, counts, 0};
    gs_pool_for(fast ? pool : NULL, tasks, bin_chunk, &ctx);
    size_t total = atomic_load(&ctx.total);
    if (total > GS_RASTER_MAX_ISECT)
        return gs_error_set(err, GS_ERR_LIMIT,
                            "raster: more than %zu tile intersections (Gaussians too large?)",
                            GS_RASTER_MAX_ISECT);
    /* Offsets per tile, and per (chunk, tile) the cursor where the chunk's
     * run in that tile's list starts. */
    uint32_t pos = 0;
    for (size_t t = 0; t < ntiles; t++) {
        off[t] = pos;
        for (int c = 0; c < tasks; c++) {
            uint32_t *cnt = counts + (size_t)c * ntiles + t, n = *cnt;
            *cnt = pos;
            pos += n;
        }
    }
    off[ntiles] = pos;
    if (gs_raster_reserve((void **)&r->isect, &r->cap_isect, total ? total : 1, sizeof(uint32_t)))
        return gs_error_set(err, GS_ERR_NOMEM, "raster: out of memory for %zu intersections",
                            total);
    r->n_isect = total;
    ctx.fill = 1;
    gs_pool_for(fast ? pool : NULL, tasks, bin_chunk, &ctx);
    return GS_OK;
}

/* ---- forward ------------------------------------------------------------ */

static int reserve_n(gs_raster *r, size_t n)
{
    if (n <= r->cap_n && r->n_block)
        return GS_OK;
    size_t cap = n < 64 ? 64 : n;
    /* proj: 2+3+1+1+1+1 = 9 floats; pgrad: 2+3+1+1 = 7 floats */
    float *blk = malloc(cap * 16 * sizeof(float));
    if (!blk)
        return GS_ERR_NOMEM;
    free(r->n_block);
    r->n_block = blk;
    r->cap_n = cap;
    gs_proj *P = &r->proj;
    P->mean2d = blk, blk += 2 * cap;
    P->conic = blk, blk += 3 * cap;
    P->depth = blk, blk += cap;
    P->opacity = blk, blk += cap;
    P->comp = blk, blk += cap;
    P->radius = blk, blk += cap;
    gs_proj_grad *G = &r->pgrad;
    G->mean2d = blk, blk += 2 * cap;
    G->conic = blk, blk += 3 * cap;
    G->opacity = blk, blk += cap;
    G->depth = blk;
    return GS_OK;
}

int gs_raster_forward(gs_raster *r, gs_pool *pool, const gs_camera *cam,
                      const gs_gaussians *g, const float *background,
                      const gs_raster_options *opt, float *out_f, float *out_alpha,
                      float *out_depth, gs_error *err)
{
    if (!r || !out_f || !out_alpha)
        return gs_error_set(err, GS_ERR_ARG, "raster: workspace and outputs are required");
    r->have_forward = 0;
    if (r->isa_error[0])
        return gs_error_set(err, GS_ERR_ARG,
                            "raster: GS_RASTER_ISA=%s is unknown or not supported by this CPU "
                            "(avx512, avx2, generic, auto)",
                            r->isa_error);
    int rc = check_inputs(cam, g, background,
                          opt && opt->path == GS_RASTER_SCALAR ? NULL : pool, err);
    if (rc)
        return rc;
    static const gs_raster_options defaults = {0, GS_RASTER_FAST, 0};
    if (opt && opt->path != GS_RASTER_FAST && opt->path != GS_RASTER_SCALAR)
        return gs_error_set(err, GS_ERR_ARG, "raster: unknown path %d", (int)opt->path);
    if (opt && (opt->changed_from < 0 || opt->changed_from > g->n))
        return gs_error_set(err, GS_ERR_ARG, "raster: changed_from %d outside [0, %d]",
                            opt->changed_from, g->n);
    r->cam = *cam;
    clamp_limits(r->has_frustum ? &r->frustum : cam, r->clamp_lim);
    r->g = *g;
    r->background = background;
    r->opt = opt ? *opt : defaults;
    int fast = r->opt.path != GS_RASTER_SCALAR;
    size_t n = (size_t)g->n, npix = (size_t)cam->width * (size_t)cam->height;
    r->tiles_x = (cam->width + GS_RASTER_TILE - 1) / GS_RASTER_TILE;
    r->tiles_y = (cam->height + GS_RASTER_TILE - 1) / GS_RASTER_TILE;
    size_t ntiles = (size_t)r->tiles_x * (size_t)r->tiles_y;
    if (fast && n > r->cap_splats) {
        free(r->splats);
        r->cap_splats = 0;
        r->splats = aligned_alloc(64, n * sizeof(gs_splat));
        if (!r->splats)
            return gs_error_set(err, GS_ERR_NOMEM, "raster: out of memory for %zu Gaussians", n);
        r->cap_splats = n;
    }
    if (reserve_n(r, n) ||
        gs_raster_reserve((void **)&r->t_final, &r->cap_pix, npix, sizeof(float)))
        return gs_error_set(err, GS_ERR_NOMEM, "raster: out of memory for %zu Gaussians", n);
    if (gs_raster_reserve((void **)&r->last, &r->cap_last, npix, sizeof(uint32_t)))
        return gs_error_set(err, GS_ERR_NOMEM, "raster: out of memory for %zu pixels", npix);
    size_t cap = r->cap_order, want = n > ntiles ? n : ntiles;
    if (want < 1)
        want = 1;
    if (want > r->cap_order) {
        free(r->order), free(r->order_tmp), free(r->keys), free(r->keys_tmp);
        r->order = malloc(want * sizeof(uint32_t));
        r->order_tmp = malloc(want * sizeof(uint32_t));
        r->keys = malloc(want * sizeof(uint32_t));
        r->keys_tmp = malloc(want * sizeof(uint32_t));
        cap = want;
        r->cap_order = (r->order && r->order_tmp && r->keys && r->keys_tmp) ? cap : 0;
        if (!r->cap_order)
            return gs_error_set(err, GS_ERR_NOMEM, "raster: out of memory");
    }

    double t0 = (1e3 * gs_clock_s());
    proj_ctx pc = {r, fast};
    int chunks = (int)((n + PROJ_CHUNK - 1) / PROJ_CHUNK);
    gs_pool_for(fast ? pool : NULL, chunks, project_chunk, &pc);

    int m = 0;
    for (size_t i = 0; i < n; i++)
        if (r->proj.radius[i] > 0) {
            uint32_t bits;
            memcpy(&bits, &r->proj.depth[i], sizeof bits);
            r->order[m] = (uint32_t)i;
            r->keys[m++] = bits;
        }
    r->visible = m;
    double t1 = (1e3 * gs_clock_s());
    if (m > 0)
        sort_by_depth(r, m);
    double t2 = (1e3 * gs_clock_s());
    rc = bin_tiles(r, pool, m, fast, err);
    if (rc)
        return rc;
    double t3 = (1e3 * gs_clock_s());

    if (fast) {
        r->fwd_kern = r->kern;
        if (r->kern->forward(r, pool, background, out_f, out_alpha, out_depth))
            return gs_error_set(err, GS_ERR_NOMEM, "raster: out of memory for tile buffers");
    } else
        gs_raster_scalar_forward(r, background, out_f, out_alpha, out_depth);
    double t4 = (1e3 * gs_clock_s());
    r->ms_phase[0] = t1 - t0, r->ms_phase[1] = t2 - t1;
    r->ms_phase[2] = t3 - t2, r->ms_phase[3] = t4 - t3;
    /* a forward of some tiles leaves the others' saved state stale */
    r->have_forward = !(fast && r->opt.changed_from > 0);
    return GS_OK;
}

/* ---- backward ----------------------------------------------------------- */

/* v_Sigma2 (full symmetric 2x2, unblurred) from the conic and opacity
 * gradients; see the derivation in raster.h's semantics. */
static void conic_vjp(const gs_raster *r, int i, float v_s[4])
{
    const float *q = r->proj.conic + 3 * i, *vq = r->pgrad.conic + 3 * i;
    /* P = [[a, b], [b, c]], G = dL/dP with the off-diagonal split evenly. */
    float a = q[0], b = q[1], c = q[2];
    float g00 = vq[0], g01 = 0.5f * vq[1], g11 = vq[2];
    /* v_B = -P G P */
    float pg00 = a * g00 + b * g01, pg01 = a * g01 + b * g11;
    float pg10 = b * g00 + c * g01, pg11 = b * g01 + c * g11;
    v_s[0] = -(pg00 * a + pg01 * b);
    v_s[1] = -(pg00 * b + pg01 * c);
    v_s[2] = -(pg10 * a + pg11 * b);
    v_s[3] = -(pg10 * b + pg11 * c);
    if (r->opt.antialiased) {
        /* opacity = sigmoid(logit) * comp, comp = sqrt(det A / det B) with
         * B = A + eps I: d comp / dA = 0.5/comp ((1 - comp^2) B^-1 - eps det(B^-1) I) */
        int idx = i;
        float comp = r->proj.comp[idx];
        float sig = 1.0f / (1.0f + expf(-r->g.opacity_logits[idx]));
        float v_comp = r->pgrad.opacity[idx] * sig;
        if (comp > 0.0f) {
            float k = v_comp * 0.5f / comp;
            float one = 1.0f - comp * comp, detp = a * c - b * b;
            v_s[0] += k * (one * a - GS_RASTER_EPS2D * detp);
            v_s[1] += k * one * b;
            v_s[2] += k * one * b;
            v_s[3] += k * (one * c - GS_RASTER_EPS2D * detp);
        }
    }
}

/* Long on purpose (a hot kernel, once per Gaussian): the projection
 * Jacobian chain written out in one pass, its intermediates in registers. */
static void project_backward_one(gs_raster *r, int i, gs_gaussian_grads *grads)
{
    if (!(r->proj.radius[i] > 0))
        return;
    const gs_camera *cam = &r->cam;
    const gs_gaussians *g = &r->g;
    camera_gaussian cg;
    to_camera(r, i, &cg); /* visible, so inside the near and far planes */
    const float *V = cam->viewmat;
    float x = cg.x, y = cg.y, z = cg.z;
    const float *R = cg.R, *qn = cg.qn, *s = cg.s, *Sc = cg.Sc;
    jacobian J = cg.J;

    float vS2[4];
    conic_vjp(r, i, vS2);
    /* Sigma2 = J Sc J^T: v_Sc = J^T vS2 J, v_J = 2 vS2 J Sc (vS2, Sc symmetric). */
    float Jm[6] = {J.j00, 0, J.j02, 0, J.j11, J.j12};
    float vSc[9];
#pragma GCC unroll 9
    for (int a = 0; a < 3; a++)
#pragma GCC unroll 9
        for (int b = 0; b < 3; b++)
            vSc[a * 3 + b] = Jm[a] * (vS2[0] * Jm[b] + vS2[1] * Jm[3 + b]) +
                             Jm[3 + a] * (vS2[2] * Jm[b] + vS2[3] * Jm[3 + b]);
    float JS[6];
#pragma GCC unroll 9
    for (int a = 0; a < 2; a++)
#pragma GCC unroll 9
        for (int b = 0; b < 3; b++)
            JS[a * 3 + b] = Jm[a * 3] * Sc[b] + Jm[a * 3 + 1] * Sc[3 + b] +
                            Jm[a * 3 + 2] * Sc[6 + b];
    float vJ[6];
#pragma GCC unroll 9
    for (int a = 0; a < 2; a++)
#pragma GCC unroll 9
        for (int b = 0; b < 3; b++)
            vJ[a * 3 + b] = 2.0f * (vS2[a * 2] * JS[b] + vS2[a * 2 + 1] * JS[3 + b]);

    /* Camera-space mean gradient: mean2d, depth, and the Jacobian. */
    const float *vm = r->pgrad.mean2d + 2 * i;
    float rz = 1.0f / z, rz2 = rz * rz, rz3 = rz2 * rz;
    float fx = cam->fx, fy = cam->fy;
    float vx = vm[0] * fx * rz;
    float vy = vm[1] * fy * rz;
    float vz = -(vm[0] * fx * x + vm[1] * fy * y) * rz2 + r->pgrad.depth[i];
    vz += -fx * rz2 * vJ[0] - fy * rz2 * vJ[4];
    /* j02 = -fx tx / z^2 with tx = x unclamped, z * lim when clamped. */
    if (J.clamp_x) {
        vz += fx * J.tx * rz3 * vJ[2];
    } else {
        vx += -fx * rz2 * vJ[2];
        vz += 2.0f * fx * x * rz3 * vJ[2];
    }
    if (J.clamp_y) {
        vz += fy * J.ty * rz3 * vJ[5];
    } else {
        vy += -fy * rz2 * vJ[5];
        vz += 2.0f * fy * y * rz3 * vJ[5];
    }
    if (grads->means) {
        float *gm = grads->means + 3 * (size_t)i;
#pragma GCC unroll 9
        for (int k = 0; k < 3; k++)
            gm[k] += V[k] * vx + V[4 + k] * vy + V[8 + k] * vz;
    }
    /* Sc = V Sigma V^T: v_Sigma = V^T vSc V. Sigma = M M^T, M = R S. */
    float vSig[9], tmp[9];
#pragma GCC unroll 9
    for (int a = 0; a < 3; a++)
#pragma GCC unroll 9
        for (int b = 0; b < 3; b++)
            tmp[a * 3 + b] = vSc[a * 3] * V[b] + vSc[a * 3 + 1] * V[4 + b] +
                             vSc[a * 3 + 2] * V[8 + b];
#pragma GCC unroll 9
    for (int a = 0; a < 3; a++)
#pragma GCC unroll 9
        for (int b = 0; b < 3; b++)
            vSig[a * 3 + b] = V[a] * tmp[b] + V[4 + a] * tmp[3 + b] + V[8 + a] * tmp[6 + b];
    float vM[9];
#pragma GCC unroll 9
    for (int a = 0; a < 3; a++)
#pragma GCC unroll 9
        for (int b = 0; b < 3; b++)
            vM[a * 3 + b] = (vSig[a * 3] + vSig[a]) * R[b] * s[b] +
                            (vSig[a * 3 + 1] + vSig[3 + a]) * R[3 + b] * s[b] +
                            (vSig[a * 3 + 2] + vSig[6 + a]) * R[6 + b] * s[b];
    if (grads->log_scales) {
        float *gs = grads->log_scales + 3 * (size_t)i;
#pragma GCC unroll 9
        for (int b = 0; b < 3; b++)
            gs[b] += (vM[b] * R[b] + vM[3 + b] * R[3 + b] + vM[6 + b] * R[6 + b]) * s[b];
    }
    const float *q = g->quats + 4 * (size_t)i;
    float qm = max_f(max_f(fabsf(q[0]), fabsf(q[1])), max_f(fabsf(q[2]), fabsf(q[3])));
    if (grads->quats && qm > 0.0f) {
        float vR[9];
#pragma GCC unroll 9
        for (int a = 0; a < 9; a++)
            vR[a] = vM[a] * s[a % 3];
        float w = qn[0], qx = qn[1], qy = qn[2], qz = qn[3];
        float vq[4];
        vq[0] = 2 * (-qz * vR[1] + qy * vR[2] + qz * vR[3] - qx * vR[5] - qy * vR[6] +
                     qx * vR[7]);
        vq[1] = 2 * (qy * vR[1] + qz * vR[2] + qy * vR[3] - 2 * qx * vR[4] - w * vR[5] +
                     qz * vR[6] + w * vR[7] - 2 * qx * vR[8]);
        vq[2] = 2 * (-2 * qy * vR[0] + qx * vR[1] + w * vR[2] + qx * vR[3] + qz * vR[5] -
                     w * vR[6] + qz * vR[7] - 2 * qy * vR[8]);
        vq[3] = 2 * (-2 * qz * vR[0] - w * vR[1] + qx * vR[2] + w * vR[3] - 2 * qz * vR[4] +
                     qy * vR[5] + qx * vR[6] + qy * vR[7]);
        float dot = vq[0] * qn[0] + vq[1] * qn[1] + vq[2] * qn[2] + vq[3] * qn[3];
        float a = q[0] / qm, b = q[1] / qm, c = q[2] / qm, d = q[3] / qm;
        float inv = 1.0f / (qm * sqrtf(a * a + b * b + c * c + d * d)); /* 1/|q| */
        float *gq = grads->quats + 4 * (size_t)i;
#pragma GCC unroll 9
        for (int k = 0; k < 4; k++)
            gq[k] += (vq[k] - qn[k] * dot) * inv;
    }
    if (grads->opacity_logits) {
        float sig = 1.0f / (1.0f + expf(-g->opacity_logits[i]));
        float f = r->opt.antialiased ? r->proj.comp[i] : 1.0f;
        grads->opacity_logits[i] += r->pgrad.opacity[i] * f * sig * (1.0f - sig);
    }
}

typedef struct {
    gs_raster *r;
    gs_gaussian_grads *grads;
    int fast;
} pback_ctx;

static void project_backward_chunk(void *vctx, int task, int worker)
{
    (void)worker;
    pback_ctx *c = vctx;
    int i0 = task * PROJ_CHUNK, i1 = i0 + PROJ_CHUNK;
    if (i1 > c->r->g.n)
        i1 = c->r->g.n;
    if (c->fast) {
        c->r->fwd_kern->project_backward(c->r, i0, i1, c->grads);
        return;
    }
    for (int i = i0; i < i1; i++)
        project_backward_one(c->r, i, c->grads);
}

/* y[0..n) += x[0..n), four at a time so that the blocks become vector adds. */
static void add_row(float *restrict y, const float *restrict x, size_t n)
{
    size_t c = 0;
    for (; c + 4 <= n; c += 4) {
        y[c] += x[c];
        y[c + 1] += x[c + 1];
        y[c + 2] += x[c + 2];
        y[c + 3] += x[c + 3];
    }
    for (; c < n; c++)
        y[c] += x[c];
}

/* Adds the per-intersection slots of tiles [t0, t1) into per-Gaussian sums,
 * in tile order: the same additions in the same order for any thread count.
 * Tasks split the slot's columns, not the pairs: task 0 takes the seven
 * projection-space values, task j >= 1 channels [16 (j - 1), 16 j), so each
 * output element still gets its additions in tile order, from one task. */
#define GATHER_CHANNELS 16

typedef struct {
    gs_raster *r;
    int t0, t1;
    size_t slot0;
    float *v_features;
} gather_ctx;

static void gather_task(void *vctx, int task, int worker)
{
    (void)worker;
    gather_ctx *c = vctx;
    gs_raster *r = c->r;
    size_t C = (size_t)r->g.channels, stride = GS_SLOT_HEAD + C;
    size_t c0 = task > 0 ? (size_t)(task - 1) * GATHER_CHANNELS : 0;
    size_t n = C - c0 < GATHER_CHANNELS ? C - c0 : GATHER_CHANNELS;
    gs_proj_grad *G = &r->pgrad;
    for (uint32_t k = r->tile_off[c->t0]; k < r->tile_off[c->t1]; k++) {
        const float *s = r->slots + (k - c->slot0) * stride;
        if (s[GS_SLOT_HEAD - 1] == 0.0f)
            continue; /* the pair changed no pixel */
        size_t i = r->isect[k];
        if (task > 0) {
            add_row(c->v_features + i * C + c0, s + GS_SLOT_HEAD + c0, n);
            continue;
        }
        G->mean2d[2 * i] += s[0];
        G->mean2d[2 * i + 1] += s[1];
        G->conic[3 * i] += s[2];
        G->conic[3 * i + 1] += s[3];
        G->conic[3 * i + 2] += s[4];
        G->opacity[i] += s[5];
        G->depth[i] += s[6];
    }
}

static void gather_slots(gs_raster *r, gs_pool *pool, int t0, int t1, size_t slot0,
                         float *v_features)
{
    gather_ctx ctx = {r, t0, t1, slot0, v_features};
    int tasks = 1;
    if (v_features)
        tasks += (r->g.channels + GATHER_CHANNELS - 1) / GATHER_CHANNELS;
    gs_pool_for(pool, tasks, gather_task, &ctx);
}

static int fast_backward(gs_raster *r, gs_pool *pool, const float *v_f, const float *v_alpha,
                         const float *v_depth, float *v_features, float *v_bg, gs_error *err)
{
    size_t C = (size_t)r->g.channels, stride = GS_SLOT_HEAD + C;
    int ntiles = r->tiles_x * r->tiles_y;
    int t0 = 0;
    while (t0 < ntiles) {
        /* Take whole tiles until the slot budget is used (at least one). */
        int t1 = t0 + 1;
        while (t1 < ntiles &&
               (size_t)(r->tile_off[t1 + 1] - r->tile_off[t0]) * stride <= GS_RASTER_SLOT_BUDGET)
            t1++;
        size_t nslots = r->tile_off[t1] - r->tile_off[t0];
        if (gs_raster_reserve((void **)&r->slots, &r->cap_slots, nslots * stride + 1,
                              sizeof(float)))
            return gs_error_set(err, GS_ERR_NOMEM, "raster: out of memory in backward");
        if (r->fwd_kern->backward(r, pool, t0, t1, r->tile_off[t0], v_f, v_alpha, v_depth,
                                     v_bg))
            return gs_error_set(err, GS_ERR_NOMEM, "raster: out of memory for tile buffers");
        gather_slots(r, pool, t0, t1, r->tile_off[t0], v_features);
        t0 = t1;
    }
    return GS_OK;
}

int gs_raster_backward(gs_raster *r, gs_pool *pool, const float *v_f, const float *v_alpha,
                       const float *v_depth, gs_gaussian_grads *grads, float *v_bg,
                       gs_error *err)
{
    if (!r || !grads || !v_f)
        return gs_error_set(err, GS_ERR_ARG, "raster: workspace, v_features and grads required");
    if (!r->have_forward)
        return gs_error_set(err, GS_ERR_STATE, "raster: backward called without a forward");
    size_t n = (size_t)r->g.n;
    memset(r->pgrad.mean2d, 0, n * 2 * sizeof(float));
    memset(r->pgrad.conic, 0, n * 3 * sizeof(float));
    memset(r->pgrad.opacity, 0, n * sizeof(float));
    memset(r->pgrad.depth, 0, n * sizeof(float));
    int fast = r->opt.path != GS_RASTER_SCALAR;
    if (fast) {
        int rc = fast_backward(r, pool, v_f, v_alpha, v_depth, grads->features, v_bg, err);
        if (rc)
            return rc;
    } else {
        gs_raster_scalar_backward(r, v_f, v_alpha, v_depth, grads->features, v_bg);
    }
    pback_ctx pc = {r, grads, fast};
    int chunks = (int)((n + PROJ_CHUNK - 1) / PROJ_CHUNK);
    gs_pool_for(fast ? pool : NULL, chunks, project_backward_chunk, &pc);
    return GS_OK;
}
