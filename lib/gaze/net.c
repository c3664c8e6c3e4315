/* Forward and backward of the estimator over its layer list, and the
 * public calls for one image. */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "gazesplat/geom.h"
#include "gazesplat/nn.h"
#include "gaze_internal.h"

int gz_ctx_init(gz_ctx *c, const gz_graph *g)
{
    memset(c, 0, sizeof *c);
    c->act = malloc(g->act_len * sizeof(float));
    c->dact = malloc(g->act_len * sizeof(float));
    c->scratch = malloc((g->scratch_len ? g->scratch_len : 1) * sizeof(float));
    return c->act && c->dact && c->scratch ? GS_OK : GS_ERR_NOMEM;
}

void gz_ctx_free(gz_ctx *c)
{
    free(c->act);
    free(c->dact);
    free(c->scratch);
    free(c->tmp);
    free(c->img);
    memset(c, 0, sizeof *c);
}

/* Grows *buf to at least n floats. */
static int reserve(float **buf, size_t *cap, size_t n)
{
    if (n <= *cap)
        return GS_OK;
    float *p = realloc(*buf, n * sizeof(float));
    if (!p)
        return GS_ERR_NOMEM;
    *buf = p;
    *cap = n;
    return GS_OK;
}

int gz_ctx_from_rgb(gz_ctx *c, const uint8_t *rgb, int w, int h, size_t stride)
{
    size_t plane = (size_t)w * (size_t)h;
    if (reserve(&c->img, &c->img_cap, 3 * plane))
        return GS_ERR_NOMEM;
    for (int y = 0; y < h; y++) {
        const uint8_t *row = rgb + (size_t)y * stride;
        for (int x = 0; x < w; x++)
            for (int k = 0; k < 3; k++)
                c->img[k * plane + (size_t)y * w + x] = row[3 * x + k] / 255.0f;
    }
    return GS_OK;
}

/* One layer forward. */
static int op_forward(const gz_graph *g, const gz_op *o, const float *P, gz_ctx *c)
{
    const float *in = c->act + g->buf[o->in].off;
    float *out = c->act + g->buf[o->out].off;
    const float *w = o->wt >= 0 ? P + g->t[o->wt].off : NULL;
    const float *b = o->wt >= 0 ? P + g->t[o->wt + 1].off : NULL;
    size_t n = g->buf[o->in].len;
    switch (o->kind) {
    case GZ_CONV3: /* in[C,H,W] -> out[OC,H,W] */
        return gs_nn_conv3x3_forward(out, in, w, b, o->C, o->OC, o->H, o->W,
                                     c->scratch, g->scratch_len);
    case GZ_CONV1: /* in[C,HW] -> out[OC,HW] */
        return gs_nn_conv1x1_forward(out, in, w, b, o->C, o->OC, o->H * o->W);
    case GZ_RELU:
        return gs_nn_relu_forward(out, in, n);
    case GZ_POOL: /* [C,H,W] -> [C,H/2,W/2] */
        return gs_nn_avgpool2x_forward(out, in, o->C, o->H, o->W);
    case GZ_ADD: {
        const float *in2 = c->act + g->buf[o->in2].off;
        for (size_t i = 0; i < n; i++)
            out[i] = in[i] + in2[i];
        return GS_OK;
    }
    case GZ_LINEAR: /* in[1,C*H*W] -> out[1,OC] */
        return gs_nn_linear_forward(out, in, w, b, 1, (int)n, o->OC);
    }
    return GS_ERR_STATE;
}

/* One layer backward; din NULL when the input needs no gradient. */
static int op_backward(const gz_graph *g, const gz_op *o, const float *P, gz_ctx *c,
                       float *dP, int need_din)
{
    const float *in = c->act + g->buf[o->in].off;
    float *din = need_din ? c->dact + g->buf[o->in].off : NULL;
    const float *dout = c->dact + g->buf[o->out].off;
    const float *w = o->wt >= 0 ? P + g->t[o->wt].off : NULL;
    float *dw = dP && o->wt >= 0 ? dP + g->t[o->wt].off : NULL;
    float *db = dP && o->wt >= 0 ? dP + g->t[o->wt + 1].off : NULL;
    size_t n = g->buf[o->in].len;
    switch (o->kind) {
    case GZ_CONV3:
        if (!din && !dw)
            return GS_OK;
        return gs_nn_conv3x3_backward(din, dw, db, dout, in, w, o->C, o->OC, o->H,
                                      o->W, c->scratch, g->scratch_len);
    case GZ_CONV1:
        return gs_nn_conv1x1_backward(din, dw, db, dout, in, w, o->C, o->OC,
                                      o->H * o->W);
    case GZ_RELU:
        return din ? gs_nn_relu_backward(din, dout, in, n) : GS_OK;
    case GZ_POOL:
        return din ? gs_nn_avgpool2x_backward(din, dout, o->C, o->H, o->W) : GS_OK;
    case GZ_ADD: {
        float *din2 = c->dact + g->buf[o->in2].off;
        for (size_t i = 0; din && i < n; i++) {
            din[i] += dout[i];
            din2[i] += dout[i];
        }
        return GS_OK;
    }
    case GZ_LINEAR:
        return gs_nn_linear_backward(din, dw, db, dout, in, w, 1, (int)n, o->OC);
    }
    return GS_ERR_STATE;
}

/* img[3,h,w] -> out[4]; keeps activations in c. */
int gz_forward(const gz_graph *g, const float *P, gz_ctx *c, const float *img,
               int w, int h, float out[4])
{
    const gz_buf *f = &g->buf[0], *e = &g->buf[1];
    c->have_forward = 0;
    if (reserve(&c->tmp, &c->tmp_cap, 3 * (size_t)h * (size_t)(f->W > e->W ? f->W : e->W)))
        return GS_ERR_NOMEM;
    gz_resize_forward(c->act + f->off, img, 3, w, h, &gz_full_window, f->W, f->H, c->tmp);
    gz_resize_forward(c->act + e->off, img, 3, w, h, &gz_eye_window, e->W, e->H, c->tmp);
    for (size_t i = 0; i < f->len + e->len; i++) /* buffers 0 and 1 are adjacent */
        c->act[i] -= 0.5f;
    for (int i = 0; i < g->nops; i++) {
        int rc = op_forward(g, &g->op[i], P, c);
        if (rc)
            return rc;
    }
    memcpy(out, c->act + g->buf[g->nbufs - 1].off, GS_GAZE_OUTPUTS * sizeof(float));
    c->src_w = w, c->src_h = h, c->have_forward = 1;
    return GS_OK;
}

/* dimg[3,h,w] and dP[nparams] += gradients of sum dout * out. */
int gz_backward(const gz_graph *g, const float *P, gz_ctx *c, const float dout[4],
                float *dimg, float *dP)
{
    if (!c->have_forward)
        return GS_ERR_STATE;
    memset(c->dact, 0, g->act_len * sizeof(float));
    memcpy(c->dact + g->buf[g->nbufs - 1].off, dout, GS_GAZE_OUTPUTS * sizeof(float));
    for (int i = g->nops - 1; i >= 0; i--) {
        const gz_op *o = &g->op[i];
        int rc = op_backward(g, o, P, c, dP, o->in > 1 || dimg != NULL);
        if (rc)
            return rc;
    }
    const gz_buf *f = &g->buf[0], *e = &g->buf[1];
    if (dimg) {
        gz_resize_adjoint(dimg, c->dact + f->off, 3, c->src_w, c->src_h, &gz_full_window, f->W,
                          f->H, c->tmp);
        gz_resize_adjoint(dimg, c->dact + e->off, 3, c->src_w, c->src_h, &gz_eye_window, e->W,
                          e->H, c->tmp);
    }
    return GS_OK;
}

/* ---- initialisation ----------------------------------------------------- */

static uint64_t splitmix(uint64_t *s)
{
    uint64_t z = (*s += 0x9E3779B97F4A7C15ull);
    z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
    z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
    return z ^ (z >> 31);
}

/* Standard normal by Box-Muller from two uniforms in (0, 1]. */
static double normal(uint64_t *s)
{
    double u1 = ((double)(splitmix(s) >> 11) + 1.0) * (1.0 / 9007199254740992.0);
    double u2 = (double)(splitmix(s) >> 11) * (1.0 / 9007199254740992.0);
    return sqrt(-2.0 * log(u1)) * cos(6.283185307179586 * u2);
}

/* He-normal weights, zero biases; the last layer starts small so the
 * first predictions are near 0 (the centre of the label range). */
static void init_params(gs_gaze_net *n, uint64_t seed)
{
    uint64_t s = seed ^ 0x67617a65ull;
    for (int i = 0; i < n->g.ntensors; i++) {
        const gz_tensor *t = &n->g.t[i];
        float *p = n->params + t->off;
        double sd = t->fan_in ? sqrt(2.0 / t->fan_in) : 0.0;
        if (i == n->g.ntensors - 2)
            sd = 0.01 / sqrt((double)t->fan_in);
        for (size_t k = 0; k < t->count; k++)
            p[k] = t->fan_in ? (float)(sd * normal(&s)) : 0.0f;
    }
}

/* ---- public ------------------------------------------------------------- */

int gs_gaze_net_create(const gs_gaze_spec *s, uint64_t seed, gs_gaze_net **out,
                       gs_error *err)
{
    if (!out)
        return gs_error_set(err, GS_ERR_ARG, "gaze: NULL argument");
    int rc = gz_net_alloc(s, out, err);
    if (!rc)
        init_params(*out, seed);
    return rc;
}

int gs_gaze_net_clone(const gs_gaze_net *n, gs_gaze_net **out, gs_error *err)
{
    if (!n || !out)
        return gs_error_set(err, GS_ERR_ARG, "gaze: NULL argument");
    int rc = gz_net_alloc(&n->spec, out, err);
    if (!rc)
        memcpy((*out)->params, n->params, n->g.nparams * sizeof(float));
    return rc;
}

void gs_gaze_net_destroy(gs_gaze_net *n)
{
    if (!n)
        return;
    gz_ctx_free(&n->ctx);
    free(n->params);
    free(n);
}

void gs_gaze_net_spec(const gs_gaze_net *n, gs_gaze_spec *s)
{
    *s = n->spec;
}

size_t gs_gaze_net_param_count(const gs_gaze_net *n)
{
    return n ? n->g.nparams : 0;
}

float *gs_gaze_net_params(gs_gaze_net *n)
{
    return n ? n->params : NULL;
}

static int size_check(int width, int height, gs_error *err)
{
    if (width < 1 || height < 1 || width > GS_GAZE_MAX_IMAGE_SIDE ||
        height > GS_GAZE_MAX_IMAGE_SIDE)
        return gs_error_set(err, GS_ERR_ARG, "gaze: image %dx%d (want 1..%d a side)",
                            width, height, GS_GAZE_MAX_IMAGE_SIDE);
    return GS_OK;
}

static int finish(int rc, const float out[4], gs_error *err)
{
    if (rc == GS_ERR_NOMEM)
        return gs_error_set(err, rc, "gaze: out of memory");
    if (rc)
        return gs_error_set(err, rc, "gaze: layer failed (%s)", gs_strerror(rc));
    for (int k = 0; k < GS_GAZE_OUTPUTS; k++)
        if (!isfinite(out[k]))
            return gs_error_set(err, GS_ERR_NONFINITE, "gaze: non-finite output");
    return GS_OK;
}

int gs_gaze_net_predict(gs_gaze_net *n, gs_pool *pool, const uint8_t *rgb, int width,
                        int height, size_t stride, float out[4], gs_error *err)
{
    (void)pool;
    if (!n || !rgb || !out)
        return gs_error_set(err, GS_ERR_ARG, "gaze: NULL argument");
    int rc = size_check(width, height, err);
    if (rc)
        return rc;
    if (stride < 3 * (size_t)width)
        return gs_error_set(err, GS_ERR_ARG, "gaze: stride %zu < 3 * width %d", stride,
                            width);
    rc = gz_ctx_from_rgb(&n->ctx, rgb, width, height, stride);
    if (!rc)
        rc = gz_forward(&n->g, n->params, &n->ctx, n->ctx.img, width, height, out);
    n->ctx.have_forward = 0; /* the float image is not the caller's */
    return finish(rc, out, err);
}

int gs_gaze_net_forward(gs_gaze_net *n, gs_pool *pool, const float *img, int width,
                        int height, float out[4], gs_error *err)
{
    (void)pool;
    if (!n || !img || !out)
        return gs_error_set(err, GS_ERR_ARG, "gaze: NULL argument");
    int rc = size_check(width, height, err);
    if (rc)
        return rc;
    rc = gz_forward(&n->g, n->params, &n->ctx, img, width, height, out);
    return finish(rc, out, err);
}

int gs_gaze_net_backward(gs_gaze_net *n, gs_pool *pool, const float dout[4], float *dimg,
                         float *dparams, gs_error *err)
{
    (void)pool;
    if (!n || !dout)
        return gs_error_set(err, GS_ERR_ARG, "gaze: NULL argument");
    if (!n->ctx.have_forward)
        return gs_error_set(err, GS_ERR_STATE, "gaze: backward without a forward");
    int rc = gz_backward(&n->g, n->params, &n->ctx, dout, dimg, dparams);
    if (rc)
        return gs_error_set(err, rc, "gaze: backward failed (%s)", gs_strerror(rc));
    return GS_OK;
}

double gs_gaze_angular_error(const float a[2], const float b[2], float da[2])
{
    double ga[3], gb[3];
    gs_geom_pitchyaw_to_vec(a[0], a[1], ga);
    gs_geom_pitchyaw_to_vec(b[0], b[1], gb);
    double ang = gs_geom_vec3_angle(ga, gb);
    if (!da)
        return ang;
    da[0] = da[1] = 0.0f;
    double s = sin(ang);
    if (s < 1e-12)
        return ang;
    /* d(acos(ga.gb))/d(ga) = -gb / sin; ga = (-cp sy, -sp, -cp cy) */
    double cp = cos(a[0]), sp = sin(a[0]), cy = cos(a[1]), sy = sin(a[1]);
    double dp[3] = {sp * sy, -cp, sp * cy}, dy[3] = {-cp * cy, 0.0, cp * sy};
    double gp = 0, gy = 0;
    for (int i = 0; i < 3; i++) {
        gp += -gb[i] / s * dp[i];
        gy += -gb[i] / s * dy[i];
    }
    da[0] = (float)gp;
    da[1] = (float)gy;
    return ang;
}
