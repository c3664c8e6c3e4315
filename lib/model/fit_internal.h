/* What the model's public files share (subject.c, render.c, fit.c,
 * finetune.c): the argument checks, a subject's frame, and the fit's image
 * loss and buffers, which fine-tuning runs on too. */
#ifndef GS_MODEL_FIT_INTERNAL_H
#define GS_MODEL_FIT_INTERNAL_H

#include "frame.h"

/* The fitted variables, one flat vector for a small Adam. */
enum { V_GAZE = 0, V_ROT = 2, V_TRANS = 5, V_GAIN = 8, V_BIAS = 11,
       V_CODE = 14 };

typedef struct fit_state {
    double x[V_CODE + GS_MODEL_MAX_CODE];
    double g[V_CODE + GS_MODEL_MAX_CODE];
    double m1[V_CODE + GS_MODEL_MAX_CODE], m2[V_CODE + GS_MODEL_MAX_CODE];
    double lr[V_CODE + GS_MODEL_MAX_CODE];
    int n;
} fit_state;

typedef struct fit_bufs {
    float *target, *w, *pred, *dpred, *ssim_scratch;
    size_t ssim_len;
    int shared; /* pred, dpred and ssim_scratch are another's */
} fit_bufs;

/* Checks of a subject's pose, a gaze and a subject against the model:
 * GS_OK or GS_ERR_ARG (GS_ERR_NONFINITE) with err. */
int gs_model_check_pose(const double R[9], const double t[3], gs_error *err);
int gs_model_check_gaze(double pitch, double yaw, gs_error *err);
int gs_model_check_subject(const gs_model *m, const gs_subject *s,
                         gs_error *err);

/* The frame that renders subject s at view v. */
void gs_model_frame_of(const gs_subject *s, const gs_view *v, gs_frame *fr);

double gs_fit_image_loss(gs_model_ctx *c, gs_pool *pool, fit_bufs *b, const fit_state *s,
                         double *dgain, double *dbias);
int gs_fit_image_bufs(const gs_model_ctx *c, const gs_fit_image *im,
                          int mirror, const fit_bufs *with, fit_bufs *b,
                          fit_bufs *bm);
/* base with image im's labels (gaze, head pose) in place of its own; the
 * mask is left as base has it. The inverse of gs_fit_image_from_options. */
void gs_fit_options_of_image(const gs_fit_options *base, const gs_fit_image *im,
                             gs_fit_options *o);
float gs_fit_weighted_psnr(const fit_bufs *b, int S);
void gs_fit_bufs_free(fit_bufs *b);

#endif
