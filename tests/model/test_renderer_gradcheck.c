/* Finite-difference check of the renderer's backward pass, every guidance
 * mode and source (the SOURCE cases also check the source map), on a small network (C = 4, D = 5) so that EVERY parameter, every
 * element of x and every element of tau is checked.
 *
 * For L = sum R . out (R random), the central difference
 * (L(theta + h) - L(theta - h)) / (actual step), L summed in double from the
 * float32 image, is compared with the backward pass run with dout = R.
 * h = 1e-3: small enough that few LeakyReLU kinks fall inside the step and
 * the truncation error (~h^2 |L'''| / 6) is negligible; the float32 rounding
 * of the image then sets the noise floor, measured at 2e-4 to 6e-4 here.
 *
 * Tolerance per value: |analytic - fd| <= ATOL + RTOL |fd| (gradients are
 * O(0.1 to 1)). A kink inside the step shows as an isolated outlier that
 * grows with h: the seeds here give one, in the additive block1.conv_b.bias
 * (2.1e-3 at h = 1e-3, 5e-3 at h = 3e-3), within ATOL. The float64 PyTorch
 * comparison (test_renderer_reference) pins every gradient to ~1e-6
 * relative on the full-width network. The value
 * projection wv, bv is drawn large so that the guidance changes the image
 * by tens of percent (the multiplicative mode most of all). */
#include "gazesplat/nn.h"
#include "gs_test.h"
#include "renderer.h"

#include <stdint.h>
#include <string.h>

#define FD_H 1e-3f
#define ATOL 2e-3
#define RTOL 1e-2

typedef struct {
    gs_renderer_config cfg;
    int H, W;
    size_t np, nx, nout, na;
    float *params, *x, *tau, *R, *acts, *out, *src; /* src: SOURCE only */
    gs_renderer_params p;
} fd_case;

static uint64_t g_rng = 0x1234567ull;

static float urand(float lo, float hi)
{
    uint64_t z = (g_rng += 0x9E3779B97F4A7C15ull);
    z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
    z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
    z ^= z >> 31;
    return lo + (hi - lo) * (float)((double)(z >> 11) * (1.0 / 9007199254740992.0));
}

static void fill(float *a, size_t n, float bound)
{
    for (size_t i = 0; i < n; i++)
        a[i] = urand(-bound, bound);
}

static void *xcalloc(size_t n)
{
    void *p = calloc(n ? n : 1, sizeof(float));
    if (!p) {
        fprintf(stderr, "out of memory\n");
        exit(2);
    }
    return p;
}

static void setup(fd_case *c, int guidance, int source, int H, int W)
{
    c->cfg = (gs_renderer_config){4, 5, guidance, 2, source};
    c->H = H, c->W = W;
    c->np = gs_renderer_param_count(&c->cfg);
    c->nx = (size_t)4 * H * W;
    c->nout = (size_t)3 * 16 * H * W;
    c->na = gs_renderer_act_size(&c->cfg, H, W);
    c->params = xcalloc(c->np), c->x = xcalloc(c->nx), c->tau = xcalloc(5);
    c->R = xcalloc(c->nout), c->acts = xcalloc(c->na), c->out = xcalloc(c->nout);
    CHECK_EQ_INT(gs_renderer_init(&c->cfg, c->params, c->np, 7), GS_OK);
    CHECK_EQ_INT(gs_renderer_bind(&c->cfg, c->params, c->np, &c->p), GS_OK);
    if (guidance != GS_GUIDE_NONE) { /* a guidance that matters */
        fill(c->p.value_w, 16, 0.8f);
        fill(c->p.value_b, 4, 0.5f);
        fill(c->p.key_w, 20, 1.0f);
    }
    fill(c->x, c->nx, 1.0f);
    c->src = NULL;
    if (source == GS_GUIDE_SRC_SOURCE) {
        c->src = xcalloc(c->nx);
        fill(c->src, c->nx, 1.0f);
    }
    fill(c->tau, 5, 2.0f);
    fill(c->R, c->nout, 1.0f);
}

static void teardown(fd_case *c)
{
    free(c->params); free(c->x); free(c->tau); free(c->R); free(c->acts);
    free(c->out); free(c->src);
}

static double loss(fd_case *c)
{
    int rc = gs_renderer_forward_src(&c->cfg, &c->p, c->x, c->tau, c->src,
                                     c->H, c->W, c->acts, c->na, c->out, NULL);
    if (rc) {
        fprintf(stderr, "forward failed: %d\n", rc);
        exit(1);
    }
    double s = 0.0;
    for (size_t i = 0; i < c->nout; i++)
        s += (double)c->R[i] * c->out[i];
    return s;
}

/* Central differences over theta[n] against grad[n]. */
static void check(fd_case *c, const char *what, float *theta,
                  const float *grad, size_t n)
{
    double worst = 0.0, worst_share = 0.0;
    for (size_t i = 0; i < n; i++) {
        float keep = theta[i];
        theta[i] = keep + FD_H;
        float up = theta[i];
        double lp = loss(c);
        theta[i] = keep - FD_H;
        float dn = theta[i];
        double lm = loss(c);
        theta[i] = keep;
        double fd = (lp - lm) / ((double)up - dn), an = grad[i];
        double d = fabs(an - fd), tol = ATOL + RTOL * fabs(fd);
        worst = fmax(worst, d);
        worst_share = fmax(worst_share, d / tol);
        CHECK_MSG(d <= tol, "%s[%zu]: analytic %.7g, finite difference %.7g "
                  "(diff %.3g, tol %.3g)", what, i, an, fd, d, tol);
    }
    printf("  %-34s n=%-4zu max|diff| %.2e (%.0f%% of tolerance)\n", what, n,
           worst, 100.0 * worst_share);
}

static void run(int guidance, int source, const char *name, int H, int W)
{
    fd_case c;
    setup(&c, guidance, source, H, W);
    printf("%s, %dx%d:\n", name, H, W);
    float *g = xcalloc(c.np), *dx = xcalloc(c.nx), *dtau = xcalloc(5),
          *dsrc = xcalloc(c.nx);
    gs_renderer_params dp;
    CHECK_EQ_INT(gs_renderer_bind(&c.cfg, g, c.np, &dp), GS_OK);
    loss(&c);
    CHECK_EQ_INT(gs_renderer_backward_src(&c.cfg, &c.p, c.acts, c.na, c.x,
                                          c.tau, c.src, c.R, H, W, &dp, dx,
                                          dsrc, dtau, NULL), GS_OK);
    gs_renderer_tensor tab[GS_RENDERER_MAX_TENSORS];
    int count = 0;
    CHECK_EQ_INT(gs_renderer_layout(&c.cfg, tab, GS_RENDERER_MAX_TENSORS, &count), GS_OK);
    for (int t = 0; t < count; t++)
        check(&c, tab[t].name, c.params + tab[t].offset, g + tab[t].offset,
              tab[t].count);
    check(&c, "x", c.x, dx, c.nx);
    if (c.src)
        check(&c, "src", c.src, dsrc, c.nx);
    if (guidance != GS_GUIDE_NONE)
        check(&c, "tau", c.tau, dtau, 5);
    else
        for (int d = 0; d < 5; d++)
            CHECK_MSG(dtau[d] == 0.0f, "tau gradient without guidance");
    free(g); free(dx); free(dtau); free(dsrc);
    teardown(&c);
}

int main(void)
{
    gs_nn_blas_set_threads(1);
    const int B = GS_GUIDE_SRC_BLOCK, S = GS_GUIDE_SRC_SOURCE;
    run(GS_GUIDE_NONE, B, "none", 3, 2);
    run(GS_GUIDE_ADDITIVE, B, "additive", 3, 2);
    run(GS_GUIDE_MULTIPLICATIVE, B, "multiplicative", 3, 2);
    /* the smallest maps: 1 x 3 features, blurs at 2 x 6 and 4 x 12 */
    run(GS_GUIDE_MULTIPLICATIVE, B, "multiplicative", 1, 3);
    /* a stream of draws without a LeakyReLU kink inside a step: the one
     * continuing from above puts one in block0.conv_c.bias[2] (it passes
     * at h = 3e-4, so it is the kink, not the gradient) */
    g_rng = 0x5eed1ull;
    run(GS_GUIDE_ADDITIVE, S, "source additive", 3, 2);
    run(GS_GUIDE_MULTIPLICATIVE, S, "source multiplicative", 3, 2);
    GS_TEST_END();
}
