/* Redirect quality (face.h) where the truth is known: synthetic normalized
 * faces of the test split rendered at a start gaze (the "input") and at a
 * changed gaze (the "output": the exact image a perfect redirect would
 * give), with the renderer's exact landmarks.
 *
 * - exact outputs: the gaze change the irises show against the change
 *   made (its error is the measure's own), iris delta E and speckle near
 *   their neutral values, scores high;
 * - broken outputs made from the exact ones: speckle painted over the eye
 *   regions raises the speckle measure and the score falls; the irises
 *   painted over with sclera white leave no iris and score 0; an unchanged
 *   output (the input again) for a 20 deg change shows the gaze error;
 * - the landmarks of a normalized face predicted from the canonical box
 *   (as the daemon does) against the exact ones. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "gazesplat/face.h"
#include "gazesplat/geom.h"
#include "gazesplat/synth.h"
#include "gs_test.h"

#define DEG (3.14159265358979323846 / 180.0)
#define S 256
#define HEADS 8

static int render(gs_synth_scene *sc, gs_synth_sample *smp)
{
    gs_synth_camera base, cam;
    gs_error err = {0, ""};
    gs_synth_camera_single(S, 650, 300, &base);
    int rc = gs_synth_camera_normalized(sc, &base, S, 0, 0, &cam, &err);
    if (!rc)
        rc = gs_synth_render(sc, &cam, NULL, NULL, smp, &err);
    CHECK_MSG(rc == GS_OK, "%s", err.msg);
    return rc;
}

static int cmp(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

static double median(double *v, int n)
{
    if (n <= 0)
        return NAN;
    qsort(v, (size_t)n, sizeof *v, cmp);
    return n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
}

static uint64_t rng = 0x9e3779b97f4a7c15ull;
static unsigned rnd(void)
{
    rng ^= rng << 13, rng ^= rng >> 7, rng ^= rng << 17;
    return (unsigned)(rng >> 33);
}

int main(void)
{
    gs_synth_ranges rg;
    gs_synth_ranges_default(&rg);
    rg.head_yaw = 25 * DEG;
    rg.head_pitch = 15 * DEG;
    rg.gaze_yaw = 15 * DEG;
    rg.gaze_pitch = 10 * DEG;
    rg.blink_prob = 0;
    rg.expression_prob = 0;
    gs_synth_sample a = {0}, b = {0};
    gs_error err = {0, ""};
    CHECK(gs_synth_sample_alloc(&a, S, S, &err) == GS_OK);
    CHECK(gs_synth_sample_alloc(&b, S, S, &err) == GS_OK);
    gs_face_quality_opts qo;
    gs_face_quality_opts_default(&qo);
    qo.px_per_mm = 800.0 / 680.0;
    static const double change[4][2] = {{0, 20}, {0, -20}, {15, 0}, {-15, 10}};
    double errs[HEADS * 4], des[HEADS * 4], scores[HEADS * 4], still[HEADS * 4], still_err[HEADS * 4];
    double art_max = 0, lm_err = 0;
    int n = 0, ns = 0, nse = 0, lm_n = 0, painted_bad = 0;
    double speck_min = 1e9, speck_score_max = 0, pxx = 0, pxy[2] = {0, 0};
    int np = 0;
    gs_face_shape_model *sp = NULL;
    int have_sp = gs_face_shape_model_load(NULL, &sp, NULL) == GS_OK;
    for (int k = 0; k < HEADS; k++) {
        gs_synth_scene sc;
        gs_synth_scene_random(gs_synth_split_seed(GS_SYNTH_TEST, (uint64_t)k), (uint64_t)k, &rg, &sc);
        if (render(&sc, &a))
            break;
        gs_io_image in = {S, S, a.stride, a.rgb}, out = {S, S, b.stride, b.rgb};
        double uv[68][2];
        memcpy(uv, a.labels.lm2d, sizeof uv);
        /* The camera is the normalized one: the labels' head rotation is
         * the head in the normalized camera. */
        double hR[9];
        memcpy(hR, a.labels.head_R, sizeof hR);
        if (have_sp) {
            double pu[68][2];
            if (gs_face_normalized_landmarks(sp, &in, pu, NULL) == GS_OK)
                for (int i = 36; i < 48; i++, lm_n++)
                    lm_err += hypot(pu[i][0] - uv[i][0], pu[i][1] - uv[i][1]);
        }
        for (int c = 0; c < 4; c++) {
            gs_synth_scene sc2 = sc;
            sc2.gaze_pitch += change[c][0] * DEG;
            sc2.gaze_yaw += change[c][1] * DEG;
            if (render(&sc2, &b))
                break;
            /* The change made, in the head frame. */
            double dp = sc2.gaze_pitch - sc.gaze_pitch, dy = sc2.gaze_yaw - sc.gaze_yaw;
            gs_face_quality q;
            CHECK_MSG(gs_face_redirect_quality(&in, &out, (const double(*)[2])uv, hR, dp, dy, &qo, &q,
                                               &err) == GS_OK, "%s", err.msg);
            int pairs = k * 4 + c;
            if (q.eyes) {
                errs[n] = q.gaze_error_deg;
                des[n++] = q.delta_e;
            }
            /* The same with the landmark model: the output's contours move
             * with its lids (the synthetic lids follow the gaze). The pitch
             * read both ways on the pairs both measure. */
            if (have_sp && dp != 0) {
                gs_face_quality qs;
                gs_face_quality_opts qos = qo;
                qos.shape = sp;
                CHECK_MSG(gs_face_redirect_quality(&in, &out, (const double(*)[2])uv, hR, dp, dy, &qos,
                                                   &qs, &err) == GS_OK, "%s", err.msg);
                if (q.eyes && qs.eyes) {
                    pxx += dp * dp;
                    pxy[0] += dp * q.measured[0];
                    pxy[1] += dp * qs.measured[0];
                    np++;
                }
            }
            scores[pairs] = q.score;
            art_max = fmax(art_max, q.artifact);
            /* Speckle over the eye regions (of a copy of the exact render). */
            uint8_t *m = malloc((size_t)S * S);
            uint8_t *exact = malloc((size_t)S * S * 3);
            gs_face_mask((const double(*)[2])uv, GS_FACE_MASK_EYES, 0, 0, S, S, m, NULL);
            memcpy(exact, b.rgb, (size_t)S * S * 3);
            for (int i = 0; i < S * S; i++)
                if (m[i] >= 128 && rnd() % 3 == 0)
                    for (int ch = 0; ch < 3; ch++)
                        b.rgb[3 * i + ch] = (uint8_t)(rnd() % 2 ? 20 + rnd() % 40 : 200 + rnd() % 50);
            CHECK(gs_face_redirect_quality(&in, &out, (const double(*)[2])uv, hR, dp, dy, &qo, &q, &err) ==
                  GS_OK);
            speck_min = fmin(speck_min, q.artifact);
            speck_score_max = fmax(speck_score_max, q.score);
            /* The irises painted over with the sclera's white. */
            memcpy(b.rgb, exact, (size_t)S * S * 3);
            free(exact);
            for (int i = 0; i < S * S; i++)
                if (m[i] >= 128)
                    b.rgb[3 * i] = 235, b.rgb[3 * i + 1] = 228, b.rgb[3 * i + 2] = 222;
            CHECK(gs_face_redirect_quality(&in, &out, (const double(*)[2])uv, hR, dp, dy, &qo, &q, &err) ==
                  GS_OK);
            /* No iris in the output: 0 where the input showed one, else
             * the half marks of "nothing to compare". */
            int in_found = q.iris[0][0].status == GS_FACE_IRIS_OK || q.iris[1][0].status == GS_FACE_IRIS_OK;
            painted_bad += q.eyes != 0 || q.score > (in_found ? 0 : 0.5);
            /* Unchanged: the input again. */
            CHECK(gs_face_redirect_quality(&in, &in, (const double(*)[2])uv, hR, dp, dy, &qo, &q, &err) ==
                  GS_OK);
            still[ns++] = q.score;
            if (q.eyes)
                still_err[nse++] = q.gaze_error_deg;
            free(m);
        }
    }
    double e_med = median(errs, n), de_med = median(des, n), s_med = median(scores, HEADS * 4);
    double st_med = median(still, ns), ste_med = median(still_err, nse);
    printf("exact outputs: %d of %d with irises in both; gaze error median %.2f deg (max %.1f); "
           "iris dE median %.1f; speckle max %.2f; score median %.2f\n",
           n, HEADS * 4, e_med, n ? errs[n - 1] : NAN, de_med, art_max, s_med);
    printf("speckled outputs: speckle >= %.2f, score <= %.2f; irises painted out: %d wrong; "
           "unchanged outputs for 15-20 deg: gaze error median %.1f deg, score median %.2f\n",
           speck_min, speck_score_max, painted_bad, ste_med, st_med);
    if (lm_n)
        printf("eye landmarks from the canonical box: %.2f px from the exact ones on average\n",
               lm_err / lm_n);
    if (np) {
        printf("pitch gain on %d exact pairs (lids that follow the gaze): %.2f inside the input's "
               "contours, %.2f inside them moved by the landmark model's change\n",
               np, pxy[0] / pxx, pxy[1] / pxx);
        CHECK(np >= 6);
        CHECK(fabs(pxy[1] / pxx - 1.0) < 0.15 && pxy[1] / pxx > pxy[0] / pxx + 0.1);
    }
    CHECK(n >= HEADS * 4 / 4);
    CHECK(e_med < 8 && de_med < 12 && art_max < 1.6 && s_med > 0.6);
    CHECK(speck_min > 2 && speck_score_max < 0.2);
    CHECK(painted_bad == 0);
    CHECK(ste_med > 12 && st_med < 0.3);
    gs_face_shape_model_destroy(sp);
    gs_synth_sample_free(&a);
    gs_synth_sample_free(&b);
    GS_TEST_END();
}
