/* Labels of a rendered sample: camera, head pose, gaze in the camera, head
 * and normalized frames, points and landmarks. */
#include <string.h>

#include "render_internal.h"

static void to_cam(const double r[9], const double t[3], const double x[3],
                   double out[3])
{
    gs_geom_mat3_vec(r, x, out);
    for (int i = 0; i < 3; i++)
        out[i] += t[i];
}

static void v3_to_d(v3 a, double out[3])
{
    out[0] = a.x;
    out[1] = a.y;
    out[2] = a.z;
}

/* Projection that tolerates points behind the camera (returns NaN there:
 * JSON writes them as null). */
static void project(const double k[9], const double x[3], double uv[2])
{
    if (gs_geom_project(k, x, uv) != GS_OK)
        uv[0] = uv[1] = NAN;
}

void gs_synth_labels_from_head(const gs_synth_scene *s,
                               const gs_synth_camera *cam,
                               const head_model *h, gs_synth_labels *l)
{
    memset(l, 0, sizeof *l);
    memcpy(l->K, cam->K, sizeof l->K);
    memcpy(l->cam_R, cam->R, sizeof l->cam_R);
    memcpy(l->cam_t, cam->t, sizeof l->cam_t);
    l->width = cam->width;
    l->height = cam->height;
    /* Head pose in this camera. */
    gs_geom_mat3_mul(cam->R, s->head_R, l->head_R);
    to_cam(cam->R, cam->t, s->head_t, l->head_t);
    gs_geom_rot_to_rodrigues(l->head_R, l->head_rvec);
    gs_geom_head_pitchyaw(l->head_R, &l->head_pitch, &l->head_yaw);
    l->head_roll = gs_geom_head_roll(l->head_R);
    /* Gaze. */
    l->gaze_head_pitch = s->gaze_pitch;
    l->gaze_head_yaw = s->gaze_yaw;
    gs_geom_pitchyaw_to_vec(s->gaze_pitch, s->gaze_yaw, l->gaze_head);
    gs_geom_mat3_vec(l->head_R, l->gaze_head, l->gaze_cam);
    gs_geom_vec_to_pitchyaw(l->gaze_cam, &l->gaze_cam_pitch, &l->gaze_cam_yaw);
    /* Optical axes: what each eyeball renders along. */
    l->has_kappa = s->kappa != 0;
    if (l->has_kappa) {
        l->kappa_h = s->kappa_h;
        l->kappa_v = s->kappa_v;
    }
    for (int e = 0; e < 2; e++) {
        double a[3] = {h->eye[e].axis.x, h->eye[e].axis.y, h->eye[e].axis.z};
        double n = sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2]);
        for (int k = 0; k < 3; k++)
            l->optical_head[e][k] = a[k] / n;
        gs_geom_vec_to_pitchyaw(l->optical_head[e], &l->optical_head_pitch[e],
                                &l->optical_head_yaw[e]);
        gs_geom_mat3_vec(l->head_R, l->optical_head[e], l->optical_cam[e]);
        gs_geom_vec_to_pitchyaw(l->optical_cam[e], &l->optical_cam_pitch[e],
                                &l->optical_cam_yaw[e]);
    }
    /* Points: the head origin is the face centre. */
    memcpy(l->face_centre, l->head_t, sizeof l->face_centre);
    project(cam->K, l->face_centre, l->face_centre_uv);
    for (int e = 0; e < 2; e++) {
        double c[3], pc[3];
        v3_to_d(h->eye[e].c, c);
        v3_to_d(h->eye[e].iris_c, pc);
        to_cam(l->head_R, l->head_t, c, l->eye_centre[e]);
        to_cam(l->head_R, l->head_t, pc, l->pupil_centre[e]);
        project(cam->K, l->eye_centre[e], l->eye_centre_uv[e]);
        project(cam->K, l->pupil_centre[e], l->pupil_uv[e]);
    }
    l->pupil_radius_mm = h->eye[0].pupil_r;
    l->iris_radius_mm = h->eye[0].iris_r;
    l->eyeball_radius_mm = h->eye[0].r_sclera;
    gs_synth_head_landmarks(h, l->lm3d_head);
    for (int i = 0; i < GS_SYNTH_LANDMARKS; i++) {
        to_cam(l->head_R, l->head_t, l->lm3d_head[i], l->lm3d[i]);
        project(cam->K, l->lm3d[i], l->lm2d[i]);
    }
    /* Normalization of this image at the default distance and focal. */
    int size = cam->width > cam->height ? cam->width : cam->height;
    double gn[3], hrn[9];
    if (gs_geom_normalize(cam->K, l->face_centre, l->head_R,
                          GS_GEOM_NORM_DISTANCE_MM, gs_geom_norm_focal(size),
                          cam->width, cam->height, &l->norm, NULL) == GS_OK) {
        gs_geom_norm_vec(&l->norm, l->gaze_cam, gn);
        gs_geom_vec_to_pitchyaw(gn, &l->gaze_norm_pitch, &l->gaze_norm_yaw);
        gs_geom_norm_rot(&l->norm, l->head_R, hrn);
        gs_geom_head_pitchyaw(hrn, &l->head_norm_pitch, &l->head_norm_yaw);
        for (int e = 0; e < 2; e++) {
            gs_geom_norm_vec(&l->norm, l->optical_cam[e], gn);
            gs_geom_vec_to_pitchyaw(gn, &l->optical_norm_pitch[e],
                                    &l->optical_norm_yaw[e]);
        }
    } else {
        l->optical_norm_pitch[0] = l->optical_norm_pitch[1] = NAN;
        l->optical_norm_yaw[0] = l->optical_norm_yaw[1] = NAN;
        l->gaze_norm_pitch = l->gaze_norm_yaw = NAN;
        l->head_norm_pitch = l->head_norm_yaw = NAN;
    }
    l->identity = s->identity;
    l->expr = s->expr;
}
