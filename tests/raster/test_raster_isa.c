#define _POSIX_C_SOURCE 200809L /* setenv, strdup */
/* The fast path's instruction sets (gs_raster_set_isa, GS_RASTER_ISA):
 * every set this CPU runs renders the same scenes as the plain baseline
 * set to rounding, each set is bit-identical across thread counts and with
 * records off, a backward uses its forward's set even when the workspace
 * switched sets in between, and bad names are refused with an error that
 * leaves the workspace as it was. */
#include "rt_util.h"

#include "gazesplat/pool.h"

static const char *const sets[] = {"avx512", "avx2", "generic"};
#define N_SETS 3

/* One forward + backward with set isa (and records on or off). */
static int run_isa(const rt_scene *s, const rt_upstream *u, const char *isa, gs_pool *pool,
                   int records, rt_result *o)
{
    gs_raster *r = gs_raster_create();
    gs_error err;
    if (gs_raster_set_isa(r, isa, &err)) {
        gs_raster_destroy(r);
        return 0;
    }
    CHECK(!strcmp(gs_raster_isa(r), isa));
    gs_raster_set_records(r, records);
    rt_run_with(r, s, GS_RASTER_FAST, pool, u, o);
    gs_raster_destroy(r);
    CHECK(o->fwd_status == GS_OK && o->bwd_status == GS_OK);
    return 1;
}

static void compare_to_generic(const char *isa, const rt_result *a, const rt_result *g)
{
    size_t np = (size_t)a->W * a->H, nf = np * a->C, n = (size_t)a->n;
    printf("  %s against generic:\n", isa);
    rt_compare_image("features", a->features, g->features, nf, 2e-5, 1e-4);
    rt_compare_image("alpha", a->alpha, g->alpha, np, 2e-6, 0);
    rt_compare_image("depth", a->depth, g->depth, np, 2e-5, 1e-5);
    /* Gradients: relative to each array's largest, with a small band for
     * pixels whose 1/255 or stop decision the last bit can flip. */
    rt_compare_grad("grad means", a->g_means, g->g_means, n * 3, 1e-4, 1e-3, 1e-3, 0.01);
    rt_compare_grad("grad log_scales", a->g_log_scales, g->g_log_scales, n * 3, 1e-4, 1e-3,
                    1e-3, 0.01);
    rt_compare_grad("grad quats", a->g_quats, g->g_quats, n * 4, 1e-4, 1e-3, 1e-3, 0.01);
    rt_compare_grad("grad opacity", a->g_opacity, g->g_opacity, n, 1e-4, 1e-3, 1e-3, 0.01);
    rt_compare_grad("grad features", a->g_features, g->g_features, n * a->C, 1e-4, 1e-3, 1e-3,
                    0.01);
    rt_compare_grad("grad background", a->g_background, g->g_background, nf, 1e-5, 1e-4, 0, 0);
    CHECK_MSG(a->stats.visible == g->stats.visible, "%s: visible %d vs %d", isa,
              a->stats.visible, g->stats.visible);
    long dc = (long)a->stats.contributions - (long)g->stats.contributions;
    CHECK_MSG(labs(dc) <= 2 + (long)(g->stats.contributions / 10000),
              "%s: contributions %zu vs %zu", isa, a->stats.contributions,
              g->stats.contributions);
}

static void run_scene(uint64_t seed, int n, int C, int W, int H, int aa)
{
    rt_scene s;
    rt_upstream u;
    rt_scene_for_grads(&s, &u, seed, n, C, W, H, aa, seed + 3, seed + 4);

    gs_pool *p2 = gs_pool_create(2), *p3 = gs_pool_create(3);
    rt_result gen;
    CHECK(run_isa(&s, &u, "generic", NULL, 1, &gen));
    int ran = 0;
    for (int k = 0; k < N_SETS; k++) {
        rt_result one, two, three, norec;
        if (!run_isa(&s, &u, sets[k], NULL, 1, &one)) {
            printf("  %s: not supported by this CPU\n", sets[k]);
            continue;
        }
        ran++;
        run_isa(&s, &u, sets[k], p2, 1, &two);
        run_isa(&s, &u, sets[k], p3, 1, &three);
        run_isa(&s, &u, sets[k], p2, 0, &norec);
        if (rt_same_bytes(sets[k], &one, &two) && rt_same_bytes(sets[k], &one, &three) &&
            rt_same_bytes(sets[k], &one, &norec))
            printf("  %s: 1, 2 and 3 threads and records off: bit-identical\n", sets[k]);
        if (k != N_SETS - 1)
            compare_to_generic(sets[k], &one, &gen);

        /* Forward with this set, then switch the workspace: the backward
         * still replays this set's records. */
        gs_raster *r = gs_raster_create();
        CHECK(gs_raster_set_isa(r, sets[k], NULL) == GS_OK);
        rt_result sw;
        rt_run_with(r, &s, GS_RASTER_FAST, p2, NULL, &sw);
        const char *other = k == N_SETS - 1 ? "auto" : "generic";
        CHECK(gs_raster_set_isa(r, other, NULL) == GS_OK);
        gs_gaussian_grads gr = {sw.g_means, sw.g_log_scales, sw.g_quats, sw.g_opacity,
                                sw.g_features};
        gs_error err;
        sw.bwd_status = gs_raster_backward(r, p2, u.v_features, u.v_alpha, u.v_depth, &gr,
                                           sw.g_background, &err);
        CHECK(sw.bwd_status == GS_OK);
        if (rt_same_bytes("switched after the forward", &one, &sw))
            printf("  %s: set switched between forward and backward: same bytes\n", sets[k]);
        gs_raster_destroy(r);
        rt_result_free(&sw);
        rt_result_free(&one), rt_result_free(&two), rt_result_free(&three);
        rt_result_free(&norec);
    }
    CHECK(ran >= 1); /* generic at least */
    rt_result_free(&gen);
    gs_pool_destroy(p2), gs_pool_destroy(p3);
    rt_upstream_free(&u);
    rt_scene_free(&s);
}

static void bad_names(void)
{
    /* Without GS_RASTER_ISA here: a new workspace takes the best set. */
    char *saved = getenv("GS_RASTER_ISA") ? strdup(getenv("GS_RASTER_ISA")) : NULL;
    unsetenv("GS_RASTER_ISA");
    gs_raster *r = gs_raster_create();
    const char *before = gs_raster_isa(r);
    CHECK(before && (!strcmp(before, "avx512") || !strcmp(before, "avx2") ||
                     !strcmp(before, "generic")));
    gs_error err;
    CHECK(gs_raster_set_isa(r, "sse9", &err) == GS_ERR_ARG);
    CHECK_MSG(strstr(err.msg, "sse9") && strstr(err.msg, "avx512"), "message: %s", err.msg);
    CHECK(gs_raster_set_isa(r, "", &err) == GS_ERR_ARG);
    CHECK(gs_raster_set_isa(r, NULL, &err) == GS_ERR_ARG);
    CHECK(gs_raster_set_isa(NULL, "auto", &err) == GS_ERR_ARG);
    CHECK(!strcmp(gs_raster_isa(r), before)); /* unchanged */
    CHECK(gs_raster_set_isa(r, "auto", &err) == GS_OK);
    CHECK(!strcmp(gs_raster_isa(r), before)); /* auto is the default */
    for (int k = 0; k < N_SETS; k++) {
        int rc = gs_raster_set_isa(r, sets[k], &err);
        CHECK_MSG(rc == GS_OK || rc == GS_ERR_UNSUPPORTED, "%s: %d", sets[k], rc);
        if (rc == GS_ERR_UNSUPPORTED)
            CHECK(strstr(err.msg, sets[k]) != NULL);
    }
    gs_raster_destroy(r);

    /* A bad GS_RASTER_ISA makes every forward of a new workspace fail with
     * a message naming it; choosing a set explicitly clears that. */
    setenv("GS_RASTER_ISA", "quantum", 1);
    rt_scene s;
    rt_random_scene(&s, 77, 50, 3, 32, 24);
    r = gs_raster_create();
    rt_result o;
    rt_run_with(r, &s, GS_RASTER_FAST, NULL, NULL, &o);
    CHECK(o.fwd_status == GS_ERR_ARG);
    float *F = rt_alloc((size_t)3 * 32 * 24, sizeof(float)), *A = rt_alloc(32 * 24, sizeof(float));
    CHECK(gs_raster_forward(r, NULL, &s.cam, &s.g, NULL, NULL, F, A, NULL, &err) == GS_ERR_ARG);
    CHECK_MSG(strstr(err.msg, "GS_RASTER_ISA=quantum") != NULL, "message: %s", err.msg);
    CHECK(gs_raster_set_isa(r, "auto", &err) == GS_OK);
    CHECK(gs_raster_forward(r, NULL, &s.cam, &s.g, NULL, NULL, F, A, NULL, &err) == GS_OK);
    free(F), free(A);
    rt_result_free(&o);
    gs_raster_destroy(r);
    rt_scene_free(&s);
    if (saved) {
        setenv("GS_RASTER_ISA", saved, 1);
        free(saved);
    } else
        unsetenv("GS_RASTER_ISA");
}

int main(void)
{
    bad_names();
    run_scene(4401, 3000, 32, 128, 96, 0);
    run_scene(5502, 1500, 3, 100, 75, 1);
    run_scene(6603, 800, 64, 61, 47, 0);
    run_scene(7704, 200, 1, 1, 1, 0);
    run_scene(8805, 900, 17, 37, 29, 1);
    GS_TEST_END();
}
