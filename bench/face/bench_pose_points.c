/* Which landmarks the head pose should be solved from: PnP (EPnP, then
 * Levenberg-Marquardt, as gs_face_head_pose) against the mean synthetic
 * head's own 3D landmarks, on the exact 2D landmarks of synthetic test
 * heads (random identities and expressions, head yaw +-60, pitch +-40,
 * roll +-10 deg), for several point sets. Prints the rotation error
 * (angle of R_est R_label^T) per set: mean, p90, max.
 * usage: bench_pose_points [HEADS] */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "cv_face_shim.h"
#include "gazesplat/geom.h"
#include "gazesplat/synth.h"

#define DEG 57.29577951308232

static int cmp(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

static double rot_angle(const double a[9], const double b[9])
{
    double bt[9], m[9];
    gs_geom_mat3_transpose(b, bt);
    gs_geom_mat3_mul(a, bt, m);
    double c = (m[0] + m[4] + m[8] - 1) / 2;
    return acos(fmax(-1, fmin(1, c))) * DEG;
}

typedef struct set {
    const char *name;
    int n;
    int idx[68];
} set;

int main(int argc, char **argv)
{
    int heads = argc > 1 ? atoi(argv[1]) : 300;
    static const set sets[] = {
        {"6: eye corners, nose wings (now)", 6, {36, 39, 42, 45, 31, 35}},
        {"10: + nose bridge and tip 27-30", 10, {36, 39, 42, 45, 31, 35, 27, 28, 29, 30}},
        {"13: + nostrils 32-34", 13, {36, 39, 42, 45, 31, 35, 27, 28, 29, 30, 32, 33, 34}},
        {"15: + mouth corners 48, 54", 15, {36, 39, 42, 45, 31, 35, 27, 28, 29, 30, 32, 33, 34, 48, 54}},
        {"16: + chin 8", 16, {36, 39, 42, 45, 31, 35, 27, 28, 29, 30, 32, 33, 34, 48, 54, 8}},
        {"25: + eye contours", 25, {36, 39, 42, 45, 31, 35, 27, 28, 29, 30, 32, 33, 34, 48, 54, 8, 37, 38, 40, 41, 43, 44, 46, 47, 51}},
    };
    int nsets = (int)(sizeof sets / sizeof sets[0]);
    gs_synth_template t;
    gs_error err = {0, ""};
    if (gs_synth_template_build(20.0, NULL, &t, &err) != GS_OK) {
        fprintf(stderr, "%s\n", err.msg);
        return 1;
    }
    double *e = calloc((size_t)heads * nsets, sizeof *e);
    gs_synth_ranges rg;
    gs_synth_ranges_default(&rg);
    for (int k = 0; k < heads; k++) {
        gs_synth_scene sc;
        gs_synth_scene_random(gs_synth_split_seed(GS_SYNTH_TEST, (uint64_t)k), (uint64_t)k, &rg, &sc);
        gs_synth_camera cam;
        gs_synth_camera_single(512, 650, 300, &cam);
        gs_synth_labels l;
        if (gs_synth_labels_compute(&sc, &cam, &l, &err) != GS_OK)
            return 1;
        for (int s = 0; s < nsets; s++) {
            double obj[68][3], img[68][2], rv[3], tv[3], R[9];
            for (int i = 0; i < sets[s].n; i++) {
                memcpy(obj[i], t.landmarks[sets[s].idx[i]], sizeof obj[i]);
                memcpy(img[i], l.lm2d[sets[s].idx[i]], sizeof img[i]);
            }
            if (gs_cvf_solve_pnp((const double(*)[3])obj, (const double(*)[2])img, sets[s].n, l.K,
                                 rv, tv, &err) != GS_OK) {
                e[s * heads + k] = 180;
                continue;
            }
            gs_geom_rodrigues(rv, R);
            e[s * heads + k] = rot_angle(R, l.head_R);
        }
    }
    printf("PnP against the mean synthetic head, exact landmarks, %d test heads:\n", heads);
    for (int s = 0; s < nsets; s++) {
        double *v = e + s * heads, sum = 0;
        for (int k = 0; k < heads; k++)
            sum += v[k];
        qsort(v, (size_t)heads, sizeof *v, cmp);
        printf("  %-36s mean %5.2f  p90 %5.2f  max %5.2f deg\n", sets[s].name, sum / heads,
               v[heads * 9 / 10], v[heads - 1]);
    }
    free(e);
    gs_synth_template_free(&t);
    return 0;
}
