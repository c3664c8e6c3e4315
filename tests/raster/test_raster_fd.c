/* Gradients of gs_raster_backward against central finite differences of
 * L = sum v_f . features + sum v_a . alpha + sum v_d . depth, evaluated in
 * double from float32 forwards, on both paths, plain and antialiased.
 *
 * The scenes avoid every discontinuity of the forward pass: few Gaussians,
 * large for the image, whose alpha stays above 2/255 on every pixel and
 * whose radius box covers the image (so the 1/255 skip, tile binning and
 * culling never switch; check_smooth asserts it), opacities 0.18..0.62 (no
 * 0.99 clamp, and T stays above 1e-3, so no early stop), depths 0.4 apart
 * (no reordering). In the 24x20 scene one Gaussian sits past the left
 * border beyond the Jacobian's frustum clamp; the 6x5 scene has 2 px
 * Gaussians, whose antialiasing compensation has a sizeable gradient.
 *
 * Tolerance: |fd - analytic| <= FD_ATOL x max|analytic| of the array +
 * FD_RTOL |analytic|. The float32 forward makes L noisy at ~1e-6, so the
 * steps are 1e-2 (2e-3 for the means of the small scene, whose Gaussians
 * are 0.15 world units wide; 0.1 for the linear features and background). */
#include "rt_util.h"

#define FD_ATOL 2e-3
#define FD_RTOL 1e-2

static double loss(const rt_scene *s, gs_raster_path path, gs_pool *pool,
                   const rt_upstream *u, gs_raster *r, float *f, float *a, float *d)
{
    size_t np = (size_t)s->cam.width * s->cam.height, nf = np * s->g.channels;
    gs_raster_options opt = {.antialiased = s->antialiased, .path = path};
    gs_error err;
    int st = gs_raster_forward(r, pool, &s->cam, &s->g, s->background, &opt, f, a, d, &err);
    if (st != GS_OK) {
        fprintf(stderr, "forward failed: %s\n", err.msg);
        exit(1);
    }
    double L = 0.0;
    for (size_t i = 0; i < nf; i++)
        L += (double)u->v_features[i] * f[i];
    for (size_t i = 0; i < np; i++)
        L += (double)u->v_alpha[i] * a[i] + (double)u->v_depth[i] * d[i];
    return L;
}

/* small = 0: 24x20 image, Gaussians 10..20 px wide, one past the
 * Jacobian's frustum clamp. small = 1: 6x5 image, Gaussians 1.6..2.6 px
 * wide, so that the antialiasing compensation (~0.9) has a real gradient. */
static void build_scene(rt_scene *s, int antialiased, int small, uint64_t seed)
{
    const int N = 6, C = 3, W = small ? 6 : 24, H = small ? 5 : 20;
    rt_rng r = {seed};
    rt_scene_init(s, N, C, W, H);
    s->antialiased = antialiased;
    s->cam.fx = 30.0f;
    s->cam.fy = 31.0f;
    s->cam.cx = 0.49f * (float)W;
    s->cam.cy = 0.51f * (float)H;
    rt_set_view(s, 0.25, -0.15, 3.0);
    for (int i = 0; i < N; i++) {
        double z = 2.0 + 0.4 * i;
        double std = small ? rt_uniform(&r, 1.6, 2.0) : rt_uniform(&r, 10.0, 15.0);
        if (i == 2 && !small) { /* past the Jacobian clamp at -3.6 px */
            rt_place(s, i, -4.5, 9.0, z);
            std = 20.0;
        } else {
            rt_place(s, i, rt_uniform(&r, 0.4, 0.6) * W, rt_uniform(&r, 0.4, 0.6) * H, z);
        }
        for (int k = 0; k < 3; k++)
            s->log_scales[3 * i + k] =
                (float)log(std * rt_uniform(&r, 0.9, 1.3) * z / s->cam.fx);
        for (int k = 0; k < 4; k++)
            s->quats[4 * i + k] = (float)(rt_normal(&r) * 1.7);
        s->opacity_logits[i] = (float)rt_uniform(&r, -1.5, 0.5);
        for (int k = 0; k < C; k++)
            s->features[i * C + k] = (float)rt_uniform(&r, -1, 1);
    }
    rt_scene_add_background(s);
    for (int i = 0; i < C * W * H; i++)
        s->background[i] = (float)rt_uniform(&r, 0, 1);
}

/* The scene must keep every Gaussian above 2/255 on every pixel, its box
 * over the whole image, and transmittance far from the stop. */
static void check_smooth(const rt_scene *s)
{
    int W = s->cam.width, H = s->cam.height;
    double minT = 1.0;
    for (int i = 0; i < s->g.n; i++) {
        rt_proj p = {0};
        CHECK_MSG(rt_project_one(s, i, &p), "Gaussian %d culled", i);
        double amin = 1.0;
        for (int y = 0; y < H; y++) {
            for (int x = 0; x < W; x++) {
                double dx = p.mx - x - 0.5, dy = p.my - y - 0.5;
                double sg = 0.5 * (p.a * dx * dx + p.c * dy * dy) + p.b * dx * dy;
                amin = fmin(amin, p.opacity * exp(-sg));
            }
        }
        CHECK_MSG(amin > 2.0 / 255 && p.opacity < 0.9, "Gaussian %d: alpha %g..%g", i,
                  amin, p.opacity);
        int tw = (W + GS_RASTER_TILE - 1) / GS_RASTER_TILE;
        int th = (H + GS_RASTER_TILE - 1) / GS_RASTER_TILE;
        CHECK_MSG(p.tx0 == 0 && p.ty0 == 0 && p.tx1 == tw && p.ty1 == th,
                  "Gaussian %d binned to tiles [%d,%d)x[%d,%d)", i, p.tx0, p.tx1,
                  p.ty0, p.ty1);
        minT *= 1.0 - p.opacity;
    }
    CHECK_MSG(minT > 1e-3, "transmittance may reach %g", minT);
}

typedef struct worst {
    double excess;
    int index;
    double fd, an;
} worst;

/* Central differences over every entry of x (every stride-th one). */
static void fd_array(const char *what, float *x, size_t count, size_t stride,
                     double h, const float *analytic, rt_scene *s,
                     gs_raster_path path, gs_pool *pool, const rt_upstream *u,
                     gs_raster *r, float *f, float *a, float *d)
{
    double *fd = rt_alloc(count, sizeof(double));
    double scale = rt_max_abs(analytic, count);
    for (size_t i = 0; i < count; i += stride) {
        float x0 = x[i];
        float xp = (float)(x0 + h), xm = (float)(x0 - h);
        x[i] = xp;
        double Lp = loss(s, path, pool, u, r, f, a, d);
        x[i] = xm;
        double Lm = loss(s, path, pool, u, r, f, a, d);
        x[i] = x0;
        fd[i] = (Lp - Lm) / ((double)xp - (double)xm);
    }
    worst w[3] = {{-1e300, -1, 0, 0}, {-1e300, -1, 0, 0}, {-1e300, -1, 0, 0}};
    int bad = 0;
    double max_err = 0.0;
    for (size_t i = 0; i < count; i += stride) {
        double an = analytic[i], tol = FD_ATOL * scale + FD_RTOL * fabs(an);
        double err = fabs(fd[i] - an), excess = err - tol;
        max_err = fmax(max_err, err);
        bad += !(err <= tol);
        for (int k = 0; k < 3; k++) {
            if (excess > w[k].excess) {
                memmove(&w[k + 1], &w[k], sizeof(worst) * (size_t)(2 - k));
                w[k] = (worst){excess, (int)i, fd[i], an};
                break;
            }
        }
    }
    printf("    %-12s max|grad| %-9.4g max|fd - grad| %-9.3g (%.2e of max)%s\n", what,
           scale, max_err, scale > 0 ? max_err / scale : 0.0, bad ? "  FAIL" : "");
    for (int k = 0; k < 3 && w[k].index >= 0; k++)
        printf("      worst %d: [%d] analytic %.7g fd %.7g\n", k + 1, w[k].index,
               w[k].an, w[k].fd);
    gs_test_checks++;
    if (bad) {
        gs_test_failures++;
        fprintf(stderr, "%s: %d entries over tolerance (atol %g x max, rtol %g)\n", what,
                bad, FD_ATOL, FD_RTOL);
    }
    CHECK_MSG(scale > 0 || strcmp(what, "quats") == 0, "%s: gradient all zero", what);
    free(fd);
}

static void run_case(int antialiased, int small, gs_raster_path path, gs_pool *pool)
{
    rt_scene s;
    build_scene(&s, antialiased, small, 1234 + (uint64_t)antialiased);
    check_smooth(&s);
    rt_upstream u;
    rt_upstream_random(&u, &s, 99);
    printf("  %s path, %dx%d, %s\n", rt_path_name(path), s.cam.width, s.cam.height,
           antialiased ? "antialiased" : "plain");
    rt_result o;
    rt_run(&s, path, pool, &u, &o);
    CHECK_EQ_INT(o.fwd_status, GS_OK);
    CHECK_EQ_INT(o.bwd_status, GS_OK);
    size_t np = (size_t)s.cam.width * s.cam.height;
    int n = s.g.n, C = s.g.channels;
    float *f = rt_alloc(np * C, sizeof(float)), *a = rt_alloc(np, sizeof(float));
    float *d = rt_alloc(np, sizeof(float));
    gs_raster *r = gs_raster_create();
    fd_array("means", s.means, (size_t)n * 3, 1, small ? 2e-3 : 1e-2, o.g_means, &s, path, pool, &u, r, f, a, d);
    fd_array("log_scales", s.log_scales, (size_t)n * 3, 1, 1e-2, o.g_log_scales, &s, path,
             pool, &u, r, f, a, d);
    fd_array("quats", s.quats, (size_t)n * 4, 1, 1e-2, o.g_quats, &s, path, pool, &u, r, f,
             a, d);
    fd_array("opacity", s.opacity_logits, (size_t)n, 1, 1e-2, o.g_opacity, &s, path, pool,
             &u, r, f, a, d);
    fd_array("features", s.features, (size_t)n * C, 1, 0.1, o.g_features, &s, path, pool,
             &u, r, f, a, d);
    fd_array("background", s.background, np * C, 7, 0.1, o.g_background, &s, path, pool,
             &u, r, f, a, d);
    gs_raster_destroy(r);
    free(f);
    free(a);
    free(d);
    rt_result_free(&o);
    rt_upstream_free(&u);
    rt_scene_free(&s);
}

int main(void)
{
    gs_pool *pool = gs_pool_create(2);
    CHECK(pool != NULL);
    for (int aa = 0; aa <= 1; aa++) {
        for (int small = 0; small <= 1; small++) {
            run_case(aa, small, GS_RASTER_SCALAR, NULL);
            run_case(aa, small, GS_RASTER_FAST, pool);
        }
    }
    gs_pool_destroy(pool);
    GS_TEST_END();
}
