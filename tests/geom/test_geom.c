/* Label maths: angle conventions, rotations and normalization invariants. */
#include "gazesplat/geom.h"
#include "gs_test.h"

#include <stdint.h>
#include <string.h>

static const double PI = 3.14159265358979323846;

/* Small deterministic generator for test inputs (splitmix64). */
static uint64_t rng_state = 0x1234abcdULL;
static double urand(double lo, double hi)
{
    uint64_t z = (rng_state += 0x9e3779b97f4a7c15ULL);
    z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ULL;
    z = (z ^ (z >> 27)) * 0x94d049bb133111ebULL;
    z ^= z >> 31;
    return lo + (hi - lo) * (double)(z >> 11) * 0x1.0p-53;
}

static double max_abs_diff(const double *a, const double *b, int n)
{
    double m = 0.0;
    for (int i = 0; i < n; i++)
        m = fmax(m, fabs(a[i] - b[i]));
    return m;
}

static void check_rotation(const double r[9], const char *what)
{
    double rt[9], p[9], id[9];
    gs_geom_mat3_transpose(r, rt);
    gs_geom_mat3_mul(rt, r, p);
    gs_geom_mat3_identity(id);
    double det = r[0] * (r[4] * r[8] - r[5] * r[7]) -
                 r[1] * (r[3] * r[8] - r[5] * r[6]) +
                 r[2] * (r[3] * r[7] - r[4] * r[6]);
    CHECK_MSG(max_abs_diff(p, id, 9) < 1e-12 && fabs(det - 1.0) < 1e-12,
              "%s not a rotation: |R^T R - I| = %.3g, det = %.15g", what,
              max_abs_diff(p, id, 9), det);
}

static void test_signs(void)
{
    double p, y, g[3];
    /* Straight at the camera. */
    double at_cam[3] = {0, 0, -1};
    CHECK(gs_geom_vec_to_pitchyaw(at_cam, &p, &y) == GS_OK);
    CHECK_CLOSE(p, 0.0, 1e-15, 0);
    CHECK_CLOSE(y, 0.0, 1e-15, 0);
    /* Up in the image is -y in the camera frame: pitch > 0. */
    double up[3] = {0, -0.5, -1};
    gs_geom_vec_to_pitchyaw(up, &p, &y);
    CHECK_MSG(p > 0.1 && fabs(y) < 1e-15, "up: pitch %g yaw %g", p, y);
    /* Toward image-left is -x: yaw > 0. */
    double left[3] = {-0.5, 0, -1};
    gs_geom_vec_to_pitchyaw(left, &p, &y);
    CHECK_MSG(y > 0.1 && fabs(p) < 1e-15, "left: pitch %g yaw %g", p, y);
    /* And the inverse agrees. */
    gs_geom_pitchyaw_to_vec(0.3, 0.0, g);
    CHECK(g[1] < 0 && g[2] < 0);
    gs_geom_pitchyaw_to_vec(0.0, 0.3, g);
    CHECK(g[0] < 0 && g[2] < 0);
    /* A head turned toward image-left has yaw > 0: its forward direction
     * -z points to -x. */
    double r[9];
    gs_geom_rot_from_pitchyaw(0.0, 0.4, 0.0, r);
    CHECK_MSG(-r[2] < 0.0, "head yaw 0.4: forward x = %g", -r[2]);
    gs_geom_rot_from_pitchyaw(0.4, 0.0, 0.0, r);
    CHECK_MSG(-r[5] < 0.0, "head pitch 0.4: forward y = %g (up is -y)",
              -r[5]);
    double zero[3] = {0, 0, 0};
    CHECK(gs_geom_vec_to_pitchyaw(zero, &p, &y) == GS_ERR_ARG);
}

static void test_pitchyaw_roundtrip(void)
{
    double worst = 0.0;
    for (int i = 0; i < 2000; i++) {
        double p = urand(-1.55, 1.55), y = urand(-3.1, 3.1), g[3], p2, y2;
        gs_geom_pitchyaw_to_vec(p, y, g);
        CHECK_CLOSE(gs_geom_vec3_norm(g), 1.0, 1e-14, 0);
        gs_geom_vec_to_pitchyaw(g, &p2, &y2);
        worst = fmax(worst, fmax(fabs(p - p2), fabs(y - y2)));
        /* Scaling the vector changes nothing. */
        double g3[3] = {3 * g[0], 3 * g[1], 3 * g[2]};
        gs_geom_vec_to_pitchyaw(g3, &p2, &y2);
        worst = fmax(worst, fmax(fabs(p - p2), fabs(y - y2)));
    }
    CHECK_MSG(worst < 1e-12, "pitch/yaw round trip: max error %.3g", worst);
}

static void test_rotations(void)
{
    double worst_angles = 0.0, worst_eye = 0.0, worst_rod = 0.0;
    for (int i = 0; i < 1000; i++) {
        double p = urand(-1.5, 1.5), y = urand(-3.1, 3.1),
               roll = urand(-3.1, 3.1), r[9], p2, y2;
        gs_geom_rot_from_pitchyaw(p, y, roll, r);
        check_rotation(r, "rot_from_pitchyaw");
        gs_geom_head_pitchyaw(r, &p2, &y2);
        double roll2 = gs_geom_head_roll(r);
        worst_angles = fmax(worst_angles, fmax(fabs(p - p2), fabs(y - y2)));
        worst_angles = fmax(worst_angles, fabs(roll - roll2));
        /* The same matrix turns the rest axis -z into the gaze (p, y). */
        double minus_z[3] = {0, 0, -1}, g[3], g2[3];
        gs_geom_mat3_vec(r, minus_z, g);
        gs_geom_pitchyaw_to_vec(p, y, g2);
        worst_eye = fmax(worst_eye, max_abs_diff(g, g2, 3));
        /* Rodrigues round trip. */
        double rv[3], r2[9];
        gs_geom_rot_to_rodrigues(r, rv);
        gs_geom_rodrigues(rv, r2);
        worst_rod = fmax(worst_rod, max_abs_diff(r, r2, 9));
    }
    CHECK_MSG(worst_angles < 1e-12, "head angle round trip: %.3g",
              worst_angles);
    CHECK_MSG(worst_eye < 1e-14, "eye rotation vs gaze vector: %.3g",
              worst_eye);
    CHECK_MSG(worst_rod < 1e-12, "Rodrigues round trip: %.3g", worst_rod);
    /* Hard cases for Rodrigues: tiny, zero and near-pi angles. */
    const double cases[][3] = {{0, 0, 0},       {1e-9, -2e-9, 3e-10},
                               {PI, 0, 0},      {0, PI - 1e-9, 0},
                               {1.8, -1.8, 1.8}, {0, 0, -PI + 1e-7}};
    for (size_t i = 0; i < sizeof cases / sizeof cases[0]; i++) {
        double r[9], rv[3], r2[9];
        gs_geom_rodrigues(cases[i], r);
        check_rotation(r, "rodrigues");
        gs_geom_rot_to_rodrigues(r, rv);
        gs_geom_rodrigues(rv, r2);
        CHECK_MSG(max_abs_diff(r, r2, 9) < 1e-9,
                  "Rodrigues case %zu: matrix diff %.3g", i,
                  max_abs_diff(r, r2, 9));
    }
    /* rot_x etc. are right-handed: Rz(90 deg) maps x to y. */
    double rz[9], ex[3] = {1, 0, 0}, out[3];
    gs_geom_rot_z(PI / 2, rz);
    gs_geom_mat3_vec(rz, ex, out);
    CHECK_CLOSE(out[1], 1.0, 1e-15, 0);
}

static void random_setup(double k[9], double c[3], double hr[9])
{
    double kk[9] = {urand(800, 4000), 0, urand(200, 800), 0, 0, urand(200, 800),
                    0, 0, 1};
    kk[4] = kk[0] * urand(0.98, 1.02);
    memcpy(k, kk, sizeof kk);
    c[0] = urand(-200, 200);
    c[1] = urand(-150, 150);
    c[2] = urand(300, 1500);
    gs_geom_rot_from_pitchyaw(urand(-0.7, 0.7), urand(-1.0, 1.0),
                              urand(-0.3, 0.3), hr);
}

static void test_normalization(void)
{
    double worst_origin = 0, worst_centre = 0, worst_vec = 0, worst_rot = 0,
           worst_pix = 0, worst_cam = 0, worst_head = 0;
    for (int it = 0; it < 500; it++) {
        double k[9], c[3], hr[9];
        random_setup(k, c, hr);
        int size = it % 2 ? 512 : 224;
        gs_geom_norm n;
        gs_error err;
        int rc = gs_geom_normalize(k, c, hr, GS_GEOM_NORM_DISTANCE_MM,
                                   gs_geom_norm_focal(size), size, size, &n,
                                   &err);
        CHECK_MSG(rc == GS_OK, "normalize failed: %s", err.msg);
        if (rc != GS_OK)
            continue;
        check_rotation(n.R, "normalization R");
        /* A target at the camera origin gives (0, 0). */
        double origin[3] = {0, 0, 0}, g[3], gn[3], p, y;
        gs_geom_gaze_from_target(c, origin, g);
        gs_geom_norm_vec(&n, g, gn);
        gs_geom_vec_to_pitchyaw(gn, &p, &y);
        worst_origin = fmax(worst_origin, fmax(fabs(p), fabs(y)));
        /* The face centre maps to the image centre. */
        double uv[2], uvn[2];
        gs_geom_project(k, c, uv);
        gs_geom_norm_pixel(&n, uv, uvn);
        worst_centre = fmax(worst_centre, fmax(fabs(uvn[0] - 0.5 * size),
                                               fabs(uvn[1] - 0.5 * size)));
        /* Round trips: vectors, rotations, pixels. */
        double v[3] = {urand(-1, 1), urand(-1, 1), urand(-1, 1)}, vn[3], v2[3];
        gs_geom_norm_vec(&n, v, vn);
        gs_geom_denorm_vec(&n, vn, v2);
        worst_vec = fmax(worst_vec, max_abs_diff(v, v2, 3));
        double hrn[9], hr2[9];
        gs_geom_norm_rot(&n, hr, hrn);
        gs_geom_denorm_rot(&n, hrn, hr2);
        worst_rot = fmax(worst_rot, max_abs_diff(hr, hr2, 9));
        double q[2] = {urand(0, 1000), urand(0, 1000)}, qn[2], q2[2];
        gs_geom_norm_pixel(&n, q, qn);
        gs_geom_denorm_pixel(&n, qn, q2);
        worst_pix = fmax(worst_pix, max_abs_diff(q, q2, 2));
        /* The normalized pinhole camera reproduces W exactly. */
        double ke[9], rc_[9], x[3] = {c[0] + urand(-100, 100),
                                      c[1] + urand(-100, 100),
                                      c[2] + urand(-100, 100)};
        double xr[3], a[2], b[2];
        gs_geom_norm_camera(&n, ke, rc_);
        gs_geom_project(k, x, uv);
        gs_geom_norm_pixel(&n, uv, a);
        gs_geom_mat3_vec(rc_, x, xr);
        gs_geom_project(ke, xr, b);
        worst_cam = fmax(worst_cam, max_abs_diff(a, b, 2));
        /* Normalized head x-axis has no vertical part (roll removed). */
        CHECK_MSG(fabs(hrn[3]) < 1e-12, "normalized head x_y = %g", hrn[3]);
        /* A head facing along the line of sight normalizes to (0, 0). */
        double fwd[3] = {c[0], c[1], c[2]}, hf[9];
        gs_geom_vec3_normalize(fwd);
        double py, yy;
        gs_geom_vec_to_pitchyaw((double[3]){-fwd[0], -fwd[1], -fwd[2]}, &py,
                                &yy);
        /* head z = fwd  <=>  head forward -z = -fwd has gaze angles (py, yy) */
        gs_geom_rot_from_pitchyaw(py, yy, urand(-0.3, 0.3), hf);
        gs_geom_normalize(k, c, hf, 680, 1600, 512, 512, &n, NULL);
        gs_geom_norm_rot(&n, hf, hrn);
        gs_geom_head_pitchyaw(hrn, &p, &y);
        worst_head = fmax(worst_head, fmax(fabs(p), fabs(y)));
    }
    CHECK_MSG(worst_origin < 1e-12, "target at camera origin: %.3g rad",
              worst_origin);
    CHECK_MSG(worst_centre < 1e-8, "face centre vs image centre: %.3g px",
              worst_centre);
    CHECK_MSG(worst_vec < 1e-14, "vector round trip %.3g", worst_vec);
    CHECK_MSG(worst_rot < 1e-14, "rotation round trip %.3g", worst_rot);
    CHECK_MSG(worst_pix < 1e-8, "pixel round trip %.3g px", worst_pix);
    CHECK_MSG(worst_cam < 1e-8, "normalized camera vs warp %.3g px",
              worst_cam);
    CHECK_MSG(worst_head < 1e-12, "head facing the camera: %.3g rad",
              worst_head);
    /* Frontal case: identity head at (0, 0, 600) gives R = I, S = 680/600. */
    double k[9] = {1000, 0, 320, 0, 1000, 240, 0, 0, 1}, c[3] = {0, 0, 600},
           id[9];
    gs_geom_mat3_identity(id);
    gs_geom_norm n;
    CHECK(gs_geom_normalize(k, c, id, 680, 1600, 512, 512, &n, NULL) == 0);
    CHECK(max_abs_diff(n.R, id, 9) < 1e-15);
    CHECK_CLOSE(n.S[2], 680.0 / 600.0, 1e-15, 0);
}

static void test_errors(void)
{
    double k[9] = {1000, 0, 320, 0, 1000, 240, 0, 0, 1}, id[9];
    gs_geom_mat3_identity(id);
    gs_geom_norm n;
    gs_error err;
    double behind[3] = {0, 0, -500};
    CHECK_EQ_INT(gs_geom_normalize(k, behind, id, 680, 1600, 64, 64, &n, &err),
                 GS_ERR_ARG);
    CHECK(strstr(err.msg, "front") != NULL);
    double nan_c[3] = {0, NAN, 500};
    CHECK_EQ_INT(gs_geom_normalize(k, nan_c, id, 680, 1600, 64, 64, &n, &err),
                 GS_ERR_NONFINITE);
    /* Head x-axis along the line of sight (a head turned by 90 degrees). */
    double c[3] = {0, 0, 500}, side[9];
    gs_geom_rot_y(-PI / 2, side);
    CHECK_EQ_INT(gs_geom_normalize(k, c, side, 680, 1600, 64, 64, &n, &err),
                 GS_ERR_ARG);
    CHECK_EQ_INT(gs_geom_normalize(k, c, id, 680, 0, 64, 64, &n, &err),
                 GS_ERR_ARG);
    double singular[9] = {0};
    CHECK_EQ_INT(gs_geom_normalize(singular, c, id, 680, 1600, 64, 64, &n, &err),
                 GS_ERR_ARG);
}

static void test_face_model(void)
{
    double m[6][3], c[3];
    gs_geom_face_model6(m);
    gs_geom_face_centre6(m, c);
    CHECK_CLOSE(c[0], -0.02, 0.005, 0);
    CHECK_CLOSE(c[1], -10.29, 0.005, 0);
    CHECK_CLOSE(c[2], 27.28, 0.005, 0);
    /* Projection round trip through unproject. */
    double k[9] = {900, 0, 310, 0, 905, 250, 0, 0, 1}, x[3] = {30, -20, 640},
           uv[2], d[3];
    CHECK(gs_geom_project(k, x, uv) == GS_OK);
    gs_geom_unproject(k, uv, d);
    double xn[3] = {x[0], x[1], x[2]};
    gs_geom_vec3_normalize(xn);
    CHECK(max_abs_diff(d, xn, 3) < 1e-14);
    double behind[3] = {0, 0, -1};
    CHECK(gs_geom_project(k, behind, uv) == GS_ERR_ARG);
    CHECK_CLOSE(gs_geom_vec3_angle((double[3]){1, 0, 0},
                                   (double[3]){1, 1e-9, 0}), 1e-9, 1e-20,
                1e-6);
}

int main(void)
{
    test_signs();
    test_pitchyaw_roundtrip();
    test_rotations();
    test_normalization();
    test_errors();
    test_face_model();
    GS_TEST_END();
}
