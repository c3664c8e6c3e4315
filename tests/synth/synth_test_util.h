/* Helpers shared by the synth tests: scene set-up, image dumps. */
#ifndef GS_SYNTH_TEST_UTIL_H
#define GS_SYNTH_TEST_UTIL_H

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

#endif
