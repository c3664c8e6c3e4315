/* A supersampled model (config.supersample = k > 1: the feature map is
 * rasterized at k feat_size and each pixel is the mean of k x k samples,
 * in training, fitting and rendering). Checks: the training forward's map
 * is the k x k means of a map rasterized at k times the size; the
 * gradients of the whole frame (streams, rasterizer, the box, renderer)
 * against central differences, at k = 1 and 2 with the same tolerance; the
 * file keeps k and files without the key mean 1; renders are full and
 * pool-independent, scale 1 is the model's own sampling; a fit converges;
 * the eye-cover loss and bad k are refused. */
#define _POSIX_C_SOURCE 200809L
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "gs_test.h"
#include "model_test_util.h"

static gs_model *ss_model(int k, uint64_t seed)
{
    gs_model_config cfg;
    tiny_config(&cfg);
    cfg.guidance = GS_GUIDE_ADDITIVE;
    cfg.guide_source = GS_GUIDE_SRC_SOURCE;
    cfg.supersample = k;
    gs_model *m = NULL;
    gs_error err;
    if (gs_model_create(&cfg, seed, &m, &err) != GS_OK) {
        fprintf(stderr, "ss_model: %s\n", err.msg);
        return NULL;
    }
    for (int i = 0; i < cfg.channels * cfg.channels; i++) /* live guidance */
        m->p.rend.value_w[i] = 0.02f * (float)((i * 7) % 11 - 5);
    return m;
}

/* The training forward's map against the k x k means of the Gaussians it
 * rasterized, through the same view at k times the size. */
static void map_means(int k)
{
    gs_model *m = ss_model(k, 3);
    CHECK(m != NULL);
    if (!m)
        return;
    gs_model_ctx *c = gs_model_ctx_create(m);
    gs_error err = {0, ""};
    gs_frame fr;
    frame_default(m, &fr);
    CHECK(gs_frame_forward(c, NULL, &fr, GS_STREAM_BOTH, 1, &err) == GS_OK);
    double worst = 1, worst_a = 1;
    CHECK(supersample_error(c, fr.head_t, k, &worst, &worst_a) == 0);
    printf("k %d: map off the %d x %d means by %.2e, alpha by %.2e\n", k, k,
           k, worst, worst_a);
    CHECK_MSG(worst < 1e-6 && worst_a < 1e-6, "k %d: %g, %g", k, worst,
              worst_a);
    gs_model_ctx_destroy(c);
    gs_model_destroy(m);
}

typedef struct objective {
    gs_model_ctx *c;
    float *w_rgb, *w_map, *w_face;
    size_t n_rgb, n_map;
} objective;

/* A fixed random linear function of the image, the merged map and the
 * face-only map (the guidance source): every path a loss takes. */
static double value(objective *o, const gs_frame *fr)
{
    gs_error err = {0, ""};
    if (gs_frame_forward(o->c, NULL, fr, GS_STREAM_BOTH, 1, &err) != GS_OK)
        return NAN;
    double s = 0;
    for (size_t i = 0; i < o->n_rgb; i++)
        s += (double)o->w_rgb[i] * o->c->rgb[i];
    for (size_t i = 0; i < o->n_map; i++)
        s += (double)o->w_map[i] * o->c->fmap[i] +
             (double)o->w_face[i] * o->c->fmap_face[i];
    return s;
}

static float *rand_weights(size_t n, unsigned *r)
{
    float *w = malloc(n * sizeof *w);
    for (size_t i = 0; i < n; i++) {
        *r = *r * 1103515245u + 12345u;
        w[i] = ((*r >> 8) & 0xffff) / 65536.0f - 0.5f;
    }
    return w;
}

/* Central differences of the code (which moves, scales and colours the
 * Gaussians through the MLPs) and of sparse directions in the feature and
 * opacity tensors, against gs_frame_backward; returns the mismatches.
 * Not the gaze: a turn of the eyes moves few Gaussians, and the jumps of
 * the rasterizer's cut-offs (alpha 1/255, 3 sigma) outweigh its small
 * smooth part in any difference step (test_model_streams checks it to the
 * Gaussians, tests/raster from there). Not the head's translation: the
 * camera's focal follows |t|, which the backward leaves out, so along the
 * optical axis the image hardly moves while the gradient says it does. */
static int gradcheck(int k)
{
    gs_model *m = ss_model(k, 11);
    CHECK(m != NULL);
    if (!m)
        return 1;
    objective o;
    o.c = gs_model_ctx_create(m);
    o.c->face_loss = 1; /* the face-only map takes its own gradient */
    int S = m->cfg.image_size, fs = o.c->fs;
    o.n_rgb = 3 * (size_t)S * S;
    o.n_map = (size_t)o.c->C * fs * fs;
    unsigned r = 4242;
    o.w_rgb = rand_weights(o.n_rgb, &r);
    o.w_map = rand_weights(o.n_map, &r);
    o.w_face = rand_weights(o.n_map, &r);
    gs_frame fr;
    frame_default(m, &fr);
    double v0 = value(&o, &fr);
    CHECK(isfinite(v0));
    float *grad = calloc(m->nparams, sizeof(float));
    gs_model_params g;
    gs_model_bind(m, grad, &g);
    gs_frame_grad fg;
    memset(&fg, 0, sizeof fg);
    gs_error err = {0, ""};
    CHECK(o.c->used_face_map);
    CHECK(gs_frame_backward(o.c, NULL, o.w_rgb, o.w_map, o.w_face, NULL, &g,
                            &fg, &err) == GS_OK);
    int bad = 0, n = 0;
    double worst = 0;
#define COMPARE(what, ana, num, rel, abs_)                                    \
    do {                                                                      \
        double a_ = (ana), n_ = (num), e_ = fabs(a_ - n_);                    \
        double t_ = (rel) * fmax(fabs(a_), fabs(n_)) + (abs_);                \
        n++;                                                                  \
        worst = fmax(worst, e_ / t_);                                         \
        if (getenv("GS_VERBOSE"))                                             \
            printf("  k %d %-28s analytic %+.5e numeric %+.5e\n", k, what,  \
                   a_, n_);                                                   \
        if (e_ > t_ || !isfinite(n_)) {                                       \
            bad++;                                                            \
            printf("  k %d MISMATCH %-28s analytic %+.5e numeric %+.5e\n", k, \
                   what, a_, n_);                                             \
        }                                                                     \
    } while (0)
    char name[96];
    for (int i = 0; i < gs_model_code_dim(&m->cfg); i++) {
        gs_frame f2 = fr;
        float h = 2e-2f;
        f2.code[i] = fr.code[i] + h;
        double up = value(&o, &f2);
        f2.code[i] = fr.code[i] - h;
        double dn = value(&o, &f2);
        double hh = (double)(fr.code[i] + h) - (double)(fr.code[i] - h);
        snprintf(name, sizeof name, "code[%d]", i);
        COMPARE(name, fg.code[i], (up - dn) / hh, 0.03, 1e-3);
    }
    /* Per-Gaussian colours, latent features and opacities: sparse
     * directions. */
    for (int ti = 0; ti < m->ntensors; ti++) {
        const gs_ptensor *t = &m->t[ti];
        if (!strstr(t->name, "colour") && !strstr(t->name, ".feat") &&
            !strstr(t->name, "opacity"))
            continue;
        float *save = malloc(t->count * sizeof(float));
        memcpy(save, m->params + t->offset, t->count * sizeof(float));
        for (int rep = 0; rep < 3; rep++) {
            float *dir = calloc(t->count, sizeof(float));
            for (int j = 0; j < 16; j++) {
                r = r * 1103515245u + 12345u;
                dir[(r >> 4) % t->count] = ((r >> 16) & 1) ? 1.0f : -1.0f;
            }
            double ana = 0, h = 2e-2, fx[2];
            for (size_t i = 0; i < t->count; i++)
                ana += (double)dir[i] * grad[t->offset + i];
            for (int sgn = 0; sgn < 2; sgn++) {
                for (size_t i = 0; i < t->count; i++)
                    m->params[t->offset + i] =
                        save[i] + (float)((sgn ? -h : h) * dir[i]);
                fx[sgn] = value(&o, &fr);
            }
            memcpy(m->params + t->offset, save, t->count * sizeof(float));
            snprintf(name, sizeof name, "%s #%d", t->name, rep);
            /* colours are linear in the map: tight; an opacity or a
             * latent feature moves the cut-offs too */
            if (strstr(t->name, "colour"))
                COMPARE(name, ana, (fx[0] - fx[1]) / (2 * h), 5e-3, 2e-5);
            else
                COMPARE(name, ana, (fx[0] - fx[1]) / (2 * h), 0.03, 1.5e-3);
            free(dir);
        }
        free(save);
    }
#undef COMPARE
    printf("k %d: %d gradients, %d mismatches, worst error %.2f of the "
           "tolerance\n", k, n, bad, worst);
    free(grad);
    free(o.w_rgb);
    free(o.w_map);
    free(o.w_face);
    gs_model_ctx_destroy(o.c);
    gs_model_destroy(m);
    return bad;
}

/* File, renders, fit, refusals. */
static void model_level(gs_pool *pool)
{
    gs_error err = {0, ""};
    gs_model *m = ss_model(2, 5), *m1 = ss_model(1, 5), *back = NULL;
    CHECK(m && m1);
    if (!m || !m1)
        return;
    char path[] = "/tmp/gs_ss_XXXXXX";
    int fd = mkstemp(path);
    CHECK(fd >= 0);
    close(fd);
    CHECK(gs_model_save(m, path, &err) == GS_OK);
    CHECK(gs_model_load(path, &back, &err) == GS_OK);
    CHECK(back && back->cfg.supersample == 2);
    gs_model_destroy(back);
    back = NULL;
    CHECK(gs_model_save(m1, path, &err) == GS_OK);
    CHECK(gs_model_load(path, &back, &err) == GS_OK);
    CHECK(back && back->cfg.supersample == 1);
    gs_model_destroy(back);
    unlink(path);
    CHECK(gs_model_set_supersample(m1, 0, &err) == GS_ERR_ARG);
    CHECK(gs_model_set_supersample(m1, 5, &err) == GS_ERR_ARG);
    CHECK(gs_model_set_supersample(NULL, 2, &err) == GS_ERR_ARG);
    CHECK(m1->cfg.supersample == 1);

    /* Renders: full, the same bytes with and without a pool, and scale 1
     * is the model's own sampling (= scale 2 here); the point-sampled
     * model with the render option 2 draws the same images. */
    enum { N = 3 };
    int S = m->cfg.image_size;
    size_t stride = 3 * (size_t)S, bytes = stride * S;
    uint8_t *img[4];
    for (int i = 0; i < 4; i++)
        img[i] = malloc(N * bytes);
    gs_subject s = frame_subject(m);
    gs_model_ctx *c = gs_model_ctx_create(m), *c1 = gs_model_ctx_create(m1);
    for (int v = 0; v < N; v++) {
        gs_view view;
        memset(&view, 0, sizeof view);
        view.gaze_pitch = 0.1 * v - 0.1;
        view.gaze_yaw = 0.3 - 0.15 * v;
        CHECK(gs_model_render(c, pool, &s, &view, img[0] + v * bytes, stride,
                              &err) == GS_OK);
        CHECK(gs_model_render(c, NULL, &s, &view, img[1] + v * bytes, stride,
                              &err) == GS_OK);
        gs_model_render_options ro;
        gs_model_render_options_default(&ro);
        ro.feature_scale = 2.0;
        CHECK(gs_model_ctx_set_render_options(c1, &ro, &err) == GS_OK);
        CHECK(gs_model_render(c1, pool, &s, &view, img[2] + v * bytes, stride,
                              &err) == GS_OK);
    }
    CHECK_MSG(memcmp(img[0], img[1], N * bytes) == 0, "pool changes bytes");
    CHECK_MSG(memcmp(img[0], img[2], N * bytes) == 0,
              "supersample 2 != render option 2 of the same weights");
    gs_model_ctx_stats st;
    gs_model_ctx_get_stats(c, &st);
    CHECK(st.renders_incremental == 0 && st.renders_full == 2 * N);

    /* A fit of the model's own render at another code comes close. */
    gs_fit_options fo;
    gs_fit_options_default(&fo);
    fo.max_iters = 30;
    fo.known_head = 1;
    fo.known_gaze = 1;
    fo.gaze_pitch = -0.1, fo.gaze_yaw = 0.3;
    memcpy(fo.head_R, s.head_R, sizeof fo.head_R);
    memcpy(fo.head_t, s.head_t, sizeof fo.head_t);
    gs_subject fit;
    CHECK(gs_model_fit(c, pool, img[0], stride, &fo, &fit, NULL, &err) ==
          GS_OK);
    printf("fit of its own render: PSNR %.2f dB\n", fit.fit_psnr);
    CHECK_MSG(isfinite(fit.fit_psnr) && fit.fit_psnr > 25,
              "fit PSNR %.2f", fit.fit_psnr);

    /* The eye-cover loss needs point-sampled maps. */
    gs_frame fr;
    frame_default(m, &fr);
    CHECK(gs_frame_forward(c, NULL, &fr, GS_STREAM_BOTH, 1, &err) == GS_OK);
    CHECK(gs_frame_eye_cover(c, NULL, &err) == GS_ERR_ARG);
    gs_model_ctx_destroy(c);
    gs_model_ctx_destroy(c1);
    for (int i = 0; i < 4; i++)
        free(img[i]);
    gs_model_destroy(m);
    gs_model_destroy(m1);
}

int main(void)
{
    map_means(2);
    map_means(3);
    int b1 = gradcheck(1), b2 = gradcheck(2);
    CHECK_MSG(b1 == 0 && b2 == 0, "gradient mismatches: k 1 %d, k 2 %d", b1,
              b2);
    gs_pool *pool = gs_pool_create(2);
    model_level(pool);
    gs_pool_destroy(pool);
    GS_TEST_END();
}
