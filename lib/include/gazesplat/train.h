/* gs_train: making and training GazeGaussian models on synthetic heads. */
#ifndef GAZESPLAT_TRAIN_H
#define GAZESPLAT_TRAIN_H

#include <stdint.h>

#include "gazesplat/error.h"
#include "gazesplat/model.h"
#include "gazesplat/pool.h"
#include "gazesplat/synth.h"

#ifdef __cplusplus
extern "C" {
#endif

/* A new, untrained model. preset: "cpu" (the default: ~11k face Gaussians
 * at 3 mm, 2 x 700 eye Gaussians, MLP width 64, 64^2 features -> 256^2
 * images), "tiny" (for tests: seconds to train, 32^2 -> 128^2) or "paper"
 * (128^2 features -> 512^2, MLP width 256). The ablation switches take
 * -1 for the preset's value. */
typedef struct gs_model_spec {
    const char *preset;
    int train_identities;   /* auto-decoder codes (>= 1) */
    int guidance;           /* 0 none, 1 additive (released), 2 Eq. 9 */
    int two_stream;         /* 0: single stream */
    int eye_rotation;       /* 0: no explicit eye rotation */
    int guide_source;       /* 0: each renderer block attends over its own
                               features (released code); 1: one vector from
                               the face stream's map (local renderer, exact
                               incremental gaze sweeps; the default) */
    int lids;               /* 1: lids that follow the gaze's pitch
                               (gs_model_add_lids); -1, 0: none */
    int supersample;        /* k = 1..4: the feature map rasterized at k
                               times its size, each pixel the mean of
                               k x k (1, point-sampled: the default) */
    int eye_direct;         /* 1: the eye stream also drawn at the image's
                               size over the renderer's image (docs/model.md,
                               "The eye at the image's size"); -1, 0: not */
} gs_model_spec;
void gs_model_spec_default(gs_model_spec *s);
int gs_model_new(const gs_model_spec *spec, uint64_t seed, gs_model **out,
                 gs_error *err);
/* Changes the guidance source of a model in memory (same tensors, so a
 * model trained with one source can continue training with the other).
 * GS_ERR_ARG for a value other than 0 or 1. */
int gs_model_set_guide_source(gs_model *m, int source, gs_error *err);
/* Changes how a model in memory samples its feature map (same tensors):
 * k = 1 at the pixel centres, k = 2..4 the mean of k x k samples per
 * pixel, in training, fitting and rendering alike (docs/model.md,
 * "Supersampled feature maps"). GS_ERR_ARG outside 1..4. Contexts made
 * before keep the old value. */
int gs_model_set_supersample(gs_model *m, int k, gs_error *err);
/* Switches the eye stream's drawing at the image's size on (1) or off
 * (0) for a model in memory (same tensors: an optimizer state still
 * fits). GS_ERR_ARG for other values and, for 1, a single-stream model.
 * Contexts made before keep the old value. */
int gs_model_set_eye_direct(gs_model *m, int on, gs_error *err);
/* A copy of m whose face Gaussians within radius_mm of an eyeball's
 * centre become lids: turned about that centre by a learned share k of
 * the gaze's pitch, each its own, starting at 0 (docs/model.md, "Lids
 * that follow the gaze"; 16 mm: GS_MODEL_LID_RADIUS_MM). The face stream
 * is reordered (the others in their order, then each eye's lids), so an
 * optimizer state of m does not fit the copy. GS_ERR_ARG without two
 * streams and explicit eye rotation, or with lids already. */
int gs_model_add_lids(const gs_model *m, double radius_mm, gs_model **out,
                      gs_error *err);
/* The lids' radius: the template's 12 mm eyeball, its 2.5 mm lid shell
 * and a margin. */
#define GS_MODEL_LID_RADIUS_MM 16.0
/* 1 when m has lids. */
int gs_model_has_lids(const gs_model *m);
/* A copy of m trained on n identities instead of its n_train_ids (n
 * more, up to 100000): the learned codes kept, the new ones at their
 * mean, every other tensor as it was. The codes' tensor grows, so an
 * optimizer state of m does not fit the copy (`train --resume
 * --fresh-optimizer STEP --identities N`). GS_ERR_ARG without training
 * codes or for n not above n_train_ids. */
int gs_model_add_identities(const gs_model *m, int n, gs_model **out,
                            gs_error *err);
/* The parts of a latent code a synthetic scene gives (bits). */
enum { GS_SCENE_CODE_EXPR = 1, GS_SCENE_CODE_LIGHT = 2, GS_SCENE_CODE_ID = 4 };
/* A code to start a fit from with some parts known (gs_fit_options's
 * code_start and code_fixed, code_dim values each): the model's mean
 * code with the scene's expression (GS_SCENE_CODE_EXPR) and/or its lights
 * in the head frame (GS_SCENE_CODE_LIGHT) written in, as a training step
 * writes them, and/or (GS_SCENE_CODE_ID) the identity code the model
 * learned for the scene's identity, which must then be one of its
 * training identities; fixed is 1 at those slots and 0 elsewhere. A
 * diagnostic: how much of what a fit gets wrong is the expression, the
 * lights or the identity (`gazesplat eval --true-code`). GS_ERR_ARG: NULL
 * arguments, parts 0 or with unknown bits, GS_SCENE_CODE_ID for a scene
 * whose identity is not one of the model's training identities. */
int gs_model_scene_code(const gs_model *m, const gs_synth_scene *scene,
                        unsigned parts, float *code, uint8_t *fixed,
                        gs_error *err);
/* Writes a model file atomically (safetensors, docs/model.md). */
int gs_model_write(const gs_model *m, const char *path, gs_error *err);

/* The subject a training step sees (`gazesplat train`): training identity
 * k (the k-th of GS_SYNTH_TRAIN, which labels->identity must be) with its
 * learned code, the scene's expression and lights, and the labels' head
 * pose (in the image's camera) and head-frame gaze; colour gain 1, bias 0;
 * fit_psnr and fit_ssim 0. gs_model_render with a view at the subject's
 * own pose then draws what training drew: what the model can do for a face
 * it has learned, no fit in between (`gazesplat eval --method oracle`).
 * GS_ERR_ARG: no training codes, k out of range, another identity. */
int gs_model_training_subject(const gs_model *m, int k,
                              const gs_synth_scene *scene,
                              const gs_synth_labels *labels, gs_subject *s,
                              gs_error *err);

typedef void (*gs_train_log_fn)(void *ctx, const char *fmt, ...)
    __attribute__((format(printf, 2, 3)));

typedef struct gs_train_options {
    const char *out_path;   /* model file; checkpoints overwrite it, and
                               out_path.opt holds the optimizer state */
    long steps;             /* total steps (a resumed run continues) */
    double lr;              /* base Adam learning rate */
    uint64_t seed;          /* sample stream */
    int resume;             /* 1: continue from out_path(.opt) */
    /* With resume: >= 0 continues out_path's weights from this step with a
     * new optimizer instead of out_path.opt (for a model shipped without
     * its optimizer state); the learning rate then ramps up linearly over
     * the first `warmup` steps, so that the first steps of zeroed moments
     * do not jolt trained weights. -1 (default): load out_path.opt. */
    long fresh_from_step;
    long warmup;            /* steps of the ramp (200) */
    /* 1: the learning rate follows a half cosine from lr at the run's
     * first step (0, or fresh_from_step) down to lr / 20 at `steps`, the
     * end of the run (its last step, steps - 1, is just above); a
     * resumed run continues the same curve (out_path.opt keeps its first
     * step). 0 (default): constant. */
    int cosine;
    long checkpoint_every;
    long log_every;
    gs_train_log_fn log;
    void *log_ctx;
    /* The gaze loss (paper: 0.1 x the angular error of a frozen gaze
     * estimator on the render against the label); NULL: none. The net
     * is the caller's (gazesplat/gaze.h); its weights are not changed,
     * and nothing else may use it while gs_train runs. */
    struct gs_gaze_net *gaze_net;
    double gaze_weight;     /* 0.1 by default */
    double eye_cover_weight; /* > 0: L1 of the eye stream's coverage of the
                                merged feature map against the visible
                                eyeball (the eye masks), times this: where
                                the lids are (docs/model.md); 0 default */
    double eye_weight;      /* weight of the eye pixels in the image L1 and
                               of the eye stream's own feature loss, 1..100;
                               0 or 5 (default): 5 */
    /* Head poses of the training samples: yaw within +-head_yaw_deg
     * (1..60) and pitch within +-head_pitch_deg (1..40) of the camera;
     * 0 (default): 40 and 25, the model's documented range. The
     * evaluation's scenes reach yaw 50 and pitch 30 (gs_eval_ranges). */
    double head_yaw_deg, head_pitch_deg;
    /* 0 (default): a second thread makes each step's sample (the synthetic
     * image and its targets) while the step before runs. 1: every sample
     * is made at its step on the calling thread. The trained bytes are the
     * same either way. */
    int sync_samples;
    /* > 0: the gradient of every parameter is scaled so that their global
     * L2 norm is at most this (torch.nn.utils.clip_grad_norm_) before the
     * Adam step; 0 (default, as the shipped models were trained): none.
     * 0..1e6. */
    double max_grad_norm;
    /* Threads that render each sample's synthetic image (the producer's
     * own pool, beside the workers' pool given to gs_train): 0 or 1
     * (default): the producer alone. More keeps a machine of many cores
     * fed when a step takes less than a sample. The same bytes for any
     * count (the synthetic renderer's rows do not depend on the pool).
     * 0..GS_TRAIN_SAMPLE_THREADS_MAX. */
    int sample_threads;
} gs_train_options;
#define GS_TRAIN_SAMPLE_THREADS_MAX 64
void gs_train_options_default(gs_train_options *o);
/* The bounds of gs_train_options' head range, degrees. */
#define GS_TRAIN_HEAD_YAW_MAX 60.0
#define GS_TRAIN_HEAD_PITCH_MAX 40.0
/* GS_OK when yaw_deg and pitch_deg make a head range gs_train takes: each
 * 0 (the default) or within 1..GS_TRAIN_HEAD_YAW_MAX and
 * 1..GS_TRAIN_HEAD_PITCH_MAX; else GS_ERR_ARG with a message naming
 * them. The one check behind gs_train, `gazesplat train --head-range` and
 * the benches that draw its samples. */
int gs_train_check_head_range(double yaw_deg, double pitch_deg, gs_error *err);
/* The sample stream gs_train draws for m under o: m's training identities,
 * o's seed and head range, normalized images at m's size (sample k of the
 * stream is step k's). */
void gs_train_sample_config(const gs_model *m, const gs_train_options *o,
                            gs_synth_gen_config *gen);

typedef struct gs_train_report {
    long steps, skipped;
    double seconds, final_loss;
    double final_gaze_deg;  /* running mean gaze loss angle (with a net) */
} gs_train_report;

/* The learning rate of `step` for a run whose curve starts at `first`
 * (0, or fresh_from_step), `done` steps into a run that ramps up (-1: no
 * ramp): lr, times the cosine's factor when o->cosine, times
 * (done + 1) / warmup during the ramp. */
double gs_train_lr(const gs_train_options *o, long first, long step, long done);

/* Trains m in place. */
int gs_train(gs_model *m, const gs_train_options *o, gs_pool *pool,
             gs_train_report *rep, gs_error *err);

#ifdef __cplusplus
}
#endif
#endif
