/* Lab: how the redirect quality's gaze reading (face.h, the input's eye
 * contours for both images) reads exact gaze changes of synthetic heads,
 * whose lids follow the gaze (lib/synth/head.c: the upper margin 0.85 of
 * the pitch, the lower 0.3), against the same localizer inside each
 * image's own contours. The "output" is the exact render at the new gaze:
 * what a perfect redirect with lids that follow the gaze gives.
 *
 * Built and run as experiments/photos/README.md shows ("Lids that follow
 * the gaze"): lid_measure [HEADS]. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "gazesplat/face.h"
#include "gazesplat/synth.h"

#define DEG (3.14159265358979323846 / 180.0)
#define S 256

static int render(gs_synth_scene *sc, gs_synth_sample *smp)
{
    gs_synth_camera base, cam;
    gs_error err = {0, ""};
    gs_synth_camera_single(S, 650, 300, &base);
    int rc = gs_synth_camera_normalized(sc, &base, S, 0, 0, &cam, &err);
    if (!rc)
        rc = gs_synth_render(sc, &cam, NULL, NULL, smp, &err);
    if (rc)
        fprintf(stderr, "render: %s\n", err.msg);
    return rc;
}

typedef struct {
    double sxx[2], sxy[2], n[2]; /* per axis: slope through 0 of read on asked */
    double e2[2];
} acc;

static void add(acc *a, int ax, double asked, double read)
{
    a->sxx[ax] += asked * asked;
    a->sxy[ax] += asked * read;
    a->e2[ax] += (read - asked) * (read - asked);
    a->n[ax] += 1;
}

int main(int argc, char **argv)
{
    int heads = argc > 1 ? atoi(argv[1]) : 40;
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
    if (gs_synth_sample_alloc(&a, S, S, &err) || gs_synth_sample_alloc(&b, S, S, &err))
        return 1;
    gs_face_iris_opts io;
    gs_face_iris_opts_default(&io);
    gs_face_iris_opts_scale(&io, 800.0 / 680.0);
    static const double change[6][2] = {{20, 0}, {-20, 0}, {10, 0}, {-10, 0}, {0, 20}, {0, -20}};
    acc in_c = {{0}}, own_c = {{0}}, pred_c = {{0}}, delta_c = {{0}};
    gs_face_shape_model *sp = NULL;
    if (gs_face_shape_model_load(NULL, &sp, &err)) {
        fprintf(stderr, "%s\n", err.msg);
        return 1;
    }
    gs_face_box box = {(int)(0.16 * S), (int)(0.19 * S), (int)(0.84 * S), (int)(0.86 * S)};
    int used = 0, total = 0;
    for (int k = 0; k < heads; k++) {
        gs_synth_scene sc;
        gs_synth_scene_random(gs_synth_split_seed(GS_SYNTH_TEST, (uint64_t)k), (uint64_t)k, &rg, &sc);
        if (render(&sc, &a))
            return 1;
        gs_io_image in = {S, S, a.stride, a.rgb}, out = {S, S, b.stride, b.rgb};
        double ua[68][2], pa[68][2];
        memcpy(ua, a.labels.lm2d, sizeof ua);
        if (gs_face_shape_predict(sp, &in, box, NULL, &pa[0][0], &err))
            return 1;
        for (int c = 0; c < 6; c++) {
            gs_synth_scene sc2 = sc;
            sc2.gaze_pitch += change[c][0] * DEG;
            sc2.gaze_yaw += change[c][1] * DEG;
            if (render(&sc2, &b))
                return 1;
            double ub[68][2], pb[68][2], db[68][2];
            memcpy(ub, b.labels.lm2d, sizeof ub);
            if (gs_face_shape_predict(sp, &out, box, NULL, &pb[0][0], &err))
                return 1;
            for (int i = 0; i < 68; i++)
                for (int j = 0; j < 2; j++)
                    db[i][j] = ua[i][j] + pb[i][j] - pa[i][j];
            double dp = sc2.gaze_pitch - sc.gaze_pitch, dy = sc2.gaze_yaw - sc.gaze_yaw;
            for (int e = 0; e < 2; e++) {
                const double(*ea)[2] = (const double(*)[2])ua[36 + 6 * e];
                const double(*eb)[2] = (const double(*)[2])ub[36 + 6 * e];
                const double(*ep)[2] = (const double(*)[2])pb[36 + 6 * e];
                const double(*ed)[2] = (const double(*)[2])db[36 + 6 * e];
                gs_face_iris ia, ib_in, ib_own, ib_p, ib_d;
                total++;
                if (gs_face_iris_locate(&in, ea, &io, &ia, &err) ||
                    gs_face_iris_locate(&out, ea, &io, &ib_in, &err) ||
                    gs_face_iris_locate(&out, eb, &io, &ib_own, &err) ||
                    gs_face_iris_locate(&out, ep, &io, &ib_p, &err) ||
                    gs_face_iris_locate(&out, ed, &io, &ib_d, &err))
                    return 1;
                if (ia.status != GS_FACE_IRIS_OK || ib_in.status != GS_FACE_IRIS_OK ||
                    ib_own.status != GS_FACE_IRIS_OK || ib_p.status != GS_FACE_IRIS_OK ||
                    ib_d.status != GS_FACE_IRIS_OK)
                    continue;
                double p1, y1, p2, y2, p3, y3, p4, y4;
                if (gs_face_iris_gaze_change(e, ea, ia.centre, ea, ib_p.centre, a.labels.head_R, &p3,
                                             &y3, &err) ||
                    gs_face_iris_gaze_change(e, ea, ia.centre, ea, ib_d.centre, a.labels.head_R, &p4,
                                             &y4, &err))
                    return 1;
                if (gs_face_iris_gaze_change(e, ea, ia.centre, ea, ib_in.centre, a.labels.head_R, &p1,
                                             &y1, &err) ||
                    gs_face_iris_gaze_change(e, ea, ia.centre, eb, ib_own.centre, a.labels.head_R, &p2,
                                             &y2, &err))
                    return 1;
                used++;
                int ax = change[c][0] != 0 ? 0 : 1;
                double asked = ax ? dy : dp;
                add(&in_c, ax, asked / DEG, (ax ? y1 : p1) / DEG);
                add(&own_c, ax, asked / DEG, (ax ? y2 : p2) / DEG);
                add(&pred_c, ax, asked / DEG, (ax ? y3 : p3) / DEG);
                add(&delta_c, ax, asked / DEG, (ax ? y4 : p4) / DEG);
            }
        }
    }
    printf("%d heads, %d of %d eye pairs located in all three\n", heads, used, total);
    const acc *r[4] = {&in_c, &own_c, &pred_c, &delta_c};
    const char *nm[4] = {"input's contour for both (the quality measure)",
                         "each image's own (exact) contour",
                         "output: predicted contour, input's frame",
                         "output: input's + predicted change, input's frame"};
    for (int j = 0; j < 4; j++)
        printf("%-52s pitch gain %.3f (rms %.2f deg, %g eyes)  yaw gain %.3f (rms %.2f deg, %g eyes)\n",
               nm[j], r[j]->sxy[0] / r[j]->sxx[0], sqrt(r[j]->e2[0] / r[j]->n[0]), r[j]->n[0],
               r[j]->sxy[1] / r[j]->sxx[1], sqrt(r[j]->e2[1] / r[j]->n[1]), r[j]->n[1]);
    return 0;
}
