/* Rotations, gaze/head angles and gaze normalization; conventions in
 * gazesplat/geom.h. */
#include "gazesplat/geom.h"

#include <math.h>
#include <string.h>

/* ---- 3x3 algebra ---- */

void gs_geom_mat3_identity(double out[9])
{
    static const double id[9] = {1, 0, 0, 0, 1, 0, 0, 0, 1};
    memcpy(out, id, sizeof id);
}

void gs_geom_mat3_mul(const double a[9], const double b[9], double out[9])
{
    double r[9];
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++)
            r[3 * i + j] = a[3 * i] * b[j] + a[3 * i + 1] * b[3 + j] +
                           a[3 * i + 2] * b[6 + j];
    memcpy(out, r, sizeof r);
}

void gs_geom_mat3_transpose(const double a[9], double out[9])
{
    double r[9];
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++)
            r[3 * j + i] = a[3 * i + j];
    memcpy(out, r, sizeof r);
}

void gs_geom_mat3_vec(const double m[9], const double v[3], double out[3])
{
    double r[3];
    for (int i = 0; i < 3; i++)
        r[i] = m[3 * i] * v[0] + m[3 * i + 1] * v[1] + m[3 * i + 2] * v[2];
    memcpy(out, r, sizeof r);
}

void gs_geom_mat3_tvec(const double m[9], const double v[3], double out[3])
{
    double r[3];
    for (int i = 0; i < 3; i++)
        r[i] = m[i] * v[0] + m[3 + i] * v[1] + m[6 + i] * v[2];
    memcpy(out, r, sizeof r);
}

int gs_geom_mat3_inverse(const double m[9], double out[9])
{
    double c[9];
    c[0] = m[4] * m[8] - m[5] * m[7];
    c[1] = m[2] * m[7] - m[1] * m[8];
    c[2] = m[1] * m[5] - m[2] * m[4];
    c[3] = m[5] * m[6] - m[3] * m[8];
    c[4] = m[0] * m[8] - m[2] * m[6];
    c[5] = m[2] * m[3] - m[0] * m[5];
    c[6] = m[3] * m[7] - m[4] * m[6];
    c[7] = m[1] * m[6] - m[0] * m[7];
    c[8] = m[0] * m[4] - m[1] * m[3];
    double det = m[0] * c[0] + m[1] * c[3] + m[2] * c[6];
    double scale = 0.0;
    for (int i = 0; i < 9; i++)
        scale = fmax(scale, fabs(m[i]));
    if (!isfinite(det) || fabs(det) <= 1e-300 ||
        fabs(det) <= 1e-14 * scale * scale * scale)
        return GS_ERR_ARG;
    for (int i = 0; i < 9; i++)
        out[i] = c[i] / det;
    return GS_OK;
}

double gs_geom_vec3_dot(const double a[3], const double b[3])
{
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
}

void gs_geom_vec3_cross(const double a[3], const double b[3], double out[3])
{
    double r[3] = {a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2],
                   a[0] * b[1] - a[1] * b[0]};
    memcpy(out, r, sizeof r);
}

double gs_geom_vec3_norm(const double a[3])
{
    return sqrt(gs_geom_vec3_dot(a, a));
}

int gs_geom_vec3_normalize(double a[3])
{
    double n = gs_geom_vec3_norm(a);
    if (!(n > 0.0) || !isfinite(n))
        return GS_ERR_ARG;
    a[0] /= n;
    a[1] /= n;
    a[2] /= n;
    return GS_OK;
}

double gs_geom_vec3_angle(const double a[3], const double b[3])
{
    /* atan2(|a x b|, a.b) keeps full precision for tiny angles, where
     * acos of a dot product loses half the digits. */
    double c[3];
    gs_geom_vec3_cross(a, b, c);
    return atan2(gs_geom_vec3_norm(c), gs_geom_vec3_dot(a, b));
}

/* ---- rotations ---- */

void gs_geom_rot_x(double angle, double out[9])
{
    double c = cos(angle), s = sin(angle);
    double r[9] = {1, 0, 0, 0, c, -s, 0, s, c};
    memcpy(out, r, sizeof r);
}

void gs_geom_rot_y(double angle, double out[9])
{
    double c = cos(angle), s = sin(angle);
    double r[9] = {c, 0, s, 0, 1, 0, -s, 0, c};
    memcpy(out, r, sizeof r);
}

void gs_geom_rot_z(double angle, double out[9])
{
    double c = cos(angle), s = sin(angle);
    double r[9] = {c, -s, 0, s, c, 0, 0, 0, 1};
    memcpy(out, r, sizeof r);
}

void gs_geom_rodrigues(const double rvec[3], double out[9])
{
    double theta = gs_geom_vec3_norm(rvec);
    if (theta < 1e-12) {
        /* First order: I + [r]x, exact to rounding at this size. */
        double r[9] = {1, -rvec[2], rvec[1], rvec[2], 1, -rvec[0],
                       -rvec[1], rvec[0], 1};
        memcpy(out, r, sizeof r);
        return;
    }
    double k[3] = {rvec[0] / theta, rvec[1] / theta, rvec[2] / theta};
    double c = cos(theta), s = sin(theta), v = 1.0 - c;
    double r[9] = {
        c + k[0] * k[0] * v,        k[0] * k[1] * v - k[2] * s,
        k[0] * k[2] * v + k[1] * s, k[1] * k[0] * v + k[2] * s,
        c + k[1] * k[1] * v,        k[1] * k[2] * v - k[0] * s,
        k[2] * k[0] * v - k[1] * s, k[2] * k[1] * v + k[0] * s,
        c + k[2] * k[2] * v};
    memcpy(out, r, sizeof r);
}

void gs_geom_rot_to_rodrigues(const double r[9], double rvec[3])
{
    double w[3] = {r[7] - r[5], r[2] - r[6], r[3] - r[1]}; /* 2 sin(t) k */
    double s2 = gs_geom_vec3_norm(w);
    double c = fmin(1.0, fmax(-1.0, 0.5 * (r[0] + r[4] + r[8] - 1.0)));
    double theta = atan2(0.5 * s2, c);
    if (s2 > 1e-6) {
        for (int i = 0; i < 3; i++)
            rvec[i] = w[i] / s2 * theta;
        return;
    }
    if (c > 0.0) { /* near identity: theta ~ s2/2, rvec ~ w/2 */
        for (int i = 0; i < 3; i++)
            rvec[i] = 0.5 * w[i];
        return;
    }
    /* Near pi: R + I = 2 k k^T (+ O(sin)); take the largest column. */
    int j = 0;
    for (int i = 1; i < 3; i++)
        if (r[4 * i] > r[4 * j])
            j = i;
    double k[3];
    for (int i = 0; i < 3; i++)
        k[i] = r[3 * i + j] + (i == j ? 1.0 : 0.0);
    gs_geom_vec3_normalize(k);
    /* Pick the sign that agrees with the small antisymmetric part. */
    if (gs_geom_vec3_dot(k, w) < 0.0)
        for (int i = 0; i < 3; i++)
            k[i] = -k[i];
    for (int i = 0; i < 3; i++)
        rvec[i] = k[i] * theta;
}

void gs_geom_rot_from_pitchyaw(double pitch, double yaw, double roll,
                               double out[9])
{
    double ry[9], rx[9], rz[9];
    gs_geom_rot_y(yaw, ry);
    gs_geom_rot_x(-pitch, rx);
    gs_geom_rot_z(roll, rz);
    gs_geom_mat3_mul(ry, rx, out);
    gs_geom_mat3_mul(out, rz, out);
}

void gs_geom_head_pitchyaw(const double r[9], double *pitch, double *yaw)
{
    double zy = fmin(1.0, fmax(-1.0, r[5]));
    *pitch = asin(zy);
    *yaw = atan2(r[2], r[8]);
}

double gs_geom_head_roll(const double r[9])
{
    /* R = Ry Rx Rz: (Ry Rx)^T R = Rz(roll). */
    double p, y, a[9], rz[9];
    gs_geom_head_pitchyaw(r, &p, &y);
    gs_geom_rot_from_pitchyaw(p, y, 0.0, a);
    gs_geom_mat3_transpose(a, a);
    gs_geom_mat3_mul(a, r, rz);
    return atan2(rz[3], rz[0]);
}

/* ---- gaze vectors ---- */

void gs_geom_pitchyaw_to_vec(double pitch, double yaw, double g[3])
{
    g[0] = -cos(pitch) * sin(yaw);
    g[1] = -sin(pitch);
    g[2] = -cos(pitch) * cos(yaw);
}

int gs_geom_vec_to_pitchyaw(const double g[3], double *pitch, double *yaw)
{
    double u[3] = {g[0], g[1], g[2]};
    if (gs_geom_vec3_normalize(u) != GS_OK)
        return GS_ERR_ARG;
    *pitch = asin(fmin(1.0, fmax(-1.0, -u[1])));
    *yaw = atan2(-u[0], -u[2]);
    return GS_OK;
}

int gs_geom_gaze_from_target(const double origin[3], const double target[3],
                             double g[3])
{
    for (int i = 0; i < 3; i++)
        g[i] = target[i] - origin[i];
    return gs_geom_vec3_normalize(g);
}

/* ---- face model ---- */

void gs_geom_face_model6(double out[6][3])
{
    static const double m[6][3] = {
        {-46.5095, -38.3271, 36.4160}, {-17.7607, -32.5852, 29.0762},
        {18.0439, -30.9568, 29.0630},  {44.7376, -34.1079, 36.7324},
        {-10.6117, 12.9583, 21.6228},  {11.2896, 13.8642, 21.8379}};
    memcpy(out, m, sizeof m);
}

/* Generated by `gazesplat synth --face-model6` (the mean synthetic head's
 * landmarks, rounded to 0.1 um); checked against the template by
 * tests/synth/test_synth_face_model.c. */
void gs_geom_face_model6_synth(double out[6][3])
{
    static const double m[6][3] = {
        {-43.3210, -24.2805, 15.0246}, {-19.6790, -21.7195, 9.1300},
        {19.6790, -21.7195, 9.1300},   {43.3210, -24.2805, 15.0246},
        {-10.2000, 23.0000, -12.0773}, {10.2000, 23.0000, -12.0773}};
    memcpy(out, m, sizeof m);
}

/* Generated with the six above by `gazesplat synth --face-model6`. */
void gs_geom_face_nose7_synth(double out[7][3])
{
    static const double m[7][3] = {
        {0.0000, -25.0000, -12.8236}, {0.0000, -11.6667, -17.1458}, {0.0000, 1.6667, -23.0248},
        {0.0000, 15.0000, -28.0987},  {-5.1000, 23.7500, -8.4015},  {0.0000, 24.5000, -10.1554},
        {5.1000, 23.7500, -8.4015}};
    memcpy(out, m, sizeof m);
}

void gs_geom_face_centre6(const double pts[6][3], double centre[3])
{
    for (int i = 0; i < 3; i++) {
        double eyes = 0.25 * (pts[0][i] + pts[1][i] + pts[2][i] + pts[3][i]);
        double nose = 0.5 * (pts[4][i] + pts[5][i]);
        centre[i] = 0.5 * (eyes + nose);
    }
}

/* ---- projection ---- */

int gs_geom_project(const double k[9], const double x[3], double uv[2])
{
    if (!(x[2] > 0.0))
        return GS_ERR_ARG;
    uv[0] = k[0] * x[0] / x[2] + k[1] * x[1] / x[2] + k[2];
    uv[1] = k[4] * x[1] / x[2] + k[5];
    return GS_OK;
}

void gs_geom_unproject(const double k[9], const double uv[2], double dir[3])
{
    double y = (uv[1] - k[5]) / k[4];
    double x = (uv[0] - k[2] - k[1] * y) / k[0];
    dir[0] = x;
    dir[1] = y;
    dir[2] = 1.0;
    gs_geom_vec3_normalize(dir);
}

/* ---- normalization ---- */

double gs_geom_norm_focal(int size)
{
    return GS_GEOM_NORM_FOCAL_512 * size / 512.0;
}

static int all_finite(const double *v, int n)
{
    for (int i = 0; i < n; i++)
        if (!isfinite(v[i]))
            return 0;
    return 1;
}

int gs_geom_normalize(const double k[9], const double c[3],
                      const double head_r[9], double d_n_mm, double f_n,
                      int width, int height, gs_geom_norm *out,
                      gs_error *err)
{
    if (!all_finite(k, 9) || !all_finite(c, 3) || !all_finite(head_r, 9) ||
        !isfinite(d_n_mm) || !isfinite(f_n))
        return gs_error_set(err, GS_ERR_NONFINITE,
                            "normalize: non-finite input");
    if (!(c[2] > 0.0))
        return gs_error_set(err, GS_ERR_ARG,
                            "normalize: face centre z = %g is not in front "
                            "of the camera", c[2]);
    if (!(d_n_mm > 0.0) || !(f_n > 0.0) || width < 1 || height < 1)
        return gs_error_set(err, GS_ERR_ARG,
                            "normalize: need d_n > 0, f_n > 0, size >= 1 "
                            "(got %g, %g, %dx%d)", d_n_mm, f_n, width,
                            height);
    memset(out, 0, sizeof *out);
    double fwd[3] = {c[0], c[1], c[2]}, hx[3] = {head_r[0], head_r[3],
                                                  head_r[6]};
    out->distance_mm = gs_geom_vec3_norm(c);
    gs_geom_vec3_normalize(fwd);
    double down[3], right[3];
    gs_geom_vec3_cross(fwd, hx, down);
    if (gs_geom_vec3_norm(down) < 1e-9 ||
        gs_geom_vec3_normalize(down) != GS_OK)
        return gs_error_set(err, GS_ERR_ARG,
                            "normalize: head x-axis parallel to the line of "
                            "sight");
    gs_geom_vec3_cross(down, fwd, right);
    gs_geom_vec3_normalize(right);
    for (int i = 0; i < 3; i++) {
        out->R[i] = right[i];
        out->R[3 + i] = down[i];
        out->R[6 + i] = fwd[i];
    }
    out->S[0] = 1.0;
    out->S[1] = 1.0;
    out->S[2] = d_n_mm / out->distance_mm;
    double kn[9] = {f_n, 0, 0.5 * width, 0, f_n, 0.5 * height, 0, 0, 1};
    memcpy(out->K_n, kn, sizeof kn);
    double kinv[9], sr[9];
    if (gs_geom_mat3_inverse(k, kinv) != GS_OK)
        return gs_error_set(err, GS_ERR_ARG, "normalize: singular K");
    memcpy(sr, out->R, sizeof sr);
    for (int j = 0; j < 3; j++)
        sr[6 + j] *= out->S[2];
    gs_geom_mat3_mul(kn, sr, out->W);
    gs_geom_mat3_mul(out->W, kinv, out->W);
    if (gs_geom_mat3_inverse(out->W, out->W_inv) != GS_OK)
        return gs_error_set(err, GS_ERR_ARG, "normalize: singular warp");
    out->d_n_mm = d_n_mm;
    out->f_n = f_n;
    out->width = width;
    out->height = height;
    return GS_OK;
}

void gs_geom_norm_vec(const gs_geom_norm *n, const double v[3],
                      double v_n[3])
{
    gs_geom_mat3_vec(n->R, v, v_n);
}

void gs_geom_denorm_vec(const gs_geom_norm *n, const double v_n[3],
                        double v[3])
{
    gs_geom_mat3_tvec(n->R, v_n, v);
}

void gs_geom_norm_rot(const gs_geom_norm *n, const double head_r[9],
                      double head_r_n[9])
{
    gs_geom_mat3_mul(n->R, head_r, head_r_n);
}

void gs_geom_denorm_rot(const gs_geom_norm *n, const double head_r_n[9],
                        double head_r[9])
{
    double rt[9];
    gs_geom_mat3_transpose(n->R, rt);
    gs_geom_mat3_mul(rt, head_r_n, head_r);
}

static void apply_homography(const double h[9], const double uv[2],
                             double out[2])
{
    double p[3] = {uv[0], uv[1], 1.0};
    gs_geom_mat3_vec(h, p, p);
    out[0] = p[0] / p[2];
    out[1] = p[1] / p[2];
}

void gs_geom_norm_pixel(const gs_geom_norm *n, const double uv[2],
                        double uv_n[2])
{
    apply_homography(n->W, uv, uv_n);
}

void gs_geom_denorm_pixel(const gs_geom_norm *n, const double uv_n[2],
                          double uv[2])
{
    apply_homography(n->W_inv, uv_n, uv);
}

void gs_geom_norm_camera(const gs_geom_norm *n, double k_eff[9],
                         double r_cam[9])
{
    /* K_n S = K_n diag(1,1,s) ~ diag(1,1,1/s)-scaled rows: dividing the
     * homogeneous result by s gives focal f_n / s at the same centre. */
    double f = n->f_n / n->S[2];
    double k[9] = {f, 0, 0.5 * n->width, 0, f, 0.5 * n->height, 0, 0, 1};
    memcpy(k_eff, k, sizeof k);
    memcpy(r_cam, n->R, sizeof n->R);
}
