/* Elementwise activations and softmax. Forward functions may run in place
 * (out == in); backward functions add into dinp. */
#include "gazesplat/nn.h"

#include <math.h>

/* out[n] = max(in, 0) */
int gs_nn_relu_forward(float *out, const float *in, size_t n)
{
    if (!out || !in || n == 0)
        return GS_ERR_ARG;
    for (size_t i = 0; i < n; i++)
        out[i] = in[i] > 0.0f ? in[i] : 0.0f;
    return GS_OK;
}

/* dinp[n] += in > 0 ? dout : 0 */
int gs_nn_relu_backward(float *dinp, const float *dout, const float *in,
                        size_t n)
{
    if (!dinp || !dout || !in || n == 0)
        return GS_ERR_ARG;
    for (size_t i = 0; i < n; i++)
        dinp[i] += in[i] > 0.0f ? dout[i] : 0.0f;
    return GS_OK;
}

/* out[n] = in > 0 ? in : slope * in */
int gs_nn_leaky_relu_forward(float *out, const float *in, float slope,
                             size_t n)
{
    if (!out || !in || n == 0 || !isfinite(slope))
        return GS_ERR_ARG;
    for (size_t i = 0; i < n; i++)
        out[i] = in[i] > 0.0f ? in[i] : slope * in[i];
    return GS_OK;
}

/* dinp[n] += in > 0 ? dout : slope * dout */
int gs_nn_leaky_relu_backward(float *dinp, const float *dout, const float *in,
                              float slope, size_t n)
{
    if (!dinp || !dout || !in || n == 0 || !isfinite(slope))
        return GS_ERR_ARG;
    for (size_t i = 0; i < n; i++)
        dinp[i] += in[i] > 0.0f ? dout[i] : slope * dout[i];
    return GS_OK;
}

/* out[n] = tanh(in) */
int gs_nn_tanh_forward(float *out, const float *in, size_t n)
{
    if (!out || !in || n == 0)
        return GS_ERR_ARG;
    for (size_t i = 0; i < n; i++)
        out[i] = tanhf(in[i]);
    return GS_OK;
}

/* dinp[n] += dout * (1 - out^2) */
int gs_nn_tanh_backward(float *dinp, const float *dout, const float *out,
                        size_t n)
{
    if (!dinp || !dout || !out || n == 0)
        return GS_ERR_ARG;
    for (size_t i = 0; i < n; i++)
        dinp[i] += dout[i] * (1.0f - out[i] * out[i]);
    return GS_OK;
}

/* exp of a non-positive argument only, so nothing overflows: for x < 0,
 * 1/(1+e^-x) = e^x/(1+e^x). */
static float sigmoid1(float x)
{
    if (x >= 0.0f)
        return 1.0f / (1.0f + expf(-x));
    float e = expf(x);
    return e / (1.0f + e);
}

/* out[n] = sigmoid(in) */
int gs_nn_sigmoid_forward(float *out, const float *in, size_t n)
{
    if (!out || !in || n == 0)
        return GS_ERR_ARG;
    for (size_t i = 0; i < n; i++)
        out[i] = sigmoid1(in[i]);
    return GS_OK;
}

/* dinp[n] += dout * out * (1 - out) */
int gs_nn_sigmoid_backward(float *dinp, const float *dout, const float *out,
                           size_t n)
{
    if (!dinp || !dout || !out || n == 0)
        return GS_ERR_ARG;
    for (size_t i = 0; i < n; i++)
        dinp[i] += dout[i] * out[i] * (1.0f - out[i]);
    return GS_OK;
}

/* out[N] = exp(in - max(in)) / sum */
int gs_nn_softmax_forward(float *out, const float *in, int N)
{
    if (!out || !in || N < 1)
        return GS_ERR_ARG;
    float mx = in[0];
    for (int i = 1; i < N; i++)
        mx = in[i] > mx ? in[i] : mx;
    double sum = 0.0;
    for (int i = 0; i < N; i++) {
        out[i] = expf(in[i] - mx);
        sum += out[i];
    }
    float inv = (float)(1.0 / sum); /* sum >= 1: the max term is exp(0) */
    for (int i = 0; i < N; i++)
        out[i] *= inv;
    return GS_OK;
}

/* dinp[N] += out * (dout - sum_j out_j dout_j) */
int gs_nn_softmax_backward(float *dinp, const float *dout, const float *out,
                           int N)
{
    if (!dinp || !dout || !out || N < 1)
        return GS_ERR_ARG;
    double dot = 0.0;
    for (int i = 0; i < N; i++)
        dot += (double)out[i] * dout[i];
    float fdot = (float)dot;
    for (int i = 0; i < N; i++)
        dinp[i] += out[i] * (dout[i] - fdot);
    return GS_OK;
}
