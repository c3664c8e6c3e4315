/* Helpers shared by the rasterizer tests: a seeded RNG, scenes that own
 * their arrays, one-call forward+backward runs, a gsplat-style comparator
 * with a boundary band, and a double-precision forward oracle that follows
 * raster.h literally (per pixel, every Gaussian, no tiles kept in memory). */
#ifndef RT_UTIL_H
#define RT_UTIL_H

#include "gazesplat/raster.h"
#include "gs_test.h"

#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* ------------------------------------------------------- instruction set */

/* The raster tests also run with GS_RASTER_ISA naming each of the fast
 * path's instruction sets (tests/raster/CMakeLists.txt); on a CPU that
 * cannot run the named set the test is skipped (ctest's code 77) instead
 * of failing in every forward. */
__attribute__((constructor)) static void rt_isa_check(void)
{
    const char *isa = getenv("GS_RASTER_ISA");
    if (!isa || !*isa)
        return;
    gs_raster *r = gs_raster_create();
    int rc = r ? gs_raster_set_isa(r, isa, NULL) : 0;
    gs_raster_destroy(r);
    if (rc) {
        printf("skipped: GS_RASTER_ISA=%s is not supported here\n", isa);
        exit(77);
    }
    printf("fast path instruction set: %s\n", isa);
}

/* ------------------------------------------------------------------ RNG */

typedef struct rt_rng {
    uint64_t s;
} rt_rng;

static inline uint64_t rt_next(rt_rng *r)
{
    /* splitmix64 */
    uint64_t z = (r->s += 0x9e3779b97f4a7c15ull);
    z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ull;
    z = (z ^ (z >> 27)) * 0x94d049bb133111ebull;
    return z ^ (z >> 31);
}

/* Uniform in [lo, hi). */
static inline double rt_uniform(rt_rng *r, double lo, double hi)
{
    return lo + (hi - lo) * (double)(rt_next(r) >> 11) * 0x1.0p-53;
}

static inline double rt_normal(rt_rng *r)
{
    double u1 = rt_uniform(r, 1e-12, 1.0), u2 = rt_uniform(r, 0.0, 1.0);
    return sqrt(-2.0 * log(u1)) * cos(6.283185307179586 * u2);
}

static inline void *rt_alloc(size_t n, size_t size)
{
    void *p = calloc(n ? n : 1, size);
    if (!p) {
        fprintf(stderr, "out of memory\n");
        exit(2);
    }
    return p;
}

/* --------------------------------------------------------------- scenes */

/* A scene owns every array; g points into them. */
typedef struct rt_scene {
    gs_camera cam;
    gs_gaussians g;
    float *means, *log_scales, *quats, *opacity_logits, *features;
    float *background; /* C x H x W or NULL */
    int antialiased;
} rt_scene;

static inline void rt_scene_init(rt_scene *s, int n, int C, int W, int H)
{
    memset(s, 0, sizeof *s);
    s->means = rt_alloc((size_t)n * 3, sizeof(float));
    s->log_scales = rt_alloc((size_t)n * 3, sizeof(float));
    s->quats = rt_alloc((size_t)n * 4, sizeof(float));
    s->opacity_logits = rt_alloc((size_t)n, sizeof(float));
    s->features = rt_alloc((size_t)n * (size_t)C, sizeof(float));
    s->g = (gs_gaussians){n, C, s->means, s->log_scales, s->quats,
                          s->opacity_logits, s->features};
    s->cam = (gs_camera){.fx = 60.0f, .fy = 60.0f, .cx = 0.5f * (float)W,
                         .cy = 0.5f * (float)H, .width = W, .height = H,
                         .viewmat = {1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0}};
    for (int i = 0; i < n; i++)
        s->quats[4 * i] = 1.0f;
}

static inline void rt_scene_add_background(rt_scene *s)
{
    size_t np = (size_t)s->cam.width * (size_t)s->cam.height;
    s->background = rt_alloc((size_t)s->g.channels * np, sizeof(float));
}

static inline void rt_scene_free(rt_scene *s)
{
    free(s->means);
    free(s->log_scales);
    free(s->quats);
    free(s->opacity_logits);
    free(s->features);
    free(s->background);
    memset(s, 0, sizeof *s);
}

/* Deep copy (so a test can edit one without touching the other). */
static inline void rt_scene_copy(rt_scene *dst, const rt_scene *src)
{
    int n = src->g.n, C = src->g.channels;
    rt_scene_init(dst, n, C, src->cam.width, src->cam.height);
    dst->cam = src->cam;
    dst->antialiased = src->antialiased;
    memcpy(dst->means, src->means, sizeof(float) * 3 * (size_t)n);
    memcpy(dst->log_scales, src->log_scales, sizeof(float) * 3 * (size_t)n);
    memcpy(dst->quats, src->quats, sizeof(float) * 4 * (size_t)n);
    memcpy(dst->opacity_logits, src->opacity_logits, sizeof(float) * (size_t)n);
    memcpy(dst->features, src->features, sizeof(float) * (size_t)n * (size_t)C);
    if (src->background) {
        rt_scene_add_background(dst);
        memcpy(dst->background, src->background,
               sizeof(float) * (size_t)C * (size_t)src->cam.width *
                   (size_t)src->cam.height);
    }
}

/* Puts Gaussian i at camera-space (px, py, z): px, py is the pixel its
 * mean projects to, z its depth. The view's rotation must be orthonormal:
 * world = R^T (camera - t). */
static inline void rt_place(rt_scene *s, int i, double px, double py, double z)
{
    const gs_camera *c = &s->cam;
    const float *V = c->viewmat;
    double pc[3] = {(px - c->cx) / c->fx * z - V[3], (py - c->cy) / c->fy * z - V[7],
                    z - V[11]};
    for (int k = 0; k < 3; k++)
        s->means[3 * i + k] = (float)(V[k] * pc[0] + V[4 + k] * pc[1] + V[8 + k] * pc[2]);
}

/* View rotation Rx(pitch) Ry(yaw), camera at distance dist from the world
 * origin along its optical axis. */
static inline void rt_set_view(rt_scene *s, double yaw, double pitch, double dist)
{
    double ca = cos(yaw), sa = sin(yaw), cb = cos(pitch), sb = sin(pitch);
    double R[9] = {ca, 0, sa, sb * sa, cb, -sb * ca, -cb * sa, sb, cb * ca};
    for (int k = 0; k < 3; k++) {
        for (int j = 0; j < 3; j++)
            s->cam.viewmat[4 * k + j] = (float)R[3 * k + j];
        s->cam.viewmat[4 * k + 3] = 0.0f;
    }
    s->cam.viewmat[11] = (float)dist;
}

/* Random scene in the style of the reference scenes: means spread past the
 * image, random rotations, log-scales and logits, random view rotation. */
static inline void rt_random_scene(rt_scene *s, uint64_t seed, int n, int C,
                                   int W, int H)
{
    rt_rng r = {seed};
    rt_scene_init(s, n, C, W, H);
    gs_camera *c = &s->cam;
    c->fx = (float)(0.9 * W);
    c->fy = (float)(0.95 * W);
    c->cx = (float)(0.48 * W);
    c->cy = (float)(0.52 * H);
    rt_set_view(s, 0.3, -0.2, 4.0);
    for (int i = 0; i < n; i++) {
        double z = rt_uniform(&r, 2.5, 6.0);
        rt_place(s, i, rt_uniform(&r, -0.15, 1.15) * W,
                 rt_uniform(&r, -0.15, 1.15) * H, z);
        for (int k = 0; k < 3; k++)
            s->log_scales[3 * i + k] = (float)rt_uniform(&r, log(0.015), log(0.2));
        for (int k = 0; k < 4; k++)
            s->quats[4 * i + k] = (float)rt_normal(&r);
        s->opacity_logits[i] = (float)rt_uniform(&r, -2.0, 7.0);
        for (int k = 0; k < C; k++)
            s->features[(size_t)i * C + k] = (float)rt_uniform(&r, -0.5, 1.5);
    }
}

/* ------------------------------------------------------------- one run */

/* Outputs and gradients of one forward + backward. */
typedef struct rt_result {
    int C, W, H, n;
    float *features, *alpha, *depth;                      /* C H W, H W, H W */
    float *g_means, *g_log_scales, *g_quats, *g_opacity, *g_features;
    float *g_background;                                  /* C H W */
    gs_raster_stats stats;
    int fwd_status, bwd_status;
} rt_result;

static inline void rt_result_free(rt_result *o)
{
    free(o->features);
    free(o->alpha);
    free(o->depth);
    free(o->g_means);
    free(o->g_log_scales);
    free(o->g_quats);
    free(o->g_opacity);
    free(o->g_features);
    free(o->g_background);
    memset(o, 0, sizeof *o);
}

/* Upstream gradients for a scene's image size; owned by the caller. */
/* memcmp of every output and gradient; names the first array that
 * differs. Stats (visible, intersections, contributions) must match too. */
static inline int rt_same_bytes(const char *what, const rt_result *a, const rt_result *b)
{
    size_t np = (size_t)a->W * a->H, nf = np * a->C, n = (size_t)a->n;
    struct {
        const char *name;
        const float *x, *y;
        size_t count;
    } arr[] = {{"features", a->features, b->features, nf},
               {"alpha", a->alpha, b->alpha, np},
               {"depth", a->depth, b->depth, np},
               {"grad means", a->g_means, b->g_means, n * 3},
               {"grad log_scales", a->g_log_scales, b->g_log_scales, n * 3},
               {"grad quats", a->g_quats, b->g_quats, n * 4},
               {"grad opacity", a->g_opacity, b->g_opacity, n},
               {"grad features", a->g_features, b->g_features, n * a->C},
               {"grad background", a->g_background, b->g_background, nf}};
    for (size_t i = 0; i < sizeof arr / sizeof arr[0]; i++) {
        if (memcmp(arr[i].x, arr[i].y, arr[i].count * sizeof(float)) != 0) {
            size_t k = 0;
            while (memcmp(&arr[i].x[k], &arr[i].y[k], sizeof(float)) == 0)
                k++;
            CHECK_MSG(0, "%s: %s differ first at [%zu]: %.9g vs %.9g", what,
                      arr[i].name, k, arr[i].x[k], arr[i].y[k]);
            return 0;
        }
    }
    CHECK_MSG(a->stats.visible == b->stats.visible &&
                  a->stats.intersections == b->stats.intersections &&
                  a->stats.contributions == b->stats.contributions,
              "%s: stats differ", what);
    return 1;
}

typedef struct rt_upstream {
    float *v_features, *v_alpha, *v_depth;
} rt_upstream;

static inline void rt_upstream_random(rt_upstream *u, const rt_scene *s,
                                      uint64_t seed)
{
    rt_rng r = {seed};
    size_t np = (size_t)s->cam.width * (size_t)s->cam.height;
    size_t nf = np * (size_t)s->g.channels;
    u->v_features = rt_alloc(nf, sizeof(float));
    u->v_alpha = rt_alloc(np, sizeof(float));
    u->v_depth = rt_alloc(np, sizeof(float));
    for (size_t i = 0; i < nf; i++)
        u->v_features[i] = (float)rt_normal(&r);
    for (size_t i = 0; i < np; i++) {
        u->v_alpha[i] = (float)rt_normal(&r);
        u->v_depth[i] = (float)(0.1 * rt_normal(&r));
    }
}

static inline void rt_upstream_free(rt_upstream *u)
{
    free(u->v_features);
    free(u->v_alpha);
    free(u->v_depth);
    memset(u, 0, sizeof *u);
}

/* A random scene (rt_random_scene) with a uniform [0, 1) background drawn
 * from bg_seed and random upstream gradients from up_seed; prints it. */
static inline void rt_scene_for_grads(rt_scene *s, rt_upstream *u, uint64_t seed, int n, int C,
                                      int W, int H, int aa, uint64_t bg_seed, uint64_t up_seed)
{
    rt_random_scene(s, seed, n, C, W, H);
    s->antialiased = aa;
    rt_scene_add_background(s);
    rt_rng rng = {bg_seed};
    for (size_t i = 0; i < (size_t)C * W * H; i++)
        s->background[i] = (float)rt_uniform(&rng, 0, 1);
    rt_upstream_random(u, s, up_seed);
    printf("scene: %d Gaussians, %dx%d, C=%d%s\n", n, W, H, C, aa ? ", antialiased" : "");
}

/* Runs forward and (when u is not NULL) backward on a fresh gs_raster.
 * Gradients start at zero. Statuses are returned in o; a failed step
 * leaves the remaining outputs at their zero/NaN fill. */
static inline void rt_run_with(gs_raster *r, const rt_scene *s,
                               gs_raster_path path, gs_pool *pool,
                               const rt_upstream *u, rt_result *o)
{
    int n = s->g.n, C = s->g.channels, W = s->cam.width, H = s->cam.height;
    size_t np = (size_t)W * (size_t)H;
    memset(o, 0, sizeof *o);
    o->C = C;
    o->W = W;
    o->H = H;
    o->n = n;
    o->features = rt_alloc(np * (size_t)C, sizeof(float));
    o->alpha = rt_alloc(np, sizeof(float));
    o->depth = rt_alloc(np, sizeof(float));
    o->g_means = rt_alloc((size_t)n * 3, sizeof(float));
    o->g_log_scales = rt_alloc((size_t)n * 3, sizeof(float));
    o->g_quats = rt_alloc((size_t)n * 4, sizeof(float));
    o->g_opacity = rt_alloc((size_t)n, sizeof(float));
    o->g_features = rt_alloc((size_t)n * (size_t)C, sizeof(float));
    o->g_background = rt_alloc(np * (size_t)C, sizeof(float));
    gs_raster_options opt = {.antialiased = s->antialiased, .path = path};
    gs_error err;
    o->fwd_status = gs_raster_forward(r, pool, &s->cam, &s->g, s->background,
                                      &opt, o->features, o->alpha, o->depth,
                                      &err);
    if (o->fwd_status != GS_OK) {
        fprintf(stderr, "  forward: %s\n", err.msg);
        return;
    }
    gs_raster_get_stats(r, &o->stats);
    if (!u)
        return;
    gs_gaussian_grads gr = {o->g_means, o->g_log_scales, o->g_quats,
                            o->g_opacity, o->g_features};
    o->bwd_status = gs_raster_backward(r, pool, u->v_features, u->v_alpha,
                                       u->v_depth, &gr, o->g_background, &err);
    if (o->bwd_status != GS_OK)
        fprintf(stderr, "  backward: %s\n", err.msg);
}

static inline void rt_run(const rt_scene *s, gs_raster_path path,
                          gs_pool *pool, const rt_upstream *u, rt_result *o)
{
    gs_raster *r = gs_raster_create();
    if (!r) {
        fprintf(stderr, "gs_raster_create failed\n");
        exit(2);
    }
    rt_run_with(r, s, path, pool, u, o);
    gs_raster_destroy(r);
}

static inline const char *rt_path_name(gs_raster_path p)
{
    return p == GS_RASTER_SCALAR ? "scalar" : "fast";
}

/* ---------------------------------------------------------- comparing */

static inline int rt_all_finite(const float *x, size_t n)
{
    for (size_t i = 0; i < n; i++) {
        if (!isfinite(x[i]))
            return 0;
    }
    return 1;
}

static inline int rt_all_zero(const float *x, size_t n)
{
    for (size_t i = 0; i < n; i++) {
        if (x[i] != 0.0f)
            return 0;
    }
    return 1;
}

static inline double rt_max_abs(const float *x, size_t n)
{
    double m = 0.0;
    for (size_t i = 0; i < n; i++)
        m = fmax(m, fabs((double)x[i]));
    return m;
}

/* Gradient comparison after gsplat's tests: entry i passes when
 * |got - want| <= atol_rel * max|want| + rtol * |want|. Entries whose
 * reference is below band * max|want| ("boundary band": tiny values that
 * the discontinuous 1/255 skip, early stop and culling can flip) may fail
 * in at most band_frac of all entries. Prints the max absolute error, the
 * max error relative to max|want|, and the failures. Returns failures that
 * count (0 = pass). */
static inline int rt_compare_grad(const char *what, const float *got,
                                  const float *want, size_t n,
                                  double atol_rel, double rtol, double band,
                                  double band_frac)
{
    double scale = rt_max_abs(want, n);
    double atol = atol_rel * scale;
    size_t bad = 0, banded = 0, worst = 0;
    double max_abs = 0.0, worst_excess = -1.0;
    for (size_t i = 0; i < n; i++) {
        double g = got[i], w = want[i], d = fabs(g - w);
        if (!isfinite(d))
            d = INFINITY;
        max_abs = fmax(max_abs, d);
        if (d <= atol + rtol * fabs(w))
            continue;
        if (fabs(w) < band * scale && isfinite(d)) {
            banded++;
            continue;
        }
        if (bad < 4)
            fprintf(stderr, "  %s[%zu]: got %.9g want %.9g (diff %.3g, tol %.3g)\n",
                    what, i, g, w, d, atol + rtol * fabs(w));
        if (d - atol - rtol * fabs(w) > worst_excess) {
            worst_excess = d - atol - rtol * fabs(w);
            worst = i;
        }
        bad++;
    }
    size_t band_limit = (size_t)(band_frac * (double)n);
    int fail = bad > 0 || banded > band_limit;
    printf("    %-16s n=%-6zu max|ref| %-10.4g max|diff| %-10.3g (%.2e of max) "
           "band %zu%s\n", what, n, scale, max_abs,
           scale > 0 ? max_abs / scale : 0.0, banded, fail ? "  FAIL" : "");
    gs_test_checks++;
    if (fail) {
        gs_test_failures++;
        fprintf(stderr, "%s: %zu over tolerance (atol %.3g = %g x max, rtol %g), "
                "%zu in the boundary band (limit %zu)",
                what, bad, atol, atol_rel, rtol, banded, band_limit);
        if (bad)
            fprintf(stderr, "; worst at %zu: got %.9g want %.9g", worst,
                    got[worst], want[worst]);
        fputc('\n', stderr);
    }
    return fail;
}

/* Image comparison: absolute tolerance, prints the max difference. */
static inline int rt_compare_image(const char *what, const float *got,
                                   const float *want, size_t n, double atol,
                                   double rtol)
{
    double max_abs = 0.0;
    for (size_t i = 0; i < n; i++) {
        double d = fabs((double)got[i] - want[i]);
        max_abs = isfinite(d) ? fmax(max_abs, d) : INFINITY;
    }
    printf("    %-16s n=%-6zu max|diff| %.3g (atol %g)\n", what, n, max_abs, atol);
    return gs_check_arrays(what, got, want, n, atol, rtol);
}

/* ------------------------------------------------------------ oracle */

/* Projection of one Gaussian in double, exactly as raster.h documents.
 * Returns 0 if culled. */
typedef struct rt_proj {
    double mx, my, a, b, c, opacity, depth;
    int tx0, tx1, ty0, ty1; /* tiles [tx0, tx1) x [ty0, ty1) */
} rt_proj;

static inline int rt_project_one(const rt_scene *s, int i, rt_proj *p)
{
    memset(p, 0, sizeof *p);
    const gs_camera *cam = &s->cam;
    const float *V = cam->viewmat;
    const float *q = s->quats + 4 * i, *ls = s->log_scales + 3 * i;
    const float *m = s->means + 3 * i;
    double qn = sqrt((double)q[0] * q[0] + (double)q[1] * q[1] +
                     (double)q[2] * q[2] + (double)q[3] * q[3]);
    double w = 1, x = 0, y = 0, z = 0;
    if (qn > 0) {
        w = q[0] / qn;
        x = q[1] / qn;
        y = q[2] / qn;
        z = q[3] / qn;
    }
    double R[9] = {1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
                   2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
                   2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)};
    double S[3] = {exp(ls[0]), exp(ls[1]), exp(ls[2])};
    double Sig[9], Sc[9], T[9];
    for (int r = 0; r < 3; r++) {
        for (int c = 0; c < 3; c++) {
            double acc = 0;
            for (int k = 0; k < 3; k++)
                acc += R[3 * r + k] * S[k] * S[k] * R[3 * c + k];
            Sig[3 * r + c] = acc;
        }
    }
    double mc[3];
    for (int r = 0; r < 3; r++)
        mc[r] = V[4 * r] * (double)m[0] + V[4 * r + 1] * (double)m[1] +
                V[4 * r + 2] * (double)m[2] + V[4 * r + 3];
    if (mc[2] < GS_RASTER_NEAR || mc[2] > GS_RASTER_FAR)
        return 0;
    for (int r = 0; r < 3; r++) { /* T = V Sig */
        for (int c = 0; c < 3; c++)
            T[3 * r + c] = V[4 * r] * Sig[c] + V[4 * r + 1] * Sig[3 + c] +
                           V[4 * r + 2] * Sig[6 + c];
    }
    for (int r = 0; r < 3; r++) { /* Sc = T V^T */
        for (int c = 0; c < 3; c++)
            Sc[3 * r + c] = T[3 * r] * V[4 * c] + T[3 * r + 1] * V[4 * c + 1] +
                            T[3 * r + 2] * V[4 * c + 2];
    }
    double fx = cam->fx, fy = cam->fy, cx = cam->cx, cy = cam->cy;
    double W = cam->width, H = cam->height, mz = mc[2];
    double mgn = GS_RASTER_CLAMP_MARGIN;
    double tx = mz * fmin((W - cx) / fx + mgn * W / fx, fmax(-(cx / fx + mgn * W / fx), mc[0] / mz));
    double ty = mz * fmin((H - cy) / fy + mgn * H / fy, fmax(-(cy / fy + mgn * H / fy), mc[1] / mz));
    double J[6] = {fx / mz, 0, -fx * tx / (mz * mz), 0, fy / mz, -fy * ty / (mz * mz)};
    double JS[6];
    for (int r = 0; r < 2; r++) {
        for (int c = 0; c < 3; c++)
            JS[3 * r + c] = J[3 * r] * Sc[c] + J[3 * r + 1] * Sc[3 + c] + J[3 * r + 2] * Sc[6 + c];
    }
    double s00 = JS[0] * J[0] + JS[1] * J[1] + JS[2] * J[2];
    double s01 = JS[0] * J[3] + JS[1] * J[4] + JS[2] * J[5];
    double s11 = JS[3] * J[3] + JS[4] * J[4] + JS[5] * J[5];
    double det0 = s00 * s11 - s01 * s01;
    s00 += GS_RASTER_EPS2D;
    s11 += GS_RASTER_EPS2D;
    double det = s00 * s11 - s01 * s01;
    if (!(det > 0))
        return 0;
    p->a = s11 / det;
    p->b = -s01 / det;
    p->c = s00 / det;
    p->opacity = 1.0 / (1.0 + exp(-(double)s->opacity_logits[i]));
    if (s->antialiased)
        p->opacity *= sqrt(fmax(0.0, det0 / det));
    double bb = 0.5 * (s00 + s11);
    double v1 = bb + sqrt(fmax(0.01, bb * bb - det));
    double rad = ceil(3.0 * sqrt(v1));
    p->mx = fx * mc[0] / mz + cx;
    p->my = fy * mc[1] / mz + cy;
    p->depth = mz;
    if (p->mx + rad <= 0 || p->mx - rad >= W || p->my + rad <= 0 || p->my - rad >= H)
        return 0;
    int ntx = (cam->width + GS_RASTER_TILE - 1) / GS_RASTER_TILE;
    int nty = (cam->height + GS_RASTER_TILE - 1) / GS_RASTER_TILE;
    p->tx0 = (int)fmin(fmax(0, floor((p->mx - rad) / GS_RASTER_TILE)), ntx);
    p->tx1 = (int)fmin(fmax(0, ceil((p->mx + rad) / GS_RASTER_TILE)), ntx);
    p->ty0 = (int)fmin(fmax(0, floor((p->my - rad) / GS_RASTER_TILE)), nty);
    p->ty1 = (int)fmin(fmax(0, ceil((p->my + rad) / GS_RASTER_TILE)), nty);
    return 1;
}

typedef struct rt_sortkey {
    double depth;
    int index;
} rt_sortkey;

static inline int rt_cmp_key(const void *pa, const void *pb)
{
    const rt_sortkey *a = pa, *b = pb;
    if (a->depth != b->depth)
        return a->depth < b->depth ? -1 : 1;
    return (a->index > b->index) - (a->index < b->index);
}

/* Forward in double: features C x H x W, alpha and depth H x W. */
static inline void rt_oracle_forward(const rt_scene *s, double *feat,
                                     double *alpha, double *depth)
{
    int n = s->g.n, C = s->g.channels, W = s->cam.width, H = s->cam.height;
    rt_proj *p = rt_alloc((size_t)n, sizeof *p);
    rt_sortkey *keys = rt_alloc((size_t)n, sizeof *keys);
    int nv = 0;
    for (int i = 0; i < n; i++) {
        if (rt_project_one(s, i, &p[i]))
            keys[nv++] = (rt_sortkey){p[i].depth, i};
    }
    qsort(keys, (size_t)nv, sizeof *keys, rt_cmp_key);
    for (int y = 0; y < H; y++) {
        for (int x = 0; x < W; x++) {
            int tx = x / GS_RASTER_TILE, ty = y / GS_RASTER_TILE;
            double T = 1.0, D = 0.0, F[GS_RASTER_MAX_CHANNELS] = {0};
            for (int k = 0; k < nv; k++) {
                const rt_proj *q = &p[keys[k].index];
                if (tx < q->tx0 || tx >= q->tx1 || ty < q->ty0 || ty >= q->ty1)
                    continue;
                double dx = q->mx - (x + 0.5), dy = q->my - (y + 0.5);
                double sg = 0.5 * (q->a * dx * dx + q->c * dy * dy) + q->b * dx * dy;
                double al = fmin(GS_RASTER_MAX_ALPHA, q->opacity * exp(-sg));
                if (sg < 0 || al < GS_RASTER_MIN_ALPHA)
                    continue;
                if (T * (1 - al) <= GS_RASTER_T_EPS)
                    break;
                const float *f = s->features + (size_t)keys[k].index * C;
                for (int c = 0; c < C; c++)
                    F[c] += f[c] * al * T;
                D += q->depth * al * T;
                T *= 1 - al;
            }
            size_t pix = (size_t)y * W + x;
            for (int c = 0; c < C; c++) {
                double bg = s->background ? s->background[(size_t)c * W * H + pix] : 0.0;
                feat[(size_t)c * W * H + pix] = F[c] + T * bg;
            }
            alpha[pix] = 1.0 - T;
            depth[pix] = D;
        }
    }
    free(p);
    free(keys);
}

/* Compares a run's forward outputs with the oracle. */
static inline int rt_check_oracle(const char *what, const rt_scene *s,
                                  const rt_result *o, double atol)
{
    size_t np = (size_t)s->cam.width * (size_t)s->cam.height;
    size_t nf = np * (size_t)s->g.channels;
    double *f = rt_alloc(nf, sizeof(double)), *a = rt_alloc(np, sizeof(double));
    double *d = rt_alloc(np, sizeof(double));
    float *ff = rt_alloc(nf, sizeof(float)), *af = rt_alloc(np, sizeof(float));
    float *df = rt_alloc(np, sizeof(float));
    rt_oracle_forward(s, f, a, d);
    for (size_t i = 0; i < nf; i++)
        ff[i] = (float)f[i];
    for (size_t i = 0; i < np; i++) {
        af[i] = (float)a[i];
        df[i] = (float)d[i];
    }
    char name[128];
    int bad = 0;
    snprintf(name, sizeof name, "%s features", what);
    bad += gs_check_arrays(name, o->features, ff, nf, atol, 1e-5);
    snprintf(name, sizeof name, "%s alpha", what);
    bad += gs_check_arrays(name, o->alpha, af, np, atol, 1e-5);
    snprintf(name, sizeof name, "%s depth", what);
    bad += gs_check_arrays(name, o->depth, df, np, atol, 1e-5);
    free(f);
    free(a);
    free(d);
    free(ff);
    free(af);
    free(df);
    return bad;
}

#endif
