/* Calibration of the iris-to-gaze map of gs_face_iris_gaze on synthetic
 * heads, and how well the map reads gaze changes.
 *
 * The model (orthographic, per eye): the iris centre seen from the
 * midpoint of the eye corners, in mm across the line of sight (the image
 * corner distance over the mean head's corner distance projected by the
 * head rotation R), equals P R (b + D g): b the eyeball centre's offset
 * from the corner midpoint (head frame, x mirrored between the eyes), D
 * the eyeball-centre-to-iris distance, g the head-frame gaze, P the first
 * two rows. Linear in (b, Dx, Dy): fitted by least squares on the label
 * iris centres (pupil_uv) and landmarks of validation-split scenes drawn
 * with gs_eval_ranges at the 256 px normalized camera.
 *
 * Then, on test-split scenes, pairs that differ only in gaze (a second
 * gaze drawn from the same ranges): the change read by
 * gs_face_iris_gaze_change (the header's constants) against the true
 * head-frame change, from the label iris centres with the true R, from
 * them with R from PnP of the label's landmarks on the synthetic 6-point
 * model (what a photo gives), with R = NULL (a frontal head assumed), and
 * from the localizer's
 * centres on rendered images (both eyes located, status OK). Reported:
 * gain (slope through 0 of read against true change), rms and p95 of the
 * error, cross-talk (slope of the other axis' error against the change),
 * per axis, over all pairs and by head angle.
 *
 *   iris_calib [--fit N] [--pairs N] [--render N]
 *
 * docs/face.md records its output. */
#define _POSIX_C_SOURCE 200809L
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "gazesplat/eval.h"
#include "gazesplat/face.h"
#include "gazesplat/synth.h"

#define S 256
#define DEG (3.14159265358979323846 / 180.0)

static int labels(uint64_t id, uint64_t scene, const gs_synth_scene *over, gs_synth_scene *sc,
                  gs_synth_camera *cam, gs_synth_labels *l)
{
    gs_synth_ranges rg;
    gs_eval_ranges(&rg);
    if (over)
        *sc = *over;
    else
        gs_synth_scene_random(id, scene, &rg, sc);
    gs_synth_camera base;
    gs_synth_camera_single(S, 600, 260, &base);
    gs_error err;
    if (gs_synth_camera_normalized(sc, &base, S, 680, 800, cam, &err) ||
        gs_synth_labels_compute(sc, cam, l, &err)) {
        fprintf(stderr, "%s\n", err.msg);
        return -1;
    }
    return 0;
}

/* Cholesky solve of the 5 x 5 normal equations. */
static int solve5(double a[25], double b[5])
{
    for (int j = 0; j < 5; j++) {
        double s = a[j * 5 + j];
        for (int k = 0; k < j; k++)
            s -= a[j * 5 + k] * a[j * 5 + k];
        if (!(s > 0))
            return -1;
        a[j * 5 + j] = sqrt(s);
        for (int i = j + 1; i < 5; i++) {
            double t = a[i * 5 + j];
            for (int k = 0; k < j; k++)
                t -= a[i * 5 + k] * a[j * 5 + k];
            a[i * 5 + j] = t / a[j * 5 + j];
        }
    }
    for (int i = 0; i < 5; i++) {
        for (int k = 0; k < i; k++)
            b[i] -= a[i * 5 + k] * b[k];
        b[i] /= a[i * 5 + i];
    }
    for (int i = 4; i >= 0; i--) {
        for (int k = i + 1; k < 5; k++)
            b[i] -= a[k * 5 + i] * b[k];
        b[i] /= a[i * 5 + i];
    }
    return 0;
}

static void fit(int n)
{
    double a[25] = {0}, b[5] = {0}, sse = 0;
    int rows = 0;
    double m6[6][3];
    gs_geom_face_model6_synth(m6);
    for (int pass = 0; pass < 2; pass++) {
        double x[5];
        if (pass) {
            double aa[25];
            memcpy(aa, a, sizeof aa);
            memcpy(x, b, sizeof x);
            if (solve5(aa, x)) {
                fprintf(stderr, "calibration: singular\n");
                exit(1);
            }
        }
        for (int i = 0; i < n; i++) {
            gs_synth_scene sc;
            gs_synth_camera cam;
            gs_synth_labels l;
            if (labels(gs_synth_split_seed(GS_SYNTH_VAL, (uint64_t)i % 200), 3000 + i, NULL, &sc,
                       &cam, &l))
                exit(1);
            for (int e = 0; e < 2; e++) {
                const double(*p)[2] = (const double(*)[2])&l.lm2d[36 + 6 * e];
                double w[3], rw[3], rg[3];
                for (int c = 0; c < 3; c++)
                    w[c] = m6[2 * e + 1][c] - m6[2 * e][c];
                gs_geom_mat3_vec(l.head_R, w, rw);
                gs_geom_mat3_vec(l.head_R, l.gaze_head, rg);
                double k = hypot(p[3][0] - p[0][0], p[3][1] - p[0][1]) / hypot(rw[0], rw[1]);
                double y[2] = {(l.pupil_uv[e][0] - 0.5 * (p[0][0] + p[3][0])) / k,
                               (l.pupil_uv[e][1] - 0.5 * (p[0][1] + p[3][1])) / k};
                double sx = e ? -1 : 1;
                for (int ax = 0; ax < 2; ax++) {
                    const double *R = l.head_R + 3 * ax;
                    double row[5] = {sx * R[0], R[1], R[2], ax == 0 ? rg[0] : 0,
                                     ax == 1 ? rg[1] : 0};
                    if (!pass) {
                        for (int u = 0; u < 5; u++) {
                            b[u] += row[u] * y[ax];
                            for (int v = 0; v < 5; v++)
                                a[u * 5 + v] += row[u] * row[v];
                        }
                    } else {
                        double r = y[ax];
                        for (int u = 0; u < 5; u++)
                            r -= row[u] * x[u];
                        sse += r * r;
                        rows++;
                    }
                }
            }
        }
        if (pass)
            printf("fit on %d validation scenes (%d eyes): b = (%.3f, %.3f, %.3f) mm, "
                   "Dx = %.3f mm, Dy = %.3f mm, rms residual %.3f mm (%.3f px at 256 px)\n",
                   n, 2 * n, x[0], x[1], x[2], x[3], x[4], sqrt(sse / rows),
                   sqrt(sse / rows) * 800 / 680);
    }
}

typedef struct acc {
    double st[2], tt[2], ee[2], e[2][100000], ct[2];
    int n;
} acc;

static void acc_add(acc *a, const double truth[2], const double read[2])
{
    if (a->n >= 100000)
        return;
    for (int ax = 0; ax < 2; ax++) {
        double err = read[ax] - truth[ax];
        a->st[ax] += read[ax] * truth[ax];
        a->tt[ax] += truth[ax] * truth[ax];
        a->ee[ax] += err * err;
        a->e[ax][a->n] = fabs(err);
        /* cross-talk: this axis' error against the other's true change */
        a->ct[ax] += err * truth[1 - ax];
    }
    a->n++;
}

static int cmp(const void *x, const void *y)
{
    double a = *(const double *)x, b = *(const double *)y;
    return (a > b) - (a < b);
}

static void acc_row(const char *name, acc *a)
{
    printf("| %s | %d |", name, a->n);
    for (int ax = 0; ax < 2; ax++) {
        qsort(a->e[ax], (size_t)a->n, sizeof(double), cmp);
        double p95 = a->n ? a->e[ax][(int)ceil(0.95 * a->n) - 1] : NAN;
        printf(" %.3f | %.2f | %.2f | %+.3f |", a->st[ax] / a->tt[ax], sqrt(a->ee[ax] / a->n),
               p95, a->ct[ax] / a->tt[1 - ax]);
    }
    printf("\n");
}

static void header(const char *what)
{
    printf("\n| %s | pairs | pitch gain | pitch rms ° | pitch p95 ° | pitch cross-talk | "
           "yaw gain | yaw rms ° | yaw p95 ° | yaw cross-talk |\n"
           "|---|---|---|---|---|---|---|---|---|---|\n", what);
}

/* The second scene of a pair: the same, a second gaze. */
static void pair_scene(uint64_t k, const gs_synth_scene *in, gs_synth_scene *out)
{
    gs_synth_ranges rg;
    gs_eval_ranges(&rg);
    gs_synth_scene t;
    gs_synth_scene_random(gs_synth_split_seed(GS_SYNTH_TEST, k % 100), 900000 + k, &rg, &t);
    *out = *in;
    out->gaze_pitch = t.gaze_pitch;
    out->gaze_yaw = t.gaze_yaw;
}

static void read_pairs(int n)
{
    static acc all_r, all_f, all_p, head_r[3], head_f0, head_p0;
    for (int i = 0; i < n; i++) {
        gs_synth_scene a, b;
        gs_synth_camera cam;
        gs_synth_labels la, lb;
        uint64_t id = gs_synth_split_seed(GS_SYNTH_TEST, (uint64_t)i % 100);
        if (labels(id, 5000 + i, NULL, &a, &cam, &la))
            exit(1);
        pair_scene((uint64_t)i, &a, &b);
        if (labels(id, 0, &b, &b, &cam, &lb))
            exit(1);
        double truth[2] = {(lb.gaze_head_pitch - la.gaze_head_pitch) / DEG,
                           (lb.gaze_head_yaw - la.gaze_head_yaw) / DEG};
        double hz[3] = {la.head_R[2], la.head_R[5], la.head_R[8]};
        double hdeg = gs_geom_vec3_angle(hz, (double[3]){0, 0, 1}) / DEG;
        /* The head rotation a photo would give: PnP of the label's
         * landmarks on the synthetic 6-point model. */
        gs_face_pose pose;
        gs_error perr;
        if (gs_face_head_pose_model((const double(*)[2])la.lm2d, la.K, GS_FACE_POSE_SYNTH, &pose,
                                    &perr)) {
            fprintf(stderr, "%s\n", perr.msg);
            exit(1);
        }
        for (int e = 0; e < 2; e++) {
            const double(*pa)[2] = (const double(*)[2])&la.lm2d[36 + 6 * e];
            const double(*pb)[2] = (const double(*)[2])&lb.lm2d[36 + 6 * e];
            double d[2], f[2], q[2];
            gs_error err;
            if (gs_face_iris_gaze_change(e, pa, la.pupil_uv[e], pb, lb.pupil_uv[e], pose.R, &q[0],
                                         &q[1], &err)) {
                fprintf(stderr, "%s\n", err.msg);
                exit(1);
            }
            q[0] /= DEG;
            q[1] /= DEG;
            acc_add(&all_p, truth, q);
            if (hdeg < 15)
                acc_add(&head_p0, truth, q);
            if (gs_face_iris_gaze_change(e, pa, la.pupil_uv[e], pb, lb.pupil_uv[e], la.head_R,
                                         &d[0], &d[1], &err) ||
                gs_face_iris_gaze_change(e, pa, la.pupil_uv[e], pb, lb.pupil_uv[e], NULL, &f[0],
                                         &f[1], &err)) {
                fprintf(stderr, "%s\n", err.msg);
                exit(1);
            }
            d[0] /= DEG;
            d[1] /= DEG;
            f[0] /= DEG;
            f[1] /= DEG;
            acc_add(&all_r, truth, d);
            acc_add(&all_f, truth, f);
            acc_add(&head_r[hdeg < 15 ? 0 : hdeg < 30 ? 1 : 2], truth, d);
            if (hdeg < 15)
                acc_add(&head_f0, truth, f);
        }
    }
    header("label iris centres");
    acc_row("head R known, all", &all_r);
    acc_row("head R known, head 0-15°", &head_r[0]);
    acc_row("head R known, head 15-30°", &head_r[1]);
    acc_row("head R known, head 30-50°", &head_r[2]);
    acc_row("R by PnP of the landmarks (synthetic 6-point model), all", &all_p);
    acc_row("R by PnP, head 0-15°", &head_p0);
    acc_row("frontal assumed (R = NULL), all", &all_f);
    acc_row("frontal assumed (R = NULL), head 0-15°", &head_f0);
}

static void read_rendered(int n)
{
    static acc all, near;
    gs_synth_sample sa, sb;
    gs_error err;
    if (gs_synth_sample_alloc(&sa, S, S, &err) || gs_synth_sample_alloc(&sb, S, S, &err)) {
        fprintf(stderr, "%s\n", err.msg);
        exit(1);
    }
    int flagged = 0, eyes = 0;
    for (int i = 0; i < n; i++) {
        gs_synth_scene a, b;
        gs_synth_camera cam;
        gs_synth_labels la;
        uint64_t id = gs_synth_split_seed(GS_SYNTH_TEST, (uint64_t)i % 100);
        if (labels(id, 5000 + i, NULL, &a, &cam, &la))
            exit(1);
        if (gs_eval_expr_narrowed(&a.expr))
            continue;
        pair_scene((uint64_t)i, &a, &b);
        if (gs_synth_render(&a, &cam, NULL, NULL, &sa, &err) ||
            gs_synth_render(&b, &cam, NULL, NULL, &sb, &err)) {
            fprintf(stderr, "%s\n", err.msg);
            exit(1);
        }
        const gs_synth_labels *l0 = &sa.labels, *l1 = &sb.labels;
        double truth[2] = {(l1->gaze_head_pitch - l0->gaze_head_pitch) / DEG,
                           (l1->gaze_head_yaw - l0->gaze_head_yaw) / DEG};
        double hz[3] = {l0->head_R[2], l0->head_R[5], l0->head_R[8]};
        double hdeg = gs_geom_vec3_angle(hz, (double[3]){0, 0, 1}) / DEG;
        gs_io_image ia = {S, S, sa.stride, sa.rgb}, ib = {S, S, sb.stride, sb.rgb};
        gs_face_iris_opts o;
        gs_face_iris_opts_default(&o);
        gs_face_iris_opts_scale(&o, 800.0 / 680.0);
        for (int e = 0; e < 2; e++) {
            const double(*pa)[2] = (const double(*)[2])&l0->lm2d[36 + 6 * e];
            const double(*pb)[2] = (const double(*)[2])&l1->lm2d[36 + 6 * e];
            gs_face_iris ra, rb;
            if (gs_face_iris_locate(&ia, pa, &o, &ra, &err) ||
                gs_face_iris_locate(&ib, pb, &o, &rb, &err)) {
                fprintf(stderr, "%s\n", err.msg);
                exit(1);
            }
            eyes++;
            if (ra.status != GS_FACE_IRIS_OK || rb.status != GS_FACE_IRIS_OK) {
                flagged++;
                continue;
            }
            double d[2];
            if (gs_face_iris_gaze_change(e, pa, ra.centre, pb, rb.centre, l0->head_R, &d[0],
                                         &d[1], &err)) {
                fprintf(stderr, "%s\n", err.msg);
                exit(1);
            }
            d[0] /= DEG;
            d[1] /= DEG;
            acc_add(&all, truth, d);
            if (hdeg < 30)
                acc_add(&near, truth, d);
        }
    }
    gs_synth_sample_free(&sa);
    gs_synth_sample_free(&sb);
    header("localized iris centres (open eyes, head R known)");
    acc_row("all", &all);
    acc_row("head 0-30°", &near);
    printf("\n%d of %d eye pairs flagged (either image not OK) and left out\n", flagged, eyes);
}

int main(int argc, char **argv)
{
    int nfit = 2000, npairs = 2000, nrender = 150;
    for (int i = 1; i < argc; i++) {
        if (!strcmp(argv[i], "--fit") && i + 1 < argc)
            nfit = atoi(argv[++i]);
        else if (!strcmp(argv[i], "--pairs") && i + 1 < argc)
            npairs = atoi(argv[++i]);
        else if (!strcmp(argv[i], "--render") && i + 1 < argc)
            nrender = atoi(argv[++i]);
        else {
            fprintf(stderr, "usage: iris_calib [--fit N] [--pairs N] [--render N]\n");
            return 2;
        }
    }
    fit(nfit);
    double b[3] = GS_FACE_IRIS_EYE_OFFSET_MM;
    printf("header: b = (%.3f, %.3f, %.3f) mm, Dx = %.3f mm, Dy = %.3f mm; at 256 px "
           "normalized (%.4f px/mm) a small turn moves the iris %.4f px/° (yaw), %.4f px/° "
           "(pitch) on a frontal head\n",
           b[0], b[1], b[2], GS_FACE_IRIS_ROT_X_MM, GS_FACE_IRIS_ROT_Y_MM, 800.0 / 680.0,
           800.0 / 680.0 * GS_FACE_IRIS_ROT_X_MM * DEG, 800.0 / 680.0 * GS_FACE_IRIS_ROT_Y_MM * DEG);
    read_pairs(npairs);
    if (nrender > 0)
        read_rendered(nrender);
    return 0;
}
