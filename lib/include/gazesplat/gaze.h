/* gs_gaze: a CNN estimating gaze and head pose from a normalized face image.
 *
 * Input: a normalized face image (the model's normalized camera, see
 * geom.h; 256 x 256 for the CPU model) of any size. The net resizes it to
 * its own input size (input_size x input_size, 64 by default) with area
 * (box) weights, and the eye band (a fixed window around both eyes) to
 * input_size/2 x 5 input_size/4, subtracts 0.5 and runs a face branch of
 * one of two architectures plus a small eye branch:
 *   GS_GAZE_RESNET  a small ResNet (the evaluation estimator)
 *   GS_GAZE_VGG     a plain conv stack (the loss estimator)
 * Output, 4 floats, radians, normalized camera frame (ETH-XGaze signs, the
 * labels GazeNeRF evaluates with):
 *   out[0] gaze pitch, out[1] gaze yaw, out[2] head pitch, out[3] head yaw.
 * docs/gaze.md lists the layers and tensors.
 *
 * Files: safetensors (safetensors.h), one F32 tensor per weight and bias,
 * __metadata__ format = "gazesplat-gaze-estimator", format_version, arch,
 * input_size, widths, hidden. The loader validates every field, shape and
 * value (finite) and refuses anything else with GS_ERR_FORMAT or
 * GS_ERR_UNSUPPORTED and a message.
 *
 * Threads and determinism: the forward and backward of one image run on
 * the calling thread (OpenBLAS pinned to one thread, see nn.h); the pool,
 * which may be NULL, splits the training batch and sample generation over
 * fixed per-sample slots summed in sample order, so every result is the
 * same bytes for any thread count. A net is not safe for concurrent use:
 * one net per thread (gs_gaze_net_clone is cheap).
 *
 * Every call returns GS_OK or a negative gs_status; err may be NULL. */
#ifndef GAZESPLAT_GAZE_H
#define GAZESPLAT_GAZE_H

#include <stddef.h>
#include <stdint.h>

#include "gazesplat/error.h"
#include "gazesplat/pool.h"

#ifdef __cplusplus
extern "C" {
#endif

#define GS_GAZE_FORMAT_NAME "gazesplat-gaze-estimator"
#define GS_GAZE_FORMAT_VERSION 1
#define GS_GAZE_OUTPUTS 4
#define GS_GAZE_STAGES 4           /* width entries */
#define GS_GAZE_MAX_IMAGE_SIDE 8192 /* images given to the net */

typedef enum gs_gaze_arch { GS_GAZE_RESNET = 0, GS_GAZE_VGG = 1 } gs_gaze_arch;

/* Name of an architecture ("resnet", "vgg"), or NULL. */
const char *gs_gaze_arch_name(int arch);
/* GS_GAZE_RESNET / GS_GAZE_VGG for a name, -1 if unknown. */
int gs_gaze_arch_from_name(const char *name);

typedef struct gs_gaze_spec {
    int arch;                   /* gs_gaze_arch */
    int input_size;             /* 32..256, a multiple of 16 */
    int widths[GS_GAZE_STAGES]; /* channels of the 4 stages, 1..512 */
    int hidden;                 /* fully connected hidden units, 1..4096 */
} gs_gaze_spec;

/* The shipped configuration: input 64, widths 12 24 48 64, hidden 96. */
void gs_gaze_spec_default(gs_gaze_spec *s, int arch);

typedef struct gs_gaze_net gs_gaze_net;

/* A new net with He-initialised weights drawn from seed (same seed, same
 * bytes). GS_ERR_ARG for a spec outside the ranges above. */
int gs_gaze_net_create(const gs_gaze_spec *s, uint64_t seed,
                       gs_gaze_net **out, gs_error *err);
int gs_gaze_net_load(const char *path, gs_gaze_net **out, gs_error *err);
int gs_gaze_net_load_mem(const void *buf, size_t len, gs_gaze_net **out,
                         gs_error *err);
/* Atomic (safetensors writer). */
int gs_gaze_net_save(const gs_gaze_net *n, const char *path, gs_error *err);
/* An independent copy (weights and spec). */
int gs_gaze_net_clone(const gs_gaze_net *n, gs_gaze_net **out, gs_error *err);
void gs_gaze_net_destroy(gs_gaze_net *n); /* NULL is fine */

void gs_gaze_net_spec(const gs_gaze_net *n, gs_gaze_spec *s);
/* All weights as one array of gs_gaze_net_param_count floats, in the
 * file's tensor order (docs/gaze.md); writable for training. */
size_t gs_gaze_net_param_count(const gs_gaze_net *n);
float *gs_gaze_net_params(gs_gaze_net *n);

/* rgb: any size (resized inside), 8-bit RGB, stride bytes per row; the
 * net sees value / 255.0f, as the float path.
 * out[4] = gaze pitch, gaze yaw, head pitch, head yaw (radians, normalized
 * camera). Sizes 1..GS_GAZE_MAX_IMAGE_SIDE. */
int gs_gaze_net_predict(gs_gaze_net *n, gs_pool *pool, const uint8_t *rgb,
                        int width, int height, size_t stride, float out[4],
                        gs_error *err);

/* Float path (for losses): img [3,height,width] CHW in [0,1] (values are
 * not clamped), out[4] as predict. Keeps the activations for backward. */
int gs_gaze_net_forward(gs_gaze_net *n, gs_pool *pool, const float *img,
                        int width, int height, float out[4], gs_error *err);
/* Backward of L = sum_k dout[k] * out[k] for the last forward:
 *   dimg[3,height,width] += dL/dimg    (NULL: skipped)
 *   dparams[param_count] += dL/dparams (NULL: skipped)
 * GS_ERR_STATE without a forward before it. */
int gs_gaze_net_backward(gs_gaze_net *n, gs_pool *pool, const float dout[4],
                         float *dimg, float *dparams, gs_error *err);

/* The estimator's training loss on one sample: L1 over the four angles.
 * Returns mean |out - lab| and sets dout[k] = scale * sign(out[k] - lab[k])
 * (0 where equal), the seed of gs_gaze_net_backward; scale carries the
 * mean's 1/4 and the batch's 1/B. */
float gs_gaze_l1_loss(const float out[4], const float lab[4], float scale,
                      float dout[4]);

/* Angle between the gaze directions of (pitch, yaw) a and b, radians, and
 * its gradient with respect to a (da may be NULL). 0 gradient where the
 * angle is 0 (the subgradient PyTorch's acos would not give). */
double gs_gaze_angular_error(const float a[2], const float b[2], float da[2]);

/* ---- training on synthetic heads (lib/synth, TRAIN identities) ---- */

typedef void (*gs_gaze_log_fn)(void *ctx, const char *fmt, ...)
    __attribute__((format(printf, 2, 3)));

typedef struct gs_gaze_train_options {
    long steps;            /* total steps (a resumed run continues to it) */
    long stop_after;       /* > 0: stop after this step, keeping the schedule
                              of `steps` (time-boxed runs); 0: run to steps */
    int batch;             /* images per step (16) */
    double lr;             /* Adam peak learning rate (1e-3), cosine decay */
    uint64_t seed;         /* sample stream (the net's init seed is separate) */
    uint64_t identities;   /* TRAIN identities drawn from (20000) */
    int cache;             /* samples kept in memory and re-drawn (2048) */
    int fresh;             /* new samples rendered per step (4) */
    int render_size;       /* 0: samples rendered at the net's input size with
                              2x2 supersampling; else at this size (input..512)
                              with one sample per pixel, as the evaluation
                              renders its targets, and resized by the net */
    double white;          /* probability that a sample is white outside the
                              head mask, as the evaluation's targets are (0) */
    int shift;             /* largest random shift of a batch image, px at the
                              sample size, edges repeated (0) */
    double blur;           /* probability of a [1,2,1]/4 blur both ways (0) */
    long checkpoint_every; /* steps (500); 0 = only at the end */
    long log_every;        /* steps (50) */
    const char *out_path;  /* checkpoints: out_path + out_path.opt */
    int resume;            /* continue from out_path.opt */
    gs_gaze_log_fn log;    /* may be NULL */
    void *log_ctx;
    /* A fixed set of samples instead of the generator (NULL: the
     * generator): data_n samples, data[i] a data_size^2 image as CHW bytes
     * (3 planes of data_size rows), data_lab[i] its 4 labels (as the
     * outputs). Each batch element draws one uniformly by a hash of (seed,
     * step, element), then the flips, shifts and blur as above; cache,
     * fresh, identities, render_size and white are not used. The set must
     * outlive the call and be the same on a resume (its size is checked). */
    const uint8_t *const *data;
    const float *const *data_lab;
    size_t data_n;
    int data_size;         /* input size..512 */
} gs_gaze_train_options;

void gs_gaze_train_options_default(gs_gaze_train_options *o);

typedef struct gs_gaze_train_report {
    long steps;         /* steps taken by this call */
    double seconds;
    double final_loss;  /* mean L1 (radians) over the last log window */
} gs_gaze_train_report;

/* Trains n in place (L1 on the 4 angles, Adam). Samples: normalized
 * images (see render_size and white), random horizontal flips (yaw signs
 * flipped), shifts and blur (shift, blur): changes that leave the gaze
 * alone, so that the estimate learns not to move with them. rep may be
 * NULL. */
int gs_gaze_train(gs_gaze_net *n, const gs_gaze_train_options *o,
                  gs_pool *pool, gs_gaze_train_report *rep, gs_error *err);

#ifdef __cplusplus
}
#endif
#endif
