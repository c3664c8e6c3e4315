/* Redirecting a face: the one place that takes a photo or a normalized
 * face to what the model fits, a fitted subject to its fine-tuned copy of
 * the model, and a subject plus a target to an image (plain, detail
 * transfer, pasted back into the photo), with one set of defaults.
 *
 * gazesplatd, every CLI command (fit, redirect, augment, eval-photos), the
 * live camera path and the evaluation call these and assemble none of it
 * themselves, so the same photo and options give the same bytes on every
 * path (tests/integration test_cli_daemon_same; docs/redirect.md).
 *
 *   photo ──gs_redirect_input_photo──▶ input (normalized face, mask, pose)
 *   face  ──gs_redirect_input_face───▶ input
 *   input ──gs_redirect_fit_options──▶ gs_fit_options ──gs_model_fit──▶ subject
 *   subject ──gs_redirect_finetune───▶ fine-tuned copy of the model
 *   subject + view ──gs_redirect_render──▶ normalized image
 *   normalized image ──gs_redirect_paste──▶ the photo with the new eyes
 */
#ifndef GAZESPLAT_REDIRECT_H
#define GAZESPLAT_REDIRECT_H

#include <stddef.h>
#include <stdint.h>

#include "gazesplat/error.h"
#include "gazesplat/face.h"
#include "gazesplat/image_io.h"
#include "gazesplat/model.h"
#include "gazesplat/pool.h"

#ifdef __cplusplus
extern "C" {
#endif

/* ---- the defaults every path serves ---- */

/* The served setting: the fit to its plateau (at most 200 iterations),
 * then 15 fine-tuning steps of the default parts with the mirrored view at
 * GS_FINETUNE_LR_SERVED (docs/model.md, "The served fit", "Per-image
 * fine-tuning"). Commands whose fine-tuning is asked for (gazesplat fit and
 * redirect --finetune N, a FIT's finetune_steps) keep the rate and parts
 * and take the steps from the request. */
#define GS_REDIRECT_FIT_ITERS 200
#define GS_REDIRECT_FINETUNE_STEPS 15

/* gs_finetune_options_default with the served rate; iters = steps. */
void gs_redirect_finetune_options(int steps, gs_finetune_options *o);

/* ---- inputs ---- */

/* What a face to redirect is: the normalized face the model fits and,
 * for a photo, the photo, its analysis (landmarks, head pose,
 * normalization) and the face mask over the normalized face. */
typedef struct gs_redirect_input {
    int is_photo;
    gs_io_image norm;     /* image_size^2 RGB, owned */
    gs_io_image photo;    /* is_photo: the photo, owned */
    gs_face_result face;  /* is_photo: its analysis */
    uint8_t *mask;        /* is_photo: face weights over norm (image_size^2), owned */
    uint8_t *opening;     /* is_photo: the eye openings over norm
                             (gs_redirect_eye_opening), owned: where the
                             transfer's eyeball warp takes the photo's own
                             eye pixels */
    int n_iris;           /* is_photo: the irises found in norm (face.h's */
    double iris[2][3];    /*   localizer, status OK: centre u, v, radius,
                             px), which anchor that warp's proxy eyeballs
                             (model.h, gs_xfer_eyes) */
    gs_face_gate gate;    /* the gate's measures when it ran; gate.refusal
                             says why an input was refused */
    int red_eye_px;       /* is_photo: pixels of norm whose red-eye was
                             repaired (gs_face_red_eye_fix), 0 if none */
} gs_redirect_input;

typedef struct gs_redirect_photo_opts {
    int index;            /* which face, largest first (0) */
    int gate;             /* 1: through the face gate (face.h) */
    int use_k;            /* 1: the photo's intrinsics k; 0: assumed (face.h) */
    double k[9];
    int keep_red_eye;     /* 1: leave red-eye pupils as they are; 0 (the
                             default): repair them in the normalized face
                             before the gate, the fit and the transfer */
} gs_redirect_photo_opts;
void gs_redirect_photo_opts_default(gs_redirect_photo_opts *o);

/* A photo: detection, landmarks, the head pose in the synthetic head frame
 * (the frame of the model's training labels), normalization to the model's
 * camera (info), the face mask; with o->gate, the face gate. Takes *photo
 * (its pixels are in->photo afterwards, or freed on failure). On failure
 * in holds nothing but in->gate, and err says why:
 * - GS_ERR_ARG, gate.refusal GS_FACE_REFUSED_NO_FACE: no usable face
 *   ("photo: ...": none found, an index past them, a face under the
 *   smallest box, a landmark outside the photo);
 * - GS_ERR_ARG, another refusal: the gate refused it ("face refused
 *   (NAME): reason");
 * - anything else: the analysis, normalization or gate could not run
 *   ("photo: ...", "photo normalization: ...", "face gate: ..."). */
int gs_redirect_input_photo(gs_face_detector *det, const gs_face_shape_model *sp,
                            const gs_model_info *info, gs_io_image *photo,
                            const gs_redirect_photo_opts *o, gs_redirect_input *in,
                            gs_error *err);

/* A normalized face given as such (image_size^2): takes *face; with gate,
 * the gate's checks for a normalized face (flat, noise). Errors as above;
 * a face of another size is GS_ERR_ARG "normalized face is WxH, the model
 * wants SxS". */
int gs_redirect_input_face(const gs_model_info *info, gs_io_image *face, int gate,
                           gs_redirect_input *in, gs_error *err);

void gs_redirect_input_free(gs_redirect_input *in);

/* The face mask every path fits a photo's face with (face.h's FACE mask,
 * feathered 4 px), from its landmarks in the normalized image. */
int gs_redirect_face_mask(const double uv_n[][2], int size, uint8_t *mask, gs_error *err);

/* The eye openings a photo's transfer warps inside (face.h's
 * EYE_OPENINGS mask grown GS_REDIRECT_OPENING_GROW px and feathered
 * GS_REDIRECT_OPENING_FEATHER px, both at 256 px and scaled to size),
 * from its landmarks in the normalized image. */
#define GS_REDIRECT_OPENING_GROW 1.0
#define GS_REDIRECT_OPENING_FEATHER 2.0
int gs_redirect_eye_opening(const double uv_n[][2], int size, uint8_t *mask, gs_error *err);

/* ---- the fit ---- */

/* The fit's options for an input: gs_fit_options_default, max_iters
 * GS_REDIRECT_FIT_ITERS, the mask, and for a photo the landmarks' head
 * pose (gs_redirect_fit_pose). Labels a caller knows go on top. */
void gs_redirect_fit_options(const gs_redirect_input *in, gs_fit_options *o);

/* A head pose known in the normalized camera (rotation R_n): the fit
 * keeps it, the face centre on the axis at distance d_n (where
 * normalization puts it; the model's distance_mm). */
void gs_redirect_fit_head(const double R_n[9], double d_n, gs_fit_options *o);

/* The same from a rotation R in the photo's camera and the face's
 * normalization n (gs_geom_norm_rot, then n->d_n_mm). */
void gs_redirect_fit_pose(const gs_geom_norm *n, const double R[9], gs_fit_options *o);

/* ---- fine-tuning ---- */

/* Fine-tunes *tuned on the n fitted (subject, image) pairs: from the shared
 * model's parameters (a NULL *tuned gets a clone of shared; an existing one,
 * a clone of the same model, is reset to them first), the images' masks in
 * im, opt's steps, parts, rate and callbacks (opt->mask is not read).
 * Contexts made for *tuned before must not be used after it. On failure a
 * clone made here is destroyed (*tuned NULL again); one given is left at
 * the shared parameters. */
int gs_redirect_finetune(gs_model **tuned, const gs_model *shared, gs_pool *pool,
                         const gs_subject *subs, const gs_fit_image *im, int n,
                         const gs_finetune_options *opt, gs_finetune_report *rep,
                         gs_error *err);

/* ---- rendering ---- */

/* What a photo input says of its eyes for the transfer (its opening and
 * irises; all empty for an input that is not a photo). */
gs_xfer_eyes gs_redirect_eyes(const gs_redirect_input *in);

/* One target into out (image_size^2 RGB rows of stride): the plain render
 * of the subject, or with input (the face it was fitted to, image_size^2
 * RGB rows of in_stride) the detail transfer from it; eyes (a photo
 * input's, gs_redirect_eyes, or NULL: the model's own) is where its eyeball
 * warp works and where the input's irises are
 * (gs_model_render_transfer_eyes). */
int gs_redirect_render(gs_model_ctx *c, gs_pool *pool, const gs_subject *sub,
                       const uint8_t *input, size_t in_stride, const gs_xfer_eyes *eyes,
                       const gs_view *v, uint8_t *out, size_t stride, gs_error *err);

/* Pasting renders back into the photo: the blend masks (the eyes for a
 * gaze change, the whole face when the head turns), made once, and the
 * output image, the photo's size. Zero it before the first use. */
typedef struct gs_redirect_paste_state {
    uint8_t *mask[2]; /* 0: eyes, 1: the whole face */
    gs_io_image out;
} gs_redirect_paste_state;

/* ps->out = in's photo with the normalized render norm pasted back into it
 * (in must be a photo); whole_face for a target with another head pose. */
int gs_redirect_paste(const gs_redirect_input *in, gs_redirect_paste_state *ps, int whole_face,
                      const gs_io_image *norm, gs_error *err);
void gs_redirect_paste_free(gs_redirect_paste_state *ps);

#ifdef __cplusplus
}
#endif

#endif
