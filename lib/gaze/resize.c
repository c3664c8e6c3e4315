/* Area (box) resize of a CHW image to N x N, separable: rows then columns.
 * Output sample o of an axis of n inputs covers [o n / N, (o + 1) n / N);
 * each input pixel weighs its overlap with that interval over its length
 * (OpenCV's INTER_AREA for shrinking; for enlarging, a box that blends the
 * two pixels an output straddles). The weights sum to 1, and the adjoint
 * applies the same weights in the same order: deterministic. */
#include <math.h>
#include <string.h>

#include "gaze_internal.h"

/* Source interval of output o, as [a, b) in input pixels. */
static void interval(int o, int n, int N, double *a, double *b)
{
    *a = (double)o * n / N;
    *b = (double)(o + 1) * n / N;
}

/* Weight of input pixel i for the interval [a, b). */
static float weight(int i, double a, double b)
{
    double lo = i > a ? i : a, hi = i + 1 < b ? i + 1 : b;
    return hi > lo ? (float)((hi - lo) / (b - a)) : 0.0f;
}

/* out[N] = area resample of in[n] (strided) */
static void resample(float *out, size_t ostride, const float *in,
                     size_t istride, int n, int N)
{
    for (int o = 0; o < N; o++) {
        double a, b;
        interval(o, n, N, &a, &b);
        int i0 = (int)floor(a), i1 = (int)ceil(b);
        if (i1 > n)
            i1 = n;
        float s = 0.0f;
        for (int i = i0; i < i1; i++)
            s += weight(i, a, b) * in[(size_t)i * istride];
        out[(size_t)o * ostride] = s;
    }
}

/* in[n] += adjoint of resample applied to out[N] */
static void resample_adj(float *in, size_t istride, const float *out,
                         size_t ostride, int n, int N)
{
    for (int o = 0; o < N; o++) {
        double a, b;
        interval(o, n, N, &a, &b);
        int i0 = (int)floor(a), i1 = (int)ceil(b);
        if (i1 > n)
            i1 = n;
        float g = out[(size_t)o * ostride];
        for (int i = i0; i < i1; i++)
            in[(size_t)i * istride] += weight(i, a, b) * g;
    }
}

/* out[C,N,N] from in[C,h,w]; tmp[C,h,N] */
void gz_resize_forward(float *out, const float *in, int C, int w, int h,
                       int N, float *tmp)
{
    for (int c = 0; c < C; c++) {
        const float *src = in + (size_t)c * (size_t)h * (size_t)w;
        float *t = tmp + (size_t)c * (size_t)h * (size_t)N;
        float *dst = out + (size_t)c * (size_t)N * (size_t)N;
        for (int y = 0; y < h; y++)
            resample(t + (size_t)y * N, 1, src + (size_t)y * w, 1, w, N);
        for (int x = 0; x < N; x++)
            resample(dst + x, (size_t)N, t + x, (size_t)N, h, N);
    }
}

/* din[C,h,w] += adjoint of gz_resize_forward applied to dout[C,N,N] */
void gz_resize_adjoint(float *din, const float *dout, int C, int w, int h,
                       int N, float *tmp)
{
    size_t tn = (size_t)C * (size_t)h * (size_t)N;
    memset(tmp, 0, tn * sizeof *tmp);
    for (int c = 0; c < C; c++) {
        float *d = din + (size_t)c * (size_t)h * (size_t)w;
        float *t = tmp + (size_t)c * (size_t)h * (size_t)N;
        const float *g = dout + (size_t)c * (size_t)N * (size_t)N;
        for (int x = 0; x < N; x++)
            resample_adj(t + x, (size_t)N, g + x, (size_t)N, h, N);
        for (int y = 0; y < h; y++)
            resample_adj(d + (size_t)y * w, 1, t + (size_t)y * N, 1, w, N);
    }
}
