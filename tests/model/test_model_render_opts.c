/* Render-time speed knobs (docs/model.md "Speed against quality"):
 * pruning the face stream (gs_model_prune) and the feature-map scale and
 * full renders (gs_model_ctx_set_render_options). Identity at 100 % / 1.0,
 * the pruned set is the most important one and nested, renders stay finite
 * with few Gaussians or a coarse or supersampled map, supersampling
 * converges, bad settings are refused. */
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "gazesplat/nn.h"
#include "gs_test.h"
#include "model_test_util.h"

static gs_model *make_model(void)
{
    gs_model_config cfg;
    tiny_config(&cfg);
    cfg.guidance = GS_GUIDE_ADDITIVE;
    cfg.guide_source = GS_GUIDE_SRC_SOURCE; /* incremental renders allowed */
    gs_model *m = NULL;
    gs_error err;
    if (gs_model_create(&cfg, 5, &m, &err) != GS_OK) {
        fprintf(stderr, "make_model: %s\n", err.msg);
        return NULL;
    }
    for (int i = 0; i < cfg.channels * cfg.channels; i++) /* live guidance */
        m->p.rend.value_w[i] = 0.02f * (float)((i * 7) % 11 - 5);
    return m;
}

static gs_view view_k(int k)
{
    gs_view v;
    memset(&v, 0, sizeof v);
    v.gaze_pitch = 0.06 * k - 0.2;
    v.gaze_yaw = 0.35 - 0.1 * k;
    return v;
}

/* Renders views 0..n-1 into imgs (n images of bytes each). */
static int render_views(gs_model_ctx *c, gs_pool *pool, const gs_subject *s,
                        int n, uint8_t *imgs, size_t stride, size_t bytes)
{
    gs_error err = {0, ""};
    for (int k = 0; k < n; k++) {
        gs_view v = view_k(k);
        if (gs_model_render(c, pool, s, &v, imgs + k * bytes, stride, &err)) {
            fprintf(stderr, "render %d: %s\n", k, err.msg);
            return -1;
        }
    }
    return 0;
}

static double mean_abs_diff(const uint8_t *a, const uint8_t *b, size_t n)
{
    double s = 0;
    for (size_t i = 0; i < n; i++)
        s += abs((int)a[i] - (int)b[i]);
    return s / (double)n;
}

/* keep >= n_face: the same model, bit for bit. */
static void prune_identity(const gs_model *m, gs_pool *pool)
{
    gs_error err = {0, ""};
    int n = m->cfg.n_face;
    for (int extra = 0; extra <= 100; extra += 100) {
        gs_model *p = NULL;
        CHECK_MSG(gs_model_prune(m, pool, n + extra, &p, &err) == GS_OK,
                  "%s", err.msg);
        if (!p)
            return;
        CHECK_EQ_INT(p->cfg.n_face, n);
        CHECK_EQ_INT(p->nparams, m->nparams);
        CHECK_MSG(memcmp(p->params, m->params,
                         m->nparams * sizeof(float)) == 0,
                  "prune to %d of %d changed the parameters", n + extra, n);
        gs_model_destroy(p);
    }
    gs_model *p = NULL;
    CHECK(gs_model_prune(m, pool, 0, &p, &err) == GS_ERR_ARG && !p);
    CHECK(gs_model_prune(m, pool, -3, &p, &err) == GS_ERR_ARG && !p);
    CHECK(gs_model_prune(NULL, pool, 3, &p, &err) == GS_ERR_ARG);
}

typedef struct rank_t {
    double v;
    int i;
} rank_t;

static int by_imp(const void *a, const void *b)
{
    const rank_t *x = a, *y = b;
    if (x->v != y->v)
        return x->v > y->v ? -1 : 1;
    return (x->i > y->i) - (x->i < y->i);
}

/* The pruned model holds the rows of the K most important face
 * Gaussians, in order; the count falls with K; the sets are nested. */
static void prune_sets(const gs_model *m, gs_pool *pool)
{
    gs_error err = {0, ""};
    int n = m->cfg.n_face, C = m->cfg.channels;
    double *imp = malloc((size_t)n * sizeof *imp);
    double *imp1 = malloc((size_t)n * sizeof *imp1);
    rank_t *r = malloc((size_t)n * sizeof *r);
    CHECK(gs_model_face_importance(m, pool, imp, &err) == GS_OK);
    CHECK(gs_model_face_importance(m, NULL, imp1, &err) == GS_OK);
    CHECK_MSG(memcmp(imp, imp1, (size_t)n * sizeof *imp) == 0,
              "importance depends on the thread count");
    int positive = 0;
    for (int i = 0; i < n; i++) {
        CHECK(isfinite(imp[i]) && imp[i] >= 0);
        positive += imp[i] > 0;
        r[i] = (rank_t){imp[i], i};
    }
    /* some Gaussians are seen, some are not (back of the head, hidden) */
    CHECK_MSG(positive > n / 10 && positive < n,
              "%d of %d face Gaussians with a weight", positive, n);
    qsort(r, (size_t)n, sizeof *r, by_imp);
    int ks[] = {n / 2, n / 4, n / 10, 1};
    int prev = n;
    for (size_t t = 0; t < sizeof ks / sizeof ks[0]; t++) {
        int k = ks[t];
        gs_model *p = NULL;
        CHECK_MSG(gs_model_prune(m, pool, k, &p, &err) == GS_OK, "%s",
                  err.msg);
        if (!p)
            continue;
        gs_model_info info;
        gs_model_get_info(p, &info);
        CHECK_EQ_INT(info.n_face, k);
        CHECK(info.n_face < prev);
        prev = info.n_face;
        CHECK_EQ_INT(info.n_eye, 2 * m->cfg.n_eye_each);
        /* expected rows: the top k indices in increasing order */
        unsigned char *keep = calloc((size_t)n, 1);
        for (int i = 0; i < k; i++)
            keep[r[i].i] = 1;
        int j = 0, rows_ok = 1;
        for (int i = 0; i < n; i++) {
            if (!keep[i])
                continue;
            rows_ok &= memcmp(p->p.f_xyz + 3 * (size_t)j,
                              m->p.f_xyz + 3 * (size_t)i,
                              3 * sizeof(float)) == 0;
            rows_ok &= memcmp(p->p.f_colour + (size_t)j * C,
                              m->p.f_colour + (size_t)i * C,
                              (size_t)C * sizeof(float)) == 0;
            rows_ok &= p->p.f_lambda[j] == m->p.f_lambda[i];
            j++;
        }
        CHECK_MSG(rows_ok, "prune %d: not the most important rows", k);
        CHECK(memcmp(p->p.e_xyz, m->p.e_xyz,
                     (size_t)6 * m->cfg.n_eye_each * sizeof(float)) == 0);
        CHECK(memcmp(p->p.rend.rgb0.w, m->p.rend.rgb0.w,
                     3 * (size_t)C * sizeof(float)) == 0);
        free(keep);
        gs_model_destroy(p);
    }
    free(imp);
    free(imp1);
    free(r);
}

/* A subject renders through pruned models down to one face Gaussian:
 * finite (gs_model_render refuses a non-finite pixel), and closer to the
 * full render with more Gaussians kept. */
static void prune_render(const gs_model *m, gs_pool *pool)
{
    gs_error err = {0, ""};
    int S = m->cfg.image_size, n = m->cfg.n_face;
    size_t stride = 3 * (size_t)S, bytes = stride * S;
    uint8_t *full = malloc(bytes), *img = malloc(bytes);
    gs_subject s = frame_subject(m);
    gs_view v = view_k(1);
    gs_model_ctx *c = gs_model_ctx_create(m);
    CHECK(gs_model_render(c, pool, &s, &v, full, stride, &err) == GS_OK);
    gs_model_ctx_destroy(c);
    int ks[] = {n, n / 2, n / 10, 1};
    double last = -1;
    for (size_t t = 0; t < sizeof ks / sizeof ks[0]; t++) {
        gs_model *p = NULL;
        CHECK(gs_model_prune(m, pool, ks[t], &p, &err) == GS_OK);
        gs_model_ctx *pc = p ? gs_model_ctx_create(p) : NULL;
        CHECK(pc != NULL);
        if (!pc) {
            gs_model_destroy(p);
            continue;
        }
        CHECK_MSG(gs_model_render(pc, pool, &s, &v, img, stride, &err) ==
                      GS_OK, "keep %d: %s", ks[t], err.msg);
        double d = mean_abs_diff(img, full, bytes);
        printf("prune: keep %d of %d face Gaussians: mean |diff| %.3f\n",
               ks[t], n, d);
        if (t == 0)
            CHECK_MSG(d == 0, "keep all: images differ (%.3g)", d);
        else
            CHECK_MSG(d >= last, "keep %d: closer (%.3f) than keeping more "
                      "(%.3f)", ks[t], d, last);
        last = d;
        gs_model_ctx_destroy(pc);
        gs_model_destroy(p);
    }
    free(full);
    free(img);
}

/* Options at their defaults (scale 1, incremental): the same bytes and
 * the same paths as a context that never had them set. */
static void scale_identity(const gs_model *m, gs_pool *pool)
{
    enum { N = 6 };
    gs_error err = {0, ""};
    int S = m->cfg.image_size;
    size_t stride = 3 * (size_t)S, bytes = stride * S;
    uint8_t *a = malloc(N * bytes), *b = malloc(N * bytes);
    gs_subject s = frame_subject(m);
    gs_model_ctx *c0 = gs_model_ctx_create(m), *c1 = gs_model_ctx_create(m);
    gs_model_render_options o;
    gs_model_render_options_default(&o);
    CHECK(o.feature_scale == 1.0 && o.full == 0);
    o.feature_scale = 0.5; /* set, then back to 1 */
    CHECK(gs_model_ctx_set_render_options(c1, &o, &err) == GS_OK);
    o.feature_scale = 1.0;
    CHECK(gs_model_ctx_set_render_options(c1, &o, &err) == GS_OK);
    CHECK(render_views(c0, pool, &s, N, a, stride, bytes) == 0);
    CHECK(render_views(c1, pool, &s, N, b, stride, bytes) == 0);
    CHECK_MSG(memcmp(a, b, N * bytes) == 0, "scale 1.0: images differ");
    gs_model_ctx_stats s0, s1;
    gs_model_ctx_get_stats(c0, &s0);
    gs_model_ctx_get_stats(c1, &s1);
    /* the first view is not the subject's own gaze: the anchor at its own
     * gaze in full, then every view incremental (gs_model_render) */
    CHECK_MSG(s1.renders_full == 1 && s1.renders_incremental == N &&
                  s0.renders_incremental == s1.renders_incremental,
              "scale 1.0: %llu full, %llu incremental",
              (unsigned long long)s1.renders_full,
              (unsigned long long)s1.renders_incremental);
    gs_model_ctx_destroy(c0);
    gs_model_ctx_destroy(c1);
    free(a);
    free(b);
}

/* --full-render: every render equals a fresh context's first render,
 * bit for bit, and none is incremental. */
static void full_renders(const gs_model *m, gs_pool *pool)
{
    enum { N = 4 };
    gs_error err = {0, ""};
    int S = m->cfg.image_size;
    size_t stride = 3 * (size_t)S, bytes = stride * S;
    uint8_t *a = malloc(N * bytes), *b = malloc(bytes);
    gs_subject s = frame_subject(m);
    gs_model_ctx *c = gs_model_ctx_create(m);
    gs_model_render_options o;
    gs_model_render_options_default(&o);
    o.full = 1;
    CHECK(gs_model_ctx_set_render_options(c, &o, &err) == GS_OK);
    CHECK(render_views(c, pool, &s, N, a, stride, bytes) == 0);
    for (int k = 0; k < N; k++) {
        gs_model_ctx *f = gs_model_ctx_create(m);
        gs_view v = view_k(k);
        CHECK(gs_model_render(f, pool, &s, &v, b, stride, &err) == GS_OK);
        CHECK_MSG(memcmp(a + k * bytes, b, bytes) == 0,
                  "full render %d differs from a fresh context's", k);
        gs_model_ctx_destroy(f);
    }
    gs_model_ctx_stats st;
    gs_model_ctx_get_stats(c, &st);
    CHECK_MSG(st.renders_full == N && st.renders_incremental == 0,
              "full: %llu full, %llu incremental",
              (unsigned long long)st.renders_full,
              (unsigned long long)st.renders_incremental);
    gs_model_ctx_destroy(c);
    free(a);
    free(b);
}

/* Coarser feature maps: finite, full renders, near the exact image, and a
 * fit through the same context is unaffected. */
static void coarse_maps(const gs_model *m, gs_pool *pool)
{
    enum { N = 3 };
    gs_error err = {0, ""};
    int S = m->cfg.image_size;
    size_t stride = 3 * (size_t)S, bytes = stride * S;
    uint8_t *ref = malloc(N * bytes), *img = malloc(N * bytes);
    gs_subject s = frame_subject(m);
    gs_model_ctx *c0 = gs_model_ctx_create(m);
    CHECK(render_views(c0, pool, &s, N, ref, stride, bytes) == 0);
    const double scales[] = {0.75, 0.5, 0.25, 2.0, 3.0};
    for (size_t t = 0; t < sizeof scales / sizeof scales[0]; t++) {
        gs_model_ctx *c = gs_model_ctx_create(m);
        gs_model_render_options o;
        gs_model_render_options_default(&o);
        o.feature_scale = scales[t];
        CHECK(gs_model_ctx_set_render_options(c, &o, &err) == GS_OK);
        CHECK(render_views(c, pool, &s, N, img, stride, bytes) == 0);
        double d = mean_abs_diff(img, ref, N * bytes);
        printf("feature scale %.2f: mean |diff| %.3f (8-bit)\n", scales[t],
               d);
        CHECK_MSG(d > 0 && d < 40, "scale %.2f: mean |diff| %.3f",
                  scales[t], d);
        gs_model_ctx_stats st;
        gs_model_ctx_get_stats(c, &st);
        CHECK(st.renders_full == N && st.renders_incremental == 0);
        /* the fit's forward runs at the model's resolution: a render at
         * scale 1 afterwards through a fresh-options context matches */
        gs_fit_options fo;
        gs_fit_options_default(&fo);
        fo.max_iters = 2;
        fo.known_head = 1;
        memcpy(fo.head_R, s.head_R, sizeof fo.head_R);
        memcpy(fo.head_t, s.head_t, sizeof fo.head_t);
        gs_subject fit_a, fit_b;
        gs_model_ctx *cf = gs_model_ctx_create(m);
        CHECK(gs_model_fit(c, pool, ref, stride, &fo, &fit_a, NULL, &err) ==
              GS_OK);
        CHECK(gs_model_fit(cf, pool, ref, stride, &fo, &fit_b, NULL, &err) ==
              GS_OK);
        CHECK_MSG(memcmp(fit_a.code, fit_b.code, sizeof fit_a.code) == 0 &&
                      fit_a.fit_psnr == fit_b.fit_psnr,
                  "scale %.2f: the fit changed", scales[t]);
        gs_model_ctx_destroy(cf);
        gs_model_ctx_destroy(c);
    }
    gs_model_ctx_destroy(c0);
    free(ref);
    free(img);
}

/* Supersampled maps (feature scale 2..4): each feature pixel the mean of
 * k x k. They converge: scale 2 is nearer scale 4 than the point-sampled
 * map is; the same bytes with and without a pool; back at scale 1 the
 * context renders the exact images again. */
static void super_maps(const gs_model *m, gs_pool *pool)
{
    enum { N = 3 };
    gs_error err = {0, ""};
    int S = m->cfg.image_size;
    size_t stride = 3 * (size_t)S, bytes = stride * S;
    uint8_t *img[4];
    for (int i = 0; i < 4; i++)
        img[i] = malloc(N * bytes);
    gs_subject s = frame_subject(m);
    gs_model_ctx *c = gs_model_ctx_create(m);
    CHECK(render_views(c, pool, &s, N, img[0], stride, bytes) == 0);
    gs_model_render_options o;
    gs_model_render_options_default(&o);
    o.feature_scale = 4.0;
    CHECK(gs_model_ctx_set_render_options(c, &o, &err) == GS_OK);
    CHECK(render_views(c, pool, &s, N, img[1], stride, bytes) == 0);
    o.feature_scale = 2.0;
    CHECK(gs_model_ctx_set_render_options(c, &o, &err) == GS_OK);
    CHECK(render_views(c, pool, &s, N, img[2], stride, bytes) == 0);
    CHECK(render_views(c, NULL, &s, N, img[3], stride, bytes) == 0);
    CHECK_MSG(memcmp(img[2], img[3], N * bytes) == 0,
              "scale 2: pool and no pool differ");
    { /* the map the renderer saw: the 2 x 2 means of one rasterized at
       * twice the size through the same view */
        double worst = 1, worst_a = 1;
        CHECK(supersample_error(c, s.head_t, 2, &worst, &worst_a) == 0);
        CHECK_MSG(worst < 1e-6 && worst_a < 1e-6,
                  "scale 2: map off the 2 x 2 means by %g, alpha by %g",
                  worst, worst_a);
    }
    double d1 = mean_abs_diff(img[0], img[1], N * bytes);
    double d2 = mean_abs_diff(img[2], img[1], N * bytes);
    printf("against scale 4: scale 1 %.3f, scale 2 %.3f (8-bit)\n", d1, d2);
    CHECK_MSG(d2 < 0.7 * d1, "scale 2 is not nearer scale 4: %.3f vs %.3f",
              d2, d1);
    o.feature_scale = 1.0;
    CHECK(gs_model_ctx_set_render_options(c, &o, &err) == GS_OK);
    CHECK(render_views(c, pool, &s, N, img[3], stride, bytes) == 0);
    CHECK_MSG(memcmp(img[0], img[3], N * bytes) == 0,
              "scale 1 after 2: images differ");
    gs_model_ctx_destroy(c);
    for (int i = 0; i < 4; i++)
        free(img[i]);
}

static void bad_options(const gs_model *m)
{
    gs_error err = {0, ""};
    gs_model_ctx *c = gs_model_ctx_create(m);
    gs_model_render_options o;
    gs_model_render_options_default(&o);
    const double bad[] = {0.0, -0.5, 1.01, 1.5, 2.5, 5.0, INFINITY, NAN,
                          3.0 / m->cfg.feat_size};
    for (size_t t = 0; t < sizeof bad / sizeof bad[0]; t++) {
        o.feature_scale = bad[t];
        CHECK_MSG(gs_model_ctx_set_render_options(c, &o, &err) == GS_ERR_ARG,
                  "scale %g accepted", bad[t]);
    }
    CHECK(gs_model_ctx_set_render_options(NULL, &o, &err) == GS_ERR_ARG);
    CHECK(gs_model_ctx_set_render_options(c, NULL, &err) == GS_ERR_ARG);
    gs_model_ctx_destroy(c);
}

/* gs_nn_resize_bilinear_forward: the 2x kernel's values at 2x, a copy at
 * 1x, and PyTorch's taps at 3 -> 5 (values from
 * F.interpolate(x, size=5, mode='bilinear', align_corners=False)). */
static void resize_kernel(void)
{
    enum { C = 2, H = 5, W = 7 };
    float in[C * H * W], a[C * 4 * H * W], b[C * 4 * H * W];
    for (int i = 0; i < C * H * W; i++)
        in[i] = (float)((i * 37) % 17) / 7.0f - 1.0f;
    CHECK(gs_nn_resize_bilinear_forward(a, in, C, H, W, 2 * H, 2 * W) ==
          GS_OK);
    CHECK(gs_nn_upsample2x_forward(b, in, C, H, W) == GS_OK);
    CHECK_MSG(memcmp(a, b, sizeof a) == 0, "resize 2x != upsample2x");
    CHECK(gs_nn_resize_bilinear_forward(a, in, C, H, W, H, W) == GS_OK);
    CHECK_MSG(memcmp(a, in, sizeof in) == 0, "resize 1x is not a copy");
    const float row[3] = {0.0f, 3.0f, 6.0f};
    const float want[5] = {0.0f, 1.2f, 3.0f, 4.8f, 6.0f};
    float got[5];
    CHECK(gs_nn_resize_bilinear_forward(got, row, 1, 1, 3, 1, 5) == GS_OK);
    for (int i = 0; i < 5; i++)
        CHECK_CLOSE(got[i], want[i], 1e-6, 0);
    CHECK(gs_nn_resize_bilinear_forward(got, row, 1, 1, 3, 0, 5) ==
          GS_ERR_ARG);
}

int main(void)
{
    gs_model *m = make_model();
    CHECK(m != NULL);
    if (!m)
        GS_TEST_END();
    gs_pool *pool = gs_pool_create(2);
    resize_kernel();
    prune_identity(m, pool);
    prune_sets(m, pool);
    prune_render(m, pool);
    scale_identity(m, pool);
    full_renders(m, NULL);
    coarse_maps(m, pool);
    super_maps(m, pool);
    bad_options(m);
    gs_pool_destroy(pool);
    gs_model_destroy(m);
    GS_TEST_END();
}
