/* The classical baseline: move the iris inside each eye opening by the 2D
 * shift its pupil would make, with no 3D model of the face. */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "gazesplat/eval.h"
#include "gazesplat/geom.h"

/* Distance (px, capped at cap) from pixel (x, y) inside the mask to the
 * nearest pixel outside it or outside the image. */
static double inner_distance(const uint8_t *m, int w, int h, int x, int y,
                             int cap)
{
    double best = cap;
    for (int dy = -cap; dy <= cap; dy++)
        for (int dx = -cap; dx <= cap; dx++) {
            int xx = x + dx, yy = y + dy;
            int out = xx < 0 || yy < 0 || xx >= w || yy >= h ||
                      !m[(size_t)yy * w + xx];
            double d = sqrt((double)(dx * dx + dy * dy));
            if (out && d < best)
                best = d;
        }
    return best;
}

/* Bilinear sample at continuous position (u, v) (pixel centres at +0.5);
 * a neighbour outside the mask contributes `fill`. */
static void sample(const uint8_t *src, size_t ss, int w, int h,
                   const uint8_t *m, const uint8_t fill[3], double u,
                   double v, uint8_t out[3])
{
    double fx = u - 0.5, fy = v - 0.5;
    int x0 = (int)floor(fx), y0 = (int)floor(fy);
    double ax = fx - x0, ay = fy - y0;
    double acc[3] = {0, 0, 0};
    for (int k = 0; k < 4; k++) {
        int xx = x0 + (k & 1), yy = y0 + (k >> 1);
        double wt = ((k & 1) ? ax : 1 - ax) * ((k >> 1) ? ay : 1 - ay);
        int in = xx >= 0 && yy >= 0 && xx < w && yy < h &&
                 m[(size_t)yy * w + xx];
        const uint8_t *p = in ? src + (size_t)yy * ss + 3 * (size_t)xx : fill;
        for (int c = 0; c < 3; c++)
            acc[c] += wt * p[c];
    }
    for (int c = 0; c < 3; c++) {
        double r = floor(acc[c] + 0.5);
        out[c] = (uint8_t)(r < 0 ? 0 : r > 255 ? 255 : r);
    }
}

int gs_eval_warp_eye(const uint8_t *src, size_t ss, uint8_t *dst, size_t ds,
                     int w, int h, const uint8_t *mask, const double disp[2],
                     double falloff_px, const uint8_t fill[3], gs_error *err)
{
    if (w < 1 || h < 1 || ss < 3 * (size_t)w || ds < 3 * (size_t)w ||
        !(falloff_px > 0 && falloff_px < 1000))
        return gs_error_set(err, GS_ERR_ARG, "warp: bad size, stride or "
                            "falloff");
    if (!isfinite(disp[0]) || !isfinite(disp[1]))
        return gs_error_set(err, GS_ERR_NONFINITE, "warp: displacement");
    int cap = (int)ceil(falloff_px);
    for (int y = 0; y < h; y++)
        for (int x = 0; x < w; x++) {
            if (!mask[(size_t)y * w + x])
                continue;
            double t = inner_distance(mask, w, h, x, y, cap) / falloff_px;
            t = t > 1 ? 1 : t;
            double wt = t * t * (3 - 2 * t);
            sample(src, ss, w, h, mask, fill, x + 0.5 - wt * disp[0],
                   y + 0.5 - wt * disp[1], dst + (size_t)y * ds + 3 * (size_t)x);
        }
    return GS_OK;
}

int gs_eval_pupil_shift(const gs_synth_labels *l, int e, double pitch,
                        double yaw, double disp[2], gs_error *err)
{
    if (e < 0 || e > 1)
        return gs_error_set(err, GS_ERR_ARG, "warp: eye %d", e);
    if (!isfinite(pitch) || !isfinite(yaw))
        return gs_error_set(err, GS_ERR_NONFINITE, "warp: target gaze");
    const double *c = l->eye_centre[e], *p = l->pupil_centre[e];
    double v[3] = {p[0] - c[0], p[1] - c[1], p[2] - c[2]};
    double len = gs_geom_vec3_norm(v), g[3], gc[3], q[3], a[2], b[2];
    gs_geom_pitchyaw_to_vec(pitch, yaw, g);
    gs_geom_mat3_vec(l->head_R, g, gc);
    for (int k = 0; k < 3; k++)
        q[k] = c[k] + len * gc[k];
    if (gs_geom_project(l->K, p, a) || gs_geom_project(l->K, q, b))
        return gs_error_set(err, GS_ERR_ARG, "warp: eye behind the camera");
    disp[0] = b[0] - a[0];
    disp[1] = b[1] - a[1];
    return GS_OK;
}

/* Mean colour of the mask's pixels farther than r px from the pupil: the
 * sclera; the whole mask's mean when no pixel is that far. */
static void sclera_colour(const gs_synth_sample *in, const uint8_t *m,
                          const double uv[2], double r, uint8_t out[3])
{
    double acc[2][4] = {{0, 0, 0, 0}, {0, 0, 0, 0}};
    for (int y = 0; y < in->height; y++)
        for (int x = 0; x < in->width; x++) {
            if (!m[(size_t)y * in->width + x])
                continue;
            double dx = x + 0.5 - uv[0], dy = y + 0.5 - uv[1];
            int far = dx * dx + dy * dy > r * r;
            const uint8_t *p = in->rgb + (size_t)y * in->stride + 3 * x;
            for (int k = 0; k < 3; k++)
                acc[far][k] += p[k];
            acc[far][3] += 1;
        }
    int use = acc[1][3] > 0;
    double n = acc[1][3] + (use ? 0 : acc[0][3]);
    for (int k = 0; k < 3; k++) {
        double s = acc[1][k] + (use ? 0 : acc[0][k]);
        out[k] = n > 0 ? (uint8_t)(s / n + 0.5) : 255;
    }
}

int gs_eval_warp_redirect(const gs_synth_sample *in, double pitch, double yaw,
                          uint8_t *out, size_t stride, gs_error *err)
{
    int w = in->width, h = in->height;
    if (stride < 3 * (size_t)w)
        return gs_error_set(err, GS_ERR_ARG, "warp: stride");
    for (int y = 0; y < h; y++)
        memcpy(out + (size_t)y * stride, in->rgb + (size_t)y * in->stride,
               3 * (size_t)w);
    const gs_synth_labels *l = &in->labels;
    for (int e = 0; e < 2; e++) {
        const uint8_t *m = gs_synth_sample_mask(
            in, e == GS_SYNTH_EYE_RIGHT ? GS_SYNTH_MASK_RIGHT_EYE
                                        : GS_SYNTH_MASK_LEFT_EYE);
        double d[2];
        int rc = gs_eval_pupil_shift(l, e, pitch, yaw, d, err);
        if (rc)
            return rc;
        /* Iris radius in pixels at the eye's depth sets the falloff. */
        double iris_px = l->K[0] * l->iris_radius_mm / l->eye_centre[e][2];
        double fall = iris_px > 2 ? 0.5 * iris_px : 1;
        uint8_t fill[3];
        sclera_colour(in, m, l->pupil_uv[e], 1.3 * iris_px, fill);
        rc = gs_eval_warp_eye(in->rgb, in->stride, out, stride, w, h, m, d,
                              fall, fill, err);
        if (rc)
            return rc;
    }
    return GS_OK;
}
