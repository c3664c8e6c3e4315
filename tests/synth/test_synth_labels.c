/* Labels: consistency between frames, the normalized and ETH-XGaze-like
 * rigs, identities and seed splits, argument checks, and the sign
 * conventions as seen in rendered pixels. */
#include <string.h>

#include "gs_test.h"
#include "synth_test_util.h"

static double max_diff(const double *a, const double *b, int n)
{
    double m = 0;
    for (int i = 0; i < n; i++)
        m = fmax(m, fabs(a[i] - b[i]));
    return m;
}

static void random_scene(uint64_t k, gs_synth_scene *s)
{
    gs_synth_ranges r;
    gs_synth_ranges_default(&r);
    gs_synth_scene_random(gs_synth_split_seed(GS_SYNTH_VAL, k), 1000 + k, &r, s);
}

static void test_frames(void)
{
    double w_gaze = 0, w_lm = 0, w_proj = 0, w_norm = 0;
    for (uint64_t k = 0; k < 40; k++) {
        gs_synth_scene s;
        random_scene(k, &s);
        gs_synth_camera cam;
        if (k % 2)
            gs_synth_camera_single(128, 600, 260, &cam);
        else
            CHECK(gs_synth_camera_ethx((int)(k % 18), 96, 600, 300, &cam) == 0);
        gs_synth_labels l;
        CHECK(gs_synth_labels_compute(&s, &cam, &l, NULL) == GS_OK);
        /* gaze_cam = head_R gaze_head, and its angles. */
        double g[3], p, y;
        gs_geom_mat3_vec(l.head_R, l.gaze_head, g);
        w_gaze = fmax(w_gaze, max_diff(g, l.gaze_cam, 3));
        gs_geom_vec_to_pitchyaw(l.gaze_cam, &p, &y);
        w_gaze = fmax(w_gaze, fmax(fabs(p - l.gaze_cam_pitch), fabs(y - l.gaze_cam_yaw)));
        gs_geom_vec_to_pitchyaw(l.gaze_head, &p, &y);
        w_gaze = fmax(w_gaze, fmax(fabs(p - s.gaze_pitch), fabs(y - s.gaze_yaw)));
        /* Landmarks: head frame -> camera -> pixels. */
        for (int i = 0; i < GS_SYNTH_LANDMARKS; i++) {
            double x[3], uv[2];
            gs_geom_mat3_vec(l.head_R, l.lm3d_head[i], x);
            for (int a = 0; a < 3; a++)
                x[a] += l.head_t[a];
            w_lm = fmax(w_lm, max_diff(x, l.lm3d[i], 3));
            if (gs_geom_project(l.K, l.lm3d[i], uv) == GS_OK)
                w_proj = fmax(w_proj, max_diff(uv, l.lm2d[i], 2));
        }
        /* Normalized labels from the stored transform. */
        double gn[3], hn[9];
        gs_geom_norm_vec(&l.norm, l.gaze_cam, gn);
        gs_geom_vec_to_pitchyaw(gn, &p, &y);
        w_norm = fmax(w_norm, fmax(fabs(p - l.gaze_norm_pitch), fabs(y - l.gaze_norm_yaw)));
        gs_geom_norm_rot(&l.norm, l.head_R, hn);
        gs_geom_head_pitchyaw(hn, &p, &y);
        w_norm = fmax(w_norm, fmax(fabs(p - l.head_norm_pitch), fabs(y - l.head_norm_yaw)));
        /* The head origin is the face centre. */
        CHECK(max_diff(l.face_centre, l.head_t, 3) == 0.0);
    }
    CHECK_MSG(w_gaze < 1e-12, "gaze frames: %.3g", w_gaze);
    CHECK_MSG(w_lm < 1e-9, "landmark frames: %.3g mm", w_lm);
    CHECK_MSG(w_proj < 1e-9, "landmark projection: %.3g px", w_proj);
    CHECK_MSG(w_norm < 1e-12, "normalized angles: %.3g", w_norm);
}

static void test_normalized_rig(void)
{
    double worst_gaze = 0, worst_centre = 0, worst_r = 0, worst_warp = 0;
    for (uint64_t k = 0; k < 30; k++) {
        gs_synth_scene s;
        random_scene(k, &s);
        gs_synth_camera base, nc;
        gs_synth_camera_single(200, 600, 260, &base);
        CHECK(gs_synth_camera_normalized(&s, &base, 224, 0, 0, &nc, NULL) == 0);
        gs_synth_labels lb, ln;
        CHECK(gs_synth_labels_compute(&s, &base, &lb, NULL) == GS_OK);
        CHECK(gs_synth_labels_compute(&s, &nc, &ln, NULL) == GS_OK);
        /* In the normalized camera the camera-frame gaze is the base
         * camera's normalized gaze, and the face centre is the image
         * centre. */
        worst_gaze = fmax(worst_gaze, fabs(ln.gaze_cam_pitch - lb.gaze_norm_pitch));
        worst_gaze = fmax(worst_gaze, fabs(ln.gaze_cam_yaw - lb.gaze_norm_yaw));
        worst_gaze = fmax(worst_gaze, fabs(ln.head_pitch - lb.head_norm_pitch));
        worst_gaze = fmax(worst_gaze, fabs(ln.head_yaw - lb.head_norm_yaw));
        worst_centre = fmax(worst_centre, fmax(fabs(ln.face_centre_uv[0] - 112),
                                               fabs(ln.face_centre_uv[1] - 112)));
        /* The base image's landmarks warped by W land on the normalized
         * image's landmarks (lb.norm is at the base size, 200: the
         * normalized focal scales with size about the centre). */
        for (int i = 0; i < GS_SYNTH_LANDMARKS; i++) {
            double uv[2];
            gs_geom_norm_pixel(&lb.norm, lb.lm2d[i], uv);
            for (int a = 0; a < 2; a++)
                uv[a] = (uv[a] - 100.0) * (224.0 / 200.0) + 112.0;
            worst_warp = fmax(worst_warp, max_diff(uv, ln.lm2d[i], 2));
        }
        /* Normalizing an already normalized view changes nothing. */
        double id[9];
        gs_geom_mat3_identity(id);
        worst_r = fmax(worst_r, max_diff(ln.norm.R, id, 9));
    }
    CHECK_MSG(worst_gaze < 1e-9, "normalized camera vs normalized labels: %.3g rad",
              worst_gaze);
    CHECK_MSG(worst_centre < 1e-6, "face centre vs image centre: %.3g px",
              worst_centre);
    CHECK_MSG(worst_r < 1e-9, "normalization of a normalized view: |R - I| %.3g",
              worst_r);
    CHECK_MSG(worst_warp < 1e-6, "warped landmarks vs normalized camera: %.3g px",
              worst_warp);
}

static void test_ethx_rig(void)
{
    gs_synth_scene s;
    gs_synth_scene_default(&s, 600.0);
    double worst = 0;
    for (int i = 0; i < GS_SYNTH_ETHX_CAMERAS; i++) {
        gs_synth_camera c;
        CHECK(gs_synth_camera_ethx(i, 64, 600, 300, &c) == GS_OK);
        gs_synth_labels l;
        CHECK(gs_synth_labels_compute(&s, &c, &l, NULL) == GS_OK);
        worst = fmax(worst, fmax(fabs(l.face_centre_uv[0] - 32), fabs(l.face_centre_uv[1] - 32)));
        CHECK_CLOSE(gs_geom_vec3_norm(l.face_centre), 600.0, 1e-9, 0);
        /* Column 0 (image-left cameras) sees the face from its right: the
         * head appears turned toward image-right, yaw < 0. Row 0 is above:
         * the head appears pitched down. */
        if (i % 6 == 0)
            CHECK_MSG(l.head_yaw < -0.9, "camera %d head yaw %.3f", i, l.head_yaw);
        if (i / 6 == 0)
            CHECK_MSG(l.head_pitch < -0.1, "camera %d head pitch %.3f", i, l.head_pitch);
    }
    CHECK_MSG(worst < 1e-9, "ETH rig: face centre off the image centre by %.3g px", worst);
    gs_synth_camera c;
    CHECK(gs_synth_camera_ethx(18, 64, 600, 300, &c) == GS_ERR_ARG);
}

static void test_identities(void)
{
    for (int i = 0; i < GS_SYNTH_ID_COUNT; i++)
        CHECK(gs_synth_identity_name(i) != NULL);
    CHECK(gs_synth_identity_name(GS_SYNTH_ID_COUNT) == NULL);
    CHECK(gs_synth_identity_name(-1) == NULL);
    for (int i = 0; i < GS_SYNTH_EXPR_COUNT; i++)
        CHECK(gs_synth_expression_name(i) != NULL);
    /* Disjoint splits. */
    for (uint64_t k = 0; k < 1000; k += 37) {
        CHECK_EQ_INT(gs_synth_seed_split(gs_synth_split_seed(GS_SYNTH_TRAIN, k)), GS_SYNTH_TRAIN);
        CHECK_EQ_INT(gs_synth_seed_split(gs_synth_split_seed(GS_SYNTH_VAL, k)), GS_SYNTH_VAL);
        CHECK_EQ_INT(gs_synth_seed_split(gs_synth_split_seed(GS_SYNTH_TEST, k)), GS_SYNTH_TEST);
    }
    CHECK_EQ_INT(gs_synth_seed_split(GS_SYNTH_SEED_VAL_FIRST - 1), GS_SYNTH_TRAIN);
    CHECK_EQ_INT(gs_synth_seed_split(GS_SYNTH_SEED_TEST_FIRST - 1), GS_SYNTH_VAL);
    CHECK_EQ_INT(gs_synth_seed_split(GS_SYNTH_SEED_TEST_FIRST + GS_SYNTH_SEED_SPLIT_COUNT), -1);
    CHECK(gs_synth_split_seed(GS_SYNTH_TRAIN, GS_SYNTH_SEED_SPLIT_COUNT + 5) ==
          gs_synth_split_seed(GS_SYNTH_TRAIN, 5));
    /* Deterministic, in range, and different per seed. */
    gs_synth_identity a, b, c;
    gs_synth_identity_from_seed(12345, &a);
    gs_synth_identity_from_seed(12345, &b);
    gs_synth_identity_from_seed(12346, &c);
    CHECK(a.seed == b.seed && memcmp(a.p, b.p, sizeof a.p) == 0);
    CHECK(memcmp(a.p, c.p, sizeof a.p) != 0);
    for (int i = 0; i < GS_SYNTH_ID_COUNT; i++)
        CHECK(a.p[i] >= -1.0f && a.p[i] <= 1.0f);
    gs_synth_identity_mean(&a);
    for (int i = 0; i < GS_SYNTH_ID_COUNT; i++)
        CHECK(a.p[i] == 0.0f);
    /* Random scenes stay within the ranges. */
    gs_synth_ranges r;
    gs_synth_ranges_default(&r);
    for (uint64_t k = 0; k < 200; k++) {
        gs_synth_scene s;
        gs_synth_scene_random(7, k, &r, &s);
        double p, y;
        gs_geom_head_pitchyaw(s.head_R, &p, &y);
        CHECK(fabs(p) <= r.head_pitch + 1e-9 && fabs(y) <= r.head_yaw + 1e-9);
        CHECK(fabs(s.gaze_pitch) <= r.gaze_pitch && fabs(s.gaze_yaw) <= r.gaze_yaw);
        CHECK(s.n_lights >= 1 && s.n_lights <= 2);
    }
}

static void test_errors(void)
{
    gs_synth_scene s;
    gs_synth_scene_default(&s, 600.0);
    gs_synth_camera cam;
    gs_synth_camera_single(32, 600, 260, &cam);
    gs_synth_sample smp;
    gs_error err;
    CHECK(gs_synth_sample_alloc(&smp, 0, 10, &err) == GS_ERR_ARG);
    CHECK(gs_synth_sample_alloc(&smp, 32, 32, &err) == GS_OK);
    s.gaze_yaw = NAN;
    CHECK_EQ_INT(gs_synth_render(&s, &cam, NULL, NULL, &smp, &err), GS_ERR_NONFINITE);
    s.gaze_yaw = 0;
    s.identity.p[3] = INFINITY;
    CHECK_EQ_INT(gs_synth_render(&s, &cam, NULL, NULL, &smp, &err), GS_ERR_NONFINITE);
    CHECK(strstr(err.msg, "head_height") != NULL);
    s.identity.p[3] = 0;
    gs_synth_camera big = cam;
    big.width = 64;
    CHECK_EQ_INT(gs_synth_render(&s, &big, NULL, NULL, &smp, &err), GS_ERR_ARG);
    gs_synth_render_opts o = {.supersample = 3};
    CHECK_EQ_INT(gs_synth_render(&s, &cam, &o, NULL, &smp, &err), GS_ERR_ARG);
    cam.K[0] = -1;
    CHECK_EQ_INT(gs_synth_render(&s, &cam, NULL, NULL, &smp, &err), GS_ERR_ARG);
    gs_synth_sample_free(&smp);
    gs_synth_sample_free(&smp); /* idempotent */
}

/* Darkness-weighted centroid of the darkest pixels of an eye image. */
static void pupil_centroid(const gs_synth_sample *s, double c[2])
{
    double lmin = 1e9, sw = 0, sx = 0, sy = 0;
    for (int y = 0; y < s->height; y++)
        for (int x = 0; x < s->width; x++)
            lmin = fmin(lmin, luminance(s, x, y));
    for (int y = 0; y < s->height; y++)
        for (int x = 0; x < s->width; x++) {
            double w = luminance(s, x, y) < lmin + 0.02 ? 1.0 : 0.0;
            sw += w;
            sx += w * (x + 0.5);
            sy += w * (y + 0.5);
        }
    c[0] = sx / sw;
    c[1] = sy / sw;
}

/* Looking up moves the pupil up in the image (pitch > 0); looking toward
 * image-left moves it left (yaw > 0); both in the labels and in pixels. */
static void test_signs_in_pixels(void)
{
    static const double gazes[4][2] = {{25, 0}, {-15, 0}, {0, 30}, {0, -30}};
    gs_synth_sample smp;
    CHECK(gs_synth_sample_alloc(&smp, 48, 48, NULL) == GS_OK);
    for (int k = 0; k < 4; k++) {
        gs_synth_scene s;
        gs_synth_scene_default(&s, 600.0);
        s.specular = 0;
        s.identity.p[GS_SYNTH_ID_IRIS_HUE] = 1.0f;
        s.gaze_pitch = gazes[k][0] * DEG;
        s.gaze_yaw = gazes[k][1] * DEG;
        gs_synth_camera cam;
        gs_synth_labels l;
        camera_aimed(48, 1800, (double[3]){0, 0, 600}, &cam);
        CHECK(gs_synth_labels_compute(&s, &cam, &l, NULL) == GS_OK);
        camera_aimed(48, 1800, l.eye_centre[GS_SYNTH_EYE_LEFT], &cam);
        CHECK(gs_synth_render(&s, &cam, NULL, NULL, &smp, NULL) == GS_OK);
        const gs_synth_labels *lb = &smp.labels;
        double c[2], du, dv;
        pupil_centroid(&smp, c);
        du = c[0] - lb->eye_centre_uv[GS_SYNTH_EYE_LEFT][0];
        dv = c[1] - lb->eye_centre_uv[GS_SYNTH_EYE_LEFT][1];
        double lu = lb->pupil_uv[GS_SYNTH_EYE_LEFT][0] - lb->eye_centre_uv[GS_SYNTH_EYE_LEFT][0];
        double lv = lb->pupil_uv[GS_SYNTH_EYE_LEFT][1] - lb->eye_centre_uv[GS_SYNTH_EYE_LEFT][1];
        if (gazes[k][0] > 0)
            CHECK_MSG(dv < -3 && lv < -3 && lb->gaze_cam_pitch > 0,
                      "looking up: pupil dv %.2f (label %.2f), pitch %.3f", dv, lv,
                      lb->gaze_cam_pitch);
        if (gazes[k][0] < 0)
            CHECK_MSG(dv > 2 && lv > 2, "looking down: pupil dv %.2f", dv);
        if (gazes[k][1] > 0)
            CHECK_MSG(du < -3 && lu < -3 && lb->gaze_cam_yaw > 0,
                      "looking image-left: pupil du %.2f (label %.2f), yaw %.3f",
                      du, lu, lb->gaze_cam_yaw);
        if (gazes[k][1] < 0)
            CHECK_MSG(du > 3 && lu > 3 && lb->gaze_cam_yaw < 0,
                      "looking image-right: pupil du %.2f", du);
        char name[32];
        snprintf(name, sizeof name, "signs_%d", k);
        dump_ppm(&smp, name);
    }
    gs_synth_sample_free(&smp);
}

int main(void)
{
    test_frames();
    test_normalized_rig();
    test_ethx_rig();
    test_identities();
    test_errors();
    test_signs_in_pixels();
    GS_TEST_END();
}
