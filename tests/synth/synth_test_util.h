/* Helpers shared by the synth tests: scene set-up, image dumps. */
#ifndef GS_SYNTH_TEST_UTIL_H
#define GS_SYNTH_TEST_UTIL_H

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "gazesplat/synth.h"

static const double DEG = 3.14159265358979323846 / 180.0;

/* Writes a binary PPM of the sample when GS_TEST_DUMP names a directory
 * (for looking at failures); does nothing otherwise. */
static inline void dump_ppm(const gs_synth_sample *s, const char *name)
{
    const char *dir = getenv("GS_TEST_DUMP");
    if (!dir)
        return;
    char path[512];
    snprintf(path, sizeof path, "%s/%s.ppm", dir, name);
    FILE *f = fopen(path, "wb");
    if (!f)
        return;
    fprintf(f, "P6\n%d %d\n255\n", s->width, s->height);
    for (int y = 0; y < s->height; y++)
        fwrite(s->rgb + (size_t)y * s->stride, 1, 3 * (size_t)s->width, f);
    fclose(f);
}

/* Linear luminance of pixel (x, y). */
static inline double luminance(const gs_synth_sample *s, int x, int y)
{
    const uint8_t *p = s->rgb + (size_t)y * s->stride + 3 * (size_t)x;
    double c[3];
    for (int i = 0; i < 3; i++) {
        double v = p[i] / 255.0;
        c[i] = v <= 0.04045 ? v / 12.92 : pow((v + 0.055) / 1.055, 2.4);
    }
    return 0.2126 * c[0] + 0.7152 * c[1] + 0.0722 * c[2];
}

/* A camera at the world origin looking along +z with focal f and the
 * principal point placed so that world point x projects to (cx, cy). */
static inline void camera_aimed(int size, double f, const double x[3],
                                gs_synth_camera *cam)
{
    memset(cam, 0, sizeof *cam);
    double k[9] = {f, 0, 0.5 * size - f * x[0] / x[2], 0, f,
                   0.5 * size - f * x[1] / x[2], 0, 0, 1};
    memcpy(cam->K, k, sizeof k);
    cam->R[0] = cam->R[4] = cam->R[8] = 1.0;
    cam->width = cam->height = size;
}

/* Darkness-weighted centroid around (u, v) within rp + 2.5 px: a pixel
 * weighs (l_iris - L) / (l_iris - l_pupil), clamped to [0, 1], which is
 * its pupil coverage for edge pixels. l_pupil is the darkest pixel, l_iris
 * the 10th percentile of a ring just outside the pupil (so iris texture
 * and lid shading around the pupil weigh nothing). */
static inline void dark_centroid(const gs_synth_sample *s, double u, double v,
                          double rp, double out[2])
{
    double ring[2048];
    int nr = 0;
    double lmin = 1e9;
    for (int y = 0; y < s->height; y++)
        for (int x = 0; x < s->width; x++) {
            double dx = x + 0.5 - u, dy = y + 0.5 - v, r = sqrt(dx * dx + dy * dy);
            double lum = luminance(s, x, y);
            if (r < rp + 2.0 && lum < lmin)
                lmin = lum;
            if (r > rp + 1.5 && r < rp + 3.5 && nr < 2048)
                ring[nr++] = lum;
        }
    /* median of the ring (insertion sort, small) */
    for (int i = 1; i < nr; i++)
        for (int j = i; j > 0 && ring[j - 1] > ring[j]; j--) {
            double t = ring[j];
            ring[j] = ring[j - 1];
            ring[j - 1] = t;
        }
    double lref = nr ? ring[nr / 10] : 1.0;
    double sw = 0, sx = 0, sy = 0;
    for (int y = 0; y < s->height; y++)
        for (int x = 0; x < s->width; x++) {
            double dx = x + 0.5 - u, dy = y + 0.5 - v;
            if (dx * dx + dy * dy > (rp + 2.5) * (rp + 2.5))
                continue;
            double w = (lref - luminance(s, x, y)) / (lref - lmin);
            w = w < 0 ? 0 : (w > 1 ? 1 : w);
            sw += w;
            sx += w * (x + 0.5);
            sy += w * (y + 0.5);
        }
    out[0] = sx / sw;
    out[1] = sy / sw;
}

#endif
