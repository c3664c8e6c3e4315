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

static gs_model *make_model(int guidance, int feat_size, int lids, int direct)
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
    cfg.eye_direct = direct;
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
    return lids ? with_lids(m) : m;
}

static double max_diff(const float *a, const float *b, size_t n)
{
    double w = 0.0;
    for (size_t i = 0; i < n; i++)
        w = fmax(w, fabs((double)a[i] - b[i]));
    return w;
}

/* With lids: the lids move the image (k = 0 renders another one), so the
 * sweep checks them. */
static void lids_move(gs_model *m, gs_pool *pool, const char *name)
{
    gs_frame fr;
    frame_default(m, &fr);
    fr.gaze[0] = 0.5;
    size_t nrgb = 3 * (size_t)m->cfg.image_size * m->cfg.image_size;
    float *a = malloc(nrgb * sizeof(float));
    int nl = gs_model_n_lid(&m->cfg);
    size_t nk = 2 * GS_LID_NU * GS_LID_NV;
    float *k = malloc(nk * sizeof(float));
    gs_model_ctx *c = gs_model_ctx_create(m);
    gs_error err;
    CHECK(a && k && c);
    if (!a || !k || !c)
        goto out;
    CHECK(gs_frame_forward(c, pool, &fr, GS_STREAM_BOTH, 1, &err) == GS_OK);
    memcpy(a, c->rgb, nrgb * sizeof(float));
    memcpy(k, m->p.lid_k, nk * sizeof(float));
    memset(m->p.lid_k, 0, nk * sizeof(float));
    CHECK(gs_frame_forward(c, pool, &fr, GS_STREAM_BOTH, 1, &err) == GS_OK);
    memcpy(m->p.lid_k, k, nk * sizeof(float));
    double d = max_diff(a, c->rgb, nrgb);
    size_t moved = 0; /* output values moved by more than 1/255 */
    for (size_t i = 0; i < nrgb; i++)
        moved += fabsf(a[i] - c->rgb[i]) > 1.0f / 255;
    printf("%-34s %d lid Gaussians move %zu image values, by up to %.3f\n",
           name, nl, moved, d);
    CHECK_MSG(d > 2.0 / 255 && moved > 20, "%s: the lids do not move the "
              "image (%.3g, %zu values)", name, d, moved);
    /* held lids (the transfer's probes): at the held pitch whatever the
     * gaze, while the eyes turn */
    size_t nf = (size_t)m->cfg.n_face, nm = nf - (size_t)nl;
    CHECK(gs_frame_forward(c, pool, &fr, GS_STREAM_BOTH, 1, &err) == GS_OK);
    float *lx = malloc(3 * nf * sizeof(float)), *ex = malloc(3 * sizeof(float));
    CHECK(lx && ex);
    if (lx && ex) {
        memcpy(lx, c->g_mean, 3 * nf * sizeof(float));
        memcpy(ex, c->g_mean + 3 * nf, 3 * sizeof(float));
        c->lid_hold = 1;
        c->lid_pitch = fr.gaze[0];
        gs_frame f2 = fr;
        f2.gaze[0] = -0.3;
        CHECK(gs_frame_forward(c, pool, &f2, GS_STREAM_BOTH, 1, &err) == GS_OK);
        c->lid_hold = 0;
        CHECK_MSG(!memcmp(lx + 3 * nm, c->g_mean + 3 * nm,
                          3 * (size_t)nl * sizeof(float)),
                  "%s: held lids moved", name);
        CHECK_MSG(memcmp(ex, c->g_mean + 3 * nf, 3 * sizeof(float)),
                  "%s: the eyes did not turn under held lids", name);
        CHECK(gs_frame_forward(c, pool, &f2, GS_STREAM_BOTH, 1, &err) == GS_OK);
        CHECK_MSG(memcmp(lx + 3 * nm, c->g_mean + 3 * nm,
                         3 * (size_t)nl * sizeof(float)),
                  "%s: the lids did not follow the pitch", name);
    }
    free(lx);
    free(ex);
out:
    gs_model_ctx_destroy(c);
    free(a);
    free(k);
}

static void sweep(int guidance, int feat_size, int lids, int direct,
                  gs_pool *pool, const char *name)
{
    gs_model *m = make_model(guidance, feat_size, lids, direct);
    CHECK(m != NULL);
    if (!m)
        return;
    if (lids)
        lids_move(m, pool, name);
    gs_model_ctx *inc = gs_model_ctx_create(m), *full = gs_model_ctx_create(m);
    CHECK(inc && full);
    gs_frame fr;
    frame_default(m, &fr);
    size_t nrgb = 3 * (size_t)m->cfg.image_size * m->cfg.image_size;
    size_t nmap = (size_t)m->cfg.channels * feat_size * feat_size;
    /* gaze (pitch, yaw) in degrees: small steps, the range's corners, the
     * same gaze again (nothing moves), back */
    static const double gz[][2] = {{0, 0},   {2, 1},    {-5, 10}, {30, -40},
                                   {-30, 40}, {-30, 39}, {15, 0},  {15, 0},
                                   {0, 0},   {40, 50},  {-40, -50}, {0, 0}};
    double worst = 0.0, worst_map = 0.0, drawn = 0.0;
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
        if (direct) /* the composite is on: the eye stream drew pixels */
            drawn = fmax(drawn, max_diff(inc->rgb, inc->rgb_main, nrgb));
        worst_map = fmax(worst_map, max_diff(inc->fmap, full->fmap, nmap));
        CHECK_MSG(d <= TOL, "%s gaze (%g, %g): incremental differs by %.3g",
                  name, gz[k][0], gz[k][1], d);
    }
    CHECK_MSG(!direct || drawn > 0.01, "%s: the eye stream drew nothing "
              "over the renderer's image (%.3g)", name, drawn);
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
    /* a forward for fitting in between overwrites the maps: the render is
     * kept aside first, and the next one starts from it */
    gs_frame other = fr;
    other.head_t[1] += 3.0;
    CHECK(gs_frame_forward(inc, pool, &other, GS_STREAM_BOTH, 0, &err) == GS_OK);
    fr.gaze[1] = 0.1;
    CHECK(gs_frame_render(inc, pool, &fr, &was_inc, &err) == GS_OK);
    CHECK_MSG(was_inc == 1, "%s: the render before a forward was not kept", name);
    gs_model_ctx_destroy(full);
    full = gs_model_ctx_create(m);
    CHECK(gs_frame_forward(full, pool, &fr, GS_STREAM_BOTH, 0, &err) == GS_OK);
    double d = max_diff(inc->rgb, full->rgb, nrgb);
    CHECK_MSG(d <= TOL, "%s: render after a forward differs by %.3g", name, d);
    /* training (a forced face stream) drops every kept render */
    CHECK(gs_frame_forward(inc, pool, &other, GS_STREAM_BOTH, 1, &err) == GS_OK);
    fr.gaze[1] = 0.2;
    CHECK(gs_frame_render(inc, pool, &fr, &was_inc, &err) == GS_OK);
    CHECK_MSG(was_inc == 0, "%s: render after training must be full", name);
    gs_model_ctx_destroy(inc);
    gs_model_ctx_destroy(full);
    gs_model_destroy(m);
}

/* Several subjects (codes) and poses in turn through one context: the
 * sweep cache keeps each one's render, so every return to a kept one is
 * incremental and equals the full render; least recently used renders are
 * evicted; a cache of one keeps only the last. */
static void subjects(gs_pool *pool, int direct)
{
    gs_model *m = make_model(GS_GUIDE_ADDITIVE, 32, 0, direct);
    CHECK(m != NULL);
    if (!m)
        return;
    gs_model_ctx *inc = gs_model_ctx_create(m);
    gs_error err = {0, ""};
    gs_frame fr[3];
    for (int k = 0; k < 3; k++) {
        frame_default(m, &fr[k]);
        fr[k].code[1] += 0.3f * (float)k;     /* another subject */
    }
    fr[2].head_t[0] += 2.0;                     /* ... in another pose */
    size_t nrgb = 3 * (size_t)m->cfg.image_size * m->cfg.image_size;
    /* cache of 3: A B C (full), then A B C A C ... all incremental */
    static const int order[] = {0, 1, 2, 0, 1, 2, 0, 2, 1, 1, 0};
    int n = (int)(sizeof order / sizeof order[0]);
    double worst = 0.0;
    CHECK(gs_model_ctx_set_sweep_cache(inc, 3, &err) == GS_OK);
    for (int k = 0; k < n; k++) {
        gs_frame f = fr[order[k]];
        f.gaze[0] = 0.05 * (k % 5) - 0.1;
        f.gaze[1] = 0.3 - 0.07 * k;
        int was_inc = -1;
        CHECK_MSG(gs_frame_render(inc, pool, &f, &was_inc, &err) == GS_OK, "%s",
                  err.msg);
        CHECK_MSG(was_inc == (k >= 3), "subjects step %d: incremental = %d", k,
                  was_inc);
        gs_model_ctx *full = gs_model_ctx_create(m);
        CHECK(gs_frame_forward(full, pool, &f, GS_STREAM_BOTH, 0, &err) == GS_OK);
        worst = fmax(worst, max_diff(inc->rgb, full->rgb, nrgb));
        gs_model_ctx_destroy(full);
    }
    CHECK_MSG(worst <= TOL, "subjects: incremental differs by %.3g", worst);
    gs_model_ctx_stats st;
    gs_model_ctx_get_stats(inc, &st);
    CHECK_MSG(st.renders_full == 3 && st.renders_incremental == (uint64_t)n - 3 &&
              st.last_incremental == 1 && st.sweep_kept == 3,
              "stats: %llu full, %llu incremental, last %d, kept %d",
              (unsigned long long)st.renders_full,
              (unsigned long long)st.renders_incremental, st.last_incremental,
              st.sweep_kept);
    /* cache of 2: A B C evicts A */
    int was_inc = -1;
    CHECK(gs_model_ctx_set_sweep_cache(inc, 2, &err) == GS_OK);
    for (int k = 0; k < 3; k++)
        CHECK(gs_frame_render(inc, pool, &fr[k], &was_inc, &err) == GS_OK);
    CHECK(gs_frame_render(inc, pool, &fr[0], &was_inc, &err) == GS_OK);
    CHECK_MSG(was_inc == 0, "LRU: the oldest subject was not evicted");
    CHECK(gs_frame_render(inc, pool, &fr[2], &was_inc, &err) == GS_OK);
    CHECK_MSG(was_inc == 1, "LRU: the newer subject was evicted");
    /* cache of 1: only the last */
    CHECK(gs_model_ctx_set_sweep_cache(inc, 1, &err) == GS_OK);
    for (int k = 0; k < 4; k++) {
        CHECK(gs_frame_render(inc, pool, &fr[k % 2], &was_inc, &err) == GS_OK);
        CHECK_MSG(was_inc == 0, "cache of 1: step %d incremental", k);
    }
    CHECK(gs_model_ctx_set_sweep_cache(inc, 0, &err) == GS_ERR_ARG);
    CHECK(gs_model_ctx_set_sweep_cache(inc, GS_MODEL_MAX_SWEEP_CACHE + 1,
                                       &err) == GS_ERR_ARG);
    gs_model_ctx_destroy(inc);
    gs_model_destroy(m);
}

/* The public render through the cache: every pixel of the caller's buffer
 * is written (the 8-bit image is updated only where the render changed,
 * then copied whole), the stride's padding is not, and a colour transform
 * that changes between calls applies to every pixel. */
static void api_sweep(int direct)
{
    gs_model *m = make_model(GS_GUIDE_MULTIPLICATIVE, 32, 0, direct);
    CHECK(m != NULL);
    if (!m)
        return;
    gs_model_info info;
    gs_model_get_info(m, &info);
    int S = info.image_size;
    size_t stride = 3 * (size_t)S + 5, bytes = stride * S;
    uint8_t *a = malloc(bytes), *b = malloc(bytes);
    gs_model_ctx *c = gs_model_ctx_create(m);
    gs_subject sub[2];
    for (int k = 0; k < 2; k++) {
        gs_frame fr;
        frame_default(m, &fr);
        memset(&sub[k], 0, sizeof sub[k]);
        sub[k].code_dim = info.code_dim;
        memcpy(sub[k].code, fr.code, sizeof(float) * (size_t)info.code_dim);
        sub[k].code[0] += 0.4f * (float)k;
        memcpy(sub[k].head_R, fr.head_R, sizeof fr.head_R);
        memcpy(sub[k].head_t, fr.head_t, sizeof fr.head_t);
        for (int j = 0; j < 3; j++)
            sub[k].colour_gain[j] = 1.0f;
    }
    gs_error err = {0, ""};
    int worst = 0, pad_ok = 1;
    for (int k = 0; k < 10; k++) {
        gs_subject s = sub[k % 2];
        if (k == 6) /* the same subject and view, another transform */
            s.colour_gain[1] = 0.8f, s.colour_bias[2] = 0.1f;
        gs_view v = {0};
        v.gaze_pitch = k == 6 ? 0.05 * 5 - 0.2 : 0.05 * k - 0.2;
        v.gaze_yaw = k == 6 ? 0.4 - 0.09 * 5 : 0.4 - 0.09 * k;
        memset(a, 0xAB, bytes);
        memset(b, 0x5C, bytes);
        CHECK_MSG(gs_model_render(c, NULL, &s, &v, a, stride, &err) == GS_OK,
                  "%s", err.msg);
        gs_model_ctx *f = gs_model_ctx_create(m);
        CHECK(gs_model_render(f, NULL, &s, &v, b, stride, &err) == GS_OK);
        gs_model_ctx_destroy(f);
        for (int y = 0; y < S; y++) {
            for (size_t x = 0; x < 3 * (size_t)S; x++) {
                int d = abs((int)a[y * stride + x] - (int)b[y * stride + x]);
                worst = d > worst ? d : worst;
            }
            for (size_t x = 3 * (size_t)S; x < stride; x++)
                pad_ok &= a[y * stride + x] == 0xAB;
        }
    }
    /* a render's bytes depend on the subject and the view alone: a fresh
     * context's (the anchor, gs_model_render), bit for bit (eye_direct
     * models: within one level) */
    CHECK_MSG(direct ? worst <= 1 : worst == 0, "api sweep: 8-bit images differ by %d", worst);
    CHECK_MSG(pad_ok, "api sweep: the stride's padding was written");
    gs_model_ctx_stats st;
    gs_model_ctx_get_stats(c, &st);
    /* each subject's anchor at its own gaze in full, then all 10 views
     * (eye_direct models are not anchored: each subject's first view in
     * full, then 8) */
    CHECK_MSG(st.renders_full == 2 && st.renders_incremental == (direct ? 8u : 10u),
              "api sweep: %llu full, %llu incremental",
              (unsigned long long)st.renders_full,
              (unsigned long long)st.renders_incremental);
    printf("api sweep: 2 subjects, 10 renders, max 8-bit diff %d\n", worst);
    free(a);
    free(b);
    gs_model_ctx_destroy(c);
    gs_model_destroy(m);
}

/* An incremental render starts from its subject's full render (the
 * anchor), so its result does not depend on the gazes rendered before it:
 * gaze g4 after g1, g2, g3 is the float image and feature map of g4 right
 * after the anchor, bit for bit, and so is g4 in a second context that
 * rendered another subject in between; back at the anchor's gaze, the
 * anchor's render. (Before the anchor, each render went on from the last
 * one and differed from that by a few ulps.) */
static void order_free(gs_pool *pool, int lids)
{
    gs_model *m = make_model(GS_GUIDE_ADDITIVE, 32, lids, 0);
    CHECK(m != NULL);
    if (!m)
        return;
    if (lids)
        lids_move(m, pool, "order");
    size_t nrgb = 3 * (size_t)m->cfg.image_size * m->cfg.image_size;
    size_t nmap = (size_t)m->cfg.channels * 32 * 32;
    static const double g[][2] = {{0, 0}, {20, -30}, {-25, 35}, {12, 40}, {6, -12}};
    gs_frame fr, other;
    frame_default(m, &fr);
    other = fr;
    other.code[0] += 0.4f;
    gs_error err = {0, ""};
    gs_model_ctx *a = gs_model_ctx_create(m), *b = gs_model_ctx_create(m);
    float *rgb0 = malloc(nrgb * sizeof(float)), *map0 = malloc(nmap * sizeof(float));
    CHECK(a && b && rgb0 && map0);
    int was_inc = -1;
    for (int k = 0; k < 5; k++) { /* a: g0 (the anchor), g1, g2, g3, g4 */
        fr.gaze[0] = g[k][0] * GS_MODEL_PI / 180, fr.gaze[1] = g[k][1] * GS_MODEL_PI / 180;
        CHECK_MSG(gs_frame_render(a, pool, &fr, &was_inc, &err) == GS_OK, "%s", err.msg);
        if (k == 0) {
            memcpy(rgb0, a->rgb, nrgb * sizeof(float));
            memcpy(map0, a->fmap, nmap * sizeof(float));
        }
    }
    CHECK(was_inc == 1);
    /* b: g0, another subject, then g4 */
    fr.gaze[0] = fr.gaze[1] = 0;
    CHECK(gs_frame_render(b, pool, &fr, NULL, &err) == GS_OK);
    other.gaze[0] = 0.3, other.gaze[1] = -0.2;
    CHECK(gs_frame_render(b, pool, &other, NULL, &err) == GS_OK);
    fr.gaze[0] = g[4][0] * GS_MODEL_PI / 180, fr.gaze[1] = g[4][1] * GS_MODEL_PI / 180;
    CHECK(gs_frame_render(b, pool, &fr, &was_inc, &err) == GS_OK);
    CHECK_MSG(was_inc == 1, "order: the kept subject renders incrementally");
    CHECK_MSG(!memcmp(a->rgb, b->rgb, nrgb * sizeof(float)) &&
                  !memcmp(a->fmap, b->fmap, nmap * sizeof(float)),
              "order%s: g4 after g1..g3 is not g4 after the anchor (image %.3g, map %.3g)",
              lids ? " (lids)" : "", max_diff(a->rgb, b->rgb, nrgb),
              max_diff(a->fmap, b->fmap, nmap));
    fr.gaze[0] = fr.gaze[1] = 0;
    CHECK(gs_frame_render(a, pool, &fr, &was_inc, &err) == GS_OK);
    CHECK_MSG(was_inc == 1 && !memcmp(a->rgb, rgb0, nrgb * sizeof(float)) &&
                  !memcmp(a->fmap, map0, nmap * sizeof(float)),
              "order%s: back at the anchor's gaze, not the anchor's render (%.3g)",
              lids ? " (lids)" : "", max_diff(a->rgb, rgb0, nrgb));
    printf("order%s: a gaze renders the same bits after any gazes before it\n",
           lids ? " (lids)" : "");
    free(rgb0);
    free(map0);
    gs_model_ctx_destroy(a);
    gs_model_ctx_destroy(b);
    gs_model_destroy(m);
}

/* A head change with the same code keeps the face stream's expression MLP
 * rows (face_expr_kept) and runs the rest: each render of a walk through
 * poses and codes must be a fresh context's, bit for bit (image and map).
 * After the parameters change, gs_model_ctx_reset must drop the rows; and
 * without it they would be stale (the rule the reset is there for). */
static void head_change(gs_pool *pool, int lids)
{
    gs_model *m = make_model(GS_GUIDE_ADDITIVE, 32, lids, 0);
    CHECK(m != NULL);
    if (!m)
        return;
    size_t nrgb = 3 * (size_t)m->cfg.image_size * m->cfg.image_size;
    size_t nmap = (size_t)m->cfg.channels * 32 * 32;
    /* pose (pitch, yaw in degrees), code offset; 1, 3 and 5 keep the rows */
    static const double walk[][3] = {{5, -10, 0}, {-8, 14, 0}, {-8, 14, 0.3},
                                     {12, 4, 0.3}, {-3, 9, 0}, {0, -20, 0}};
    enum { NW = sizeof walk / sizeof walk[0] };
    gs_error err = {0, ""};
    gs_model_ctx *a = gs_model_ctx_create(m);
    CHECK(a != NULL);
    int bad = -1;
    gs_frame fr;
    for (int k = 0; k < NW && a; k++) {
        frame_default(m, &fr);
        gs_geom_rot_from_pitchyaw(walk[k][0] * GS_MODEL_PI / 180,
                                  walk[k][1] * GS_MODEL_PI / 180, 0.02, fr.head_R);
        fr.code[0] += (float)walk[k][2];
        CHECK_MSG(gs_frame_render(a, pool, &fr, NULL, &err) == GS_OK, "%s", err.msg);
        gs_model_ctx *f = gs_model_ctx_create(m);
        CHECK(f && gs_frame_render(f, pool, &fr, NULL, &err) == GS_OK);
        if (f && bad < 0 &&
            (memcmp(a->rgb, f->rgb, nrgb * sizeof(float)) ||
             memcmp(a->fmap, f->fmap, nmap * sizeof(float))))
            bad = k;
        gs_model_ctx_destroy(f);
    }
    CHECK_MSG(bad < 0, "head change%s: render %d differs from a fresh context's",
              lids ? " (lids)" : "", bad);
    /* a render's merged map starts from the face-only map and composites
     * the tiles the eyes and lids reach: a training forward composites
     * every tile, and the map is the same bits */
    gs_model_ctx *t = gs_model_ctx_create(m);
    CHECK(t && gs_frame_forward(t, pool, &fr, GS_STREAM_BOTH, 0, &err) == GS_OK);
    CHECK_MSG(t && !memcmp(a->fmap, t->fmap, nmap * sizeof(float)) &&
                  !memcmp(a->rgb, t->rgb, nrgb * sizeof(float)),
              "head change%s: a render's map is not a training forward's (%.3g)",
              lids ? " (lids)" : "", t ? max_diff(a->fmap, t->fmap, nmap) : -1.0);
    gs_model_ctx_destroy(t);
    gs_model_ctx_stats st;
    gs_model_ctx_get_stats(a, &st);
    CHECK_MSG(st.face_expr_kept == 3, "head change: %llu renders kept the rows, want 3",
              (unsigned long long)st.face_expr_kept);
    /* new parameters (as gs_model_tuned_apply gives): with the reset, a new
     * pose is a fresh context's; without it, the old rows show */
    for (int i = 0; i < m->p.face_e.dims[1]; i++)
        m->p.face_e.b[0][i] += 0.05f;
    gs_model_ctx *stale = gs_model_ctx_create(m);
    CHECK(stale && gs_frame_render(stale, pool, &fr, NULL, &err) == GS_OK);
    for (int i = 0; i < m->p.face_e.dims[1]; i++)
        m->p.face_e.b[0][i] += 0.25f;
    gs_model_ctx_reset(a);
    gs_geom_rot_from_pitchyaw(0.1, 0.1, 0.02, fr.head_R);
    CHECK(gs_frame_render(a, pool, &fr, NULL, &err) == GS_OK);
    CHECK(stale && gs_frame_render(stale, pool, &fr, NULL, &err) == GS_OK);
    gs_model_ctx *f = gs_model_ctx_create(m);
    CHECK(f && gs_frame_render(f, pool, &fr, NULL, &err) == GS_OK);
    CHECK_MSG(f && !memcmp(a->rgb, f->rgb, nrgb * sizeof(float)),
              "head change: after new parameters and a reset, not a fresh render (%.3g)",
              f ? max_diff(a->rgb, f->rgb, nrgb) : -1.0);
    CHECK_MSG(f && stale && max_diff(stale->rgb, f->rgb, nrgb) > 1e-4,
              "head change: without a reset the kept rows did not show");
    gs_model_ctx_get_stats(a, &st);
    CHECK_MSG(st.face_expr_kept == 3, "head change: the reset kept the rows");
    printf("head change%s: %d renders the bits of fresh ones, 3 kept the expression rows\n",
           lids ? " (lids)" : "", NW);
    gs_model_ctx_destroy(f);
    gs_model_ctx_destroy(stale);
    gs_model_ctx_destroy(a);
    gs_model_destroy(m);
}

/* BLOCK guidance (the released code's) depends on every pixel: such models
 * always render in full. */
static void block_is_full(void)
{
    gs_model *m = make_model(GS_GUIDE_ADDITIVE, 32, 0, 0);
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
    sweep(GS_GUIDE_ADDITIVE, 32, 0, 0, NULL, "additive 32^2");
    sweep(GS_GUIDE_MULTIPLICATIVE, 32, 0, 0, pool, "multiplicative 32^2, 2 threads");
    sweep(GS_GUIDE_NONE, 32, 0, 0, NULL, "no guidance 32^2");
    sweep(GS_GUIDE_ADDITIVE, 64, 0, 0, pool, "additive 64^2, 2 threads");
    sweep(GS_GUIDE_ADDITIVE, 32, 1, 0, NULL, "additive 32^2, lids");
    sweep(GS_GUIDE_MULTIPLICATIVE, 64, 1, 0, pool, "multiplicative 64^2, lids, 2 thr");
    /* the eye stream also drawn at the image's size (config.eye_direct) */
    sweep(GS_GUIDE_ADDITIVE, 32, 0, 1, NULL, "additive 32^2, eye direct");
    sweep(GS_GUIDE_MULTIPLICATIVE, 64, 1, 1, pool, "mult. 64^2, lids, eye direct, 2 thr");
    subjects(pool, 0);
    subjects(pool, 1);
    api_sweep(0);
    api_sweep(1);
    order_free(pool, 0);
    order_free(NULL, 1);
    head_change(pool, 0);
    head_change(NULL, 1);
    block_is_full();
    gs_pool_destroy(pool);
    GS_TEST_END();
}
