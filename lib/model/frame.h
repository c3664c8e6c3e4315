/* One frame through the model: streams -> rasterizer -> renderer, and its
 * backward. Shared by rendering, fitting and training. */
#ifndef GS_MODEL_FRAME_H
#define GS_MODEL_FRAME_H

#include "model_internal.h"

/* What a frame is conditioned on. */
typedef struct gs_frame {
    float code[GS_MODEL_MAX_CODE]; /* tau = [id | expr | light] */
    double head_R[9], head_t[3];   /* head to camera */
    double gaze[2];                /* pitch, yaw (head frame) */
} gs_frame;

/* Gradients of a frame's inputs (accumulated by backward). */
typedef struct gs_frame_grad {
    float code[GS_MODEL_MAX_CODE];
    double rot[3];     /* left perturbation R <- exp([w]) R */
    double trans[3];
    double gaze[2];
} gs_frame_grad;

/* Which streams to rasterize. */
enum { GS_STREAM_BOTH = 0, GS_STREAM_FACE = 1, GS_STREAM_EYE = 2 };

/* A subject's (code + head pose) render kept for later incremental ones:
 * the fields of gs_model_ctx with the same names (swapped, never copied). */
typedef struct gs_sweep_slot {
    int valid;
    uint64_t used;                    /* sweep_clock at the last use */
    gs_frame key;
    int rect[4];
    float *g_mean, *g_scale, *g_quat, *g_opac, *g_feat, *fmap, *rgb, *gvec;
    float *eye_base, *x_head, *q_head;
    float eye_base_code[GS_MODEL_MAX_CODE];
    int eye_base_valid;
    int16_t *fbox;
    uint8_t *rgb8;
    int rgb8_valid;
    float rgb8_tf[6];
    int rgb_dirty[4];
    float *rgb_main;                  /* eye_direct: the renderer's image */
    int dir_box[4];
    float *anc_fmap, *anc_rgb;
    int anc_valid;
    int anc_rect[4], anc_fbox[4], anc_rbox[4];
} gs_sweep_slot;

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

typedef struct gs_ctx_scratch gs_ctx_scratch;

struct gs_model_ctx {
    const gs_model *m;
    /* the buffers only a backward reads (frame.c, "what only fitting and
     * training use") are allocated: train_bytes of them */
    int train_ready;
    size_t train_bytes;
    /* a render's scratch (frame.c, "a render's scratch"), perhaps shared
     * with other contexts (gs_model_ctx_share_scratch) */
    gs_ctx_scratch *scr;
    int nf, ne, n;         /* face, eye, total Gaussians */
    /* lids: the face Gaussians [nm, nf), eye 0's first (nl0 of them);
     * they move with the gaze, so renders treat [nm, n) as the moving
     * part and the guidance source is [0, nm) */
    int nl, nl0, nm;
    /* the pitch the lids follow: the frame's gaze, or lid_pitch while
     * lid_hold is set (the transfer's probes: lids held, eyes turned) */
    int lid_hold;
    double lid_pitch;
    float *lid_save;                  /* [nl, 7] backward scratch */
    /* the eye stream's coverage of the merged map (gs_frame_eye_cover,
     * training): an indicator channel (1 eye, 0 face) rasterized with
     * every Gaussian; cover_grad, when set, is its gradient and
     * gs_frame_backward adds its Gaussian gradients */
    gs_raster *raster_cov;
    float *cov_ind, *cov_bg, *cover, *v_ind; /* [n], [fs^2], [2 fs^2], [n] */
    int cover_valid;
    const float *cover_grad;
    int F, D, C, fs, S;
    /* face stream */
    float *fe_in, *fe_act, *fe_out;   /* [nf, F+D], acts, [nf, FACE_OUT] */
    float *fp_in, *fp_act, *fp_out;   /* [nf, F+PE], acts, [nf, FACE_OUT] */
    /* the face stream's MLPs run in nfblk blocks of fblk rows on the pool
     * (frame.c, "the face stream in blocks"); per block: the MLP's weight
     * gradients, then the code's and the gaze encoding's */
    int fblk, nfblk;
    size_t blk_grad_len;              /* floats per block in blk_grad */
    float *blk_grad, *blk_red;        /* [nfblk, blk_grad_len], [nfblk, D+PE2] */
    /* eye stream */
    float *e_in, *e_act, *e_out;      /* [ne, F+D+PE2], acts, [ne, EYE_OUT] */
    float er_in[GS_PE_DIM(2)];
    float *er_act[2];
    float er_out[2][4];
    double eye_R[2][9], eye_Rg[9], eye_Rres[2][9], eye_c[2][3];
    double eye_q[2][4];               /* residual quaternion, unnormalized */
    /* Gaussians in the camera frame, [n x ...] face first */
    float *g_mean, *g_scale, *g_quat, *g_opac, *g_feat;
    float *x_head;                    /* [n, 3] head-frame positions */
    float *q_head;                    /* [nf, 4] head-frame quaternions */
    float *v_mean, *v_scale, *v_quat, *v_opac, *v_feat;   /* their grads */
    /* gs_frame_set_feature_mask: where the Gaussians' features (colours)
     * take gradient, [fs, fs] 0/1 (NULL: everywhere), and its scratch */
    const float *feat_mask;
    float *v_fmap_m, *v_fmap_face_m, *v_feat_keep;
    /* raster + renderer */
    gs_raster *raster;
    /* SOURCE guidance (renderer.h): the face stream's own map is the
     * guidance source; it and its vector are kept with the face cache */
    int src_mode;                     /* SOURCE guidance and two streams */
    gs_raster *raster_face;
    float *fmap_face, *alpha_face, *v_fmap_face; /* [C,fs,fs], [fs,fs] */
    float *gvec;                      /* [C] guidance vector of fmap_face */
    int face_fresh;                   /* face stream redone by the last call */
    int face_map_valid;               /* fmap_face matches the face cache */
    int face_loss;                    /* training: always make fmap_face */
    int eye_loss;                     /* training: make fmap_eye */
    int used_src, used_face_map, used_eye_map; /* what the last forward did */
    gs_raster *raster_eye;
    float *fmap_eye, *alpha_eye, *v_fmap_eye; /* the eye stream alone */
    float *bg_crop;                   /* [C, fs*fs] background of a crop */
    /* supersampled renders (feature scale 2..4): the map, its alpha and
     * background at s fs pixels, [C + 1 + C, (s fs)^2], made on first use */
    float *ss_buf;
    size_t ss_cap;
    /* the eye MLP's first layer for renders: W0 [f_i, tau] + b0 of every
     * eye Gaussian for the code eye_base_code (W0's [f | tau] columns are
     * copied to eye_w0 [h, F+D]; PE(gaze) adds one vector to all) */
    float *eye_w0, *eye_base, *eye_v;  /* [h, F+D], [ne, h], [h] */
    float eye_base_code[GS_MODEL_MAX_CODE];
    int eye_base_valid;
    /* incremental renders (gs_frame_render): fmap and rgb hold the full
     * render of inc_key; inc_rect the eye stream's footprint in it; the
     * face part of g_* is inc_key's and fbox its screen boxes */
    int inc_ok;                       /* the model allows them */
    int inc_valid;
    gs_frame inc_key;
    int inc_rect[4];                  /* x0, y0, x1, y1 (exclusive), feat px */
    int16_t *fbox;                    /* [nf, 4] face Gaussian pixel boxes */
    /* the anchor: the full render of inc_key (its feature map, float image
     * and eye footprint), from which every incremental render starts, so
     * that an incremental render is a function of the anchor and its own
     * gaze alone, never of the gazes rendered before it. anc_fbox and
     * anc_rbox bound what fmap and rgb hold of the last incremental render
     * (feature px, image px): restored from the anchor before the next.
     * Not for eye_direct models (their own undo, direct_undo). */
    float *anc_fmap, *anc_rgb;        /* [C, fs, fs], [3, S, S] or NULL */
    int anc_valid;
    int anc_rect[4], anc_fbox[4], anc_rbox[4];
    gs_raster *raster_crop;
    double inc_stats[2];              /* feature px re-rasterized, changed */
    /* the crop's Gaussians: the face ones whose box meets it, then the eye
     * stream, [n x ...] at most */
    float *k_mean, *k_scale, *k_quat, *k_opac, *k_feat;
    /* 8-bit image of rgb (gs_model_render): rgb8 is rgb under the colour
     * transform rgb8_tf (gain, bias) except over rgb_dirty (image px) */
    int rgb8_valid;
    float rgb8_tf[6];
    int rgb_dirty[4];
    /* other subjects' renders, swapped in and out of the fields above */
    gs_sweep_slot *slots;             /* [sweep_n - 1], allocated lazily */
    int sweep_n;                      /* subjects kept, the live one too */
    uint64_t sweep_clock;
    uint64_t n_full, n_inc;           /* renders by path */
    /* gs_model_render_options: the feature size renders rasterize at
     * (fs: the normal path) and whether every render starts from scratch */
    int render_fs;
    int render_full;
    /* the model's supersampling k (config.supersample): training and
     * fitting forwards rasterize at k fs, and backwards spread each
     * pixel's gradient over its k x k samples */
    int ss;
    /* the eye stream at the image's size (config.eye_direct): every
     * Gaussian rasterized at S x S with 4 channels, the eye stream's
     * colour (first three feature channels) and an indicator (1 eye, 0
     * face), background 0: E and beta; rgb = rgb_main (1 - beta) + E.
     * Made on first use; dir_valid: the last forward made them. */
    int eye_direct, dir_valid;
    int dir_box[4];                   /* the crop rasterized: the eye
                                         stream's reach (gs_frame_eye_tiles
                                         at S), x0 y0 x1 y1; beta and E are
                                         0 outside it */
    gs_raster *raster_dir;
    float *dir_feat, *dir_vfeat;      /* [n, 4] features, their gradient */
    float *dir_out, *dir_alpha, *dir_bg; /* the crop's [4, h, w], [h, w],
                                            [4, h, w] (sized for S x S) */
    float *rgb_main, *dir_dmain;      /* [3, S, S] the renderer's image and
                                         its gradient */
    float *dir_d;                     /* [4, h, w] the raster's output
                                         gradient */
    float xfer_head_w; /* transfer_head_weight (render options) */
    float xfer_eye_w;  /* transfer_eye_weight (render options) */
    double xfer_warp_deg; /* transfer_eye_warp_deg (render options) */
    int xfer_warp_head;   /* transfer_eye_warp_head (render options) */
    int face_map_fs;                  /* the size fmap_face was made at */
    int last_inc;
    float *bg, *fmap, *alpha, *rgb;   /* [C,fs,fs], [fs,fs], [3,S,S] */
    float *v_fmap, *v_rgb;
    float *r_act;           /* the renderer's full buffer (training) */
    size_t r_act_len;
    float *r_grad;          /* renderer weight gradients nobody asked for */
    gs_renderer_params r_grad_p;
    float *scratch;
    size_t scratch_len, scratch_blk;
    /* last frame */
    gs_frame fr;
    int stream;
    int face_valid;                   /* fe/fp outputs match fr */
    gs_frame face_key;                /* the frame the face cache is for */
    uint8_t *rgb8;                    /* [S, S, 3] */
    gs_xfer *xfer;                    /* gs_model_render_transfer, lazily */
    /* how the context drops and invalidates it: set by transfer.c with
     * xfer, so that the frame calls no transfer code */
    void (*xfer_free)(gs_xfer *x);
    void (*xfer_invalidate)(gs_xfer *x);
    uint64_t n_xfer_full, n_xfer_inc; /* transfers by path of their maps */
    int last_xfer_inc;
    double xfer_px;                   /* image px redone by incremental ones */
};

int gs_frame_ctx_init(gs_model_ctx *c, const gs_model *m);

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

/* Until called again with NULL, gs_frame_backward gives the Gaussians'
 * features (colours: feat[k]) only the gradient of the feature-map pixels
 * where mask [fs, fs] (kept by the caller) is 1; their positions, scales,
 * rotations and opacities still take the whole map's. Costs one more
 * rasterizer backward. GS_ERR_NOMEM when its scratch cannot be had. */
int gs_frame_set_feature_mask(gs_model_ctx *c, const float *mask,
                              gs_error *err);

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
