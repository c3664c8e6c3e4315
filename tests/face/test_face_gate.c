/* The face gate (face.h) where the truth is known.
 *
 * Normalized faces: black, white, grey and noise frames are refused (flat,
 * noise); synthetic normalized faces of the test split (random identities,
 * poses, expressions and lights) all pass, and their measures are printed
 * against the thresholds.
 *
 * Photos: synthetic heads rendered by one camera, analysed from the
 * renderer's exact landmarks (gs_face_analyze_landmarks), so that each case
 * tests the gate and not the landmark model: an open frontal face passes;
 * closed eyes, a face so far away that its eyes are 8 px wide, a head
 * turned beyond the trained range and a face whose forehead is cut by the
 * border each get their own refusal; bad arguments are errors. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "gazesplat/face.h"
#include "gazesplat/geom.h"
#include "gazesplat/synth.h"
#include "gs_test.h"

#define DEG 57.29577951308232
#define S 256

static gs_face_refusal gate_of(const uint8_t *rgb, gs_face_gate *g)
{
    gs_io_image im = {S, S, 3 * S, (uint8_t *)rgb};
    gs_error err = {0, ""};
    int rc = gs_face_gate_normalized(&im, NULL, g, &err);
    CHECK_MSG(rc == GS_OK, "%s", err.msg);
    return rc == GS_OK ? g->refusal : (gs_face_refusal)-1;
}

static void frames(void)
{
    static uint8_t px[S * S * 3];
    gs_face_gate g;
    const int fill[3] = {0, 255, 128};
    for (int f = 0; f < 3; f++) {
        memset(px, fill[f], sizeof px);
        CHECK_MSG(gate_of(px, &g) == GS_FACE_REFUSED_FLAT, "fill %d: %s", fill[f], g.reason);
        CHECK(strstr(g.reason, "no contrast") != NULL);
    }
    /* A dark frame with sensor noise of 2 grey levels is flat too. */
    uint64_t x = 88172645463325252ull;
    for (size_t i = 0; i < sizeof px; i++) {
        x ^= x << 13, x ^= x >> 7, x ^= x << 17;
        px[i] = (uint8_t)(10 + (x >> 40) % 5);
    }
    CHECK_MSG(gate_of(px, &g) == GS_FACE_REFUSED_FLAT, "dark noisy frame: %s (contrast %.2f)",
              g.reason, g.contrast);
    for (size_t i = 0; i < sizeof px; i++) {
        x ^= x << 13, x ^= x >> 7, x ^= x << 17;
        px[i] = (uint8_t)(x >> 56);
    }
    CHECK_MSG(gate_of(px, &g) == GS_FACE_REFUSED_NOISE, "uniform noise: %s", g.reason);
    printf("uniform noise: roughness %.3f (about 1.13 expected)\n", g.roughness);
    CHECK(fabs(g.roughness - 1.13) < 0.05);
    CHECK(strcmp(gs_face_refusal_name(g.refusal), "noise") == 0);
}

static void synthetic_faces(void)
{
    gs_synth_ranges rg;
    gs_synth_ranges_default(&rg);
    gs_synth_sample smp = {0};
    gs_error err = {0, ""};
    CHECK(gs_synth_sample_alloc(&smp, S, S, &err) == GS_OK);
    double cmin = 1e9, rmax = 0;
    int pass = 0, n = 12;
    for (int k = 0; k < n; k++) {
        gs_synth_scene sc;
        gs_synth_scene_random(gs_synth_split_seed(GS_SYNTH_TEST, (uint64_t)k), (uint64_t)k, &rg,
                              &sc);
        gs_synth_camera base, cam;
        gs_synth_camera_single(S, 650, 300, &base);
        CHECK(gs_synth_camera_normalized(&sc, &base, S, 0, 0, &cam, &err) == GS_OK);
        CHECK_MSG(gs_synth_render(&sc, &cam, NULL, NULL, &smp, &err) == GS_OK, "%s", err.msg);
        gs_face_gate g;
        if (gate_of(smp.rgb, &g) == GS_FACE_USABLE)
            pass++;
        else
            fprintf(stderr, "synthetic face %d refused: %s\n", k, g.reason);
        cmin = fmin(cmin, g.contrast);
        rmax = fmax(rmax, g.roughness);
    }
    printf("synthetic normalized faces: %d of %d pass; contrast >= %.1f (threshold 5), "
           "roughness <= %.3f (threshold 0.5)\n", pass, n, cmin, rmax);
    CHECK(pass == n);
    gs_synth_sample_free(&smp);
}

/* One photo case: the mean head at `dist` mm, turned by (pitch, yaw),
 * with `blink`, seen by a 512-px camera whose width spans `field` mm at
 * 600 mm, its principal point moved by (dx, dy) px; the landmarks those of
 * the same head with blink `lm_blink` (< 0: its own), as a landmark model
 * that draws open contours on closed eyes gives; opts may be NULL. */
static gs_face_gate photo_lm(double dist, double field, double pitch, double yaw, float blink,
                             double dx, double dy, float lm_blink, const gs_face_gate_opts *opts)
{
    gs_synth_scene sc;
    gs_synth_scene_default(&sc, dist);
    gs_geom_rot_from_pitchyaw(pitch / DEG, yaw / DEG, 0, sc.head_R);
    sc.expr.blink = blink;
    gs_synth_camera cam;
    gs_synth_camera_single(512, 600, field, &cam);
    cam.K[2] += dx;
    cam.K[5] += dy;
    gs_synth_sample smp = {0};
    gs_error err = {0, ""};
    gs_face_gate g;
    memset(&g, 0, sizeof g);
    g.refusal = (gs_face_refusal)-1;
    CHECK(gs_synth_sample_alloc(&smp, 512, 512, &err) == GS_OK);
    double lm[68][2];
    if (lm_blink >= 0) {
        sc.expr.blink = lm_blink;
        CHECK_MSG(gs_synth_render(&sc, &cam, NULL, NULL, &smp, &err) == GS_OK, "%s", err.msg);
        memcpy(lm, smp.labels.lm2d, sizeof lm);
        sc.expr.blink = blink;
    }
    CHECK_MSG(gs_synth_render(&sc, &cam, NULL, NULL, &smp, &err) == GS_OK, "%s", err.msg);
    if (lm_blink < 0)
        memcpy(lm, smp.labels.lm2d, sizeof lm);
    gs_face_opts o;
    gs_face_opts_default(&o);
    o.pose_model = GS_FACE_POSE_SYNTH;
    o.norm_size = S;
    o.use_k = 1;
    memcpy(o.k, cam.K, sizeof o.k);
    gs_face_result r;
    gs_io_image img = {smp.width, smp.height, smp.stride, smp.rgb}, norm = {0};
    int rc = gs_face_analyze_landmarks((const double(*)[2])lm, 512, 512, &o, &r, &err);
    CHECK_MSG(rc == GS_OK, "analyze: %s", err.msg);
    if (rc == GS_OK && gs_face_normalize_image(&img, &r.norm, &norm, &err) == GS_OK) {
        CHECK_MSG(gs_face_gate_photo(&r, &norm, opts, &g, &err) == GS_OK, "%s", err.msg);
        /* the irises located by the caller give the same verdict */
        gs_face_iris_opts io;
        gs_face_iris_opts_default(&io);
        gs_face_iris_opts_scale(&io, r.norm.f_n / r.norm.d_n_mm);
        gs_face_iris ir[2];
        int located = 1;
        for (int e = 0; e < 2; e++) {
            double eye[6][2];
            memcpy(eye, r.uv_n[36 + 6 * e], sizeof eye);
            located &= gs_face_iris_locate(&norm, (const double(*)[2])eye, &io, &ir[e], NULL) ==
                       GS_OK;
        }
        if (located) {
            gs_face_gate gi;
            CHECK_MSG(gs_face_gate_photo_irises(&r, &norm, ir, opts, &gi, &err) == GS_OK, "%s",
                      err.msg);
            CHECK_MSG(gi.refusal == g.refusal && gi.irises == g.irises &&
                          !memcmp(&gi.iris_contrast, &g.iris_contrast, sizeof g.iris_contrast),
                      "given irises: %s, %d irises, contrast %g; located by the gate: %s, %d, %g",
                      gs_face_refusal_name(gi.refusal), gi.irises, gi.iris_contrast,
                      gs_face_refusal_name(g.refusal), g.irises, g.iris_contrast);
            /* and the gate reads them: a usable face whose irises are said
             * to be unseen, at contrast 5, is refused for closed eyes */
            if (g.refusal == GS_FACE_USABLE && !opts) {
                for (int e = 0; e < 2; e++)
                    ir[e].status = GS_FACE_IRIS_NO_EDGE, ir[e].contrast = 5.0;
                CHECK(gs_face_gate_photo_irises(&r, &norm, ir, NULL, &gi, &err) == GS_OK);
                CHECK_MSG(gi.refusal == GS_FACE_REFUSED_EYES_CLOSED && gi.iris_contrast == 5.0,
                          "given unseen irises: %s, contrast %g", gs_face_refusal_name(gi.refusal),
                          gi.iris_contrast);
            }
        }
        printf("  dist %4.0f field %4.0f pitch %+3.0f yaw %+3.0f blink %.1f shift %+4.0f,%+4.0f: "
               "%-11s eyes %.1f/%.1f px open %.2f/%.2f irises %d (contrast %.1f) head %+.1f,%+.1f "
               "outside %.3f contrast %.1f rough %.3f %s\n",
               dist, field, pitch, yaw, blink, dx, dy, gs_face_refusal_name(g.refusal),
               g.eye_px[0], g.eye_px[1], g.eye_open[0], g.eye_open[1], g.irises, g.iris_contrast,
               g.head_pitch_deg, g.head_yaw_deg, g.outside, g.contrast, g.roughness, g.reason);
    }
    gs_io_image_free(&norm);
    gs_synth_sample_free(&smp);
    return g;
}

static gs_face_gate photo(double dist, double field, double pitch, double yaw, float blink,
                          double dx, double dy)
{
    return photo_lm(dist, field, pitch, yaw, blink, dx, dy, -1.0f, NULL);
}

static void photos(void)
{
    printf("photos (exact landmarks):\n");
    gs_face_gate g = photo(600, 300, 0, 0, 0, 0, 0);
    CHECK_MSG(g.refusal == GS_FACE_USABLE, "frontal open face: %s", g.reason);
    CHECK(g.eye_px[0] > 30 && g.eye_open[0] > 0.2 && fabs(g.head_yaw_deg) < 3);
    CHECK_MSG(g.irises == 2 && g.iris_contrast > 40, "frontal open face: %d irises, contrast %.1f",
              g.irises, g.iris_contrast);
    /* Closed eyes inside open contours: no iris, and what the fits find is
     * no sclera against an iris. */
    g = photo_lm(600, 300, 0, 0, 1.0f, 0, 0, 0.0f, NULL);
    CHECK_MSG(g.refusal == GS_FACE_REFUSED_EYES_CLOSED && g.irises == 0 &&
                  strstr(g.reason, "no iris"),
              "closed eyes in open contours: %s (%s)", gs_face_refusal_name(g.refusal), g.reason);
    gs_face_gate_opts off;
    gs_face_gate_opts_default(&off);
    CHECK(off.min_iris_contrast == 15);
    off.min_iris_contrast = 0;
    g = photo_lm(600, 300, 0, 0, 1.0f, 0, 0, 0.0f, &off);
    CHECK_MSG(g.refusal == GS_FACE_USABLE, "the iris check off: %s", gs_face_refusal_name(g.refusal));
    g = photo(600, 300, 15, -25, 0, 0, 0);
    CHECK_MSG(g.refusal == GS_FACE_USABLE, "turned face within range: %s", g.reason);
    g = photo(600, 300, 0, 0, 1.0f, 0, 0);
    CHECK_MSG(g.refusal == GS_FACE_REFUSED_EYES_CLOSED, "closed eyes: %s",
              gs_face_refusal_name(g.refusal));
    g = photo(600, 2000, 0, 0, 0, 0, 0);
    CHECK_MSG(g.refusal == GS_FACE_REFUSED_SMALL_EYES, "8 px eyes: %s",
              gs_face_refusal_name(g.refusal));
    CHECK(g.eye_px[0] < 12);
    g = photo(600, 300, 0, 70, 0, 0, 0);
    CHECK_MSG(g.refusal == GS_FACE_REFUSED_HEAD_POSE, "yaw 70: %s",
              gs_face_refusal_name(g.refusal));
    g = photo(600, 300, 50, 0, 0, 0, 0);
    CHECK_MSG(g.refusal == GS_FACE_REFUSED_HEAD_POSE, "pitch 50: %s",
              gs_face_refusal_name(g.refusal));
    /* The brows a few px under the top edge: the forehead is outside. */
    g = photo(600, 300, 0, 0, 0, 0, -183);
    CHECK_MSG(g.refusal == GS_FACE_REFUSED_AT_BORDER, "forehead cut: %s (outside %.3f)",
              gs_face_refusal_name(g.refusal), g.outside);
}

static void bad_arguments(void)
{
    gs_face_gate g;
    gs_error err = {0, ""};
    uint8_t px[16 * 16 * 3] = {0};
    gs_io_image tiny = {4, 4, 12, px};
    CHECK(gs_face_gate_normalized(&tiny, NULL, &g, &err) == GS_ERR_ARG);
    CHECK(gs_face_gate_normalized(NULL, NULL, &g, &err) == GS_ERR_ARG);
    gs_io_image im = {16, 16, 48, px};
    CHECK(gs_face_gate_normalized(&im, NULL, NULL, &err) == GS_ERR_ARG);
    gs_face_gate_opts o;
    gs_face_gate_opts_default(&o);
    o.min_contrast = NAN;
    CHECK(gs_face_gate_normalized(&im, &o, &g, &err) == GS_ERR_ARG);
    CHECK(gs_face_gate_photo(NULL, &im, NULL, &g, &err) == GS_ERR_ARG);
    CHECK(gs_face_refusal_name((gs_face_refusal)GS_FACE_REFUSAL_COUNT) == NULL);
    double uv[68][2] = {{0}};
    uv[3][0] = NAN;
    gs_face_result r;
    CHECK(gs_face_analyze_landmarks((const double(*)[2])uv, 100, 100, NULL, &r, &err) ==
          GS_ERR_NONFINITE);
    uv[3][0] = 500;
    CHECK(gs_face_analyze_landmarks((const double(*)[2])uv, 100, 100, NULL, &r, &err) ==
          GS_ERR_ARG);
}

int main(void)
{
    frames();
    synthetic_faces();
    photos();
    bad_arguments();
    GS_TEST_END();
}
