/* gazesplat eval: per-pair results and the reports written from them. */
#ifndef GS_CLI_EVAL_REPORT_H
#define GS_CLI_EVAL_REPORT_H

#include <stdio.h>

#include "gazesplat/eval.h"

enum {
    EVAL_MODEL = 0,
    EVAL_WARP = 1,
    EVAL_IDENTITY = 2,
    EVAL_TRANSFER = 3, /* the model with detail transfer */
    EVAL_ORACLE = 4,   /* training pairs: the model with the identity's
                          learned code, the target's true expression and
                          lights, no fit (gs_model_training_subject) */
    EVAL_METHODS = 5
};
/* Identities a pairing reaches: its largest identity index + 1 (0 when
 * empty). */
static inline int eval_pairs_identities(const gs_eval_pairs *ps)
{
    int top = -1;
    for (int i = 0; i < ps->n; i++)
        top = ps->p[i].identity > top ? ps->p[i].identity : top;
    return top + 1;
}
/* Methods that fit the model to the input. */
static inline int eval_method_fits(int m)
{
    return m == EVAL_MODEL || m == EVAL_TRANSFER;
}
extern const char *const eval_method_names[EVAL_METHODS];

enum { EVAL_ROW_OK = 0, EVAL_ROW_DIVERGED = 1, EVAL_ROW_ERROR = 2 };

/* The metrics of one pair, in the order of the CSV columns. */
enum {
    M_GAZE, M_GAZE_LABEL, M_HEAD, M_HEAD_LABEL, M_FLOOR_GAZE, M_FLOOR_HEAD,
    M_PSNR, M_SSIM, M_EYE_PSNR, M_EYE_SSIM, M_ID_PSNR, M_ID_SSIM,
    M_READ, M_READ_FLOOR, /* --readout: the synthesis readout's gaze error
                             on the output, and on the GT target */
    M_READ_PITCH, M_READ_YAW, /* --readout: the gaze read on the output
                                 (head frame, degrees) */
    M_TRUE_PITCH, M_TRUE_YAW, /* the target's true gaze, in the readout's
                                 frame (head frame, degrees) */
    M_THEAD_PITCH, M_THEAD_YAW, /* the target's head pose (normalized
                                   camera, degrees) */
    M_READ_SOFT,  /* --readout: the softness the readout matched the
                     output at (px; 0 unless --readout-soft) */
    M_COUNT
};
extern const char *const eval_metric_names[M_COUNT];

typedef struct eval_row {
    int method, pair, status;
    int nonfinite;          /* metrics that should exist but are not finite */
    int no_eye;             /* eye region empty (closed eyes): eye metrics n/a */
    int fit_row;            /* this row carries its input's fit time */
    double fit_s, fit_psnr, render_ms;
    double m[M_COUNT];      /* NaN where not measured */
} eval_row;

typedef struct eval_run_info {
    const char *model, *estimator, *pairs, *command;
    int readout;          /* --readout */
    double readout_shift; /* --readout-shift (its alignment, px) */
    double readout_soft;  /* --readout-soft (the softness searched, px) */
    int threads, iters, inputs, image_size;
    double fit_lr_code, fit_lr_colour; /* the fit's Adam rates */
    int fits_reused;      /* fits taken from an earlier run's DIR/fits */
    int fits_stale;       /* cached fits of another model, fit options or
                             input, made again */
    /* render settings of the model method (--prune, --feature-scale,
     * --full-render): face Gaussians kept of n_face, the scale, 0/1 */
    int face_kept, n_face;
    double feature_scale;
    int supersample;      /* the model's own (config.supersample) */
    int eye_direct;       /* the model's config.eye_direct */
    int full_render;
    double transfer_head_weight; /* render option, transfer method */
    double transfer_eye_weight;  /* render option, transfer method */
    double transfer_eye_warp_deg; /* render option, transfer method */
    int transfer_eye_warp_head;   /* render option, transfer method */
    int light_on_head;    /* --light-on-head */
    unsigned true_code;   /* --true-code: GS_SCENE_CODE_* bits (0: none) */
    int true_start;       /* --true-code-start: the parts start the fit only */
    int bound_expression; /* --bound-expression */
    double code_prior;    /* --code-prior, or the model's */
    int code_prior_model; /* 1: code_prior is the model file's */
    double id_prior;      /* --id-prior (0: none) */
    int anneal;           /* --fit-anneal (0: none) */
    int fit_mirror;       /* --fit-mirror */
    double fit_eye_w;     /* --fit-eye-weight (1: the whole image alike) */
    int fit_lr_code_model; /* 1: fit_lr_code is the model file's */
    /* --finetune: steps, GS_FT_* parts, rate; inputs done and their means */
    int ft_iters;
    unsigned ft_parts;
    double ft_lr, ft_eye_w;
    int ft_outline;             /* --finetune-outline PX */
    int ft_mirror;              /* --finetune-mirror */
    int ft_n;
    double ft_s, ft_psnr_first, ft_psnr_best;
} eval_run_info;

void eval_csv_header(FILE *f);
void eval_csv_row(FILE *f, const eval_row *r, const gs_eval_pair *p);
/* Markdown summary of every method in rows[0..n). */
void eval_summary(FILE *f, const eval_run_info *info, const eval_row *rows,
                  int n, const gs_eval_pairs *ps, const int *methods,
                  int nmethods);

#endif
