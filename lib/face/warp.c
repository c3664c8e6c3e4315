/* The normalization warp, its inverse, and paste-back. Our homographies
 * work in geom.h pixels (centres at +0.5); OpenCV's at integers, so the
 * matrix handed to it is T(-1/2) H T(+1/2). */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "cv_face_shim.h"
#include "face_internal.h"

static int alloc_image(int w, int h, gs_io_image *out, gs_error *err)
{
    unsigned char *d = calloc((size_t)w * (size_t)h, 3);
    if (!d)
        return gs_error_set(err, GS_ERR_NOMEM, "warp: cannot allocate %dx%d", w, h);
    out->width = w;
    out->height = h;
    out->stride = 3 * (size_t)w;
    out->data = d;
    return GS_OK;
}

/* OpenCV form of a geom.h homography h: T(-1/2) h T(+1/2). */
static void to_opencv(const double h[9], double m[9])
{
    const double a[9] = {1, 0, -0.5, 0, 1, -0.5, 0, 0, 1};
    const double b[9] = {1, 0, 0.5, 0, 1, 0.5, 0, 0, 1};
    double t[9];
    gs_geom_mat3_mul(h, b, t);
    gs_geom_mat3_mul(a, t, m);
}

static int check_image(const gs_io_image *img, const char *what, gs_error *err)
{
    if (!img || !img->data || img->width < 1 || img->height < 1 ||
        img->stride < 3 * (size_t)img->width)
        return gs_error_set(err, GS_ERR_ARG, "warp: empty or malformed %s image", what);
    return GS_OK;
}

/* dst (w x h, new) = src sampled at h_dst_to_src (geom.h pixels). */
static int warp(const gs_io_image *src, const double h_dst_to_src[9], int w, int h,
                gs_io_image *out, gs_error *err)
{
    gs_io_image dst;
    double m[9];
    int rc = alloc_image(w, h, &dst, err);
    if (rc)
        return rc;
    to_opencv(h_dst_to_src, m);
    rc = gs_cvf_warp(src, &dst, m, err);
    if (rc) {
        free(dst.data);
        return rc;
    }
    *out = dst;
    return GS_OK;
}

int gs_face_normalize_image(const gs_io_image *img, const gs_geom_norm *n, gs_io_image *out,
                            gs_error *err)
{
    int rc = check_image(img, "source", err);
    if (rc)
        return rc;
    if (!n || !out || n->width < 1 || n->height < 1 || n->width > 8192 || n->height > 8192)
        return gs_error_set(err, GS_ERR_ARG, "warp: bad normalization");
    return warp(img, n->W_inv, n->width, n->height, out, err);
}

int gs_face_denormalize_image(const gs_io_image *norm_img, const gs_geom_norm *n, int width,
                              int height, gs_io_image *out, gs_error *err)
{
    int rc = check_image(norm_img, "normalized", err);
    if (rc)
        return rc;
    if (!n || !out || width < 1 || height < 1 || (size_t)width * (size_t)height > ((size_t)1 << 28))
        return gs_error_set(err, GS_ERR_ARG, "warp: bad size %dx%d", width, height);
    return warp(norm_img, n->W, width, height, out, err);
}

/* Bilinear sample of img at geom.h position (u, v) into rgb[3]; 0 when the
 * four neighbours are not all inside. */
static int sample(const gs_io_image *img, double u, double v, double rgb[3])
{
    double x = u - 0.5, y = v - 0.5;
    if (!(x >= 0 && y >= 0 && x <= img->width - 1 && y <= img->height - 1))
        return 0;
    int x0 = (int)x, y0 = (int)y;
    int x1 = x0 + 1 < img->width ? x0 + 1 : x0, y1 = y0 + 1 < img->height ? y0 + 1 : y0;
    double fx = x - x0, fy = y - y0;
    const unsigned char *r0 = img->data + (size_t)y0 * img->stride;
    const unsigned char *r1 = img->data + (size_t)y1 * img->stride;
    for (int c = 0; c < 3; c++) {
        double top = r0[3 * x0 + c] * (1 - fx) + r0[3 * x1 + c] * fx;
        double bot = r1[3 * x0 + c] * (1 - fx) + r1[3 * x1 + c] * fx;
        rgb[c] = top * (1 - fy) + bot * fy;
    }
    return 1;
}

int gs_face_paste_back(gs_io_image *photo, const gs_io_image *norm_face, const gs_geom_norm *n,
                       const uint8_t *mask, gs_error *err)
{
    int rc = check_image(photo, "photo", err);
    if (!rc)
        rc = check_image(norm_face, "normalized", err);
    if (rc)
        return rc;
    if (!n || !mask)
        return gs_error_set(err, GS_ERR_ARG, "paste-back: NULL normalization or mask");
    for (int y = 0; y < photo->height; y++) {
        const uint8_t *mr = mask + (size_t)y * photo->width;
        unsigned char *row = photo->data + (size_t)y * photo->stride;
        for (int x = 0; x < photo->width; x++) {
            if (!mr[x])
                continue;
            const double p[2] = {x + 0.5, y + 0.5};
            double q[2], rgb[3];
            gs_geom_norm_pixel(n, p, q);
            if (!sample(norm_face, q[0], q[1], rgb))
                continue;
            double a = mr[x] / 255.0;
            for (int c = 0; c < 3; c++) {
                double v = a * rgb[c] + (1 - a) * row[3 * x + c];
                row[3 * x + c] = (unsigned char)lround(v < 0 ? 0 : v > 255 ? 255 : v);
            }
        }
    }
    return GS_OK;
}

int gs_face_paste_mask(const gs_face_result *r, int whole_face, uint8_t *mask,
                       gs_error *err)
{
    if (!r || !mask)
        return gs_error_set(err, GS_ERR_ARG, "paste mask: NULL argument");
    double feather = 0.04 * (r->box.right - r->box.left + 1);
    return gs_face_mask((const double(*)[2])r->uv,
                        whole_face ? GS_FACE_MASK_FACE : GS_FACE_MASK_EYES, 2.0,
                        feather < 2 ? 2 : feather, r->image_width, r->image_height,
                        mask, err);
}
