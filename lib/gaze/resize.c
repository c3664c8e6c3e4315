/* Area (box) resize of a window of a CHW image to Nw x Nh, separable: rows
 * then columns. Along an axis of n pixels, the window [a0 n, a1 n) (a0, a1
 * fractions of the image) is cut into N equal intervals; output o averages
 * its interval, each input pixel weighted by its overlap (OpenCV's
 * INTER_AREA when shrinking; when enlarging, a box blending the pixels an
 * output straddles). The weights sum to 1, and the adjoint applies the same
 * weights in the same order: deterministic. */
#include <math.h>
#include <string.h>

#include "gaze_internal.h"

const gz_window gz_full_window = {0.0, 1.0, 0.0, 1.0};

/* Source interval of output o, [*a, *b) in input pixels. */
static void interval(int o, int n, double f0, double f1, int N, double *a, double *b)
{
    double w = (f1 - f0) * n / N;
    *a = f0 * n + o * w;
    *b = *a + w;
}

/* Weight of input pixel i for the interval [a, b). */
static float weight(int i, double a, double b)
{
    double lo = i > a ? i : a, hi = i + 1 < b ? i + 1 : b;
    return hi > lo ? (float)((hi - lo) / (b - a)) : 0.0f;
}

static void span(double a, double b, int n, int *i0, int *i1)
{
    *i0 = (int)floor(a);
    *i1 = (int)ceil(b);
    if (*i0 < 0)
        *i0 = 0;
    if (*i1 > n)
        *i1 = n;
}

/* out[N] (stride os) = area resample of the window [f0, f1) of in[n]
 * (stride is) */
static void resample(float *out, size_t os, const float *in, size_t is, int n, double f0,
                     double f1, int N)
{
    for (int o = 0; o < N; o++) {
        double a, b;
        int i0, i1;
        interval(o, n, f0, f1, N, &a, &b);
        span(a, b, n, &i0, &i1);
        float s = 0.0f;
        for (int i = i0; i < i1; i++)
            s += weight(i, a, b) * in[(size_t)i * is];
        out[(size_t)o * os] = s;
    }
}

/* in[n] += adjoint of resample applied to out[N] */
static void resample_adj(float *in, size_t is, const float *out, size_t os, int n, double f0,
                         double f1, int N)
{
    for (int o = 0; o < N; o++) {
        double a, b;
        int i0, i1;
        interval(o, n, f0, f1, N, &a, &b);
        span(a, b, n, &i0, &i1);
        float g = out[(size_t)o * os];
        for (int i = i0; i < i1; i++)
            in[(size_t)i * is] += weight(i, a, b) * g;
    }
}

/* out[C,Nh,Nw] from the window wd of in[C,h,w]; tmp[C,h,Nw] */
void gz_resize_forward(float *out, const float *in, int C, int w, int h,
                       const gz_window *wd, int Nw, int Nh, float *tmp)
{
    for (int c = 0; c < C; c++) {
        const float *src = in + (size_t)c * (size_t)h * (size_t)w;
        float *t = tmp + (size_t)c * (size_t)h * (size_t)Nw;
        float *dst = out + (size_t)c * (size_t)Nh * (size_t)Nw;
        for (int y = 0; y < h; y++)
            resample(t + (size_t)y * Nw, 1, src + (size_t)y * w, 1, w, wd->x0, wd->x1, Nw);
        for (int x = 0; x < Nw; x++)
            resample(dst + x, (size_t)Nw, t + x, (size_t)Nw, h, wd->y0, wd->y1, Nh);
    }
}

/* din[C,h,w] += adjoint of gz_resize_forward applied to dout[C,Nh,Nw] */
void gz_resize_adjoint(float *din, const float *dout, int C, int w, int h,
                       const gz_window *wd, int Nw, int Nh, float *tmp)
{
    memset(tmp, 0, (size_t)C * (size_t)h * (size_t)Nw * sizeof *tmp);
    for (int c = 0; c < C; c++) {
        float *d = din + (size_t)c * (size_t)h * (size_t)w;
        float *t = tmp + (size_t)c * (size_t)h * (size_t)Nw;
        const float *g = dout + (size_t)c * (size_t)Nh * (size_t)Nw;
        for (int x = 0; x < Nw; x++)
            resample_adj(t + x, (size_t)Nw, g + x, (size_t)Nw, h, wd->y0, wd->y1, Nh);
        for (int y = 0; y < h; y++)
            resample_adj(d + (size_t)y * w, 1, t + (size_t)y * Nw, 1, w, wd->x0, wd->x1, Nw);
    }
}
