/* gs_model: the GazeGaussian head model, its file, fitting and redirection.
 *
 * A trained model is a set of neutral 3D Gaussians in the head frame (a face
 * stream on the face surface, an eye stream on each eyeball), the MLPs that
 * deform them from a latent code tau (identity + expression), the head pose
 * and the gaze, and an expression-guided neural renderer that turns the
 * rasterized 32-channel feature map into an RGB image.
 *
 * Frames and units are those of gazesplat/geom.h: head frame (x toward the
 * subject's left, y down, z into the head, origin at the face centre), mm,
 * radians, gaze in the head frame with the ETH-XGaze signs (pitch > 0 looks
 * up, yaw > 0 looks toward image-left for a frontal head).
 *
 * A model renders normalized face images (DESIGN.md normalization): square,
 * config.image_size pixels, the face centre on the optical axis. A gs_view
 * gives the head pose in that camera (default: the fitted one).
 *
 * Threads: a gs_model is immutable once loaded and may be shared by any
 * number of threads; each thread renders and fits through its own
 * gs_model_ctx (workspace). Results are bit-identical for any pool size.
 * No call ever returns an image with a non-finite value. */
#ifndef GAZESPLAT_MODEL_H
#define GAZESPLAT_MODEL_H

#include <stddef.h>
#include <stdint.h>

#include "gazesplat/error.h"
#include "gazesplat/pool.h"

#ifdef __cplusplus
extern "C" {
#endif

#define GS_MODEL_FORMAT_VERSION 1
#define GS_MODEL_MAX_CODE 256

/* ---- the target ranges ----
 * The documented range of every field of a render or fit target (gaze in
 * the head frame, head pose in the normalized camera), degrees, defined
 * here once. Each is inclusive at both ends: v is in range when
 * lo <= v <= hi, so exactly +-limit is accepted and anything beyond it
 * (by any amount) or non-finite is refused. The daemon's request
 * validation, the gazesplat CLI and this library's own render and fit
 * checks all go through gs_model_check_target / gs_model_check_range, so a
 * target accepted up front is never refused later. A target has no head
 * roll or translation: the head keeps the subject's distance and turns
 * without roll. */
#define GS_MODEL_MAX_GAZE_PITCH_DEG 50.0
#define GS_MODEL_MAX_GAZE_YAW_DEG 60.0
#define GS_MODEL_MAX_HEAD_PITCH_DEG 70.0
#define GS_MODEL_MAX_HEAD_YAW_DEG 70.0

/* The same limits in radians, for the fit's clamps (checks take degrees). */
#define GS_MODEL_DEG_TO_RAD (3.14159265358979323846 / 180.0)
#define GS_MODEL_MAX_GAZE_PITCH (GS_MODEL_MAX_GAZE_PITCH_DEG * GS_MODEL_DEG_TO_RAD)
#define GS_MODEL_MAX_GAZE_YAW (GS_MODEL_MAX_GAZE_YAW_DEG * GS_MODEL_DEG_TO_RAD)
#define GS_MODEL_MAX_HEAD_ANGLE (GS_MODEL_MAX_HEAD_PITCH_DEG * GS_MODEL_DEG_TO_RAD)

typedef enum gs_target_field {
    GS_TARGET_GAZE_PITCH,
    GS_TARGET_GAZE_YAW,
    GS_TARGET_HEAD_PITCH,
    GS_TARGET_HEAD_YAW,
    GS_TARGET_NFIELDS
} gs_target_field;

/* One row of the table: "gaze pitch", -50, 50, "deg" and so on. */
typedef struct gs_target_range {
    const char *name;
    double lo, hi; /* inclusive */
    const char *unit;
} gs_target_range;

/* The table, indexed by gs_target_field. */
extern const gs_target_range gs_target_ranges[GS_TARGET_NFIELDS];

/* Checks one field's value (degrees) against its row: GS_OK, GS_ERR_ARG
 * outside the range, GS_ERR_NONFINITE for NaN or Inf; the message names
 * the field, the value and the inclusive range, e.g. "gaze pitch 200 deg
 * outside [-50, 50] deg (inclusive)". */
int gs_model_check_range(gs_target_field f, double v, gs_error *err);

/* Checks a target: gaze_deg = {pitch, yaw} and head_deg = {pitch, yaw},
 * degrees, either NULL when absent. Every field given is checked (in the
 * table's order); returns as gs_model_check_range. */
int gs_model_check_target(const double gaze_deg[2], const double head_deg[2], gs_error *err);

typedef struct gs_model gs_model;
typedef struct gs_model_ctx gs_model_ctx;

/* Loads and validates a model file (safetensors, see docs/model.md).
 * A truncated, corrupt or inconsistent file gives GS_ERR_FORMAT with a
 * message naming the tensor or field. */
int gs_model_load(const char *path, gs_model **out, gs_error *err);
/* The same from a file image in memory (copied). */
int gs_model_load_mem(const void *buf, size_t len, gs_model **out,
                      gs_error *err);
void gs_model_destroy(gs_model *m);

/* What callers need to know about a loaded model. */
typedef struct gs_model_info {
    int image_size;   /* output images are image_size x image_size RGB */
    int feat_size;    /* rasterized feature map edge */
    int supersample;  /* k: each feature pixel the mean of k x k samples
                         (1: point-sampled; docs/model.md) */
    int eye_direct;   /* 1: the eye stream is also drawn at the image's
                         size (docs/model.md, "The eye at the image's size") */
    int code_dim;     /* latent code length */
    int n_train_ids;  /* training identities with a learned code (0: none) */
    int n_face, n_eye; /* Gaussians: face stream, eye stream (both eyes) */
    double focal;     /* normalized camera focal length, pixels */
    double distance_mm; /* normalized camera distance d_n */
    size_t param_bytes; /* memory held by the parameters */
    uint64_t param_id;  /* names the parameters the model was loaded,
                           created or pruned with (a hash of them and of
                           the tensor table); clones keep it */
    unsigned tuned_parts; /* GS_FT_* parts fine-tuned since (0: none) */
    double fit_code_prior; /* the fit's code prior weight the model file
                              names (config.fit_code_prior; 0: none) */
    double fit_code_rate;  /* the fit's code rate the model file names
                              (config.fit_code_rate; 0: none, the fit
                              runs at GS_FIT_LR_CODE_DEFAULT) */
} gs_model_info;
void gs_model_get_info(const gs_model *m, gs_model_info *info);

/* A fitted subject: everything that differs from one face to the next. A
 * plain value, copied by assignment; serialize with gs_subject_encode. */
typedef struct gs_subject {
    int code_dim;
    float code[GS_MODEL_MAX_CODE];
    double head_R[9];   /* head to normalized camera rotation */
    double head_t[3];   /* face centre in the normalized camera, mm */
    double gaze_pitch, gaze_yaw; /* gaze of the fitted image, head frame */
    float colour_gain[3], colour_bias[3]; /* per-subject output colour */
    float fit_psnr, fit_ssim;   /* fit quality on the input image */
} gs_subject;

/* Fixed-size little-endian encoding of a subject (for caches on disk).
 * encode returns the bytes written or needed; decode refuses bad input. */
#define GS_SUBJECT_ENCODED_MAX 2048
size_t gs_subject_encode(const gs_subject *s, uint8_t *buf, size_t cap);
int gs_subject_decode(const uint8_t *buf, size_t len, gs_subject *s,
                      gs_error *err);
/* The length of the encoded subject that buf starts with (whatever
 * follows it, such as a tuned block), from its header; 0 when buf is too
 * short or its code length is out of range (decode then says why). */
size_t gs_subject_encoded_len(const uint8_t *buf, size_t len);

/* A view to render: gaze in the head frame and head pose in the camera.
 * At another head pose the lights stay where they are in the camera, as a
 * room's do when a person turns: the subject's light (fitted in its head
 * frame) is turned into the view's head frame (docs/model.md, "Lights at
 * another head pose"). light_on_head = 1 keeps the fitted light on the head
 * instead, so the shading turns with it. */
typedef struct gs_view {
    double gaze_pitch, gaze_yaw;
    int use_head;        /* 0: the subject's own head pose */
    double head_R[9], head_t[3];
    int light_on_head;   /* 0 (default): lights fixed in the camera */
} gs_view;

/* Contexts and memory. A context belongs to one model (which must outlive
 * it) and is used by one thread at a time; it owns every buffer it
 * allocates. Rendering needs the render state it keeps (the face stream's
 * Gaussians, the feature maps and the image of its live render: about
 * 18 MB at the cpu configuration, and 4.5 MB per other kept render) and a
 * scratch used only during a call (the renderer's forward buffer and the
 * face stream's per-thread block scratch: 27 MB at cpu with two threads),
 * which contexts can share (gs_model_ctx_share_scratch: then owned by
 * all of them together, freed with the last). The first fit or training step through a
 * context (gs_model_fit, gazesplat train) adds the buffers a backward
 * reads (the face MLPs' activations of every Gaussian, gradients, the
 * renderer's saved maps: 108 MB at cpu), kept until gs_model_ctx_trim or
 * destroy. Renders compute the same bytes whatever a context holds.
 * gs_model_finetune runs through a context of its own, freed before it
 * returns. */
gs_model_ctx *gs_model_ctx_create(const gs_model *m);
void gs_model_ctx_destroy(gs_model_ctx *c);
/* Frees the buffers only fitting and training use (gs_model_ctx_stats.
 * train_bytes) and the records its rasterizers kept for a backward
 * (gs_raster_trim); kept renders and the face stream stay. The next fit
 * allocates them again. GS_OK (NULL: nothing to do). */
int gs_model_ctx_trim(gs_model_ctx *c);
/* c uses with's render scratch from now on (its own goes when no other
 * context uses it). For contexts that are never in a call at the same
 * time, such as one thread's contexts for several fine-tuned clones of a
 * model (any models: the scratch grows to the largest need); a call on
 * one may then not run while a call on another does, and they must be
 * created and destroyed by that one thread too. The scratch lives until
 * the last context using it is destroyed, in any order. GS_ERR_ARG for
 * NULL. */
int gs_model_ctx_share_scratch(gs_model_ctx *c, gs_model_ctx *with);

/* Renders `view` of subject `s` into rgb (image_size^2, 8-bit sRGB RGB,
 * `stride` bytes per row; every pixel is written). Consecutive calls for the
 * same subject and head pose reuse the cached face stream: only the eye
 * stream is redone, and with models that allow it (SOURCE or no guidance,
 * two streams; docs/model.md "Gaze sweeps") only the eyes' reach in the
 * image is re-rendered. The result equals a render from a fresh context
 * within float rounding. */
int gs_model_render(gs_model_ctx *c, gs_pool *pool, const gs_subject *s,
                    const gs_view *view, uint8_t *rgb, size_t stride,
                    gs_error *err);

/* Detail transfer (docs/model.md "Detail transfer"): renders `view` like
 * gs_model_render, then adds back what the fit could not reproduce: the
 * residual of `input` (the normalized image s was fitted to, image_size^2
 * 8-bit RGB) against the subject's own view, carried to the target through
 * the model's depth and head poses, everywhere except on the eyeballs
 * (which come from the model alone) and where the input does not see the
 * target's surface. With the input's head pose the residual is taken
 * in place. The subject's own view is rendered once and kept while the
 * subject and the render options are the same. Needs the eye stream
 * (GS_ERR_ARG for single-stream models). */
int gs_model_render_transfer(gs_model_ctx *c, gs_pool *pool,
                             const gs_subject *s, const uint8_t *input,
                             size_t in_stride, const gs_view *view,
                             uint8_t *rgb, size_t stride, gs_error *err);

/* What a photo says of the input's eyes, for the eyeball warp at the
 * input's head pose (docs/model.md, "The eyeball warp on photos"). A
 * photo's eyes are where its landmarks and its own pixels put them; the
 * model's drawing of them, and so its probes and its eyeball's place, can
 * be off or broken on a real face.
 *   opening: image_size^2 bytes, 0 closed .. 255 open (the landmarks' eye
 *     contours): where the warp may take and put the input's own eye
 *     pixels, in place of the opening the model's probe renders find;
 *     NULL: those. A point the warp would take from where this opening
 *     is shut (under a lid) takes the pixel mirrored about its proxy's
 *     iris row instead, where the opening shows that, or else, on the
 *     sclera, the input's sclera colour.
 *   iris[0..n_iris): iris circles seen in the input (centre u, v and
 *     limbus radius, image pixels, geom.h's +0.5 convention; any order, at
 *     most 2). Each anchors the warp's proxy eyeball whose iris, at the
 *     input's gaze, shows nearest to it (within GS_XFER_IRIS_ANCHOR_MAX of
 *     that iris's radius; farther ones are ignored): the proxy is scaled so
 *     its iris has that radius (by a factor clamped to [1/2, 2]) and moved
 *     across the input's view so that it shows at that centre. The model's
 *     own eyeballs and the rest of the transfer are untouched. */
#define GS_XFER_IRIS_ANCHOR_MAX 3.0
typedef struct gs_xfer_eyes {
    const uint8_t *opening;
    int n_iris;
    double iris[2][3];
} gs_xfer_eyes;

/* gs_model_render_transfer with what a photo says of the input's eyes
 * (eyes; NULL or all empty: the same bytes as gs_model_render_transfer).
 * GS_ERR_ARG for n_iris outside 0..2 or a circle that is not finite with
 * a positive radius. */
int gs_model_render_transfer_eyes(gs_model_ctx *c, gs_pool *pool,
                                  const gs_subject *s, const uint8_t *input,
                                  size_t in_stride, const gs_xfer_eyes *eyes,
                                  const gs_view *view, uint8_t *rgb,
                                  size_t stride, gs_error *err);

/* The bytes of a render. gs_model_render's depend on the model, the
 * subject and the view alone: each gaze of a subject renders from the
 * subject's render at its own gaze (docs/model.md, "Gaze sweeps"), never
 * from the gaze rendered before it. A transfer's target maps and warped
 * residual go on from the subject's last transfer target at the same head
 * pose, so a transfer's bytes may also depend on that target, by a level
 * in a few pixels near the eyes. This call forgets every subject's last
 * transfer target: the next transfer of each takes the full path, as in a
 * fresh context. A request that must give the same bytes whatever ran
 * before it (a server's REDIRECT) calls it first. */
void gs_model_ctx_forget_transfer_targets(gs_model_ctx *c);

/* Gaze sweeps over several subjects: a context keeps the renders of the
 * last n (subject, head pose) pairs it rendered (n = 1: the last only), so
 * that returning to any of them renders incrementally. Each costs about
 * 4 MB at the cpu configuration, allocated when first needed. A context
 * assumes its model's parameters do not change; training drops the kept
 * renders itself, and this call drops them too. */
#define GS_MODEL_SWEEP_CACHE_DEFAULT 4
#define GS_MODEL_MAX_SWEEP_CACHE 64
int gs_model_ctx_set_sweep_cache(gs_model_ctx *c, int n, gs_error *err);

/* What a context's renders did (gs_model_render and
 * gs_model_render_transfer; counters since create). */
typedef struct gs_model_ctx_stats {
    uint64_t renders_full;         /* everything rasterized and rendered */
    uint64_t renders_incremental;  /* only the eyes' reach */
    int last_incremental;          /* the last successful render's path */
    int sweep_kept;                /* renders kept for incremental reuse */
    /* gs_model_render_transfer: full maps, or only the eyes' reach (the
     * last target had the same subject, settings and head pose) */
    uint64_t transfers_full;
    uint64_t transfers_incremental;
    int last_transfer_incremental;  /* the last successful transfer's path */
    /* bytes held by the buffers only fitting and training use (0 until
     * the context's first fit or training step, and after
     * gs_model_ctx_trim; a context that only renders never has them) */
    size_t train_bytes;
    /* full renders that kept the face stream's expression MLP rows: a
     * head change with the same code and parameters runs only the pose
     * MLP and what follows (docs/model.md, "Rendering") */
    uint64_t face_expr_kept;
} gs_model_ctx_stats;
void gs_model_ctx_get_stats(const gs_model_ctx *c, gs_model_ctx_stats *st);

/* Forgets everything c kept from earlier renders (the face stream, kept
 * sweep renders): needed after its model's parameters changed
 * (gs_model_tuned_apply, gs_model_copy_params, gs_model_finetune). */
void gs_model_ctx_reset(gs_model_ctx *c);

/* ---- speed against quality at render time (docs/model.md) ---- */

/* Settings of a context's gs_model_render; fitting and training through the
 * same context always run the model as it is. */
typedef struct gs_model_render_options {
    /* Rasterize the feature map at round(feature_scale * feat_size) pixels
     * and resample it bilinearly (align_corners = False) to feat_size for
     * the renderer. (0, 1]; 1 is the normal path, bit for bit. 2, 3 or 4:
     * supersampled, each feature pixel the mean of the k x k pixels of a
     * map rasterized at k * feat_size. Off 1 every render is a full one
     * (the incremental path works at the model's resolution). */
    double feature_scale;
    /* 1: every render from scratch: no incremental sweep, no cached face
     * stream (what a render costs with nothing to reuse). */
    int full;
    /* gs_model_render_transfer at another head pose than the input's: the
     * weight of the residual it carries there, [0, 1] (default
     * GS_XFER_HEAD_WEIGHT_DEFAULT). At a head change only the skin's
     * smoothed residual is carried (docs/model.md, "Detail transfer");
     * 0 gives the plain render there. */
    double transfer_head_weight;
    /* gs_model_render_transfer at another gaze: the weight, [0, 1]
     * (default GS_XFER_EYE_WEIGHT_DEFAULT), of the eyeball residual that
     * turns with the eye, reached smoothly from 1 at the input's own gaze
     * (docs/model.md, "Detail transfer"). The skin always carries all of
     * its residual at the input's head pose. */
    double transfer_eye_weight;
    /* gs_model_render_transfer at another gaze, same head pose: the input's
     * own eyeball pixels, turned with the eye about the model's eyeball and
     * kept inside the eye opening, make the eyeball, with weight
     * exp(-(theta / transfer_eye_warp_deg)^2) for a turn of theta degrees;
     * the rest is the model's render plus the residual as above
     * (docs/model.md, "The eyeball warp"). Degrees, [0, 90] (default
     * GS_XFER_EYE_WARP_DEG_DEFAULT); 0 turns the warp off. */
    double transfer_eye_warp_deg;
    /* 1: the eyeball warp also at another head pose than the input's: the
     * input's eyeball pixels, turned with the eye, seen from the target's
     * camera inside the eye opening the model shows at that pose, with
     * the same falloff; the rest as at any head change (docs/model.md,
     * "The eyeball warp at a head change"). 0: only at the input's head
     * pose. Default GS_XFER_EYE_WARP_HEAD_DEFAULT. */
    int transfer_eye_warp_head;
    /* The warp's falloff where the input's eye opening is given
     * (gs_xfer_eyes.opening: a photo's eye contours), degrees,
     * (0, 90] (default GS_XFER_EYE_WARP_GIVEN_DEG_DEFAULT). The narrower
     * transfer_eye_warp_deg hands large turns back to the model's own
     * eyeball, which is the better one on the synthetic heads it learned;
     * on a real photo the model draws the eyes far worse than the photo
     * shows them, and the given opening already keeps the warp from taking
     * what the lids hide (docs/model.md, "The eyeball warp on photos"). */
    double transfer_eye_warp_given_deg;
    /* Lids that follow the gaze on a photo (a given opening at the input's
     * head pose): the upper lid's margin moves by this share of the
     * vertical move of the iris's centre, the lower lid's by
     * GS_XFER_LID_LOWER of that, and the lid skin beside each margin with
     * it, fading out (docs/model.md, "The eyeball warp on photos"). [0, 1.5]
     * (default GS_XFER_LID_FOLLOW_DEFAULT); 0 keeps the photo's lids where
     * they are. */
    double transfer_lid_follow;
} gs_model_render_options;
#define GS_XFER_HEAD_WEIGHT_DEFAULT 0.5
#define GS_XFER_EYE_WEIGHT_DEFAULT 0.5
#define GS_XFER_EYE_WARP_DEG_DEFAULT 20.0
#define GS_XFER_EYE_WARP_HEAD_DEFAULT 0
#define GS_XFER_EYE_WARP_GIVEN_DEG_DEFAULT 90.0
#define GS_XFER_LID_FOLLOW_DEFAULT 0.8
#define GS_XFER_LID_LOWER 0.35
void gs_model_render_options_default(gs_model_render_options *o);
/* Takes effect from the next render; drops the context's kept renders.
 * A scale outside (0, 1] (or giving a map under 4 pixels): GS_ERR_ARG. */
int gs_model_ctx_set_render_options(gs_model_ctx *c,
                                    const gs_model_render_options *o,
                                    gs_error *err);

/* Importance of each face-stream Gaussian: its accumulated blending
 * weight sum_p T_p alpha_p (the share of the feature map it supplies),
 * summed over GS_MODEL_PRUNE_VIEWS normalized views of the mean code with
 * the eyes in place (head yaw -30, 0, 30 deg x pitch -15, 0, 15 deg, gaze
 * ahead). out: info.n_face values. pool may be NULL; the values are the
 * same for any thread count. */
#define GS_MODEL_PRUNE_VIEWS 9
int gs_model_face_importance(const gs_model *m, gs_pool *pool, double *out,
                             gs_error *err);

/* A new model with only the keep_face most important face Gaussians
 * (gs_model_face_importance; ties by index), kept in their original
 * order, and the whole eye stream; everything else is copied. keep_face
 * >= n_face gives an exact copy (same renders, bit for bit). A model's
 * lids (gs_model_add_lids) are always kept and count in keep_face (at
 * least one other is kept). Subjects fitted with m render with the
 * pruned model. keep_face < 1: GS_ERR_ARG. */
int gs_model_prune(const gs_model *m, gs_pool *pool, int keep_face,
                   gs_model **out, gs_error *err);

/* ---- fitting a new face ---- */
typedef struct gs_fit_options {
    int max_iters;       /* <= 0: default 200 */
    double time_budget_s; /* <= 0: none */
    double plateau_rel;  /* stop when the loss improves by less than this
                            fraction over 20 iterations; <= 0: 1e-3 */
    int known_gaze;      /* 1: gaze_pitch/yaw are given and kept fixed */
    double gaze_pitch, gaze_yaw;
    int known_head;      /* 1: head_R/head_t are given and kept fixed */
    double head_R[9], head_t[3];
    const uint8_t *mask; /* image_size^2 weights 0..255 (face region), or
                            NULL for the whole image */
    /* Adam's rates for the latent code and for the colour gain and bias;
     * 0: the rate the model file names for the code
     * (gs_model_info.fit_code_rate) or, when it names none,
     * GS_FIT_LR_CODE_DEFAULT; GS_FIT_LR_COLOUR_DEFAULT for the colours.
     * Each in [0, 10]. (docs/model.md, "Fitting") */
    double lr_code, lr_colour;
    /* Parts of the code known beforehand: NULL, or code_dim values each.
     * The fit starts from code_start (NULL: the model's mean code) and
     * keeps every slot whose code_fixed is nonzero where it started
     * (gs_model_scene_code makes both from a synthetic scene). */
    const float *code_start;
    const uint8_t *code_fixed;
    /* 1: the expression's slots are kept where training put them (each
     * clamped to the synthetic sampler's range after every step); 0
     * (default): free. Measured worse (docs/model.md, "Fitting"). */
    int bound_expression;
    /* Weight of a Gaussian prior on the code's expression and lights, with
     * the mean and covariance those slots have over the training sampler
     * (at most about `code_prior` added to the loss for a code the sampler
     * draws); 0: none; in [0, 10]. GS_FIT_CODE_PRIOR_MODEL (the default of
     * gs_fit_options_default): the weight the model file names
     * (gs_model_info.fit_code_prior, 0 when it names none). Which weight
     * suits depends on the model (docs/model.md, "Fitting"). */
    double code_prior;
    /* Weight of a Gaussian prior on the code's identity slots, with the
     * mean and covariance of the identity codes training learned (a ridge
     * of 1 % of their mean variance): at most about `id_prior` added to the
     * loss for a code like the learned ones; 0 (default): none; [0, 10]. */
    double id_prior;
    /* Times Adam's rates are halved at a plateau before the fit stops: 0
     * (default) stops at the first plateau, as before; each halving gives
     * the fit 20 more iterations before the next plateau test, within
     * max_iters and time_budget_s. [0, 8]. (docs/model.md, "Fitting") */
    int anneal;
    /* 1: each iteration also fits the input flipped left to right, seen
     * from the mirrored pose (the fine-tuning's mirrored view, now for the
     * code): a second view of a near-symmetric face; an iteration costs
     * about twice as much, and the report's losses sum both views (the
     * subject's fit_psnr and fit_ssim are the input's). 0 (default): the
     * input alone. */
    int mirror;
    /* Polled once per iteration (a fraction of a second at the served
     * sizes): a nonzero return ends the fit with GS_ERR_CANCELLED and
     * *out untouched. NULL: never. Not part of gs_model_fit_key. */
    int (*cancel)(void *arg);
    void *cancel_arg;
} gs_fit_options;
#define GS_FIT_ANNEAL_MAX 8
#define GS_FIT_CODE_PRIOR_MODEL (-1.0)
#define GS_FIT_LR_CODE_DEFAULT 0.12
#define GS_FIT_LR_COLOUR_DEFAULT 0.02
void gs_fit_options_default(gs_fit_options *o);
/* Sets the code prior weight a model names for its fits (0..10; 0: none),
 * kept in the file gs_model_write writes (config.fit_code_prior).
 * GS_ERR_ARG outside [0, 10] or not finite. */
int gs_model_set_fit_code_prior(gs_model *m, double weight, gs_error *err);
/* Sets the fit's code rate a model names for its fits (0..10; 0: none,
 * GS_FIT_LR_CODE_DEFAULT), kept in the file gs_model_write writes
 * (config.fit_code_rate). GS_ERR_ARG outside [0, 10] or not finite. */
int gs_model_set_fit_code_rate(gs_model *m, double rate, gs_error *err);
/* The code rate a fit of m runs at when its options ask for lr_code: that
 * rate when > 0, else the model's (gs_model_info.fit_code_rate), else
 * GS_FIT_LR_CODE_DEFAULT. */
double gs_model_fit_code_rate(const gs_model *m, double lr_code);

typedef struct gs_fit_report {
    int iters;
    double seconds;
    double loss_first, loss_last;
    int stopped_on_plateau;
    int stopped_on_time; /* time_budget_s ended it before max_iters and
                            before a plateau: the result is a partial fit */
    int halvings; /* times the rates were halved (gs_fit_options.anneal) */
} gs_fit_report;

/* Fits a subject to one normalized face image (image_size^2 RGB). A fit
 * that diverges returns GS_ERR_NONFINITE with the iteration in the
 * message and leaves *out unchanged. */
int gs_model_fit(gs_model_ctx *c, gs_pool *pool, const uint8_t *rgb,
                 size_t stride, const gs_fit_options *opt, gs_subject *out,
                 gs_fit_report *report, gs_error *err);

/* A 64-bit name of what gs_model_fit would return for these arguments:
 * the model's parameters (hashed as they are now, so a fine-tuned clone is
 * another model) and configuration, the options as the fit reads them (the
 * code prior weight resolved: the model's, when opt names
 * GS_FIT_CODE_PRIOR_MODEL; the defaults that 0 means filled in), the mask
 * and the image. The fit is deterministic for any thread count, so two
 * fits with the same key give the same subject: a cache of fits keys its
 * entries with it (gs_eval_fit_cache_read). Not cryptographic. opt NULL:
 * the defaults. The image must be image_size^2 RGB rows of `stride`. */
uint64_t gs_model_fit_key(const gs_model *m, const gs_fit_options *opt,
                          const uint8_t *rgb, size_t stride);

/* ---- a subject from several images of one person (docs/subjects.md) ---- */

/* At most this many images in one fit or fine-tune. */
#define GS_FIT_IMAGES_MAX 16

/* One image of a fit over several: the normalized face (image_size^2 RGB
 * rows of `stride`), its face mask (as gs_fit_options.mask) and the labels
 * known for it (as gs_fit_options' known_gaze and known_head). */
typedef struct gs_fit_image {
    const uint8_t *rgb;
    size_t stride;
    const uint8_t *mask;
    int known_gaze;
    double gaze_pitch, gaze_yaw;
    int known_head;
    double head_R[9], head_t[3];
} gs_fit_image;

/* An image with the mask and labels opt names (NULL: none): what
 * gs_model_fit fits. */
void gs_fit_image_from_options(gs_fit_image *im, const uint8_t *rgb,
                               size_t stride, const gs_fit_options *opt);

/* Fits k images (1..GS_FIT_IMAGES_MAX) of one person together: one identity
 * (the code's first id_dim slots) shared by all, and per image its own
 * expression, lights, gaze, head pose and colour gain and bias. Adam on the
 * sum of the images' losses (each under its mask, the code prior per image,
 * the identity prior once), the plateau and time tests on that sum.
 * out[i] (k subjects) is image i's subject; their identity slots are equal
 * bit for bit. opt as for gs_model_fit, but its labels and mask must be
 * unset (GS_ERR_ARG): each image carries its own. k = 1 gives the bytes
 * gs_model_fit gives for that image and its labels. Deterministic for any
 * thread count; an iteration costs k single-image ones. A bad image or
 * label is refused (GS_ERR_ARG; GS_ERR_NONFINITE for a non-finite label)
 * before any work, the message naming the image (from 0) when k > 1; on
 * any error *out is untouched. */
int gs_model_fit_images(gs_model_ctx *c, gs_pool *pool, const gs_fit_image *im,
                        int k, const gs_fit_options *opt, gs_subject *out,
                        gs_fit_report *report, gs_error *err);

/* gs_model_fit_key for gs_model_fit_images: covers every image, mask and
 * label in order; k = 1 gives gs_model_fit_key of that image with its
 * labels in the options. 0 for bad arguments (k out of range, NULL). */
uint64_t gs_model_fit_images_key(const gs_model *m, const gs_fit_options *opt,
                                 const gs_fit_image *im, int k);

/* ---- per-image fine-tuning (the paper's last step) ---- */

/* A copy of m with its own parameters (same configuration), for
 * fine-tuning one subject without touching the shared model. */
int gs_model_clone(const gs_model *m, gs_model **out, gs_error *err);
/* Puts src's parameters back into dst (a clone of src or of the same
 * configuration): GS_ERR_ARG when the layouts differ. */
int gs_model_copy_params(gs_model *dst, const gs_model *src, gs_error *err);

/* What gs_model_finetune adjusts (bits). */
enum {
    GS_FT_FACE = 1,     /* face Gaussians' colour and features */
    GS_FT_EYE = 2,      /* eye Gaussians' colour and features */
    GS_FT_RENDERER = 4, /* the neural renderer's weights */
    GS_FT_MLP = 8,      /* the deformation MLPs and the eyeball shift */
    GS_FT_GEOMETRY = 16, /* Gaussian positions, scales, rotations, opacities
                            (never the lids' share of the pitch) */
    GS_FT_FACE_GEOMETRY = 32 /* the same for the face stream (and lids)
                                alone: the eyeballs keep the model's shape */
};
#define GS_FT_ALL_PARTS 0x3fu
/* The face Gaussians' colours and features and the Gaussians' geometry:
 * better than the face alone on every image and gaze figure, on the
 * validation pairs at 15 and 100 steps and on the test pairs
 * (experiments/eval/README.md, "Tuning the geometry too"). */
#define GS_FT_DEFAULT (GS_FT_FACE | GS_FT_GEOMETRY)

typedef struct gs_finetune_options {
    int iters;            /* <= 0: 50 */
    double lr;            /* Adam's base rate, <= 0: 1e-3; each part scaled
                             as in training (features x5, positions x10) */
    unsigned parts;       /* GS_FT_* bits; 0: GS_FT_DEFAULT */
    const uint8_t *mask;  /* as gs_fit_options.mask */
    double time_budget_s; /* > 0: stop after the step that passes it,
                             keeping the best iterate; <= 0: none */
    double plateau_rel;   /* > 0: stop when the loss improved by less than
                             this fraction over 20 steps (the fit's rule);
                             <= 0: run every step (the default) */
    int outline_px;       /* 0..8: feature pixels within this many of the
                             model's outline at the input's view (coverage
                             under 0.5) teach the Gaussians' features and
                             colours nothing, only their geometry; 0 (the
                             default): off. Removes background-coloured
                             patches at other head poses, at a cost at the
                             input's own pose (docs/model.md) */
    int mirror;           /* 1 (the default): each step also fits the input
                             mirrored left to right, seen from the mirrored
                             head pose with the mirrored gaze and lights (a
                             face is close to symmetric: the side the input
                             hides gets the other side's look); 0: the input
                             alone. Doubles the cost of a step */
    /* Polled once per step: a nonzero return ends the call with
     * GS_ERR_CANCELLED and m restored to its parameters before the call.
     * NULL: never. */
    int (*cancel)(void *arg);
    void *cancel_arg;
} gs_finetune_options;
void gs_finetune_options_default(gs_finetune_options *o);
/* The rate every served path fine-tunes at unless told otherwise (the
 * daemon's finetune_lr, gazesplat fit/redirect/augment/eval-photos): it
 * read best at 15 steps after the fit (docs/model.md, "The fit's rates");
 * gs_finetune_options_default keeps the library's 1e-3. */
#define GS_FINETUNE_LR_SERVED 0.004

/* GS_FT_* bits from names, comma-separated: face, eye, renderer, mlp,
 * geometry, face-geometry ("face,eye"). GS_ERR_ARG for an unknown or empty name. */
int gs_finetune_parts_parse(const char *s, unsigned *parts, gs_error *err);
/* The names of GS_FT_* bits, comma-separated, into buf; returns buf. */
const char *gs_finetune_parts_name(unsigned parts, char *buf, size_t cap);

typedef struct gs_finetune_report {
    int iters;            /* steps taken */
    double seconds;
    double loss_first, loss_best;
    float psnr_first, psnr_best; /* on the weighted region, dB */
    size_t params_tuned;  /* floats adjusted */
    int stopped_on_time;  /* the time budget ended it before iters */
    int stopped_on_plateau; /* plateau_rel ended it before iters */
} gs_finetune_report;

/* Fine-tunes the chosen parts of m (a clone: gs_model_clone) so that it
 * renders the fitted subject s (gs_model_fit on the same image) closer to
 * that image: Adam on the fit's loss, the subject kept fixed, the best
 * iterate kept. Contexts made for m before the call must not be used after
 * it (their kept renders are stale): make new ones. A step with a
 * non-finite loss or gradient ends the call with GS_ERR_NONFINITE and m
 * restored to its parameters before the call. */
int gs_model_finetune(gs_model *m, gs_pool *pool, const gs_subject *s,
                      const uint8_t *rgb, size_t stride,
                      const gs_finetune_options *opt,
                      gs_finetune_report *report, gs_error *err);

/* gs_model_finetune over k (subject, image) pairs of one person (s[i]
 * fitted to im[i].rgb, as gs_model_fit_images gives them): one set of
 * tuned parameters, each step's loss the sum over the pairs (each under
 * im[i].mask; the labels of im are not read). opt->mask must be NULL
 * (GS_ERR_ARG). The report's PSNRs are the pairs' mean. k = 1 gives the
 * bytes of gs_model_finetune with that image and mask. A step costs k
 * single-image steps. */
int gs_model_finetune_images(gs_model *m, gs_pool *pool, const gs_subject *s,
                             const gs_fit_image *im, int k,
                             const gs_finetune_options *opt,
                             gs_finetune_report *report, gs_error *err);

/* ---- serving fine-tuned subjects (docs/model.md) ---- */

/* The tensors of every part m has fine-tuned (gs_model_finetune since m
 * was cloned) as one self-contained block: the parts, the param_id of the
 * model they were tuned from, the values and a checksum. *out is
 * malloc'd (free it); a face-only block of the cpu model is 2.9 MB.
 * GS_ERR_ARG when m has not been fine-tuned. */
int gs_model_tuned_encode(const gs_model *m, uint8_t **out, size_t *len,
                          gs_error *err);

/* Makes dst, a clone of base (gs_model_clone), render as the model the
 * block was encoded from: base's parameters with the block's tensors in
 * their place. buf NULL and len 0 puts base's parameters back. The block
 * is checked whole before dst changes: bad magic, truncation, a wrong
 * checksum or a non-finite value give GS_ERR_FORMAT, another version
 * GS_ERR_UNSUPPORTED, a block tuned from another model (param_id) or a dst
 * not of base's layout GS_ERR_ARG; dst is then untouched. Only the
 * block's tensors and those dst had tuned otherwise are copied (a face
 * block after another: 2.9 MB at cpu). Reset dst's contexts afterwards
 * (gs_model_ctx_reset). */
int gs_model_tuned_apply(gs_model *dst, const gs_model *base,
                         const uint8_t *buf, size_t len, gs_error *err);

#ifdef __cplusplus
}
#endif
#endif
