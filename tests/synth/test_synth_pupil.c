/* Geometry: the projected pupil centre label lies within 0.5 px of the
 * centroid of the dark pupil found in the rendered pixels, for gazes over
 * the whole range (+-50 deg yaw, +-40 deg pitch in the head frame, drawn
 * stratified so every fifth of each range is hit) and head poses over
 * theirs (+-60 deg yaw, +-40 deg pitch, +-10 deg roll). Each eye is
 * rendered by a camera zoomed on it (4 px per mm at 600 mm), 2x2
 * supersampled, with a light low-contrast iris and no specular highlight so
 * that the pupil is the only dark blob, and with the render option
 * open_lids: the lids follow gaze pitch and would otherwise cover part of
 * the pupil when looking down (below about -13 deg), which biases a
 * centroid. Eyes whose pupil is still hidden (by the nose or the other
 * side of the face at large head yaw, or seen too obliquely) are skipped;
 * the test requires enough visible ones in every fifth of both gaze
 * ranges. */
#include "gs_test.h"
#include "synth_internal.h"
#include "synth_test_util.h"

enum { SIZE = 72, TRIALS = 75, BINS = 5 };

/* True when a circle 1.2 mm outside the pupil rim is seen through the
 * cornea with nothing of the head in front: the pupil and the iris ring
 * the estimator uses are in the open, away from lid shadows. */
static int pupil_visible(const head_model *h, const gs_synth_labels *l, int e)
{
    const eye_model *eye = &h->eye[e];
    double o[3];
    gs_geom_mat3_tvec(l->head_R, l->head_t, o);
    v3 cam = v3_make((float)-o[0], (float)-o[1], (float)-o[2]);
    for (int k = 0; k < 24; k++) {
        float a = 6.2831853f * (float)k / 24.0f;
        float r = eye->pupil_r + 1.2f;
        v3 q = v3_add(eye->iris_c, v3_add(v3_scale(eye->iris_u, r * cosf(a)),
                                          v3_scale(eye->iris_v, r * sinf(a))));
        v3 d = v3_sub(q, cam);
        float len = v3_len(d);
        d = v3_scale(d, 1.0f / len);
        if (v3_dot(d, eye->axis) > -0.45f) /* too oblique */
            return 0;
        int on_cornea = 0;
        float te = gs_synth_eye_intersect(eye, cam, d, 1.0f, len, &on_cornea);
        if (te == INFINITY || !on_cornea)
            return 0;
        for (int other = 0; other < 2; other++) {
            int oc;
            if (other != e &&
                gs_synth_eye_intersect(&h->eye[other], cam, d, 1.0f, len, &oc) <
                    len)
                return 0;
        }
        /* March the head field up to the cornea entry. */
        float t = 1.0f;
        while (t < te) {
            float dist = gs_synth_head_sdf(h, v3_add(cam, v3_scale(d, t)));
            if (dist < 0.02f)
                return 0;
            t += 0.9f * dist;
        }
    }
    return 1;
}

/* Uniform in the k-th of BINS equal parts of [-range, range]. */
static double stratified(gs_rng *rng, int k, double range)
{
    return -range + 2.0 * range * (k + gs_rng_uniform(rng, 0, 1)) / BINS;
}

static int bin_of(double v, double range)
{
    int b = (int)floor((v + range) / (2.0 * range) * BINS);
    return b < 0 ? 0 : (b >= BINS ? BINS - 1 : b);
}

int main(void)
{
    gs_rng rng;
    gs_rng_seed(&rng, 77);
    gs_synth_sample s;
    CHECK(gs_synth_sample_alloc(&s, SIZE, SIZE, NULL) == GS_OK);
    gs_synth_render_opts opts = {.supersample = 2, .open_lids = 1};
    int tested = 0, pitch_bins[BINS] = {0}, yaw_bins[BINS] = {0};
    double worst = 0.0, sum = 0.0, rsum = 0.0, yaw_lo = 0, yaw_hi = 0,
           pitch_lo = 0, pitch_hi = 0, hy_max = 0, hp_max = 0;
    for (int trial = 0; trial < TRIALS; trial++) {
        gs_synth_scene sc;
        gs_synth_scene_default(&sc, 600.0);
        gs_synth_identity_from_seed(
            gs_synth_split_seed(GS_SYNTH_TEST, (uint64_t)trial), &sc.identity);
        sc.identity.p[GS_SYNTH_ID_IRIS_HUE] = 1.0f;
        sc.identity.p[GS_SYNTH_ID_IRIS_BRIGHTNESS] = 1.0f;
        sc.identity.p[GS_SYNTH_ID_IRIS_PATTERN] = -1.0f;
        sc.expr.pupil = (float)gs_rng_uniform(&rng, -1, 1);
        sc.specular = 0;
        sc.ambient[0] = sc.ambient[1] = sc.ambient[2] = 0.7f;
        double hp = gs_rng_uniform(&rng, -40, 40), hy = gs_rng_uniform(&rng, -60, 60);
        gs_geom_rot_from_pitchyaw(hp * DEG, hy * DEG,
                                  gs_rng_uniform(&rng, -10, 10) * DEG, sc.head_R);
        sc.gaze_pitch = stratified(&rng, trial % BINS, 40) * DEG;
        sc.gaze_yaw = stratified(&rng, (trial / BINS) % BINS, 50) * DEG;
        head_model h;
        gs_synth_head_build(&sc.identity, &sc.expr, sc.gaze_pitch, sc.gaze_yaw,
                            &h);
        gs_synth_head_open_lids(&h);
        for (int e = 0; e < 2; e++) {
            gs_synth_labels l;
            gs_synth_camera cam;
            camera_aimed(SIZE, 2400.0, (double[3]){0, 0, 600}, &cam);
            CHECK(gs_synth_labels_compute(&sc, &cam, &l, NULL) == GS_OK);
            camera_aimed(SIZE, 2400.0, l.pupil_centre[e], &cam);
            CHECK(gs_synth_labels_compute(&sc, &cam, &l, NULL) == GS_OK);
            if (!pupil_visible(&h, &l, e))
                continue;
            CHECK(gs_synth_render(&sc, &cam, &opts, NULL, &s, NULL) == GS_OK);
            double rp = l.pupil_radius_mm * 2400.0 / l.pupil_centre[e][2];
            double c[2];
            dark_centroid(&s, l.pupil_uv[e][0], l.pupil_uv[e][1], rp, c);
            double err = hypot(c[0] - l.pupil_uv[e][0], c[1] - l.pupil_uv[e][1]);
            char name[64];
            snprintf(name, sizeof name, "pupil_%02d_%d", trial, e);
            dump_ppm(&s, name);
            CHECK_MSG(err <= 0.5,
                      "trial %d eye %d (gaze %.1f %.1f deg, head %.1f %.1f "
                      "deg): pupil label (%.2f, %.2f) vs dark centroid (%.2f, "
                      "%.2f): %.3f px > 0.5", trial, e, sc.gaze_pitch / DEG,
                      sc.gaze_yaw / DEG, hp, hy, l.pupil_uv[e][0],
                      l.pupil_uv[e][1], c[0], c[1], err);
            worst = err > worst ? err : worst;
            sum += err;
            rsum += rp;
            yaw_lo = fmin(yaw_lo, sc.gaze_yaw / DEG);
            yaw_hi = fmax(yaw_hi, sc.gaze_yaw / DEG);
            pitch_lo = fmin(pitch_lo, sc.gaze_pitch / DEG);
            pitch_hi = fmax(pitch_hi, sc.gaze_pitch / DEG);
            hy_max = fmax(hy_max, fabs(hy));
            hp_max = fmax(hp_max, fabs(hp));
            pitch_bins[bin_of(sc.gaze_pitch / DEG, 40)]++;
            yaw_bins[bin_of(sc.gaze_yaw / DEG, 50)]++;
            tested++;
        }
    }
    printf("pupil centroid: %d of %d eyes visible, gaze pitch %.0f..%.0f yaw "
           "%.0f..%.0f deg, head |pitch| <= %.0f |yaw| <= %.0f deg, pupil "
           "radius %.1f px: error mean %.3f px, worst %.3f px\n", tested,
           2 * TRIALS, pitch_lo, pitch_hi, yaw_lo, yaw_hi, hp_max, hy_max,
           tested ? rsum / tested : 0.0, tested ? sum / tested : 0.0, worst);
    printf("  eyes per fifth of gaze pitch (-40..40):");
    for (int b = 0; b < BINS; b++)
        printf(" %d", pitch_bins[b]);
    printf("; of gaze yaw (-50..50):");
    for (int b = 0; b < BINS; b++)
        printf(" %d", yaw_bins[b]);
    printf("\n");
    CHECK_MSG(tested >= TRIALS / 2, "only %d of %d pupils visible", tested,
              2 * TRIALS);
    for (int b = 0; b < BINS; b++)
        CHECK_MSG(pitch_bins[b] >= 5 && yaw_bins[b] >= 5,
                  "fifth %d of the gaze range: %d eyes (pitch), %d (yaw), "
                  "fewer than 5", b, pitch_bins[b], yaw_bins[b]);
    gs_synth_sample_free(&s);
    GS_TEST_END();
}
