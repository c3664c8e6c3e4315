/* The gate (face.h): measures that decide, before any fit, whether a face
 * can be redirected well, and the first one that says no. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "face_internal.h"

#define RAD2DEG (180.0 / 3.14159265358979323846)

void gs_face_gate_opts_default(gs_face_gate_opts *o)
{
    o->min_eye_px = 16;
    o->min_eye_open = 0.13;
    o->max_head_yaw_deg = 60;
    o->max_head_pitch_deg = 40;
    o->max_outside = 0.05;
    o->min_contrast = 5;
    o->max_roughness = 0.5;
    o->min_iris_contrast = 15;
}

const char *gs_face_refusal_name(gs_face_refusal r)
{
    static const char *const names[GS_FACE_REFUSAL_COUNT] = {
        "usable", "no_face", "flat", "noise", "at_border", "head_pose", "small_eyes", "eyes_closed"};
    return (unsigned)r < GS_FACE_REFUSAL_COUNT ? names[r] : NULL;
}

static int check_opts(const gs_face_gate_opts *o, gs_error *err)
{
    const double v[8] = {o->min_eye_px,  o->min_eye_open,  o->max_head_yaw_deg, o->max_head_pitch_deg,
                         o->max_outside, o->min_contrast, o->max_roughness, o->min_iris_contrast};
    for (int i = 0; i < 8; i++)
        if (!isfinite(v[i]) || v[i] < 0)
            return gs_error_set(err, GS_ERR_ARG, "face gate: thresholds must be finite and >= 0");
    return GS_OK;
}

static int check_image(const gs_io_image *im, gs_error *err)
{
    if (!im || !im->data || im->width < 8 || im->height < 8 || im->stride < 3 * (size_t)im->width)
        return gs_error_set(err, GS_ERR_ARG, "face gate: no image, or one under 8x8");
    return GS_OK;
}

/* Luma (BT.601) standard deviation and roughness of the central half
 * (in each direction) of the normalized face: at the normalized camera
 * the face spans about 0.7 of the image, so that square is all face. */
static void texture(const gs_io_image *im, double *contrast, double *roughness)
{
    int x0 = im->width / 4, x1 = im->width - im->width / 4;
    int y0 = im->height / 4, y1 = im->height - im->height / 4;
    double sum = 0, sum2 = 0, dsum = 0;
    long n = 0, nd = 0;
    for (int y = y0; y < y1; y++) {
        const uint8_t *row = im->data + (size_t)y * im->stride;
        const uint8_t *below = y + 1 < y1 ? row + im->stride : NULL;
        for (int x = x0; x < x1; x++) {
            const uint8_t *p = row + 3 * (size_t)x;
            double l = 0.299 * p[0] + 0.587 * p[1] + 0.114 * p[2];
            sum += l;
            sum2 += l * l;
            n++;
            if (x + 1 < x1) {
                double r = 0.299 * p[3] + 0.587 * p[4] + 0.114 * p[5];
                dsum += fabs(r - l);
                nd++;
            }
            if (below) {
                const uint8_t *q = below + 3 * (size_t)x;
                double b = 0.299 * q[0] + 0.587 * q[1] + 0.114 * q[2];
                dsum += fabs(b - l);
                nd++;
            }
        }
    }
    double mean = sum / (double)n;
    double var = sum2 / (double)n - mean * mean;
    double sd = var > 0 ? sqrt(var) : 0;
    *contrast = sd;
    /* A flat region has no roughness to speak of: 0, and "flat" says why. */
    *roughness = sd > 1e-6 ? dsum / (double)nd / sd : 0;
}

static int image_checks(const gs_io_image *norm, const gs_face_gate_opts *o, gs_face_gate *g)
{
    texture(norm, &g->contrast, &g->roughness);
    if (g->contrast < o->min_contrast) {
        g->refusal = GS_FACE_REFUSED_FLAT;
        snprintf(g->reason, sizeof g->reason,
                 "no contrast in the face: luma standard deviation %.1f (need %.1f); a black, "
                 "white or grey frame?",
                 g->contrast, o->min_contrast);
        return 1;
    }
    if (g->roughness > o->max_roughness) {
        g->refusal = GS_FACE_REFUSED_NOISE;
        snprintf(g->reason, sizeof g->reason,
                 "the face region is pixel noise: roughness %.2f (faces 0.1-0.2, at most %.2f)",
                 g->roughness, o->max_roughness);
        return 1;
    }
    return 0;
}

int gs_face_gate_normalized(const gs_io_image *norm_face, const gs_face_gate_opts *opts,
                            gs_face_gate *out, gs_error *err)
{
    gs_face_gate_opts def;
    if (!opts) {
        gs_face_gate_opts_default(&def);
        opts = &def;
    }
    if (!out)
        return gs_error_set(err, GS_ERR_ARG, "face gate: NULL result");
    int rc = check_opts(opts, err);
    if (!rc)
        rc = check_image(norm_face, err);
    if (rc)
        return rc;
    memset(out, 0, sizeof *out);
    out->iris_contrast = NAN;
    image_checks(norm_face, opts, out);
    return GS_OK;
}

static double dist(const double a[2], const double b[2])
{
    return hypot(a[0] - b[0], a[1] - b[1]);
}

/* Eye aspect ratio of the six contour points p0..p5 (corner, two upper,
 * corner, two lower): (|p1 - p5| + |p2 - p4|) / (2 |p0 - p3|). */
static double eye_open(const double (*p)[2])
{
    double w = dist(p[0], p[3]);
    return w > 0 ? (dist(p[1], p[5]) + dist(p[2], p[4])) / (2 * w) : 0;
}

/* Fraction of the face (its mask in the normalized image, at least half
 * on) whose source pixel lies outside the photo. */
static int outside_fraction(const gs_face_result *r, double *out, gs_error *err)
{
    int w = r->norm.width, h = r->norm.height;
    uint8_t *m = malloc((size_t)w * (size_t)h);
    if (!m)
        return gs_error_set(err, GS_ERR_NOMEM, "face gate: out of memory");
    int rc = gs_face_mask((const double(*)[2])r->uv_n, GS_FACE_MASK_FACE, 0, 0, w, h, m, err);
    long in = 0, off = 0;
    for (int y = 0; !rc && y < h; y++)
        for (int x = 0; x < w; x++) {
            if (m[(size_t)y * w + x] < 128)
                continue;
            double q[2] = {x + 0.5, y + 0.5}, p[2];
            gs_geom_denorm_pixel(&r->norm, q, p);
            in++;
            if (!(p[0] >= 0 && p[1] >= 0 && p[0] < r->image_width && p[1] < r->image_height))
                off++;
        }
    free(m);
    *out = in ? (double)off / (double)in : 1;
    return rc;
}

/* The landmark checks, in the enum's order. */
static void landmark_checks(const gs_face_gate_opts *opts, gs_face_gate *g)
{
    if (g->outside > opts->max_outside) {
        g->refusal = GS_FACE_REFUSED_AT_BORDER;
        snprintf(g->reason, sizeof g->reason,
                 "the face is cut by the photo's border: %.0f%% of it outside (at most %.0f%%)",
                 100 * g->outside, 100 * opts->max_outside);
    } else if (fabs(g->head_yaw_deg) > opts->max_head_yaw_deg ||
               fabs(g->head_pitch_deg) > opts->max_head_pitch_deg) {
        g->refusal = GS_FACE_REFUSED_HEAD_POSE;
        snprintf(g->reason, sizeof g->reason,
                 "head turned beyond the model's range: pitch %.0f, yaw %.0f degrees (at most "
                 "%.0f, %.0f)",
                 g->head_pitch_deg, g->head_yaw_deg, opts->max_head_pitch_deg,
                 opts->max_head_yaw_deg);
    } else if (fmin(g->eye_px[0], g->eye_px[1]) < opts->min_eye_px) {
        g->refusal = GS_FACE_REFUSED_SMALL_EYES;
        snprintf(g->reason, sizeof g->reason,
                 "eyes too small: %.1f and %.1f px wide in the photo (need %.0f)", g->eye_px[0],
                 g->eye_px[1], opts->min_eye_px);
    } else if (fmin(g->eye_open[0], g->eye_open[1]) < opts->min_eye_open) {
        g->refusal = GS_FACE_REFUSED_EYES_CLOSED;
        snprintf(g->reason, sizeof g->reason,
                 "eyes closed: opening %.2f and %.2f (height over width; need %.2f)",
                 g->eye_open[0], g->eye_open[1], opts->min_eye_open);
    } else if (opts->min_iris_contrast > 0 && !g->irises &&
               g->iris_contrast < opts->min_iris_contrast) {
        /* NaN (no fit in either eye) compares false: an eye looking far
         * aside may give no fit at all, and so does a closed one */
        g->refusal = GS_FACE_REFUSED_EYES_CLOSED;
        snprintf(g->reason, sizeof g->reason,
                 "eyes closed or hidden: no iris in either eye, sclera-iris contrast at most "
                 "%.1f (need %.0f)", g->iris_contrast, opts->min_iris_contrast);
    }
}

/* The irises of the normalized face (g->irises, g->iris_contrast), at
 * its scale, or those the caller located (given); an eye the localizer
 * refuses to search counts as no fit. */
static void iris_checks(const gs_face_result *r, const gs_io_image *norm_face,
                        const gs_face_iris *given, gs_face_gate *g)
{
    gs_face_iris_opts io;
    gs_face_iris_opts_default(&io);
    if (r->norm.d_n_mm > 0 && r->norm.f_n > 0)
        gs_face_iris_opts_scale(&io, r->norm.f_n / r->norm.d_n_mm);
    g->irises = 0;
    g->iris_contrast = NAN;
    for (int e = 0; e < 2; e++) {
        gs_face_iris ir;
        if (given)
            ir = given[e];
        else if (gs_face_iris_locate(norm_face, (const double(*)[2])r->uv_n[36 + 6 * e], &io,
                                     &ir, NULL) != GS_OK)
            continue;
        g->irises += ir.status == GS_FACE_IRIS_OK;
        if (isfinite(ir.contrast) && !(ir.contrast <= g->iris_contrast))
            g->iris_contrast = ir.contrast;
    }
}

int gs_face_gate_photo(const gs_face_result *r, const gs_io_image *norm_face,
                       const gs_face_gate_opts *opts, gs_face_gate *out, gs_error *err)
{
    return gs_face_gate_photo_irises(r, norm_face, NULL, opts, out, err);
}

int gs_face_gate_photo_irises(const gs_face_result *r, const gs_io_image *norm_face,
                              const gs_face_iris *iris, const gs_face_gate_opts *opts,
                              gs_face_gate *out, gs_error *err)
{
    gs_face_gate_opts def;
    if (!opts) {
        gs_face_gate_opts_default(&def);
        opts = &def;
    }
    if (!r || !out)
        return gs_error_set(err, GS_ERR_ARG, "face gate: NULL argument");
    int rc = check_opts(opts, err);
    if (!rc)
        rc = check_image(norm_face, err);
    if (rc)
        return rc;
    if (norm_face->width != r->norm.width || norm_face->height != r->norm.height)
        return gs_error_set(err, GS_ERR_ARG,
                            "face gate: the normalized face is %dx%d, its normalization %dx%d",
                            norm_face->width, norm_face->height, r->norm.width, r->norm.height);
    gs_face_gate g;
    memset(&g, 0, sizeof g);
    for (int e = 0; e < 2; e++) {
        const double(*p)[2] = (const double(*)[2])r->uv[36 + 6 * e];
        g.eye_px[e] = dist(p[0], p[3]);
        g.eye_open[e] = eye_open(p);
    }
    g.head_pitch_deg = r->head_pitch_n * RAD2DEG;
    g.head_yaw_deg = r->head_yaw_n * RAD2DEG;
    if ((rc = outside_fraction(r, &g.outside, err)))
        return rc;
    iris_checks(r, norm_face, iris, &g);
    /* Image checks first: on a frame that is no face the landmarks are
     * noise too, and "small eyes" would name the wrong cause. */
    if (!image_checks(norm_face, opts, &g))
        landmark_checks(opts, &g);
    *out = g;
    return GS_OK;
}
