/* One frame through the model: streams -> rasterizer -> renderer, and its
 * backward. Shared by rendering, fitting and training. */
#ifndef GS_MODEL_FRAME_H
#define GS_MODEL_FRAME_H

#include "frame_ctx.h"
#include "frame_state.h"
#include "frame_sweep.h"


/* The eye stream's coverage of the merged feature map of the last forward
 * (GS_STREAM_BOTH) into c->cover [fs, fs]: its Gaussians' share of each
 * pixel, the visible eyeball. With c->cover_grad set (d loss / d cover),
 * the next gs_frame_backward carries it to the Gaussians and the streams
 * (the lids' placement, mostly). */
int gs_frame_eye_cover(gs_model_ctx *c, gs_pool *pool, gs_error *err);

/* Detail transfer's state (transfer.c). */
typedef struct gs_xfer gs_xfer;
void gs_xfer_free(gs_xfer *x);
void gs_xfer_invalidate(gs_xfer *x);
/* Drops only the kept target: the next transfer takes the full path
 * (benchmarks of that path). */
void gs_xfer_forget_target(gs_xfer *x);
/* The last target's depth (mm), coverage and eye coverage maps [S*S]
 * (tests); NULL before the first transfer. */
void gs_xfer_target_maps(const gs_xfer *x, const float **z, const float **a,
                         const float **e);
/* The live subject's eye opening [S*S], 0..1 (tests read it, or overwrite
 * it to pin the opening); NULL until a warped transfer made it. */
float *gs_xfer_eye_opening(gs_xfer *x);
/* The same at the last head-changed target's pose (transfer_eye_warp_head);
 * NULL until a warped transfer at another head pose made it. */
float *gs_xfer_target_opening(gs_xfer *x);
/* The eyeball warp's proxy iris (transfer.c): its radius over the proxy
 * eyeball's (an eye's 6 mm over 12 mm) and its plane's inset behind the
 * limbus, as a share of the eyeball's radius. */
#define GS_XFER_IRIS_RATIO 0.5
#define GS_XFER_IRIS_INSET 0.03
/* Lids that follow the gaze on a photo (transfer.c): the lid skin that
 * moves with a margin, in iris radii above the upper one and below the
 * lower one. */
#define GS_XFER_LID_SKIN_UP 2.0
#define GS_XFER_LID_SKIN_DOWN 1.5


/* Runs the frame: fills c->fmap and c->rgb (3 x S x S, in [0,1]). The face
 * stream is recomputed only when the code, head pose (or, in the single
 * stream ablation, the gaze) changed since the last call, unless
 * force_face. */
int gs_frame_forward(gs_model_ctx *c, gs_pool *pool, const gs_frame *fr,
                     int stream, int force_face, gs_error *err);

/* Only the streams of gs_frame_forward: the camera-frame Gaussians in
 * c->g_* (tests of the stream gradients); allocates the training buffers
 * as gs_frame_forward does (GS_ERR_NOMEM when it cannot). */
int gs_frame_forward_streams(gs_model_ctx *c, gs_pool *pool,
                             const gs_frame *fr, int force_face);

/* Backward of the last forward from d_rgb [3,S,S] (may be NULL),
 * d_fmap [C,fs,fs] (may be NULL), d_fmap_face (the face-only map
 * c->fmap_face, made with SOURCE guidance or face_loss; may be NULL) and
 * d_fmap_eye (the eye-only map c->fmap_eye, made with eye_loss; may be
 * NULL). Adds parameter gradients
 * into `grads` (a gs_model_params bound to a gradient array; NULL skips
 * them) and the frame's input gradients into fg (may be NULL). */
int gs_frame_backward(gs_model_ctx *c, gs_pool *pool, const float *d_rgb,
                      const float *d_fmap, const float *d_fmap_face,
                      const float *d_fmap_eye, const gs_model_params *grads,
                      gs_frame_grad *fg, gs_error *err);

/* fr seen in a mirror: the image flipped left to right is the same head
 * (if symmetric about its x = 0 plane) at head rotation S R S and
 * translation S t, S = diag(-1, 1, 1), with the gaze's yaw and the light
 * directions' head-frame x negated. Its own inverse. */
void gs_frame_mirror(const gs_frame *fr, int code_dim, gs_frame *out);
/* The code's part of gs_frame_mirror, in place: the light directions'
 * head-frame x negated. Linear and its own inverse, so it maps a gradient
 * over the mirrored code back to the code too. */
void gs_frame_mirror_code(float *code, int code_dim);


/* Renders a frame into c->rgb for display (no backward). When the model
 * allows it (SOURCE or no guidance, two streams) and the last render had
 * the same code and head pose, only the eye stream's footprint (old and
 * new) is rasterized again and only the renderer's reach around it is
 * recomputed; the result equals gs_frame_forward's within float rounding
 * (test_model_api). *incremental (may be NULL) tells which path ran. */
/* 1 when c renders incrementally (anchored renders: not eye_direct, no
 * supersampling, not render_full) and keeps no full render (anchor) of
 * fr's code and head pose, live or in its sweep cache: the next
 * gs_frame_render of fr would take the full path. */
int gs_frame_wants_anchor(const gs_model_ctx *c, const gs_frame *fr);
int gs_frame_render(gs_model_ctx *c, gs_pool *pool, const gs_frame *fr,
                    int *incremental, gs_error *err);

/* The stream part of the backward: from the Gaussian gradients in
 * c->v_mean, v_scale, v_quat, v_opac, v_feat (camera frame) to the
 * parameters and the frame inputs. */
void gs_frame_backward_streams(gs_model_ctx *c, gs_pool *pool,
                               const gs_model_params *grads, gs_frame_grad *fg);

/* Zeroes the camera-frame Gaussian gradients c->v_mean .. v_feat (all n
 * Gaussians) before a rasterizer backward adds into them. */
void gs_frame_clear_gaussian_grads(gs_model_ctx *c);

/* The camera the model renders a frame with at feature resolution. */
void gs_frame_camera(const gs_model *m, const double head_t[3],
                     gs_camera *cam);

/* ---- crops of a render (incremental renders, detail transfer) ---- */

/* Writable arrays of Gaussians, n x 3, 3, 4, 1 and channels each. */
typedef struct gs_frame_soa {
    float *mean, *scale, *quat, *opac, *feat;
} gs_frame_soa;

/* The tile-aligned box (pixels of cam: x0 y0 x1 y1, exclusive, clipped to
 * its image; empty when x0 >= x1) that the moving Gaussians in c->g_* (the
 * lids and the eye stream, [nm, n)) can reach: the rasterizer changes no
 * pixel outside it when only they move. */
void gs_frame_eye_tiles(const gs_model_ctx *c, const gs_camera *cam,
                        int r[4]);

/* Per face Gaussian of c->g_*, a pixel box (fbox [nf, 4], x0 y0 x1 y1) that
 * holds its footprint through cam and through any crop of cam
 * (gs_frame_raster_crop). */
void gs_frame_face_boxes(const gs_model_ctx *c, const gs_camera *cam,
                         int16_t *fbox);

/* a = the bounding box of a and b (an empty one adds nothing) */
void gs_frame_box_union(int a[4], const int b[4]);

/* Copies into dst the first nf Gaussians of src (the still face: c->nm)
 * whose fbox meets the box d, then all the others (lids, eye stream),
 * and returns them
 * as Gaussians in dst's arrays: what a crop at d needs. */
gs_gaussians gs_frame_gather(const gs_gaussians *src, int nf,
                             const int16_t *fbox, const int d[4],
                             const gs_frame_soa *dst);

/* Rasterizes g into the tile-aligned box d of the image seen by full:
 * full's camera shifted by d's origin, at d's size, with full's frustum,
 * so each pixel equals the whole image's to float rounding. out, alpha
 * and depth are d-sized (depth may be NULL). r keeps full's frustum for
 * later forwards: give it crops only. */
int gs_frame_raster_crop(gs_raster *r, gs_pool *pool, const gs_camera *full,
                         const int d[4], const gs_gaussians *g,
                         const float *bg, float *out, float *alpha,
                         float *depth, gs_error *err);

/* Whether a crop's value differs from the whole image's `old` by more than
 * the float rounding of the crop's shifted camera (1e-6 (1 + |old|)). */
int gs_frame_moved(float old, float now);

#endif
