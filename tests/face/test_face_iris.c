/* The iris localizer (gs_face_iris_locate) where the truth is exact:
 * synthetic heads of the test split at the 256 px normalized camera (d_n
 * 680 mm, f_n 800 px), scenes drawn as the evaluation draws them
 * (gs_eval_ranges), the label's own eye contours, the radius range of the
 * normalized scale. Truth: the label's projected iris centre (pupil_uv).
 *
 *   open eyes       head within 30 deg of the camera, not narrowed, the
 *                   eye not hidden by the face: median error of the eyes
 *                   located (status OK) <= 0.5 px, p95 <= 2.5 px, at
 *                   least a third located
 *   narrowed eyes   squint 0.4-0.9: each located within 3 px or flagged
 *   closed eyes     blink 1: none located
 *   painted         a red-eye pupil, a bright (white) pupil (each the
 *                   label's pupil disc) and a glint (1.2 px radius, up
 *                   and out of the pupil) painted on located eyes add
 *                   <= 0.5 px to the centre's error
 *   gaze            gs_face_iris_gaze_change on the label centres reads a
 *                   known gaze change within 1.5 deg (frontal head), with
 *                   the documented signs
 *   errors          bad arguments are errors, a tiny eye is TOO_SMALL,
 *                   the same input gives the same bytes
 *
 * Only the tiles around the eyes are rendered (region option): the test
 * stays fast under the sanitizers. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "gazesplat/eval.h"
#include "gazesplat/face.h"
#include "gazesplat/synth.h"
#include "gs_test.h"

#define S 256
#define DEG (3.14159265358979323846 / 180.0)

static gs_synth_sample smp;

/* Renders the tiles around both eyes of `sc` at the normalized camera. */
static void render(const gs_synth_scene *sc)
{
    gs_synth_camera base, cam;
    gs_error err;
    gs_synth_camera_single(S, 600, 260, &base);
    CHECK(gs_synth_camera_normalized(sc, &base, S, 680, 800, &cam, &err) == GS_OK);
    gs_synth_labels l;
    CHECK(gs_synth_labels_compute(sc, &cam, &l, &err) == GS_OK);
    double lo[2] = {S, S}, hi[2] = {0, 0};
    for (int i = 36; i < 48; i++)
        for (int c = 0; c < 2; c++) {
            lo[c] = fmin(lo[c], l.lm2d[i][c]);
            hi[c] = fmax(hi[c], l.lm2d[i][c]);
        }
    gs_synth_render_opts o = {.supersample = 1};
    o.region[0] = (int)fmax(0, lo[0] - 24);
    o.region[1] = (int)fmax(0, lo[1] - 24);
    o.region[2] = (int)fmin(S, hi[0] + 24);
    o.region[3] = (int)fmin(S, hi[1] + 24);
    memset(smp.rgb, 0, smp.stride * S);
    CHECK_MSG(gs_synth_render(sc, &cam, &o, NULL, &smp, &err) == GS_OK, "%s", err.msg);
}

static gs_io_image image(void)
{
    return (gs_io_image){S, S, smp.stride, smp.rgb};
}

static const double (*contour(int e))[2]
{
    return (const double(*)[2])&smp.labels.lm2d[36 + 6 * e];
}

static void opts(gs_face_iris_opts *o)
{
    gs_face_iris_opts_default(o);
    gs_face_iris_opts_scale(o, 800.0 / 680.0);
}

static double err_px(const gs_face_iris *r, int e)
{
    return hypot(r->centre[0] - smp.labels.pupil_uv[e][0],
                 r->centre[1] - smp.labels.pupil_uv[e][1]);
}

/* Fraction of the contour's pixels on the rendered eyeball. */
static double contour_seen(int e)
{
    const double(*pg)[2] = contour(e);
    const uint8_t *m = gs_synth_sample_mask(&smp, e ? GS_SYNTH_MASK_LEFT_EYE
                                                    : GS_SYNTH_MASK_RIGHT_EYE);
    int in = 0, both = 0;
    for (int y = 0; y < S; y++)
        for (int x = 0; x < S; x++) {
            int inside = 0;
            double qx = x + 0.5, qy = y + 0.5;
            for (int a = 0, b = 5; a < 6; b = a++)
                if ((pg[a][1] > qy) != (pg[b][1] > qy) &&
                    qx < pg[a][0] + (qy - pg[a][1]) * (pg[b][0] - pg[a][0]) / (pg[b][1] - pg[a][1]))
                    inside = !inside;
            in += inside;
            both += inside && m[(size_t)y * S + x];
        }
    return in ? (double)both / in : 0;
}

static int cmp(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

static double head_deg(const gs_synth_labels *l)
{
    double hz[3] = {l->head_R[2], l->head_R[5], l->head_R[8]}, z[3] = {0, 0, 1};
    return gs_geom_vec3_angle(hz, z) / DEG;
}

/* Paints a disc of radius r (px) around c in rgb. */
static void paint_disc(const double c[2], double r, const uint8_t rgb[3])
{
    for (int y = (int)floor(c[1] - r); y <= (int)ceil(c[1] + r); y++)
        for (int x = (int)floor(c[0] - r); x <= (int)ceil(c[0] + r); x++)
            if (x >= 0 && y >= 0 && x < S && y < S && hypot(x + 0.5 - c[0], y + 0.5 - c[1]) <= r)
                memcpy(smp.rgb + (size_t)y * smp.stride + 3 * (size_t)x, rgb, 3);
}

static void test_errors(void)
{
    gs_synth_scene sc;
    gs_synth_scene_default(&sc, 600);
    render(&sc);
    gs_io_image img = image();
    gs_face_iris r;
    gs_error err;
    double p[6][2];
    memcpy(p, contour(0), sizeof p);
    CHECK(gs_face_iris_locate(NULL, p, NULL, &r, &err) == GS_ERR_ARG);
    CHECK(gs_face_iris_locate(&img, NULL, NULL, &r, &err) == GS_ERR_ARG);
    CHECK(gs_face_iris_locate(&img, p, NULL, NULL, &err) == GS_ERR_ARG);
    gs_io_image bad = img;
    bad.stride = 10;
    CHECK(gs_face_iris_locate(&bad, p, NULL, &r, &err) == GS_ERR_ARG);
    double q[6][2];
    memcpy(q, p, sizeof q);
    q[2][0] = NAN;
    CHECK(gs_face_iris_locate(&img, q, NULL, &r, &err) == GS_ERR_NONFINITE);
    memcpy(q, p, sizeof q);
    q[4][1] = S + 3;
    CHECK(gs_face_iris_locate(&img, q, NULL, &r, &err) == GS_ERR_ARG);
    for (int i = 0; i < 6; i++) /* all points at one place */
        memcpy(q[i], p[0], sizeof q[i]);
    CHECK(gs_face_iris_locate(&img, q, NULL, &r, &err) == GS_ERR_ARG);
    memcpy(q, p, sizeof q);
    q[5][0] = p[0][0] - 100; /* a point 3 eye widths off */
    CHECK(gs_face_iris_locate(&img, q, NULL, &r, &err) == GS_ERR_ARG);
    gs_face_iris_opts o;
    opts(&o);
    o.radius_min_px = 9;
    o.radius_max_px = 5;
    CHECK(gs_face_iris_locate(&img, p, &o, &r, &err) == GS_ERR_ARG);
    /* A tiny eye: the contour shrunk about its centre to 6 px. */
    double cx = 0.5 * (p[0][0] + p[3][0]), cy = 0.5 * (p[0][1] + p[3][1]);
    for (int i = 0; i < 6; i++) {
        q[i][0] = cx + 0.2 * (p[i][0] - cx);
        q[i][1] = cy + 0.2 * (p[i][1] - cy);
    }
    CHECK(gs_face_iris_locate(&img, q, NULL, &r, &err) == GS_OK);
    CHECK_EQ_INT(r.status, GS_FACE_IRIS_TOO_SMALL);
    CHECK(isnan(r.centre[0]) && r.eye_width < 10);
    /* Deterministic: the same bytes twice. */
    gs_face_iris a, b;
    opts(&o);
    CHECK(gs_face_iris_locate(&img, p, &o, &a, &err) == GS_OK);
    CHECK(gs_face_iris_locate(&img, p, &o, &b, &err) == GS_OK);
    CHECK(memcmp(&a, &b, sizeof a) == 0);
    CHECK_EQ_INT(a.status, GS_FACE_IRIS_OK);
    CHECK_MSG(err_px(&a, 0) < 0.5, "frontal eye off by %.2f px", err_px(&a, 0));
    double pt, yw;
    CHECK(gs_face_iris_gaze(2, p, a.centre, NULL, &pt, &yw, &err) == GS_ERR_ARG);
    CHECK(gs_face_iris_gaze(0, p, a.centre, NULL, NULL, &yw, &err) == GS_ERR_ARG);
}

/* Open eyes over the evaluation's scenes with the head within 30 deg. */
static void test_open(void)
{
    gs_synth_ranges rg;
    gs_eval_ranges(&rg);
    double e[256];
    int n = 0, tried = 0, flagged = 0;
    for (uint64_t k = 0; k < 400 && tried < 90; k++) {
        gs_synth_scene sc;
        gs_synth_scene_random(gs_synth_split_seed(GS_SYNTH_TEST, k % 100), 11000 + k, &rg, &sc);
        if (gs_eval_expr_narrowed(&sc.expr))
            continue;
        gs_synth_camera base, cam;
        gs_synth_labels l;
        gs_synth_camera_single(S, 600, 260, &base);
        if (gs_synth_camera_normalized(&sc, &base, S, 680, 800, &cam, NULL) ||
            gs_synth_labels_compute(&sc, &cam, &l, NULL) || head_deg(&l) >= 30)
            continue;
        render(&sc);
        gs_io_image img = image();
        gs_face_iris_opts o;
        opts(&o);
        for (int eye = 0; eye < 2; eye++) {
            if (contour_seen(eye) < 0.5)
                continue;
            gs_face_iris r;
            gs_error err;
            CHECK(gs_face_iris_locate(&img, contour(eye), &o, &r, &err) == GS_OK);
            tried++;
            if (r.status != GS_FACE_IRIS_OK) {
                flagged++;
                continue;
            }
            if (n < 256)
                e[n++] = err_px(&r, eye);
        }
    }
    qsort(e, (size_t)n, sizeof e[0], cmp);
    double med = n ? e[n / 2] : NAN, p95 = n ? e[(int)ceil(0.95 * n) - 1] : NAN;
    printf("open eyes, head < 30 deg: %d eyes, %d located, %d flagged; centre error median "
           "%.3f px, p95 %.3f px, max %.3f px\n", tried, n, flagged, med, p95, n ? e[n - 1] : NAN);
    CHECK_MSG(3 * n >= tried, "only %d of %d eyes located", n, tried);
    CHECK_MSG(med <= 0.5, "median error %.3f px > 0.5", med);
    CHECK_MSG(p95 <= 2.5, "p95 error %.3f px > 2.5", p95);
}

/* Narrowed (squinting) eyes: located within 3 px or flagged; closed
 * (blinking) eyes: never located. */
static void test_narrowed_closed(void)
{
    gs_synth_ranges rg;
    gs_eval_ranges(&rg);
    int located = 0, flagged = 0, closed = 0, closed_located = 0;
    double worst = 0;
    for (uint64_t k = 0; k < 24; k++) {
        gs_synth_scene sc;
        gs_synth_scene_random(gs_synth_split_seed(GS_SYNTH_TEST, 40 + k), 13000 + k, &rg, &sc);
        int shut = k % 3 == 2;
        sc.expr.squint = shut ? 0.0f : 0.4f + 0.5f * (float)(k % 8) / 7.0f;
        sc.expr.blink = shut ? 1.0f : 0.0f;
        render(&sc);
        gs_io_image img = image();
        gs_face_iris_opts o;
        opts(&o);
        for (int eye = 0; eye < 2; eye++) {
            gs_face_iris r;
            gs_error err;
            CHECK(gs_face_iris_locate(&img, contour(eye), &o, &r, &err) == GS_OK);
            int ok = r.status == GS_FACE_IRIS_OK;
            if (shut) {
                closed++;
                closed_located += ok;
                continue;
            }
            if (!ok) {
                flagged++;
                continue;
            }
            located++;
            double d = err_px(&r, eye);
            worst = fmax(worst, d);
            CHECK_MSG(d <= 3.0, "narrowed eye (squint %.2f) located %.2f px off", sc.expr.squint,
                      d);
        }
    }
    printf("narrowed eyes: %d located (worst %.2f px), %d flagged; closed eyes: %d of %d "
           "located\n", located, worst, flagged, closed_located, closed);
    CHECK_EQ_INT(closed_located, 0);
}

/* Red-eye and bright pupils, and a glint, painted on located eyes. */
static void test_painted(void)
{
    static const uint8_t red[3] = {220, 40, 40}, white[3] = {235, 225, 225},
                         glint[3] = {255, 255, 255};
    double worst[3] = {-INFINITY, -INFINITY, -INFINITY}, moved[3] = {0, 0, 0};
    int tested = 0, kept[3] = {0, 0, 0};
    for (int k = 0; k < 6; k++) {
        gs_synth_scene sc;
        gs_synth_scene_default(&sc, 600);
        gs_synth_identity_from_seed(gs_synth_split_seed(GS_SYNTH_TEST, 60 + (uint64_t)k),
                                    &sc.identity);
        sc.gaze_yaw = (k - 2.5) * 4 * DEG;
        sc.gaze_pitch = (k % 2 ? 5 : -3) * DEG;
        gs_geom_rot_from_pitchyaw((k % 3 - 1) * 6 * DEG, (k - 2.5) * 3 * DEG, 0, sc.head_R);
        render(&sc);
        gs_synth_sample keep = smp;
        uint8_t *orig = malloc(smp.stride * S);
        if (!orig)
            abort();
        memcpy(orig, smp.rgb, smp.stride * S);
        gs_io_image img = image();
        gs_face_iris_opts o;
        opts(&o);
        for (int eye = 0; eye < 2; eye++) {
            gs_face_iris r0;
            CHECK(gs_face_iris_locate(&img, contour(eye), &o, &r0, NULL) == GS_OK);
            if (r0.status != GS_FACE_IRIS_OK)
                continue;
            tested++;
            const gs_synth_labels *l = &keep.labels;
            double rp = l->K[0] * l->pupil_radius_mm / l->pupil_centre[eye][2];
            double ri = l->K[0] * l->iris_radius_mm / l->pupil_centre[eye][2];
            for (int v = 0; v < 3; v++) {
                memcpy(smp.rgb, orig, smp.stride * S);
                if (v < 2) {
                    paint_disc(l->pupil_uv[eye], rp, v ? white : red);
                } else {
                    double g[2] = {l->pupil_uv[eye][0] - 0.45 * ri,
                                   l->pupil_uv[eye][1] - 0.35 * ri};
                    paint_disc(g, 1.2, glint);
                }
                gs_face_iris r;
                CHECK(gs_face_iris_locate(&img, contour(eye), &o, &r, NULL) == GS_OK);
                /* The centre is filled for OK and PARTIAL; what counts is
                 * how much the paint adds to the error against the truth
                 * (a painted pupil sits exactly at the truth and may well
                 * pull a poor centre toward it). */
                double d = r.status == GS_FACE_IRIS_OK || r.status == GS_FACE_IRIS_PARTIAL
                               ? err_px(&r, eye) - err_px(&r0, eye)
                               : INFINITY;
                worst[v] = fmax(worst[v], d);
                moved[v] = fmax(moved[v], hypot(r.centre[0] - r0.centre[0],
                                                r.centre[1] - r0.centre[1]));
                kept[v] += r.status == GS_FACE_IRIS_OK;
            }
        }
        free(orig);
    }
    static const char *const name[3] = {"red pupil", "white pupil", "glint"};
    for (int v = 0; v < 3; v++) {
        printf("painted %s on %d located eyes: error grew by at most %+.3f px (the centre "
               "moved up to %.3f px); still OK: %d\n", name[v], tested, worst[v], moved[v],
               kept[v]);
        CHECK_MSG(worst[v] <= 0.5, "a painted %s adds %.3f px to the error", name[v], worst[v]);
    }
    CHECK(tested >= 6);
}

/* The calibrated map on the label centres: a frontal head, known gaze
 * changes. */
static void test_gaze(void)
{
    double worst = 0;
    for (int k = 0; k < 8; k++) {
        gs_synth_scene a, b;
        gs_synth_scene_default(&a, 600);
        gs_synth_identity_from_seed(gs_synth_split_seed(GS_SYNTH_TEST, 70 + (uint64_t)k),
                                    &a.identity);
        a.gaze_pitch = ((k % 3) - 1) * 8 * DEG;
        a.gaze_yaw = ((k % 4) - 1.5) * 8 * DEG;
        b = a;
        b.gaze_pitch += (k % 2 ? 10 : -12) * DEG;
        b.gaze_yaw += (k % 3 ? 15 : -9) * DEG;
        gs_synth_camera base, cam;
        gs_synth_labels la, lb;
        gs_synth_camera_single(S, 600, 260, &base);
        CHECK(gs_synth_camera_normalized(&a, &base, S, 680, 800, &cam, NULL) == GS_OK);
        CHECK(gs_synth_labels_compute(&a, &cam, &la, NULL) == GS_OK);
        CHECK(gs_synth_labels_compute(&b, &cam, &lb, NULL) == GS_OK);
        for (int e = 0; e < 2; e++) {
            double dp, dy;
            gs_error err;
            CHECK(gs_face_iris_gaze_change(e, (const double(*)[2])&la.lm2d[36 + 6 * e],
                                           la.pupil_uv[e], (const double(*)[2])&lb.lm2d[36 + 6 * e],
                                           lb.pupil_uv[e], la.head_R, &dp, &dy, &err) == GS_OK);
            double tp = (lb.gaze_head_pitch - la.gaze_head_pitch) / DEG;
            double ty = (lb.gaze_head_yaw - la.gaze_head_yaw) / DEG;
            worst = fmax(worst, fmax(fabs(dp / DEG - tp), fabs(dy / DEG - ty)));
            /* Signs: yaw > 0 moves the iris toward image-left, pitch > 0 up. */
            if (ty > 0)
                CHECK(lb.pupil_uv[e][0] < la.pupil_uv[e][0] && dy > 0);
            if (tp > 0)
                CHECK(lb.pupil_uv[e][1] < la.pupil_uv[e][1] && dp > 0);
        }
    }
    printf("gaze change from the label centres, frontal head: worst error %.3f deg\n", worst);
    CHECK_MSG(worst <= 1.5, "gaze change off by %.3f deg", worst);
}

/* Red-eye repair (gs_face_red_eye_fix) on located synthetic eyes: a clean
 * eye, a white pupil, an amber iris ring and an iris as red as its pupil
 * keep their bytes; a red pupil
 * (a dark red disc with a pink highlight, as flash photos show) loses its
 * red: no red pixel is left in it, only R changed and only inside the
 * eye's contour, and the located centre moves by at most 0.5 px against
 * the clean eye's. */
static void test_red_eye(void)
{
    static const uint8_t red[3] = {160, 40, 35}, pink[3] = {235, 165, 155},
                         white[3] = {235, 225, 225}, amber[3] = {140, 95, 70};
    int tested = 0, repaired = 0, left_red = 0, false_fix = 0, other = 0;
    double moved = 0;
    uint8_t *orig = malloc(smp.stride * S), *want = malloc(smp.stride * S);
    CHECK(orig && want);
    for (int k = 0; k < 6 && orig && want; k++) {
        gs_synth_scene sc;
        gs_synth_scene_default(&sc, 600);
        gs_synth_identity_from_seed(gs_synth_split_seed(GS_SYNTH_TEST, 80 + (uint64_t)k),
                                    &sc.identity);
        sc.gaze_yaw = (k - 2.5) * 5 * DEG;
        sc.gaze_pitch = (k % 2 ? 4 : -4) * DEG;
        render(&sc);
        memcpy(orig, smp.rgb, smp.stride * S);
        gs_io_image img = image();
        const double(*uv)[2] = (const double(*)[2])smp.labels.lm2d;
        gs_face_iris_opts o;
        opts(&o);
        int fixed = -1;
        CHECK(gs_face_red_eye_fix(&img, uv, 800.0 / 680.0, &fixed, NULL) == GS_OK);
        false_fix += fixed != 0 || memcmp(orig, smp.rgb, smp.stride * S) != 0;
        for (int eye = 0; eye < 2; eye++) {
            memcpy(smp.rgb, orig, smp.stride * S);
            gs_face_iris r0;
            CHECK(gs_face_iris_locate(&img, contour(eye), &o, &r0, NULL) == GS_OK);
            if (r0.status != GS_FACE_IRIS_OK)
                continue;
            tested++;
            const gs_synth_labels *l = &smp.labels;
            double rp = l->K[0] * l->pupil_radius_mm / l->pupil_centre[eye][2];
            double ri = l->K[0] * l->iris_radius_mm / l->pupil_centre[eye][2];
            /* not red-eye: a white pupil, an amber ring around a dark pupil */
            paint_disc(l->pupil_uv[eye], rp, white);
            memcpy(want, smp.rgb, smp.stride * S);
            CHECK(gs_face_red_eye_fix(&img, uv, 800.0 / 680.0, &fixed, NULL) == GS_OK);
            false_fix += fixed != 0 || memcmp(want, smp.rgb, smp.stride * S) != 0;
            memcpy(smp.rgb, orig, smp.stride * S);
            paint_disc(l->pupil_uv[eye], 0.9 * ri, amber);
            paint_disc(l->pupil_uv[eye], rp, (const uint8_t[3]){25, 20, 18});
            memcpy(want, smp.rgb, smp.stride * S);
            CHECK(gs_face_red_eye_fix(&img, uv, 800.0 / 680.0, &fixed, NULL) == GS_OK);
            false_fix += fixed != 0 || memcmp(want, smp.rgb, smp.stride * S) != 0;
            /* the whole iris as red as the pupil (warm light, a red cast):
             * nothing stands out, nothing is repaired */
            memcpy(smp.rgb, orig, smp.stride * S);
            paint_disc(l->pupil_uv[eye], 0.95 * ri, (const uint8_t[3]){150, 97, 83});
            paint_disc(l->pupil_uv[eye], rp, red);
            memcpy(want, smp.rgb, smp.stride * S);
            CHECK(gs_face_red_eye_fix(&img, uv, 800.0 / 680.0, &fixed, NULL) == GS_OK);
            false_fix += fixed != 0 || memcmp(want, smp.rgb, smp.stride * S) != 0;
            /* red-eye */
            memcpy(smp.rgb, orig, smp.stride * S);
            paint_disc(l->pupil_uv[eye], rp, red);
            double h[2] = {l->pupil_uv[eye][0] - 0.3 * rp, l->pupil_uv[eye][1] - 0.3 * rp};
            paint_disc(h, 0.35 * rp, pink);
            memcpy(want, smp.rgb, smp.stride * S);
            CHECK(gs_face_red_eye_fix(&img, uv, 800.0 / 680.0, &fixed, NULL) == GS_OK);
            repaired += fixed > 0;
            for (int y = 0; y < S; y++)
                for (int x = 0; x < S; x++) {
                    const uint8_t *a = want + (size_t)y * smp.stride + 3 * (size_t)x;
                    const uint8_t *b = smp.rgb + (size_t)y * smp.stride + 3 * (size_t)x;
                    double d = hypot(x + 0.5 - l->pupil_uv[eye][0], y + 0.5 - l->pupil_uv[eye][1]);
                    int m = b[1] > b[2] ? b[1] : b[2];
                    left_red += d <= rp - 0.5 && b[0] > 1.35 * m && b[0] - m > 40;
                    other += a[1] != b[1] || a[2] != b[2] || (a[0] != b[0] && d > 1.5 * ri);
                }
            gs_face_iris r;
            CHECK(gs_face_iris_locate(&img, contour(eye), &o, &r, NULL) == GS_OK);
            moved = fmax(moved, r.status == GS_FACE_IRIS_OK || r.status == GS_FACE_IRIS_PARTIAL
                                    ? hypot(r.centre[0] - r0.centre[0], r.centre[1] - r0.centre[1])
                                    : INFINITY);
        }
    }
    printf("red-eye: %d eyes, %d repaired, %d red pixels left, %d other pixels changed, "
           "%d false repairs, centre moved %.2f px at most\n",
           tested, repaired, left_red, other, false_fix, moved);
    CHECK(tested >= 4);
    CHECK_EQ_INT(repaired, tested);
    CHECK_EQ_INT(left_red, 0);
    CHECK_EQ_INT(other, 0);
    CHECK_EQ_INT(false_fix, 0);
    CHECK_MSG(moved <= 0.5, "red-eye repair moved the centre by %.2f px", moved);
    gs_io_image bad = {0, 0, 0, NULL};
    CHECK(gs_face_red_eye_fix(&bad, (const double(*)[2])smp.labels.lm2d, 0, NULL, NULL) ==
          GS_ERR_ARG);
    free(orig);
    free(want);
}

int main(void)
{
    if (gs_synth_sample_alloc(&smp, S, S, NULL) != GS_OK)
        return 1;
    test_errors();
    test_gaze();
    test_painted();
    test_red_eye();
    test_narrowed_closed();
    test_open();
    gs_synth_sample_free(&smp);
    printf("%d checks, %d failures\n", gs_test_checks, gs_test_failures);
    return gs_test_failures != 0;
}
