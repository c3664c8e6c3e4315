/* Angle kappa (synth.h, docs/synth.md): the draw per identity (its
 * distribution, stable across scenes and thread counts), the signs of the
 * optical axes (temporal and down of the visual axis, mirrored between the
 * eyes), the rendered pupil following the optical axis, the labels, and
 * the dataset README round trip. */
#define _POSIX_C_SOURCE 200809L /* mkdtemp */
#include <unistd.h>

#include "gazesplat/pool.h"
#include "gs_test.h"
#include "synth_internal.h"
#include "synth_test_util.h"

enum { SIZE = 72 };

static double angle_between(const double a[3], const double b[3])
{
    double d = a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
    return acos(d > 1.0 ? 1.0 : (d < -1.0 ? -1.0 : d));
}

/* The literature preset over many identities: mean and sd as asked (the
 * 3-sd truncation takes 1.4 % off the sd), nothing beyond 3 sd, and the
 * same value on every call. Off: exactly zero. */
static void test_distribution(void)
{
    gs_synth_kappa k;
    gs_synth_kappa_literature(&k);
    CHECK(gs_synth_kappa_check(&k, NULL) == GS_OK);
    enum { N = 4000 };
    double sh = 0, sh2 = 0, sv = 0, sv2 = 0, hmin = 1e9, hmax = -1e9, vmin = 1e9, vmax = -1e9;
    for (int i = 0; i < N; i++) {
        uint64_t seed = gs_synth_split_seed(GS_SYNTH_TRAIN, (uint64_t)i);
        double h, v, h2, v2;
        gs_synth_kappa_draw(&k, seed, &h, &v);
        gs_synth_kappa_draw(&k, seed, &h2, &v2);
        CHECK(h == h2 && v == v2);
        h /= DEG;
        v /= DEG;
        sh += h;
        sh2 += h * h;
        sv += v;
        sv2 += v * v;
        hmin = fmin(hmin, h);
        hmax = fmax(hmax, h);
        vmin = fmin(vmin, v);
        vmax = fmax(vmax, v);
    }
    double mh = sh / N, mv = sv / N;
    double dh = sqrt(sh2 / N - mh * mh), dv = sqrt(sv2 / N - mv * mv);
    printf("kappa literature, %d identities: h %.3f +- %.3f deg [%.2f, %.2f], v %.3f +- "
           "%.3f deg [%.2f, %.2f]\n", N, mh, dh, hmin, hmax, mv, dv, vmin, vmax);
    /* Standard errors: 1.3 / sqrt(4000) = 0.021 deg for the mean. */
    CHECK_CLOSE(mh, 5.0, 0.08, 0);
    CHECK_CLOSE(mv, 1.5, 0.06, 0);
    CHECK_CLOSE(dh, 1.3 * 0.986, 0.06, 0);
    CHECK_CLOSE(dv, 1.0 * 0.986, 0.05, 0);
    CHECK(hmin >= 5.0 - 3 * 1.3 - 1e-9 && hmax <= 5.0 + 3 * 1.3 + 1e-9);
    CHECK(vmin >= 1.5 - 3 * 1.0 - 1e-9 && vmax <= 1.5 + 3 * 1.0 + 1e-9);
    k.enabled = 0;
    double h, v;
    gs_synth_kappa_draw(&k, 12345, &h, &v);
    CHECK(h == 0.0 && v == 0.0);
    /* Bad parameters name the field. */
    gs_synth_kappa bad;
    gs_synth_kappa_literature(&bad);
    bad.v_sd_deg = -1;
    gs_error err = {0, ""};
    CHECK(gs_synth_kappa_check(&bad, &err) == GS_ERR_ARG);
    CHECK_MSG(strstr(err.msg, "vertical sd") != NULL, "message: %s", err.msg);
    bad.v_sd_deg = 1;
    bad.h_mean_deg = NAN;
    CHECK(gs_synth_kappa_check(&bad, &err) == GS_ERR_ARG);
    gs_synth_gen_config c;
    gs_synth_gen_config_default(&c);
    c.kappa = bad;
    gs_synth_scene sc;
    gs_synth_camera cam;
    CHECK(gs_synth_gen_scene(&c, 0, &sc, &cam, &err) == GS_ERR_ARG);
}

/* Fixed kappa (5 deg nasal, 2 deg up; sds 0) at many gazes: the optical
 * axes are 5.39 deg from the gaze, the right eye's turned toward -x (yaw
 * up), the left eye's toward +x, both down; the visual axis stays the
 * label. */
static void test_signs(void)
{
    gs_synth_kappa k = {1, 5.0, 0.0, 2.0, 0.0};
    gs_rng rng;
    gs_rng_seed(&rng, 5);
    double want = acos(cos(5 * DEG) * cos(2 * DEG));
    for (int t = 0; t < 40; t++) {
        gs_synth_scene sc;
        gs_synth_scene_default(&sc, 600.0);
        gs_synth_identity_from_seed(gs_synth_split_seed(GS_SYNTH_TEST, (uint64_t)t), &sc.identity);
        sc.gaze_pitch = gs_rng_uniform(&rng, -40, 40) * DEG;
        sc.gaze_yaw = gs_rng_uniform(&rng, -50, 50) * DEG;
        gs_synth_scene_set_kappa(&k, &sc);
        CHECK(sc.kappa == 1);
        CHECK_CLOSE(sc.kappa_h, 5 * DEG, 1e-15, 0);
        CHECK_CLOSE(sc.kappa_v, 2 * DEG, 1e-15, 0);
        gs_synth_camera cam;
        gs_synth_camera_single(128, 600.0, 260.0, &cam);
        gs_synth_labels l, l0;
        CHECK(gs_synth_labels_compute(&sc, &cam, &l, NULL) == GS_OK);
        sc.kappa = 0;
        CHECK(gs_synth_labels_compute(&sc, &cam, &l0, NULL) == GS_OK);
        CHECK(l.has_kappa == 1 && l0.has_kappa == 0);
        /* The gaze label is the visual axis either way. */
        CHECK(memcmp(l.gaze_head, l0.gaze_head, sizeof l.gaze_head) == 0);
        CHECK(memcmp(l.gaze_cam, l0.gaze_cam, sizeof l.gaze_cam) == 0);
        for (int e = 0; e < 2; e++) {
            double a = angle_between(l.optical_head[e], l.gaze_head);
            CHECK_CLOSE(a, want, 1e-6, 0);
            CHECK_CLOSE(angle_between(l0.optical_head[e], l0.gaze_head), 0.0, 1e-6, 0);
            /* In the gaze's own frame (R(gaze)^T optical): temporal, down. */
            double r[9], o[3];
            gs_geom_rot_from_pitchyaw(sc.gaze_pitch, sc.gaze_yaw, 0.0, r);
            gs_geom_mat3_tvec(r, l.optical_head[e], o);
            double p, y;
            gs_geom_vec_to_pitchyaw(o, &p, &y);
            CHECK_CLOSE(p, -2 * DEG, 1e-6, 0);
            CHECK_CLOSE(y, e == GS_SYNTH_EYE_RIGHT ? 5 * DEG : -5 * DEG, 1e-6, 0);
            /* The pupil label sits on the optical axis. */
            double d[3];
            for (int i = 0; i < 3; i++)
                d[i] = l.pupil_centre[e][i] - l.eye_centre[e][i];
            double n = sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
            for (int i = 0; i < 3; i++)
                d[i] /= n;
            CHECK_CLOSE(angle_between(d, l.optical_cam[e]), 0.0, 1e-5, 0);
        }
        /* Frontal head, camera in front: the pupils move apart (temporal)
         * and down in the image. */
        CHECK(l.pupil_uv[GS_SYNTH_EYE_RIGHT][0] < l0.pupil_uv[GS_SYNTH_EYE_RIGHT][0]);
        CHECK(l.pupil_uv[GS_SYNTH_EYE_LEFT][0] > l0.pupil_uv[GS_SYNTH_EYE_LEFT][0]);
        CHECK(l.pupil_uv[0][1] > l0.pupil_uv[0][1] && l.pupil_uv[1][1] > l0.pupil_uv[1][1]);
        /* Everything but the eyeballs is unchanged. */
        /* Everything but the eyeballs is unchanged; the lid-margin
         * landmarks, which lie where the lids meet the eyeball, follow its
         * cornea by a few hundredths of a px. */
        for (int i = 0; i < GS_SYNTH_LANDMARKS; i++) {
            double d = hypot(l.lm2d[i][0] - l0.lm2d[i][0], l.lm2d[i][1] - l0.lm2d[i][1]);
            CHECK_MSG(i >= 36 && i < 48 ? d < 0.2 : d == 0.0, "landmark %d moved %.4f px", i, d);
        }
        CHECK(memcmp(l.face_centre, l0.face_centre, sizeof l.face_centre) == 0);
        CHECK(memcmp(l.eye_centre, l0.eye_centre, sizeof l.eye_centre) == 0);
        /* A scene's non-finite kappa is refused. */
        sc.kappa = 1;
        sc.kappa_v = NAN;
        CHECK(gs_synth_labels_compute(&sc, &cam, &l, NULL) == GS_ERR_NONFINITE);
    }
}

/* The rendered pupil follows the optical axis: each eye seen by a camera
 * zoomed on it (4 px per mm), 2x2 supersampled, lids open, light iris, no
 * highlight; the dark-pupil centroid lies within 0.5 px of the kappa
 * label and several px from where the visual axis would put it. */
static void test_render(void)
{
    gs_synth_kappa k;
    gs_synth_kappa_literature(&k);
    gs_synth_sample s;
    CHECK(gs_synth_sample_alloc(&s, SIZE, SIZE, NULL) == GS_OK);
    gs_synth_render_opts opts = {.supersample = 2, .open_lids = 1};
    gs_rng rng;
    gs_rng_seed(&rng, 9);
    double worst = 0, shift_min = 1e9, sum = 0;
    int n = 0;
    for (int t = 0; t < 12; t++) {
        gs_synth_scene sc;
        gs_synth_scene_default(&sc, 600.0);
        gs_synth_identity_from_seed(gs_synth_split_seed(GS_SYNTH_VAL, (uint64_t)t), &sc.identity);
        sc.identity.p[GS_SYNTH_ID_IRIS_HUE] = 1.0f;
        sc.identity.p[GS_SYNTH_ID_IRIS_BRIGHTNESS] = 1.0f;
        sc.identity.p[GS_SYNTH_ID_IRIS_PATTERN] = -1.0f;
        sc.specular = 0;
        sc.ambient[0] = sc.ambient[1] = sc.ambient[2] = 0.7f;
        sc.gaze_pitch = gs_rng_uniform(&rng, -20, 20) * DEG;
        sc.gaze_yaw = gs_rng_uniform(&rng, -25, 25) * DEG;
        gs_synth_scene_set_kappa(&k, &sc);
        for (int e = 0; e < 2; e++) {
            gs_synth_labels l, l0;
            gs_synth_camera cam;
            camera_aimed(SIZE, 2400.0, (double[3]){0, 0, 600}, &cam);
            CHECK(gs_synth_labels_compute(&sc, &cam, &l, NULL) == GS_OK);
            camera_aimed(SIZE, 2400.0, l.pupil_centre[e], &cam);
            CHECK(gs_synth_labels_compute(&sc, &cam, &l, NULL) == GS_OK);
            sc.kappa = 0;
            CHECK(gs_synth_labels_compute(&sc, &cam, &l0, NULL) == GS_OK);
            sc.kappa = 1;
            CHECK(gs_synth_render(&sc, &cam, &opts, NULL, &s, NULL) == GS_OK);
            double rp = l.pupil_radius_mm * 2400.0 / l.pupil_centre[e][2];
            double c[2];
            dark_centroid(&s, l.pupil_uv[e][0], l.pupil_uv[e][1], rp, c);
            double err = hypot(c[0] - l.pupil_uv[e][0], c[1] - l.pupil_uv[e][1]);
            double vis = hypot(c[0] - l0.pupil_uv[e][0], c[1] - l0.pupil_uv[e][1]);
            double shift = hypot(l.pupil_uv[e][0] - l0.pupil_uv[e][0],
                                 l.pupil_uv[e][1] - l0.pupil_uv[e][1]);
            CHECK_MSG(err <= 0.5 && vis > err + 1.0,
                      "identity %d eye %d (kappa %.2f %.2f deg): centroid (%.2f, %.2f), "
                      "optical label (%.2f, %.2f) %.3f px, visual (%.2f, %.2f) %.3f px", t,
                      e, sc.kappa_h / DEG, sc.kappa_v / DEG, c[0], c[1], l.pupil_uv[e][0],
                      l.pupil_uv[e][1], err, l0.pupil_uv[e][0], l0.pupil_uv[e][1], vis);
            worst = fmax(worst, err);
            shift_min = fmin(shift_min, shift);
            sum += err;
            n++;
        }
    }
    printf("rendered pupil vs optical-axis label: %d eyes, mean %.3f px, worst %.3f px; "
           "optical vs visual label at least %.2f px apart\n", n, sum / n, worst, shift_min);
    gs_synth_sample_free(&s);
}

/* Kappa per identity through the generator: the same identity has the
 * same kappa in every scene; renders equal for 1 and 2 threads. */
static void test_generator(void)
{
    gs_synth_gen_config c;
    gs_synth_gen_config_default(&c);
    c.identities = 3;
    c.size = 48;
    gs_synth_kappa_literature(&c.kappa);
    double kh[3] = {NAN, NAN, NAN}, kv[3] = {NAN, NAN, NAN};
    int seen = 0;
    gs_pool *pool = gs_pool_create(2);
    CHECK(pool != NULL);
    gs_synth_sample a, b;
    CHECK(gs_synth_sample_alloc(&a, 48, 48, NULL) == GS_OK);
    CHECK(gs_synth_sample_alloc(&b, 48, 48, NULL) == GS_OK);
    for (uint64_t i = 0; i < 12; i++) {
        CHECK(gs_synth_gen_sample(&c, i, NULL, &a, NULL) == GS_OK);
        CHECK(gs_synth_gen_sample(&c, i, pool, &b, NULL) == GS_OK);
        CHECK(memcmp(a.rgb, b.rgb, 3 * 48 * 48) == 0);
        CHECK(memcmp(a.mask, b.mask, GS_SYNTH_MASK_COUNT * 48 * 48) == 0);
        CHECK(memcmp(&a.labels, &b.labels, sizeof a.labels) == 0);
        CHECK(a.labels.has_kappa == 1);
        int k = (int)(a.labels.identity.seed - gs_synth_split_seed(c.split, 0));
        CHECK(k >= 0 && k < 3);
        if (isnan(kh[k])) {
            kh[k] = a.labels.kappa_h;
            kv[k] = a.labels.kappa_v;
            seen++;
        }
        CHECK_MSG(a.labels.kappa_h == kh[k] && a.labels.kappa_v == kv[k],
                  "sample %llu: identity %d's kappa changed", (unsigned long long)i, k);
        double h, v;
        gs_synth_kappa_draw(&c.kappa, a.labels.identity.seed, &h, &v);
        CHECK(h == kh[k] && v == kv[k]);
    }
    CHECK(seen >= 2);
    CHECK(seen < 2 || kh[0] != kh[1] || kh[1] != kh[2]);
    /* Off: no kappa labels and the eyes as before. */
    c.kappa.enabled = 0;
    CHECK(gs_synth_gen_sample(&c, 0, NULL, &a, NULL) == GS_OK);
    CHECK(a.labels.has_kappa == 0);
    char line[65536];
    CHECK(gs_synth_labels_json(&a.labels, "x.png", line, sizeof line) > 0);
    CHECK(strstr(line, "gaze_axis") == NULL && strstr(line, "kappa") == NULL);
    gs_synth_kappa_literature(&c.kappa);
    CHECK(gs_synth_gen_sample(&c, 0, NULL, &a, NULL) == GS_OK);
    CHECK(gs_synth_labels_json(&a.labels, "x.png", line, sizeof line) > 0);
    static const char *const keys[] = {"\"gaze_axis\":\"visual\"", "\"kappa_h_rad\":",
                                       "\"kappa_v_rad\":", "\"gaze_optical_head\":[[",
                                       "\"gaze_optical_cam\":[[", "\"gaze_optical_norm_yaw_rad\":["};
    for (size_t i = 0; i < sizeof keys / sizeof keys[0]; i++)
        CHECK_MSG(strstr(line, keys[i]) != NULL, "labels without %s", keys[i]);
    gs_synth_sample_free(&a);
    gs_synth_sample_free(&b);
    gs_pool_destroy(pool);
}

/* The README a dataset writes gives its configuration back, kappa bits
 * included. */
static void test_readme(void)
{
    char dir[] = "/tmp/gs_kappa_XXXXXX";
    CHECK(mkdtemp(dir) != NULL);
    gs_synth_gen_config c, r;
    gs_synth_gen_config_default(&c);
    c.split = GS_SYNTH_VAL;
    c.identities = 7;
    c.seed = 31;
    c.size = 32;
    c.kappa = (gs_synth_kappa){1, 4.7, 1.3, 1.1, 0.7};
    gs_synth_dataset_opts o = {5, 2, 0, NULL, NULL};
    gs_error err = {0, ""};
    CHECK(gs_synth_dataset_write(dir, &c, &o, NULL, &err) == GS_OK);
    uint64_t first = 0, count = 0;
    CHECK_MSG(gs_synth_dataset_config_read(dir, &r, &first, &count, &err) == GS_OK, "%s",
              err.msg);
    CHECK(first == 5 && count == 2);
    CHECK(r.split == c.split && r.identities == c.identities && r.seed == c.seed &&
          r.size == c.size && r.rig == c.rig && r.supersample == c.supersample);
    CHECK(memcmp(&r.kappa, &c.kappa, sizeof c.kappa) == 0);
    char path[128];
    snprintf(path, sizeof path, "%s/README.md", dir);
    FILE *f = fopen(path, "w");
    CHECK(f != NULL);
    fputs("# Something else\n", f);
    fclose(f);
    CHECK(gs_synth_dataset_config_read(dir, &r, NULL, NULL, &err) == GS_ERR_FORMAT);
    CHECK_MSG(strstr(err.msg, "README.md") != NULL, "message: %s", err.msg);
    unlink(path);
    CHECK(gs_synth_dataset_config_read(dir, &r, NULL, NULL, &err) == GS_ERR_IO);
    snprintf(path, sizeof path, "rm -rf '%s'", dir);
    CHECK(system(path) == 0);
}

int main(void)
{
    test_distribution();
    test_signs();
    test_render();
    test_generator();
    test_readme();
    GS_TEST_END();
}
