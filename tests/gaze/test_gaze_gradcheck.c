/* Finite differences on tiny estimators (both archs): the gradient of
 * L = sum dout * out with respect to sampled weights of every tensor and to
 * sampled pixels of a non-square input image (which also crosses the area
 * resize), and the resize's adjoint identity <A x, y> = <x, A^T y>.
 * Central differences in float32 with step 1e-3 (one-sided ones at 1e-4
 * where a probe sits on a ReLU kink); tolerance
 * |fd - analytic| <= 2e-3 + 3e-2 |analytic|. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>

#include "gaze_internal.h"
#include "gazesplat/nn.h"
#include "gs_test.h"

enum { IH = 37, IW = 45 };

static uint64_t rs = 12345;
static float urand(void)
{
    rs = rs * 6364136223846793005ull + 1442695040888963407ull;
    return (float)((rs >> 40) * (1.0 / 16777216.0));
}

static double loss(gs_gaze_net *n, const float *img, const float *dout)
{
    float out[4];
    if (gs_gaze_net_forward(n, NULL, img, IW, IH, out, NULL))
        return NAN;
    double l = 0;
    for (int k = 0; k < 4; k++)
        l += (double)dout[k] * out[k];
    return l;
}

/* (L(x + hp) - L(x - hm)) / (hp + hm) */
static double fd_at(gs_gaze_net *n, float *x, float hp, float hm, const float *img,
                    const float *dout)
{
    float x0 = *x;
    *x = x0 + hp;
    double lp = loss(n, img, dout);
    *x = x0 - hm;
    double lm = loss(n, img, dout);
    *x = x0;
    return (lp - lm) / ((double)hp + (double)hm);
}

/* A bias moves a whole channel, so a probe may sit on a ReLU kink, where
 * the analytic gradient is one of the one-sided slopes: the check takes
 * the central difference at 1e-3, else the closest of the central,
 * forward and backward differences at 1e-4. */
static void fd_check(const char *what, gs_gaze_net *n, float *x, float analytic,
                     const float *img, const float *dout)
{
    double tol = 2e-3 + 3e-2 * fabs(analytic);
    double fd = fd_at(n, x, 1e-3f, 1e-3f, img, dout);
    const float h[3][2] = {{1e-4f, 1e-4f}, {1e-4f, 0.0f}, {0.0f, 1e-4f}};
    for (int i = 0; i < 3 && fabs(fd - analytic) > tol; i++) {
        double f = fd_at(n, x, h[i][0], h[i][1], img, dout);
        if (fabs(f - analytic) < fabs(fd - analytic))
            fd = f;
    }
    CHECK_MSG(fabs(fd - analytic) <= tol, "%s: finite difference %.6g, analytic %.6g", what,
              fd, analytic);
}

static void check_arch(int arch)
{
    gs_gaze_spec s;
    gs_gaze_spec_default(&s, arch);
    s.input_size = 32;
    s.widths[0] = 3, s.widths[1] = 4, s.widths[2] = 4, s.widths[3] = 5;
    s.hidden = 6;
    gs_gaze_net *n = NULL;
    gs_error err = {0, ""};
    CHECK_MSG(gs_gaze_net_create(&s, 7, &n, &err) == GS_OK, "%s", err.msg);
    if (!n)
        return;
    size_t np = gs_gaze_net_param_count(n);
    float *P = gs_gaze_net_params(n);
    for (int i = 0; i < n->g.ntensors; i++) /* biases away from zero */
        if (!n->g.t[i].fan_in)
            for (size_t k = 0; k < n->g.t[i].count; k++)
                P[n->g.t[i].off + k] = 0.2f * (urand() - 0.5f);
    for (size_t k = n->g.t[n->g.ntensors - 2].off; k < np; k++)
        P[k] = urand() - 0.5f; /* a last layer that passes gradient */
    float img[3 * IH * IW], dimg[3 * IH * IW] = {0}, dout[4], out[4];
    for (int i = 0; i < 3 * IH * IW; i++)
        img[i] = urand();
    for (int k = 0; k < 4; k++)
        dout[k] = urand() - 0.5f;
    float *dp = calloc(np, sizeof *dp);
    CHECK(gs_gaze_net_forward(n, NULL, img, IW, IH, out, &err) == GS_OK);
    CHECK(gs_gaze_net_backward(n, NULL, dout, dimg, dp, &err) == GS_OK);
    char what[96];
    for (int i = 0; i < n->g.ntensors; i++) {
        const gz_tensor *t = &n->g.t[i];
        for (int j = 0; j < 3; j++) {
            size_t k = t->off + (size_t)(urand() * (float)t->count) % t->count;
            snprintf(what, sizeof what, "%s d%s[%zu]", gs_gaze_arch_name(arch), t->name,
                     k - t->off);
            fd_check(what, n, &P[k], dp[k], img, dout);
        }
    }
    for (int j = 0; j < 24; j++) {
        int k = (int)(urand() * 3 * IH * IW) % (3 * IH * IW);
        snprintf(what, sizeof what, "%s dimg[%d]", gs_gaze_arch_name(arch), k);
        fd_check(what, n, &img[k], dimg[k], img, dout);
    }
    free(dp);
    gs_gaze_net_destroy(n);
}

/* <A x, y> == <x, A^T y> for enlarging and shrinking sizes, the whole
 * image and the eye window (N x N, or N/2 x 5N/4 for the window). */
static void check_resize_adjoint(int w, int h, int N, int eye)
{
    const gz_window *wd = eye ? &gz_eye_window : &gz_full_window;
    int Nw = N, Nh = N;
    if (eye)
        gz_eye_size(N, &Nh, &Nw);
    size_t ni = 3 * (size_t)w * h, no = 3 * (size_t)Nw * Nh;
    float *x = malloc(ni * 4), *ax = malloc(no * 4), *y = malloc(no * 4);
    float *aty = calloc(ni, 4), *tmp = malloc(3 * (size_t)h * Nw * 4);
    for (size_t i = 0; i < ni; i++)
        x[i] = urand();
    for (size_t i = 0; i < no; i++)
        y[i] = urand();
    gz_resize_forward(ax, x, 3, w, h, wd, Nw, Nh, tmp);
    gz_resize_adjoint(aty, y, 3, w, h, wd, Nw, Nh, tmp);
    double a = 0, b = 0;
    for (size_t i = 0; i < no; i++)
        a += (double)ax[i] * y[i];
    for (size_t i = 0; i < ni; i++)
        b += (double)x[i] * aty[i];
    CHECK_MSG(fabs(a - b) <= 1e-4 * fabs(a), "resize %dx%d -> %d: <Ax,y> %.9g <x,A'y> %.9g",
              w, h, N, a, b);
    /* a constant image stays constant: the weights sum to 1 */
    for (size_t i = 0; i < ni; i++)
        x[i] = 0.25f;
    gz_resize_forward(ax, x, 3, w, h, wd, Nw, Nh, tmp);
    for (size_t i = 0; i < no; i++)
        if (fabsf(ax[i] - 0.25f) > 1e-6f) {
            CHECK_MSG(0, "resize %dx%d -> %d: constant 0.25 became %.9g at %zu", w, h, N,
                      ax[i], i);
            break;
        }
    free(x), free(ax), free(y), free(aty), free(tmp);
}

int main(void)
{
    gs_nn_blas_set_threads(1);
    check_arch(GS_GAZE_RESNET);
    check_arch(GS_GAZE_VGG);
    for (int eye = 0; eye < 2; eye++) {
        check_resize_adjoint(45, 37, 32, eye);
        check_resize_adjoint(256, 256, 64, eye);
        check_resize_adjoint(20, 13, 32, eye);
    }
    GS_TEST_END();
}
