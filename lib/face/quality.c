/* Quality of one redirected face against its input (face.h, "Redirect
 * quality"): the gaze the irises show against the gaze asked for, the
 * iris colour kept, and the eye regions free of speckle. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "face_internal.h"

#define RAD2DEG (180.0 / 3.14159265358979323846)

void gs_face_quality_opts_default(gs_face_quality_opts *o)
{
    /* The measure's own noise sets the tolerances: on exact synthetic
     * pairs one image's gaze change reads within 5.5 (pitch) and 7.6 (yaw)
     * deg rms, its iris colour within delta E 11 at the median
     * (test_face_quality, docs/face.md). */
    o->gaze_tol_deg = 10;
    o->gaze_tol_frac = 0.5;
    o->max_delta_e = 15;
    o->max_artifact = 1.6;
    o->px_per_mm = 0;
    o->shape = NULL;
}

/* Fine-scale energy of the eye regions: the mean absolute difference of
 * the luma from its 3 x 3 box mean, over the pixels of `mask` (eye
 * polygons, grown). Speckle and doubled edges raise it; the smooth skin,
 * sclera and iris of a good render do not. */
static double fine_energy(const gs_io_image *im, const uint8_t *mask)
{
    int w = im->width, h = im->height;
    double sum = 0;
    long n = 0;
    for (int y = 1; y + 1 < h; y++)
        for (int x = 1; x + 1 < w; x++) {
            if (mask[(size_t)y * w + x] < 128)
                continue;
            double c = 0, box = 0;
            for (int dy = -1; dy <= 1; dy++)
                for (int dx = -1; dx <= 1; dx++) {
                    const uint8_t *p = im->data + (size_t)(y + dy) * im->stride + 3 * (size_t)(x + dx);
                    double l = 0.299 * p[0] + 0.587 * p[1] + 0.114 * p[2];
                    box += l;
                    if (!dx && !dy)
                        c = l;
                }
            sum += fabs(c - box / 9);
            n++;
        }
    return n ? sum / (double)n : 0;
}

int gs_face_normalized_landmarks(const gs_face_shape_model *sp, const gs_io_image *img,
                                 double uv[][2], gs_error *err)
{
    if (!sp || !img || !img->data || !uv || img->width < 16 || img->height < 16)
        return gs_error_set(err, GS_ERR_ARG, "normalized landmarks: no model or image");
    int w = img->width, h = img->height;
    gs_face_box box = {(int)(0.16 * w), (int)(0.19 * h), (int)(0.84 * w), (int)(0.86 * h)};
    return gs_face_shape_predict(sp, img, box, NULL, &uv[0][0], err);
}

static double sq(double v)
{
    return v * v;
}

/* What every image of one input is measured against: the input's irises,
 * its eye mask and the mask's fine-scale energy, found once; with the
 * landmark model, also what it predicts for the input (pred). */
struct gs_face_quality_ref {
    gs_face_quality_opts opts;
    gs_face_iris_opts iris_opts;
    double uv[GS_FACE_LANDMARKS][2];
    double pred[GS_FACE_LANDMARKS][2];
    gs_face_iris iris[2];
    int width, height, in_found;
    uint8_t *mask;
    double energy;
};

int gs_face_quality_ref_create(const gs_io_image *input, const double uv[][2],
                               const gs_face_quality_opts *opts, gs_face_quality_ref **out,
                               gs_error *err)
{
    if (!input || !input->data || !uv || !out)
        return gs_error_set(err, GS_ERR_ARG, "redirect quality: NULL argument");
    *out = NULL;
    if (input->width < 8 || input->height < 8)
        return gs_error_set(err, GS_ERR_ARG, "redirect quality: a %dx%d input", input->width,
                            input->height);
    gs_face_quality_ref *r = calloc(1, sizeof *r);
    if (r)
        r->mask = malloc((size_t)input->width * (size_t)input->height);
    if (!r || !r->mask) {
        free(r);
        return gs_error_set(err, GS_ERR_NOMEM, "redirect quality: out of memory");
    }
    if (opts)
        r->opts = *opts;
    else
        gs_face_quality_opts_default(&r->opts);
    gs_face_iris_opts_default(&r->iris_opts);
    if (r->opts.px_per_mm > 0)
        gs_face_iris_opts_scale(&r->iris_opts, r->opts.px_per_mm);
    memcpy(r->uv, uv, sizeof r->uv);
    r->width = input->width;
    r->height = input->height;
    int rc = GS_OK;
    for (int e = 0; e < 2 && !rc; e++) {
        rc = gs_face_iris_locate(input, (const double(*)[2])r->uv[36 + 6 * e], &r->iris_opts,
                                 &r->iris[e], err);
        r->in_found += !rc && r->iris[e].status == GS_FACE_IRIS_OK;
    }
    if (!rc)
        rc = gs_face_mask(uv, GS_FACE_MASK_EYES, 0, 0, r->width, r->height, r->mask, err);
    if (!rc && r->opts.shape)
        rc = gs_face_normalized_landmarks(r->opts.shape, input, r->pred, err);
    if (rc) {
        gs_face_quality_ref_destroy(r);
        return rc;
    }
    r->energy = fine_energy(input, r->mask);
    *out = r;
    return GS_OK;
}

void gs_face_quality_ref_destroy(gs_face_quality_ref *r)
{
    if (r) {
        free(r->mask);
        free(r);
    }
}

int gs_face_quality_measure(const gs_face_quality_ref *r, const gs_io_image *output,
                            const double head_R[9], double cmd_pitch, double cmd_yaw,
                            gs_face_quality *out, gs_error *err)
{
    if (!r || !output || !output->data || !out)
        return gs_error_set(err, GS_ERR_ARG, "redirect quality: NULL argument");
    if (output->width != r->width || output->height != r->height)
        return gs_error_set(err, GS_ERR_ARG, "redirect quality: images of %dx%d and %dx%d",
                            r->width, r->height, output->width, output->height);
    if (!isfinite(cmd_pitch) || !isfinite(cmd_yaw))
        return gs_error_set(err, GS_ERR_NONFINITE, "redirect quality: non-finite target");
    const gs_face_quality_opts *opts = &r->opts;
    gs_face_quality q;
    memset(&q, 0, sizeof q);
    q.commanded[0] = cmd_pitch;
    q.commanded[1] = cmd_yaw;
    double meas[2] = {0, 0}, de = 0;
    /* The output's eye contours: the input's, moved by the change the
     * landmark model sees (its own bias cancels), or the input's. */
    double moved[12][2];
    if (opts->shape) {
        double pb[GS_FACE_LANDMARKS][2];
        int rc = gs_face_normalized_landmarks(opts->shape, output, pb, err);
        if (rc)
            return rc;
        for (int i = 0; i < 12; i++)
            for (int j = 0; j < 2; j++)
                moved[i][j] = r->uv[36 + i][j] + pb[36 + i][j] - r->pred[36 + i][j];
    } else {
        memcpy(moved, r->uv[36], sizeof moved);
    }
    for (int e = 0; e < 2; e++) {
        const double(*eye)[2] = (const double(*)[2])r->uv[36 + 6 * e];
        const gs_face_iris *a = &r->iris[e];
        gs_face_iris b;
        int rc = gs_face_iris_locate(output, (const double(*)[2])moved[6 * e], &r->iris_opts, &b, err);
        if (rc)
            return rc;
        q.iris[e][0] = *a;
        q.iris[e][1] = b;
        if (a->status != GS_FACE_IRIS_OK || b.status != GS_FACE_IRIS_OK)
            continue;
        double dp, dy;
        if ((rc = gs_face_iris_gaze_change(e, eye, a->centre, eye, b.centre, head_R, &dp, &dy, err)))
            return rc;
        meas[0] += dp;
        meas[1] += dy;
        de += sqrt(sq(a->lab[0] - b.lab[0]) + sq(a->lab[1] - b.lab[1]) + sq(a->lab[2] - b.lab[2]));
        q.eyes++;
    }
    q.artifact = fine_energy(output, r->mask) / fmax(r->energy, 0.5);
    /* The score: one factor per measure, each 1 within its tolerance and
     * falling smoothly past it. */
    double s_gaze, s_colour = 1;
    if (q.eyes) {
        q.measured[0] = meas[0] / q.eyes;
        q.measured[1] = meas[1] / q.eyes;
        q.delta_e = de / q.eyes;
        q.gaze_error_deg = hypot(q.measured[0] - cmd_pitch, q.measured[1] - cmd_yaw) * RAD2DEG;
        double tol = fmax(opts->gaze_tol_deg, opts->gaze_tol_frac * hypot(cmd_pitch, cmd_yaw) * RAD2DEG);
        /* Past the tolerance the factor halves within another 0.6 tol: an
         * output left unchanged (error = the change asked, 20 deg) scores
         * 0.14. */
        s_gaze = exp(-0.5 * sq(fmax(0, q.gaze_error_deg - tol) / (0.5 * tol)));
        s_colour = exp(-0.5 * sq(fmax(0, q.delta_e - opts->max_delta_e) / opts->max_delta_e));
    } else {
        q.measured[0] = q.measured[1] = q.delta_e = q.gaze_error_deg = NAN;
        /* An iris the input shows and the output lost: the eyes are
         * broken. Neither shows one: nothing to measure, half marks. */
        s_gaze = r->in_found ? 0 : 0.5;
    }
    double s_art = exp(-0.5 * sq(fmax(0, q.artifact - opts->max_artifact) / 0.5));
    q.score = s_gaze * s_colour * s_art;
    if (!q.eyes)
        snprintf(q.reason, sizeof q.reason, r->in_found ? "no iris in the output's eyes"
                                                        : "no iris found in the input to compare");
    else if (s_gaze < 0.5)
        snprintf(q.reason, sizeof q.reason, "gaze off by %.1f deg (asked %+.1f, %+.1f; seen %+.1f, %+.1f)",
                 q.gaze_error_deg, cmd_pitch * RAD2DEG, cmd_yaw * RAD2DEG, q.measured[0] * RAD2DEG,
                 q.measured[1] * RAD2DEG);
    else if (s_art < 0.5)
        snprintf(q.reason, sizeof q.reason, "speckle in the eyes: %.2f times the input's", q.artifact);
    else if (s_colour < 0.5)
        snprintf(q.reason, sizeof q.reason, "iris colour changed: delta E %.1f", q.delta_e);
    *out = q;
    return GS_OK;
}

int gs_face_redirect_quality(const gs_io_image *input, const gs_io_image *output,
                             const double uv[][2], const double head_R[9], double cmd_pitch,
                             double cmd_yaw, const gs_face_quality_opts *opts, gs_face_quality *out,
                             gs_error *err)
{
    gs_face_quality_ref *r;
    int rc = gs_face_quality_ref_create(input, uv, opts, &r, err);
    if (rc)
        return rc;
    rc = gs_face_quality_measure(r, output, head_R, cmd_pitch, cmd_yaw, out, err);
    gs_face_quality_ref_destroy(r);
    return rc;
}
