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
#include "frame_gradcheck.h"
#include "model_test_util.h"

static gs_model *ss_model(int k, uint64_t seed)
{
    gs_model_config cfg;
    tiny_config(&cfg);
    cfg.guidance = GS_GUIDE_ADDITIVE;
    cfg.guide_source = GS_GUIDE_SRC_SOURCE;
    cfg.supersample = k;
    return fg_model(&cfg, seed);
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

/* The whole frame's gradients (frame_gradcheck.h) at k; returns the
 * mismatches. */
static int gradcheck(int k)
{
    gs_model *m = ss_model(k, 11);
    CHECK(m != NULL);
    if (!m)
        return 1;
    char tag[16];
    snprintf(tag, sizeof tag, "k %d", k);
    int bad = frame_gradcheck(m, tag, 2e-2);
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
