/* Iris localizer, independent of any model: the limbus of one eye from the
 * image and the eye's 6 contour landmarks.
 *
 *   1. Grey patch around the eye, (2G + B) / 3 (a red-eye pupil reads
 *      dark there, a blue iris still differs from the sclera), box-averaged
 *      to at most MAX_EYE_PX across the eye, then opened (erosion, then
 *      dilation) by a square a quarter of the smallest radius wide: glints
 *      go, the edges of larger regions stay where they are.
 *   2. The opening: the patch pixels inside the contour shrunk by a
 *      margin, so lids and lashes never count as iris or sclera.
 *   3. Start: the disc that best splits the opening into a dark and a
 *      bright class (largest between-class variance), over a grid of
 *      centres and radii.
 *   4. Fit: the opening's grey modelled as a pupil disc inside a
 *      concentric iris disc on a sclera with a linear shading ramp, each
 *      disc edge an anti-aliased pixel ramp; the levels (pupil, iris,
 *      sclera ramp) enter linearly and are solved for at every step
 *      (variable projection), the centre and both radii by damped
 *      Gauss-Newton with Huber weights. The pupil level is free, so a
 *      dark pupil, a bright (red-eye) one or none at all all fit; where
 *      lids cover the top and bottom of the limbus, the pupil's edge and
 *      the curvature of the lateral limbus arcs still place the centre.
 *
 * Everything is in patch pixels until the result is written. */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "gazesplat/face.h"
#include "gazesplat/geom.h"

#include "face_internal.h"

#define PI 3.14159265358979323846
#define MAX_EYE_PX 96.0     /* eye width in the patch, after downsampling */
#define MAX_OPENING 1200    /* opening pixels the fit uses (subsampled past) */
#define NLIN 5              /* linear levels: pupil, iris, sclera + ramp */
#define NGEO 6              /* centre (2), iris radius, pupil radius, tilt (2) */
#define MAX_SHAPE 0.5       /* |e|: axis ratio down to 0.58 (55 deg off the view) */
#define LIMBUS_POINTS 64    /* samples of the circle for `visible` */
#define RAMP 1.0            /* anti-aliased edge width, patch px */
/* Priors of the fit, each weighing like PRIOR_PIXELS opening pixels one
 * robust sigma off: the major semi-axis about the middle of the searched
 * range (RADIUS_SD of it), the shape about a circle. */
#define PRIOR_PIXELS 10.0
#define RADIUS_SD 0.05
#define SHAPE_SD 0.3
#define MIN_ARC_SPAN 0.8
#define STRONG_PUPIL 0.3   /* pupil contrast, of the limbus contrast, that wins outright */
#define START_PUPIL 0.4   /* pupil size of the start search, of the radius */

void gs_face_iris_opts_default(gs_face_iris_opts *o)
{
    o->min_eye_width_px = 10;
    o->min_opening = 0.12;
    o->radius_min_px = 0;
    o->radius_max_px = 0;
    o->min_visible = 0.08;
    o->min_contrast = 8;
}

void gs_face_iris_opts_scale(gs_face_iris_opts *o, double px_per_mm)
{
    o->radius_min_px = GS_FACE_IRIS_RADIUS_MIN_MM * px_per_mm;
    o->radius_max_px = GS_FACE_IRIS_RADIUS_MAX_MM * px_per_mm;
}

/* ---- the eye's frame and contour ---- */

typedef struct eye_geom {
    double o[2], ex[2], ey[2];  /* corner midpoint, unit x (p0 -> p3), y */
    double width, opening;
    double poly[6][2];
} eye_geom;

static void eye_geom_make(const double p[6][2], eye_geom *g)
{
    double dx = p[3][0] - p[0][0], dy = p[3][1] - p[0][1];
    g->width = hypot(dx, dy);
    g->o[0] = 0.5 * (p[0][0] + p[3][0]);
    g->o[1] = 0.5 * (p[0][1] + p[3][1]);
    double w = g->width > 0 ? g->width : 1;
    g->ex[0] = dx / w;
    g->ex[1] = dy / w;
    g->ey[0] = -g->ex[1]; /* 90 deg clockwise on screen: image down */
    g->ey[1] = g->ex[0];
    double h1 = (p[5][0] - p[1][0]) * g->ey[0] + (p[5][1] - p[1][1]) * g->ey[1];
    double h2 = (p[4][0] - p[2][0]) * g->ey[0] + (p[4][1] - p[2][1]) * g->ey[1];
    g->opening = 0.5 * (h1 + h2) / w;
    memcpy(g->poly, p, sizeof g->poly);
}

/* Eye-frame coordinates of an image point. */
static void to_frame(const eye_geom *g, double x, double y, double *a, double *b)
{
    double dx = x - g->o[0], dy = y - g->o[1];
    *a = dx * g->ex[0] + dy * g->ex[1];
    *b = dx * g->ey[0] + dy * g->ey[1];
}

/* face_internal.h */
double gs_face_contour_dist(const double pg[6][2], double qx, double qy)
{
    double best = INFINITY;
    int inside = 0;
    for (int i = 0, j = 5; i < 6; j = i++) {
        const double *a = pg[j], *b = pg[i];
        double ex = b[0] - a[0], ey = b[1] - a[1];
        double wx = qx - a[0], wy = qy - a[1];
        double ee = ex * ex + ey * ey;
        double t = ee > 0 ? (wx * ex + wy * ey) / ee : 0;
        t = t < 0 ? 0 : t > 1 ? 1 : t;
        double px = wx - t * ex, py = wy - t * ey, d = sqrt(px * px + py * py);
        if (d < best)
            best = d;
        if ((a[1] > qy) != (b[1] > qy) && qx < a[0] + (qy - a[1]) * ex / ey)
            inside = !inside;
    }
    return inside ? -best : best;
}

/* ---- the grey patch ---- */

/* One pixel of the opening: patch coordinates of its centre, eye-frame
 * coordinates in eye widths (for the shading ramp), grey. */
typedef struct opx {
    float u, v, a, b, g;
} opx;

/* Patch pixel (i, j) averages image pixels [x0 + s i, x0 + s (i + 1)) x
 * [y0 + s j, ...): patch coordinate u maps to image x0 + s u (pixel
 * centres at +0.5 in both). Pixels off the image are NaN. One allocation
 * holds the grey, a scratch plane and the opening's pixels. */
typedef struct patch {
    int w, h, s, x0, y0;
    float *g, *tmp;
    opx *op;
    int n_op;
    unsigned char *in;   /* pixel centre inside the contour */
} patch;

static float grey_at(const gs_io_image *img, int x, int y)
{
    const unsigned char *p = img->data + (size_t)y * img->stride + 3 * (size_t)x;
    return (2.0f * p[1] + p[2]) / 3.0f;
}

static int patch_make(const gs_io_image *img, const double poly[6][2], const double lo[2],
                      const double hi[2], int s, patch *p)
{
    p->s = s;
    p->x0 = (int)floor(lo[0]);
    p->y0 = (int)floor(lo[1]);
    p->w = (int)ceil((hi[0] - p->x0) / s) + 1;
    p->h = (int)ceil((hi[1] - p->y0) / s) + 1;
    size_t npx = (size_t)p->w * (size_t)p->h;
    p->g = malloc(2 * npx * sizeof(float) + MAX_OPENING * sizeof(opx) + npx);
    if (!p->g)
        return -1;
    p->tmp = p->g + npx;
    p->op = (opx *)(p->tmp + npx);
    p->in = (unsigned char *)(p->op + MAX_OPENING);
    p->n_op = 0;
    float inv = 1.0f / (float)(s * s);
    for (int j = 0; j < p->h; j++)
        for (int i = 0; i < p->w; i++) {
            int x = p->x0 + s * i, y = p->y0 + s * j;
            float *d = p->g + (size_t)j * p->w + i;
            p->in[(size_t)j * p->w + i] = gs_face_contour_dist(poly, x + 0.5 * s, y + 0.5 * s) <= 0;
            if (x < 0 || y < 0 || x + s > img->width || y + s > img->height) {
                *d = NAN;
                continue;
            }
            float a = 0;
            for (int v = 0; v < s; v++)
                for (int u = 0; u < s; u++)
                    a += grey_at(img, x + u, y + v);
            *d = a * inv;
        }
    return 0;
}

/* One pass of a k-wide running min (or max) along rows or columns; NaN
 * (off the image) spreads, so nothing off the image is ever sampled. */
static void minmax_pass(const float *in, float *out, int w, int h, int k, int horiz, int is_max)
{
    int r = k / 2;
    for (int j = 0; j < h; j++)
        for (int i = 0; i < w; i++) {
            float m = in[(size_t)j * w + i];
            for (int d = -r; d <= r && !isnan(m); d++) {
                int x = horiz ? i + d : i, y = horiz ? j : j + d;
                if (x < 0 || y < 0 || x >= w || y >= h)
                    continue;
                float v = in[(size_t)y * w + x];
                if (isnan(v) || (is_max ? v > m : v < m))
                    m = v;
            }
            out[(size_t)j * w + i] = m;
        }
}

/* Grey opening by a k x k square (k odd). */
static void patch_open(patch *p, int k)
{
    minmax_pass(p->g, p->tmp, p->w, p->h, k, 1, 0);
    minmax_pass(p->tmp, p->g, p->w, p->h, k, 0, 0);
    minmax_pass(p->g, p->tmp, p->w, p->h, k, 1, 1);
    minmax_pass(p->tmp, p->g, p->w, p->h, k, 0, 1);
}

/* Collects the opening: pixels whose centre lies `shrink` image px inside
 * the contour, every stride-th row and column so that at most MAX_OPENING
 * are kept. */
static void patch_opening(patch *p, const eye_geom *g, double shrink)
{
    for (int stride = 1;; stride++) {
        int n = 0;
        for (int j = 0; j < p->h; j += stride)
            for (int i = 0; i < p->w; i += stride) {
                float v = p->g[(size_t)j * p->w + i];
                double x = p->x0 + p->s * (i + 0.5), y = p->y0 + p->s * (j + 0.5);
                if (isnan(v) || gs_face_contour_dist(g->poly, x, y) > -shrink)
                    continue;
                if (n < MAX_OPENING) {
                    double a, b;
                    to_frame(g, x, y, &a, &b);
                    p->op[n] = (opx){(float)(i + 0.5), (float)(j + 0.5),
                                     (float)(a / g->width), (float)(b / g->width), v};
                }
                n++;
            }
        if (n <= MAX_OPENING) {
            p->n_op = n;
            return;
        }
    }
}

/* Bilinear sample at patch coordinates; 0 when off the patch or image. */
static int sample(const patch *p, double u, double v, double *out)
{
    double x = u - 0.5, y = v - 0.5;
    if (!(x >= 0 && y >= 0))
        return 0;
    int i = (int)x, j = (int)y;
    if (i + 1 >= p->w || j + 1 >= p->h)
        return 0;
    double fx = x - i, fy = y - j;
    const float *a = p->g + (size_t)j * p->w + i;
    float a00 = a[0], a01 = a[1], a10 = a[p->w], a11 = a[p->w + 1];
    if (isnan(a00) || isnan(a01) || isnan(a10) || isnan(a11))
        return 0;
    *out = (1 - fy) * ((1 - fx) * a00 + fx * a01) + fy * ((1 - fx) * a10 + fx * a11);
    return 1;
}

/* ---- start: the disc that best splits the opening ---- */

typedef struct circle {
    double u, v, r, score;
} circle;

/* Coverage of a pixel at distance d from the centre by a disc of radius r:
 * a linear ramp RAMP px wide across the edge. */
static double cover(double r, double d)
{
    double m = (r - d) / RAMP + 0.5;
    return m <= 0 ? 0 : m >= 1 ? 1 : m;
}

static double start_score(const patch *p, const double *w, double cu, double cv, double r);

/* Best start over centres on a grid of `step` in the eye-frame box
 * [a0, a1] x [b0, b1] (patch px about the frame origin o) and radii r0..r1
 * in steps of 6 %. */
static void best_start(const patch *p, const double *w, const eye_geom *g, const double o[2],
                       const double box[4], double r0, double r1, double step, circle *best)
{
    int na = (int)floor((box[1] - box[0]) / step) + 1;
    int nb = (int)floor((box[3] - box[2]) / step) + 1;
    for (int j = 0; j < nb; j++)
        for (int i = 0; i < na; i++) {
            double x = box[0] + i * step, y = box[2] + j * step;
            double cu = o[0] + x * g->ex[0] + y * g->ey[0];
            double cv = o[1] + x * g->ex[1] + y * g->ey[1];
            for (double r = r0; r <= r1 * 1.0001; r *= 1.06) {
                double sc = start_score(p, w, cu, cv, r);
                if (sc > best->score)
                    *best = (circle){cu, cv, r, sc};
            }
        }
}

/* ---- fit: pupil and iris discs on a shaded sclera ---- */

/* The iris and pupil are concentric circles on one plane; seen from the
 * camera, concentric ellipses of one shape. A point q from the centre lies
 * on the ellipse of size R when q^T M q = R^2, M = [1 + e1, e2; e2, 1 - e1]
 * (|e| < 1): semi-axes R / sqrt(1 -+ |e|), the major one the circle's
 * radius. The shape enters linearly, so the fit can leave the circle. */
typedef struct model {
    double t[NGEO];     /* centre u, v; iris size; pupil size; shape e1, e2 */
    double beta[NLIN];  /* pupil, iris, sclera, sclera ramp along a, b */
    double sse;         /* weighted sum of squared residuals */
} model;

/* Elliptic radius of q from the centre and its gradient's length. */
static void ell_dist(const double t[NGEO], double qu, double qv, double *de, double *gm)
{
    double mu = (1 + t[4]) * qu + t[5] * qv, mv = t[5] * qu + (1 - t[4]) * qv;
    double d2 = qu * mu + qv * mv;
    *de = sqrt(d2 > 0 ? d2 : 0);
    *gm = *de > 1e-9 ? sqrt(mu * mu + mv * mv) / *de : 1;
}

/* Coverage by the ellipse of radius r: the elliptic distance turned into
 * image px by its gradient. */
static double cover_ell(double r, double de, double gm)
{
    return cover(r, r - (r - de) / gm);
}

static void basis(const opx *q, const double t[NGEO], double f[NLIN])
{
    double de, gm;
    ell_dist(t, q->u - t[0], q->v - t[1], &de, &gm);
    double mi = cover_ell(t[2], de, gm), mp = cover_ell(t[3], de, gm);
    f[0] = mp;
    f[1] = mi - mp;
    f[2] = 1 - mi;
    f[3] = (1 - mi) * q->a;
    f[4] = (1 - mi) * q->b;
}

/* Cholesky solve of the n x n SPD system a x = b (a overwritten); 0 when
 * not positive definite. */
static int chol_solve(double *a, double *b, int n)
{
    for (int j = 0; j < n; j++) {
        double s = a[j * n + j];
        for (int k = 0; k < j; k++)
            s -= a[j * n + k] * a[j * n + k];
        if (!(s > 1e-12))
            return 0;
        a[j * n + j] = sqrt(s);
        for (int i = j + 1; i < n; i++) {
            double t = a[i * n + j];
            for (int k = 0; k < j; k++)
                t -= a[i * n + k] * a[j * n + k];
            a[i * n + j] = t / a[j * n + j];
        }
    }
    for (int i = 0; i < n; i++) {
        double t = b[i];
        for (int k = 0; k < i; k++)
            t -= a[i * n + k] * b[k];
        b[i] = t / a[i * n + i];
    }
    for (int i = n - 1; i >= 0; i--) {
        double t = b[i];
        for (int k = i + 1; k < n; k++)
            t -= a[k * n + i] * b[k];
        b[i] = t / a[i * n + i];
    }
    return 1;
}

/* The levels for geometry t by weighted least squares (a small ridge keeps
 * an absent pupil or sclera solvable), the residuals into res (may be
 * NULL) and the weighted SSE into m. */
static void solve_levels(const patch *p, const double *w, const double t[NGEO], model *m,
                         double *res)
{
    double a[NLIN * NLIN] = {0}, b[NLIN] = {0}, f[NLIN];
    for (int k = 0; k < p->n_op; k++) {
        basis(&p->op[k], t, f);
        for (int i = 0; i < NLIN; i++) {
            b[i] += w[k] * f[i] * p->op[k].g;
            for (int j = 0; j <= i; j++)
                a[i * NLIN + j] += w[k] * f[i] * f[j];
        }
    }
    for (int i = 0; i < NLIN; i++)
        for (int j = i + 1; j < NLIN; j++)
            a[i * NLIN + j] = a[j * NLIN + i];
    /* A small ridge: the pupil level toward the iris level (no pupil
     * seen), the shading ramp toward none, the sclera level toward 0 (no
     * sclera seen), so every geometry has levels. */
    double ridge = 1e-3 * (double)p->n_op;
    a[0 * NLIN + 0] += ridge;
    a[1 * NLIN + 1] += ridge;
    a[0 * NLIN + 1] -= ridge;
    a[1 * NLIN + 0] -= ridge;
    a[2 * NLIN + 2] += 1e-3 * ridge;
    a[3 * NLIN + 3] += 10 * ridge;
    a[4 * NLIN + 4] += 10 * ridge;
    memcpy(m->t, t, sizeof m->t);
    if (!chol_solve(a, b, NLIN)) {
        m->sse = INFINITY;
        return;
    }
    memcpy(m->beta, b, sizeof m->beta);
    double sse = 0;
    for (int k = 0; k < p->n_op; k++) {
        basis(&p->op[k], t, f);
        double r = p->op[k].g;
        for (int i = 0; i < NLIN; i++)
            r -= b[i] * f[i];
        if (res)
            res[k] = r;
        sse += w[k] * r * r;
    }
    m->sse = sse;
}

/* The start's score: minus the misfit of an iris disc (no pupil) on the
 * shaded sclera; -inf unless the disc is darker than the sclera. */
static double start_score(const patch *p, const double *w, double cu, double cv, double r)
{
    double t[NGEO] = {cu, cv, r, START_PUPIL * r, 0, 0};
    model m;
    solve_levels(p, w, t, &m, NULL);
    return m.beta[2] > m.beta[1] ? -m.sse : -INFINITY;
}

static int cmp_double(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

/* Keeps the geometry in its box: radius in [r0, r1], pupil within
 * [0.12, 0.75] of it. */
/* The ellipse's major semi-axis (the iris radius) from the size. */
static double major_axis(const double t[NGEO])
{
    return t[2] / sqrt(1 - hypot(t[4], t[5]));
}

static void clamp_geo(double t[NGEO], double r0, double r1)
{
    double el = hypot(t[4], t[5]);
    if (el > MAX_SHAPE) {
        t[4] *= MAX_SHAPE / el;
        t[5] *= MAX_SHAPE / el;
        el = MAX_SHAPE;
    }
    double k = sqrt(1 - el);
    t[2] = t[2] < r0 * k ? r0 * k : t[2] > r1 * k ? r1 * k : t[2];
    double p0 = 0.12 * t[2], p1 = 0.75 * t[2];
    t[3] = t[3] < p0 ? p0 : t[3] > p1 ? p1 : t[3];
}

typedef struct fit_out {
    model m;
    double cost;       /* unit-weight SSE plus the priors, at one scale */
    double rms;        /* robust rms residual, grey levels */
    double cov_c[3];   /* centre covariance uu, vv, uv */
} fit_out;

/* Damped Gauss-Newton on the geometry with the levels projected out;
 * Huber weights from the residuals of the previous step (scale 1.4826 x
 * their median magnitude). w holds n_op weights, res (2 + NGEO) n_op. */
/* Gaussian priors on the geometry: mean and 1/sigma^2 (0: none), in
 * units of the robust residual variance per opening pixel. */
typedef struct prior {
    double mean[NGEO], inv_var[NGEO];
} prior;

/* The priors' cost; the radius prior is on the major semi-axis. */
static double prior_cost(const prior *pr, const double t[NGEO], double k)
{
    double c = 0;
    for (int i = 0; i < NGEO; i++) {
        double x = i == 2 ? major_axis(t) : t[i];
        c += k * pr->inv_var[i] * (x - pr->mean[i]) * (x - pr->mean[i]);
    }
    return c;
}

/* The residuals at t moved by h[i] along each parameter i, into column i
 * of col (NGEO columns of n_op): the forward differences' other ends. */
static void step_residuals(const patch *p, const double *w, const double t[NGEO],
                           const double h[NGEO], double *col)
{
    for (int i = 0; i < NGEO; i++) {
        double ti[NGEO];
        memcpy(ti, t, sizeof ti);
        ti[i] += h[i];
        model mi;
        solve_levels(p, w, ti, &mi, col + (size_t)i * p->n_op);
    }
}

/* Huber weights at 1.345 robust sigmas of the residuals (res: n, then
 * n of scratch); returns the robust sigma (at least 1). */
static double huber_weights(double *res, double *w, int n)
{
    double *mag = res + n; /* scratch after the residuals */
    for (int k = 0; k < n; k++)
        mag[k] = fabs(res[k]);
    qsort(mag, (size_t)n, sizeof *mag, cmp_double);
    double scale = fmax(1.0, 1.4826 * mag[n / 2]);
    double c = 1.345 * scale;
    for (int k = 0; k < n; k++)
        w[k] = fabs(res[k]) <= c ? 1 : c / fabs(res[k]);
    return scale;
}

/* One Levenberg-Marquardt step from t on the normal equations (jtj, jtr)
 * at cost `cost`, the damping adapted by the outcome: 0 when no step
 * lowered the cost, 1 when one did, 2 when it barely moved. */
static int lm_step(const patch *p, const double *w, double t[NGEO], const double *jtj,
                   const double *jtr, double cost, double kp, const prior *pr, double r0,
                   double r1, double *lambda)
{
    /* Levenberg-Marquardt step, the damping adapted by the outcome. */
    int improved = 0;
    for (int tries = 0; tries < 8 && !improved; tries++) {
        double a[NGEO * NGEO], step[NGEO];
        memcpy(a, jtj, sizeof a);
        for (int i = 0; i < NGEO; i++) {
            a[i * NGEO + i] += *lambda * (jtj[i * NGEO + i] + 1e-6);
            step[i] = -jtr[i];
        }
        if (!chol_solve(a, step, NGEO)) {
            *lambda *= 10;
            continue;
        }
        double tn[NGEO];
        for (int i = 0; i < NGEO; i++)
            tn[i] = t[i] + step[i];
        clamp_geo(tn, r0, r1);
        model mn;
        solve_levels(p, w, tn, &mn, NULL);
        if (mn.sse + prior_cost(pr, tn, kp) < cost) {
            double moved = fabs(tn[0] - t[0]) + fabs(tn[1] - t[1]) + fabs(tn[2] - t[2]);
            memcpy(t, tn, sizeof tn);
            *lambda = fmax(1e-4, *lambda * 0.3);
            improved = 1 + (moved < 1e-4);
        } else {
            *lambda *= 10;
        }
    }
    return improved;
}

/* The robust rms and the centre's covariance sigma^2 (J^T W J)^-1 at t,
 * res holding t's residuals (then scratch for the Jacobian). */
static void centre_cov(const patch *p, const double *w, const double t[NGEO], double sse,
                       double *res, const prior *pr, fit_out *out)
{
    static const double h[NGEO] = {0.05, 0.05, 0.05, 0.05, 0.01, 0.01};
    int n = p->n_op;
    double sw = 0;
    for (int k = 0; k < n; k++)
        sw += w[k];
    out->rms = sw > 0 ? sqrt(sse / sw) : NAN;
    double *col = res + 2 * n, jtj[NGEO * NGEO] = {0};
    step_residuals(p, w, t, h, col);
    for (int k = 0; k < n; k++)
        for (int i = 0; i < NGEO; i++) {
            double ji = (col[(size_t)i * n + k] - res[k]) / h[i];
            for (int j = 0; j <= i; j++)
                jtj[i * NGEO + j] += w[k] * ji * (col[(size_t)j * n + k] - res[k]) / h[j];
        }
    double var = out->rms * out->rms;
    for (int i = 0; i < NGEO; i++) {
        for (int j = i + 1; j < NGEO; j++)
            jtj[i * NGEO + j] = jtj[j * NGEO + i];
        jtj[i * NGEO + i] += var * PRIOR_PIXELS * pr->inv_var[i];
    }
    out->cov_c[0] = out->cov_c[1] = out->cov_c[2] = NAN;
    for (int c = 0; c < 2; c++) {
        double a[NGEO * NGEO], e[NGEO] = {0};
        memcpy(a, jtj, sizeof a);
        e[c] = 1;
        if (!chol_solve(a, e, NGEO))
            return;
        out->cov_c[c] = var * e[c];
        if (c == 0)
            out->cov_c[2] = var * e[1];
    }
}

static void fit_model(const patch *p, const double start[NGEO], double r0, double r1,
                      const prior *pr, double *w, double *res, fit_out *out)
{
    static const double h[NGEO] = {0.05, 0.05, 0.05, 0.05, 0.01, 0.01};
    int n = p->n_op;
    for (int k = 0; k < n; k++)
        w[k] = 1;
    double t[NGEO];
    memcpy(t, start, sizeof t);
    clamp_geo(t, r0, r1);
    model cur;
    solve_levels(p, w, t, &cur, res);
    double lambda = 1e-2, scale = 1;
    for (int it = 0; it < 30; it++) {
        scale = huber_weights(res, w, n);
        solve_levels(p, w, t, &cur, res);
        double kp = scale * scale * PRIOR_PIXELS;
        /* Jacobian of the residuals by forward differences. */
        double jtj[NGEO * NGEO] = {0}, jtr[NGEO] = {0};
        double *col = res + 2 * n;  /* NGEO columns of n */
        step_residuals(p, w, t, h, col);
        for (int i = 0; i < NGEO; i++)
            for (int k = 0; k < n; k++)
                col[(size_t)i * n + k] = (col[(size_t)i * n + k] - res[k]) / h[i];
        for (int k = 0; k < n; k++)
            for (int i = 0; i < NGEO; i++) {
                double ji = col[(size_t)i * n + k];
                jtr[i] += w[k] * ji * res[k];
                for (int j = 0; j <= i; j++)
                    jtj[i * NGEO + j] += w[k] * ji * col[(size_t)j * n + k];
            }
        for (int i = 0; i < NGEO; i++) {
            for (int j = i + 1; j < NGEO; j++)
                jtj[i * NGEO + j] = jtj[j * NGEO + i];
            jtj[i * NGEO + i] += kp * pr->inv_var[i];
            jtr[i] += kp * pr->inv_var[i] * ((i == 2 ? major_axis(t) : t[i]) - pr->mean[i]);
        }
        double cost = cur.sse + prior_cost(pr, t, kp);
        int improved = lm_step(p, w, t, jtj, jtr, cost, kp, pr, r0, r1, &lambda);
        solve_levels(p, w, t, &cur, res);
        if (!improved || improved == 2)
            break;
    }
    out->m = cur;
    {
        /* A cost comparable between fits: Huber on the residuals at a
         * fixed scale (the ramp's 10 grey levels), plus the priors. */
        double cst = 0, hc = 10;
        for (int k = 0; k < n; k++) {
            double a = fabs(res[k]);
            cst += a <= hc ? a * a : hc * (2 * a - hc);
        }
        out->cost = cst + prior_cost(pr, t, hc * hc * PRIOR_PIXELS);
    }
    centre_cov(p, w, t, cur.sse, res, pr, out);
}

/* Fraction of the circle's points inside the contour where the grey steps
 * up across the limbus by at least 35 % of the fitted sclera-iris
 * contrast there. */
static double limbus_visible(const patch *p, const eye_geom *g, const model *m, int sides[2],
                             double *span)
{
    int seen = 0;
    double lo = 1, hi = -1;
    sides[0] = sides[1] = 0;
    double el = hypot(m->t[4], m->t[5]), half = 0.5 * atan2(m->t[5], m->t[4]);
    double au = cos(half), av = sin(half);  /* eigenvector of 1 + |e|: minor axis */
    double sa = m->t[2] / sqrt(1 + el), sb = m->t[2] / sqrt(1 - el);
    for (int k = 0; k < LIMBUS_POINTS; k++) {
        double an = 2 * PI * k / LIMBUS_POINTS;
        /* Ellipse point and its normal (along M q). */
        double qa = sa * cos(an), qb = sb * sin(an);
        double qu = qa * au - qb * av, qv = qa * av + qb * au;
        double u = m->t[0] + qu, v = m->t[1] + qv;
        double na = (1 + el) * qa, nb = (1 - el) * qb, nl = hypot(na, nb);
        double du = (na * au - nb * av) / nl, dv = (na * av + nb * au) / nl;
        double x = p->x0 + p->s * u, y = p->y0 + p->s * v;
        if (gs_face_contour_dist(g->poly, x, y) > 0)
            continue;
        double in, outv, a, b;
        if (!sample(p, u - du, v - dv, &in) || !sample(p, u + du, v + dv, &outv))
            continue;
        to_frame(g, x, y, &a, &b);
        double sclera = m->beta[2] + m->beta[3] * a / g->width + m->beta[4] * b / g->width;
        double con = sclera - m->beta[1];
        if (con > 0 && outv - in >= 0.35 * con) {
            seen++;
            sides[(du * g->ex[0] + dv * g->ex[1]) > 0]++;
            double up = du * g->ey[0] + dv * g->ey[1];
            lo = fmin(lo, up);
            hi = fmax(hi, up);
        }
    }
    *span = hi > lo ? hi - lo : 0;
    return (double)seen / LIMBUS_POINTS;
}

/* ---- the pupil: a disc darker (or brighter) than the iris around it ---- */

/* How well a disc of radius rho at (cu, cv) stands out of the ring rho..
 * 1.6 rho around it, counting the pixels inside the contour and inside the
 * limbus ellipse t: the ring is cut into four quadrants and the contrast is
 * the weakest quadrant's (a pupil differs from the iris on every side, a
 * lid's shadow or a lash line only on one), signed: > 0 for a dark disc.
 * Returns |contrast| sqrt(disc pixels), 0 when under 60 % of the disc or
 * under three quadrants (each 40 % present) lie inside. */
/* The grey where a pupil may be, into p->tmp: pixels inside the contour
 * and 0.75 px inside the limbus ellipse t; NaN elsewhere. */
static void pupil_plane(patch *p, const double t[NGEO])
{
    for (int j = 0; j < p->h; j++)
        for (int i = 0; i < p->w; i++) {
            size_t k = (size_t)j * p->w + i;
            double de, gm;
            ell_dist(t, i + 0.5 - t[0], j + 0.5 - t[1], &de, &gm);
            p->tmp[k] = p->in[k] && de <= t[2] - 0.75 ? p->g[k] : NAN;
        }
}

static double pupil_score(const patch *p, double cu, double cv, double rho, double *delta)
{
    double outer = 1.6 * rho, sd = 0, nd = 0, fd = 0;
    double sq[4] = {0}, nq[4] = {0}, fq[4] = {0};
    int i0 = (int)floor(cu - outer - 1), i1 = (int)ceil(cu + outer + 1);
    int j0 = (int)floor(cv - outer - 1), j1 = (int)ceil(cv + outer + 1);
    for (int j = j0 < 0 ? 0 : j0; j <= j1 && j < p->h; j++)
        for (int i = i0 < 0 ? 0 : i0; i <= i1 && i < p->w; i++) {
            double du = i + 0.5 - cu, dv = j + 0.5 - cv, d = sqrt(du * du + dv * dv);
            double md = cover(rho, d), mr = cover(outer, d) - md;
            if (md <= 0 && mr <= 0)
                continue;
            int q = (du >= 0) + 2 * (dv >= 0);
            fd += md;
            fq[q] += mr;
            float v = p->tmp[(size_t)j * p->w + i];
            if (isnan(v))
                continue;
            sd += md * v;
            nd += md;
            sq[q] += mr * v;
            nq[q] += mr;
        }
    *delta = 0;
    if (nd < 0.6 * fd || nd < 1)
        return 0;
    double mind = sd / nd, lo = INFINITY, hi = -INFINITY;
    int quads = 0;
    for (int q = 0; q < 4; q++) {
        if (nq[q] < 0.4 * fq[q] || nq[q] < 0.5)
            continue;
        double dq = sq[q] / nq[q] - mind;
        lo = fmin(lo, dq);
        hi = fmax(hi, dq);
        quads++;
    }
    if (quads < 3)
        return 0;
    /* Dark disc: every quadrant brighter (lo > 0); bright: every one
     * darker (hi < 0). */
    *delta = lo > 0 ? lo : hi < 0 ? hi : 0;
    return fabs(*delta) * sqrt(nd);
}

typedef struct pupil {
    double u, v, rho, delta, score;
} pupil;

/* Best pupil within `reach` of (cu, cv), radius rlo..rhi: a grid of 0.5
 * patch px and 10 % radius steps, then one of 0.1 px and 3 % around the
 * best. */
static pupil find_pupil(patch *p, const double t[NGEO], double cu, double cv, double reach,
                        double rlo, double rhi)
{
    pupil_plane(p, t);
    pupil best = {cu, cv, 0, 0, 0};
    for (int pass = 0; pass < 2; pass++) {
        double step = pass ? 0.1 : 0.5, rstep = pass ? 1.03 : 1.1;
        double u0 = pass ? best.u : cu, v0 = pass ? best.v : cv, span = pass ? 0.6 : reach;
        double ra = pass ? fmax(rlo, best.rho / 1.1) : rlo;
        double rb = pass ? fmin(rhi, best.rho * 1.1) : rhi;
        if (pass && !(best.score > 0))
            break;
        int nstep = (int)floor(span / step);
        for (int j = -nstep; j <= nstep; j++)
            for (int i = -nstep; i <= nstep; i++) {
                double u = u0 + i * step, v = v0 + j * step;
                if (!pass && (u - cu) * (u - cu) + (v - cv) * (v - cv) > reach * reach)
                    continue;
                for (double r = ra; r <= rb * 1.0001; r *= rstep) {
                    double dl, sc = pupil_score(p, u, v, r, &dl);
                    if (sc > best.score)
                        best = (pupil){u, v, r, dl, sc};
                }
            }
    }
    return best;
}

/* ---- colour ---- */

static double srgb_to_linear(double c)
{
    c /= 255.0;
    return c <= 0.04045 ? c / 12.92 : pow((c + 0.055) / 1.055, 2.4);
}

static double lab_f(double t)
{
    const double d = 6.0 / 29.0;
    return t > d * d * d ? cbrt(t) : t / (3 * d * d) + 4.0 / 29.0;
}

/* sRGB (D65) to CIELAB. */
static void rgb_to_lab(const unsigned char *p, double lab[3])
{
    double r = srgb_to_linear(p[0]), g = srgb_to_linear(p[1]), b = srgb_to_linear(p[2]);
    double x = (0.4124564 * r + 0.3575761 * g + 0.1804375 * b) / 0.95047;
    double y = 0.2126729 * r + 0.7151522 * g + 0.0721750 * b;
    double z = (0.0193339 * r + 0.1191920 * g + 0.9503041 * b) / 1.08883;
    double fx = lab_f(x), fy = lab_f(y), fz = lab_f(z);
    lab[0] = 116 * fy - 16;
    lab[1] = 500 * (fx - fy);
    lab[2] = 200 * (fy - fz);
}

/* Mean Lab of the image pixels of the iris ring (outside the pupil plus
 * a pixel, inside 0.9 of the radius) within the contour; pixels 20 L
 * above the ring's median (glints) left out. Two passes, no storage. */
static void iris_lab(const gs_io_image *img, const eye_geom *g, double cx, double cy, double r,
                     double rp, gs_face_iris *out)
{
    int x0 = (int)floor(cx - r), x1 = (int)ceil(cx + r);
    int y0 = (int)floor(cy - r), y1 = (int)ceil(cy + r);
    x0 = x0 < 0 ? 0 : x0;
    y0 = y0 < 0 ? 0 : y0;
    x1 = x1 > img->width - 1 ? img->width - 1 : x1;
    y1 = y1 > img->height - 1 ? img->height - 1 : y1;
    double inner = fmin(rp + 1, 0.75 * r), outer = 0.9 * r, lmax = 100;
    int hist[101] = {0}, n = 0, m = 0;
    double acc[3] = {0, 0, 0};
    for (int pass = 0; pass < 2; pass++) {
        if (pass == 1) {
            int c = 0, k = 0;
            for (; k < 100 && 2 * (c + hist[k]) < n; k++)
                c += hist[k];
            lmax = k + 20;
        }
        for (int y = y0; y <= y1; y++)
            for (int x = x0; x <= x1; x++) {
                double dx = x + 0.5 - cx, dy = y + 0.5 - cy, d = sqrt(dx * dx + dy * dy);
                if (d < inner || d > outer || gs_face_contour_dist(g->poly, x + 0.5, y + 0.5) > 0)
                    continue;
                double lab[3];
                rgb_to_lab(img->data + (size_t)y * img->stride + 3 * (size_t)x, lab);
                if (pass == 0) {
                    int k = (int)lrint(lab[0]);
                    hist[k < 0 ? 0 : k > 100 ? 100 : k]++;
                    n++;
                } else if (lab[0] <= lmax) {
                    for (int c = 0; c < 3; c++)
                        acc[c] += lab[c];
                    m++;
                }
            }
    }
    out->lab_pixels = m;
    for (int c = 0; c < 3; c++)
        out->lab[c] = m ? acc[c] / m : NAN;
}

/* ---- the call ---- */

static int check_args(const gs_io_image *img, const double p[6][2], const gs_face_iris_opts *o,
                      gs_error *err)
{
    if (!img || !p)
        return gs_error_set(err, GS_ERR_ARG, "iris: NULL argument");
    if (!img->data || img->width < 1 || img->height < 1 || img->stride < 3 * (size_t)img->width)
        return gs_error_set(err, GS_ERR_ARG, "iris: bad image");
    if (!isfinite(o->min_eye_width_px) || !isfinite(o->min_opening) ||
        !isfinite(o->radius_min_px) || !isfinite(o->radius_max_px) ||
        !isfinite(o->min_visible) || !isfinite(o->min_contrast))
        return gs_error_set(err, GS_ERR_NONFINITE, "iris: non-finite option");
    if (o->radius_min_px < 0 || o->radius_max_px < o->radius_min_px ||
        (o->radius_max_px > 0 && o->radius_min_px <= 0))
        return gs_error_set(err, GS_ERR_ARG, "iris: radius range [%g, %g]", o->radius_min_px,
                            o->radius_max_px);
    for (int i = 0; i < 6; i++) {
        if (!isfinite(p[i][0]) || !isfinite(p[i][1]))
            return gs_error_set(err, GS_ERR_NONFINITE, "iris: non-finite contour point %d", i);
        if (p[i][0] < 0 || p[i][1] < 0 || p[i][0] > img->width || p[i][1] > img->height)
            return gs_error_set(err, GS_ERR_ARG,
                                "iris: contour point %d (%.1f, %.1f) outside the %dx%d image", i,
                                p[i][0], p[i][1], img->width, img->height);
    }
    double w = hypot(p[3][0] - p[0][0], p[3][1] - p[0][1]);
    if (!(w >= 1))
        return gs_error_set(err, GS_ERR_ARG, "iris: eye corners %.2f px apart", w);
    for (int i = 0; i < 6; i++)
        for (int j = 0; j < i; j++)
            if (hypot(p[i][0] - p[j][0], p[i][1] - p[j][1]) > 3 * w)
                return gs_error_set(err, GS_ERR_ARG,
                                    "iris: contour points %d and %d over 3 eye widths apart", j,
                                    i);
    return GS_OK;
}

static void result_empty(gs_face_iris *out, gs_face_iris_status st, const eye_geom *g)
{
    memset(out, 0, sizeof *out);
    out->status = st;
    out->centre[0] = out->centre[1] = out->radius = out->pupil_radius = NAN;
    out->pupil_centre[0] = out->pupil_centre[1] = NAN;
    out->residual = out->centre_sd_px = out->contrast = NAN;
    out->lab[0] = out->lab[1] = out->lab[2] = NAN;
    out->eye_width = g->width;
    out->opening = g->opening;
}

/* Start and fit on the patch; fills out (status OK or NO_EDGE). */
/* The fit's start in patch p (s px per patch pixel): the best circle of a
 * coarse search, centres between the lids' extremes along the corner line,
 * then of a fine one about it; score -INFINITY when none. w: n_op weights,
 * set to 1. */
static circle find_start(const patch *pp, const eye_geom *g, int s, double r0, double r1,
                         double *w)
{
    double inv_s = 1.0 / s, wp = g->width * inv_s;
    double op[2] = {(g->o[0] - pp->x0) * inv_s, (g->o[1] - pp->y0) * inv_s};
    double box[4] = {-0.45 * wp, 0.45 * wp, INFINITY, -INFINITY};
    for (int i = 0; i < 6; i++) {
        double a, b;
        to_frame(g, g->poly[i][0], g->poly[i][1], &a, &b);
        box[2] = fmin(box[2], b * inv_s - 0.05 * wp);
        box[3] = fmax(box[3], b * inv_s + 0.05 * wp);
    }
    double step = fmax(0.5, wp / 40);
    circle c = {0, 0, 0, -INFINITY};
    for (int i = 0; i < pp->n_op; i++)
        w[i] = 1;
    best_start(pp, w, g, op, box, r0, r1, 2 * step, &c);
    if (c.score > -INFINITY) {
        double ca, cb;
        to_frame(g, pp->x0 + s * c.u, pp->y0 + s * c.v, &ca, &cb);
        double fine[4] = {ca * inv_s - 2 * step, ca * inv_s + 2 * step,
                          cb * inv_s - 2 * step, cb * inv_s + 2 * step};
        best_start(pp, w, g, op, fine, fmax(r0, c.r / 1.13), fmin(r1, c.r * 1.13),
                   0.5 * step, &c);
    }
    return c;
}

static int locate(const gs_io_image *img, const eye_geom *g, const gs_face_iris_opts *o,
                  double rmin, double rmax, gs_face_iris *out)
{
    int s = (int)ceil(g->width / MAX_EYE_PX);
    double lo[2] = {INFINITY, INFINITY}, hi[2] = {-INFINITY, -INFINITY};
    double margin = 1.2 * rmax + 2 * s + 2;
    for (int i = 0; i < 6; i++)
        for (int c = 0; c < 2; c++) {
            lo[c] = fmin(lo[c], g->poly[i][c] - margin);
            hi[c] = fmax(hi[c], g->poly[i][c] + margin);
        }
    patch p;
    if (patch_make(img, g->poly, lo, hi, s, &p))
        return GS_ERR_NOMEM;
    double inv_s = 1.0 / s;
    double r0 = rmin * inv_s, r1 = rmax * inv_s;
    int k = 2 * (int)floor(0.125 * r0) + 1;
    patch_open(&p, k < 3 ? 3 : k);
    patch_opening(&p, g, 0.04 * g->width + 0.3);
    out->status = GS_FACE_IRIS_NO_EDGE;
    int n = p.n_op;
    double *w = NULL;
    double *res = NULL;
    if (n >= 12) {
        /* weights, then residuals, scratch and the Jacobian's columns */
        w = malloc((size_t)(3 + NGEO) * (size_t)n * sizeof *w);
        if (!w) {
            free(p.g);
            return GS_ERR_NOMEM;
        }
        res = w + n;
    }
    if (w) {
        circle c = find_start(&p, g, s, r0, r1, w);
        if (c.score > -INFINITY) {
            prior pr = {{0}, {0}};
            pr.mean[2] = 0.5 * (r0 + r1);
            pr.inv_var[2] = 1 / (RADIUS_SD * pr.mean[2] * RADIUS_SD * pr.mean[2]);
            pr.inv_var[4] = pr.inv_var[5] = 1 / (SHAPE_SD * SHAPE_SD);
            /* Fit from the start; then from the pupil it finds, if any;
             * keep the one that explains the opening better. */
            fit_out fa, fb;
            double ta[NGEO] = {c.u, c.v, c.r, 0.45 * c.r, 0, 0};
            fit_model(&p, ta, r0, r1, &pr, w, res, &fa);
            const model *m = &fa.m;
            double rmaj = major_axis(m->t);
            pupil pu = find_pupil(&p, m->t, m->t[0], m->t[1], 0.6 * rmaj, fmax(0.8, 0.1 * rmaj),
                                  0.55 * rmaj);
            const fit_out *f = &fa;
            if (pu.score > 0 && fabs(pu.delta) >= o->min_contrast) {
                double tb[NGEO] = {pu.u, pu.v, m->t[2], pu.rho, m->t[4], m->t[5]};
                fit_model(&p, tb, r0, r1, &pr, w, res, &fb);
                /* A strong pupil wins when the fit from it stays on it. */
                double sclera_a = fa.m.beta[2], con_a = sclera_a - fa.m.beta[1];
                int strong = fabs(pu.delta) >= STRONG_PUPIL * con_a &&
                             hypot(fb.m.t[0] - pu.u, fb.m.t[1] - pu.v) <= 0.12 * major_axis(fb.m.t) + 0.5;
                if (fb.cost < fa.cost || strong)
                    f = &fb;
            }
            m = &f->m;
            rmaj = major_axis(m->t);
            double cx = p.x0 + s * m->t[0], cy = p.y0 + s * m->t[1];
            double ca2, cb2;
            to_frame(g, cx, cy, &ca2, &cb2);
            double sclera = m->beta[2] + m->beta[3] * ca2 / g->width +
                            m->beta[4] * cb2 / g->width;
            double contrast = sclera - m->beta[1];
            int sides[2];
            double span;
            double visible = limbus_visible(&p, g, m, sides, &span);

            /* The pupil counts when it stands out of the iris and the
             * detector, run again about the final centre, agrees. */
            pupil pf = find_pupil(&p, m->t, m->t[0], m->t[1], 0.3 * rmaj, fmax(0.8, 0.1 * rmaj),
                                  0.55 * rmaj);
            int pupil_ok = pf.score > 0 && fabs(pf.delta) >= fmax(o->min_contrast, 0.15 * contrast) &&
                           hypot(pf.u - m->t[0], pf.v - m->t[1]) <= 0.12 * rmaj + 0.5;
            int both = sides[0] >= LIMBUS_POINTS / 16 && sides[1] >= LIMBUS_POINTS / 16;
            if (pupil_ok) {
                out->pupil_centre[0] = p.x0 + s * pf.u;
                out->pupil_centre[1] = p.y0 + s * pf.v;
            }
            if (isfinite(m->sse) && contrast >= o->min_contrast && visible >= o->min_visible &&
                gs_face_contour_dist(g->poly, cx, cy) <= 0.1 * g->width) {
                /* Without a pupil the limbus has to be seen on both sides
                 * (the horizontal position) and over a vertical span of
                 * its arc (sin of elevation, top minus bottom, >= 0.8:
                 * the curvature that places it vertically). */
                out->status = pupil_ok || (both && span >= MIN_ARC_SPAN) ? GS_FACE_IRIS_OK
                                                                         : GS_FACE_IRIS_PARTIAL;
                out->centre[0] = cx;
                out->centre[1] = cy;
                out->radius = s * rmaj;
                out->pupil_radius = pupil_ok ? s * pf.rho : 0;
                out->pupil_contrast = pupil_ok ? -pf.delta : 0;
                out->residual = f->rms;
                double tr = 0.5 * (f->cov_c[0] + f->cov_c[1]);
                double dd = sqrt(0.25 * (f->cov_c[0] - f->cov_c[1]) * (f->cov_c[0] - f->cov_c[1]) +
                                 f->cov_c[2] * f->cov_c[2]);
                out->centre_sd_px = s * sqrt(fmax(0, tr + dd));
                out->visible = visible;
                out->contrast = contrast;
                /* Confidence: enough limbus, enough contrast against the
                 * residual, a centre known to a fraction of the radius. */
                double snr = contrast / (contrast + 2 * f->rms);
                double sd = out->centre_sd_px / (0.1 * out->radius);
                out->confidence = fmin(1, visible / 0.4) * snr / (1 + sd * sd);
                iris_lab(img, g, cx, cy, out->radius,
                         out->pupil_radius > 0 ? out->pupil_radius : 0.3 * out->radius, out);
            }
        }
    }
    free(w);
    free(p.g);
    return GS_OK;
}

int gs_face_iris_locate(const gs_io_image *img, const double eye_uv[6][2],
                        const gs_face_iris_opts *opts, gs_face_iris *out, gs_error *err)
{
    gs_face_iris_opts def;
    gs_face_iris_opts_default(&def);
    const gs_face_iris_opts *o = opts ? opts : &def;
    if (!out)
        return gs_error_set(err, GS_ERR_ARG, "iris: NULL argument");
    int rc = check_args(img, eye_uv, o, err);
    if (rc)
        return rc;
    eye_geom g;
    eye_geom_make(eye_uv, &g);
    result_empty(out, GS_FACE_IRIS_OK, &g);
    if (g.width < o->min_eye_width_px) {
        out->status = GS_FACE_IRIS_TOO_SMALL;
        return GS_OK;
    }
    if (g.opening < o->min_opening) {
        out->status = GS_FACE_IRIS_CLOSED;
        return GS_OK;
    }
    double rmin = o->radius_max_px > 0 ? o->radius_min_px : 0.14 * g.width;
    double rmax = o->radius_max_px > 0 ? o->radius_max_px : 0.62 * g.width;
    rmax = fmin(rmax, g.width);
    rmin = fmin(rmin, rmax);
    if (locate(img, &g, o, rmin, rmax, out) == GS_ERR_NOMEM)
        return gs_error_set(err, GS_ERR_NOMEM, "iris: out of memory");
    return GS_OK;
}

/* ---- gaze from the iris ---- */

static const double eye_offset_mm[3] = GS_FACE_IRIS_EYE_OFFSET_MM;

int gs_face_iris_gaze(int eye, const double eye_uv[6][2], const double iris_uv[2],
                      const double head_R[9], double *pitch, double *yaw, gs_error *err)
{
    if (eye < 0 || eye > 1)
        return gs_error_set(err, GS_ERR_ARG, "iris gaze: eye %d", eye);
    if (!eye_uv || !iris_uv || !pitch || !yaw)
        return gs_error_set(err, GS_ERR_ARG, "iris gaze: NULL argument");
    for (int i = 0; i < 6; i++)
        if (!isfinite(eye_uv[i][0]) || !isfinite(eye_uv[i][1]))
            return gs_error_set(err, GS_ERR_NONFINITE, "iris gaze: contour point %d", i);
    if (!isfinite(iris_uv[0]) || !isfinite(iris_uv[1]))
        return gs_error_set(err, GS_ERR_NONFINITE, "iris gaze: iris centre");
    double r[9];
    if (head_R) {
        for (int i = 0; i < 9; i++)
            if (!isfinite(head_R[i]))
                return gs_error_set(err, GS_ERR_NONFINITE, "iris gaze: head rotation");
        memcpy(r, head_R, sizeof r);
    } else {
        gs_geom_mat3_identity(r);
    }
    /* The eye's corners on the mean synthetic head (head frame) set the
     * scale: their distance in the image over their distance across the
     * line of sight. */
    double m6[6][3], w[3], rw[3];
    gs_geom_face_model6_synth(m6);
    for (int c = 0; c < 3; c++)
        w[c] = m6[2 * eye + 1][c] - m6[2 * eye][c];
    gs_geom_mat3_vec(r, w, rw);
    double wmm = hypot(rw[0], rw[1]);
    double wpx = hypot(eye_uv[3][0] - eye_uv[0][0], eye_uv[3][1] - eye_uv[0][1]);
    if (!(wmm > 1) || !(wpx >= 1))
        return gs_error_set(err, GS_ERR_ARG, "iris gaze: eye corners %.2f px apart, %.2f mm "
                            "across the view", wpx, wmm);
    double k = wpx / wmm;
    /* Iris centre from the corner midpoint, mm across the view, less the
     * eyeball centre's offset; what is left is the gaze's image part
     * times the eyeball-to-iris distance. */
    double b[3] = {eye ? -eye_offset_mm[0] : eye_offset_mm[0], eye_offset_mm[1],
                   eye_offset_mm[2]}, rb[3];
    gs_geom_mat3_vec(r, b, rb);
    double m[2];
    m[0] = ((iris_uv[0] - 0.5 * (eye_uv[0][0] + eye_uv[3][0])) / k - rb[0]) /
           GS_FACE_IRIS_ROT_X_MM;
    m[1] = ((iris_uv[1] - 0.5 * (eye_uv[0][1] + eye_uv[3][1])) / k - rb[1]) /
           GS_FACE_IRIS_ROT_Y_MM;
    double mm = hypot(m[0], m[1]);
    if (mm > 0.999) {
        m[0] *= 0.999 / mm;
        m[1] *= 0.999 / mm;
        mm = 0.999;
    }
    /* The gaze looks back toward the camera (z < 0 in the camera frame). */
    double gc[3] = {m[0], m[1], -sqrt(1 - mm * mm)}, gh[3];
    gs_geom_mat3_tvec(r, gc, gh);
    return gs_geom_vec_to_pitchyaw(gh, pitch, yaw) ? gs_error_set(err, GS_ERR_ARG, "iris gaze")
                                                   : GS_OK;
}

int gs_face_iris_gaze_change(int eye, const double eye_uv0[6][2], const double iris_uv0[2],
                             const double eye_uv1[6][2], const double iris_uv1[2],
                             const double head_R[9], double *dpitch, double *dyaw, gs_error *err)
{
    double p0, y0, p1, y1;
    if (!dpitch || !dyaw)
        return gs_error_set(err, GS_ERR_ARG, "iris gaze: NULL argument");
    int rc = gs_face_iris_gaze(eye, eye_uv0, iris_uv0, head_R, &p0, &y0, err);
    if (!rc)
        rc = gs_face_iris_gaze(eye, eye_uv1, iris_uv1, head_R, &p1, &y1, err);
    if (rc)
        return rc;
    *dpitch = p1 - p0;
    *dyaw = y1 - y0;
    return GS_OK;
}
