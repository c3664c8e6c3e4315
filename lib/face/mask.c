/* Face and eye masks from the 68 landmarks, rasterized at pixel centres
 * (+0.5) from the signed distance to a polygon: grown by a margin, with a
 * linear ramp across the edge. */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "face_internal.h"

#define MAX_POLY 32

typedef struct poly {
    int n;
    double p[MAX_POLY][2];
} poly;

static double cross(const double o[2], const double a[2], const double b[2])
{
    return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0]);
}

static int lex_less(const double a[2], const double b[2])
{
    return a[0] < b[0] || (a[0] == b[0] && a[1] < b[1]);
}

/* Convex hull (Andrew's monotone chain) of n <= MAX_POLY points. */
static void hull(const double (*pts)[2], int n, poly *out)
{
    double s[MAX_POLY][2];
    memcpy(s, pts, (size_t)n * sizeof s[0]);
    for (int i = 1; i < n; i++) /* insertion sort: n is tiny */
        for (int j = i; j > 0 && lex_less(s[j], s[j - 1]); j--) {
            double t[2] = {s[j][0], s[j][1]};
            memcpy(s[j], s[j - 1], sizeof t);
            memcpy(s[j - 1], t, sizeof t);
        }
    double h[2 * MAX_POLY][2];
    int k = 0;
    for (int i = 0; i < n; i++) {
        while (k >= 2 && cross(h[k - 2], h[k - 1], s[i]) <= 0)
            k--;
        memcpy(h[k++], s[i], sizeof h[0]);
    }
    for (int i = n - 2, lo = k + 1; i >= 0; i--) {
        while (k >= lo && cross(h[k - 2], h[k - 1], s[i]) <= 0)
            k--;
        memcpy(h[k++], s[i], sizeof h[0]);
    }
    out->n = k > 1 ? k - 1 : k;
    memcpy(out->p, h, (size_t)out->n * sizeof h[0]);
}

/* Signed distance from q to the polygon boundary, negative inside
 * (even-odd rule). */
static double signed_dist(const poly *pg, double qx, double qy)
{
    double best = INFINITY;
    int inside = 0;
    for (int i = 0, j = pg->n - 1; i < pg->n; j = i++) {
        const double *a = pg->p[j], *b = pg->p[i];
        double ex = b[0] - a[0], ey = b[1] - a[1];
        double wx = qx - a[0], wy = qy - a[1];
        double ee = ex * ex + ey * ey;
        double t = ee > 0 ? (wx * ex + wy * ey) / ee : 0;
        t = t < 0 ? 0 : t > 1 ? 1 : t;
        double dx = wx - t * ex, dy = wy - t * ey;
        double d = dx * dx + dy * dy;
        if (d < best)
            best = d;
        if ((a[1] > qy) != (b[1] > qy) && qx < a[0] + (qy - a[1]) * ex / ey)
            inside = !inside;
    }
    return inside ? -sqrt(best) : sqrt(best);
}

/* mask = max(mask, coverage of pg grown by `grow` with a `feather` ramp). */
static void raster_max(const poly *pg, double grow, double feather, int w, int h, uint8_t *mask)
{
    double lo[2] = {INFINITY, INFINITY}, hi[2] = {-INFINITY, -INFINITY};
    for (int i = 0; i < pg->n; i++)
        for (int c = 0; c < 2; c++) {
            lo[c] = fmin(lo[c], pg->p[i][c]);
            hi[c] = fmax(hi[c], pg->p[i][c]);
        }
    double reach = grow + feather * 0.5 + 1;
    int x0 = (int)fmax(0, floor(lo[0] - reach)), x1 = (int)fmin(w - 1, ceil(hi[0] + reach));
    int y0 = (int)fmax(0, floor(lo[1] - reach)), y1 = (int)fmin(h - 1, ceil(hi[1] + reach));
    for (int y = y0; y <= y1; y++)
        for (int x = x0; x <= x1; x++) {
            double d = signed_dist(pg, x + 0.5, y + 0.5) - grow;
            double a = feather > 0 ? 0.5 - d / feather : (d <= 0 ? 1 : 0);
            a = a < 0 ? 0 : a > 1 ? 1 : a;
            uint8_t v = (uint8_t)lround(255 * a);
            uint8_t *m = mask + (size_t)y * w + x;
            if (v > *m)
                *m = v;
        }
}

/* Face polygon: hull of the jaw and the brows raised by 10% of the
 * brow-to-chin distance (a strip of forehead). */
static void face_poly(const double (*uv)[2], poly *out)
{
    double pts[27][2], brow[2] = {0, 0};
    for (int i = 17; i < 27; i++) {
        brow[0] += uv[i][0] / 10;
        brow[1] += uv[i][1] / 10;
    }
    double up[2] = {0.1 * (brow[0] - uv[8][0]), 0.1 * (brow[1] - uv[8][1])};
    for (int i = 0; i < 27; i++) {
        pts[i][0] = uv[i][0] + (i >= 17 ? up[0] : 0);
        pts[i][1] = uv[i][1] + (i >= 17 ? up[1] : 0);
    }
    hull((const double(*)[2])pts, 27, out);
}

/* Eye polygon (6 points from `first`) and its width. */
static double eye_poly(const double (*uv)[2], int first, poly *out)
{
    out->n = 6;
    for (int i = 0; i < 6; i++)
        memcpy(out->p[i], uv[first + i], sizeof out->p[i]);
    return hypot(uv[first + 3][0] - uv[first][0], uv[first + 3][1] - uv[first][1]);
}

/* Eye masks are grown by this share of the eye width so lids and a margin
 * of skin move with the eye; the openings are not. */
#define EYE_GROW 0.3

/* The eyes in `which` (bit 0 right, bit 1 left), each polygon grown by
 * dilate plus `grow` of its width. */
static void eyes(const double (*uv)[2], int which, double dilate, double grow, double feather,
                 int w, int h, uint8_t *mask)
{
    static const int first[2] = {36, 42};
    for (int e = 0; e < 2; e++) {
        if (!(which & (1 << e)))
            continue;
        poly pg;
        double ew = eye_poly(uv, first[e], &pg);
        raster_max(&pg, dilate + grow * ew, feather, w, h, mask);
    }
}

int gs_face_mask(const double uv[][2], gs_face_mask_kind kind, double dilate, double feather,
                 int width, int height, uint8_t *mask, gs_error *err)
{
    if (!uv || !mask || width < 1 || height < 1 || !isfinite(dilate) || !isfinite(feather) ||
        feather < 0 || (size_t)width * (size_t)height > ((size_t)1 << 30))
        return gs_error_set(err, GS_ERR_ARG, "mask: bad arguments");
    for (int i = 0; i < GS_FACE_LANDMARKS; i++)
        if (!isfinite(uv[i][0]) || !isfinite(uv[i][1]))
            return gs_error_set(err, GS_ERR_NONFINITE, "mask: non-finite landmark %d", i);
    size_t npx = (size_t)width * (size_t)height;
    memset(mask, 0, npx);
    poly pg;
    switch (kind) {
    case GS_FACE_MASK_FACE:
        face_poly(uv, &pg);
        raster_max(&pg, dilate, feather, width, height, mask);
        return GS_OK;
    case GS_FACE_MASK_FACE_NO_EYES: {
        face_poly(uv, &pg);
        raster_max(&pg, dilate, feather, width, height, mask);
        /* Subtract the eyes (drawn without the dilation). */
        uint8_t *eye = calloc(npx, 1);
        if (!eye)
            return gs_error_set(err, GS_ERR_NOMEM, "mask: out of memory");
        eyes(uv, 3, 0, EYE_GROW, feather, width, height, eye);
        for (size_t i = 0; i < npx; i++)
            mask[i] = (uint8_t)((mask[i] * (255 - eye[i]) + 127) / 255);
        free(eye);
        return GS_OK;
    }
    case GS_FACE_MASK_EYES:
        eyes(uv, 3, dilate, EYE_GROW, feather, width, height, mask);
        return GS_OK;
    case GS_FACE_MASK_RIGHT_EYE:
        eyes(uv, 1, dilate, EYE_GROW, feather, width, height, mask);
        return GS_OK;
    case GS_FACE_MASK_LEFT_EYE:
        eyes(uv, 2, dilate, EYE_GROW, feather, width, height, mask);
        return GS_OK;
    case GS_FACE_MASK_EYE_OPENINGS:
        eyes(uv, 3, dilate, 0.0, feather, width, height, mask);
        return GS_OK;
    }
    return gs_error_set(err, GS_ERR_ARG, "mask: unknown kind %d", (int)kind);
}
