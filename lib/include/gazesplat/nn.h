/* gs_nn: neural-network kernels as forward/backward pairs, losses and Adam.
 *
 * Conventions (llm.c style):
 * - gs_nn_X_forward(out, in, weights..., dims...) writes out.
 * - gs_nn_X_backward(dinp, dweights..., dout, saved..., dims...) ADDS (+=)
 *   into every gradient it is given; a NULL gradient pointer is skipped.
 *   Zero the gradients before the first backward of a step.
 * - Tensors are float32, row-major. Feature maps are CHW (channel planes of
 *   H x W, row 0 at the top); a batch is a loop in the caller. Shapes are
 *   written at each function in brackets.
 * - Every call returns GS_OK or a negative gs_status: GS_ERR_ARG for a NULL
 *   required pointer, a size < 1, a scratch buffer that is too short or a bad
 *   scalar; GS_ERR_LIMIT when a size does not fit the int dimensions of BLAS.
 *   Kernels do not check data for NaN/Inf (the optimizer does).
 * - Outputs must not alias inputs unless a function says so.
 * - No kernel allocates. Those that need temporary memory take a caller
 *   buffer `scratch` of `scratch_len` floats; gs_nn_X_scratch_size() gives
 *   the length needed (0 for invalid sizes).
 * - Determinism: kernels run their own loops in a fixed order on the calling
 *   thread and keep no state, so any number of threads calling them gets the
 *   same bytes, PROVIDED OpenBLAS runs one thread. OpenBLAS's threaded sgemm
 *   does not give the bits of its single-threaded run (measured with
 *   OpenBLAS 0.3.21: 1 vs 2 threads differ with its Haswell/Zen kernels even
 *   on power-of-two shapes, and with 3+ threads, or odd shapes, on others).
 *   Programs pin it once with gs_nn_blas_set_threads(1) (or the environment
 *   variable OPENBLAS_NUM_THREADS=1) and parallelise with gs_pool over fixed
 *   partitions.
 */
#ifndef GAZESPLAT_NN_H
#define GAZESPLAT_NN_H

#include <stddef.h>

#include "gazesplat/error.h"

#ifdef __cplusplus
extern "C" {
#endif

/* ---- OpenBLAS threads (process-wide policy, for programs) --------------- */

/* Sets the number of OpenBLAS threads for the whole process (see
 * Determinism above: 1 for bit-identical results). The library never calls
 * it itself. */
void gs_nn_blas_set_threads(int n);
int gs_nn_blas_threads(void);

/* OpenBLAS's kernels for this CPU (process-wide policy, for programs).
 * OpenBLAS chooses its kernels when it is loaded, from the CPU model; on a
 * CPU it does not recognise (virtual machines) it falls back to its SSE3
 * "Prescott" kernels, about 4x slower than the AVX-512 ones. When
 * OPENBLAS_CORETYPE is unset, OpenBLAS chose such a fallback, and CPUID shows
 * AVX-512 (F, CD, BW, DQ, VL) or AVX2 + FMA, this sets OPENBLAS_CORETYPE to
 * SkylakeX or Haswell and executes the program again (/proc/self/exe, same
 * argv, same process id, open descriptors kept): call it first thing in
 * main, before threads, files or sockets. It does not return then. Returns 0
 * when there is nothing to do (the variable is set, by the user or by the
 * exec, or OpenBLAS recognised the CPU, or the CPU lacks the features), or
 * GS_ERR_UNSUPPORTED when the exec failed (the program goes on unchanged).
 * Set OPENBLAS_CORETYPE yourself to keep another choice. */
int gs_nn_blas_select_kernels(char **argv);

/* OpenBLAS's name of the kernels in use ("SkylakeX", "Prescott", ...). */
const char *gs_nn_blas_core(void);

/* ---- Linear and convolutions ------------------------------------------ */

/* out[B,OC] = in[B,IC] . w[OC,IC]^T + b[OC]. b may be NULL (no bias). */
int gs_nn_linear_forward(float *out, const float *in, const float *w,
                         const float *b, int B, int IC, int OC);
/* dinp[B,IC] += dout[B,OC] . w[OC,IC]
 * dw[OC,IC]  += dout[B,OC]^T . in[B,IC]
 * db[OC]     += sum_b dout[b,:] */
int gs_nn_linear_backward(float *dinp, float *dw, float *db,
                          const float *dout, const float *in, const float *w,
                          int B, int IC, int OC);

/* 1x1 convolution, a linear map over the pixels of a CHW map:
 * out[OC,HW] = w[OC,IC] . in[IC,HW] + b[OC]  (HW = H*W). b may be NULL. */
int gs_nn_conv1x1_forward(float *out, const float *in, const float *w,
                          const float *b, int IC, int OC, int HW);
/* dinp[IC,HW] += w^T . dout;  dw[OC,IC] += dout . in^T;
 * db[OC] += sum_p dout[:,p] */
int gs_nn_conv1x1_backward(float *dinp, float *dw, float *db,
                           const float *dout, const float *in, const float *w,
                           int IC, int OC, int HW);

/* 3x3 convolution, stride 1, zero padding 1 (PyTorch Conv2d(k=3, p=1)):
 * out[OC,H,W] = conv(in[IC,H,W], w[OC,IC,3,3]) + b[OC]. b may be NULL.
 * Runs as im2col + sgemm over bands of rows; the band height depends on W
 * only, so results do not depend on the scratch length given. */
size_t gs_nn_conv3x3_scratch_size(int IC, int H, int W);
int gs_nn_conv3x3_forward(float *out, const float *in, const float *w,
                          const float *b, int IC, int OC, int H, int W,
                          float *scratch, size_t scratch_len);
/* Gradients for in[IC,H,W], w[OC,IC,3,3], b[OC] from dout[OC,H,W]. */
int gs_nn_conv3x3_backward(float *dinp, float *dw, float *db,
                           const float *dout, const float *in, const float *w,
                           int IC, int OC, int H, int W, float *scratch,
                           size_t scratch_len);

/* ---- Elementwise activations (n values; forward may run in place) ------ */

/* out = max(in, 0); the gradient at 0 is 0. */
int gs_nn_relu_forward(float *out, const float *in, size_t n);
int gs_nn_relu_backward(float *dinp, const float *dout, const float *in,
                        size_t n);
/* out = in > 0 ? in : slope * in; the gradient at 0 is slope (as PyTorch). */
int gs_nn_leaky_relu_forward(float *out, const float *in, float slope,
                             size_t n);
int gs_nn_leaky_relu_backward(float *dinp, const float *dout, const float *in,
                              float slope, size_t n);
/* out = tanh(in); backward uses the saved out. */
int gs_nn_tanh_forward(float *out, const float *in, size_t n);
int gs_nn_tanh_backward(float *dinp, const float *dout, const float *out,
                        size_t n);
/* out = 1 / (1 + exp(-in)), never overflowing; backward uses the saved out. */
int gs_nn_sigmoid_forward(float *out, const float *in, size_t n);
int gs_nn_sigmoid_backward(float *dinp, const float *dout, const float *out,
                           size_t n);
/* out[N] = softmax(in[N]) = exp(in - max) / sum; sums in double.
 * Backward: dinp += out * (dout - sum(out * dout)), using the saved out. */
int gs_nn_softmax_forward(float *out, const float *in, int N);
int gs_nn_softmax_backward(float *dinp, const float *dout, const float *out,
                           int N);

/* ---- Resampling --------------------------------------------------------- */

/* Pixel shuffle x2 (PyTorch PixelShuffle(2)): in[4C,H,W] -> out[C,2H,2W],
 * out[c, 2h+i, 2w+j] = in[4c+2i+j, h, w]. */
int gs_nn_pixel_shuffle_forward(float *out, const float *in, int C, int H,
                                int W);
/* dinp[4C,H,W] += the inverse permutation of dout[C,2H,2W]. */
int gs_nn_pixel_shuffle_backward(float *dinp, const float *dout, int C, int H,
                                 int W);

/* Bilinear 2x upsampling, PyTorch interpolate(scale_factor=2,
 * mode='bilinear', align_corners=False): in[C,H,W] -> out[C,2H,2W].
 * Along each axis, output index o reads src = (o + 0.5) / 2 - 0.5, clamped
 * below at 0; i0 = floor(src), i1 = min(i0 + 1, n - 1), weights
 * (1 - (src - i0), src - i0). */
int gs_nn_upsample2x_forward(float *out, const float *in, int C, int H, int W);
/* Output rows [oy0, oy1) of every channel only (the same values: a pool
 * splits the rows). */
int gs_nn_upsample2x_forward_rows(float *out, const float *in, int C, int H,
                                  int W, int oy0, int oy1);
int gs_nn_upsample2x_backward(float *dinp, const float *dout, int C, int H,
                              int W);
/* Bilinear resize to any size, PyTorch interpolate(size=(OH, OW),
 * mode='bilinear', align_corners=False): in[C,H,W] -> out[C,OH,OW].
 * Along each axis src = (n / n_out) (o + 0.5) - 0.5 in float, clamped below
 * at 0, with the taps above; OH = 2H gives gs_nn_upsample2x_forward's
 * values exactly. Forward only (render-time feature resampling). */
int gs_nn_resize_bilinear_forward(float *out, const float *in, int C, int H,
                                  int W, int OH, int OW);

/* Fixed blur [1,2,1] x [1,2,1] / 16 per channel, reflect border (PyTorch
 * pad mode 'reflect': index -1 reads 1, index n reads n - 2), so H, W >= 2.
 * in[C,H,W] -> out[C,H,W]. */
int gs_nn_blur_forward(float *out, const float *in, int C, int H, int W);
int gs_nn_blur_backward(float *dinp, const float *dout, int C, int H, int W);

/* 2x2 average pooling, stride 2 (PyTorch AvgPool2d(2)) for even H, W:
 * in[C,H,W] -> out[C,H/2,W/2], out[c,y,x] = mean of in[c,2y..2y+1,2x..2x+1].
 * GS_ERR_ARG for an odd H or W. */
int gs_nn_avgpool2x_forward(float *out, const float *in, int C, int H, int W);
/* dinp[C,H,W] += dout[C,H/2,W/2] / 4 spread over each 2x2 window. */
int gs_nn_avgpool2x_backward(float *dinp, const float *dout, int C, int H,
                             int W);

/* ---- Cross-attention of a code vector over the pixels ------------------- */

/* GazeGaussian renderer attention. For x[C,HW], code[D], wk[D,C], bk[D],
 * wv[C,C], bv[C]:
 *   k_p = wk x_p + bk,  v_p = wv x_p + bv          (per pixel p)
 *   att = softmax_p((k_p . code) / temp)           (over all HW pixels)
 *   out_p = x_p + sum_q att_q v_q                  (one vector, every pixel)
 * The released model uses temp = 12 = sqrt(144).
 * Computed in the folded form: k_p . code = x_p . (wk^T code) + bk . code,
 * and the constant bk . code cancels in the softmax, so bk does not change
 * out (it may be NULL) and its gradient is exactly zero; sum_q att_q v_q =
 * wv (sum_q att_q x_q) + bv. Cost O(C (HW + C + D)).
 * att[HW] is written by forward and read by backward (a saved activation).
 * scratch: gs_nn_attention_scratch_size(C) floats. */
size_t gs_nn_attention_scratch_size(int C);
int gs_nn_attention_forward(float *out, float *att, const float *x,
                            const float *code, const float *wk,
                            const float *bk, const float *wv, const float *bv,
                            int C, int D, int HW, float temp, float *scratch,
                            size_t scratch_len);
/* Gradients for x[C,HW], code[D], wk[D,C], bk[D] (adds 0), wv[C,C], bv[C]
 * from dout[C,HW], with x and att as in forward. */
int gs_nn_attention_backward(float *dx, float *dcode, float *dwk, float *dbk,
                             float *dwv, float *dbv, const float *dout,
                             const float *x, const float *att,
                             const float *code, const float *wk,
                             const float *wv, int C, int D, int HW, float temp,
                             float *scratch, size_t scratch_len);

/* ---- Losses (forward stores the loss value; backward takes dloss) ------- */

/* Masked L1: loss = sum_{c,p} m_p |a[c,p] - b[c,p]| / (C * HW), a, b [C,HW],
 * mask [HW] broadcast over channels, NULL = all ones. The mean is over ALL
 * C*HW elements, not over the masked ones: for a 0/1 mask this equals the
 * plain L1 mean after compositing both images onto the same background
 * outside the mask (the GazeNeRF/GazeGaussian training loss), and an empty
 * mask gives 0 rather than 0/0.
 * Backward: da += dloss * m_p * sign(a - b) / (C * HW), sign(0) = 0. */
int gs_nn_l1_forward(float *loss, const float *a, const float *b,
                     const float *mask, int C, int HW);
int gs_nn_l1_backward(float *da, float dloss, const float *a, const float *b,
                      const float *mask, int C, int HW);

/* SSIM loss = 1 - mean SSIM over channels and window positions, for images
 * x (prediction), y (target) [C,H,W] with data range 1:
 *   window: 11x11 Gaussian, sigma 1.5, normalised to sum 1 (separable)
 *   C1 = 0.01^2, C2 = 0.03^2,
 *   SSIM = (2 mx my + C1)(2 sxy + C2) / ((mx^2 + my^2 + C1)(sx2 + sy2 + C2))
 *   with sx2 = E[x^2] - mx^2 etc. under the window.
 * Padding (which window positions are averaged):
 *   GS_NN_SSIM_VALID: windows inside the image only, (H-10) x (W-10)
 *     positions (pytorch-msssim's ssim(..., size_average=True, no downsampling)).
 *   GS_NN_SSIM_ZERO: zero padding 5, H x W positions (the 'ssim' of the
 *     GazeNeRF/GazeGaussian loss).
 * Backward: dx += dloss * d(loss)/dx (no gradient for y). */
enum { GS_NN_SSIM_VALID = 0, GS_NN_SSIM_ZERO = 1 };
size_t gs_nn_ssim_scratch_size(int H, int W, int padding);
int gs_nn_ssim_loss_forward(float *loss, const float *x, const float *y,
                            int C, int H, int W, int padding, float *scratch,
                            size_t scratch_len);
int gs_nn_ssim_loss_backward(float *dx, float dloss, const float *x,
                             const float *y, int C, int H, int W, int padding,
                             float *scratch, size_t scratch_len);
/* The loss and, when dx is not NULL, its gradient (dx += dloss *
 * d(loss)/dx) in one pass over the window statistics, on a pool (NULL:
 * inline), channel by channel in bands of rows. The same bytes as
 * gs_nn_ssim_loss_forward and gs_nn_ssim_loss_backward for any thread
 * count (the sum of the loss keeps their order). scratch: at least
 * gs_nn_ssim_fused_scratch_size(C, H, W, padding) floats (0: sizes out of
 * range). Like any gs_pool_for, not to be called from a task of the same
 * pool. */
struct gs_pool;
size_t gs_nn_ssim_fused_scratch_size(int C, int H, int W, int padding);
int gs_nn_ssim_loss_fused(struct gs_pool *pool, float *loss, float *dx, float dloss,
                          const float *x, const float *y, int C, int H, int W, int padding,
                          float *scratch, size_t scratch_len);

/* ---- Adam with parameter groups and gradient clipping ------------------- */

/* A group of parameters with its gradient buffer (both owned by the caller,
 * who must keep them alive while the optimizer uses them). */
typedef struct gs_nn_param_group {
    float *param;   /* [n], updated in place by gs_nn_adam_step */
    float *grad;    /* [n], read by step, zeroed by gs_nn_adam_zero_grad */
    size_t n;       /* >= 1 */
    double lr_mult; /* this group's learning rate = lr * lr_mult, >= 0 */
} gs_nn_param_group;

/* Hyperparameters are doubles, as PyTorch's Python floats: the float32
 * update uses (float)beta1, (float)(1 - beta1) etc., so the arithmetic
 * matches torch.optim.Adam on float32 parameters. */
typedef struct gs_nn_adam_config {
    double beta1;         /* 0.9 */
    double beta2;         /* 0.999 */
    double eps;           /* 1e-8 */
    double max_grad_norm; /* clip the global L2 norm to this; <= 0: never */
} gs_nn_adam_config;

typedef struct gs_nn_adam gs_nn_adam; /* opaque; moments in one allocation */

/* The defaults above (PyTorch's Adam, no clipping). */
gs_nn_adam_config gs_nn_adam_default_config(void);

/* Creates an optimizer for ngroups groups (copied; the arrays they point to
 * are not). cfg NULL = defaults. Moments start at zero, step count at 0. */
int gs_nn_adam_create(gs_nn_adam **out, const gs_nn_param_group *groups,
                      int ngroups, const gs_nn_adam_config *cfg,
                      gs_error *err);
void gs_nn_adam_destroy(gs_nn_adam *adam);

/* One step with base learning rate lr (>= 0), as PyTorch's Adam:
 *   norm = sqrt(sum of every squared gradient) (in double, in fixed
 *          chunks of each group, chunk by chunk in group order)
 *   if non-finite: return GS_ERR_NONFINITE and change nothing (skip the step)
 *   g = grad * min(1, max_grad_norm / (norm + 1e-6)) when clipping is on
 *       (torch.nn.utils.clip_grad_norm_); the grad buffers are not modified
 *   t += 1; m = b1 m + (1 - b1) g; v = b2 v + (1 - b2) g^2
 *   param -= (lr_mult lr / (1 - b1^t)) m / (sqrt(v) / sqrt(1 - b2^t) + eps)
 * grad_norm (may be NULL) receives the norm before clipping. */
int gs_nn_adam_step(gs_nn_adam *adam, double lr, double *grad_norm);
/* The same step with its chunks on the pool (NULL: inline): the same
 * bytes for any thread count. */
int gs_nn_adam_step_pool(gs_nn_adam *adam, struct gs_pool *pool, double lr,
                         double *grad_norm);

/* Sets every group's gradient to zero. */
void gs_nn_adam_zero_grad(gs_nn_adam *adam);

/* Number of steps taken (t), and setting it when restoring a checkpoint. */
long gs_nn_adam_steps(const gs_nn_adam *adam);
int gs_nn_adam_set_steps(gs_nn_adam *adam, long t);

/* First and second moments of group g, [n] each, for checkpoints. */
int gs_nn_adam_moments(gs_nn_adam *adam, int g, float **m, float **v);

#ifdef __cplusplus
}
#endif
#endif
