/* The two architectures as layer lists over numbered buffers. Buffer 0 is
 * the resized, centred input [3,N,N]; the last buffer is the output [4]. */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "gazesplat/nn.h"
#include "gaze_internal.h"

const char *gs_gaze_arch_name(int arch)
{
    return arch == GS_GAZE_RESNET ? "resnet" : arch == GS_GAZE_VGG ? "vgg" : NULL;
}

int gs_gaze_arch_from_name(const char *name)
{
    if (name && strcmp(name, "resnet") == 0)
        return GS_GAZE_RESNET;
    if (name && strcmp(name, "vgg") == 0)
        return GS_GAZE_VGG;
    return -1;
}

void gs_gaze_spec_default(gs_gaze_spec *s, int arch)
{
    static const int w[GS_GAZE_STAGES] = {12, 24, 48, 64};
    s->arch = arch;
    s->input_size = 64;
    memcpy(s->widths, w, sizeof w);
    s->hidden = 96;
}

int gz_spec_check(const gs_gaze_spec *s, gs_error *err)
{
    if (!s)
        return gs_error_set(err, GS_ERR_ARG, "gaze: NULL spec");
    if (!gs_gaze_arch_name(s->arch))
        return gs_error_set(err, GS_ERR_ARG, "gaze: unknown arch %d", s->arch);
    if (s->input_size < 32 || s->input_size > 256 || s->input_size % 16)
        return gs_error_set(err, GS_ERR_ARG,
                            "gaze: input size %d (want 32..256, a multiple of 16)",
                            s->input_size);
    for (int i = 0; i < GS_GAZE_STAGES; i++)
        if (s->widths[i] < 1 || s->widths[i] > 512)
            return gs_error_set(err, GS_ERR_ARG, "gaze: width %d = %d (want 1..512)",
                                i, s->widths[i]);
    if (s->hidden < 1 || s->hidden > 4096)
        return gs_error_set(err, GS_ERR_ARG, "gaze: hidden %d (want 1..4096)",
                            s->hidden);
    return GS_OK;
}

/* ---- builder ------------------------------------------------------------ */

static int add_buf(gz_graph *g, int C, int H, int W)
{
    gz_buf *b = &g->buf[g->nbufs];
    b->C = C, b->H = H, b->W = W;
    b->off = g->act_len;
    b->len = (size_t)C * (size_t)H * (size_t)W;
    g->act_len += b->len;
    return g->nbufs++;
}

static int add_tensor(gz_graph *g, const char *name, int ndim, const int64_t *shape,
                      int fan_in)
{
    gz_tensor *t = &g->t[g->ntensors];
    snprintf(t->name, sizeof t->name, "%s", name);
    t->ndim = ndim;
    t->count = 1;
    for (int i = 0; i < ndim; i++) {
        t->shape[i] = shape[i];
        t->count *= (size_t)shape[i];
    }
    t->off = g->nparams;
    t->fan_in = fan_in;
    g->nparams += t->count;
    return g->ntensors++;
}

static gz_op *add_op(gz_graph *g, int kind, int in)
{
    gz_op *o = &g->op[g->nops++];
    const gz_buf *b = &g->buf[in];
    memset(o, 0, sizeof *o);
    o->kind = kind, o->in = in, o->in2 = -1, o->wt = -1;
    o->C = b->C, o->H = b->H, o->W = b->W;
    return o;
}

/* Weight name.w [shape] and bias name.b [OC]. */
static int add_weights(gz_graph *g, const char *name, int ndim, const int64_t *shape,
                       int fan_in)
{
    char n[32];
    snprintf(n, sizeof n, "%s.w", name);
    int wt = add_tensor(g, n, ndim, shape, fan_in);
    snprintf(n, sizeof n, "%s.b", name);
    add_tensor(g, n, 1, shape, 0);
    return wt;
}

static int conv(gz_graph *g, int in, const char *name, int OC, int k)
{
    gz_op *o = add_op(g, k == 3 ? GZ_CONV3 : GZ_CONV1, in);
    int64_t shape[4] = {OC, o->C, k, k};
    o->OC = OC;
    o->wt = add_weights(g, name, k == 3 ? 4 : 2, shape, o->C * k * k);
    o->out = add_buf(g, OC, o->H, o->W);
    if (k == 3) {
        size_t s = gs_nn_conv3x3_scratch_size(o->C, o->H, o->W);
        if (s > g->scratch_len)
            g->scratch_len = s;
    }
    return o->out;
}

static int relu(gz_graph *g, int in)
{
    gz_op *o = add_op(g, GZ_RELU, in);
    o->out = add_buf(g, o->C, o->H, o->W);
    return o->out;
}

static int pool(gz_graph *g, int in)
{
    gz_op *o = add_op(g, GZ_POOL, in);
    o->out = add_buf(g, o->C, o->H / 2, o->W / 2);
    return o->out;
}

static int add(gz_graph *g, int a, int b)
{
    gz_op *o = add_op(g, GZ_ADD, a);
    o->in2 = b;
    o->out = add_buf(g, o->C, o->H, o->W);
    return o->out;
}

static int linear(gz_graph *g, int in, const char *name, int OC)
{
    gz_op *o = add_op(g, GZ_LINEAR, in);
    int IC = o->C * o->H * o->W;
    int64_t shape[2] = {OC, IC};
    o->OC = OC;
    o->wt = add_weights(g, name, 2, shape, IC);
    o->out = add_buf(g, OC, 1, 1);
    return o->out;
}

/* The eye band: rows 72..136 and columns 48..208 of a 256 px normalized
 * image. Over the generator's head poses the eye landmarks stay within
 * columns 70..190 and rows 90..120 (measured on test identities). */
const gz_window gz_eye_window = {0.1875, 0.8125, 0.28125, 0.53125};

/* stem, then per stage: pool, conv-relu-conv + 1x1 skip, add, relu */
static int build_resnet(gz_graph *g, const gs_gaze_spec *s, int x)
{
    char n[32];
    x = relu(g, conv(g, x, "stem1", s->widths[0], 3));
    x = relu(g, conv(g, x, "stem2", s->widths[0], 3));
    for (int st = 1; st < GS_GAZE_STAGES; st++) {
        x = pool(g, x);
        snprintf(n, sizeof n, "s%d.conv1", st);
        int m = relu(g, conv(g, x, n, s->widths[st], 3));
        snprintf(n, sizeof n, "s%d.conv2", st);
        m = conv(g, m, n, s->widths[st], 3);
        snprintf(n, sizeof n, "s%d.skip", st);
        x = relu(g, add(g, m, conv(g, x, n, s->widths[st], 1)));
    }
    return pool(g, x);
}

/* (conv-relu) x 2, pool for three stages; conv-relu, pool for the last */
static int build_vgg(gz_graph *g, const gs_gaze_spec *s, int x)
{
    char n[32];
    int k = 1;
    for (int st = 0; st < GS_GAZE_STAGES; st++) {
        for (int r = 0; r < (st < GS_GAZE_STAGES - 1 ? 2 : 1); r++) {
            snprintf(n, sizeof n, "conv%d", k++);
            x = relu(g, conv(g, x, n, s->widths[st], 3));
        }
        x = pool(g, x);
    }
    return x;
}

/* The eye branch, plain in both archs: (conv-relu) x 2 at w0, pool,
 * conv-relu at w1, pool, conv-relu at w2, pool. */
static int build_eyes(gz_graph *g, const gs_gaze_spec *s, int x)
{
    x = relu(g, conv(g, x, "eye1", s->widths[0], 3));
    x = pool(g, relu(g, conv(g, x, "eye2", s->widths[0], 3)));
    x = pool(g, relu(g, conv(g, x, "eye3", s->widths[1], 3)));
    return pool(g, relu(g, conv(g, x, "eye4", s->widths[2], 3)));
}

/* Eye band size for input N: N/2 rows, 5N/4 columns rounded to a multiple
 * of 8 (three 2x2 pools). */
void gz_eye_size(int N, int *Eh, int *Ew)
{
    *Eh = N / 2;
    *Ew = 8 * ((5 * N + 16) / 32);
}

int gz_graph_build(const gs_gaze_spec *s, gz_graph *g, gs_error *err)
{
    int rc = gz_spec_check(s, err), Eh, Ew;
    if (rc)
        return rc;
    memset(g, 0, sizeof *g);
    gz_eye_size(s->input_size, &Eh, &Ew);
    int x = add_buf(g, 3, s->input_size, s->input_size);
    int e = add_buf(g, 3, Eh, Ew);
    x = s->arch == GS_GAZE_RESNET ? build_resnet(g, s, x) : build_vgg(g, s, x);
    e = build_eyes(g, s, e);
    x = relu(g, add(g, linear(g, x, "fc1", s->hidden), linear(g, e, "fc1e", s->hidden)));
    linear(g, x, "fc2", GS_GAZE_OUTPUTS);
    return GS_OK;
}

int gz_net_alloc(const gs_gaze_spec *s, gs_gaze_net **out, gs_error *err)
{
    gs_gaze_net *n = calloc(1, sizeof *n);
    if (!n)
        return gs_error_set(err, GS_ERR_NOMEM, "gaze: out of memory");
    int rc = gz_graph_build(s, &n->g, err);
    if (!rc) {
        n->spec = *s;
        n->params = calloc(n->g.nparams, sizeof(float));
        if (!n->params || gz_ctx_init(&n->ctx, &n->g))
            rc = gs_error_set(err, GS_ERR_NOMEM, "gaze: out of memory");
    }
    if (rc) {
        gs_gaze_net_destroy(n);
        return rc;
    }
    *out = n;
    return GS_OK;
}
