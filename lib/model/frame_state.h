/* The frame's types: what a frame is conditioned on, its gradients, a
 * kept sweep slot and the context (gs_model_ctx) with its render scratch.
 * Types only: the context's buffers are made in frame_ctx.c, the sweep
 * cache is frame_sweep.c, the forward and backward frame.c. */
#ifndef GS_MODEL_FRAME_STATE_H
#define GS_MODEL_FRAME_STATE_H

#include <stdlib.h>

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

/* Detail transfer's state (transfer.c; the context holds it). */
typedef struct gs_xfer gs_xfer;

/* A render's scratch: the renderer's forward-only buffer and each pool
 * thread's face-stream rows, shared by contexts that are never used at
 * the same time (gs_model_ctx_share_scratch; frame_ctx.c). */
typedef struct gs_ctx_scratch {
    int refs;                 /* contexts using it */
    float *act, *face;
    size_t act_len, face_len; /* floats */
} gs_ctx_scratch;

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
    double xfer_warp_given_deg; /* transfer_eye_warp_given_deg */
    double xfer_lid; /* transfer_lid_follow */
    int xfer_warp_head;   /* transfer_eye_warp_head (render options) */
    int face_map_fs;                  /* the size fmap_face was made at */
    int last_inc;
    float *bg, *fmap, *alpha, *rgb;   /* [C,fs,fs], [fs,fs], [3,S,S] */
    float *v_fmap, *v_rgb;
    float *r_act;           /* the renderer's full buffer (training) */
    size_t r_act_len;
    float *scratch;
    size_t scratch_len, scratch_blk;
    /* last frame */
    gs_frame fr;
    int stream;
    int face_valid;                   /* fe/fp outputs match fr */
    int face_saved;                   /* and its MLP activations are in the
                                         training buffers (fe_act, fp_act),
                                         which a backward reads */
    gs_frame face_key;                /* the frame the face cache is for */
    /* fe_out holds the expression MLP's outputs at fe_code under the
     * current parameters (a render's head change keeps the code: only the
     * pose MLP and what follows run again). Set by a render-only face
     * forward, dropped by gs_sweep_drop (training, new parameters). */
    int fe_valid;
    float fe_code[GS_MODEL_MAX_CODE];
    uint64_t n_fe_kept;               /* face forwards that kept them */
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

/* n zeroed floats (at least one); sets *fail when out of memory. */
static inline float *gs_ctx_falloc(size_t n, int *fail)
{
    float *p = calloc(n ? n : 1, sizeof(float));
    if (!p)
        *fail = 1;
    return p;
}

#endif
