/* Hard cases for gs_raster, on both paths. Each case asserts finite
 * outputs and gradients and the behaviour raster.h documents; forward
 * outputs are compared with a double-precision oracle (rt_util.h) where
 * the case is well conditioned. */
#include "rt_util.h"

static gs_raster_path g_path;
static gs_pool *g_pool;

static void run(const rt_scene *s, rt_result *o)
{
    rt_upstream u;
    rt_upstream_random(&u, s, 77);
    rt_run(s, g_path, g_path == GS_RASTER_FAST ? g_pool : NULL, &u, o);
    rt_upstream_free(&u);
}

static int result_finite(const rt_result *o)
{
    size_t np = (size_t)o->W * o->H, nf = np * o->C, n = (size_t)o->n;
    return rt_all_finite(o->features, nf) && rt_all_finite(o->alpha, np) &&
           rt_all_finite(o->depth, np) && rt_all_finite(o->g_means, 3 * n) &&
           rt_all_finite(o->g_log_scales, 3 * n) && rt_all_finite(o->g_quats, 4 * n) &&
           rt_all_finite(o->g_opacity, n) && rt_all_finite(o->g_features, n * o->C) &&
           rt_all_finite(o->g_background, nf);
}

static int grads_zero_for(const rt_result *o, int i)
{
    int C = o->C;
    return rt_all_zero(o->g_means + 3 * i, 3) && rt_all_zero(o->g_log_scales + 3 * i, 3) &&
           rt_all_zero(o->g_quats + 4 * i, 4) && rt_all_zero(o->g_opacity + i, 1) &&
           rt_all_zero(o->g_features + (size_t)i * C, (size_t)C);
}

/* alpha in [0, 1], each feature a convex mix of the Gaussians' features
 * and the background (the weights and T sum to 1). */
static int result_sane(const rt_scene *s, const rt_result *o)
{
    int C = s->g.channels, W = s->cam.width, H = s->cam.height;
    for (int p = 0; p < W * H; p++) {
        if (!(o->alpha[p] >= 0.0f && o->alpha[p] <= 1.0f))
            return 0;
        for (int c = 0; c < C; c++) {
            double lo = s->background ? s->background[(size_t)c * W * H + p] : 0.0, hi = lo;
            for (int i = 0; i < s->g.n; i++) {
                lo = fmin(lo, s->features[(size_t)i * C + c]);
                hi = fmax(hi, s->features[(size_t)i * C + c]);
            }
            double v = o->features[(size_t)c * W * H + p];
            double slack = 1e-5 * (1 + fabs(hi) + fabs(lo));
            if (!(v >= lo - slack && v <= hi + slack))
                return 0;
        }
    }
    return 1;
}

/* The scene's own Gaussians make no difference: outputs equal the
 * background, alpha and depth are zero, every gradient is zero. */
static void check_invisible(const char *what, const rt_scene *s, const rt_result *o)
{
    size_t np = (size_t)s->cam.width * s->cam.height, nf = np * s->g.channels;
    CHECK_MSG(o->fwd_status == GS_OK && o->bwd_status == GS_OK, "%s: status %d/%d", what,
              o->fwd_status, o->bwd_status);
    CHECK_MSG(o->stats.visible == 0, "%s: %d visible", what, o->stats.visible);
    int bg_ok = s->background ? memcmp(o->features, s->background, nf * sizeof(float)) == 0
                              : rt_all_zero(o->features, nf);
    CHECK_MSG(bg_ok, "%s: features differ from the background", what);
    CHECK_MSG(rt_all_zero(o->alpha, np) && rt_all_zero(o->depth, np),
              "%s: alpha/depth not zero", what);
    int zero = 1;
    for (int i = 0; i < s->g.n; i++)
        zero &= grads_zero_for(o, i);
    CHECK_MSG(zero, "%s: non-zero gradient", what);
}

static void fill_background(rt_scene *s, uint64_t seed)
{
    rt_rng r = {seed};
    rt_scene_add_background(s);
    for (int i = 0; i < s->g.channels * s->cam.width * s->cam.height; i++)
        s->background[i] = (float)rt_uniform(&r, 0, 1);
}

/* One Gaussian of 2D std px pixels at (x, y) pixels, depth z. */
static void one_gaussian(rt_scene *s, double x, double y, double z, double std_px)
{
    rt_scene_init(s, 1, 3, 32, 32);
    rt_place(s, 0, x, y, z);
    for (int k = 0; k < 3; k++)
        s->log_scales[k] = (float)log(std_px * fabs(z) / s->cam.fx + 1e-30);
    s->opacity_logits[0] = 1.0f;
    s->features[0] = 0.9f;
    s->features[1] = -0.3f;
    s->features[2] = 0.4f;
    fill_background(s, 5);
}

/* --------------------------------------------------------------- cases */

static void near_plane(void)
{
    /* Behind the camera or closer than GS_RASTER_NEAR: culled. */
    const float behind[] = {-1.0f, 0.0f, 0.005f, 0.0099f, nextafterf(GS_RASTER_NEAR, 0)};
    for (size_t k = 0; k < sizeof behind / sizeof behind[0]; k++) {
        rt_scene s;
        one_gaussian(&s, 16.3, 15.8, 1.0, 3.0);
        s.means[2] = behind[k];
        s.log_scales[0] = s.log_scales[1] = s.log_scales[2] = (float)log(0.05);
        rt_result o;
        run(&s, &o);
        char what[64];
        snprintf(what, sizeof what, "z = %g", (double)behind[k]);
        check_invisible(what, &s, &o);
        CHECK_MSG(result_finite(&o), "%s: non-finite", what);
        rt_result_free(&o);
        rt_scene_free(&s);
    }
    /* At and just in front of the plane: drawn (raster.h culls z < NEAR
     * only), with finite outputs and gradients. */
    const float front[] = {GS_RASTER_NEAR, 0.0101f, 0.02f, 0.1f};
    for (size_t k = 0; k < sizeof front / sizeof front[0]; k++) {
        for (int edge = 0; edge <= 1; edge++) {
            rt_scene s;
            /* edge: far off-axis with a large world scale, where the
             * Jacobian's frustum clamp matters most. */
            one_gaussian(&s, edge ? 60.0 : 16.3, edge ? -20.0 : 15.8, front[k], 3.0);
            s.means[2] = front[k];
            if (edge)
                s.log_scales[0] = s.log_scales[1] = s.log_scales[2] = (float)log(0.05);
            rt_result o;
            run(&s, &o);
            char what[64];
            snprintf(what, sizeof what, "z = %.9g%s", (double)front[k],
                     edge ? " off-axis" : "");
            CHECK_MSG(o.fwd_status == GS_OK && o.bwd_status == GS_OK, "%s: status", what);
            CHECK_MSG(result_finite(&o), "%s: non-finite", what);
            CHECK_MSG(result_sane(&s, &o), "%s: outputs out of range", what);
            CHECK_MSG(o.stats.visible == 1, "%s: visible %d, want 1", what, o.stats.visible);
            if (!edge) {
                CHECK_MSG(o.alpha[15 * 32 + 16] > 0.5f, "%s: alpha %g at the mean", what,
                          (double)o.alpha[15 * 32 + 16]);
                CHECK_MSG(!grads_zero_for(&o, 0), "%s: zero gradient", what);
                CHECK_MSG(rt_check_oracle(what, &s, &o, 1e-5) == 0, "%s: oracle", what);
            }
            rt_result_free(&o);
            rt_scene_free(&s);
        }
    }
}

static void offscreen(void)
{
    /* Radius boxes that miss the image: culled. */
    const double miss[][2] = {{-30, 16}, {16, 70}, {100, 16}, {-40, -40}, {45, 45}};
    for (size_t k = 0; k < sizeof miss / sizeof miss[0]; k++) {
        rt_scene s;
        one_gaussian(&s, miss[k][0], miss[k][1], 3.0, 2.0);
        rt_result o;
        run(&s, &o);
        char what[64];
        snprintf(what, sizeof what, "off-screen (%g, %g)", miss[k][0], miss[k][1]);
        check_invisible(what, &s, &o);
        rt_result_free(&o);
        rt_scene_free(&s);
    }
    /* Straddling a border (mean outside or on the edge): drawn on the
     * border pixels only. */
    const double edge[][3] = {{-2, 10, 3}, {33, 31, 4}, {16, -1.5, 2}, {0, 0, 3}, {32, 16, 1}};
    for (size_t k = 0; k < sizeof edge / sizeof edge[0]; k++) {
        rt_scene s;
        one_gaussian(&s, edge[k][0], edge[k][1], 3.0, edge[k][2]);
        rt_result o;
        run(&s, &o);
        char what[64];
        snprintf(what, sizeof what, "straddling (%g, %g)", edge[k][0], edge[k][1]);
        CHECK_MSG(o.fwd_status == GS_OK && o.bwd_status == GS_OK, "%s: status", what);
        CHECK_MSG(result_finite(&o), "%s: non-finite", what);
        CHECK_MSG(o.stats.visible == 1, "%s: not visible", what);
        CHECK_MSG(!grads_zero_for(&o, 0), "%s: zero gradient", what);
        CHECK_MSG(rt_check_oracle(what, &s, &o, 1e-5) == 0, "%s: oracle", what);
        rt_result_free(&o);
        rt_scene_free(&s);
    }
}

static void scales(void)
{
    /* Isotropic 1e-6 .. 1e4: well conditioned, compared with the oracle. */
    const double iso[] = {-13.8, -9.0, -5.0, -2.0, 0.0, 3.0, 6.0, 9.2};
    for (size_t k = 0; k < sizeof iso / sizeof iso[0]; k++) {
        for (int aa = 0; aa <= 1; aa++) {
            rt_scene s;
            one_gaussian(&s, 16.3, 15.8, 3.0, 1.0);
            s.antialiased = aa;
            s.log_scales[0] = s.log_scales[1] = s.log_scales[2] = (float)iso[k];
            rt_result o;
            run(&s, &o);
            char what[64];
            snprintf(what, sizeof what, "log-scale %g%s", iso[k], aa ? " aa" : "");
            CHECK_MSG(o.fwd_status == GS_OK && o.bwd_status == GS_OK, "%s: status", what);
            CHECK_MSG(result_finite(&o), "%s: non-finite", what);
            CHECK_MSG(result_sane(&s, &o), "%s: outputs out of range", what);
            CHECK_MSG(rt_check_oracle(what, &s, &o, 1e-5) == 0, "%s: oracle", what);
            rt_result_free(&o);
            rt_scene_free(&s);
        }
    }
    /* Extreme anisotropy (needles and sheets 1e-6 x 1e4), rotated: the 2D
     * covariance is ill conditioned in float32; only finiteness and sane
     * ranges are asserted. */
    const double aniso[][3] = {{-13.8, 0.0, 9.2}, {9.2, 9.2, -13.8}, {-13.8, -13.8, 9.2},
                               {9.2, -13.8, -5.0}};
    rt_rng r = {31};
    for (size_t k = 0; k < sizeof aniso / sizeof aniso[0]; k++) {
        for (int aa = 0; aa <= 1; aa++) {
            rt_scene s;
            one_gaussian(&s, 10.0 + 3.0 * k, 20.0, 2.0 + k, 1.0);
            s.antialiased = aa;
            for (int j = 0; j < 3; j++)
                s.log_scales[j] = (float)aniso[k][j];
            for (int j = 0; j < 4; j++)
                s.quats[j] = (float)rt_normal(&r);
            rt_result o;
            run(&s, &o);
            char what[64];
            snprintf(what, sizeof what, "log-scales (%g, %g, %g)%s", aniso[k][0],
                     aniso[k][1], aniso[k][2], aa ? " aa" : "");
            CHECK_MSG(o.fwd_status == GS_OK && o.bwd_status == GS_OK, "%s: status", what);
            CHECK_MSG(result_finite(&o), "%s: non-finite", what);
            CHECK_MSG(result_sane(&s, &o), "%s: outputs out of range", what);
            rt_result_free(&o);
            rt_scene_free(&s);
        }
    }
}

static void quaternions(void)
{
    rt_scene base;
    rt_random_scene(&base, 404, 40, 3, 40, 30);
    for (int i = 0; i < 40; i++) { /* anisotropic, so rotation matters */
        base.log_scales[3 * i] = (float)log(0.2);
        base.log_scales[3 * i + 1] = (float)log(0.05);
        base.log_scales[3 * i + 2] = (float)log(0.1);
    }
    rt_result ref;
    run(&base, &ref);
    CHECK(ref.fwd_status == GS_OK && ref.bwd_status == GS_OK);
    size_t np = 40 * 30, nf = np * 3;
    /* 1e-21 and 1e21: |q|^2 under- or overflows float32 although q and
     * q / |q| are representable; raster.h accepts "any norm". */
    const double lam[] = {1e-3, 0.37, 6.5, 1e3, 1e-21, 1e21, 1e-30};
    for (size_t k = 0; k < sizeof lam / sizeof lam[0]; k++) {
        rt_scene s;
        rt_scene_copy(&s, &base);
        for (int i = 0; i < 160; i++)
            s.quats[i] = (float)(s.quats[i] * lam[k]);
        rt_result o;
        run(&s, &o);
        printf("  quaternions x %g:\n", lam[k]);
        char what[5][48];
        const char *names[5] = {"features", "alpha", "lam grad quats", "grad means",
                                "grad log_scales"};
        for (int j = 0; j < 5; j++)
            snprintf(what[j], sizeof what[j], "%s (q x %g)", names[j], lam[k]);
        rt_compare_image(what[0], o.features, ref.features, nf, 2e-6, 1e-5);
        rt_compare_image(what[1], o.alpha, ref.alpha, np, 2e-6, 1e-5);
        /* d/dq f(q/|q|) at lam q is (1/lam) times its value at q. */
        float *gq = rt_alloc(160, sizeof(float));
        for (int i = 0; i < 160; i++)
            gq[i] = (float)(o.g_quats[i] * lam[k]);
        rt_compare_grad(what[2], gq, ref.g_quats, 160, 1e-4, 1e-3, 0, 0);
        rt_compare_grad(what[3], o.g_means, ref.g_means, 120, 1e-4, 1e-3, 0, 0);
        rt_compare_grad(what[4], o.g_log_scales, ref.g_log_scales, 120, 1e-4, 1e-3, 0, 0);
        free(gq);
        rt_result_free(&o);
        rt_scene_free(&s);
    }
    /* Zero quaternion = identity rotation, with zero rotation gradient. */
    rt_scene id, zero;
    rt_scene_copy(&id, &base);
    rt_scene_copy(&zero, &base);
    for (int i = 0; i < 10; i++) {
        for (int j = 0; j < 4; j++) {
            id.quats[4 * i + j] = j == 0 ? 1.0f : 0.0f;
            zero.quats[4 * i + j] = 0.0f;
        }
    }
    rt_result oi, oz;
    run(&id, &oi);
    run(&zero, &oz);
    printf("  zero quaternions vs identity:\n");
    CHECK(oz.fwd_status == GS_OK && oz.bwd_status == GS_OK);
    CHECK(result_finite(&oz));
    rt_compare_image("features", oz.features, oi.features, nf, 1e-6, 1e-6);
    rt_compare_image("alpha", oz.alpha, oi.alpha, np, 1e-6, 1e-6);
    CHECK_MSG(rt_all_zero(oz.g_quats, 40), "zero quaternion got a rotation gradient");
    CHECK_MSG(!rt_all_zero(oi.g_quats, 40), "identity quaternions got no gradient");
    rt_compare_grad("grad means", oz.g_means, oi.g_means, 120, 1e-5, 1e-4, 0, 0);
    rt_compare_grad("grad quats 10..", oz.g_quats + 40, oi.g_quats + 40, 120, 1e-5, 1e-4, 0, 0);
    rt_result_free(&oi);
    rt_result_free(&oz);
    rt_scene_free(&id);
    rt_scene_free(&zero);
    rt_result_free(&ref);
    rt_scene_free(&base);
}

static void opacity_extremes(void)
{
    for (int aa = 0; aa <= 1; aa++) {
        /* +30: sigmoid = 1, alpha clamped at the centre. Mean exactly at a
         * pixel centre and a large footprint so compensation is ~1. */
        rt_scene s;
        one_gaussian(&s, 16.5, 15.5, 3.0, 6.0);
        s.antialiased = aa;
        s.opacity_logits[0] = 30.0f;
        rt_result o;
        run(&s, &o);
        CHECK(o.fwd_status == GS_OK && o.bwd_status == GS_OK);
        CHECK(result_finite(&o));
        CHECK(result_sane(&s, &o));
        if (!aa)
            CHECK_CLOSE(o.alpha[15 * 32 + 16], GS_RASTER_MAX_ALPHA, 1e-6, 0);
        CHECK_MSG(rt_check_oracle("logit +30", &s, &o, 1e-5) == 0, "logit +30: oracle");
        rt_result_free(&o);
        rt_scene_free(&s);

        /* -30: alpha < 1/255 everywhere: nothing drawn, zero gradients. */
        one_gaussian(&s, 16.5, 15.5, 3.0, 6.0);
        s.antialiased = aa;
        s.opacity_logits[0] = -30.0f;
        run(&s, &o);
        CHECK(o.fwd_status == GS_OK && o.bwd_status == GS_OK);
        CHECK_MSG(rt_all_zero(o.alpha, 32 * 32), "logit -30 drew something");
        CHECK_MSG(memcmp(o.features, s.background, 3 * 32 * 32 * sizeof(float)) == 0,
                  "logit -30 changed the background");
        CHECK_MSG(grads_zero_for(&o, 0), "logit -30: non-zero gradient");
        rt_result_free(&o);
        rt_scene_free(&s);
    }
}

/* n Gaussians on the centre of a 1x1 image, in shuffled depth order
 * (depth 1 + 0.001 rank), all with opacity sigmoid(logit) at the pixel.
 * Feature 0 is 1 for all; feature 1 is the depth rank. */
static void pile(rt_scene *s, int n, float logit)
{
    rt_scene_init(s, n, 2, 1, 1);
    s->cam.cx = 0.5f;
    s->cam.cy = 0.5f;
    int *rank = rt_alloc((size_t)n, sizeof(int));
    for (int i = 0; i < n; i++)
        rank[i] = i;
    rt_rng r = {8};
    for (int i = n - 1; i > 0; i--) {
        int j = (int)(rt_next(&r) % (uint64_t)(i + 1)), t = rank[i];
        rank[i] = rank[j];
        rank[j] = t;
    }
    for (int i = 0; i < n; i++) {
        s->means[3 * i + 2] = 1.0f + 0.001f * (float)rank[i];
        s->log_scales[3 * i] = s->log_scales[3 * i + 1] = s->log_scales[3 * i + 2] =
            (float)log(0.02);
        s->opacity_logits[i] = logit;
        s->features[2 * i] = 1.0f;
        s->features[2 * i + 1] = (float)rank[i];
    }
    free(rank);
}

static void many_on_one_pixel(void)
{
    /* alpha = 0.5 exactly: T after k is 2^-k; the stop excludes the
     * Gaussian that would take T(1 - alpha) to <= 1e-4, so exactly 13
     * contribute. alpha = 0.01: 916 contribute. Everything behind the
     * stop gets exactly zero gradient. */
    const struct {
        float logit;
        int n;
    } cases[] = {{0.0f, 3000}, {(float)log(0.01 / 0.99), 3000}};
    for (size_t c = 0; c < 2; c++) {
        rt_scene s;
        pile(&s, cases[c].n, cases[c].logit);
        rt_result o;
        run(&s, &o);
        CHECK(o.fwd_status == GS_OK && o.bwd_status == GS_OK);
        CHECK(result_finite(&o));
        double a = 1.0 / (1.0 + exp(-(double)cases[c].logit));
        int k = 0;
        double T = 1.0, F1 = 0.0, D = 0.0;
        while (T * (1 - a) > GS_RASTER_T_EPS) {
            F1 += k * a * T;
            D += (1.0 + 0.001f * (float)k) * a * T;
            T *= 1 - a;
            k++;
        }
        printf("  %d Gaussians on one pixel, alpha %.3g: %d contribute, alpha_out %.9g "
               "(want %.9g)\n", cases[c].n, a, k, (double)o.alpha[0], 1 - T);
        CHECK_CLOSE(o.alpha[0], 1 - T, 1e-6, 0);
        CHECK_CLOSE(o.features[0], 1 - T, 1e-6, 0);
        CHECK_CLOSE(o.features[1], F1, 1e-4, 1e-4);
        CHECK_CLOSE(o.depth[0], D, 1e-5, 1e-4);
        int contributors = 0, zero_behind = 1;
        for (int i = 0; i < s.g.n; i++) {
            int rank = (int)s.features[2 * i + 1];
            if (rank >= k)
                zero_behind &= grads_zero_for(&o, i);
            else
                contributors += o.g_features[2 * i] != 0.0f;
        }
        CHECK_MSG(zero_behind, "a Gaussian behind the stop got a gradient");
        CHECK_EQ_INT(contributors, k);
        rt_result_free(&o);
        rt_scene_free(&s);
    }
    /* Opacity 1 (alpha clamped at 0.99): finite, alpha_out >= 0.99. */
    rt_scene s;
    pile(&s, 3000, 30.0f);
    rt_result o;
    run(&s, &o);
    CHECK(o.fwd_status == GS_OK && o.bwd_status == GS_OK);
    CHECK(result_finite(&o));
    CHECK(o.alpha[0] >= 0.99f - 1e-6f && o.alpha[0] <= 1.0f);
    rt_result_free(&o);
    rt_scene_free(&s);
    /* Thousands of large Gaussians over a whole image. */
    rt_random_scene(&s, 606, 4000, 4, 48, 40);
    for (int i = 0; i < 4000; i++) {
        rt_place(&s, i, 24.0 + 3.0 * rt_normal(&(rt_rng){(uint64_t)i}), 20.0, 3.0 + 1e-3 * i);
        s.opacity_logits[i] = 1.0f;
        for (int j = 0; j < 3; j++)
            s.log_scales[3 * i + j] = (float)log(0.4);
    }
    run(&s, &o);
    CHECK(o.fwd_status == GS_OK && o.bwd_status == GS_OK);
    CHECK(result_finite(&o));
    CHECK(result_sane(&s, &o));
    CHECK_MSG(rt_check_oracle("4000 overlapping", &s, &o, 1e-5) == 0, "4000 overlapping");
    rt_result_free(&o);
    rt_scene_free(&s);
}

static void equal_depths(void)
{
    /* Two Gaussians identical except for their features: same depth, so
     * the lower index is in front. */
    for (int swap = 0; swap <= 1; swap++) {
        rt_scene s;
        rt_scene_init(&s, 2, 2, 8, 8);
        for (int i = 0; i < 2; i++) {
            rt_place(&s, i, 4.5, 4.5, 2.0);
            for (int j = 0; j < 3; j++)
                s.log_scales[3 * i + j] = (float)log(0.05);
            s.opacity_logits[i] = 0.0f;
        }
        s.features[swap ? 2 : 0] = 1.0f; /* A = (1, 0) */
        s.features[swap ? 1 : 3] = 1.0f; /* B = (0, 1) */
        CHECK(memcmp(s.means, s.means + 3, 3 * sizeof(float)) == 0);
        rt_result o;
        run(&s, &o);
        CHECK(o.fwd_status == GS_OK && o.bwd_status == GS_OK);
        int p = 4 * 8 + 4; /* the pixel at the mean: alpha 0.5 each */
        float front = o.features[p], back = o.features[64 + p];
        if (swap) {
            float t = front;
            front = back;
            back = t;
        }
        printf("  equal depths%s: first %.6f second %.6f (want 0.5, 0.25)\n",
               swap ? ", swapped" : "", (double)front, (double)back);
        CHECK_CLOSE(front, 0.5, 1e-6, 0);
        CHECK_CLOSE(back, 0.25, 1e-6, 0);
        CHECK_MSG(rt_check_oracle("equal depths", &s, &o, 1e-6) == 0, "equal depths: oracle");
        rt_result_free(&o);
        rt_scene_free(&s);
    }
    /* Distinct depths: permuting the arrays permutes the gradients and
     * leaves the image unchanged. */
    rt_scene a, b;
    rt_random_scene(&a, 505, 60, 3, 40, 30);
    rt_scene_copy(&b, &a);
    int perm[60];
    for (int i = 0; i < 60; i++)
        perm[i] = (i * 37 + 11) % 60;
    for (int i = 0; i < 60; i++) {
        int j = perm[i];
        memcpy(b.means + 3 * i, a.means + 3 * j, 3 * sizeof(float));
        memcpy(b.log_scales + 3 * i, a.log_scales + 3 * j, 3 * sizeof(float));
        memcpy(b.quats + 4 * i, a.quats + 4 * j, 4 * sizeof(float));
        memcpy(b.features + 3 * i, a.features + 3 * j, 3 * sizeof(float));
        b.opacity_logits[i] = a.opacity_logits[j];
    }
    rt_result oa, ob;
    run(&a, &oa);
    run(&b, &ob);
    size_t np = 40 * 30;
    CHECK_MSG(memcmp(oa.features, ob.features, 3 * np * sizeof(float)) == 0 &&
                  memcmp(oa.alpha, ob.alpha, np * sizeof(float)) == 0,
              "permuted Gaussians changed the image");
    float *gp = rt_alloc(60 * 3, sizeof(float)), *go = rt_alloc(60, sizeof(float));
    for (int i = 0; i < 60; i++) {
        memcpy(gp + 3 * i, oa.g_means + 3 * perm[i], 3 * sizeof(float));
        go[i] = oa.g_opacity[perm[i]];
    }
    printf("  permuted arrays:\n");
    rt_compare_grad("grad means", ob.g_means, gp, 180, 1e-6, 1e-5, 0, 0);
    rt_compare_grad("grad opacity", ob.g_opacity, go, 60, 1e-6, 1e-5, 0, 0);
    free(gp);
    free(go);
    rt_result_free(&oa);
    rt_result_free(&ob);
    rt_scene_free(&a);
    rt_scene_free(&b);
}

/* ------------------------------------------------------- refused inputs */

#define SENTINEL 12345.0f

/* Forward must refuse with want; outputs untouched (all SENTINEL) or all
 * finite. The refused forward follows a valid one (of ok, the same scene
 * without the bad value); backward must then refuse (GS_ERR_STATE): its
 * "last forward" failed. */
static void expect_refused(const char *what, const rt_scene *s, const rt_scene *ok,
                           int want)
{
    size_t np = (size_t)s->cam.width * s->cam.height, nf = np * s->g.channels;
    float *f = rt_alloc(nf, sizeof(float)), *a = rt_alloc(np, sizeof(float));
    float *d = rt_alloc(np, sizeof(float));
    for (size_t i = 0; i < nf; i++)
        f[i] = SENTINEL;
    for (size_t i = 0; i < np; i++)
        a[i] = d[i] = SENTINEL;
    gs_raster *r = gs_raster_create();
    gs_raster_options opt = {.antialiased = s->antialiased, .path = g_path};
    gs_error err = {0, {0}};
    float *f0 = rt_alloc(nf, sizeof(float)), *a0 = rt_alloc(np, sizeof(float));
    int st = gs_raster_forward(r, g_pool, &ok->cam, &ok->g, ok->background, &opt, f0, a0,
                               NULL, &err);
    CHECK_MSG(st == GS_OK, "%s: the valid scene failed: %s", what, err.msg);
    free(f0);
    free(a0);
    st = gs_raster_forward(r, g_pool, &s->cam, &s->g, s->background, &opt, f, a, d, &err);
    CHECK_MSG(st == want, "%s: status %d (%s), want %d", what, st, err.msg, want);
    CHECK_MSG(err.code == st && (st == GS_OK || err.msg[0] != 0),
              "%s: gs_error not filled (code %d)", what, err.code);
    int untouched = 1, finite = rt_all_finite(f, nf) && rt_all_finite(a, np) &&
                                rt_all_finite(d, np);
    for (size_t i = 0; i < nf; i++)
        untouched &= f[i] == SENTINEL;
    for (size_t i = 0; i < np; i++)
        untouched &= a[i] == SENTINEL && d[i] == SENTINEL;
    CHECK_MSG(untouched || finite, "%s: non-finite values written", what);
    if (st != GS_OK) {
        gs_gaussian_grads gr = {0};
        float *vf = rt_alloc(nf, sizeof(float));
        int bst = gs_raster_backward(r, g_pool, vf, NULL, NULL, &gr, NULL, &err);
        CHECK_MSG(bst == GS_ERR_STATE, "%s: backward after a refused forward gave %d", what,
                  bst);
        free(vf);
    }
    gs_raster_destroy(r);
    free(f);
    free(a);
    free(d);
}

static void nonfinite_inputs(void)
{
    const float bad[] = {NAN, INFINITY, -INFINITY};
    rt_scene base;
    rt_random_scene(&base, 707, 5, 3, 16, 16);
    fill_background(&base, 9);
    rt_place(&base, 4, 8.0, 8.0, -5.0); /* Gaussian 4 is behind the camera */
    for (size_t v = 0; v < 3; v++) {
        for (int who = 0; who < 2; who++) {
            int i = who ? 4 : 0;
            struct {
                const char *name;
                size_t offset;
            } fields[] = {{"means", 0}, {"log_scales", 1}, {"quats", 2},
                          {"opacity_logits", 3}, {"features", 4}};
            for (size_t k = 0; k < 5; k++) {
                rt_scene s;
                rt_scene_copy(&s, &base);
                float *arr[] = {s.means + 3 * i + 1, s.log_scales + 3 * i + 2,
                                s.quats + 4 * i + 3, s.opacity_logits + i,
                                s.features + 3 * i + 1};
                *arr[fields[k].offset] = bad[v];
                char what[96];
                snprintf(what, sizeof what, "%s of %s Gaussian = %g", fields[k].name,
                         who ? "a culled" : "a visible", (double)bad[v]);
                expect_refused(what, &s, &base, GS_ERR_NONFINITE);
                rt_scene_free(&s);
            }
        }
        rt_scene s;
        /* every place of the finite check's loops (blocks of 4 vectors of
         * 8 or 16 lanes, single vectors, the scalar tail) in a 768-value
         * background */
        const int at[] = {0, 1, 7, 8, 15, 16, 31, 32, 63, 64, 100, 127, 128, 700, 735, 736,
                          751, 752, 760, 766, 767};
        for (size_t k = 0; k < sizeof at / sizeof at[0]; k++) {
            rt_scene_copy(&s, &base);
            s.background[at[k]] = bad[v];
            char what[64];
            snprintf(what, sizeof what, "background[%d] = %g", at[k], (double)bad[v]);
            expect_refused(what, &s, &base, GS_ERR_NONFINITE);
            rt_scene_free(&s);
        }
        for (int k = 0; k < 16; k++) { /* fx fy cx cy viewmat[12] */
            rt_scene_copy(&s, &base);
            gs_camera *c = &s.cam;
            float *field[] = {&c->fx, &c->fy, &c->cx, &c->cy};
            *(k < 4 ? field[k] : &c->viewmat[k - 4]) = bad[v];
            char what[64];
            snprintf(what, sizeof what, "camera field %d = %g", k, (double)bad[v]);
            expect_refused(what, &s, &base, GS_ERR_NONFINITE);
            rt_scene_free(&s);
        }
    }
    rt_scene_free(&base);
}

/* The finite check runs in blocks of 65,536 values over the pool: a bad
 * value on either side of a block boundary, in the last block and in its
 * last value is found, and with two bad arrays the error names the first
 * (features before background) whatever block finishes first. */
static void nonfinite_blocks(void)
{
    rt_scene base;
    rt_random_scene(&base, 708, 4100, 64, 16, 16); /* 262,400 feature values */
    fill_background(&base, 10);
    size_t nf = (size_t)4100 * 64;
    const size_t at[] = {0, 65535, 65536, 131071, 131072, 200000, nf - 1};
    for (size_t k = 0; k < sizeof at / sizeof at[0]; k++) {
        rt_scene s;
        rt_scene_copy(&s, &base);
        s.features[at[k]] = NAN;
        char what[64];
        snprintf(what, sizeof what, "features[%zu] = nan of %zu", at[k], nf);
        expect_refused(what, &s, &base, GS_ERR_NONFINITE);
        rt_scene_free(&s);
    }
    rt_scene s;
    rt_scene_copy(&s, &base);
    s.features[nf - 1] = INFINITY;
    s.background[0] = NAN;
    gs_raster *r = gs_raster_create();
    gs_raster_options opt = {.antialiased = s.antialiased, .path = g_path};
    size_t np = 16 * 16;
    float *f = rt_alloc(np * 64, sizeof(float)), *a = rt_alloc(np, sizeof(float));
    gs_error err = {0, {0}};
    int st = gs_raster_forward(r, g_pool, &s.cam, &s.g, s.background, &opt, f, a, NULL, &err);
    CHECK_MSG(st == GS_ERR_NONFINITE && strstr(err.msg, "features"),
              "two bad arrays: status %d, \"%s\" (want features named)", st, err.msg);
    gs_raster_destroy(r);
    free(f);
    free(a);
    rt_scene_free(&s);
    rt_scene_free(&base);
}

/* Finite but overflowing values: either refused with an error code or
 * rendered with finite outputs and gradients; never NaN with GS_OK. */
static void extreme_finite(void)
{
    struct {
        const char *what;
        int field, comp;
        float value;
    } cases[] = {{"log-scale 100", 1, 0, 100.0f},   {"log-scale -100", 1, 1, -100.0f},
                 {"log-scale 88", 1, 2, 88.0f},     {"mean 1e30", 0, 0, 1e30f},
                 {"mean z 1e30", 0, 2, 1e30f},      {"mean 3e38", 0, 1, 3e38f},
                 {"quat 1e30", 2, 0, 1e30f},        {"quat 1e-30", 2, 3, 1e-30f},
                 {"quat 3e38", 2, 1, 3e38f},        {"logit 1e30", 3, 0, 1e30f},
                 {"logit -1e30", 3, 0, -1e30f},     {"feature 1e30", 4, 0, 1e30f}};
    for (size_t k = 0; k < sizeof cases / sizeof cases[0]; k++) {
        rt_scene s;
        rt_random_scene(&s, 808, 6, 3, 16, 16);
        if (cases[k].field == 2) /* tiny quaternion: all components */
            for (int j = 0; j < 4 && cases[k].value < 1; j++)
                s.quats[j] = cases[k].value;
        float *arr[] = {s.means, s.log_scales, s.quats, s.opacity_logits, s.features};
        arr[cases[k].field][cases[k].comp] = cases[k].value;
        rt_result o;
        run(&s, &o);
        int ok = o.fwd_status == GS_OK && o.bwd_status == GS_OK;
        CHECK_MSG(ok ? result_finite(&o) : o.fwd_status < 0,
                  "%s: status %d/%d, finite %d", cases[k].what, o.fwd_status, o.bwd_status,
                  ok ? result_finite(&o) : -1);
        if (!ok)
            printf("  %s: refused with %d\n", cases[k].what, o.fwd_status);
        rt_result_free(&o);
        rt_scene_free(&s);
    }
}

/* ---------------------------------------------------------------- sizes */

static void sizes_and_channels(void)
{
    const int dims[][3] = {{1, 1, 3},   {17, 33, 3}, {33, 17, 3}, {16, 16, 3},
                           {15, 1, 3},  {1, 40, 3},  {31, 29, 1}, {31, 29, 64}};
    for (size_t k = 0; k < sizeof dims / sizeof dims[0]; k++) {
        int W = dims[k][0], H = dims[k][1], C = dims[k][2];
        rt_scene s;
        rt_random_scene(&s, 900 + k, 30, C, W, H);
        /* Keep footprints comparable to the image even when it is tiny. */
        for (int i = 0; i < 30; i++)
            rt_place(&s, i, rt_uniform(&(rt_rng){k * 100 + (uint64_t)i}, -0.2, 1.2) * W,
                     rt_uniform(&(rt_rng){k * 100 + (uint64_t)i + 50}, -0.2, 1.2) * H,
                     3.0 + 0.05 * i);
        fill_background(&s, 10 + k);
        rt_result o;
        run(&s, &o);
        char what[64];
        snprintf(what, sizeof what, "%dx%d C=%d", W, H, C);
        CHECK_MSG(o.fwd_status == GS_OK && o.bwd_status == GS_OK, "%s: status", what);
        CHECK_MSG(result_finite(&o), "%s: non-finite", what);
        CHECK_MSG(rt_check_oracle(what, &s, &o, 1e-5) == 0, "%s: oracle", what);
        rt_result_free(&o);
        rt_scene_free(&s);
    }
}

/* --------------------------------------------------------- bad arguments */

static void bad_arguments(void)
{
    rt_scene s;
    rt_random_scene(&s, 111, 4, 3, 16, 16);
    float f[3 * 256], a[256], d[256], vf[3 * 256] = {0};
    gs_raster *r = gs_raster_create();
    gs_raster_options opt = {.antialiased = 0, .path = g_path};
    gs_error err;
    int st;
#define EXPECT(call, want)                                                            \
    do {                                                                              \
        err.code = 0;                                                                 \
        err.msg[0] = 0;                                                               \
        st = (call);                                                                  \
        CHECK_MSG(st == (want), "%s: %d, want %d", #call, st, want);                  \
        CHECK_MSG(st == GS_OK || (err.code == st && err.msg[0]), "%s: no gs_error",   \
                  #call);                                                             \
    } while (0)

    /* Backward before any forward. */
    gs_gaussian_grads gr = {0};
    EXPECT(gs_raster_backward(r, g_pool, vf, NULL, NULL, &gr, NULL, &err), GS_ERR_STATE);

    EXPECT(gs_raster_forward(NULL, g_pool, &s.cam, &s.g, NULL, &opt, f, a, d, &err),
           GS_ERR_ARG);
    EXPECT(gs_raster_forward(r, g_pool, NULL, &s.g, NULL, &opt, f, a, d, &err), GS_ERR_ARG);
    EXPECT(gs_raster_forward(r, g_pool, &s.cam, NULL, NULL, &opt, f, a, d, &err),
           GS_ERR_ARG);
    EXPECT(gs_raster_forward(r, g_pool, &s.cam, &s.g, NULL, &opt, NULL, a, d, &err),
           GS_ERR_ARG);
    EXPECT(gs_raster_forward(r, g_pool, &s.cam, &s.g, NULL, &opt, f, NULL, d, &err),
           GS_ERR_ARG);

    const int channels[] = {0, -1, GS_RASTER_MAX_CHANNELS + 1};
    for (int k = 0; k < 3; k++) {
        gs_gaussians g = s.g;
        g.channels = channels[k];
        EXPECT(gs_raster_forward(r, g_pool, &s.cam, &g, NULL, &opt, f, a, d, &err),
               GS_ERR_ARG);
    }
    gs_gaussians gn = s.g;
    gn.n = -1;
    EXPECT(gs_raster_forward(r, g_pool, &s.cam, &gn, NULL, &opt, f, a, d, &err), GS_ERR_ARG);
    for (int k = 0; k < 5; k++) {
        gs_gaussians g = s.g;
        const float **p[] = {&g.means, &g.log_scales, &g.quats, &g.opacity_logits,
                             &g.features};
        *p[k] = NULL;
        EXPECT(gs_raster_forward(r, g_pool, &s.cam, &g, NULL, &opt, f, a, d, &err),
               GS_ERR_ARG);
    }
    const int sizes[][2] = {{0, 16}, {16, 0}, {-1, 16}, {16, -5},
                            {GS_RASTER_MAX_SIZE + 1, 1}, {1, GS_RASTER_MAX_SIZE + 1}};
    for (int k = 0; k < 6; k++) {
        gs_camera c = s.cam;
        c.width = sizes[k][0];
        c.height = sizes[k][1];
        EXPECT(gs_raster_forward(r, g_pool, &c, &s.g, NULL, &opt, f, a, d, &err), GS_ERR_ARG);
    }
    /* A valid forward, then backward's own checks. */
    EXPECT(gs_raster_forward(r, g_pool, &s.cam, &s.g, NULL, &opt, f, a, d, &err), GS_OK);
    EXPECT(gs_raster_backward(NULL, g_pool, vf, NULL, NULL, &gr, NULL, &err), GS_ERR_ARG);
    EXPECT(gs_raster_backward(r, g_pool, NULL, NULL, NULL, &gr, NULL, &err), GS_ERR_ARG);
    EXPECT(gs_raster_backward(r, g_pool, vf, NULL, NULL, &gr, NULL, &err), GS_OK);
    /* A NULL gs_error is allowed. */
    CHECK_EQ_INT(gs_raster_forward(r, g_pool, NULL, &s.g, NULL, &opt, f, a, d, NULL),
                 GS_ERR_ARG);
#undef EXPECT
    gs_raster_destroy(r);
    gs_raster_destroy(NULL);
    rt_scene_free(&s);

    /* The largest image side is accepted. */
    rt_scene big;
    rt_random_scene(&big, 112, 20, 1, GS_RASTER_MAX_SIZE, 1);
    rt_result o;
    run(&big, &o);
    CHECK_EQ_INT(o.fwd_status, GS_OK);
    CHECK_EQ_INT(o.bwd_status, GS_OK);
    rt_result_free(&o);
    rt_scene_free(&big);
}

/* ------------------------------------------------------- API contracts */

static void api_contracts(void)
{
    rt_scene s;
    rt_random_scene(&s, 222, 50, 3, 40, 30);
    fill_background(&s, 11);
    rt_upstream u;
    rt_upstream_random(&u, &s, 12);
    gs_pool *pool = g_path == GS_RASTER_FAST ? g_pool : NULL;
    size_t np = 40 * 30, nf = 3 * np;
    rt_result base;
    rt_run(&s, g_path, pool, &u, &base);
    CHECK(base.fwd_status == GS_OK && base.bwd_status == GS_OK);

    gs_raster *r = gs_raster_create();
    gs_raster_options opt = {.antialiased = 0, .path = g_path};
    float *f = rt_alloc(nf, sizeof(float)), *a = rt_alloc(np, sizeof(float));
    float *gm = rt_alloc(150, sizeof(float)), *gf = rt_alloc(150, sizeof(float));
    float *gb = rt_alloc(nf, sizeof(float));
    gs_error err;
    /* out_depth NULL: same features and alpha. */
    CHECK_EQ_INT(gs_raster_forward(r, pool, &s.cam, &s.g, s.background, &opt, f, a, NULL,
                                   &err), GS_OK);
    CHECK(memcmp(f, base.features, nf * sizeof(float)) == 0);
    CHECK(memcmp(a, base.alpha, np * sizeof(float)) == 0);
    /* Backward adds into the gradients and skips NULL arrays; running it
     * twice after one forward gives twice the result. */
    for (int i = 0; i < 150; i++)
        gm[i] = 1.0f;
    gs_gaussian_grads gr = {gm, NULL, NULL, NULL, gf};
    CHECK_EQ_INT(gs_raster_backward(r, pool, u.v_features, u.v_alpha, u.v_depth, &gr, gb,
                                    &err), GS_OK);
    int acc = 1;
    double mmax = rt_max_abs(base.g_means, 150);
    for (int i = 0; i < 150; i++)
        acc &= fabs(gm[i] - (1.0 + base.g_means[i])) <= 1e-5 * (1 + mmax);
    CHECK_MSG(acc, "backward does not add into the gradient arrays");
    CHECK(memcmp(gf, base.g_features, 150 * sizeof(float)) == 0);
    CHECK(memcmp(gb, base.g_background, nf * sizeof(float)) == 0);
    CHECK_EQ_INT(gs_raster_backward(r, pool, u.v_features, u.v_alpha, u.v_depth, &gr, NULL,
                                    &err), GS_OK);
    int twice = 1;
    double gmax = rt_max_abs(base.g_features, 150);
    for (int i = 0; i < 150; i++)
        twice &= fabs(gf[i] - 2.0 * base.g_features[i]) <=
                 1e-5 * (gmax + fabs(base.g_features[i]));
    CHECK_MSG(twice, "a second backward did not repeat the first");
    /* v_alpha and v_depth NULL mean zero. */
    memset(gf, 0, 150 * sizeof(float));
    float *gf0 = rt_alloc(150, sizeof(float)), *zero = rt_alloc(np, sizeof(float));
    gs_gaussian_grads g1 = {NULL, NULL, NULL, NULL, gf}, g0 = {NULL, NULL, NULL, NULL, gf0};
    CHECK_EQ_INT(gs_raster_backward(r, pool, u.v_features, NULL, NULL, &g1, NULL, &err),
                 GS_OK);
    CHECK_EQ_INT(gs_raster_backward(r, pool, u.v_features, zero, zero, &g0, NULL, &err),
                 GS_OK);
    int same = 1; /* by value: +0 and -0 may differ in bytes */
    for (int i = 0; i < 150; i++)
        same &= gf[i] == gf0[i];
    CHECK_MSG(same, "NULL v_alpha/v_depth differ from zero arrays");
    /* opt NULL: not antialiased, fast path. */
    CHECK_EQ_INT(gs_raster_forward(r, g_pool, &s.cam, &s.g, s.background, NULL, f, a, NULL,
                                   &err), GS_OK);
    rt_result fastres;
    rt_run(&s, GS_RASTER_FAST, g_pool, NULL, &fastres);
    CHECK(memcmp(f, fastres.features, nf * sizeof(float)) == 0);
    rt_result_free(&fastres);
    /* No Gaussians: the background, zero alpha; v_background = v_features. */
    gs_gaussians none = s.g;
    none.n = 0;
    CHECK_EQ_INT(gs_raster_forward(r, pool, &s.cam, &none, s.background, &opt, f, a, NULL,
                                   &err), GS_OK);
    CHECK(memcmp(f, s.background, nf * sizeof(float)) == 0);
    CHECK(rt_all_zero(a, np));
    memset(gb, 0, nf * sizeof(float));
    gs_gaussian_grads gz = {0};
    CHECK_EQ_INT(gs_raster_backward(r, pool, u.v_features, u.v_alpha, NULL, &gz, gb, &err),
                 GS_OK);
    CHECK(memcmp(gb, u.v_features, nf * sizeof(float)) == 0);
    gs_raster_stats st;
    gs_raster_get_stats(r, &st);
    CHECK_EQ_INT(st.visible, 0);
    CHECK_EQ_INT(st.intersections, 0);
    gs_raster_destroy(r);
    free(f);
    free(a);
    free(gm);
    free(gf);
    free(gf0);
    free(gb);
    free(zero);
    rt_result_free(&base);
    rt_upstream_free(&u);
    rt_scene_free(&s);
}

int main(void)
{
    g_pool = gs_pool_create(2);
    CHECK(g_pool != NULL);
    const gs_raster_path paths[] = {GS_RASTER_SCALAR, GS_RASTER_FAST};
    for (int k = 0; k < 2; k++) {
        g_path = paths[k];
        printf("== %s path\n", rt_path_name(g_path));
        int before = gs_test_failures;
        near_plane();
        offscreen();
        scales();
        quaternions();
        opacity_extremes();
        many_on_one_pixel();
        equal_depths();
        nonfinite_inputs();
        nonfinite_blocks();
        extreme_finite();
        sizes_and_channels();
        bad_arguments();
        api_contracts();
        printf("   %s path: %d failed checks\n", rt_path_name(g_path),
               gs_test_failures - before);
    }
    gs_pool_destroy(g_pool);
    GS_TEST_END();
}
