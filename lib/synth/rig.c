/* Cameras: a single frontal camera, an 18-camera dome after ETH-XGaze, and
 * the normalized face camera. */
#include <string.h>

#include "synth_internal.h"

static const double DEG_D = 3.14159265358979323846 / 180.0;

static void square_k(int size, double f, double k[9])
{
    double kk[9] = {f, 0, 0.5 * size, 0, f, 0.5 * size, 0, 0, 1};
    memcpy(k, kk, sizeof kk);
}

void gs_synth_camera_single(int size, double distance_mm, double field_mm,
                            gs_synth_camera *cam)
{
    memset(cam, 0, sizeof *cam);
    square_k(size, size * distance_mm / field_mm, cam->K);
    gs_geom_mat3_identity(cam->R);
    cam->width = cam->height = size;
}

int gs_synth_camera_ethx(int index, int size, double distance_mm,
                         double field_mm, gs_synth_camera *cam)
{
    if (index < 0 || index >= GS_SYNTH_ETHX_CAMERAS)
        return GS_ERR_ARG;
    static const double pitch[3] = {20.0, 0.0, -20.0};
    int row = index / 6, col = index % 6;
    double g[3], head[3] = {0, 0, distance_mm}, pos[3];
    /* Column 0 sits at image-left of the frontal view: yaw > 0. */
    gs_geom_pitchyaw_to_vec(pitch[row] * DEG_D, (62.5 - 25.0 * col) * DEG_D, g);
    for (int i = 0; i < 3; i++)
        pos[i] = head[i] + distance_mm * g[i];
    double fwd[3] = {-g[0], -g[1], -g[2]}, down_w[3] = {0, 1, 0}, right[3],
           down[3];
    gs_geom_vec3_cross(down_w, fwd, right);
    gs_geom_vec3_normalize(right);
    gs_geom_vec3_cross(fwd, right, down);
    memset(cam, 0, sizeof *cam);
    for (int i = 0; i < 3; i++) {
        cam->R[i] = right[i];
        cam->R[3 + i] = down[i];
        cam->R[6 + i] = fwd[i];
    }
    gs_geom_mat3_vec(cam->R, pos, cam->t);
    for (int i = 0; i < 3; i++)
        cam->t[i] = -cam->t[i];
    square_k(size, size * distance_mm / field_mm, cam->K);
    cam->width = cam->height = size;
    return GS_OK;
}

int gs_synth_camera_normalized(const gs_synth_scene *s,
                               const gs_synth_camera *base, int size,
                               double d_n_mm, double f_n,
                               gs_synth_camera *out, gs_error *err)
{
    if (d_n_mm <= 0.0)
        d_n_mm = GS_GEOM_NORM_DISTANCE_MM;
    if (f_n <= 0.0)
        f_n = gs_geom_norm_focal(size);
    double c[3], hr[9];
    gs_geom_mat3_vec(base->R, s->head_t, c);
    for (int i = 0; i < 3; i++)
        c[i] += base->t[i];
    gs_geom_mat3_mul(base->R, s->head_R, hr);
    gs_geom_norm n;
    int rc = gs_geom_normalize(base->K, c, hr, d_n_mm, f_n, size, size, &n, err);
    if (rc != GS_OK)
        return rc;
    double rn[9];
    gs_synth_camera nc; /* out may alias base */
    memset(&nc, 0, sizeof nc);
    gs_geom_norm_camera(&n, nc.K, rn);
    gs_geom_mat3_mul(rn, base->R, nc.R);
    gs_geom_mat3_vec(rn, base->t, nc.t);
    nc.width = nc.height = size;
    *out = nc;
    return GS_OK;
}
