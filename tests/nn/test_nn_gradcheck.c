/* Finite-difference gradient checks for every nn kernel and every input and
 * parameter.
 *
 * For a kernel y = f(theta) and a random R, the functional L = sum R . y is
 * evaluated in double from the float32 outputs; its central difference
 * (L(theta_i + h) - L(theta_i - h)) / (actual step) is compared with the
 * backward pass run with dout = R. Kernels that are linear in the checked
 * input (linear, convolutions, resampling, bias terms) use a large step,
 * h = 0.25, where the difference is exact up to float rounding; the others
 * use h = 1e-2 (truncation error ~h^2/6 |f'''|). Inputs of ReLU, LeakyReLU
 * and L1 are kept >= 0.1 away from their kinks.
 *
 * Differences use the 5-point stencil (error O(h^4)).
 *
 * Tolerance per value: |analytic - fd| <= atol + rtol |fd|, with
 *   linear-in-input checks: atol 2e-4, rtol 1e-4
 *   nonlinear checks:       atol 5e-4, rtol 2e-3
 *   SSIM:                   atol 1.5e-5, rtol 5e-3, h = 2e-2. The loss is a
 *     mean of n terms, so its gradients are O(1/n) and the float32 rounding
 *     noise of the loss (~3e-8), over the step, sets a floor near 5e-6 that
 *     no step size removes. The float64 PyTorch comparison
 *     (test_nn_reference) pins these gradients to ~1e-7.
 * Each check prints its worst difference and the share of its tolerance. */
#include "gazesplat/nn.h"
#include "gs_test.h"
#include "nn_test_util.h"

#define LIN_H 0.25f
#define LIN_ATOL 2e-4
#define LIN_RTOL 1e-4
#define NL_H 1e-2f
#define NL_ATOL 5e-4
#define NL_RTOL 2e-3

typedef void (*fwd_fn)(void *ctx, float *out);

typedef struct {
    fwd_fn fwd;
    void *ctx;
    float *out;
    const float *R;
    size_t nout;
} fd_fun;

static double fd_eval(const fd_fun *f)
{
    f->fwd(f->ctx, f->out);
    double s = 0.0;
    for (size_t i = 0; i < f->nout; i++)
        s += (double)f->R[i] * f->out[i];
    return s;
}

/* Central differences of f with respect to param[n], against grad[n]. */
static void fd_check(const char *what, const fd_fun *f, float *param,
                     const float *grad, size_t n, float h, double atol,
                     double rtol)
{
    float *fd = nn_alloc(n);
    double worst = 0.0, worst_ratio = 0.0;
    for (size_t i = 0; i < n; i++) {
        /* 5-point stencil (error O(h^4)); the actual float steps are used */
        float x0 = param[i];
        double x[4], L[4];
        static const float k[4] = {-2.0f, -1.0f, 1.0f, 2.0f};
        for (int j = 0; j < 4; j++) {
            param[i] = x0 + k[j] * h;
            x[j] = (double)param[i] - x0;
            L[j] = fd_eval(f);
        }
        param[i] = x0;
        /* exact weights for the steps taken would differ from the nominal
         * ones only by float rounding of x0 + k h; scale by the mean step */
        double step = (x[3] - x[0] + 2.0 * (x[2] - x[1])) / 8.0;
        fd[i] = (float)((L[0] - 8.0 * L[1] + 8.0 * L[2] - L[3]) / (12.0 * step));
        double d = fabs((double)grad[i] - fd[i]);
        double ratio = d / (atol + rtol * fabs(fd[i]));
        worst = d > worst ? d : worst;
        worst_ratio = ratio > worst_ratio ? ratio : worst_ratio;
    }
    printf("%-28s n=%-4zu max|diff| %.2e  (%.0f%% of tolerance)\n", what, n,
           worst, 100.0 * worst_ratio);
    gs_check_arrays(what, grad, fd, n, atol, rtol);
    free(fd);
}

/* ---- linear -------------------------------------------------------------- */
typedef struct { float *in, *w, *b; int B, IC, OC; } lin_ctx;

static void lin_fwd(void *c, float *out)
{
    lin_ctx *k = c;
    gs_nn_linear_forward(out, k->in, k->w, k->b, k->B, k->IC, k->OC);
}

static void test_linear(nn_rng *r)
{
    lin_ctx k = {0, 0, 0, 3, 4, 5};
    size_t nin = 12, nw = 20, nout = 15;
    k.in = nn_alloc(nin); k.w = nn_alloc(nw); k.b = nn_alloc(5);
    float *din = nn_alloc(nin), *dw = nn_alloc(nw), *db = nn_alloc(5);
    float *R = nn_alloc(nout), *out = nn_alloc(nout);
    nn_fill(r, k.in, nin, -1, 1); nn_fill(r, k.w, nw, -1, 1);
    nn_fill(r, k.b, 5, -1, 1); nn_fill(r, R, nout, -1, 1);
    CHECK_EQ_INT(gs_nn_linear_backward(din, dw, db, R, k.in, k.w, 3, 4, 5), GS_OK);
    fd_fun f = {lin_fwd, &k, out, R, nout};
    fd_check("linear dinp", &f, k.in, din, nin, LIN_H, LIN_ATOL, LIN_RTOL);
    fd_check("linear dw", &f, k.w, dw, nw, LIN_H, LIN_ATOL, LIN_RTOL);
    fd_check("linear db", &f, k.b, db, 5, LIN_H, LIN_ATOL, LIN_RTOL);
    free(k.in); free(k.w); free(k.b); free(din); free(dw); free(db);
    free(R); free(out);
}

/* ---- conv1x1 ------------------------------------------------------------- */
typedef struct { float *in, *w, *b; int IC, OC, HW; } c1_ctx;

static void c1_fwd(void *c, float *out)
{
    c1_ctx *k = c;
    gs_nn_conv1x1_forward(out, k->in, k->w, k->b, k->IC, k->OC, k->HW);
}

static void test_conv1x1(nn_rng *r)
{
    c1_ctx k = {0, 0, 0, 3, 4, 15};
    size_t nin = 45, nw = 12, nout = 60;
    k.in = nn_alloc(nin); k.w = nn_alloc(nw); k.b = nn_alloc(4);
    float *din = nn_alloc(nin), *dw = nn_alloc(nw), *db = nn_alloc(4);
    float *R = nn_alloc(nout), *out = nn_alloc(nout);
    nn_fill(r, k.in, nin, -1, 1); nn_fill(r, k.w, nw, -1, 1);
    nn_fill(r, k.b, 4, -1, 1); nn_fill(r, R, nout, -1, 1);
    CHECK_EQ_INT(gs_nn_conv1x1_backward(din, dw, db, R, k.in, k.w, 3, 4, 15), GS_OK);
    fd_fun f = {c1_fwd, &k, out, R, nout};
    fd_check("conv1x1 dinp", &f, k.in, din, nin, LIN_H, LIN_ATOL, LIN_RTOL);
    fd_check("conv1x1 dw", &f, k.w, dw, nw, LIN_H, LIN_ATOL, LIN_RTOL);
    fd_check("conv1x1 db", &f, k.b, db, 4, LIN_H, LIN_ATOL, LIN_RTOL);
    free(k.in); free(k.w); free(k.b); free(din); free(dw); free(db);
    free(R); free(out);
}

/* ---- conv3x3 ------------------------------------------------------------- */
typedef struct { float *in, *w, *b, *scratch; size_t ns; int IC, OC, H, W; } c3_ctx;

static void c3_fwd(void *c, float *out)
{
    c3_ctx *k = c;
    gs_nn_conv3x3_forward(out, k->in, k->w, k->b, k->IC, k->OC, k->H, k->W,
                          k->scratch, k->ns);
}

static void test_conv3x3(nn_rng *r)
{
    c3_ctx k = {0, 0, 0, 0, 0, 2, 3, 5, 4};
    size_t nin = 40, nw = 54, nout = 60;
    k.ns = gs_nn_conv3x3_scratch_size(2, 5, 4);
    k.in = nn_alloc(nin); k.w = nn_alloc(nw); k.b = nn_alloc(3);
    k.scratch = nn_alloc(k.ns);
    float *din = nn_alloc(nin), *dw = nn_alloc(nw), *db = nn_alloc(3);
    float *R = nn_alloc(nout), *out = nn_alloc(nout);
    nn_fill(r, k.in, nin, -1, 1); nn_fill(r, k.w, nw, -1, 1);
    nn_fill(r, k.b, 3, -1, 1); nn_fill(r, R, nout, -1, 1);
    CHECK_EQ_INT(gs_nn_conv3x3_backward(din, dw, db, R, k.in, k.w, 2, 3, 5, 4,
                                        k.scratch, k.ns), GS_OK);
    fd_fun f = {c3_fwd, &k, out, R, nout};
    fd_check("conv3x3 dinp", &f, k.in, din, nin, LIN_H, LIN_ATOL, LIN_RTOL);
    fd_check("conv3x3 dw", &f, k.w, dw, nw, LIN_H, LIN_ATOL, LIN_RTOL);
    fd_check("conv3x3 db", &f, k.b, db, 3, LIN_H, LIN_ATOL, LIN_RTOL);
    free(k.in); free(k.w); free(k.b); free(k.scratch); free(din); free(dw);
    free(db); free(R); free(out);
}

/* ---- elementwise and softmax --------------------------------------------- */
enum { ACT_RELU, ACT_LRELU, ACT_TANH, ACT_SIGMOID, ACT_SOFTMAX };
typedef struct { float *in; int n, kind; } act_ctx;

static void act_fwd(void *c, float *out)
{
    act_ctx *k = c;
    size_t n = (size_t)k->n;
    switch (k->kind) {
    case ACT_RELU: gs_nn_relu_forward(out, k->in, n); break;
    case ACT_LRELU: gs_nn_leaky_relu_forward(out, k->in, 0.2f, n); break;
    case ACT_TANH: gs_nn_tanh_forward(out, k->in, n); break;
    case ACT_SIGMOID: gs_nn_sigmoid_forward(out, k->in, n); break;
    default: gs_nn_softmax_forward(out, k->in, k->n); break;
    }
}

static void test_activation(nn_rng *r, int kind, const char *what)
{
    enum { N = 11 };
    float in[N], out[N], din[N] = {0}, R[N];
    act_ctx k = {in, N, kind};
    if (kind == ACT_RELU || kind == ACT_LRELU)
        nn_fill_away(r, in, N, 0.1f, 2.0f);
    else
        nn_fill(r, in, N, -3, 3);
    nn_fill(r, R, N, -1, 1);
    act_fwd(&k, out);
    int rc;
    switch (kind) {
    case ACT_RELU: rc = gs_nn_relu_backward(din, R, in, N); break;
    case ACT_LRELU: rc = gs_nn_leaky_relu_backward(din, R, in, 0.2f, N); break;
    case ACT_TANH: rc = gs_nn_tanh_backward(din, R, out, N); break;
    case ACT_SIGMOID: rc = gs_nn_sigmoid_backward(din, R, out, N); break;
    default: rc = gs_nn_softmax_backward(din, R, out, N); break;
    }
    CHECK_EQ_INT(rc, GS_OK);
    fd_fun f = {act_fwd, &k, out, R, N};
    fd_check(what, &f, in, din, N, NL_H, NL_ATOL, NL_RTOL);
}

/* ---- resampling ------------------------------------------------------------ */
enum { RS_SHUFFLE, RS_UP, RS_BLUR, RS_POOL };
typedef struct { float *in; int C, H, W, kind; } rs_ctx;

static void rs_fwd(void *c, float *out)
{
    rs_ctx *k = c;
    if (k->kind == RS_SHUFFLE)
        gs_nn_pixel_shuffle_forward(out, k->in, k->C, k->H, k->W);
    else if (k->kind == RS_UP)
        gs_nn_upsample2x_forward(out, k->in, k->C, k->H, k->W);
    else if (k->kind == RS_BLUR)
        gs_nn_blur_forward(out, k->in, k->C, k->H, k->W);
    else
        gs_nn_avgpool2x_forward(out, k->in, k->C, k->H, k->W);
}

static void test_resample(nn_rng *r, int kind, int C, int H, int W,
                          const char *what)
{
    size_t hw = (size_t)H * (size_t)W;
    size_t nin = (kind == RS_SHUFFLE ? 4 : 1) * (size_t)C * hw;
    size_t nout = (kind == RS_BLUR ? 4 : kind == RS_POOL ? 1 : 16) * (size_t)C * hw / 4;
    rs_ctx k = {nn_alloc(nin), C, H, W, kind};
    float *din = nn_alloc(nin), *R = nn_alloc(nout), *out = nn_alloc(nout);
    nn_fill(r, k.in, nin, -1, 1);
    nn_fill(r, R, nout, -1, 1);
    int rc;
    if (kind == RS_SHUFFLE)
        rc = gs_nn_pixel_shuffle_backward(din, R, C, H, W);
    else if (kind == RS_UP)
        rc = gs_nn_upsample2x_backward(din, R, C, H, W);
    else if (kind == RS_BLUR)
        rc = gs_nn_blur_backward(din, R, C, H, W);
    else
        rc = gs_nn_avgpool2x_backward(din, R, C, H, W);
    CHECK_EQ_INT(rc, GS_OK);
    fd_fun f = {rs_fwd, &k, out, R, nout};
    fd_check(what, &f, k.in, din, nin, LIN_H, LIN_ATOL, LIN_RTOL);
    free(k.in); free(din); free(R); free(out);
}

/* ---- attention ----------------------------------------------------------- */
typedef struct {
    float *x, *code, *wk, *bk, *wv, *bv, *att, *scratch;
    size_t ns;
    int C, D, HW;
    float temp;
} at_ctx;

static void at_fwd(void *c, float *out)
{
    at_ctx *k = c;
    gs_nn_attention_forward(out, k->att, k->x, k->code, k->wk, k->bk, k->wv,
                            k->bv, k->C, k->D, k->HW, k->temp, k->scratch,
                            k->ns);
}

static void test_attention(nn_rng *r)
{
    enum { C = 4, D = 6, HW = 12 };
    at_ctx k = {0};
    k.C = C; k.D = D; k.HW = HW; k.temp = 2.5f;
    k.ns = gs_nn_attention_scratch_size(C);
    k.x = nn_alloc(C * HW); k.code = nn_alloc(D); k.wk = nn_alloc(D * C);
    k.bk = nn_alloc(D); k.wv = nn_alloc(C * C); k.bv = nn_alloc(C);
    k.att = nn_alloc(HW); k.scratch = nn_alloc(k.ns);
    float *dx = nn_alloc(C * HW), *dcode = nn_alloc(D), *dwk = nn_alloc(D * C);
    float *dbk = nn_alloc(D), *dwv = nn_alloc(C * C), *dbv = nn_alloc(C);
    float *R = nn_alloc(C * HW), *out = nn_alloc(C * HW);
    nn_fill(r, k.x, C * HW, -1, 1); nn_fill(r, k.code, D, -1, 1);
    nn_fill(r, k.wk, D * C, -1, 1); nn_fill(r, k.bk, D, -1, 1);
    nn_fill(r, k.wv, C * C, -1, 1); nn_fill(r, k.bv, C, -1, 1);
    nn_fill(r, R, C * HW, -1, 1);
    at_fwd(&k, out);
    CHECK_EQ_INT(gs_nn_attention_backward(dx, dcode, dwk, dbk, dwv, dbv, R, k.x,
                                          k.att, k.code, k.wk, k.wv, C, D, HW,
                                          k.temp, k.scratch, k.ns), GS_OK);
    fd_fun f = {at_fwd, &k, out, R, C * HW};
    fd_check("attention dx", &f, k.x, dx, C * HW, NL_H, NL_ATOL, NL_RTOL);
    fd_check("attention dcode", &f, k.code, dcode, D, NL_H, NL_ATOL, NL_RTOL);
    fd_check("attention dwk", &f, k.wk, dwk, D * C, NL_H, NL_ATOL, NL_RTOL);
    fd_check("attention dbk", &f, k.bk, dbk, D, NL_H, NL_ATOL, NL_RTOL);
    fd_check("attention dwv", &f, k.wv, dwv, C * C, LIN_H, LIN_ATOL, LIN_RTOL);
    fd_check("attention dbv", &f, k.bv, dbv, C, LIN_H, LIN_ATOL, LIN_RTOL);
    for (int d = 0; d < D; d++)
        CHECK_MSG(dbk[d] == 0.0f, "dbk[%d] = %g, must be exactly 0", d, dbk[d]);
    free(k.x); free(k.code); free(k.wk); free(k.bk); free(k.wv); free(k.bv);
    free(k.att); free(k.scratch); free(dx); free(dcode); free(dwk); free(dbk);
    free(dwv); free(dbv); free(R); free(out);
}

/* ---- losses -------------------------------------------------------------- */
typedef struct { float *a, *b, *mask; int C, HW; } l1_ctx;

static void l1_fwd(void *c, float *out)
{
    l1_ctx *k = c;
    gs_nn_l1_forward(out, k->a, k->b, k->mask, k->C, k->HW);
}

static void test_l1(nn_rng *r, int masked)
{
    enum { C = 2, HW = 10 };
    float a[C * HW], b[C * HW], m[HW], da[C * HW] = {0}, out[1], R[1];
    nn_fill(r, b, C * HW, 0, 1);
    nn_fill_away(r, a, C * HW, 0.1f, 0.5f); /* a - b away from 0 */
    for (int i = 0; i < C * HW; i++)
        a[i] += b[i];
    nn_fill(r, m, HW, 0, 1);
    nn_fill(r, R, 1, 0.5f, 2);
    l1_ctx k = {a, b, masked ? m : NULL, C, HW};
    CHECK_EQ_INT(gs_nn_l1_backward(da, R[0], a, b, k.mask, C, HW), GS_OK);
    fd_fun f = {l1_fwd, &k, out, R, 1};
    fd_check(masked ? "l1 masked da" : "l1 da", &f, a, da, C * HW, NL_H,
             NL_ATOL, NL_RTOL);
}

typedef struct { float *x, *y, *scratch; size_t ns; int C, H, W, pad; } ss_ctx;

static void ss_fwd(void *c, float *out)
{
    ss_ctx *k = c;
    gs_nn_ssim_loss_forward(out, k->x, k->y, k->C, k->H, k->W, k->pad,
                            k->scratch, k->ns);
}

static void test_ssim(nn_rng *r, int C, int H, int W, int pad,
                      const char *what)
{
    size_t n = (size_t)C * H * W;
    ss_ctx k = {nn_alloc(n), nn_alloc(n), 0, gs_nn_ssim_scratch_size(H, W, pad),
                C, H, W, pad};
    k.scratch = nn_alloc(k.ns);
    float *dx = nn_alloc(n), out[1], R[1];
    nn_fill(r, k.y, n, 0, 1);
    for (size_t i = 0; i < n; i++)
        k.x[i] = 0.6f * k.y[i] + nn_rng_uniform(r, 0, 0.4f);
    nn_fill(r, R, 1, 0.5f, 2);
    CHECK_EQ_INT(gs_nn_ssim_loss_backward(dx, R[0], k.x, k.y, C, H, W, pad,
                                          k.scratch, k.ns), GS_OK);
    fd_fun f = {ss_fwd, &k, out, R, 1};
    fd_check(what, &f, k.x, dx, n, 2e-2f, 1.5e-5, 5e-3);
    free(k.x); free(k.y); free(k.scratch); free(dx);
}

int main(void)
{
    nn_rng r = {12345};
    test_linear(&r);
    test_conv1x1(&r);
    test_conv3x3(&r);
    test_activation(&r, ACT_RELU, "relu dinp");
    test_activation(&r, ACT_LRELU, "leaky_relu dinp");
    test_activation(&r, ACT_TANH, "tanh dinp");
    test_activation(&r, ACT_SIGMOID, "sigmoid dinp");
    test_activation(&r, ACT_SOFTMAX, "softmax dinp");
    test_resample(&r, RS_SHUFFLE, 2, 2, 3, "pixel_shuffle dinp");
    test_resample(&r, RS_UP, 2, 3, 4, "upsample2x dinp");
    test_resample(&r, RS_UP, 1, 1, 2, "upsample2x dinp 1x2");
    test_resample(&r, RS_BLUR, 2, 4, 5, "blur dinp");
    test_resample(&r, RS_BLUR, 1, 2, 3, "blur dinp 2x3");
    test_resample(&r, RS_POOL, 2, 4, 6, "avgpool2x dinp");
    test_resample(&r, RS_POOL, 1, 2, 2, "avgpool2x dinp 2x2");
    test_attention(&r);
    test_l1(&r, 0);
    test_l1(&r, 1);
    test_ssim(&r, 2, 12, 13, GS_NN_SSIM_VALID, "ssim valid dx");
    test_ssim(&r, 1, 7, 8, GS_NN_SSIM_ZERO, "ssim zero-pad dx");
    GS_TEST_END();
}
