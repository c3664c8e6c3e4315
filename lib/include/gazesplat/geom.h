/* gs_geom: rotations, gaze and head angles, and gaze normalization.
 *
 * Shared by the synthetic heads (lib/synth) and the real-face pipeline.
 * Everything is double precision; 3x3 matrices are row-major double[9],
 * vectors double[3]; angles are radians, lengths millimetres.
 *
 * Frames (see the project's design notes):
 *   camera  OpenCV: x right, y down, z forward.
 *   head    x toward image right (the subject's left), y down, z into the
 *           head; origin at the face centre (midpoint of the eye-corner
 *           centre and the nose-wing centre, iBUG 36, 39, 42, 45 and 31, 35).
 *   A head pose (R, t) maps head to camera: X_cam = R X_head + t.
 *
 * Pixels: continuous coordinates, pixel (i, j) covers [i, i+1) x [j, j+1)
 * and its centre is (i + 0.5, j + 0.5), as in the rasterizer. (OpenCV puts
 * pixel centres at integers: u_opencv = u - 0.5.) K = [[fx, 0, cx],
 * [0, fy, cy], [0, 0, 1]] projects X to (fx X/Z + cx, fy Y/Z + cy).
 *
 * Angles, ETH-XGaze convention. A unit gaze vector g points from the eye
 * (or face centre) toward the target:
 *   pitch = asin(-g_y), yaw = atan2(-g_x, -g_z)
 *   g = (-cos p sin y, -sin p, -cos p cos y)
 * so pitch > 0 looks up and yaw > 0 looks toward image-left; (0, 0) looks
 * straight back at the camera. The head angles of a rotation R are those
 * of its z-axis z = R e_z (into the head): pitch = asin(z_y),
 * yaw = atan2(z_x, z_z), i.e. the gaze angles of the face's forward
 * direction -z.
 *
 * Normalization (Zhang, Sugano, Bulling, ETRA 2018), for a reference point
 * c (face centre, camera frame) and head rotation hR:
 *   forward = c/|c|, down = norm(forward x hR e_x), right = norm(down x forward)
 *   R = [right; down; forward] (rows), S = diag(1, 1, d_n/|c|)
 *   K_n = [[f_n, 0, W/2], [0, f_n, H/2], [0, 0, 1]], W = K_n S R K^-1
 * Gaze and head rotation are normalized by R alone (never S):
 *   g_n = R g, hR_n = R hR; back: g = R^T g_n, hR = R^T hR_n. */
#ifndef GAZESPLAT_GEOM_H
#define GAZESPLAT_GEOM_H

#include "gazesplat/error.h"

#ifdef __cplusplus
extern "C" {
#endif

/* Defaults of the normalized face camera (as GazeNeRF / GazeGaussian on
 * ETH-XGaze): distance 680 mm, focal 1600 px at 512 px, scaling with size. */
#define GS_GEOM_NORM_DISTANCE_MM 680.0
#define GS_GEOM_NORM_FOCAL_512 1600.0

/* ---- 3x3 algebra ---- */
void gs_geom_mat3_identity(double out[9]);
void gs_geom_mat3_mul(const double a[9], const double b[9], double out[9]);
void gs_geom_mat3_transpose(const double a[9], double out[9]);
/* out = m v and out = m^T v; out may alias v. */
void gs_geom_mat3_vec(const double m[9], const double v[3], double out[3]);
void gs_geom_mat3_tvec(const double m[9], const double v[3], double out[3]);
/* Inverse; GS_ERR_ARG when |det| is tiny relative to the entries. */
int gs_geom_mat3_inverse(const double m[9], double out[9]);
double gs_geom_vec3_dot(const double a[3], const double b[3]);
void gs_geom_vec3_cross(const double a[3], const double b[3], double out[3]);
double gs_geom_vec3_norm(const double a[3]);
/* Scales a to unit length; GS_ERR_ARG (a unchanged) when it is zero or
 * not finite. */
int gs_geom_vec3_normalize(double a[3]);
/* Angle between two non-zero vectors, radians in [0, pi]; robust near 0. */
double gs_geom_vec3_angle(const double a[3], const double b[3]);

/* ---- rotations ---- */
/* Right-handed rotations about the camera axes. */
void gs_geom_rot_x(double angle, double out[9]);
void gs_geom_rot_y(double angle, double out[9]);
void gs_geom_rot_z(double angle, double out[9]);
/* Axis-angle (Rodrigues) vector <-> rotation matrix. */
void gs_geom_rodrigues(const double rvec[3], double out[9]);
void gs_geom_rot_to_rodrigues(const double r[9], double rvec[3]);

/* R = Ry(yaw) Rx(-pitch) Rz(roll). Its head angles are (pitch, yaw), and it
 * maps -e_z to the gaze vector of (pitch, yaw): it is both the head pose of
 * a head turned by (pitch, yaw, roll) and the rotation of an eye whose rest
 * axis is -e_z (looking out of the face) to a gaze of (pitch, yaw). */
void gs_geom_rot_from_pitchyaw(double pitch, double yaw, double roll,
                               double out[9]);
/* Head angles (pitch, yaw) of R, see above. Roll is not returned. */
void gs_geom_head_pitchyaw(const double r[9], double *pitch, double *yaw);
/* Roll of R about its own z-axis, the inverse of gs_geom_rot_from_pitchyaw
 * together with gs_geom_head_pitchyaw. */
double gs_geom_head_roll(const double r[9]);

/* ---- gaze vectors ---- */
void gs_geom_pitchyaw_to_vec(double pitch, double yaw, double g[3]);
/* g need not be unit; GS_ERR_ARG for a zero or non-finite vector. */
int gs_geom_vec_to_pitchyaw(const double g[3], double *pitch, double *yaw);
/* Unit vector from origin toward target; GS_ERR_ARG if they coincide. */
int gs_geom_gaze_from_target(const double origin[3], const double target[3],
                             double g[3]);

/* ---- face model and face centre ---- */
/* The generic 6-point face model (iBUG 36, 39, 42, 45, 31, 35), head-frame
 * axes, millimetres, origin as published (not the face centre). */
void gs_geom_face_model6(double out[6][3]);
/* The same six points measured on the mean synthetic head of lib/synth
 * (mean identity, neutral expression; gs_synth_template_build's
 * landmarks), head frame, origin at its face centre. Regenerate with
 * `gazesplat synth --face-model6`; tests/synth/test_synth_face_model.c
 * checks them against the template. */
void gs_geom_face_model6_synth(double out[6][3]);
/* Seven more points of the same head, same frame: the nose bridge and tip
 * (iBUG 27, 28, 29, 30) and the nostrils (32, 33, 34). With the six they
 * are the 13 points the head pose of a photo is solved from
 * (GS_FACE_POSE_SYNTH): the bridge stands out of the nearly flat plane of
 * the six, which alone leave the tilt ill-conditioned (docs/face.md). */
void gs_geom_face_nose7_synth(double out[7][3]);
/* Face centre of six points in that order: mean of (mean of the 4 eye
 * corners, mean of the 2 nose wings). */
void gs_geom_face_centre6(const double pts[6][3], double centre[3]);

/* ---- pinhole projection ---- */
/* Projects a camera-frame point; GS_ERR_ARG when z <= 0. */
int gs_geom_project(const double k[9], const double x_cam[3], double uv[2]);
/* Unit ray direction (camera frame) through a pixel position. */
void gs_geom_unproject(const double k[9], const double uv[2], double dir[3]);

/* ---- normalization ---- */
typedef struct gs_geom_norm {
    double R[9];          /* rows: right, down, forward (camera frame) */
    double S[3];          /* diagonal of S: 1, 1, d_n / |c| */
    double K_n[9];        /* normalized intrinsics */
    double W[9];          /* pixel warp K_n S R K^-1 (original -> normalized) */
    double W_inv[9];      /* its inverse */
    double distance_mm;   /* |c| */
    double d_n_mm, f_n;   /* normalized distance and focal length */
    int width, height;    /* normalized image size */
} gs_geom_norm;

/* Focal length of the default normalized camera for a square image of
 * `size` pixels: 1600 * size / 512. */
double gs_geom_norm_focal(int size);

/* Fills *out for camera intrinsics k, reference point c (camera frame,
 * z > 0), head rotation head_r (head to camera), normalized distance d_n_mm,
 * focal f_n and size. Fails with GS_ERR_ARG if c is behind the camera, the
 * head x-axis is parallel to c, or a size/focal is not positive;
 * GS_ERR_NONFINITE for NaN/Inf inputs. */
int gs_geom_normalize(const double k[9], const double c[3],
                      const double head_r[9], double d_n_mm, double f_n,
                      int width, int height, gs_geom_norm *out,
                      gs_error *err);

/* Gaze (or any direction): v_n = R v and its inverse. */
void gs_geom_norm_vec(const gs_geom_norm *n, const double v[3],
                      double v_n[3]);
void gs_geom_denorm_vec(const gs_geom_norm *n, const double v_n[3],
                        double v[3]);
/* Head rotation: hR_n = R hR and its inverse. */
void gs_geom_norm_rot(const gs_geom_norm *n, const double head_r[9],
                      double head_r_n[9]);
void gs_geom_denorm_rot(const gs_geom_norm *n, const double head_r_n[9],
                        double head_r[9]);
/* Pixel positions through W and W^-1. */
void gs_geom_norm_pixel(const gs_geom_norm *n, const double uv[2],
                        double uv_n[2]);
void gs_geom_denorm_pixel(const gs_geom_norm *n, const double uv_n[2],
                          double uv[2]);
/* A pinhole camera that renders exactly the normalized image: it sits at
 * the original camera centre, is rotated by R (X' = R X_cam) and has focal
 * f_n |c| / d_n with the principal point at the image centre. Pixels it
 * projects equal W applied to the original projection. */
void gs_geom_norm_camera(const gs_geom_norm *n, double k_eff[9],
                         double r_cam[9]);

#ifdef __cplusplus
}
#endif
#endif
