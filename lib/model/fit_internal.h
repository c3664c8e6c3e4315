/* What the model's public files share (subject.c, render.c, fit.c,
 * finetune.c): the argument checks, a subject's frame, and the fit's image
 * loss and buffers, which fine-tuning runs on too. */
#ifndef GS_MODEL_FIT_INTERNAL_H
#define GS_MODEL_FIT_INTERNAL_H

#include <math.h>

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

/* The stopping rules that fitting and fine-tuning share: the first and
 * the best loss, the plateau test (the loss fell by less than plateau_rel
 * of itself over the last 20 iterations, and 20 have passed since the
 * start or the last restart) and the time budget (0: none). The two keep
 * their own optimizers: the fit a small Adam in doubles over 14 + code
 * variables (fit_state), fine-tuning gs_nn_adam over up to a million
 * floats of the model; what they share is when to stop and what to keep. */
typedef struct gs_opt_watch {
    double t0, first, best, hist[20];
    double plateau_rel, time_budget_s;
    int since;
} gs_opt_watch;

static inline void gs_opt_watch_start(gs_opt_watch *w, double plateau_rel, double time_budget_s,
                                      double t0)
{
    w->t0 = t0;
    w->first = NAN;
    w->best = INFINITY;
    w->plateau_rel = plateau_rel;
    w->time_budget_s = time_budget_s;
    w->since = 0;
}

/* Iteration it's loss: 1 when it is the best so far (the caller keeps its
 * iterate). */
static inline int gs_opt_watch_best(gs_opt_watch *w, int it, double loss)
{
    if (it == 0)
        w->first = loss;
    if (!(loss < w->best))
        return 0;
    w->best = loss;
    return 1;
}

/* Records iteration it's loss; 1 when the loss has plateaued. */
static inline int gs_opt_watch_plateau(gs_opt_watch *w, int it, double loss)
{
    w->hist[it % 20] = loss;
    return w->plateau_rel > 0 && it >= 20 && it - w->since >= 20 &&
           w->hist[(it + 1) % 20] - loss < w->plateau_rel * loss;
}

/* The plateau test starts over from iteration it (the fit's annealing). */
static inline void gs_opt_watch_restart(gs_opt_watch *w, int it)
{
    w->since = it;
}

/* 1 when the time budget is spent at now (seconds, gs_clock_s). */
static inline int gs_opt_watch_over_time(const gs_opt_watch *w, double now)
{
    return w->time_budget_s > 0 && now - w->t0 > w->time_budget_s;
}

#endif
