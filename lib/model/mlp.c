/* Per-point MLPs (the paper's 1x1 Conv1d stacks) and positional encoding.
 * Hidden layers use LeakyReLU 0.01, the output layer is linear. */
#include <math.h>
#include <string.h>

#include "gazesplat/nn.h"
#include "model_internal.h"

#define GS_MLP_SLOPE 0.01f

/* acts layout: for each hidden layer l: pre[n, dims[l+1]] then
 * post[n, dims[l+1]]. */
size_t gs_mlp_act_size(const gs_mlp *m, int n)
{
    size_t s = 0;
    for (int l = 0; l + 1 < m->nl; l++)
        s += 2 * (size_t)n * (size_t)m->dims[l + 1];
    return s;
}

size_t gs_mlp_scratch_size(const gs_mlp *m, int n)
{
    int widest = 0;
    for (int l = 0; l < m->nl; l++)
        if (m->dims[l] > widest)
            widest = m->dims[l];
    return 2 * (size_t)n * (size_t)widest;
}

/* out[i] = pre[i] > 0 ? x[i] : slope x[i] (out may be x): the LeakyReLU
 * (x = pre) and its backward (x = the gradient), the same values as gs_nn's,
 * with the choice made as a bitwise blend on the sign-tested bits: GCC
 * keeps the float compare as a branch that random signs make mispredict,
 * while this form vectorises (renderer_ops.c's select_pos). */
static void leaky_select(float *out, const float *x, const float *pre,
                         float slope, size_t n)
{
    for (size_t i = 0; i < n; i++) {
        float b = slope * x[i];
        int32_t k, ix, ib, r;
        memcpy(&k, &pre[i], sizeof k);
        memcpy(&ix, &x[i], sizeof ix);
        memcpy(&ib, &b, sizeof ib);
        int32_t m = -(int32_t)(k > 0);
        r = (ix & m) | (ib & ~m);
        memcpy(&out[i], &r, sizeof r);
    }
}

void gs_mlp_forward(const gs_mlp *m, const float *in, int n, float *acts,
                    float *out)
{
    const float *x = in;
    for (int l = 0; l < m->nl; l++) {
        int ic = m->dims[l], oc = m->dims[l + 1];
        if (l + 1 == m->nl) {
            gs_nn_linear_forward(out, x, m->w[l], m->b[l], n, ic, oc);
            break;
        }
        float *pre = acts, *post = acts + (size_t)n * oc;
        gs_nn_linear_forward(pre, x, m->w[l], m->b[l], n, ic, oc);
        leaky_select(post, pre, pre, GS_MLP_SLOPE, (size_t)n * oc);
        x = post;
        acts += 2 * (size_t)n * oc;
    }
}

void gs_mlp_forward_after_first(const gs_mlp *m, int n, float *acts,
                                float *out)
{
    int h = m->dims[1];
    if (m->nl == 1) {
        memcpy(out, acts, (size_t)n * h * sizeof(float));
        return;
    }
    float *post = acts + (size_t)n * h;
    leaky_select(post, acts, acts, GS_MLP_SLOPE, (size_t)n * h);
    const float *x = post;
    acts += 2 * (size_t)n * h;
    for (int l = 1; l < m->nl; l++) {
        int ic = m->dims[l], oc = m->dims[l + 1];
        if (l + 1 == m->nl) {
            gs_nn_linear_forward(out, x, m->w[l], m->b[l], n, ic, oc);
            break;
        }
        float *pre = acts;
        post = acts + (size_t)n * oc;
        gs_nn_linear_forward(pre, x, m->w[l], m->b[l], n, ic, oc);
        leaky_select(post, pre, pre, GS_MLP_SLOPE, (size_t)n * oc);
        x = post;
        acts += 2 * (size_t)n * oc;
    }
}

/* dout[n, dims[nl]] is read only. scratch: gs_mlp_scratch_size floats
 * (two ping-pong buffers for the hidden-layer gradients). */
void gs_mlp_backward(const gs_mlp *m, const gs_mlp *g, const float *in, int n,
                     const float *acts, const float *dout, float *din,
                     float *scratch)
{
    const float *pre[4] = {0}, *post[4] = {0};
    const float *a = acts;
    for (int l = 0; l + 1 < m->nl; l++) {
        size_t sz = (size_t)n * m->dims[l + 1];
        pre[l] = a;
        post[l] = a + sz;
        a += 2 * sz;
    }
    size_t half = gs_mlp_scratch_size(m, n) / 2;
    const float *d = dout;  /* gradient at the output of layer l */
    for (int l = m->nl - 1; l >= 0; l--) {
        int ic = m->dims[l], oc = m->dims[l + 1];
        const float *x = l == 0 ? in : post[l - 1];
        if (l == 0) {
            gs_nn_linear_backward(din, g->w[0], g->b[0], d, x, m->w[0], n,
                                  ic, oc);
            break;
        }
        float *dx = scratch + (l & 1) * half;
        size_t sz = (size_t)n * ic;
        memset(dx, 0, sz * sizeof(float));
        gs_nn_linear_backward(dx, g->w[l], g->b[l], d, x, m->w[l], n, ic, oc);
        /* Through the LeakyReLU of layer l-1. */
        leaky_select(dx, dx, pre[l - 1], GS_MLP_SLOPE, sz);
        d = dx;
    }
}

void gs_model_pe(const double *x, int n, float *out)
{
    for (int i = 0; i < n; i++)
        out[i] = (float)x[i];
    float *o = out + n;
    for (int k = 0; k < GS_PE_FREQS; k++) {
        double f = (double)(1 << k);
        for (int i = 0; i < n; i++) {
            o[i] = (float)sin(f * x[i]);
            o[n + i] = (float)cos(f * x[i]);
        }
        o += 2 * n;
    }
}

void gs_model_pe_backward(const double *x, int n, const float *dout,
                          double *dx)
{
    for (int i = 0; i < n; i++)
        dx[i] += dout[i];
    const float *d = dout + n;
    for (int k = 0; k < GS_PE_FREQS; k++) {
        double f = (double)(1 << k);
        for (int i = 0; i < n; i++)
            dx[i] += f * (cos(f * x[i]) * d[i] - sin(f * x[i]) * d[n + i]);
        d += 2 * n;
    }
}

size_t gs_mlp_param_count(const gs_mlp *m)
{
    size_t n = 0;
    for (int l = 0; l < m->nl; l++)
        n += (size_t)m->dims[l] * m->dims[l + 1] + (size_t)m->dims[l + 1];
    return n;
}
