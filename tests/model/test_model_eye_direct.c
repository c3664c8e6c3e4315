/* The eye stream drawn at the image's size (config.eye_direct = 1): every
 * Gaussian rasterized at S x S with the eye stream's colour and an
 * indicator, the image = the renderer's (1 - beta) + E. Checks: the
 * renderer's image is the plain model's, and the composite equals one made
 * here from an independent raster of the whole image (beta in [0, 1],
 * eyeball where the eyes are, none outside the crop the model rasterized,
 * which is less than half the image); the gradients of a fixed random linear
 * function of the image and the maps against central differences (code,
 * colours, latent features, opacities); the file
 * keeps the flag and a file without the key is 0; a gaze sweep renders
 * incrementally (test_model_incremental compares it with full renders),
 * the same bytes with and without a pool and not the plain model's; detail
 * transfer from its own render gives that render back; a fit of
 * its own render converges; bad values and single-stream models are
 * refused. */
#define _POSIX_C_SOURCE 200809L
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "gazesplat/raster.h"
#include "gs_test.h"
#include "frame_gradcheck.h"
#include "model_test_util.h"

static gs_model *ed_model(int on, uint64_t seed)
{
    gs_model_config cfg;
    tiny_config(&cfg);
    cfg.guidance = GS_GUIDE_ADDITIVE;
    cfg.guide_source = GS_GUIDE_SRC_SOURCE;
    cfg.eye_direct = on;
    return fg_model(&cfg, seed);
}

/* The composite against the plain model's image and an independent
 * raster of the same Gaussians. */
static void composite(void)
{
    gs_model *m = ed_model(1, 3), *p = ed_model(0, 3);
    CHECK(m && p);
    if (!m || !p)
        return;
    CHECK(memcmp(m->params, p->params, m->nparams * sizeof(float)) == 0);
    gs_model_ctx *c = gs_model_ctx_create(m), *cp = gs_model_ctx_create(p);
    gs_error err = {0, ""};
    gs_frame fr;
    frame_default(m, &fr);
    CHECK(gs_frame_forward(c, NULL, &fr, GS_STREAM_BOTH, 1, &err) == GS_OK);
    CHECK(gs_frame_forward(cp, NULL, &fr, GS_STREAM_BOTH, 1, &err) == GS_OK);
    int S = c->S, n = c->n;
    size_t plane = (size_t)S * S;
    CHECK(c->dir_valid && !cp->dir_valid);
    CHECK_MSG(memcmp(c->rgb_main, cp->rgb, 3 * plane * sizeof(float)) == 0,
              "the renderer's image is not the plain model's");
    float *feat = malloc(4 * (size_t)n * sizeof(float));
    float *out = malloc(4 * plane * sizeof(float)), *al = malloc(plane * sizeof(float));
    float *bg = calloc(4 * plane, sizeof(float));
    for (int i = 0; i < n; i++) {
        for (int k = 0; k < 3; k++)
            feat[4 * i + k] = i >= c->nf ? c->g_feat[(size_t)i * c->C + k] : 0.0f;
        feat[4 * i + 3] = i >= c->nf ? 1.0f : 0.0f;
    }
    gs_gaussians g = {.n = n, .channels = 4, .means = c->g_mean,
                      .log_scales = c->g_scale, .quats = c->g_quat,
                      .opacity_logits = c->g_opac, .features = feat};
    gs_camera cam;
    gs_frame_camera(m, fr.head_t, &cam);
    float s = (float)S / (float)c->fs;
    cam.fx *= s, cam.fy *= s, cam.cx *= s, cam.cy *= s;
    cam.width = cam.height = S;
    gs_raster *r = gs_raster_create();
    CHECK(gs_raster_forward(r, NULL, &cam, &g, bg, NULL, out, al, NULL, &err) == GS_OK);
    double worst = 0, bmax = 0, bmin = 1, outside = 0;
    const int *d = c->dir_box;
    for (size_t i = 0; i < plane; i++) {
        double b = out[3 * plane + i];
        int x = (int)(i % (size_t)S), y = (int)(i / (size_t)S);
        if (x < d[0] || x >= d[2] || y < d[1] || y >= d[3])
            outside = fmax(outside, b);
        bmax = fmax(bmax, b);
        bmin = fmin(bmin, b);
        for (int k = 0; k < 3; k++) {
            double want = (double)cp->rgb[k * plane + i] * (1 - b) + out[k * plane + i];
            worst = fmax(worst, fabs(want - c->rgb[k * plane + i]));
        }
    }
    printf("composite off an independent one by %.2e; beta in [%.3f, %.3f]; "
           "crop %d x %d of %d x %d, beta outside it %.1e\n",
           worst, bmin, bmax, d[2] - d[0], d[3] - d[1], S, S, outside);
    CHECK_MSG(outside == 0 && (d[2] - d[0]) * (d[3] - d[1]) < S * S / 2,
              "the crop misses beta %g or is not a crop", outside);
    CHECK_MSG(worst < 1e-6, "composite off by %g", worst);
    CHECK_MSG(bmin >= 0 && bmax <= 1 + 1e-6 && bmax > 0.3, "beta [%g, %g]", bmin, bmax);
    CHECK_MSG(out[3 * plane] == 0.0f, "eyeball in the corner: %g", out[3 * plane]);
    gs_raster_destroy(r);
    free(feat), free(out), free(al), free(bg);
    gs_model_ctx_destroy(c);
    gs_model_ctx_destroy(cp);
    gs_model_destroy(m);
    gs_model_destroy(p);
}

/* The whole frame's gradients (frame_gradcheck.h), plain (on = 0) or with
 * the direct eye; returns the mismatches. The code moves every eye
 * Gaussian (W_e tau and the eye MLP's offsets, scales and opacities), so
 * it checks the geometry's gradient through the image-size raster too.
 * Opacities take a step of 0.1: at 5e-3 and 2e-2 the differences scatter
 * 15 % about the gradient, the image-size raster meeting more cut-offs,
 * at 0.1 they settle within 5 %. */
static int gradcheck(int on)
{
    gs_model *m = ed_model(on, 11);
    CHECK(m != NULL);
    if (!m)
        return 1;
    int bad = frame_gradcheck(m, on ? "direct 1" : "direct 0", 0.1);
    gs_model_destroy(m);
    return bad;
}

/* File, renders, fit, refusals. */
static void model_level(gs_pool *pool)
{
    gs_error err = {0, ""};
    gs_model *m = ed_model(1, 5), *m0 = ed_model(0, 5), *back = NULL;
    CHECK(m && m0);
    if (!m || !m0)
        return;
    char path[] = "/tmp/gs_ed_XXXXXX";
    int fd = mkstemp(path);
    CHECK(fd >= 0);
    close(fd);
    CHECK(gs_model_save(m, path, &err) == GS_OK);
    CHECK(gs_model_load(path, &back, &err) == GS_OK);
    CHECK(back && back->cfg.eye_direct == 1);
    gs_model_info info;
    if (back) {
        gs_model_get_info(back, &info);
        CHECK(info.eye_direct == 1);
    }
    gs_model_destroy(back);
    back = NULL;
    CHECK(gs_model_save(m0, path, &err) == GS_OK);
    CHECK(gs_model_load(path, &back, &err) == GS_OK);
    CHECK(back && back->cfg.eye_direct == 0);
    gs_model_destroy(back);
    unlink(path);
    CHECK(gs_model_set_eye_direct(m0, 2, &err) == GS_ERR_ARG);
    CHECK(gs_model_set_eye_direct(m0, -1, &err) == GS_ERR_ARG);
    CHECK(gs_model_set_eye_direct(NULL, 1, &err) == GS_ERR_ARG);
    CHECK(m0->cfg.eye_direct == 0);
    {
        gs_model_config cfg;
        tiny_config(&cfg);
        cfg.two_stream = 0;
        gs_model *ss = NULL;
        CHECK(gs_model_create(&cfg, 1, &ss, &err) == GS_OK);
        CHECK(ss && gs_model_set_eye_direct(ss, 1, &err) == GS_ERR_ARG &&
              strstr(err.msg, "eye stream"));
        gs_model_destroy(ss);
        cfg.eye_direct = 1;
        ss = NULL;
        CHECK(gs_model_create(&cfg, 1, &ss, &err) != GS_OK && ss == NULL);
    }

    /* Renders: a sweep (the first full, the rest incremental), the same
     * bytes with and without a pool, not the plain model's. */
    enum { N = 3 };
    int S = m->cfg.image_size;
    size_t stride = 3 * (size_t)S, bytes = stride * S;
    uint8_t *img[3];
    for (int i = 0; i < 3; i++)
        img[i] = malloc(N * bytes);
    gs_subject s = frame_subject(m);
    gs_model_ctx *c = gs_model_ctx_create(m), *c0 = gs_model_ctx_create(m0),
                 *c1 = gs_model_ctx_create(m);
    for (int v = 0; v < N; v++) {
        gs_view view;
        memset(&view, 0, sizeof view);
        view.gaze_pitch = 0.1 * v - 0.1;
        view.gaze_yaw = 0.3 - 0.15 * v;
        CHECK(gs_model_render(c, pool, &s, &view, img[0] + v * bytes, stride,
                              &err) == GS_OK);
        CHECK(gs_model_render(c1, NULL, &s, &view, img[1] + v * bytes, stride,
                              &err) == GS_OK);
        CHECK(gs_model_render(c0, pool, &s, &view, img[2] + v * bytes, stride,
                              &err) == GS_OK);
    }
    CHECK_MSG(memcmp(img[0], img[1], N * bytes) == 0, "pool changes bytes");
    CHECK_MSG(memcmp(img[0], img[2], N * bytes) != 0,
              "the direct eye changed no pixel");
    gs_model_ctx_stats st;
    gs_model_ctx_get_stats(c, &st);
    CHECK_MSG(st.renders_incremental == N - 1 && st.renders_full == 1,
              "%llu full, %llu incremental renders",
              (unsigned long long)st.renders_full,
              (unsigned long long)st.renders_incremental);
    /* Detail transfer from its own render: the residual is nothing, so
     * at the input's own view it gives the render back, and it runs at
     * another gaze. */
    {
        gs_subject si = s; /* the subject of img[0]'s first view */
        si.gaze_pitch = -0.1, si.gaze_yaw = 0.3;
        gs_view own;
        memset(&own, 0, sizeof own);
        own.gaze_pitch = si.gaze_pitch, own.gaze_yaw = si.gaze_yaw;
        uint8_t *tr = malloc(bytes);
        CHECK(gs_model_render_transfer(c, pool, &si, img[0], stride, &own, tr,
                                       stride, &err) == GS_OK);
        int most = 0;
        for (size_t i = 0; i < bytes; i++) {
            int dv = abs((int)tr[i] - (int)img[0][i]);
            most = dv > most ? dv : most;
        }
        printf("transfer at the input's own view: largest difference %d levels\n", most);
        CHECK_MSG(most <= 1, "transfer at the own view differs by %d", most);
        own.gaze_yaw = -0.2;
        CHECK(gs_model_render_transfer(c, pool, &si, img[0], stride, &own, tr,
                                       stride, &err) == GS_OK);
        /* its eyeball map is the composite's beta: the target's render
         * left beta over its crop in c */
        const float *tz, *ta, *te;
        gs_xfer_target_maps(c->xfer, &tz, &ta, &te);
        const int *d = c->dir_box;
        int w = d[2] - d[0];
        double off = 0, most_b = 0, outside = 0;
        for (int y = 0; te && y < S; y++)
            for (int x = 0; x < S; x++) {
                float e = te[(size_t)y * S + x];
                if (x >= d[0] && x < d[2] && y >= d[1] && y < d[3]) {
                    float b = c->dir_out[3 * (size_t)w * (d[3] - d[1]) +
                                         (size_t)(y - d[1]) * w + x - d[0]];
                    off = fmax(off, fabs((double)e - b));
                    most_b = fmax(most_b, b);
                } else
                    outside = fmax(outside, e);
            }
        printf("transfer's eyeball map against beta: off by %.2e (beta up to "
               "%.3f), %.2e outside the crop\n", off, most_b, outside);
        CHECK_MSG(te && off < 1e-5 && most_b > 0.1 && outside == 0,
                  "transfer's eyeball map is not beta: %.3g", off);
        free(tr);
    }

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
    CHECK(gs_model_fit(c, pool, img[0], stride, &fo, &fit, NULL, &err) == GS_OK);
    printf("fit of its own render: PSNR %.2f dB\n", fit.fit_psnr);
    CHECK_MSG(isfinite(fit.fit_psnr) && fit.fit_psnr > 25, "fit PSNR %.2f",
              fit.fit_psnr);
    gs_model_ctx_destroy(c);
    gs_model_ctx_destroy(c0);
    gs_model_ctx_destroy(c1);
    for (int i = 0; i < 3; i++)
        free(img[i]);
    gs_model_destroy(m);
    gs_model_destroy(m0);
}

int main(void)
{
    composite();
    int b0 = gradcheck(0), b1 = gradcheck(1);
    CHECK_MSG(b0 == 0 && b1 == 0, "gradient mismatches: plain %d, direct %d",
              b0, b1);
    gs_pool *pool = gs_pool_create(2);
    model_level(pool);
    gs_pool_destroy(pool);
    GS_TEST_END();
}
