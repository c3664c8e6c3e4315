/* Red-eye (gs_face_red_eye_fix): a flash's light back from the retina
 * turns the pupil red. Left in a photo it is a dark-red disc that the fit
 * and the detail transfer both keep where it was, so a redirected face
 * shows the old pupil beside the new iris (a ghost; its gaze barely moves).
 *
 * Per eye: the iris localizer (iris.c) finds the iris and, where one
 * stands out, the pupil; its grey, (2G + B) / 3, reads a red-eye pupil as
 * dark, so the eye is located like any other. A pixel is red when its red
 * stands well above both other channels (R > RATIO max(G, B) and
 * R - max(G, B) > MARGIN): a glint (white), a bright white pupil and most
 * skin are not, but a brown iris or lid under warm light can be, so the
 * decision is the eye's, not the pixel's. The eye has red-eye when at
 * least MIN_SHARE of the pixels of its pupil disc (the pupil's, or 0.45
 * of the iris radius when no pupil stands out) are, and a smaller share of the iris ring around it (from REACH pupil
 * radii out to the limbus), under RING_SHARE: under warm light, or with a
 * camera's red cast, lids, skin and iris are as red as such a pupil, and
 * nothing stands out. (On the test photos: the red-eye pupils of sample6
 * face 0, 95 % and 40 % of the disc against 5 % and 28 % of the ring; the
 * warm-lit brown eye of sample5 face 2, 47 % against 61 %.) Then every red
 * pixel inside the eye's contour and within REACH pupil radii of the
 * centre gets R = (G + B) / 2, the usual repair: the pupil's own dark is
 * kept and its red goes. Nothing else is touched, so
 * an eye without red-eye keeps its bytes. */
#include <math.h>
#include <string.h>

#include "gazesplat/face.h"
#include "face_internal.h"

#define RATIO 1.35
#define MARGIN 40
#define MIN_SHARE 0.3
#define REACH 1.35
#define PUPIL_OF_IRIS 0.45
#define RING_SHARE 0.5

static int is_red(const uint8_t *p)
{
    int m = p[1] > p[2] ? p[1] : p[2];
    return p[0] > RATIO * m && p[0] - m > MARGIN;
}

/* Counts (and with fix, repairs) the red pixels at distances in
 * [r0, r1] from (cx, cy) inside the contour; *seen gets the number of
 * pixels looked at. */
static int red_ring(gs_io_image *img, const double c[6][2], double cx, double cy,
                    double r0, double r1, int fix, int *seen)
{
    int x0 = (int)floor(cx - r1), x1 = (int)ceil(cx + r1);
    int y0 = (int)floor(cy - r1), y1 = (int)ceil(cy + r1);
    x0 = x0 < 0 ? 0 : x0, y0 = y0 < 0 ? 0 : y0;
    x1 = x1 > img->width ? img->width : x1, y1 = y1 > img->height ? img->height : y1;
    int red = 0, n = 0;
    for (int y = y0; y < y1; y++)
        for (int x = x0; x < x1; x++) {
            double dx = x + 0.5 - cx, dy = y + 0.5 - cy, d2 = dx * dx + dy * dy;
            if (d2 > r1 * r1 || d2 < r0 * r0 || gs_face_contour_dist(c, x + 0.5, y + 0.5) > 0)
                continue;
            n++;
            uint8_t *p = img->data + (size_t)y * img->stride + 3 * (size_t)x;
            if (!is_red(p))
                continue;
            red++;
            if (fix)
                p[0] = (uint8_t)((p[1] + p[2] + 1) / 2);
        }
    if (seen)
        *seen = n;
    return red;
}

int gs_face_red_eye_fix(gs_io_image *img, const double uv[GS_FACE_LANDMARKS][2],
                        double px_per_mm, int *fixed_px, gs_error *err)
{
    if (fixed_px)
        *fixed_px = 0;
    if (!img || !img->data || !uv || img->width < 1 || img->height < 1 ||
        img->stride < 3 * (size_t)img->width)
        return gs_error_set(err, GS_ERR_ARG, "red-eye: bad image or landmarks");
    gs_face_iris_opts o;
    gs_face_iris_opts_default(&o);
    if (px_per_mm > 0)
        gs_face_iris_opts_scale(&o, px_per_mm);
    int total = 0;
    for (int e = 0; e < 2; e++) {
        const double(*c)[2] = (const double(*)[2])uv[36 + 6 * e];
        gs_face_iris ir;
        int rc = gs_face_iris_locate(img, c, &o, &ir, err);
        if (rc != GS_OK)
            return rc;
        if (ir.status != GS_FACE_IRIS_OK && ir.status != GS_FACE_IRIS_PARTIAL)
            continue;
        double cx = ir.centre[0], cy = ir.centre[1], rp = PUPIL_OF_IRIS * ir.radius;
        if (ir.pupil_radius > 0 && isfinite(ir.pupil_centre[0])) {
            cx = ir.pupil_centre[0], cy = ir.pupil_centre[1], rp = ir.pupil_radius;
        }
        /* red-eye: the pupil red, the iris ring around it not (warm light
         * or a red-tinted camera reddens skin, lids and iris alike) */
        int disc = 0, red = red_ring(img, c, cx, cy, 0, rp, 0, &disc);
        if (disc == 0 || red < MIN_SHARE * disc)
            continue;
        double ro = fmax(0.95 * ir.radius, (REACH + 0.4) * rp);
        int ring = 0, ring_red = red_ring(img, c, cx, cy, REACH * rp, ro, 0, &ring);
        if (ring == 0 || (double)ring_red / ring >= fmin(RING_SHARE, (double)red / disc))
            continue;
        total += red_ring(img, c, cx, cy, 0, REACH * rp, 1, NULL);
    }
    if (fixed_px)
        *fixed_px = total;
    return GS_OK;
}
