/* Compares every gs_nn kernel with the PyTorch reference written by
 * nn_reference.py (float64 torch on float32 inputs; Adam in float32).
 *
 * Usage: test_nn_reference REFERENCE_FILE
 *
 * Outputs and gradients must match within |got - want| <= atol + rtol |want|:
 *   kernels (outputs and gradients):  atol 1e-5, rtol 1e-4
 *   losses and their gradients:       atol 1e-6 (1e-7 scaled for the
 *                                     per-pixel loss gradients), rtol 1e-4
 *   Adam parameters after each step:  atol 1e-6, rtol 1e-5; norms rtol 1e-5
 * Gradients are prefilled with 0.5 and compared with reference + 0.5, which
 * also checks that backward accumulates. A missing or malformed file fails. */
#include "gazesplat/nn.h"
#include "gazesplat/pool.h"
#include "gs_test.h"
#include "nn_test_util.h"

#include <stdint.h>

#define K_ATOL 1e-5
#define K_RTOL 1e-4
#define ACC 0.5f

enum { MAX_TENSORS = 512, MAX_DIMS = 8 };

typedef struct {
    char name[96];
    int ndim;
    int dims[MAX_DIMS];
    size_t n;
    float *data;
} ref_tensor;

typedef struct {
    ref_tensor t[MAX_TENSORS];
    int count;
} ref_file;

static ref_file g_ref;

/* Reads n bytes at *pos of buf[len]; 0 when the file is truncated. */
static int take(const unsigned char *buf, size_t len, size_t *pos, void *dst,
                size_t n)
{
    if (n > len - *pos)
        return 0;
    memcpy(dst, buf + *pos, n);
    *pos += n;
    return 1;
}

static int take_u32(const unsigned char *buf, size_t len, size_t *pos,
                    uint32_t *v)
{
    unsigned char b[4];
    if (!take(buf, len, pos, b, 4))
        return 0;
    *v = (uint32_t)b[0] | (uint32_t)b[1] << 8 | (uint32_t)b[2] << 16 |
         (uint32_t)b[3] << 24;
    return 1;
}

static int parse(ref_file *rf, const unsigned char *buf, size_t len)
{
    size_t pos = 0;
    char magic[8];
    uint32_t version, count;
    if (!take(buf, len, &pos, magic, 8) || memcmp(magic, "GSNNREF\0", 8) != 0)
        return fprintf(stderr, "bad magic\n"), 0;
    if (!take_u32(buf, len, &pos, &version) || version != 1)
        return fprintf(stderr, "unsupported version\n"), 0;
    if (!take_u32(buf, len, &pos, &count) || count > MAX_TENSORS)
        return fprintf(stderr, "bad tensor count\n"), 0;
    for (uint32_t i = 0; i < count; i++) {
        ref_tensor *t = &rf->t[i];
        uint32_t nlen, ndim, d;
        if (!take_u32(buf, len, &pos, &nlen) || nlen >= sizeof t->name ||
            !take(buf, len, &pos, t->name, nlen))
            return fprintf(stderr, "tensor %u: bad name\n", i), 0;
        t->name[nlen] = '\0';
        if (!take_u32(buf, len, &pos, &ndim) || ndim < 1 || ndim > MAX_DIMS)
            return fprintf(stderr, "%s: bad ndim\n", t->name), 0;
        t->ndim = (int)ndim;
        t->n = 1;
        for (uint32_t k = 0; k < ndim; k++) {
            if (!take_u32(buf, len, &pos, &d) || d < 1 || d > (1u << 24) ||
                t->n > ((size_t)1 << 28) / d)
                return fprintf(stderr, "%s: bad dims\n", t->name), 0;
            t->dims[k] = (int)d;
            t->n *= d;
        }
        t->data = nn_alloc(t->n);
        if (!take(buf, len, &pos, t->data, t->n * sizeof(float)))
            return fprintf(stderr, "%s: truncated data\n", t->name), 0;
        rf->count++;
    }
    if (pos != len)
        return fprintf(stderr, "trailing bytes\n"), 0;
    return 1;
}

static int load(ref_file *rf, const char *path)
{
    FILE *f = fopen(path, "rb");
    if (!f)
        return fprintf(stderr, "cannot open %s\n", path), 0;
    fseek(f, 0, SEEK_END);
    long len = ftell(f);
    fseek(f, 0, SEEK_SET);
    unsigned char *buf = malloc(len > 0 ? (size_t)len : 1);
    int ok = len > 0 && buf && fread(buf, 1, (size_t)len, f) == (size_t)len &&
             parse(rf, buf, (size_t)len);
    free(buf);
    fclose(f);
    return ok;
}

/* The named tensor; a missing one ends the test with a failure. */
static const ref_tensor *need(const char *name)
{
    for (int i = 0; i < g_ref.count; i++)
        if (strcmp(g_ref.t[i].name, name) == 0)
            return &g_ref.t[i];
    fprintf(stderr, "reference tensor %s missing\n", name);
    exit(1);
}

static const float *get(const char *kase, const char *what, size_t *n)
{
    char name[128];
    snprintf(name, sizeof name, "%s.%s", kase, what);
    const ref_tensor *t = need(name);
    if (n)
        *n = t->n;
    return t->data;
}

/* Compares got[n] with the reference tensor kase.what (+ offset), printing
 * the largest difference. */
static void compare(const char *kase, const char *what, const float *got,
                    size_t n_got, float offset, double atol, double rtol)
{
    size_t n;
    const float *want = get(kase, what, &n);
    char label[128];
    snprintf(label, sizeof label, "%s.%s", kase, what);
    if (n != n_got) {
        CHECK_MSG(0, "%s: %zu values, reference has %zu", label, n_got, n);
        return;
    }
    float *w = nn_alloc(n);
    double worst = 0.0;
    for (size_t i = 0; i < n; i++) {
        w[i] = want[i] + offset;
        double d = fabs((double)got[i] - w[i]);
        worst = d > worst ? d : worst;
    }
    printf("%-26s n=%-5zu max|diff| %.2e\n", label, n, worst);
    gs_check_arrays(label, got, w, n, atol, rtol);
    free(w);
}

/* A gradient buffer of n values prefilled with ACC. */
static float *grad_buf(size_t n)
{
    float *g = nn_alloc(n);
    for (size_t i = 0; i < n; i++)
        g[i] = ACC;
    return g;
}

static void t_linear(void)
{
    size_t nin, nw, nout;
    const float *in = get("linear", "in", &nin), *w = get("linear", "w", &nw);
    const float *b = get("linear", "b", NULL), *dout = get("linear", "dout", &nout);
    const ref_tensor *wt = need("linear.w");
    int OC = wt->dims[0], IC = wt->dims[1], B = (int)(nin / (size_t)IC);
    float *out = nn_alloc(nout), *din = grad_buf(nin), *dw = grad_buf(nw),
          *db = grad_buf((size_t)OC);
    CHECK_EQ_INT(gs_nn_linear_forward(out, in, w, b, B, IC, OC), GS_OK);
    CHECK_EQ_INT(gs_nn_linear_backward(din, dw, db, dout, in, w, B, IC, OC), GS_OK);
    compare("linear", "out", out, nout, 0, K_ATOL, K_RTOL);
    compare("linear", "din", din, nin, ACC, K_ATOL, K_RTOL);
    compare("linear", "dw", dw, nw, ACC, K_ATOL, K_RTOL);
    compare("linear", "db", db, (size_t)OC, ACC, K_ATOL, K_RTOL);
    free(out); free(din); free(dw); free(db);
}

static void t_conv1x1(void)
{
    size_t nin, nw, nout;
    const float *in = get("conv1x1", "in", &nin), *w = get("conv1x1", "w", &nw);
    const float *b = get("conv1x1", "b", NULL), *dout = get("conv1x1", "dout", &nout);
    const ref_tensor *wt = need("conv1x1.w");
    int OC = wt->dims[0], IC = wt->dims[1], HW = (int)(nin / (size_t)IC);
    float *out = nn_alloc(nout), *din = grad_buf(nin), *dw = grad_buf(nw),
          *db = grad_buf((size_t)OC);
    CHECK_EQ_INT(gs_nn_conv1x1_forward(out, in, w, b, IC, OC, HW), GS_OK);
    CHECK_EQ_INT(gs_nn_conv1x1_backward(din, dw, db, dout, in, w, IC, OC, HW), GS_OK);
    compare("conv1x1", "out", out, nout, 0, K_ATOL, K_RTOL);
    compare("conv1x1", "din", din, nin, ACC, K_ATOL, K_RTOL);
    compare("conv1x1", "dw", dw, nw, ACC, K_ATOL, K_RTOL);
    compare("conv1x1", "db", db, (size_t)OC, ACC, K_ATOL, K_RTOL);
    free(out); free(din); free(dw); free(db);
}

static void t_conv3x3(void)
{
    size_t nin, nw, nout;
    const float *in = get("conv3x3", "in", &nin), *w = get("conv3x3", "w", &nw);
    const float *b = get("conv3x3", "b", NULL), *dout = get("conv3x3", "dout", &nout);
    const ref_tensor *it = need("conv3x3.in"), *wt = need("conv3x3.w");
    int IC = it->dims[0], H = it->dims[1], W = it->dims[2], OC = wt->dims[0];
    size_t ns = gs_nn_conv3x3_scratch_size(IC, H, W);
    float *scratch = nn_alloc(ns), *out = nn_alloc(nout), *din = grad_buf(nin),
          *dw = grad_buf(nw), *db = grad_buf((size_t)OC);
    CHECK_EQ_INT(gs_nn_conv3x3_forward(out, in, w, b, IC, OC, H, W, scratch, ns), GS_OK);
    CHECK_EQ_INT(gs_nn_conv3x3_backward(din, dw, db, dout, in, w, IC, OC, H, W,
                                        scratch, ns), GS_OK);
    compare("conv3x3", "out", out, nout, 0, K_ATOL, K_RTOL);
    compare("conv3x3", "din", din, nin, ACC, K_ATOL, K_RTOL);
    compare("conv3x3", "dw", dw, nw, ACC, K_ATOL, K_RTOL);
    compare("conv3x3", "db", db, (size_t)OC, ACC, K_ATOL, K_RTOL);
    free(scratch); free(out); free(din); free(dw); free(db);
}

static void t_activation(const char *kase)
{
    size_t n;
    const float *in = get(kase, "in", &n), *dout = get(kase, "dout", NULL);
    float *out = nn_alloc(n), *din = grad_buf(n);
    int rc1, rc2;
    if (strcmp(kase, "relu") == 0) {
        rc1 = gs_nn_relu_forward(out, in, n);
        rc2 = gs_nn_relu_backward(din, dout, in, n);
    } else if (strcmp(kase, "leaky_relu") == 0) {
        float slope = get(kase, "slope", NULL)[0];
        rc1 = gs_nn_leaky_relu_forward(out, in, slope, n);
        rc2 = gs_nn_leaky_relu_backward(din, dout, in, slope, n);
    } else if (strcmp(kase, "tanh") == 0) {
        rc1 = gs_nn_tanh_forward(out, in, n);
        rc2 = gs_nn_tanh_backward(din, dout, out, n);
    } else if (strcmp(kase, "sigmoid") == 0) {
        rc1 = gs_nn_sigmoid_forward(out, in, n);
        rc2 = gs_nn_sigmoid_backward(din, dout, out, n);
    } else {
        rc1 = gs_nn_softmax_forward(out, in, (int)n);
        rc2 = gs_nn_softmax_backward(din, dout, out, (int)n);
    }
    CHECK_EQ_INT(rc1, GS_OK);
    CHECK_EQ_INT(rc2, GS_OK);
    compare(kase, "out", out, n, 0, K_ATOL, K_RTOL);
    compare(kase, "din", din, n, ACC, K_ATOL, K_RTOL);
    free(out); free(din);
}

enum { RS_SHUFFLE, RS_UP, RS_BLUR, RS_POOL };

static void t_resample(const char *kase, int kind)
{
    char name[64];
    snprintf(name, sizeof name, "%s.in", kase);
    const ref_tensor *it = need(name);
    size_t nin = it->n, nout;
    const float *in = it->data, *dout = get(kase, "dout", &nout);
    int C = it->dims[0], H = it->dims[1], W = it->dims[2];
    float *out = nn_alloc(nout), *din = grad_buf(nin);
    int rc1, rc2;
    if (kind == RS_SHUFFLE) {
        rc1 = gs_nn_pixel_shuffle_forward(out, in, C / 4, H, W);
        rc2 = gs_nn_pixel_shuffle_backward(din, dout, C / 4, H, W);
    } else if (kind == RS_UP) {
        rc1 = gs_nn_upsample2x_forward(out, in, C, H, W);
        rc2 = gs_nn_upsample2x_backward(din, dout, C, H, W);
    } else if (kind == RS_BLUR) {
        rc1 = gs_nn_blur_forward(out, in, C, H, W);
        rc2 = gs_nn_blur_backward(din, dout, C, H, W);
    } else {
        rc1 = gs_nn_avgpool2x_forward(out, in, C, H, W);
        rc2 = gs_nn_avgpool2x_backward(din, dout, C, H, W);
    }
    CHECK_EQ_INT(rc1, GS_OK);
    CHECK_EQ_INT(rc2, GS_OK);
    compare(kase, "out", out, nout, 0, K_ATOL, K_RTOL);
    compare(kase, "din", din, nin, ACC, K_ATOL, K_RTOL);
    free(out); free(din);
}

static void t_attention(void)
{
    const char *k = "attention";
    const ref_tensor *xt = need("attention.x"), *ct = need("attention.code");
    int C = xt->dims[0], HW = xt->dims[1], D = ct->dims[0];
    float temp = get(k, "temp", NULL)[0];
    const float *x = xt->data, *code = ct->data, *wk = get(k, "wk", NULL),
                *bk = get(k, "bk", NULL), *wv = get(k, "wv", NULL),
                *bv = get(k, "bv", NULL), *dout = get(k, "dout", NULL);
    size_t ns = gs_nn_attention_scratch_size(C), n = (size_t)C * (size_t)HW;
    float *scratch = nn_alloc(ns), *out = nn_alloc(n), *att = nn_alloc((size_t)HW);
    float *dx = grad_buf(n), *dcode = grad_buf((size_t)D),
          *dwk = grad_buf((size_t)D * (size_t)C), *dbk = grad_buf((size_t)D),
          *dwv = grad_buf((size_t)C * (size_t)C), *dbv = grad_buf((size_t)C);
    CHECK_EQ_INT(gs_nn_attention_forward(out, att, x, code, wk, bk, wv, bv, C, D,
                                         HW, temp, scratch, ns), GS_OK);
    CHECK_EQ_INT(gs_nn_attention_backward(dx, dcode, dwk, dbk, dwv, dbv, dout, x,
                                          att, code, wk, wv, C, D, HW, temp,
                                          scratch, ns), GS_OK);
    compare(k, "out", out, n, 0, K_ATOL, K_RTOL);
    compare(k, "dx", dx, n, ACC, K_ATOL, K_RTOL);
    compare(k, "dcode", dcode, (size_t)D, ACC, K_ATOL, K_RTOL);
    compare(k, "dwk", dwk, (size_t)D * (size_t)C, ACC, K_ATOL, K_RTOL);
    compare(k, "dbk", dbk, (size_t)D, ACC, K_ATOL, K_RTOL);
    compare(k, "dwv", dwv, (size_t)C * (size_t)C, ACC, K_ATOL, K_RTOL);
    compare(k, "dbv", dbv, (size_t)C, ACC, K_ATOL, K_RTOL);
    free(scratch); free(out); free(att); free(dx); free(dcode); free(dwk);
    free(dbk); free(dwv); free(dbv);
}

static void t_l1(const char *kase, int masked)
{
    const ref_tensor *at = need(masked ? "l1_mask.a" : "l1.a");
    int C = at->dims[0], HW = at->dims[1];
    size_t n = at->n;
    const float *a = at->data, *b = get(kase, "b", NULL);
    const float *mask = masked ? get(kase, "mask", NULL) : NULL;
    float dloss = get(kase, "dout", NULL)[0], loss;
    float *da = grad_buf(n);
    CHECK_EQ_INT(gs_nn_l1_forward(&loss, a, b, mask, C, HW), GS_OK);
    CHECK_EQ_INT(gs_nn_l1_backward(da, dloss, a, b, mask, C, HW), GS_OK);
    compare(kase, "out", &loss, 1, 0, 1e-6, K_RTOL);
    compare(kase, "da", da, n, ACC, 1e-7, K_RTOL);
    free(da);
}

static void t_ssim(const char *kase, int padding)
{
    char name[64];
    snprintf(name, sizeof name, "%s.x", kase);
    const ref_tensor *xt = need(name);
    int C = xt->dims[0], H = xt->dims[1], W = xt->dims[2];
    const float *x = xt->data, *y = get(kase, "y", NULL);
    float dloss = get(kase, "dout", NULL)[0], loss;
    size_t ns = gs_nn_ssim_scratch_size(H, W, padding);
    float *scratch = nn_alloc(ns), *dx = grad_buf(xt->n);
    CHECK_EQ_INT(gs_nn_ssim_loss_forward(&loss, x, y, C, H, W, padding, scratch, ns), GS_OK);
    CHECK_EQ_INT(gs_nn_ssim_loss_backward(dx, dloss, x, y, C, H, W, padding,
                                          scratch, ns), GS_OK);
    compare(kase, "out", &loss, 1, 0, 1e-6, K_RTOL);
    compare(kase, "dx", dx, xt->n, ACC, 1e-7, K_RTOL);
    /* the pooled one-pass version: the same bytes, so the same reference */
    gs_pool *pool = gs_pool_create(2);
    size_t nf = gs_nn_ssim_fused_scratch_size(C, H, W, padding);
    float *sf = nn_alloc(nf), *dxf = grad_buf(xt->n), lossf;
    CHECK(pool != NULL);
    CHECK_EQ_INT(gs_nn_ssim_loss_fused(pool, &lossf, dxf, dloss, x, y, C, H, W, padding, sf, nf),
                 GS_OK);
    CHECK_MSG(memcmp(&lossf, &loss, sizeof loss) == 0 && memcmp(dxf, dx, xt->n * sizeof *dx) == 0,
              "%s: fused != forward + backward", kase);
    compare(kase, "out", &lossf, 1, 0, 1e-6, K_RTOL);
    compare(kase, "dx", dxf, xt->n, ACC, 1e-7, K_RTOL);
    gs_pool_destroy(pool);
    free(scratch); free(dx); free(sf); free(dxf);
}

/* Several steps of two groups against torch.optim.Adam + clip_grad_norm_. */
static void t_adam(void)
{
    size_t n0, n1;
    double lr = 0.01; /* as written by the script; the file holds float32 */
    CHECK_CLOSE(get("adam", "lr", NULL)[0], lr, 0, 1e-7);
    const float *mult = get("adam", "lr_mult", NULL);
    float p0[8], p1[8], g0[8], g1[8];
    const float *i0 = get("adam", "p0", &n0), *i1 = get("adam", "p1", &n1);
    if (n0 > 8 || n1 > 8) {
        CHECK_MSG(0, "adam groups larger than the test buffers");
        return;
    }
    memcpy(p0, i0, n0 * sizeof *p0);
    memcpy(p1, i1, n1 * sizeof *p1);
    /* the multipliers 1 and 0.3 as doubles, as in the script */
    double m0 = 1.0, m1 = 0.3;
    CHECK(mult[0] == (float)m0 && mult[1] == (float)m1);
    gs_nn_param_group groups[2] = {{p0, g0, n0, m0}, {p1, g1, n1, m1}};
    gs_nn_adam_config cfg = gs_nn_adam_default_config();
    cfg.max_grad_norm = get("adam", "max_norm", NULL)[0];
    gs_nn_adam *adam = NULL;
    CHECK_EQ_INT(gs_nn_adam_create(&adam, groups, 2, &cfg, NULL), GS_OK);
    int steps = (int)get("adam", "steps", NULL)[0];
    CHECK(steps >= 2);
    for (int step = 0; adam && step < steps; step++) {
        char kase[32];
        snprintf(kase, sizeof kase, "adam.step%d", step);
        memcpy(g0, get(kase, "g0", NULL), n0 * sizeof *g0);
        memcpy(g1, get(kase, "g1", NULL), n1 * sizeof *g1);
        double norm = -1.0;
        CHECK_EQ_INT(gs_nn_adam_step(adam, lr, &norm), GS_OK);
        float fnorm = (float)norm;
        compare(kase, "norm", &fnorm, 1, 0, 0, 1e-5);
        if (step == 0)
            CHECK_MSG(norm > cfg.max_grad_norm, "step 0 must clip (norm %g)", norm);
        compare(kase, "p0", p0, n0, 0, 1e-6, 1e-5);
        compare(kase, "p1", p1, n1, 0, 1e-6, 1e-5);
    }
    gs_nn_adam_destroy(adam);
}

int main(int argc, char **argv)
{
    if (argc != 2) {
        fprintf(stderr, "usage: %s REFERENCE_FILE\n", argv[0]);
        return 2;
    }
    if (!load(&g_ref, argv[1])) {
        fprintf(stderr, "FAILED: cannot read reference %s\n", argv[1]);
        return 1;
    }
    t_linear();
    t_conv1x1();
    t_conv3x3();
    t_activation("relu");
    t_activation("leaky_relu");
    t_activation("tanh");
    t_activation("sigmoid");
    t_activation("softmax");
    t_resample("pixel_shuffle", RS_SHUFFLE);
    t_resample("upsample2x", RS_UP);
    t_resample("upsample2x_1x3", RS_UP);
    t_resample("blur", RS_BLUR);
    t_resample("blur_2x2", RS_BLUR);
    t_resample("avgpool2x", RS_POOL);
    t_resample("avgpool2x_2x2", RS_POOL);
    t_attention();
    t_l1("l1", 0);
    t_l1("l1_mask", 1);
    t_ssim("ssim_valid", GS_NN_SSIM_VALID);
    t_ssim("ssim_zero", GS_NN_SSIM_ZERO);
    t_adam();
    for (int i = 0; i < g_ref.count; i++)
        free(g_ref.t[i].data);
    GS_TEST_END();
}
