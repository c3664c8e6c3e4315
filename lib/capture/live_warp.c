/* Eye patches onto the current frame: a similarity from the frame's eye
 * corners to the render's, and a masked bilinear blend over the eye's box
 * only (never the whole frame: this runs on every frame). Also the face
 * models behind the tracking interface. */
#include <math.h>
#include <string.h>

#include "gazesplat/live.h"

int gs_live_similarity(const double dst0[2], const double dst1[2], const double src0[2],
                       const double src1[2], double m[4])
{
    /* As complex numbers: src = z dst + c with z = (s1 - s0) / (d1 - d0). */
    double dx = dst1[0] - dst0[0], dy = dst1[1] - dst0[1];
    double sx = src1[0] - src0[0], sy = src1[1] - src0[1];
    double den = dx * dx + dy * dy;
    if (!(den > 1e-12))
        return GS_ERR_ARG;
    double a = (sx * dx + sy * dy) / den, b = (sy * dx - sx * dy) / den;
    m[0] = a;
    m[1] = b;
    m[2] = src0[0] - (a * dst0[0] - b * dst0[1]);
    m[3] = src0[1] - (b * dst0[0] + a * dst0[1]);
    return GS_OK;
}

/* Bilinear sample of an RGB image at geom.h position (u, v); 0 outside. */
static int sample(const uint8_t *img, size_t stride, int w, int h, double u, double v,
                  float out[3])
{
    double x = u - 0.5, y = v - 0.5;
    if (!(x >= 0 && y >= 0 && x <= w - 1 && y <= h - 1))
        return 0;
    int x0 = (int)x, y0 = (int)y;
    int x1 = x0 + 1 < w ? x0 + 1 : x0, y1 = y0 + 1 < h ? y0 + 1 : y0;
    float fx = (float)(x - x0), fy = (float)(y - y0);
    const uint8_t *a = img + (size_t)y0 * stride + 3 * (size_t)x0;
    const uint8_t *b = img + (size_t)y0 * stride + 3 * (size_t)x1;
    const uint8_t *c = img + (size_t)y1 * stride + 3 * (size_t)x0;
    const uint8_t *d = img + (size_t)y1 * stride + 3 * (size_t)x1;
    for (int k = 0; k < 3; k++) {
        float top = a[k] + fx * (b[k] - a[k]), bot = c[k] + fx * (d[k] - c[k]);
        out[k] = top + fy * (bot - top);
    }
    return 1;
}

void gs_live_blend_patch(uint8_t *frame, size_t stride, int width, int height, int x0, int y0,
                         int x1, int y1, const uint8_t *mask, const uint8_t *patch,
                         size_t patch_stride, int patch_w, int patch_h, const double m[4],
                         float alpha)
{
    int bw = x1 - x0;
    for (int y = y0 < 0 ? 0 : y0; y < y1 && y < height; y++) {
        for (int x = x0 < 0 ? 0 : x0; x < x1 && x < width; x++) {
            float w = alpha * (float)mask[(size_t)(y - y0) * (size_t)bw + (size_t)(x - x0)] / 255.0f;
            if (w <= 0.0f)
                continue;
            double px = x + 0.5, py = y + 0.5;
            double u = m[0] * px - m[1] * py + m[2], v = m[1] * px + m[0] * py + m[3];
            float s[3];
            if (!sample(patch, patch_stride, patch_w, patch_h, u, v, s))
                continue;
            uint8_t *q = frame + (size_t)y * stride + 3 * (size_t)x;
            for (int k = 0; k < 3; k++) {
                float o = q[k] + w * (s[k] - q[k]);
                q[k] = (uint8_t)(o < 0 ? 0 : o > 255 ? 255 : o + 0.5f);
            }
        }
    }
}

/* ---- the real face models ---- */

static int face_detect(void *ctx, const gs_io_image *img, int min_size, gs_face_box *box,
                       int *found, gs_error *err)
{
    gs_live_face_models *m = ctx;
    gs_face_detect_opts o;
    gs_face_detect_opts_default(&o);
    o.min_size = min_size > 24 ? min_size : 24;
    gs_face_detection d;
    int n = 0;
    int r = gs_face_detect(m->det, img, &o, &d, 1, &n, err);
    *found = r == GS_OK && n > 0;
    if (*found)
        *box = d.box;
    return r;
}

static int face_landmarks(void *ctx, const gs_io_image *img, gs_face_box box, double uv[][2],
                          gs_error *err)
{
    gs_live_face_models *m = ctx;
    return gs_face_shape_predict(m->sp, img, box, NULL, &uv[0][0], err);
}

gs_live_track_ops gs_live_track_ops_face(gs_live_face_models *m)
{
    gs_live_track_ops o = {m, face_detect, face_landmarks};
    return o;
}
