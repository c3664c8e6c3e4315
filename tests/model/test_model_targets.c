/* The target table (gazesplat/model.h): each field's limits inclusive
 * (exactly +-limit accepted, a hair beyond refused), NaN and Inf refused,
 * messages naming the field, the value and the range; and the library's
 * own render and fit checks accept every target the table accepts, at
 * every corner of the ranges, built from degrees the way the daemon and
 * the CLI build views. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "gs_test.h"
#include "model_test_util.h"

#define DEG (3.14159265358979323846 / 180.0) /* as the daemon and the CLI */

static void check_refused(gs_target_field f, double v, int code, const char *what)
{
    gs_error err = {0, ""};
    const gs_target_range *r = &gs_target_ranges[f];
    int rc = gs_model_check_range(f, v, &err);
    CHECK_MSG(rc == code, "%s %.17g (%s): got %d, want %d", r->name, v, what, rc, code);
    CHECK_MSG(strstr(err.msg, r->name) != NULL, "message '%s' lacks '%s'", err.msg, r->name);
    if (code == GS_ERR_ARG) {
        char range[64];
        snprintf(range, sizeof range, "[%g, %g] deg (inclusive)", r->lo, r->hi);
        CHECK_MSG(strstr(err.msg, range) != NULL, "message '%s' lacks '%s'", err.msg, range);
    }
}

static void test_table(void)
{
    static const double lim[GS_TARGET_NFIELDS] = {50, 60, 70, 70};
    static const char *const names[GS_TARGET_NFIELDS] = {"gaze pitch", "gaze yaw", "head pitch",
                                                         "head yaw"};
    for (int f = 0; f < GS_TARGET_NFIELDS; f++) {
        const gs_target_range *r = &gs_target_ranges[f];
        CHECK_MSG(!strcmp(r->name, names[f]) && !strcmp(r->unit, "deg"), "row %d: %s", f, r->name);
        CHECK_MSG(r->lo == -lim[f] && r->hi == lim[f], "%s: [%g, %g]", r->name, r->lo, r->hi);
        gs_error err = {0, ""};
        /* Inclusive: both ends and everything between. */
        CHECK_MSG(gs_model_check_range(f, r->hi, &err) == GS_OK, "%s %g: %s", r->name, r->hi,
                  err.msg);
        CHECK_MSG(gs_model_check_range(f, r->lo, &err) == GS_OK, "%s %g: %s", r->name, r->lo,
                  err.msg);
        CHECK(gs_model_check_range(f, 0.0, &err) == GS_OK);
        CHECK(gs_model_check_range(f, nextafter(r->hi, 0), &err) == GS_OK);
        /* Anything beyond, however little. */
        check_refused(f, r->hi + 1e-9, GS_ERR_ARG, "limit + 1e-9");
        check_refused(f, r->lo - 1e-9, GS_ERR_ARG, "-limit - 1e-9");
        check_refused(f, nextafter(r->hi, INFINITY), GS_ERR_ARG, "next double past the limit");
        check_refused(f, 1e30, GS_ERR_ARG, "1e30");
        check_refused(f, -1e30, GS_ERR_ARG, "-1e30");
        check_refused(f, NAN, GS_ERR_NONFINITE, "NaN");
        check_refused(f, INFINITY, GS_ERR_NONFINITE, "+Inf");
        check_refused(f, -INFINITY, GS_ERR_NONFINITE, "-Inf");
    }
    /* A value just past a limit does not print as the limit. */
    gs_error err = {0, ""};
    CHECK(gs_model_check_range(GS_TARGET_HEAD_YAW, 70.000000001, &err) == GS_ERR_ARG);
    CHECK_MSG(strstr(err.msg, "head yaw 70.000000001 deg outside [-70, 70] deg (inclusive)"),
              "'%s'", err.msg);
    CHECK(gs_model_check_range(GS_TARGET_NFIELDS, 0, &err) == GS_ERR_ARG);

    /* A target: each part optional, every field checked. */
    const double g_ok[2] = {50, -60}, h_ok[2] = {-70, 70};
    const double g_bad[2] = {0, 60.5}, h_bad[2] = {0, -70.000001};
    CHECK(gs_model_check_target(NULL, NULL, &err) == GS_OK);
    CHECK(gs_model_check_target(g_ok, NULL, &err) == GS_OK);
    CHECK(gs_model_check_target(NULL, h_ok, &err) == GS_OK);
    CHECK(gs_model_check_target(g_ok, h_ok, &err) == GS_OK);
    CHECK(gs_model_check_target(g_bad, h_ok, &err) == GS_ERR_ARG && strstr(err.msg, "gaze yaw"));
    CHECK(gs_model_check_target(g_ok, h_bad, &err) == GS_ERR_ARG && strstr(err.msg, "head yaw"));
    const double h_nan[2] = {NAN, 0};
    CHECK(gs_model_check_target(g_ok, h_nan, &err) == GS_ERR_NONFINITE &&
          strstr(err.msg, "head pitch"));
    /* The radian forms are the same limits. */
    CHECK_CLOSE(GS_MODEL_MAX_GAZE_PITCH, 50 * DEG, 1e-15, 0);
    CHECK_CLOSE(GS_MODEL_MAX_GAZE_YAW, 60 * DEG, 1e-15, 0);
    CHECK_CLOSE(GS_MODEL_MAX_HEAD_ANGLE, 70 * DEG, 1e-15, 0);
}

/* Renders and fits at every corner of the ranges: what the table accepts
 * (no slack), the library accepts (its own checks re-derive the angles
 * from radians and a rotation). */
static void test_library_agrees(void)
{
    gs_model *m = tiny_model(1, 5);
    CHECK(m != NULL);
    if (!m)
        return;
    gs_model_ctx *c = gs_model_ctx_create(m);
    CHECK(c != NULL);
    gs_subject s = frame_subject(m);
    int S = m->cfg.image_size;
    uint8_t *rgb = malloc((size_t)3 * S * S);
    CHECK(rgb != NULL);
    gs_error err = {0, ""};
    static const double sg[4][2] = {{1, 1}, {1, -1}, {-1, 1}, {-1, -1}};
    int bad = 0;
    for (int gi = 0; gi < 4; gi++)
        for (int hi = 0; hi < 5; hi++) {
            double g[2] = {sg[gi][0] * GS_MODEL_MAX_GAZE_PITCH_DEG,
                           sg[gi][1] * GS_MODEL_MAX_GAZE_YAW_DEG};
            double h[2] = {hi < 4 ? sg[hi][0] * GS_MODEL_MAX_HEAD_PITCH_DEG : 0,
                           hi < 4 ? sg[hi][1] * GS_MODEL_MAX_HEAD_YAW_DEG : 0};
            CHECK(gs_model_check_target(g, h, &err) == GS_OK);
            gs_view v;
            memset(&v, 0, sizeof v);
            v.gaze_pitch = g[0] * DEG;
            v.gaze_yaw = g[1] * DEG;
            v.use_head = hi < 4;
            gs_geom_rot_from_pitchyaw(h[0] * DEG, h[1] * DEG, 0, v.head_R);
            memcpy(v.head_t, s.head_t, sizeof v.head_t);
            int rc = gs_model_render(c, NULL, &s, &v, rgb, (size_t)3 * S, &err);
            CHECK_MSG(rc == GS_OK, "render gaze (%g, %g) head (%g, %g): %s", g[0], g[1], h[0],
                      h[1], err.msg);
            bad += rc != GS_OK;
        }
    CHECK_MSG(bad == 0, "%d of 20 corners refused by the renderer", bad);
    /* Just past a limit, the renderer refuses too, naming the field. */
    gs_view v;
    memset(&v, 0, sizeof v);
    v.use_head = 1;
    gs_geom_rot_from_pitchyaw(70.001 * DEG, 0, 0, v.head_R);
    memcpy(v.head_t, s.head_t, sizeof v.head_t);
    CHECK(gs_model_render(c, NULL, &s, &v, rgb, (size_t)3 * S, &err) == GS_ERR_ARG);
    CHECK_MSG(strstr(err.msg, "head pitch 70.001") && strstr(err.msg, "[-70, 70]"), "'%s'",
              err.msg);
    v.use_head = 0;
    v.gaze_yaw = -60.001 * DEG;
    CHECK(gs_model_render(c, NULL, &s, &v, rgb, (size_t)3 * S, &err) == GS_ERR_ARG);
    CHECK_MSG(strstr(err.msg, "gaze yaw -60.001"), "'%s'", err.msg);
    v.gaze_yaw = NAN;
    CHECK(gs_model_render(c, NULL, &s, &v, rgb, (size_t)3 * S, &err) == GS_ERR_NONFINITE);

    /* The fit's known labels at the limits: accepted. */
    memset(rgb, 128, (size_t)3 * S * S);
    gs_fit_options fo;
    gs_fit_options_default(&fo);
    fo.max_iters = 1;
    fo.known_gaze = 1;
    fo.gaze_pitch = -50 * DEG;
    fo.gaze_yaw = 60 * DEG;
    fo.known_head = 1;
    gs_geom_rot_from_pitchyaw(70 * DEG, -70 * DEG, 0, fo.head_R);
    memcpy(fo.head_t, s.head_t, sizeof fo.head_t);
    gs_subject out;
    int rc = gs_model_fit(c, NULL, rgb, (size_t)3 * S, &fo, &out, NULL, &err);
    CHECK_MSG(rc == GS_OK, "fit with labels at the limits: %s", err.msg);
    fo.gaze_pitch = -50.0001 * DEG;
    CHECK(gs_model_fit(c, NULL, rgb, (size_t)3 * S, &fo, &out, NULL, &err) == GS_ERR_ARG);
    CHECK_MSG(strstr(err.msg, "gaze pitch"), "'%s'", err.msg);
    free(rgb);
    gs_model_ctx_destroy(c);
    gs_model_destroy(m);
}

int main(void)
{
    test_table();
    test_library_agrees();
    GS_TEST_END();
}
