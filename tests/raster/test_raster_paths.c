/* Fast path against scalar path on bigger random scenes, and determinism:
 * the fast path gives bit-identical outputs and gradients for pools of
 * 1, 2 and 3 threads (and no pool), and a reused gs_raster gives the
 * bytes of a fresh one (scalar path: whatever pool it is handed).
 *
 * Tolerances fast vs scalar: images |diff| <= 1e-5 + 1e-5 |ref|;
 * gradients |diff| <= 1e-4 max|ref| + 1e-3 |ref| with the boundary band
 * (entries below 1e-5 max|ref| may differ in <= 0.1% of entries). */
#include "rt_util.h"

static void compare_paths(const rt_result *fast, const rt_result *ref)
{
    size_t np = (size_t)ref->W * ref->H, nf = np * ref->C, n = (size_t)ref->n;
    rt_compare_image("features", fast->features, ref->features, nf, 1e-5, 1e-5);
    rt_compare_image("alpha", fast->alpha, ref->alpha, np, 1e-5, 1e-5);
    rt_compare_image("depth", fast->depth, ref->depth, np, 5e-5, 1e-5);
    rt_compare_grad("means", fast->g_means, ref->g_means, n * 3, 1e-4, 1e-3, 1e-5, 1e-3);
    rt_compare_grad("log_scales", fast->g_log_scales, ref->g_log_scales, n * 3, 1e-4, 1e-3,
                    1e-5, 1e-3);
    rt_compare_grad("quats", fast->g_quats, ref->g_quats, n * 4, 1e-4, 1e-3, 1e-5, 1e-3);
    rt_compare_grad("opacity", fast->g_opacity, ref->g_opacity, n, 1e-4, 1e-3, 1e-5, 1e-3);
    rt_compare_grad("features", fast->g_features, ref->g_features, n * ref->C, 1e-4, 1e-3,
                    1e-5, 1e-3);
    rt_compare_grad("background", fast->g_background, ref->g_background, nf, 1e-4, 1e-3,
                    1e-5, 1e-3);
    printf("    stats: fast visible %d isect %zu contrib %zu, scalar visible %d isect %zu "
           "contrib %zu\n", fast->stats.visible, fast->stats.intersections,
           fast->stats.contributions, ref->stats.visible, ref->stats.intersections,
           ref->stats.contributions);
    /* The fast path may cull more (tiles and Gaussians that cannot reach
     * alpha 1/255), never composite a different set of pairs. */
    CHECK_EQ_INT(fast->stats.contributions, ref->stats.contributions);
    CHECK(fast->stats.visible <= ref->stats.visible);
    CHECK(fast->stats.intersections <= ref->stats.intersections);
}

/* The fast path with pools of t0..3 threads against no pool. */
static void check_threads(const rt_scene *s, const rt_upstream *u, const rt_result *fast0,
                          int t0)
{
    for (int t = t0; t <= 3; t++) {
        gs_pool *pool = gs_pool_create(t);
        CHECK(pool != NULL);
        rt_result o;
        rt_run(s, GS_RASTER_FAST, pool, u, &o);
        char what[64];
        snprintf(what, sizeof what, "fast, %d thread(s) vs no pool", t);
        if (rt_same_bytes(what, &o, fast0))
            printf("  %s: bit-identical\n", what);
        rt_result_free(&o);
        gs_pool_destroy(pool);
    }
}

/* A reused gs_raster (its buffers grown by a bigger render in between)
 * gives the bytes of a fresh one; the scalar path ignores the pool. */
static void check_reuse(const rt_scene *s, const rt_upstream *u, gs_raster_path path,
                        const rt_result *fresh, uint64_t seed)
{
    rt_scene big;
    rt_random_scene(&big, seed, s->g.n + 200, s->g.channels, s->cam.width + 24,
                    s->cam.height + 16);
    rt_upstream ubig;
    rt_upstream_random(&ubig, &big, seed + 1);
    gs_pool *pool = gs_pool_create(3);
    gs_raster *r = gs_raster_create();
    rt_result first, mid, again;
    rt_run_with(r, s, path, pool, u, &first);
    rt_run_with(r, &big, path, pool, &ubig, &mid);
    rt_run_with(r, s, path, pool, u, &again);
    char what[64];
    snprintf(what, sizeof what, "%s, reused gs_raster, 3 threads", rt_path_name(path));
    if (rt_same_bytes(what, &first, fresh) && rt_same_bytes(what, &again, fresh))
        printf("  %s: bit-identical\n", what);
    rt_result_free(&first);
    rt_result_free(&mid);
    rt_result_free(&again);
    gs_raster_destroy(r);
    gs_pool_destroy(pool);
    rt_upstream_free(&ubig);
    rt_scene_free(&big);
}

/* scale_mul multiplies every scale: large Gaussians make many (tile,
 * Gaussian) pairs, enough to split the fast backward into several batches
 * (its scratch budget is 4M floats: 58k pairs at C = 64). reuse: also
 * check reuse of a gs_raster (1: fast path, 2: both paths). */
static void run_config(uint64_t seed, int n, int C, int W, int H, int aa, int bg,
                       double scale_mul, int reuse)
{
    rt_scene s;
    rt_random_scene(&s, seed, n, C, W, H);
    s.antialiased = aa;
    for (int i = 0; i < 3 * n; i++)
        s.log_scales[i] += (float)log(scale_mul);
    if (bg) {
        rt_rng r = {seed + 7};
        rt_scene_add_background(&s);
        for (size_t i = 0; i < (size_t)C * W * H; i++)
            s.background[i] = (float)rt_uniform(&r, 0, 1);
    }
    rt_upstream u;
    rt_upstream_random(&u, &s, seed + 8);
    printf("scene: %d Gaussians, %dx%d, C=%d%s%s\n", n, W, H, C, aa ? ", antialiased" : "",
           bg ? ", background" : "");

    rt_result scalar, fast0;
    rt_run(&s, GS_RASTER_SCALAR, NULL, &u, &scalar);
    CHECK(scalar.fwd_status == GS_OK && scalar.bwd_status == GS_OK);
    double mean_alpha = 0.0;
    for (int i = 0; i < W * H; i++)
        mean_alpha += scalar.alpha[i] / (W * H);
    printf("  visible %d, intersections %zu, contributors per pixel %.1f, mean alpha %.3f\n",
           scalar.stats.visible, scalar.stats.intersections,
           (double)scalar.stats.contributions / (W * H), mean_alpha);
    rt_run(&s, GS_RASTER_FAST, NULL, &u, &fast0);
    CHECK(fast0.fwd_status == GS_OK && fast0.bwd_status == GS_OK);
    printf("  fast vs scalar:\n");
    compare_paths(&fast0, &scalar);
    check_threads(&s, &u, &fast0, n > 50000 ? 3 : 1);
    if (reuse >= 1)
        check_reuse(&s, &u, GS_RASTER_FAST, &fast0, seed + 1);
    if (reuse >= 2)
        check_reuse(&s, &u, GS_RASTER_SCALAR, &scalar, seed + 3);
    rt_result_free(&fast0);
    rt_result_free(&scalar);
    rt_upstream_free(&u);
    rt_scene_free(&s);
}

int main(void)
{
    run_config(1001, 2000, 32, 128, 96, 0, 1, 1.0, 1);
    run_config(2002, 1500, 3, 100, 75, 1, 0, 1.0, 1);
    run_config(3003, 800, 64, 61, 47, 0, 1, 1.0, 2);
    run_config(4004, 5000, 64, 96, 96, 0, 1, 6.0, 0); /* 2 batches */
    run_config(5005, 90000, 64, 16, 16, 1, 1, 1.0, 0); /* 1 tile over budget */
    GS_TEST_END();
}
