/* gs_eval: the redirection evaluation protocol on synthetic heads.
 *
 * A pairing says which held-out (test split) identity is shown in which
 * input scene and which target each input is redirected to. Every sample
 * is a pure function of (identity seed, scene seed) through
 * gs_synth_scene_random with gs_eval_ranges, so the generator reproduces it
 * byte for byte. A target keeps everything of its input scene (identity,
 * expression, lights, background) and takes the gaze, and when
 * head_change is set also the head pose, of the scene drawn from its own
 * scene seed. See docs/eval.md for the protocol, metrics and bins.
 *
 * Images are 8-bit sRGB RGB interleaved with an explicit stride; masks are
 * width*height bytes, 0 = outside. */
#ifndef GAZESPLAT_EVAL_H
#define GAZESPLAT_EVAL_H

#include <stddef.h>
#include <stdint.h>
#include <stdio.h>

#include "gazesplat/error.h"
#include "gazesplat/gaze.h"
#include "gazesplat/model.h"
#include "gazesplat/synth.h"

#ifdef __cplusplus
extern "C" {
#endif

/* ---- pairs ---- */

/* Ranges of the evaluation scenes: the model's training ranges for gaze
 * (yaw +-40, pitch +-30 deg), head yaw +-50, pitch +-30, roll +-5 deg (the
 * 30-50 deg head bin reaches past training), blinks 10% of the time. */
void gs_eval_ranges(gs_synth_ranges *r);

/* Bins. Gaze change: angle between input and target gaze (head frame).
 * Head pose: angle between the target head's forward axis and the optical
 * axis of its normalized camera. */
enum { GS_EVAL_BIN_0_15 = 0, GS_EVAL_BIN_15_30 = 1, GS_EVAL_BIN_30_50 = 2,
       GS_EVAL_BIN_OVER_50 = 3, GS_EVAL_BINS = 4 };
/* Bin of an angle in degrees: [0,15) [15,30) [30,50) [50,inf). */
int gs_eval_angle_bin(double deg);
/* "0-15", "15-30", "30-50", "50+". */
const char *gs_eval_bin_name(int bin);

/* Eyes narrowed or blinking: squint >= 0.35 or blink >= 0.3. */
int gs_eval_expr_narrowed(const gs_synth_expression *ex);
/* Harsh lighting: one light only, ambient < 0.2 and the key light more
 * than 30 deg to the side (|dir.x| >= 0.5): hard shadows on half a face. */
int gs_eval_scene_harsh(const gs_synth_scene *s);

typedef struct gs_eval_pair {
    int input;                 /* index of the input group (0-based) */
    int identity;              /* k of gs_synth_split_seed(TEST, k) */
    uint64_t identity_seed;
    uint64_t input_scene, target_scene;
    int head_change;           /* 1: the target takes its own head pose */
    /* derived (recomputed and checked when a file is read) */
    double gaze_change_deg, head_deg, head_change_deg;
    int narrowed, harsh;
} gs_eval_pair;

typedef struct gs_eval_pairs {
    int n;
    gs_eval_pair *p;           /* grouped by input, inputs in order */
} gs_eval_pairs;

typedef struct gs_eval_pairs_spec {
    gs_synth_split split;      /* GS_SYNTH_TEST (default) or GS_SYNTH_VAL:
                                * held-out identities either way; choose
                                * methods on VAL, report on TEST */
    int identities;            /* identities 0..identities-1 of the split */
    int inputs;                /* input scenes per identity */
    int targets;               /* targets per input */
    uint64_t seed;             /* pairing stream */
} gs_eval_pairs_spec;
/* Test split, 15 identities x 10 inputs x 10 targets, seed 1. */
void gs_eval_pairs_spec_default(gs_eval_pairs_spec *s);

/* Draws the pairing (deterministic). Input i of identity k has class
 * c = (i + 2k) mod 10: head-pose bin c mod 3, narrowed or blinking eyes
 * when c = 3, harsh lighting when c = 4 (neither otherwise). Inputs are
 * ordered input-major (i * identities + k): the first 2 x identities
 * inputs (two per identity) cover every class; the first `identities`
 * inputs only the even ones (every head bin and harsh lighting, no
 * narrowed eyes). Targets cycle through the gaze-change bins and alternate
 * gaze-only / gaze-and-head. Free with gs_eval_pairs_free. */
int gs_eval_pairs_make(const gs_eval_pairs_spec *spec, gs_eval_pairs *out,
                       gs_error *err);
void gs_eval_pairs_free(gs_eval_pairs *ps);

/* The input and target scenes of a pair. */
void gs_eval_pair_scenes(const gs_eval_pair *p, gs_synth_scene *input,
                         gs_synth_scene *target);
/* Fills the derived fields of *p from its seeds. */
int gs_eval_pair_derive(gs_eval_pair *p, gs_error *err);

/* CSV with a header line (docs/eval.md). Reading recomputes the derived
 * columns and refuses a file whose values differ (a different generator)
 * with GS_ERR_FORMAT naming the line. */
int gs_eval_pairs_write(FILE *f, const gs_eval_pairs *ps, gs_error *err);
int gs_eval_pairs_read(FILE *f, gs_eval_pairs *out, gs_error *err);

/* Renders a scene at the normalized camera of a model (size px, distance
 * d_n_mm, focal f_n at that size) with the background outside the head
 * mask made white, as the model is trained. out is allocated here (free
 * with gs_synth_sample_free). */
int gs_eval_render_scene(const gs_synth_scene *scene, int size, double d_n_mm,
                         double f_n, gs_pool *pool, gs_synth_sample *out,
                         gs_error *err);

/* ---- metrics ---- */

/* PSNR in dB over the pixels where mask != 0 (all when mask is NULL), 3
 * channels, peak 255. 100 dB for identical pixels; NaN for an empty mask. */
double gs_eval_psnr(const uint8_t *a, size_t sa, const uint8_t *b, size_t sb,
                    int w, int h, const uint8_t *mask);
/* SSIM (Gaussian window sigma 1.5, 11 taps, C1 = 0.01^2, C2 = 0.03^2 on
 * [0,1] values; the window is renormalised at the border) per pixel and
 * channel, averaged over the pixels where mask != 0 (all when NULL) and the
 * 3 channels. 1 for identical images; NaN for an empty mask. */
double gs_eval_ssim(const uint8_t *a, size_t sa, const uint8_t *b, size_t sb,
                    int w, int h, const uint8_t *mask, gs_error *err);

/* Square dilation of a mask by r pixels (out must not alias in).
 * GS_ERR_NOMEM leaves out unchanged. */
int gs_eval_mask_dilate(const uint8_t *in, int w, int h, int r, uint8_t *out);
/* Pixels set in a mask. */
size_t gs_eval_mask_count(const uint8_t *m, int w, int h);

/* Evaluation regions of a ground-truth sample: the eye region (both
 * visible eyeballs dilated by size/64 px, so the lid margins count) and
 * the face without the eyes (face mask minus the eye region), the region
 * of the identity-consistency metric. */
int gs_eval_regions(const gs_synth_sample *gt, uint8_t *eye, uint8_t *face);

/* Angle in degrees between two (pitch, yaw) directions, radians. */
double gs_eval_angle_deg(double p0, double y0, double p1, double y1);

/* ---- the synthesis readout: the gaze an image shows ---- */

/* Reads the gaze (head frame) an image of `scene` shows, by analysis by
 * synthesis: the scene (identity, expression, lights, head pose: all but
 * the gaze) is rendered through the normalized camera of
 * gs_eval_render_scene (size, d_n_mm, f_n), over two eye boxes only (+-1.7
 * x +-1.2 projected eyeball radii about each eyeball centre).
 *  1. Alignment: the image's 2D shift (up to max_shift_px) that best
 *     matches the scene at its own gaze on the boxes' still pixels, those
 *     no gaze changes (probe renders at pitch +-30 and yaw +-45 degrees
 *     mark the eyeballs and the lids, which follow the pitch).
 *  2. Gaze: on the pixels where the scene at its own gaze shows eyeball,
 *     the candidate gaze whose render best matches the shifted image
 *     (least mean square, 8-bit levels) wins: a grid of grid_deg over
 *     +-pitch_range_deg x +-yaw_range_deg, then a pattern search (8
 *     neighbours, step halved down to tol_deg) from its 2 best local
 *     minima.
 * Image and renders are blurred alike (Gaussian, blur_px) before they are
 * compared. A soft image (a redirection's eyes usually are) matches a
 * sharp render of the wrong gaze better than one of its own (the true
 * target blurred by sigma 1.5 px reads 2.3 degrees off): with soft_max_px
 * > 0 each candidate is also compared blurred further, as an image of
 * softness 0.25, 0.5, ... soft_max_px px would be, and keeps its best
 * level (the softness read comes back in soft_px). On the scene's own
 * render it reads the scene's gaze (within 0.1 degree at 256 px). Deterministic for any thread count. Meant for
 * eval-sized images (256 px): smaller eyes give coarser readings. */
typedef struct gs_eval_readout_options {
    double max_shift_px;       /* 4; [0, 8] (0: no alignment) */
    double grid_deg;           /* 10; [1, 45] */
    double tol_deg;            /* 0.05; [0.01, grid_deg / 2] */
    double pitch_range_deg;    /* 40; [0, 80] */
    double yaw_range_deg;      /* 50; [0, 80] */
    double blur_px;            /* 1; [0, 3]: Gaussian sigma applied to the
                                  image and to every candidate before they
                                  are compared (0: none) */
    double soft_max_px;        /* 0 (off); [0, 2.5], with blur_px^2 +
                                  soft_max_px^2 <= 9: the image softness
                                  (Gaussian sigma, px) tried up to, in
                                  steps of 0.25 */
} gs_eval_readout_options;
void gs_eval_readout_options_default(gs_eval_readout_options *o);

typedef struct gs_eval_readout {
    double pitch, yaw;         /* the gaze read, head frame, radians */
    double shift[2];           /* the image's shift found (px) */
    double rms;                /* residual RMS on the eyeball pixels at the
                                  gaze read (8-bit levels, blurred) */
    int renders;               /* renders, probes and reference included */
    int pixels;                /* eyeball pixels compared */
    double soft_px;            /* the softness level of the match (px; 0
                                  when soft_max_px is 0) */
} gs_eval_readout;

/* opts NULL: the defaults. GS_ERR_ARG for bad sizes, options out of
 * range, no eye inside the image or no eyeball visible (closed eyes); out
 * is written only on success. */
int gs_eval_gaze_readout(const gs_synth_scene *scene, int size, double d_n_mm,
                         double f_n, const uint8_t *rgb, size_t stride,
                         const gs_eval_readout_options *opts, gs_pool *pool,
                         gs_eval_readout *out, gs_error *err);

/* ---- the 2D warping baseline ---- */

/* Moves the content of one eye opening by disp (pixels): inside the mask a
 * pixel p takes the input at p - w(p) disp, w rising from 0 at the mask
 * border to 1 at falloff_px inside it (smoothstep), so the iris moves
 * rigidly and the lid margins stay put; a source outside the mask takes
 * `fill` (the sclera colour). Pixels outside the mask are not written, so
 * both eyes can be warped into one copy of the input. dst must not alias
 * src. */
int gs_eval_warp_eye(const uint8_t *src, size_t ss, uint8_t *dst, size_t ds,
                     int w, int h, const uint8_t *mask, const double disp[2],
                     double falloff_px, const uint8_t fill[3], gs_error *err);

/* Pixel displacement of eye e's pupil when the gaze (head frame) of the
 * labelled image changes to (pitch, yaw): the pupil centre rotates about
 * the eyeball centre with the gaze, both projected through the image's K. */
int gs_eval_pupil_shift(const gs_synth_labels *l, int e, double pitch,
                        double yaw, double disp[2], gs_error *err);

/* The baseline: output = the input with both eye openings warped toward
 * the target gaze (head frame), using the input's labels and eye masks
 * only. No 3D: the head pose never changes. */
int gs_eval_warp_redirect(const gs_synth_sample *in, double pitch, double yaw,
                          uint8_t *out, size_t stride, gs_error *err);

/* ---- fitting an input (the protocol's fit) and the fit cache ---- */

/* Fits m's subject to a ground-truth sample with its true head pose and
 * gaze given and kept fixed (known_head, known_gaze), no mask, iteration
 * cap iters (<= 0: 200), the default plateau stop, Adam's rates lr_code
 * and lr_colour (gs_fit_options; 0: the defaults). secs: wall time (may
 * be NULL). GS_ERR_NONFINITE when the fit diverges. */
int gs_eval_fit_sample(gs_model_ctx *c, gs_pool *pool,
                       const gs_synth_sample *in, int iters, double lr_code,
                       double lr_colour, gs_subject *sub, double *secs,
                       gs_error *err);
/* The same fit with the other options of base (its known gaze and head
 * pose replaced by the sample's labels): iterations, rates, known parts
 * of the code (`gazesplat eval --true-code`), a bounded expression. */
int gs_eval_fit_sample_with(gs_model_ctx *c, gs_pool *pool,
                            const gs_synth_sample *in,
                            const gs_fit_options *base, gs_subject *sub,
                            double *secs, gs_error *err);

/* The key of gs_eval_fit_sample_with's fit of `in` with options base
 * (gs_model_fit_key of the options that fit uses: the sample's labels
 * given). m is the model the fit's context was made from. */
uint64_t gs_eval_fit_key(const gs_model *m, const gs_fit_options *base,
                         const gs_synth_sample *in);
/* The protocol's fit of k samples of one person together (1..
 * GS_FIT_IMAGES_MAX, gs_model_fit_images: one identity, per image its own
 * expression, lights, head pose and gaze): each sample's true head pose is
 * given; its true gaze too unless free_gaze, when the fit finds the gaze
 * each image shows (with angle kappa that is the eyeballs' optical axis,
 * not the labelled visual one). out[k]; secs as for gs_eval_fit_sample.
 * k = 1 without free_gaze gives gs_eval_fit_sample's subject. */
int gs_eval_fit_samples(gs_model_ctx *c, gs_pool *pool,
                        const gs_synth_sample *in, int k, int iters,
                        double lr_code, double lr_colour, int free_gaze,
                        gs_subject *out, double *secs, gs_error *err);
/* The same for gs_eval_fit_sample's options. */
uint64_t gs_eval_fit_sample_key(const gs_model *m, const gs_synth_sample *in,
                                int iters, double lr_code, double lr_colour);

/* A cached fit, keyed by what made it: 8 bytes of magic "GSFITC2\n", the
 * key (gs_eval_fit_key; u64 little-endian), the fit seconds (a native
 * double), then the gs_subject_encode bytes. write replaces the file
 * atomically. read: GS_OK only for a file written with this key;
 * GS_ERR_IO when there is no such file, GS_ERR_FORMAT when it is not a
 * fit cache file, GS_ERR_STATE when it is one of another key (another
 * model, fit options or input) or an unkeyed one of an older version:
 * the fit must run again. */
int gs_eval_fit_cache_read(const char *path, uint64_t key, gs_subject *sub,
                           double *secs, gs_error *err);
int gs_eval_fit_cache_write(const char *path, uint64_t key,
                            const gs_subject *sub, double secs,
                            gs_error *err);

/* ---- downstream: adapting a gaze estimator to a new person ---- */

/* The paper's gaze-estimation experiment on synthetic heads (docs/eval.md
 * "Downstream"). Per held-out identity: a pool of GS_EVAL_DS_POOL real
 * (ground-truth) images, test images of the same person, and set_size
 * redirected images made from real sample 1 by the model and by the warp
 * baseline. For k = 1..max_k a copy of the estimator is fine-tuned on
 *   REAL  the k real images,
 *   OURS  the k real images + set_size - k model renders,
 *   WARP  the k real images + set_size - k warped images,
 * and its mean gaze angle against the true labels of the test images is
 * measured. k = 0 is the estimator as given. */
#define GS_EVAL_DS_POOL 9
enum { GS_EVAL_DS_REAL = 0, GS_EVAL_DS_OURS = 1, GS_EVAL_DS_WARP = 2,
       GS_EVAL_DS_CONDITIONS = 3 };
/* "real", "real+ours", "real+warp"; "?" out of range. */
const char *gs_eval_ds_condition_name(int c);

typedef struct gs_eval_ds_options {
    int test_images;       /* per identity (50) */
    int set_size;          /* training set of the mixed conditions (200),
                              > max_k */
    int max_k;             /* 1..GS_EVAL_DS_POOL (9) */
    int steps;             /* fine-tuning steps per run (60) */
    int batch;             /* images per step (8) */
    double lr;             /* Adam learning rate, constant (1e-4) */
    double real_fraction;  /* mixed conditions: at least this share of each
                              batch is real images (0.25), and never less
                              than the real images' share k / set_size */
    int fit_iters;         /* fit iteration cap (200) */
    double fit_lr_code, fit_lr_colour; /* the fit's rates (gs_fit_options:
                                          0 (the code's default) is the
                                          model file's code rate, else
                                          GS_FIT_LR_CODE_DEFAULT;
                                          GS_FIT_LR_COLOUR_DEFAULT) */
    uint64_t seed;         /* scenes, targets and batch draws (1) */
    /* The calibration experiment (issue-free defaults: all off). */
    gs_synth_kappa kappa;  /* every scene of an identity gets that
                              identity's angle kappa (gs_synth_kappa_draw);
                              labels stay the visual axis */
    int subject_from_k;    /* 1: for each k the subject is fitted from the
                              k real images together (gs_eval_fit_samples)
                              and the k-th sets are redirected from them in
                              turn (target j from real image j mod k, at
                              its head pose); 0: one subject from real
                              sample 1 for every k */
    int calibrate;         /* 1: the fits find each image's gaze (head pose
                              given) and the renders aim at target +
                              offset, offset = mean over the fitted images
                              of (fitted - labelled gaze), head frame: the
                              person's visual-to-optical offset as the
                              images show it; labels stay the target */
    unsigned ks;           /* bit k set: run k (1..max_k); 0: every k */
} gs_eval_ds_options;
void gs_eval_ds_options_default(gs_eval_ds_options *o);
/* GS_ERR_ARG with a message for options outside their ranges:
 * test_images 1..100000, steps 1..1000000, batch 1..4096, lr in (0, 1],
 * real_fraction in [0, 1], fit_iters 1..100000, fit rates in [0, 10],
 * a valid kappa (gs_synth_kappa_check), ks within bits 1..max_k. */
int gs_eval_ds_options_check(const gs_eval_ds_options *o, gs_error *err);

/* Scene of sample `index` of test identity `identity` (the identity seed
 * gs_synth_split_seed(GS_SYNTH_TEST, identity)): index 0..8 are the real
 * pool (real sample 1 is index 0), GS_EVAL_DS_POOL + i test image i. A
 * gs_synth_scene_random draw with gs_eval_ranges. */
void gs_eval_ds_scene(uint64_t seed, int identity, int index,
                      gs_synth_scene *s);
/* Target gaze j (head frame, radians) of the redirected samples: uniform
 * in the gaze ranges of gs_eval_ranges. */
void gs_eval_ds_target(uint64_t seed, int identity, int j, double *pitch,
                       double *yaw);

typedef struct gs_eval_ds_result {
    /* mean gaze angle on the test images, degrees; [0][c] = the estimator
     * as given (the same for every c); rows k > max_k are NaN */
    double err[GS_EVAL_DS_POOL + 1][GS_EVAL_DS_CONDITIONS];
    double fit_s;          /* fit wall time (from the cache when reused) */
    int fit_reused;
    double fit_psnr;       /* the fit on real sample 1 */
    long renders_incremental, renders_full; /* the model's renders */
    double finetune_s;     /* mean wall time of one fine-tune */
    int cache_write_failed;
    double kappa_h_deg, kappa_v_deg; /* the identity's kappa (0: off) */
    /* calibrate: the offset (pitch, yaw, degrees, head frame) the k-th
     * renders aimed with; 0 without calibrate, NaN for k not run */
    double offset_deg[GS_EVAL_DS_POOL + 1][2];
} gs_eval_ds_result;

/* The whole experiment for one identity. est is not changed. fit_path:
 * this identity's fit cache file (NULL: no cache); with reuse_fit the fit
 * is read from it when there and valid, and every new fit is written to it
 * (a failed write sets cache_write_failed, nothing else). pool may be
 * NULL. Deterministic: every number but the times is the same for any
 * thread count. */
int gs_eval_downstream_identity(const gs_model *m, const gs_gaze_net *est,
                                const gs_eval_ds_options *o, int identity,
                                const char *fit_path, int reuse_fit,
                                gs_pool *pool, gs_eval_ds_result *res,
                                gs_error *err);

/* ---- range: training an estimator on narrow data, augmented ---- */

/* The range experiment (docs/eval.md "Range"): source data of a narrow gaze
 * and head range; the same source images redirected across the model's
 * range; estimators trained from scratch on each set; tested on identities
 * no set holds, over the whole range. Conditions: */
enum { GS_EVAL_RANGE_SOURCE = 0,   /* the source images alone */
       GS_EVAL_RANGE_OURS = 1,     /* + the model's, gaze and head changed */
       GS_EVAL_RANGE_OURS_GAZE = 2,/* + the model's, gaze only */
       GS_EVAL_RANGE_WARP = 3,     /* + the warp's (gaze only: it cannot
                                      turn a head) */
       GS_EVAL_RANGE_CONDITIONS = 4 };
/* "source", "source+ours", "source+ours-gaze", "source+warp"; "?". */
const char *gs_eval_range_condition_name(int c);

typedef struct gs_eval_range_options {
    int sources;          /* source identities, TEST split 0.. (20) */
    int per_source;       /* source images per identity (10) */
    int targets;          /* redirected images per source identity and
                             condition (100) */
    double src_gaze_pitch, src_gaze_yaw; /* source gaze, head frame, +-
                                            (10, 15 deg; radians) */
    double src_head;      /* source head yaw and pitch, +- (10 deg) */
    double gaze_pitch, gaze_yaw; /* the targets' and the tests' gaze, +-
                                    (30, 40 deg: the model's range) */
    double head_pitch, head_yaw; /* the targets' head changes and the tests'
                                    head, +- (20, 30 deg: within the model's
                                    training range) */
    int tests;            /* test identities, VAL split 0.. (20) */
    int per_test;         /* test images per identity (10) */
    long steps;           /* training steps per estimator (3000) */
    int batch;            /* (16) */
    double lr;            /* peak rate, gs_gaze_train's schedule (1e-3) */
    int fit_iters;        /* fit cap per source identity (200) */
    uint64_t seed;        /* scenes, targets, init and batches (1) */
    gs_gaze_log_fn log;   /* progress (may be NULL) */
    void *log_ctx;
} gs_eval_range_options;
void gs_eval_range_options_default(gs_eval_range_options *o);
int gs_eval_range_options_check(const gs_eval_range_options *o,
                                gs_error *err);

/* One test image's result. */
typedef struct gs_eval_range_row {
    int identity, index;          /* VAL split identity, image */
    double gaze_pitch, gaze_yaw;  /* true normalized gaze, degrees */
    double head_pitch, head_yaw;  /* true normalized head, degrees */
    int in_source_range;          /* the gaze (head frame) inside the
                                     source's range, whatever the head */
    double err[GS_EVAL_RANGE_CONDITIONS]; /* gaze angle, degrees */
} gs_eval_range_row;

typedef struct gs_eval_range_result {
    int n;                        /* tests * per_test rows */
    gs_eval_range_row *rows;
    double fit_s, render_s, train_s[GS_EVAL_RANGE_CONDITIONS];
    double fit_psnr;              /* mean over the source identities */
    long set_size[GS_EVAL_RANGE_CONDITIONS];
    double train_loss[GS_EVAL_RANGE_CONDITIONS];
} gs_eval_range_result;
void gs_eval_range_result_free(gs_eval_range_result *r);

/* The whole experiment. est_dir: when not NULL, each trained estimator is
 * written there as <condition>.safetensors. Deterministic for any thread
 * count (timings aside). */
int gs_eval_range(const gs_model *m, const gs_eval_range_options *o,
                  const char *est_dir, gs_pool *pool,
                  gs_eval_range_result *res, gs_error *err);

#ifdef __cplusplus
}
#endif
#endif
