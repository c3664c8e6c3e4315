/* Renderer bookkeeping and contracts: config validation, the parameter
 * layout (count, names, shapes, offsets, binding), the seeded init (bounds,
 * determinism, guidance starting as the identity), determinism of forward
 * and backward (same bytes twice, backward accumulating, the same bytes on
 * pools of 1, 2 and 3 threads as inline), the forward-only buffer (the same
 * bytes as the full one), the CPU default size (64^2 -> 256^2) and bad
 * arguments. */
#include "gazesplat/nn.h"
#include "gazesplat/pool.h"
#include "gs_test.h"
#include "renderer.h"
#include "renderer_ops.h"

#include <stdint.h>
#include <string.h>

static void *xcalloc(size_t n)
{
    void *p = calloc(n ? n : 1, sizeof(float));
    if (!p) {
        fprintf(stderr, "out of memory\n");
        exit(2);
    }
    return p;
}

static void fill(float *a, size_t n, uint32_t seed)
{
    uint32_t s = seed;
    for (size_t i = 0; i < n; i++) {
        s = s * 1664525u + 1013904223u;
        a[i] = (float)(s >> 8) * (2.0f / 16777216.0f) - 1.0f;
    }
}

static void t_config(void)
{
    gs_error err;
    gs_renderer_config ok = {32, 144, GS_GUIDE_MULTIPLICATIVE, 2, 0};
    CHECK_EQ_INT(gs_renderer_config_validate(&ok, &err), GS_OK);
    const gs_renderer_config bad[] = {
        {0, 144, 0, 2, 0}, {257, 144, 0, 2, 0}, {32, 0, 0, 2, 0},
        {32, 257, 0, 2, 0}, {32, 144, 3, 2, 0}, {32, 144, -1, 2, 0},
        {32, 144, 0, 1, 0}, {32, 144, 0, 3, 0}, {32, 144, 1, 2, 2},
        {32, 144, 1, 2, -1}};
    for (size_t i = 0; i < sizeof bad / sizeof bad[0]; i++) {
        gs_error_clear(&err);
        CHECK_EQ_INT(gs_renderer_config_validate(&bad[i], &err), GS_ERR_ARG);
        CHECK_MSG(strstr(err.msg, "renderer:") != NULL, "case %zu: message '%s'",
                  i, err.msg);
        CHECK_EQ_INT(gs_renderer_param_count(&bad[i]), 0);
        CHECK_EQ_INT(gs_renderer_act_size(&bad[i], 8, 8), 0);
    }
    CHECK_EQ_INT(gs_renderer_config_validate(NULL, NULL), GS_ERR_ARG);
}

/* C = 32, D = 144: 99 + 2 (2112 + 8320 + 1056 + 99) + (4608 + 1024 + 32) */
static void t_layout(void)
{
    gs_renderer_config g = {32, 144, GS_GUIDE_ADDITIVE, 2, 0};
    gs_renderer_config n = {32, 144, GS_GUIDE_NONE, 2, 0};
    CHECK_EQ_INT(gs_renderer_param_count(&g), 28937);
    CHECK_EQ_INT(gs_renderer_param_count(&n), 23273);
    gs_renderer_tensor tab[GS_RENDERER_MAX_TENSORS];
    int count = 0;
    CHECK_EQ_INT(gs_renderer_layout(&g, tab, GS_RENDERER_MAX_TENSORS, &count), GS_OK);
    CHECK_EQ_INT(count, 21);
    CHECK_EQ_INT(gs_renderer_layout(&g, tab, 20, &count), GS_ERR_ARG);
    CHECK_EQ_INT(gs_renderer_layout(&g, NULL, 21, &count), GS_ERR_ARG);
    CHECK_EQ_INT(gs_renderer_layout(&g, tab, GS_RENDERER_MAX_TENSORS, &count), GS_OK);
    size_t off = 0;
    for (int i = 0; i < count; i++) {
        const gs_renderer_tensor *t = &tab[i];
        CHECK_MSG(t->offset == off, "%s: offset %zu, expected %zu", t->name,
                  t->offset, off);
        CHECK_EQ_INT(t->count, (size_t)t->shape[0] * (size_t)t->shape[1]);
        CHECK(t->rank == 1 || t->rank == 2);
        CHECK(strncmp(t->name, "renderer.", 9) == 0);
        for (int j = 0; j < i; j++)
            CHECK_MSG(strcmp(t->name, tab[j].name) != 0, "duplicate %s", t->name);
        off += t->count;
    }
    CHECK_EQ_INT(off, 28937);
    CHECK(strcmp(tab[0].name, "renderer.conv_rgb.weight") == 0);
    CHECK(strcmp(tab[4].name, "renderer.block0.conv_b.weight") == 0);
    CHECK(tab[4].shape[0] == 128 && tab[4].shape[1] == 64 && tab[4].rank == 2);
    CHECK(strcmp(tab[5].name, "renderer.block0.conv_b.bias") == 0);
    CHECK(tab[5].shape[0] == 128 && tab[5].rank == 1);
    CHECK(strcmp(tab[18].name, "renderer.guide.key.weight") == 0);
    CHECK(tab[18].shape[0] == 144 && tab[18].shape[1] == 32);

    float *base = xcalloc(28937);
    gs_renderer_params p;
    CHECK_EQ_INT(gs_renderer_bind(&g, base, 28936, &p), GS_ERR_ARG);
    CHECK_EQ_INT(gs_renderer_bind(&g, NULL, 28937, &p), GS_ERR_ARG);
    CHECK_EQ_INT(gs_renderer_bind(&g, base, 28937, &p), GS_OK);
    CHECK(p.rgb0.w == base && p.rgb0.b == base + tab[1].offset);
    CHECK(p.block[0].b.w == base + tab[4].offset);
    CHECK(p.block[1].rgb.b == base + tab[17].offset);
    CHECK(p.key_w == base + tab[18].offset && p.value_w == base + tab[19].offset);
    CHECK(p.value_b == base + tab[20].offset);
    CHECK_EQ_INT(gs_renderer_bind(&n, base, 28937, &p), GS_OK);
    CHECK(p.key_w == NULL && p.value_w == NULL && p.value_b == NULL);
    free(base);
}

static void t_init(void)
{
    gs_renderer_config g = {32, 144, GS_GUIDE_MULTIPLICATIVE, 2, 0};
    size_t np = gs_renderer_param_count(&g);
    float *a = xcalloc(np), *b = xcalloc(np), *c = xcalloc(np);
    CHECK_EQ_INT(gs_renderer_init(&g, a, np, 42), GS_OK);
    CHECK_EQ_INT(gs_renderer_init(&g, b, np, 42), GS_OK);
    CHECK_EQ_INT(gs_renderer_init(&g, c, np, 43), GS_OK);
    CHECK(memcmp(a, b, np * sizeof *a) == 0);
    CHECK(memcmp(a, c, np * sizeof *a) != 0);
    CHECK_EQ_INT(gs_renderer_init(&g, a, np - 1, 42), GS_ERR_ARG);
    gs_renderer_tensor tab[GS_RENDERER_MAX_TENSORS];
    int count = 0;
    gs_renderer_layout(&g, tab, GS_RENDERER_MAX_TENSORS, &count);
    for (int i = 0; i < count; i++) {
        const gs_renderer_tensor *t = &tab[i];
        int fan_in = t->rank == 2 ? t->shape[1] : tab[i - 1].shape[1];
        double bound = 1.0 / sqrt((double)fan_in), big = 0.0;
        for (size_t k = 0; k < t->count; k++)
            big = fmax(big, fabs(a[t->offset + k]));
        if (strstr(t->name, "guide.value"))
            CHECK_MSG(big == 0.0, "%s not zero", t->name);
        else
            CHECK_MSG(big <= bound && big > 0.5 * bound, "%s: max %g, bound %g",
                      t->name, big, bound);
    }
    free(a); free(b); free(c);
}

typedef struct {
    gs_renderer_config cfg;
    int H, W;
    size_t np, na, nx, nout;
    float *params, *grads, *acts, *x, *tau, *out, *dout, *dx, *dtau;
    gs_renderer_params p, dp;
} net;

static void net_make(net *n, int guidance, int D, int H, int W, uint64_t seed)
{
    n->cfg = (gs_renderer_config){32, D, guidance, 2, 0};
    n->H = H, n->W = W;
    n->np = gs_renderer_param_count(&n->cfg);
    n->na = gs_renderer_act_size(&n->cfg, H, W);
    n->nx = (size_t)32 * H * W, n->nout = (size_t)48 * H * W;
    n->params = xcalloc(n->np), n->grads = xcalloc(n->np);
    n->acts = xcalloc(n->na), n->x = xcalloc(n->nx), n->tau = xcalloc((size_t)D);
    n->out = xcalloc(n->nout), n->dout = xcalloc(n->nout);
    n->dx = xcalloc(n->nx), n->dtau = xcalloc((size_t)D);
    gs_renderer_init(&n->cfg, n->params, n->np, seed);
    gs_renderer_bind(&n->cfg, n->params, n->np, &n->p);
    gs_renderer_bind(&n->cfg, n->grads, n->np, &n->dp);
    fill(n->x, n->nx, 1);
    fill(n->tau, (size_t)D, 2);
    fill(n->dout, n->nout, 3);
}

/* A live guidance (the init's value projection is zero) for a guided
 * net: value_w and value_b drawn from seeds seed and seed + 1. */
static void live_guidance(net *n, uint32_t seed)
{
    if (n->cfg.guidance == GS_GUIDE_NONE)
        return;
    fill(n->p.value_w, 32 * 32, seed);
    fill(n->p.value_b, 32, seed + 1);
}

static void net_free(net *n)
{
    free(n->params); free(n->grads); free(n->acts); free(n->x); free(n->tau);
    free(n->out); free(n->dout); free(n->dx); free(n->dtau);
}

static int net_forward(net *n)
{
    return gs_renderer_forward(&n->cfg, &n->p, n->x, n->tau, n->H, n->W,
                               n->acts, n->na, n->out, NULL);
}

static int net_backward(net *n)
{
    return gs_renderer_backward(&n->cfg, &n->p, n->acts, n->na, n->x, n->tau,
                                n->dout, n->H, n->W, &n->dp, n->dx, n->dtau, NULL);
}

/* With the init's zero value projection, both guidance modes give the
 * plain renderer's image, bit for bit (the conv tensors come first in the
 * layout, so the same seed draws the same convolutions). */
static void t_identity_at_init(void)
{
    net plain, add, mul;
    net_make(&plain, GS_GUIDE_NONE, 16, 5, 7, 9);
    net_make(&add, GS_GUIDE_ADDITIVE, 16, 5, 7, 9);
    net_make(&mul, GS_GUIDE_MULTIPLICATIVE, 16, 5, 7, 9);
    CHECK_EQ_INT(net_forward(&plain), GS_OK);
    CHECK_EQ_INT(net_forward(&add), GS_OK);
    CHECK_EQ_INT(net_forward(&mul), GS_OK);
    CHECK(memcmp(plain.out, add.out, plain.nout * sizeof(float)) == 0);
    CHECK(memcmp(plain.out, mul.out, plain.nout * sizeof(float)) == 0);
    net_free(&plain); net_free(&add); net_free(&mul);
}

static void fill_const(float *a, size_t n, float v)
{
    for (size_t i = 0; i < n; i++)
        a[i] = v;
}

/* got == want + 0.5 up to the rounding of a few accumulation steps. */
static void check_offset(const char *what, const float *got, const float *want,
                         size_t n)
{
    double big = 0.0;
    float *w = xcalloc(n);
    for (size_t i = 0; i < n; i++) {
        big = fmax(big, fabs((double)want[i]));
        w[i] = want[i] + 0.5f;
    }
    gs_check_arrays(what, got, w, n, 1e-6 * big + 1e-7, 1e-6);
    free(w);
}

/* Same bytes twice (over a dirty activation buffer); backward adds. */
static void t_determinism(int guidance)
{
    net n;
    net_make(&n, guidance, 144, 6, 9, 5);
    live_guidance(&n, 11);
    CHECK_EQ_INT(net_forward(&n), GS_OK);
    CHECK_EQ_INT(net_backward(&n), GS_OK);
    float *out1 = xcalloc(n.nout), *g1 = xcalloc(n.np), *dx1 = xcalloc(n.nx);
    float *dt1 = xcalloc(144);
    memcpy(out1, n.out, n.nout * sizeof(float));
    memcpy(g1, n.grads, n.np * sizeof(float));
    memcpy(dx1, n.dx, n.nx * sizeof(float));
    memcpy(dt1, n.dtau, 144 * sizeof(float));
    /* a fresh run over a dirty activation buffer gives the same bytes */
    memset(n.grads, 0, n.np * sizeof(float));
    memset(n.dx, 0, n.nx * sizeof(float));
    memset(n.dtau, 0, 144 * sizeof(float));
    fill(n.acts, n.na, 77);
    CHECK_EQ_INT(net_forward(&n), GS_OK);
    CHECK_EQ_INT(net_backward(&n), GS_OK);
    CHECK(memcmp(out1, n.out, n.nout * sizeof(float)) == 0);
    CHECK(memcmp(g1, n.grads, n.np * sizeof(float)) == 0);
    CHECK(memcmp(dx1, n.dx, n.nx * sizeof(float)) == 0);
    CHECK(memcmp(dt1, n.dtau, 144 * sizeof(float)) == 0);
    /* backward adds: run again (the saved part of acts is intact) into
     * gradients prefilled with 0.5 */
    fill_const(n.grads, n.np, 0.5f);
    fill_const(n.dx, n.nx, 0.5f);
    fill_const(n.dtau, 144, 0.5f);
    CHECK_EQ_INT(net_backward(&n), GS_OK);
    check_offset("params", n.grads, g1, n.np);
    check_offset("dx", n.dx, dx1, n.nx);
    check_offset("dtau", n.dtau, dt1, 144);
    /* NULL dx and dtau: the parameter gradients do not change */
    memset(n.grads, 0, n.np * sizeof(float));
    CHECK_EQ_INT(gs_renderer_backward(&n.cfg, &n.p, n.acts, n.na, n.x, n.tau,
                                      n.dout, n.H, n.W, &n.dp, NULL, NULL, NULL), GS_OK);
    CHECK(memcmp(g1, n.grads, n.np * sizeof(float)) == 0);
    free(out1); free(g1); free(dx1); free(dt1);
    net_free(&n);
}

/* Inline (NULL pool) and pools of 1, 2 and 3 threads give the same bytes:
 * 24 x 24 features so that the 1x1 convolutions and the guidance split into
 * several pixel bands (2 at 48^2, 5 at 96^2). */
static void t_threads(int guidance)
{
    net n;
    net_make(&n, guidance, 144, 24, 24, 8);
    live_guidance(&n, 13);
    CHECK_EQ_INT(net_forward(&n), GS_OK);
    CHECK_EQ_INT(net_backward(&n), GS_OK);
    float *out1 = xcalloc(n.nout), *g1 = xcalloc(n.np), *dx1 = xcalloc(n.nx);
    float *dt1 = xcalloc(144);
    memcpy(out1, n.out, n.nout * sizeof(float));
    memcpy(g1, n.grads, n.np * sizeof(float));
    memcpy(dx1, n.dx, n.nx * sizeof(float));
    memcpy(dt1, n.dtau, 144 * sizeof(float));
    for (int threads = 1; threads <= 3; threads++) {
        gs_pool *pool = gs_pool_create(threads);
        CHECK(pool != NULL);
        memset(n.grads, 0, n.np * sizeof(float));
        memset(n.dx, 0, n.nx * sizeof(float));
        memset(n.dtau, 0, 144 * sizeof(float));
        memset(n.out, 0, n.nout * sizeof(float));
        CHECK_EQ_INT(gs_renderer_forward(&n.cfg, &n.p, n.x, n.tau, n.H, n.W,
                                         n.acts, n.na, n.out, pool), GS_OK);
        CHECK_EQ_INT(gs_renderer_backward(&n.cfg, &n.p, n.acts, n.na, n.x, n.tau,
                                          n.dout, n.H, n.W, &n.dp, n.dx, n.dtau,
                                          pool), GS_OK);
        CHECK_MSG(memcmp(out1, n.out, n.nout * sizeof(float)) == 0,
                  "mode %d, %d threads: image differs", guidance, threads);
        CHECK_MSG(memcmp(g1, n.grads, n.np * sizeof(float)) == 0,
                  "mode %d, %d threads: parameter gradients differ", guidance, threads);
        CHECK_MSG(memcmp(dx1, n.dx, n.nx * sizeof(float)) == 0,
                  "mode %d, %d threads: dx differs", guidance, threads);
        CHECK_MSG(memcmp(dt1, n.dtau, 144 * sizeof(float)) == 0,
                  "mode %d, %d threads: dtau differs", guidance, threads);
        gs_pool_destroy(pool);
    }
    free(out1); free(g1); free(dx1); free(dt1);
    net_free(&n);
}

/* A backward without parameter gradients (dparams NULL: a fit) gives the
 * input gradients of one with them, bit for bit, in every guidance mode
 * and source, inline and on 2 threads; and it adds into dx and dtau as the
 * full one does. A source-guided backward sends the source's gradient to
 * dsrc either way. */
static void t_input_grads_only(int guidance, int source)
{
    net n;
    net_make(&n, guidance, 144, 24, 20, 10);
    n.cfg.guide_source = source;
    live_guidance(&n, 17);
    float *src = xcalloc(n.nx), *ds1 = xcalloc(n.nx), *ds2 = xcalloc(n.nx);
    float *dx1 = xcalloc(n.nx), *dt1 = xcalloc(144);
    fill(src, n.nx, 22);
    gs_pool *pool = gs_pool_create(2);
    for (int pi = 0; pi < 2; pi++) {
        gs_pool *pl = pi ? pool : NULL;
        CHECK_EQ_INT(gs_renderer_forward_src(&n.cfg, &n.p, n.x, n.tau, src, n.H, n.W, n.acts,
                                             n.na, n.out, pl), GS_OK);
        memset(n.grads, 0, n.np * sizeof(float));
        memset(n.dx, 0, n.nx * sizeof(float));
        memset(n.dtau, 0, 144 * sizeof(float));
        memset(ds1, 0, n.nx * sizeof(float));
        CHECK_EQ_INT(gs_renderer_backward_src(&n.cfg, &n.p, n.acts, n.na, n.x, n.tau, src,
                                              n.dout, n.H, n.W, &n.dp, n.dx, ds1, n.dtau, pl),
                     GS_OK);
        size_t touched = 0;
        for (size_t i = 0; i < n.np; i++)
            touched += n.grads[i] != 0.0f;
        CHECK_MSG(touched > n.np / 2, "guidance %d source %d: %zu of %zu gradients set",
                  guidance, source, touched, n.np);
        memcpy(dx1, n.dx, n.nx * sizeof(float));
        memcpy(dt1, n.dtau, 144 * sizeof(float));
        fill_const(n.dx, n.nx, 0.5f);
        fill_const(n.dtau, 144, 0.5f);
        fill_const(ds2, n.nx, 0.5f);
        CHECK_EQ_INT(gs_renderer_backward_src(&n.cfg, &n.p, n.acts, n.na, n.x, n.tau, src,
                                              n.dout, n.H, n.W, NULL, n.dx, ds2, n.dtau, pl),
                     GS_OK);
        check_offset("dx without dparams", n.dx, dx1, n.nx);
        check_offset("dtau without dparams", n.dtau, dt1, 144);
        check_offset("dsrc without dparams", ds2, ds1, n.nx);
        memset(n.dx, 0, n.nx * sizeof(float));
        memset(n.dtau, 0, 144 * sizeof(float));
        CHECK_EQ_INT(gs_renderer_backward_src(&n.cfg, &n.p, n.acts, n.na, n.x, n.tau, src,
                                              n.dout, n.H, n.W, NULL, n.dx, ds2, n.dtau, pl),
                     GS_OK);
        CHECK_MSG(memcmp(dx1, n.dx, n.nx * sizeof(float)) == 0,
                  "guidance %d source %d pool %d: dx without dparams differs", guidance,
                  source, pi);
        CHECK_MSG(memcmp(dt1, n.dtau, 144 * sizeof(float)) == 0,
                  "guidance %d source %d pool %d: dtau without dparams differs", guidance,
                  source, pi);
    }
    gs_pool_destroy(pool);
    free(src); free(ds1); free(ds2); free(dx1); free(dt1);
    net_free(&n);
}

/* The CPU default: 64 x 64 features -> 256 x 256 image, finite, in (0, 1). */
static void t_default_size(void)
{
    net n;
    net_make(&n, GS_GUIDE_MULTIPLICATIVE, 144, 64, 64, 1);
    fill(n.p.value_w, 32 * 32, 4);
    CHECK_EQ_INT(net_forward(&n), GS_OK);
    CHECK_EQ_INT(net_backward(&n), GS_OK);
    size_t bad = 0;
    for (size_t i = 0; i < n.nout; i++)
        bad += !(n.out[i] >= 0.0f && n.out[i] <= 1.0f);
    for (size_t i = 0; i < n.np; i++)
        bad += !isfinite(n.grads[i]);
    for (size_t i = 0; i < n.nx; i++)
        bad += !isfinite(n.dx[i]);
    CHECK_MSG(bad == 0, "%zu values out of range or non-finite", bad);
    printf("64x64 -> 256x256: %zu parameters, activations %.1f MB (forward only %.1f MB)\n",
           n.np, (double)n.na * 4.0 / 1e6,
           (double)gs_renderer_fwd_size(&n.cfg, 64, 64) * 4.0 / 1e6);
    net_free(&n);
}

static void t_bad_args(void)
{
    net n;
    net_make(&n, GS_GUIDE_ADDITIVE, 8, 4, 4, 3);
    const gs_renderer_config *c = &n.cfg;
    gs_renderer_config badcfg = n.cfg;
    badcfg.blocks = 3;
    /* sizes */
    CHECK_EQ_INT(gs_renderer_act_size(c, 0, 4), 0);
    CHECK_EQ_INT(gs_renderer_act_size(c, 4, -1), 0);
    CHECK_EQ_INT(gs_renderer_act_size(c, GS_RENDERER_MAX_SIDE + 1, 4), 0);
    CHECK(gs_renderer_act_size(c, 1, 1) > 0);
    CHECK_EQ_INT(gs_renderer_forward(c, &n.p, n.x, n.tau, 0, 4, n.acts, n.na, n.out, NULL), GS_ERR_ARG);
    CHECK_EQ_INT(gs_renderer_forward(c, &n.p, n.x, n.tau, 4, 0, n.acts, n.na, n.out, NULL), GS_ERR_ARG);
    CHECK_EQ_INT(gs_renderer_forward(c, &n.p, n.x, n.tau, GS_RENDERER_MAX_SIDE + 1, 4,
                                     n.acts, n.na, n.out, NULL), GS_ERR_LIMIT);
    /* a forward-only buffer for 4 x 4 is too short for 4 x 5, and one
     * float short of it for 4 x 4 (a forward takes any buffer of at least
     * gs_renderer_fwd_size) */
    size_t nl = gs_renderer_fwd_size(c, 4, 4);
    CHECK(nl > 0 && nl < n.na);
    CHECK_EQ_INT(gs_renderer_forward(c, &n.p, n.x, n.tau, 4, 5, n.acts, nl, n.out, NULL), GS_ERR_ARG);
    CHECK_EQ_INT(gs_renderer_forward(c, &n.p, n.x, n.tau, 4, 4, n.acts, nl - 1, n.out, NULL), GS_ERR_ARG);
    CHECK_EQ_INT(gs_renderer_forward(c, &n.p, n.x, n.tau, 4, 4, n.acts, nl, n.out, NULL), GS_OK);
    /* NULLs and a bad config */
    CHECK_EQ_INT(gs_renderer_forward(NULL, &n.p, n.x, n.tau, 4, 4, n.acts, n.na, n.out, NULL), GS_ERR_ARG);
    CHECK_EQ_INT(gs_renderer_forward(&badcfg, &n.p, n.x, n.tau, 4, 4, n.acts, n.na, n.out, NULL), GS_ERR_ARG);
    CHECK_EQ_INT(gs_renderer_forward(c, NULL, n.x, n.tau, 4, 4, n.acts, n.na, n.out, NULL), GS_ERR_ARG);
    CHECK_EQ_INT(gs_renderer_forward(c, &n.p, NULL, n.tau, 4, 4, n.acts, n.na, n.out, NULL), GS_ERR_ARG);
    CHECK_EQ_INT(gs_renderer_forward(c, &n.p, n.x, NULL, 4, 4, n.acts, n.na, n.out, NULL), GS_ERR_ARG);
    CHECK_EQ_INT(gs_renderer_forward(c, &n.p, n.x, n.tau, 4, 4, NULL, n.na, n.out, NULL), GS_ERR_ARG);
    CHECK_EQ_INT(gs_renderer_forward(c, &n.p, n.x, n.tau, 4, 4, n.acts, n.na, NULL, NULL), GS_ERR_ARG);
    gs_renderer_params holes = n.p;
    holes.block[1].c.b = NULL;
    CHECK_EQ_INT(gs_renderer_forward(c, &holes, n.x, n.tau, 4, 4, n.acts, n.na, n.out, NULL), GS_ERR_ARG);
    holes = n.p;
    holes.value_w = NULL;
    CHECK_EQ_INT(gs_renderer_forward(c, &holes, n.x, n.tau, 4, 4, n.acts, n.na, n.out, NULL), GS_ERR_ARG);
    /* backward */
    CHECK_EQ_INT(net_forward(&n), GS_OK);
    CHECK_EQ_INT(gs_renderer_backward(c, &n.p, n.acts, n.na, n.x, n.tau, NULL, 4, 4,
                                      &n.dp, n.dx, n.dtau, NULL), GS_ERR_ARG);
    CHECK_EQ_INT(gs_renderer_backward(c, &n.p, n.acts, n.na, n.x, n.tau, n.dout, 4, 4,
                                      &holes, n.dx, n.dtau, NULL), GS_ERR_ARG);
    CHECK_EQ_INT(gs_renderer_backward(c, &n.p, n.acts, n.na - 1, n.x, n.tau, n.dout, 4, 4,
                                      &n.dp, n.dx, n.dtau, NULL), GS_ERR_ARG);
    CHECK_EQ_INT(gs_renderer_backward(c, &n.p, n.acts, n.na, n.x, n.tau, n.dout, -4, 4,
                                      &n.dp, n.dx, n.dtau, NULL), GS_ERR_ARG);
    CHECK_EQ_INT(gs_renderer_backward(c, &n.p, NULL, n.na, n.x, n.tau, n.dout, 4, 4,
                                      &n.dp, n.dx, n.dtau, NULL), GS_ERR_ARG);
    /* nothing was added by the refused calls */
    size_t touched = 0;
    for (size_t i = 0; i < n.np; i++)
        touched += n.grads[i] != 0.0f;
    CHECK_EQ_INT(touched, 0);
    /* the plain renderer needs no tau */
    net plain;
    net_make(&plain, GS_GUIDE_NONE, 8, 2, 3, 3);
    CHECK_EQ_INT(gs_renderer_forward(&plain.cfg, &plain.p, plain.x, NULL, 2, 3,
                                     plain.acts, plain.na, plain.out, NULL), GS_OK);
    CHECK_EQ_INT(gs_renderer_backward(&plain.cfg, &plain.p, plain.acts, plain.na,
                                      plain.x, NULL, plain.dout, 2, 3, &plain.dp,
                                      plain.dx, NULL, NULL), GS_OK);
    net_free(&plain);
    net_free(&n);
}

/* SOURCE guidance is local given its vector:
 * - forward_src equals guide_vector + forward_vec byte for byte;
 * - a change of one feature pixel (i, j) changes only output pixels within
 *   4 (i +- GS_RENDERER_REACH) (and the bound is tight: pixels at the edge
 *   of that window do change);
 * - a crop of the feature map rendered with forward_vec equals the full
 *   render away from the crop's cut edges (REACH feature pixels inside). */
static void t_source_locality(int guidance)
{
    enum { H = 14, W = 17, R = GS_RENDERER_REACH };
    gs_renderer_config cfg = {32, 16, guidance, 2, GS_GUIDE_SRC_SOURCE};
    size_t np = gs_renderer_param_count(&cfg), na = gs_renderer_act_size(&cfg, H, W);
    size_t nx = (size_t)32 * H * W, nout = (size_t)48 * H * W;
    float *params = xcalloc(np), *acts = xcalloc(na), *x = xcalloc(nx);
    float *src = xcalloc(nx), *tau = xcalloc(16), *o1 = xcalloc(nout);
    float *o2 = xcalloc(nout), *a = xcalloc(32);
    gs_renderer_params p;
    CHECK_EQ_INT(gs_renderer_init(&cfg, params, np, 3), GS_OK);
    CHECK_EQ_INT(gs_renderer_bind(&cfg, params, np, &p), GS_OK);
    fill(p.value_w, 32 * 32, 0.3f);
    fill(p.value_b, 32, 0.5f);
    fill(x, nx, 1), fill(src, nx, 1), fill(tau, 16, 2);
    CHECK_EQ_INT(gs_renderer_forward_src(&cfg, &p, x, tau, src, H, W, acts, na,
                                         o1, NULL), GS_OK);
    CHECK_EQ_INT(gs_renderer_guide_vector(&cfg, &p, src, tau, H, W, acts, na,
                                          a, NULL), GS_OK);
    CHECK_EQ_INT(gs_renderer_forward_vec(&cfg, &p, x, a, H, W, acts, na, o2,
                                         NULL), GS_OK);
    CHECK(memcmp(o1, o2, nout * sizeof(float)) == 0);
    /* an impulse at (5, 8) in every channel */
    int pi = 5, pj = 8, edge = 0;
    for (int c = 0; c < 32; c++)
        x[((size_t)c * H + pi) * W + pj] += 0.7f;
    CHECK_EQ_INT(gs_renderer_forward_vec(&cfg, &p, x, a, H, W, acts, na, o2,
                                         NULL), GS_OK);
    int bad = 0;
    for (int c = 0; c < 3; c++)
        for (int y = 0; y < 4 * H; y++)
            for (int z = 0; z < 4 * W; z++) {
                size_t k = ((size_t)c * 4 * H + y) * 4 * W + z;
                int inside = y >= 4 * (pi - R) && y < 4 * (pi + R + 1) &&
                             z >= 4 * (pj - R) && z < 4 * (pj + R + 1);
                if (o1[k] != o2[k] && !inside)
                    bad++;
                if (o1[k] != o2[k] && (y < 4 * (pi - R + 1) || z < 4 * (pj - R + 1)))
                    edge = 1;
            }
    CHECK_MSG(bad == 0, "%d output values changed outside the reach", bad);
    CHECK_MSG(edge, "the reach bound is not tight (REACH could be smaller)");
    /* the same in output pixels (GS_RENDERER_REACH_PX) */
    const int RP = GS_RENDERER_REACH_PX;
    int bad_px = 0, edge_px = 0;
    for (int c = 0; c < 3; c++)
        for (int y = 0; y < 4 * H; y++)
            for (int z = 0; z < 4 * W; z++) {
                size_t k = ((size_t)c * 4 * H + y) * 4 * W + z;
                if (o1[k] == o2[k])
                    continue;
                bad_px += y < 4 * pi - RP || y >= 4 * pi + 4 + RP ||
                          z < 4 * pj - RP || z >= 4 * pj + 4 + RP;
                edge_px |= y == 4 * pi - RP || y == 4 * pi + 3 + RP ||
                           z == 4 * pj - RP || z == 4 * pj + 3 + RP;
            }
    CHECK_MSG(bad_px == 0, "%d output values changed beyond %d px", bad_px, RP);
    CHECK_MSG(edge_px, "the reach bound in pixels is not tight");
    /* a crop [y0, y1) x [x0, x1) against the full render */
    int y0 = 3, y1 = 11, x0 = 4, x1 = 13, h = y1 - y0, w = x1 - x0;
    float *xc = xcalloc((size_t)32 * h * w), *oc = xcalloc((size_t)48 * h * w);
    for (int c = 0; c < 32; c++)
        for (int y = 0; y < h; y++)
            memcpy(xc + ((size_t)c * h + y) * w, x + ((size_t)c * H + y + y0) * W + x0,
                   (size_t)w * sizeof(float));
    size_t nac = gs_renderer_act_size(&cfg, h, w);
    float *actc = xcalloc(nac);
    CHECK_EQ_INT(gs_renderer_forward_vec(&cfg, &p, xc, a, h, w, actc, nac, oc,
                                         NULL), GS_OK);
    double worst = 0.0;
    for (int c = 0; c < 3; c++)
        for (int y = 4 * R; y < 4 * (h - R); y++)
            for (int z = 4 * R; z < 4 * (w - R); z++) {
                float got = oc[((size_t)c * 4 * h + y) * 4 * w + z];
                float want = o2[((size_t)c * 4 * H + y + 4 * y0) * 4 * W + z + 4 * x0];
                worst = fmax(worst, fabs((double)got - want));
            }
    CHECK_MSG(worst <= 1e-6, "crop differs from the full render by %.3g", worst);
    worst = 0.0; /* and REACH_PX output pixels inside */
    const int RQ = GS_RENDERER_REACH_PX;
    for (int c = 0; c < 3; c++)
        for (int y = RQ; y < 4 * h - RQ; y++)
            for (int z = RQ; z < 4 * w - RQ; z++) {
                float got = oc[((size_t)c * 4 * h + y) * 4 * w + z];
                float want = o2[((size_t)c * 4 * H + y + 4 * y0) * 4 * W + z + 4 * x0];
                worst = fmax(worst, fabs((double)got - want));
            }
    CHECK_MSG(worst <= 1e-6, "crop differs %d px inside its edges by %.3g", RQ, worst);
    free(xc); free(oc); free(actc);
    free(params); free(acts); free(x); free(src); free(tau); free(o1);
    free(o2); free(a);
}

/* The elementwise passes run in vector blocks and a scalar remainder: at
 * every length around the block (8) and the task chunk (65,536), on no
 * pool and on a pool of two, each element equals its one-line definition
 * to the bit (LeakyReLU backward: the gradient where the output is above
 * zero, else 0.2 times it, zero outputs of either sign included; guidance
 * applied: u + u a or u + a; its backward: dg (1 + a) or dg). */
static void t_elementwise_lengths(void)
{
    const size_t lens[] = {1, 2, 7, 8, 9, 15, 16, 17, 31, 65535, 65536, 65537,
                           2 * 65536 + 13};
    gs_pool *pool2 = gs_pool_create(2);
    CHECK(pool2 != NULL);
    for (int pi = 0; pi < 2; pi++) {
        gs_rop_ctx x = {.pool = pi ? pool2 : NULL};
        for (size_t li = 0; li < sizeof lens / sizeof lens[0]; li++) {
            size_t n = lens[li];
            float *y = xcalloc(n), *d = xcalloc(n), *d0 = xcalloc(n);
            fill(y, n, 11u + (uint32_t)n);
            fill(d0, n, 12u + (uint32_t)n);
            for (size_t i = 0; i < n; i += 5)
                y[i] = (i / 5) % 2 ? 0.0f : -0.0f;
            memcpy(d, d0, n * sizeof *d);
            gs_rop_lrelu_backward(&x, d, y, n);
            size_t bad = 0;
            for (size_t i = 0; i < n; i++) {
                float want = y[i] > 0.0f ? d0[i] : GS_ROP_LRELU_SLOPE * d0[i];
                bad += memcmp(&d[i], &want, sizeof want) != 0;
            }
            CHECK_MSG(bad == 0, "lrelu backward, n %zu, pool %d: %zu elements differ",
                      n, pi, bad);
            /* guidance over two channels of n pixels each */
            if (n <= 65537) {
                float a[2] = {0.37f, -1.25f}, da[2];
                float *u = xcalloc(2 * n), *dg = xcalloc(2 * n), *gg = xcalloc(2 * n),
                      *duu = xcalloc(2 * n);
                fill(u, 2 * n, 13u + (uint32_t)n);
                fill(dg, 2 * n, 14u + (uint32_t)n);
                for (int mult = 0; mult < 2; mult++) {
                    gs_rop_guide gd = {.C = 2, .D = 1, .mult = mult, .temp = 1.0f};
                    gs_rop_guide_apply(&x, &gd, gg, u, a, n);
                    gs_rop_guide_apply_backward(&x, &gd, duu, da, dg, u, a, n);
                    size_t bg = 0, bd = 0;
                    for (int c = 0; c < 2; c++)
                        for (size_t i = 0; i < n; i++) {
                            size_t k = (size_t)c * n + i;
                            float wg = mult ? u[k] + u[k] * a[c] : u[k] + a[c];
                            float wd = dg[k] * (mult ? 1.0f + a[c] : 1.0f);
                            bg += memcmp(&gg[k], &wg, sizeof wg) != 0;
                            bd += memcmp(&duu[k], &wd, sizeof wd) != 0;
                        }
                    CHECK_MSG(bg == 0 && bd == 0,
                              "guide apply (mult %d), n %zu, pool %d: %zu / %zu differ",
                              mult, n, pi, bg, bd);
                }
                free(u);
                free(dg);
                free(gg);
                free(duu);
            }
            free(y);
            free(d);
            free(d0);
        }
    }
    gs_pool_destroy(pool2);
}

/* A forward-only buffer (gs_renderer_fwd_size, what renders use) gives
 * the same bytes as the full one, through every forward, guidance mode and
 * source, inline and on a pool, over a dirty buffer; a backward refuses
 * it. */
static void t_lean(int guidance, int source)
{
    net n;
    net_make(&n, guidance, 144, 24, 20, 9);
    n.cfg.guide_source = source;
    live_guidance(&n, 15);
    size_t nl = gs_renderer_fwd_size(&n.cfg, n.H, n.W);
    CHECK_MSG(nl > 0 && nl < n.na, "lean %zu floats, full %zu", nl, n.na);
    float *lean = xcalloc(nl), *o1 = xcalloc(n.nout), *o2 = xcalloc(n.nout);
    float *src = xcalloc(n.nx), a[32];
    fill(src, n.nx, 21);
    gs_pool *pool = gs_pool_create(2);
    for (int pi = 0; pi < 2; pi++) {
        gs_pool *pl = pi ? pool : NULL;
        fill(lean, nl, 78 + pi);
        CHECK_EQ_INT(gs_renderer_forward_src(&n.cfg, &n.p, n.x, n.tau, src, n.H, n.W, n.acts,
                                             n.na, o1, pl), GS_OK);
        CHECK_EQ_INT(gs_renderer_forward_src(&n.cfg, &n.p, n.x, n.tau, src, n.H, n.W, lean, nl,
                                             o2, pl), GS_OK);
        CHECK_MSG(memcmp(o1, o2, n.nout * sizeof(float)) == 0,
                  "guidance %d source %d pool %d: the lean forward differs", guidance, source,
                  pi);
        if (guidance == GS_GUIDE_NONE || source == GS_GUIDE_SRC_SOURCE) {
            if (guidance != GS_GUIDE_NONE)
                CHECK_EQ_INT(gs_renderer_guide_vector(&n.cfg, &n.p, src, n.tau, n.H, n.W, lean,
                                                      nl, a, pl), GS_OK);
            CHECK_EQ_INT(gs_renderer_forward_vec(&n.cfg, &n.p, n.x, a, n.H, n.W, n.acts, n.na,
                                                 o1, pl), GS_OK);
            CHECK_EQ_INT(gs_renderer_forward_vec(&n.cfg, &n.p, n.x, a, n.H, n.W, lean, nl, o2,
                                                 pl), GS_OK);
            CHECK_MSG(memcmp(o1, o2, n.nout * sizeof(float)) == 0,
                      "guidance %d pool %d: the lean forward_vec differs", guidance, pi);
        }
    }
    CHECK_EQ_INT(gs_renderer_forward(&n.cfg, &n.p, n.x, n.tau, n.H, n.W, lean, nl - 1, o2,
                                     NULL), GS_ERR_ARG);
    CHECK_EQ_INT(gs_renderer_backward(&n.cfg, &n.p, lean, nl, n.x, n.tau, n.dout, n.H, n.W,
                                      &n.dp, n.dx, n.dtau, NULL), GS_ERR_ARG);
    gs_pool_destroy(pool);
    free(lean); free(o1); free(o2); free(src);
    net_free(&n);
}

int main(void)
{
    gs_nn_blas_set_threads(1);
    t_config();
    t_layout();
    t_init();
    t_identity_at_init();
    t_determinism(GS_GUIDE_NONE);
    t_determinism(GS_GUIDE_ADDITIVE);
    t_determinism(GS_GUIDE_MULTIPLICATIVE);
    t_threads(GS_GUIDE_NONE);
    t_threads(GS_GUIDE_ADDITIVE);
    t_threads(GS_GUIDE_MULTIPLICATIVE);
    t_source_locality(GS_GUIDE_ADDITIVE);
    t_source_locality(GS_GUIDE_MULTIPLICATIVE);
    for (int g = GS_GUIDE_NONE; g <= GS_GUIDE_MULTIPLICATIVE; g++)
        for (int src = GS_GUIDE_SRC_BLOCK; src <= GS_GUIDE_SRC_SOURCE; src++)
            t_lean(g, src);
    for (int g = GS_GUIDE_NONE; g <= GS_GUIDE_MULTIPLICATIVE; g++)
        for (int src = GS_GUIDE_SRC_BLOCK; src <= GS_GUIDE_SRC_SOURCE; src++)
            t_input_grads_only(g, src);
    t_default_size();
    t_bad_args();
    t_elementwise_lengths();
    GS_TEST_END();
}
