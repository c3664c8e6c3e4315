/* Incremental gaze sweeps (gs_frame_render): after a full render, a render
 * that changes only the gaze re-rasterizes the eye stream's tiles and
 * re-runs the renderer over their reach. It must match a full render from
 * a fresh context within 1e-5 on every output value, for every guidance
 * mode that allows it, on the tiny and the cpu-sized feature maps, with and
 * without a pool, across gaze changes up to the model's range; a change of
 * head pose or code must fall back to the full path.
 *
 * The renderer's guidance projection is drawn at random (a trained model's
 * guidance is not the identity the init gives), so the guidance vector
 * matters in the images compared. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "gazesplat/nn.h"
#include "gazesplat/train.h"
#include "gs_test.h"
#include "model_test_util.h"

#define TOL 1e-5

static uint64_t g_rng = 0x9e3779b97f4a7c15ull;

static float urand(float b)
{
    uint64_t z = (g_rng += 0x9E3779B97F4A7C15ull);
    z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
    z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
    z ^= z >> 31;
    return b * (2.0f * (float)((double)(z >> 11) / 9007199254740992.0) - 1.0f);
}

static gs_model *make_model(int guidance, int feat_size)
{
    gs_model_config cfg;
    gs_model_config_default(&cfg);
    cfg.template_spacing_mm = feat_size >= 64 ? 3.0 : 6.0;
    cfg.n_eye_each = feat_size >= 64 ? 700 : 60;
    cfg.feat_dim = 8;
    cfg.id_dim = 4;
    cfg.hidden = 16;
    cfg.channels = 8;
    cfg.feat_size = feat_size;
    cfg.image_size = 4 * feat_size;
    cfg.focal = 1600.0 * cfg.image_size / 512;
    cfg.guidance = guidance;
    cfg.guide_source = GS_GUIDE_SRC_SOURCE;
    cfg.n_train_ids = 2;
    gs_model *m = NULL;
    gs_error err;
    if (gs_model_create(&cfg, 11, &m, &err) != GS_OK) {
        fprintf(stderr, "make_model: %s\n", err.msg);
        return NULL;
    }
    const gs_renderer_params *r = &m->p.rend;
    int C = cfg.channels;
    if (r->value_w) { /* a guidance that changes the image */
        for (int i = 0; i < C * C; i++)
            r->value_w[i] = urand(0.5f);
        for (int i = 0; i < C; i++)
            r->value_b[i] = urand(0.5f);
    }
    return m;
}

static double max_diff(const float *a, const float *b, size_t n)
{
    double w = 0.0;
    for (size_t i = 0; i < n; i++)
        w = fmax(w, fabs((double)a[i] - b[i]));
    return w;
}

static void sweep(int guidance, int feat_size, gs_pool *pool, const char *name)
{
    gs_model *m = make_model(guidance, feat_size);
    CHECK(m != NULL);
    if (!m)
        return;
    gs_model_ctx *inc = gs_model_ctx_create(m), *full = gs_model_ctx_create(m);
    CHECK(inc && full);
    gs_frame fr;
    frame_default(m, &fr);
    size_t nrgb = 3 * (size_t)m->cfg.image_size * m->cfg.image_size;
    size_t nmap = (size_t)m->cfg.channels * feat_size * feat_size;
    /* gaze (pitch, yaw) in degrees: small steps, the range's corners, back */
    static const double gz[][2] = {{0, 0},   {2, 1},    {-5, 10}, {30, -40},
                                   {-30, 40}, {-30, 39}, {15, 0},  {0, 0},
                                   {40, 50}, {-40, -50}, {0, 0}};
    double worst = 0.0, worst_map = 0.0;
    int incs = 0, n = (int)(sizeof gz / sizeof gz[0]);
    gs_error err = {0, ""};
    for (int k = 0; k < n; k++) {
        fr.gaze[0] = gz[k][0] * GS_MODEL_PI / 180;
        fr.gaze[1] = gz[k][1] * GS_MODEL_PI / 180;
        int was_inc = -1;
        CHECK_MSG(gs_frame_render(inc, pool, &fr, &was_inc, &err) == GS_OK,
                  "%s", err.msg);
        incs += was_inc;
        CHECK_MSG(was_inc == (k > 0), "%s step %d: incremental = %d", name, k,
                  was_inc);
        /* the full render, from scratch */
        gs_model_ctx_destroy(full);
        full = gs_model_ctx_create(m);
        CHECK(gs_frame_forward(full, pool, &fr, GS_STREAM_BOTH, 0, &err) == GS_OK);
        double d = max_diff(inc->rgb, full->rgb, nrgb);
        worst = fmax(worst, d);
        worst_map = fmax(worst_map, max_diff(inc->fmap, full->fmap, nmap));
        CHECK_MSG(d <= TOL, "%s gaze (%g, %g): incremental differs by %.3g",
                  name, gz[k][0], gz[k][1], d);
    }
    double area = (double)feat_size * feat_size * (incs ? incs : 1);
    printf("%-34s %d incremental renders, max |diff| image %.2e, features "
           "%.2e; re-rasterized %.0f%%, changed %.0f%% of the map\n",
           name, incs, worst, worst_map, 100 * inc->inc_stats[0] / area,
           100 * inc->inc_stats[1] / area);
    /* head pose or code changes: the full path */
    int was_inc = -1;
    fr.head_t[0] += 1.0;
    CHECK(gs_frame_render(inc, pool, &fr, &was_inc, &err) == GS_OK);
    CHECK_MSG(was_inc == 0, "%s: a new head pose must render in full", name);
    fr.code[0] += 0.25f;
    CHECK(gs_frame_render(inc, pool, &fr, &was_inc, &err) == GS_OK);
    CHECK_MSG(was_inc == 0, "%s: a new code must render in full", name);
    /* a forward for fitting in between invalidates the cache */
    CHECK(gs_frame_forward(inc, pool, &fr, GS_STREAM_BOTH, 0, &err) == GS_OK);
    fr.gaze[1] = 0.1;
    CHECK(gs_frame_render(inc, pool, &fr, &was_inc, &err) == GS_OK);
    CHECK_MSG(was_inc == 0, "%s: render after a forward must be full", name);
    gs_model_ctx_destroy(inc);
    gs_model_ctx_destroy(full);
    gs_model_destroy(m);
}

/* BLOCK guidance (the released code's) depends on every pixel: such models
 * always render in full. */
static void block_is_full(void)
{
    gs_model *m = make_model(GS_GUIDE_ADDITIVE, 32);
    CHECK(m && gs_model_set_guide_source(m, GS_GUIDE_SRC_BLOCK, NULL) == GS_OK);
    gs_model_ctx *c = gs_model_ctx_create(m);
    gs_frame fr;
    frame_default(m, &fr);
    int was_inc = -1;
    gs_error err;
    CHECK(gs_frame_render(c, NULL, &fr, &was_inc, &err) == GS_OK);
    fr.gaze[1] += 0.1;
    CHECK(gs_frame_render(c, NULL, &fr, &was_inc, &err) == GS_OK);
    CHECK_MSG(was_inc == 0, "BLOCK guidance rendered incrementally");
    gs_model_ctx_destroy(c);
    gs_model_destroy(m);
}

int main(void)
{
    gs_nn_blas_set_threads(1);
    gs_pool *pool = gs_pool_create(2);
    CHECK(pool != NULL);
    sweep(GS_GUIDE_ADDITIVE, 32, NULL, "additive 32^2");
    sweep(GS_GUIDE_MULTIPLICATIVE, 32, pool, "multiplicative 32^2, 2 threads");
    sweep(GS_GUIDE_NONE, 32, NULL, "no guidance 32^2");
    sweep(GS_GUIDE_ADDITIVE, 64, pool, "additive 64^2, 2 threads");
    block_is_full();
    gs_pool_destroy(pool);
    GS_TEST_END();
}
