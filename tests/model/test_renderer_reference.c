/* Compares the renderer with the PyTorch reference written by
 * renderer_reference.py (float64 torch on float32 inputs; the guidance
 * unfolded there, with a key bias the C code omits), in every guidance
 * mode and source: the output and the gradient of every parameter tensor, of x and of
 * tau.
 *
 * Usage: test_renderer_reference REFERENCE_DIR
 *
 * Each parameter is loaded by the name and shape of the C layout table, so a
 * name or shape that differs from the script's fails too. Tolerance per
 * value: |got - want| <= ATOL_REL * max|want| + RTOL |want| (the scale of a
 * gradient tensor varies over orders of magnitude between tensors). */
#include "gazesplat/image_io.h"
#include "gazesplat/nn.h"
#include "gazesplat/pool.h"
#include "gs_test.h"
#include "renderer.h"

#include <string.h>

#define ATOL_REL 1e-5
#define RTOL 1e-5

static const char *g_dir;
static gs_pool *g_pool; /* 2 threads: the split passes against PyTorch */

/* Loads DIR/mode/name.npy, checking the shape; NULL (and a failure) when it
 * is missing or has another shape. want_rank 0 skips the shape check. */
static float *load(const char *mode, const char *name, int want_rank,
                   const size_t *want_shape, size_t *count)
{
    char path[512];
    snprintf(path, sizeof path, "%s/%s/%s.npy", g_dir, mode, name);
    gs_io_array a;
    gs_error err;
    int rc = gs_io_npy_read(path, 0, &a, &err);
    if (rc) {
        CHECK_MSG(0, "%s: %s", path, err.msg);
        return NULL;
    }
    int ok = a.dtype == GS_IO_F32 && (want_rank == 0 || a.rank == want_rank);
    for (int k = 0; ok && want_rank && k < want_rank; k++)
        ok = a.shape[k] == want_shape[k];
    if (!ok) {
        CHECK_MSG(0, "%s: dtype or shape differs from the C layout", path);
        gs_io_array_free(&a);
        return NULL;
    }
    if (count)
        *count = gs_io_array_count(&a);
    return a.data; /* owned by the caller (free) */
}

static void compare(const char *mode, const char *what, const float *got,
                    const float *want, size_t n)
{
    double big = 0.0, worst = 0.0;
    for (size_t i = 0; i < n; i++) {
        big = fmax(big, fabs((double)want[i]));
        worst = fmax(worst, fabs((double)got[i] - want[i]));
    }
    char label[160];
    snprintf(label, sizeof label, "%s %s", mode, what);
    printf("%-52s n=%-6zu max|want| %.3e  max|diff| %.2e (%.1e of max)\n",
           label, n, big, worst, big > 0 ? worst / big : 0.0);
    gs_check_arrays(label, got, want, n, ATOL_REL * big + 1e-12, RTOL);
}

/* Loads every parameter tensor of the layout into params[n]. */
static int load_params(const char *mode, const gs_renderer_tensor *tab,
                       int count, float *params)
{
    for (int i = 0; i < count; i++) {
        char name[96];
        size_t shape[2] = {(size_t)tab[i].shape[0], (size_t)tab[i].shape[1]};
        snprintf(name, sizeof name, "param.%.47s", tab[i].name);
        float *t = load(mode, name, tab[i].rank, shape, NULL);
        if (!t)
            return 0;
        memcpy(params + tab[i].offset, t, tab[i].count * sizeof *t);
        free(t);
    }
    return 1;
}

static void run_mode(const char *mode, int guidance, int source)
{
    gs_renderer_config cfg = {32, 144, guidance, 2, source};
    gs_renderer_tensor tab[GS_RENDERER_MAX_TENSORS];
    int count = 0;
    CHECK_EQ_INT(gs_renderer_layout(&cfg, tab, GS_RENDERER_MAX_TENSORS, &count), GS_OK);
    size_t np = gs_renderer_param_count(&cfg), nx = 0, nt = 0;
    float *params = calloc(np, sizeof(float)), *grads = calloc(np, sizeof(float));
    float *x = load(mode, "x", 0, NULL, &nx), *tau = load(mode, "tau", 0, NULL, &nt);
    float *dout = load(mode, "dout", 0, NULL, NULL), *want = load(mode, "out", 0, NULL, NULL);
    float *want_dx = load(mode, "dx", 0, NULL, NULL), *want_dtau = load(mode, "dtau", 0, NULL, NULL);
    if (!params || !grads || !x || !tau || !dout || !want || !want_dx ||
        !want_dtau || !load_params(mode, tab, count, params) || nt != 144) {
        CHECK_MSG(0, "%s: cannot set up the case", mode);
        goto done;
    }
    int H = 8, W = 12; /* as written by the script; the count must agree */
    CHECK_EQ_INT(nx, (size_t)32 * H * W);
    size_t na = gs_renderer_act_size(&cfg, H, W), nout = 3 * 16 * (size_t)H * W;
    float *acts = calloc(na, sizeof(float)), *out = calloc(nout, sizeof(float));
    float *dx = calloc(nx, sizeof(float)), *dtau = calloc(nt, sizeof(float));
    gs_renderer_params p, dp;
    CHECK_EQ_INT(gs_renderer_bind(&cfg, params, np, &p), GS_OK);
    CHECK_EQ_INT(gs_renderer_bind(&cfg, grads, np, &dp), GS_OK);
    float *src = NULL, *want_dsrc = NULL, *dsrc = NULL;
    if (source) {
        src = load(mode, "src", 0, NULL, NULL);
        want_dsrc = load(mode, "dsrc", 0, NULL, NULL);
        dsrc = calloc(nx, sizeof(float));
    }
    CHECK_EQ_INT(gs_renderer_forward_src(&cfg, &p, x, tau, src, H, W, acts, na,
                                         out, g_pool), GS_OK);
    CHECK_EQ_INT(gs_renderer_backward_src(&cfg, &p, acts, na, x, tau, src, dout,
                                          H, W, &dp, dx, dsrc, dtau, g_pool),
                 GS_OK);
    compare(mode, "out", out, want, nout);
    compare(mode, "dx", dx, want_dx, nx);
    if (source && dsrc && want_dsrc)
        compare(mode, "dsrc", dsrc, want_dsrc, nx);
    free(src); free(want_dsrc); free(dsrc);
    if (guidance != GS_GUIDE_NONE)
        compare(mode, "dtau", dtau, want_dtau, nt);
    for (int i = 0; i < count; i++) {
        char name[96];
        snprintf(name, sizeof name, "grad.%.47s", tab[i].name);
        float *g = load(mode, name, 0, NULL, NULL);
        if (g)
            compare(mode, tab[i].name, grads + tab[i].offset, g, tab[i].count);
        free(g);
    }
    free(acts); free(out); free(dx); free(dtau);
done:
    free(params); free(grads); free(x); free(tau); free(dout); free(want);
    free(want_dx); free(want_dtau);
}

int main(int argc, char **argv)
{
    if (argc != 2) {
        fprintf(stderr, "usage: %s REFERENCE_DIR\n", argv[0]);
        return 2;
    }
    g_dir = argv[1];
    gs_nn_blas_set_threads(1);
    g_pool = gs_pool_create(2);
    if (!g_pool)
        return fprintf(stderr, "cannot create a pool\n"), 1;
    run_mode("none", GS_GUIDE_NONE, GS_GUIDE_SRC_BLOCK);
    run_mode("additive", GS_GUIDE_ADDITIVE, GS_GUIDE_SRC_BLOCK);
    run_mode("multiplicative", GS_GUIDE_MULTIPLICATIVE, GS_GUIDE_SRC_BLOCK);
    run_mode("source_additive", GS_GUIDE_ADDITIVE, GS_GUIDE_SRC_SOURCE);
    run_mode("source_multiplicative", GS_GUIDE_MULTIPLICATIVE,
             GS_GUIDE_SRC_SOURCE);
    gs_pool_destroy(g_pool);
    GS_TEST_END();
}
