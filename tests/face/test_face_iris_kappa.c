/* Angle kappa seen by the iris localizer: the same synthetic scenes
 * (test identities, 256 px normalized camera, head within 15 deg of the
 * camera, gaze within +-20 deg, open eyes) rendered without kappa and with
 * a fixed kappa of 5 deg horizontal, 1.5 deg vertical. gs_face_iris_locate
 * on the label's eye contours finds each iris moved as the exact pupil
 * labels say (the optical axis): temporally (the right eye toward image
 * left, the left toward image right, every eye) and, on average, down, by
 * about 5.2 deg x 0.21 px/deg, the localizer's calibration (docs/face.md). */
#include <math.h>
#include <stdio.h>
#include <string.h>

#include "gazesplat/face.h"
#include "gazesplat/synth.h"
#include "gs_test.h"

#define S 256
#define DEG (3.14159265358979323846 / 180.0)
#define SCENES 24

static int locate(const gs_synth_scene *sc, gs_synth_sample *smp, int e, double c[2],
                  double label[2])
{
    gs_synth_camera base, cam;
    gs_synth_camera_single(S, 600, 260, &base);
    CHECK(gs_synth_camera_normalized(sc, &base, S, 680, 800, &cam, NULL) == GS_OK);
    CHECK(gs_synth_render(sc, &cam, NULL, NULL, smp, NULL) == GS_OK);
    double eye[6][2];
    for (int i = 0; i < 6; i++)
        for (int k = 0; k < 2; k++)
            eye[i][k] = smp->labels.lm2d[(e == GS_SYNTH_EYE_RIGHT ? 36 : 42) + i][k];
    gs_face_iris_opts o;
    gs_face_iris_opts_default(&o);
    gs_face_iris_opts_scale(&o, 800.0 / 680.0);
    gs_face_iris r;
    gs_io_image img = {S, S, smp->stride, smp->rgb};
    CHECK(gs_face_iris_locate(&img, (const double(*)[2])eye, &o, &r, NULL) == GS_OK);
    c[0] = r.centre[0];
    c[1] = r.centre[1];
    label[0] = smp->labels.pupil_uv[e][0];
    label[1] = smp->labels.pupil_uv[e][1];
    return r.status == GS_FACE_IRIS_OK;
}

int main(void)
{
    gs_synth_sample smp;
    CHECK(gs_synth_sample_alloc(&smp, S, S, NULL) == GS_OK);
    gs_synth_kappa k = {1, 5.0, 0.0, 1.5, 0.0};
    int n = 0, sign_ok = 0, down = 0;
    double sum_diff = 0, worst_diff = 0, sum_meas = 0, sum_label = 0, sum_dx = 0, sum_dy = 0,
           sum_ly = 0;
    unsigned long long state = 0x6b61707061ULL;
    for (int t = 0; t < SCENES; t++) {
        gs_synth_scene sc;
        gs_synth_scene_default(&sc, 600.0);
        gs_synth_identity_from_seed(gs_synth_split_seed(GS_SYNTH_TEST, (uint64_t)t), &sc.identity);
        /* A small LCG keeps the test self-contained. */
        double u[4];
        for (int i = 0; i < 4; i++) {
            state = state * 6364136223846793005ULL + 1442695040888963407ULL;
            u[i] = (double)(state >> 11) / 9007199254740992.0 * 2.0 - 1.0;
        }
        gs_geom_rot_from_pitchyaw(10 * u[0] * DEG, 15 * u[1] * DEG, 0.0, sc.head_R);
        sc.gaze_pitch = 15 * u[2] * DEG;
        sc.gaze_yaw = 20 * u[3] * DEG;
        for (int e = 0; e < 2; e++) {
            double c0[2], c1[2], l0[2], l1[2];
            sc.kappa = 0;
            int ok0 = locate(&sc, &smp, e, c0, l0);
            gs_synth_scene_set_kappa(&k, &sc);
            int ok1 = locate(&sc, &smp, e, c1, l1);
            sc.kappa = 0;
            if (!ok0 || !ok1)
                continue;
            double dm[2] = {c1[0] - c0[0], c1[1] - c0[1]};
            double dl[2] = {l1[0] - l0[0], l1[1] - l0[1]};
            double diff = hypot(dm[0] - dl[0], dm[1] - dl[1]);
            sum_dx += fabs(dm[0] - dl[0]);
            sum_dy += dm[1];
            sum_ly += dl[1];
            sum_diff += diff;
            worst_diff = fmax(worst_diff, diff);
            sum_meas += hypot(dm[0], dm[1]);
            sum_label += hypot(dl[0], dl[1]);
            sign_ok += e == GS_SYNTH_EYE_RIGHT ? dm[0] < 0 : dm[0] > 0;
            down += dm[1] > 0;
            n++;
        }
    }
    printf("iris shift by kappa 5/1.5 deg, %d eyes located of %d: measured %.3f px, labels "
           "%.3f px (%.3f px/deg); measured - label: mean %.3f px, worst %.3f px; temporal %d, "
           "down %d; horizontal |measured - label| mean %.3f px; vertical mean measured %.3f "
           "px, labels %.3f px\n", n, 2 * SCENES, sum_meas / n, sum_label / n,
           sum_meas / n / (acos(cos(5 * DEG) * cos(1.5 * DEG)) / DEG), sum_diff / n,
           worst_diff, sign_ok, down, sum_dx / n, sum_dy / n, sum_ly / n);
    CHECK_MSG(n >= SCENES, "only %d eyes located", n);
    CHECK_MSG(sign_ok == n, "%d of %d iris shifts temporal", sign_ok, n);
    /* The 1.5 deg vertical part (0.3 px) is within the localizer's noise
     * eye by eye (the lids cut the limbus above and below); on average it
     * shows. */
    CHECK_MSG(sum_dy / n > 0.5 * sum_ly / n, "mean vertical shift %.3f px, labels %.3f px",
              sum_dy / n, sum_ly / n);
    CHECK_MSG(sum_dx / n <= 0.3, "horizontal shift %.3f px from the labels' on average",
              sum_dx / n);
    CHECK_MSG(sum_diff / n <= 0.5, "measured shift %.3f px from the labels' on average",
              sum_diff / n);
    CHECK_CLOSE(sum_label / n / (acos(cos(5 * DEG) * cos(1.5 * DEG)) / DEG), 0.21, 0.03, 0);
    gs_synth_sample_free(&smp);
    GS_TEST_END();
}
