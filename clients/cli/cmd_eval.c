/* gazesplat eval: measure gaze redirection on held-out synthetic heads
 * (docs/eval.md), and write the fixed pairing file it reads. */
#define _POSIX_C_SOURCE 200809L /* clock_gettime */

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <time.h>

#include "cli.h"
#include "eval_estimator.h"
#include "eval_report.h"
#include "gazesplat/eval.h"
#include "gazesplat/geom.h"
#include "gazesplat/image_io.h"
#include "gazesplat/model.h"
#include "gazesplat/nn.h"
#include "gazesplat/train.h"

#define RAD_TO_DEG (180.0 / 3.14159265358979323846)

static int run_eval(const cli_command *cmd, cli_opt *o);

static const cli_opt eval_opts[] = {
    {"--model", 1, NULL}, {"--pairs", 1, NULL}, {"--out", 1, NULL}, {"--estimator", 1, NULL},
    {"--method", 1, NULL}, {"--limit-inputs", 1, NULL}, {"--iters", 1, NULL},
    {"--fit-lr", 1, NULL}, {"--threads", 1, NULL}, {"--reuse-fits", 0, NULL},
    {"--save-images", 1, NULL}, {"--prune", 1, NULL}, {"--feature-scale", 1, NULL},
    {"--full-render", 0, NULL}, {"--finetune", 1, NULL}, {"--finetune-parts", 1, NULL},
    {"--finetune-lr", 1, NULL}, {"--finetune-eye-weight", 1, NULL},
    {"--transfer-head-weight", 1, NULL}, {"--light-on-head", 0, NULL},
    {"--transfer-eye-weight", 1, NULL}, {"--transfer-eye-warp", 1, NULL},
    {"--transfer-eye-warp-head", 1, NULL}, {"--finetune-outline", 1, NULL},
    {"--finetune-mirror", 1, NULL}, {"--readout", 0, NULL}, {"--readout-shift", 1, NULL},
    {"--readout-soft", 1, NULL}, {"--true-code", 1, NULL}, {"--true-code-start", 0, NULL},
    {"--bound-expression", 0, NULL}, {"--code-prior", 1, NULL}, {"--id-prior", 1, NULL},
    {"--fit-anneal", 1, NULL}, {"--fit-mirror", 1, NULL}, {"--fit-eye-weight", 1, NULL},
    {"--make-pairs", 1, NULL}, {"--identities", 1, NULL}, {"--inputs", 1, NULL},
    {"--targets", 1, NULL}, {"--seed", 1, NULL}, {"--split", 1, NULL}};

const cli_command cli_eval_command = {
    "eval",
    "measure redirection (model, warp baseline, identity) on held-out heads",
    "usage: gazesplat eval --model M --pairs FILE --out DIR [--estimator E]\n"
    "                      [--method LIST] [--limit-inputs N] [--iters N]\n"
    "                      [--fit-lr CODE[,COLOUR]] [--bound-expression]\n"
    "                      [--code-prior W] [--id-prior W] [--true-code LIST]\n"
    "                      [--true-code-start] [--fit-anneal N]\n"
    "                      [--fit-mirror 0|1] [--fit-eye-weight W]\n"
    "                      [--threads N] [--reuse-fits] [--save-images N]\n"
    "                      [--prune K|P%] [--feature-scale S] [--full-render]\n"
    "                      [--transfer-head-weight W] [--light-on-head]\n"
    "                      [--transfer-eye-weight W] [--transfer-eye-warp DEG]\n"
    "                      [--finetune N] [--finetune-parts LIST]\n"
    "                      [--finetune-lr X] [--finetune-eye-weight W]\n"
    "                      [--finetune-outline PX] [--finetune-mirror 0|1]\n"
    "                      [--readout] [--readout-shift PX] [--readout-soft PX]\n"
    "       gazesplat eval --make-pairs FILE [--identities N] [--inputs N]\n"
    "                      [--targets N] [--seed N] [--split S]\n"
    "\n"
    "  --model FILE      the model to evaluate (its image size and camera)\n"
    "  --pairs FILE      the pairing (bench/eval/pairs.csv; --make-pairs)\n"
    "  --out DIR         writes DIR/pairs.csv (one row per pair and method)\n"
    "                    and DIR/summary.md (created if needed)\n"
    "  --estimator FILE  gaze/head estimator for the angular errors; without\n"
    "                    it only the image metrics are measured\n"
    "  --readout         also read the gaze of every output (and of the GT\n"
    "                    target: the floor) by synthesis: the target scene\n"
    "                    rendered at candidate gazes over the eye regions,\n"
    "                    the best match wins (gs_eval_gaze_readout); about\n"
    "                    0.9 s per image on 2 threads\n"
    "  --readout-shift PX  the readout's alignment: the largest 2D shift\n"
    "                    (px) searched before the eyeballs are compared,\n"
    "                    0..8 (default 4; 0: none)\n"
    "  --readout-soft PX  the readout also matches candidates blurred as an\n"
    "                    output of softness up to PX would be (0..2.5,\n"
    "                    steps of 0.25; default 0: off), so a soft eye is\n"
    "                    read by where it points, not by its sharpness\n"
    "  --method LIST     comma-separated: model, transfer (the model with\n"
    "                    detail transfer from the input), warp (2D eye\n"
    "                    warping), identity (output = input), oracle\n"
    "                    (training pairs only: the model with the\n"
    "                    identity's learned code and the target's true\n"
    "                    expression and lights, no fit: what it can draw);\n"
    "                    default model\n"
    "  --limit-inputs N  only the first N inputs of the file\n"
    "  --iters N         fit iteration cap (default 200)\n"
    "  --fit-lr CODE[,COLOUR]  the fit's Adam rates for the latent code and\n"
    "                    the colour gain and bias, each in (0, 10]\n"
    "                    (default: the code rate the model file names,\n"
    "                    config.fit_code_rate, else 0.12, and 0.02;\n"
    "                    COLOUR defaults to CODE / 6)\n"
    "  --bound-expression  the fit keeps the code's expression where\n"
    "                    training put it (clamped each step); default free\n"
    "  --code-prior W    the fit's prior on the code's expression and\n"
    "                    lights (the training sampler's Gaussian), weight\n"
    "                    W in [0, 10], 0: none (default: the weight the\n"
    "                    model file names, config.fit_code_prior; none\n"
    "                    when it names none)\n"
    "  --id-prior W      the fit's prior on the code's identity slots (the\n"
    "                    learned identity codes' Gaussian), weight W in\n"
    "                    [0, 10], 0: none (default)\n"
    "  --fit-anneal N    at a plateau the fit halves its rates and goes on,\n"
    "                    N times (0..8) before it stops; 0: stops at the\n"
    "                    first plateau (default)\n"
    "  --fit-mirror 0|1  1: the fit also fits the input flipped left to\n"
    "                    right from the mirrored pose, a second view (an\n"
    "                    iteration costs twice as much); 0: the input alone\n"
    "                    (default)\n"
    "  --fit-eye-weight W  weight of the input's eye region in the fit's\n"
    "                    loss against the rest of the image, 0..16 (default\n"
    "                    1; 0: the code is fitted to the rest of the face;\n"
    "                    above 1 the rest is weighted 1/W)\n"
    "  --true-code LIST  a diagnostic, not a served figure: the fit is given\n"
    "                    the input's true expression, lights and/or (pairs\n"
    "                    of --split train only) the identity code training\n"
    "                    learned (comma-separated: expr, light, id) and\n"
    "                    keeps them; how much of the error is the fit\n"
    "                    getting them wrong\n"
    "  --true-code-start (with --true-code) the given parts only start the\n"
    "                    fit, which moves them as it moves the rest: whether\n"
    "                    the image pulls the fit away from the true code\n"
    "  --threads N       worker threads (default 2); results are the same\n"
    "                    for a given count, timings aside\n"
    "  --reuse-fits      take each input's fit from DIR/fits/ (written by\n"
    "                    every run) when there and made with this model,\n"
    "                    these fit options and this input (each file is\n"
    "                    keyed by them; any other is fitted again and\n"
    "                    rewritten): rescoring with another estimator,\n"
    "                    method list or render setting costs no fitting\n"
    "  --save-images N   write the input, target and outputs of the first N\n"
    "                    pairs as DIR/images/PAIR_WHAT.png\n"
    "  render settings of the model method (speed against error; the fit\n"
    "  always runs the whole model, so fits can be reused across them):\n"
    "  --prune K|P%      render with only the K (or P percent of the) most\n"
    "                    important face Gaussians (gs_model_prune)\n"
    "  --feature-scale S rasterize the feature map at S x its size, S in\n"
    "                    (0, 1] (default 1), resampled for the renderer;\n"
    "                    2, 3 or 4: supersampled, each pixel the mean of\n"
    "                    S x S\n"
    "  --full-render     every render from scratch (no incremental sweeps,\n"
    "                    no cached face stream)\n"
    "  --transfer-head-weight W  the transfer method at another head pose:\n"
    "                    weight of the smoothed skin residual, 0..1\n"
    "                    (default 0.5; 0 = the model's render there)\n"
    "  --transfer-eye-weight W  the transfer method at another gaze: weight\n"
    "                    of the eyeball residual once the eye has turned a\n"
    "                    few degrees, 0..1 (default 0.5; all of it at the\n"
    "                    input's own gaze)\n"
    "  --transfer-eye-warp DEG  the transfer method at another gaze, same\n"
    "                    head pose: the input's eyeball pixels, turned with\n"
    "                    the eye inside its opening, weighted\n"
    "                    exp(-(turn / DEG)^2); 0..90 (default 20; 0 = off)\n"
    "  --transfer-eye-warp-head 0|1  1: the same warp at another head pose\n"
    "                    too (the opening the model shows there); default 0\n"
    "  --light-on-head   model and transfer methods: at a head change keep\n"
    "                    the fitted light on the head (default: the lights\n"
    "                    stay in the camera, as in the ground truth)\n"
    "  --finetune N      after each fit, fine-tune a copy of the model on the\n"
    "                    input for N Adam steps (gs_model_finetune) and render\n"
    "                    that input's targets with it; fit time includes it\n"
    "  --finetune-parts LIST  what is tuned, comma-separated: face (face\n"
    "                    Gaussians' colours and features), eye, renderer,\n"
    "                    mlp, geometry, face-geometry (the face stream's\n"
    "                    alone); default face,geometry\n"
    "  --finetune-lr X   Adam's base rate (default 0.004, the daemon's)\n"
    "  --finetune-eye-weight W  weight of the input's eye region in the\n"
    "                    fine-tuning loss, 0..1 (default 1; 0 leaves the\n"
    "                    eyes to the shared model)\n"
    "  --finetune-outline PX  colours learn nothing within PX feature pixels\n"
    "                    of the model's outline, only the geometry (0..8,\n"
    "                    default 0)\n"
    "  --finetune-mirror 0|1  also fit the input mirrored left to right from\n"
    "                    the mirrored pose (default 1); 0: the input alone\n"
    "  --make-pairs FILE write a pairing: --identities held-out identities\n"
    "                    (15) x --inputs scenes each (10) x --targets (10),\n"
    "                    --seed (1); deterministic. --split test (default)\n"
    "                    or validation: choose methods and settings on\n"
    "                    validation pairs, report on test pairs; train: the\n"
    "                    first identities the model was trained on, a\n"
    "                    diagnostic (what it draws for faces it has seen),\n"
    "                    never a held-out figure\n",
    .opts = eval_opts,
    .nopts = CLI_NOPTS(eval_opts),
    .run_opts = run_eval,
};

enum {
    O_MODEL, O_PAIRS, O_OUT, O_EST, O_METHOD, O_LIMIT, O_ITERS, O_FIT_LR, O_THREADS,
    O_REUSE, O_SAVE, O_PRUNE, O_FSCALE, O_FULL, O_FT, O_FT_PARTS, O_FT_LR, O_FT_EYE,
    O_XHW, O_LOH, O_XEW, O_XWARP, O_XWARP_HEAD, O_FT_OUTLINE, O_FT_MIRROR, O_READ, O_READ_SHIFT,
    O_READ_SOFT, O_TRUE_CODE, O_TRUE_START, O_BOUND_EXPR, O_CODE_PRIOR, O_ID_PRIOR, O_ANNEAL, O_FIT_MIRROR, O_FIT_EYE, O_MAKE, O_IDS, O_INPUTS, O_TARGETS, O_SEED, O_SPLIT, O_N
};

/* --true-code LIST: comma-separated expr, light, id (each at most once). */
static int parse_true_code(const char *s, unsigned *out)
{
    unsigned bits = 0;
    while (*s) {
        size_t n = strcspn(s, ",");
        unsigned b = n == 4 && !strncmp(s, "expr", 4)    ? GS_SCENE_CODE_EXPR
                     : n == 5 && !strncmp(s, "light", 5) ? GS_SCENE_CODE_LIGHT
                     : n == 2 && !strncmp(s, "id", 2)    ? GS_SCENE_CODE_ID
                                                         : 0;
        if (!b || (bits & b))
            return -1;
        bits |= b;
        s += n;
        if (*s == ',' && !*++s)
            return -1;
    }
    *out = bits;
    return bits ? 0 : -1;
}

static int make_pairs(const cli_opt *o)
{
    const cli_command *cmd = &cli_eval_command;
    gs_eval_pairs_spec sp;
    gs_eval_pairs_spec_default(&sp);
    long v;
    if (o[O_IDS].value) {
        if (cli_parse_long(o[O_IDS].value, 1, 100000, &v))
            return cli_usage_error(cmd, "--identities: want 1..100000");
        sp.identities = (int)v;
    }
    if (o[O_INPUTS].value) {
        if (cli_parse_long(o[O_INPUTS].value, 1, 1000, &v))
            return cli_usage_error(cmd, "--inputs: want 1..1000");
        sp.inputs = (int)v;
    }
    if (o[O_TARGETS].value) {
        if (cli_parse_long(o[O_TARGETS].value, 1, 1000, &v))
            return cli_usage_error(cmd, "--targets: want 1..1000");
        sp.targets = (int)v;
    }
    if (o[O_SEED].value) {
        if (cli_parse_long(o[O_SEED].value, 0, 4294967295L, &v))
            return cli_usage_error(cmd, "--seed: want 0..4294967295");
        sp.seed = (uint64_t)v;
    }
    if (o[O_SPLIT].value) {
        const char *s = o[O_SPLIT].value;
        if (!strcmp(s, "test"))
            sp.split = GS_SYNTH_TEST;
        else if (!strcmp(s, "validation"))
            sp.split = GS_SYNTH_VAL;
        else if (!strcmp(s, "train"))
            sp.split = GS_SYNTH_TRAIN;
        else
            return cli_usage_error(cmd, "--split: want test, validation or train");
    }
    gs_eval_pairs ps;
    gs_error err = {0, ""};
    if (gs_eval_pairs_make(&sp, &ps, &err))
        return cli_fail(cmd, "%s", err.msg);
    FILE *f = fopen(o[O_MAKE].value, "w");
    int rc = CLI_OK;
    if (!f || gs_eval_pairs_write(f, &ps, &err) || fclose(f)) {
        rc = cli_fail(cmd, "cannot write %s", o[O_MAKE].value);
        f = NULL;
    }
    if (!rc)
        printf("gazesplat eval: %d pairs -> %s\n", ps.n, o[O_MAKE].value);
    gs_eval_pairs_free(&ps);
    return rc;
}

/* Everything one evaluation run holds. */
typedef struct evaluator {
    gs_model *m;
    gs_model_ctx *c;
    gs_model *pm;               /* pruned model (--prune), or NULL */
    gs_model_ctx *rctx;         /* renders the model method: c, or pm's */
    double prune_pct;           /* --prune P%: P; else 0 */
    long prune_k;               /* --prune K: K; else 0 */
    gs_model_render_options ro;
    int light_on_head;    /* --light-on-head */
    eval_estimator *est;
    int readout;                /* --readout */
    gs_eval_readout_options read_opts; /* --readout-shift */
    gs_pool *pool;
    int S, iters;
    double lr_code, lr_colour;  /* --fit-lr */
    unsigned true_code;         /* --true-code: GS_SCENE_CODE_* bits */
    int true_start;             /* --true-code-start: a start, not kept */
    int bound_expression;       /* --bound-expression */
    double code_prior;          /* --code-prior */
    double id_prior;            /* --id-prior */
    int anneal;                 /* --fit-anneal */
    int fit_mirror;             /* --fit-mirror */
    double fit_eye_w;           /* --fit-eye-weight */
    double focal, d_n;
    int methods[EVAL_METHODS], nmethods;
    uint8_t *out, *eye, *face;  /* S*S*3, S*S, S*S */
    eval_row *rows;
    int nrows;
    const char *dir;            /* --out */
    int reuse_fits, fits_reused, fits_stale;
    int save_images;            /* pairs [0, save_images) as PNG */
    gs_finetune_options fo;     /* --finetune: fo.iters > 0 */
    double ft_eye_w;            /* --finetune-eye-weight */
    uint8_t *ftmask;            /* its loss weights (eye_weights) */
    uint8_t *fitmask;           /* --fit-eye-weight: the fit's */
    gs_model *ftm;              /* the copy that is fine-tuned per input */
    gs_model_ctx *ftctx;        /* renders it */
    int ft_n;                   /* inputs fine-tuned */
    double ft_s, ft_psnr_first, ft_psnr_best; /* their sums */
} evaluator;

/* Angular error in degrees of two (pitch, yaw) predictions; NaN if either
 * is missing. */
static double ang(double p0, double y0, double p1, double y1)
{
    if (!isfinite(p0) || !isfinite(y0) || !isfinite(p1) || !isfinite(y1))
        return NAN;
    return gs_eval_angle_deg(p0, y0, p1, y1);
}

static int predict(evaluator *ev, const uint8_t *rgb, float out[4])
{
    gs_error err = {0, ""};
    for (int k = 0; k < 4; k++)
        out[k] = NAN;
    if (!ev->est)
        return 0;
    return eval_estimator_predict(ev->est, ev->pool, rgb, ev->S, ev->S,
                                  3 * (size_t)ev->S, out, &err) != GS_OK;
}

/* The synthesis readout's error (degrees) on an image of the target scene
 * against its true gaze, and the gaze read (head frame, degrees) and the
 * softness matched (px) into read[3] when not NULL; NaN, and a message, if
 * it fails. */
static double read_err(evaluator *ev, const gs_synth_scene *ts,
                       const uint8_t *rgb, size_t stride, int pair,
                       double *read)
{
    gs_eval_readout rd;
    gs_error err = {0, ""};
    if (gs_eval_gaze_readout(ts, ev->S, ev->d_n, ev->focal, rgb, stride,
                             &ev->read_opts, ev->pool, &rd, &err)) {
        fprintf(stderr, "gazesplat eval: pair %d: readout: %s\n", pair,
                err.msg);
        return NAN;
    }
    if (read) {
        read[0] = rd.pitch * RAD_TO_DEG;
        read[1] = rd.yaw * RAD_TO_DEG;
        read[2] = rd.soft_px;
    }
    return gs_eval_angle_deg(rd.pitch, rd.yaw, ts->gaze_pitch, ts->gaze_yaw);
}

/* Image and angle metrics of ev->out against the GT target. */
static void measure(evaluator *ev, const gs_synth_sample *gt,
                    const gs_synth_scene *ts, const float gt_est[4],
                    double read_floor, eval_row *r)
{
    int S = ev->S;
    size_t st = 3 * (size_t)S;
    gs_error err = {0, ""};
    /* Labels as the estimator is trained: normalized gaze and head. */
    const gs_synth_labels *l = &gt->labels;
    r->m[M_PSNR] = gs_eval_psnr(ev->out, st, gt->rgb, gt->stride, S, S, NULL);
    r->m[M_SSIM] = gs_eval_ssim(ev->out, st, gt->rgb, gt->stride, S, S, NULL,
                                &err);
    r->no_eye = gs_eval_mask_count(ev->eye, S, S) == 0;
    r->m[M_EYE_PSNR] = gs_eval_psnr(ev->out, st, gt->rgb, gt->stride, S, S,
                                    ev->eye);
    r->m[M_EYE_SSIM] = gs_eval_ssim(ev->out, st, gt->rgb, gt->stride, S, S,
                                    ev->eye, &err);
    r->m[M_ID_PSNR] = gs_eval_psnr(ev->out, st, gt->rgb, gt->stride, S, S,
                                   ev->face);
    r->m[M_ID_SSIM] = gs_eval_ssim(ev->out, st, gt->rgb, gt->stride, S, S,
                                   ev->face, &err);
    float o[4];
    int bad_est = predict(ev, ev->out, o);
    r->m[M_GAZE] = ang(o[0], o[1], gt_est[0], gt_est[1]);
    r->m[M_GAZE_LABEL] = ang(o[0], o[1], l->gaze_norm_pitch,
                             l->gaze_norm_yaw);
    r->m[M_HEAD] = ang(o[2], o[3], gt_est[2], gt_est[3]);
    r->m[M_HEAD_LABEL] = ang(o[2], o[3], l->head_norm_pitch,
                             l->head_norm_yaw);
    r->m[M_FLOOR_GAZE] = ang(gt_est[0], gt_est[1], l->gaze_norm_pitch,
                             l->gaze_norm_yaw);
    r->m[M_FLOOR_HEAD] = ang(gt_est[2], gt_est[3], l->head_norm_pitch,
                             l->head_norm_yaw);
    /* The readout reads eyes: none when the target's are closed. */
    if (ev->readout && !r->no_eye) {
        double rd[3] = {NAN, NAN, NAN};
        r->m[M_READ] = read_err(ev, ts, ev->out, st, r->pair, rd);
        r->m[M_READ_PITCH] = rd[0];
        r->m[M_READ_YAW] = rd[1];
        r->m[M_READ_SOFT] = rd[2];
        r->m[M_READ_FLOOR] = read_floor;
    }
    /* The truth the readout is held to, for signed errors downstream. */
    r->m[M_TRUE_PITCH] = ts->gaze_pitch * RAD_TO_DEG;
    r->m[M_TRUE_YAW] = ts->gaze_yaw * RAD_TO_DEG;
    r->m[M_THEAD_PITCH] = l->head_norm_pitch * RAD_TO_DEG;
    r->m[M_THEAD_YAW] = l->head_norm_yaw * RAD_TO_DEG;
    /* Every metric that should exist must be finite. */
    for (int k = 0; k < M_COUNT; k++) {
        int eye_metric = k == M_EYE_PSNR || k == M_EYE_SSIM;
        int angle = k <= M_FLOOR_HEAD;
        int read = k == M_READ || k == M_READ_FLOOR || k == M_READ_PITCH ||
                   k == M_READ_YAW || k == M_READ_SOFT;
        if ((eye_metric && r->no_eye) || (angle && !ev->est) ||
            (read && (!ev->readout || r->no_eye)))
            continue;
        r->nonfinite += !isfinite(r->m[k]);
    }
    r->nonfinite += bad_est;
}

static eval_row *new_row(evaluator *ev, int method, int pair)
{
    eval_row *r = &ev->rows[ev->nrows++];
    memset(r, 0, sizeof *r);
    r->method = method;
    r->pair = pair;
    r->fit_s = r->fit_psnr = r->render_ms = NAN;
    for (int k = 0; k < M_COUNT; k++)
        r->m[k] = NAN;
    return r;
}

/* Produces the method's output for one target into ev->out. */
static int produce(evaluator *ev, int method, const gs_subject *sub,
                   const gs_synth_sample *in, const gs_synth_sample *gt,
                   const gs_synth_scene *tscene, int identity, double *ms,
                   gs_error *err)
{
    size_t st = 3 * (size_t)ev->S;
    double t0 = cli_now_s();
    int rc = GS_OK;
    /* The model's target: the target's gaze (head frame) and its
     * normalized-camera head pose. */
    gs_view v = {0};
    v.gaze_pitch = tscene->gaze_pitch;
    v.gaze_yaw = tscene->gaze_yaw;
    v.use_head = 1;
    v.light_on_head = ev->light_on_head;
    memcpy(v.head_R, gt->labels.head_R, sizeof v.head_R);
    memcpy(v.head_t, gt->labels.head_t, sizeof v.head_t);
    if (method == EVAL_MODEL) {
        rc = gs_model_render(ev->rctx, ev->pool, sub, &v, ev->out, st, err);
    } else if (method == EVAL_ORACLE) {
        /* the shared model (never the fine-tuned or pruned copy) at the
         * training subject's own view: what training drew */
        gs_subject os;
        rc = gs_model_training_subject(ev->m, identity, tscene, &gt->labels,
                                       &os, err);
        if (!rc) {
            gs_view own = {.gaze_pitch = os.gaze_pitch, .gaze_yaw = os.gaze_yaw};
            rc = gs_model_render(ev->c, ev->pool, &os, &own, ev->out, st, err);
        }
    } else if (method == EVAL_TRANSFER) {
        rc = gs_model_render_transfer(ev->rctx, ev->pool, sub, in->rgb,
                                      in->stride, &v, ev->out, st, err);
    } else if (method == EVAL_WARP) {
        rc = gs_eval_warp_redirect(in, tscene->gaze_pitch, tscene->gaze_yaw,
                                   ev->out, st, err);
    } else {
        for (int y = 0; y < ev->S; y++)
            memcpy(ev->out + y * st, in->rgb + (size_t)y * in->stride, st);
    }
    *ms = 1000.0 * (cli_now_s() - t0);
    return rc;
}

/* Pixel weights from the input's eye region (gs_eval_regions, into
 * ev->eye and ev->face, which each target writes again before it reads
 * them): the eyes weighted W against the rest of the image, and above 1
 * the rest weighted 1/W instead. Into *mask (S*S, made on first use).
 * --fit-eye-weight and --finetune-eye-weight. */
static int eye_weights(evaluator *ev, const gs_synth_sample *in, double W,
                       uint8_t **mask, gs_error *err)
{
    const size_t n = (size_t)ev->S * ev->S;
    if (!*mask && !(*mask = malloc(n)))
        return gs_error_set(err, GS_ERR_NOMEM, "out of memory");
    int rc = gs_eval_regions(in, ev->eye, ev->face);
    if (rc)
        return rc;
    const uint8_t we = (uint8_t)lround(255.0 * fmin(W, 1.0)),
                  wr = (uint8_t)lround(255.0 / fmax(W, 1.0));
    for (size_t i = 0; i < n; i++)
        (*mask)[i] = ev->eye[i] ? we : wr;
    return GS_OK;
}

/* Fits are the slow part: each successful fit is kept as DIR/fits/N.bin
 * (gs_eval_fit_cache_write), keyed by what made it (the model, the fit's
 * options and the input: gs_eval_fit_key), and --reuse-fits takes it from
 * there instead of fitting again when the key is this run's. A fit of
 * another key is made again (counted in fits_stale). */
static int cached_fit(evaluator *ev, int input, const gs_synth_sample *in,
                      const gs_synth_scene *iscene, gs_subject *sub,
                      double *secs, gs_error *err)
{
    gs_fit_options o;
    gs_fit_options_default(&o);
    o.max_iters = ev->iters;
    o.lr_code = ev->lr_code;
    o.lr_colour = ev->lr_colour;
    o.bound_expression = ev->bound_expression;
    o.code_prior = ev->code_prior;
    o.id_prior = ev->id_prior;
    o.anneal = ev->anneal;
    o.mirror = ev->fit_mirror;
    if (ev->fit_eye_w != 1.0) {
        int rc = eye_weights(ev, in, ev->fit_eye_w, &ev->fitmask, err);
        if (rc)
            return rc;
        o.mask = ev->fitmask;
    }
    float code[GS_MODEL_MAX_CODE];
    uint8_t fixed[GS_MODEL_MAX_CODE];
    if (ev->true_code) {
        int rc = gs_model_scene_code(ev->m, iscene, ev->true_code, code,
                                     fixed, err);
        if (rc)
            return rc;
        o.code_start = code;
        o.code_fixed = ev->true_start ? NULL : fixed;
    }
    char path[4200];
    snprintf(path, sizeof path, "%s/fits/%05d.bin", ev->dir, input);
    const uint64_t key = gs_eval_fit_key(ev->m, &o, in);
    if (ev->reuse_fits) {
        int rd = gs_eval_fit_cache_read(path, key, sub, secs, NULL);
        if (rd == GS_OK) {
            ev->fits_reused++;
            return GS_OK;
        }
        if (rd == GS_ERR_STATE)
            ev->fits_stale++;
    }
    int rc = gs_eval_fit_sample_with(ev->c, ev->pool, in, &o, sub, secs, err);
    if (rc)
        return rc;
    if (gs_eval_fit_cache_write(path, key, sub, *secs, NULL))
        fprintf(stderr, "gazesplat eval: cannot write %s\n", path);
    return GS_OK;
}

/* DIR/images/PAIR_NAME.png, for looking at the outputs. */
static void save_png(const evaluator *ev, int pair, const char *name,
                     const uint8_t *rgb, size_t stride)
{
    char path[4200];
    snprintf(path, sizeof path, "%s/images/%05d_%s.png", ev->dir, pair, name);
    gs_io_image img = {ev->S, ev->S, stride, (unsigned char *)rgb};
    gs_error err = {0, ""};
    if (gs_io_image_write(path, &img, GS_IO_PNG, 0, &err))
        fprintf(stderr, "gazesplat eval: %s: %s\n", path, err.msg);
}

/* --finetune: the model copy gets the shared model's parameters back, is
 * fine-tuned on this input's fit, and a fresh context on it renders the
 * targets (a context's kept renders belong to the parameters it saw). */
static int finetune_input(evaluator *ev, const gs_synth_sample *in,
                          const gs_subject *sub, double *secs, float *psnr,
                          gs_error *err)
{
    gs_model_ctx_destroy(ev->ftctx);
    ev->ftctx = NULL;
    ev->rctx = NULL;
    int rc = gs_model_copy_params(ev->ftm, ev->m, err);
    gs_finetune_report rep;
    memset(&rep, 0, sizeof rep);
    gs_finetune_options fo = ev->fo;
    if (!rc && ev->ft_eye_w < 1.0 &&
        !(rc = eye_weights(ev, in, ev->ft_eye_w, &ev->ftmask, err)))
        fo.mask = ev->ftmask;
    if (!rc)
        rc = gs_model_finetune(ev->ftm, ev->pool, sub, in->rgb, in->stride,
                               &fo, &rep, err);
    *secs = rep.seconds;
    if (!rc && !(ev->ftctx = gs_model_ctx_create(ev->ftm)))
        rc = gs_error_set(err, GS_ERR_NOMEM, "out of memory");
    if (!rc)
        rc = gs_model_ctx_set_render_options(ev->ftctx, &ev->ro, err);
    if (rc)
        return rc;
    ev->rctx = ev->ftctx;
    *psnr = rep.psnr_best;
    ev->ft_n++;
    ev->ft_s += rep.seconds;
    ev->ft_psnr_first += rep.psnr_first;
    ev->ft_psnr_best += rep.psnr_best;
    return GS_OK;
}

/* One input and all its targets [first, last), every method. */
static int eval_input(evaluator *ev, const gs_eval_pairs *ps, int first,
                      int last, FILE *csv)
{
    gs_synth_scene iscene, tscene;
    gs_synth_sample in = {0}, gt = {0};
    gs_error err = {0, ""};
    gs_eval_pair_scenes(&ps->p[first], &iscene, &tscene);
    int rc = gs_eval_render_scene(&iscene, ev->S, ev->d_n, ev->focal,
                                  ev->pool, &in, &err);
    if (rc) {
        fprintf(stderr, "gazesplat eval: input %d: %s\n", ps->p[first].input,
                err.msg);
        return rc;
    }
    gs_subject sub;
    memset(&sub, 0, sizeof sub);
    int fit_status = EVAL_ROW_OK;
    double fit_s = NAN;
    int fits = 0;
    for (int k = 0; k < ev->nmethods; k++)
        fits |= eval_method_fits(ev->methods[k]);
    if (fits) {
        rc = cached_fit(ev, ps->p[first].input, &in, &iscene, &sub, &fit_s,
                        &err);
        if (rc) {
            fit_status = rc == GS_ERR_NONFINITE ? EVAL_ROW_DIVERGED
                                                : EVAL_ROW_ERROR;
            fprintf(stderr, "gazesplat eval: input %d: fit: %s\n",
                    ps->p[first].input, err.msg);
        }
    }
    float fit_psnr = sub.fit_psnr;
    if (fit_status == EVAL_ROW_OK && ev->fo.iters > 0 && fits) {
        double ft_s = 0;
        rc = finetune_input(ev, &in, &sub, &ft_s, &fit_psnr, &err);
        if (rc) {
            fit_status = rc == GS_ERR_NONFINITE ? EVAL_ROW_DIVERGED
                                                : EVAL_ROW_ERROR;
            fprintf(stderr, "gazesplat eval: input %d: fine-tune: %s\n",
                    ps->p[first].input, err.msg);
        }
        fit_s += ft_s;
    }
    for (int i = first; i < last; i++) {
        gs_eval_pair_scenes(&ps->p[i], &iscene, &tscene);
        rc = gs_eval_render_scene(&tscene, ev->S, ev->d_n, ev->focal,
                                  ev->pool, &gt, &err);
        float gt_est[4];
        int bad_gt = rc ? 0 : predict(ev, gt.rgb, gt_est);
        if (!rc)
            rc = gs_eval_regions(&gt, ev->eye, ev->face);
        double read_floor = NAN;
        if (!rc && ev->readout && gs_eval_mask_count(ev->eye, ev->S, ev->S))
            read_floor = read_err(ev, &tscene, gt.rgb, gt.stride, i, NULL);
        if (!rc && i < ev->save_images) {
            save_png(ev, i, "input", in.rgb, in.stride);
            save_png(ev, i, "target", gt.rgb, gt.stride);
        }
        if (rc)
            fprintf(stderr, "gazesplat eval: pair %d: ground truth: %s\n", i,
                    err.msg[0] ? err.msg : gs_strerror(rc));
        for (int k = 0; k < ev->nmethods; k++) {
            int mth = ev->methods[k];
            eval_row *r = new_row(ev, mth, i);
            if (eval_method_fits(mth)) {
                r->fit_s = fit_s;
                r->fit_row = i == first;
                r->fit_psnr = fit_status == EVAL_ROW_OK ? fit_psnr : NAN;
                r->status = fit_status;
            }
            if (rc)
                r->status = EVAL_ROW_ERROR;
            if (r->status == EVAL_ROW_OK) {
                gs_error e2 = {0, ""};
                if (produce(ev, mth, &sub, &in, &gt, &tscene,
                            ps->p[i].identity, &r->render_ms, &e2)) {
                    r->status = EVAL_ROW_ERROR;
                    fprintf(stderr, "gazesplat eval: pair %d %s: %s\n", i,
                            eval_method_names[mth], e2.msg);
                } else {
                    if (i < ev->save_images)
                        save_png(ev, i, eval_method_names[mth], ev->out,
                                 3 * (size_t)ev->S);
                    measure(ev, &gt, &tscene, gt_est, read_floor, r);
                    r->nonfinite += bad_gt;
                }
            }
            eval_csv_row(csv, r, &ps->p[i]);
        }
        gs_synth_sample_free(&gt);
        rc = GS_OK;
    }
    fflush(csv);
    gs_synth_sample_free(&in);
    return GS_OK;
}

/* --prune K or P% */
static int parse_prune(const char *s, evaluator *ev)
{
    size_t n = strlen(s);
    if (n > 1 && s[n - 1] == '%') {
        char num[64];
        float p;
        if (n > sizeof num)
            return -1;
        memcpy(num, s, n - 1);
        num[n - 1] = '\0';
        if (cli_parse_floats(num, &p, 1) || !(p > 0.0f && p <= 100.0f))
            return -1;
        ev->prune_pct = p;
        return 0;
    }
    return cli_parse_long(s, 1, 100000000L, &ev->prune_k);
}

static int parse_methods(const char *s, evaluator *ev)
{
    ev->nmethods = 0;
    while (*s) {
        size_t len = strcspn(s, ",");
        int k = 0;
        while (k < EVAL_METHODS && (strlen(eval_method_names[k]) != len ||
                                    strncmp(eval_method_names[k], s, len)))
            k++;
        if (k == EVAL_METHODS)
            return -1;
        for (int j = 0; j < ev->nmethods; j++)
            if (ev->methods[j] == k)
                return -1;
        ev->methods[ev->nmethods++] = k;
        s += len;
        if (*s == ',' && *++s == '\0')
            return -1;
    }
    return ev->nmethods ? 0 : -1;
}

static int make_dir(const char *path)
{
    struct stat st;
    return mkdir(path, 0777) == 0 ||
           (stat(path, &st) == 0 && S_ISDIR(st.st_mode));
}

/* Number of inputs to run and the pair count they cover. */
static int count_inputs(const gs_eval_pairs *ps, long limit, int *npairs)
{
    int inputs = 0, i = 0;
    while (i < ps->n && (limit <= 0 || inputs < limit)) {
        int in = ps->p[i].input;
        while (i < ps->n && ps->p[i].input == in)
            i++;
        inputs++;
    }
    *npairs = i;
    return inputs;
}

static int evaluate(evaluator *ev, const cli_opt *o, const gs_eval_pairs *ps,
                    long limit, eval_run_info *info)
{
    const cli_command *cmd = &cli_eval_command;
    int npairs;
    info->inputs = count_inputs(ps, limit, &npairs);
    char path[4096];
    snprintf(path, sizeof path, "%s/pairs.csv", o[O_OUT].value);
    FILE *csv = fopen(path, "w");
    if (!csv)
        return cli_fail(cmd, "cannot write %s", path);
    eval_csv_header(csv);
    ev->rows = calloc((size_t)npairs * ev->nmethods + 1, sizeof *ev->rows);
    size_t S = (size_t)ev->S;
    ev->out = malloc(3 * S * S);
    ev->eye = malloc(S * S);
    ev->face = malloc(S * S);
    int rc = CLI_OK;
    if (!ev->rows || !ev->out || !ev->eye || !ev->face)
        rc = cli_fail(cmd, "out of memory");
    cli_progress_t prog;
    cli_progress_start(&prog);
    for (int i = 0, done = 0; !rc && i < npairs; done++) {
        int j = i;
        while (j < npairs && ps->p[j].input == ps->p[i].input)
            j++;
        eval_input(ev, ps, i, j, csv);
        i = j;
        cli_progress(&prog, j == npairs, "gazesplat eval: input %d/%d, %.0f s", done + 1, info->inputs,
                     cli_now_s() - prog.start);
    }
    cli_progress_done(&prog);
    if (fclose(csv) && !rc)
        rc = cli_fail(cmd, "cannot write %s", path);
    snprintf(path, sizeof path, "%s/summary.md", o[O_OUT].value);
    FILE *md = rc ? NULL : fopen(path, "w");
    if (!rc && !md)
        rc = cli_fail(cmd, "cannot write %s", path);
    if (md) {
        info->fits_reused = ev->fits_reused;
        info->fits_stale = ev->fits_stale;
        info->ft_n = ev->ft_n;
        if (ev->ft_n) {
            info->ft_s = ev->ft_s / ev->ft_n;
            info->ft_psnr_first = ev->ft_psnr_first / ev->ft_n;
            info->ft_psnr_best = ev->ft_psnr_best / ev->ft_n;
        }
        eval_summary(md, info, ev->rows, ev->nrows, ps, ev->methods,
                     ev->nmethods);
        if (fclose(md))
            rc = cli_fail(cmd, "cannot write %s", path);
        else
            printf("gazesplat eval: %d pairs x %d methods -> %s/pairs.csv, "
                   "%s\n", npairs, ev->nmethods, o[O_OUT].value, path);
    }
    free(ev->rows);
    free(ev->out);
    free(ev->eye);
    free(ev->face);
    return rc;
}

static int read_pairs(const char *path, gs_eval_pairs *ps)
{
    gs_error err = {0, ""};
    FILE *f = fopen(path, "r");
    if (!f)
        return cli_fail(&cli_eval_command, "cannot open %s", path);
    int rc = gs_eval_pairs_read(f, ps, &err);
    fclose(f);
    if (rc)
        return cli_fail(&cli_eval_command, "%s: %s", path, err.msg);
    return CLI_OK;
}

/* The context that renders the model method: the fit's own, or one on
 * the pruned model; then the render options. */
static int render_setup(evaluator *ev, eval_run_info *info)
{
    const cli_command *cmd = &cli_eval_command;
    gs_error err = {0, ""};
    gs_model_info mi;
    gs_model_get_info(ev->m, &mi);
    long k = ev->prune_k;
    if (ev->prune_pct > 0) {
        k = lround(ev->prune_pct / 100.0 * mi.n_face);
        k = k < 1 ? 1 : k;
    }
    k = k > 0 && k < mi.n_face ? k : mi.n_face;
    ev->rctx = ev->c;
    if (ev->fo.iters > 0) {
        if (k < mi.n_face)
            return cli_usage_error(cmd, "--finetune does not go with --prune");
        if (gs_model_clone(ev->m, &ev->ftm, &err))
            return cli_fail(cmd, "--finetune: %s", err.msg);
    }
    if (k < mi.n_face) {
        if (gs_model_prune(ev->m, ev->pool, (int)k, &ev->pm, &err))
            return cli_fail(cmd, "--prune: %s", err.msg);
        ev->rctx = gs_model_ctx_create(ev->pm);
        if (!ev->rctx)
            return cli_fail(cmd, "out of memory");
    }
    if (gs_model_ctx_set_render_options(ev->rctx, &ev->ro, &err))
        return cli_usage_error(cmd, "--feature-scale: %s", err.msg);
    info->face_kept = (int)k;
    info->n_face = mi.n_face;
    info->feature_scale = ev->ro.feature_scale;
    info->supersample = mi.supersample;
    info->eye_direct = mi.eye_direct;
    info->full_render = ev->ro.full;
    info->transfer_head_weight = ev->ro.transfer_head_weight;
    info->transfer_eye_weight = ev->ro.transfer_eye_weight;
    info->transfer_eye_warp_deg = ev->ro.transfer_eye_warp_deg;
    info->transfer_eye_warp_head = ev->ro.transfer_eye_warp_head;
    info->light_on_head = ev->light_on_head;
    return CLI_OK;
}

static int run_checked(const cli_opt *o, evaluator *ev, long limit,
                       long threads, eval_run_info *info)
{
    const cli_command *cmd = &cli_eval_command;
    gs_eval_pairs ps = {0, NULL};
    gs_error err = {0, ""};
    int rc = read_pairs(o[O_PAIRS].value, &ps);
    if (rc)
        return rc;
    char fits[4200];
    snprintf(fits, sizeof fits, "%s/fits", o[O_OUT].value);
    if (!make_dir(o[O_OUT].value) || !make_dir(fits))
        rc = cli_fail(cmd, "cannot create %s", fits);
    snprintf(fits, sizeof fits, "%s/images", o[O_OUT].value);
    if (!rc && ev->save_images && !make_dir(fits))
        rc = cli_fail(cmd, "cannot create %s", fits);
    if (!rc && gs_model_load(o[O_MODEL].value, &ev->m, &err))
        rc = cli_fail(cmd, "%s: %s", o[O_MODEL].value, err.msg);
    if (!rc && o[O_EST].value &&
        eval_estimator_load(o[O_EST].value, &ev->est, &err))
        rc = cli_fail(cmd, "%s: %s", o[O_EST].value, err.msg);
    if (!rc) {
        gs_model_info mi;
        gs_model_get_info(ev->m, &mi);
        ev->S = mi.image_size;
        ev->focal = mi.focal;
        ev->d_n = mi.distance_mm;
        info->image_size = mi.image_size;
        if (ev->code_prior == GS_FIT_CODE_PRIOR_MODEL) {
            ev->code_prior = mi.fit_code_prior; /* the report names it */
            info->code_prior = mi.fit_code_prior;
            info->code_prior_model = 1;
        }
        if (ev->lr_code == 0) { /* no --fit-lr: the model's rate, if it names one */
            info->fit_lr_code_model = mi.fit_code_rate > 0;
            ev->lr_code = gs_model_fit_code_rate(ev->m, 0);
            info->fit_lr_code = ev->lr_code;
        }
        int oracle = 0, top = eval_pairs_identities(&ps) - 1;
        for (int k = 0; k < ev->nmethods; k++)
            oracle |= ev->methods[k] == EVAL_ORACLE;
        /* the oracle and --true-code id read the learned codes */
        const char *learned = oracle ? "--method oracle"
                              : ev->true_code & GS_SCENE_CODE_ID ? "--true-code id"
                                                                 : NULL;
        if (learned && ps.n > 0 &&
            gs_synth_seed_split(ps.p[0].identity_seed) != GS_SYNTH_TRAIN)
            rc = cli_usage_error(cmd, "%s: the pairs must be of "
                                      "training identities (--make-pairs FILE "
                                      "--split train)", learned);
        else if (learned && top >= mi.n_train_ids)
            rc = cli_usage_error(cmd, "%s: the pairs reach training "
                                      "identity %d; %s holds codes for %d",
                                 learned, top, o[O_MODEL].value, mi.n_train_ids);
    }
    if (!rc) {
        ev->c = gs_model_ctx_create(ev->m);
        ev->pool = gs_pool_create((int)threads);
        if (!ev->c || !ev->pool)
            rc = cli_fail(cmd, "out of memory");
    }
    if (!rc)
        rc = render_setup(ev, info);
    if (!rc)
        rc = evaluate(ev, o, &ps, limit, info);
    gs_pool_destroy(ev->pool);
    if (ev->rctx != ev->c && ev->rctx != ev->ftctx)
        gs_model_ctx_destroy(ev->rctx);
    gs_model_ctx_destroy(ev->ftctx);
    gs_model_destroy(ev->ftm);
    free(ev->ftmask);
    free(ev->fitmask);
    gs_model_ctx_destroy(ev->c);
    gs_model_destroy(ev->pm);
    eval_estimator_free(ev->est);
    gs_model_destroy(ev->m);
    gs_eval_pairs_free(&ps);
    return rc;
}

_Static_assert(CLI_NOPTS(eval_opts) == O_N, "eval_opts: one entry per option index");

static int run_eval(const cli_command *cmd, cli_opt *o)
{
    int rc = CLI_OK;
    if (o[O_MAKE].value) {
        for (int k = 0; k < O_MAKE; k++)
            if (o[k].value)
                return cli_usage_error(cmd, "--make-pairs takes only "
                                       "--identities, --inputs, --targets, "
                                       "--seed and --split");
        return make_pairs(o);
    }
    for (int k = O_IDS; k < O_N; k++)
        if (o[k].value)
            return cli_usage_error(cmd, "%s goes with --make-pairs",
                                   o[k].name);
    if (!o[O_MODEL].value || !o[O_PAIRS].value || !o[O_OUT].value)
        return cli_usage_error(cmd, "--model, --pairs and --out are needed");
    evaluator ev;
    memset(&ev, 0, sizeof ev);
    ev.code_prior = GS_FIT_CODE_PRIOR_MODEL; /* --code-prior replaces it */
    ev.iters = 200;
    ev.nmethods = 1;
    long limit = 0, threads = 2, iters = 200;
    if (o[O_METHOD].value && parse_methods(o[O_METHOD].value, &ev))
        return cli_usage_error(cmd, "--method: want a list of model, transfer, "
                               "warp, identity; got '%s'", o[O_METHOD].value);
    if (o[O_LIMIT].value && cli_parse_long(o[O_LIMIT].value, 1, 100000000L,
                                           &limit))
        return cli_usage_error(cmd, "--limit-inputs: want 1 or more");
    if (o[O_ITERS].value && cli_parse_long(o[O_ITERS].value, 1, 100000,
                                           &iters))
        return cli_usage_error(cmd, "--iters: want 1..100000");
    if (o[O_THREADS].value && cli_parse_long(o[O_THREADS].value, 1, 256,
                                             &threads))
        return cli_usage_error(cmd, "--threads: want 1..256");
    long save = 0;
    if (o[O_SAVE].value && cli_parse_long(o[O_SAVE].value, 0, 100000, &save))
        return cli_usage_error(cmd, "--save-images: want 0..100000");
    ev.save_images = (int)save;
    if (o[O_PRUNE].value && parse_prune(o[O_PRUNE].value, &ev))
        return cli_usage_error(cmd, "--prune: want a count K >= 1 or a "
                               "percentage P%% in (0, 100]; got '%s'",
                               o[O_PRUNE].value);
    gs_model_render_options_default(&ev.ro);
    float fscale = 1.0f;
    if (o[O_FSCALE].value && (cli_parse_floats(o[O_FSCALE].value, &fscale, 1) ||
                              !((fscale > 0.0f && fscale <= 1.0f) ||
                                fscale == 2.0f || fscale == 3.0f ||
                                fscale == 4.0f)))
        return cli_usage_error(cmd, "--feature-scale: want a number in "
                               "(0, 1], or 2, 3 or 4 (supersampled); got "
                               "'%s'", o[O_FSCALE].value);
    ev.ro.feature_scale = fscale;
    ev.ro.full = o[O_FULL].value != NULL;
    if ((rc = cli_parse_unit(cmd, "--transfer-head-weight", o[O_XHW].value,
                             &ev.ro.transfer_head_weight)) ||
        (rc = cli_parse_unit(cmd, "--transfer-eye-weight", o[O_XEW].value,
                             &ev.ro.transfer_eye_weight)) ||
        (rc = cli_parse_range(cmd, "--transfer-eye-warp", o[O_XWARP].value, 0.0, 90.0,
                              CLI_WARP_WANT, &ev.ro.transfer_eye_warp_deg)))
        return rc;
    if (o[O_XWARP_HEAD].value) {
        long v;
        if (cli_parse_long(o[O_XWARP_HEAD].value, 0, 1, &v))
            return cli_usage_error(cmd, "--transfer-eye-warp-head: want 0 or 1");
        ev.ro.transfer_eye_warp_head = (int)v;
    }
    ev.light_on_head = o[O_LOH].value != NULL;
    if ((rc = cli_parse_finetune(cmd, o[O_FT].value, o[O_FT_PARTS].value, o[O_FT_LR].value, NULL,
                                 o[O_FT_OUTLINE].value, o[O_FT_MIRROR].value,
                                 &ev.fo)))
        return rc;
    ev.ft_eye_w = 1.0;
    if (o[O_FT_EYE].value) {
        float w;
        if (cli_parse_floats(o[O_FT_EYE].value, &w, 1) || !(w >= 0 && w <= 1))
            return cli_usage_error(cmd, "--finetune-eye-weight: want 0..1");
        ev.ft_eye_w = w;
    }
    if ((o[O_FT_PARTS].value || o[O_FT_LR].value || o[O_FT_EYE].value) &&
        !ev.fo.iters)
        return cli_usage_error(cmd, "--finetune-parts, --finetune-lr and "
                               "--finetune-eye-weight go with --finetune N");
    ev.iters = (int)iters;
    ev.lr_code = 0; /* the model's (config.fit_code_rate), resolved on loading */
    ev.lr_colour = GS_FIT_LR_COLOUR_DEFAULT;
    if (o[O_FIT_LR].value && cli_parse_fit_lr(o[O_FIT_LR].value, &ev.lr_code,
                                          &ev.lr_colour))
        return cli_usage_error(cmd, "--fit-lr: want CODE[,COLOUR], each in "
                               "(0, 10]; got '%s'", o[O_FIT_LR].value);
    if (o[O_TRUE_CODE].value && parse_true_code(o[O_TRUE_CODE].value, &ev.true_code))
        return cli_usage_error(cmd, "--true-code: want a list of expr, light, id; "
                               "got '%s'", o[O_TRUE_CODE].value);
    ev.true_start = o[O_TRUE_START].value != NULL;
    if (ev.true_start && !ev.true_code)
        return cli_usage_error(cmd, "--true-code-start: give --true-code LIST "
                                    "as well (the parts that start the fit)");
    ev.bound_expression = o[O_BOUND_EXPR].value != NULL;
    if ((rc = cli_parse_range(cmd, "--code-prior", o[O_CODE_PRIOR].value, 0.0, 10.0,
                              "a weight in [0, 10] (0: no prior)", &ev.code_prior)) ||
        (rc = cli_parse_range(cmd, "--id-prior", o[O_ID_PRIOR].value, 0.0, 10.0,
                              "a weight in [0, 10] (0: no prior)", &ev.id_prior)))
        return rc;
    if (o[O_ANNEAL].value) {
        long v;
        if (cli_parse_long(o[O_ANNEAL].value, 0, GS_FIT_ANNEAL_MAX, &v))
            return cli_usage_error(cmd, "--fit-anneal: want 0..%d halvings, "
                                        "got '%s'", GS_FIT_ANNEAL_MAX,
                                   o[O_ANNEAL].value);
        ev.anneal = (int)v;
    }
    if (o[O_FIT_MIRROR].value) {
        long v;
        if (cli_parse_long(o[O_FIT_MIRROR].value, 0, 1, &v))
            return cli_usage_error(cmd, "--fit-mirror: want 0 or 1, got '%s'",
                                   o[O_FIT_MIRROR].value);
        ev.fit_mirror = (int)v;
    }
    ev.fit_eye_w = 1.0;
    if (o[O_FIT_EYE].value) {
        float w;
        if (cli_parse_floats(o[O_FIT_EYE].value, &w, 1) || !(w >= 0 && w <= 16))
            return cli_usage_error(cmd, "--fit-eye-weight: want 0..16, got '%s'",
                                   o[O_FIT_EYE].value);
        ev.fit_eye_w = w;
    }
    ev.dir = o[O_OUT].value;
    ev.reuse_fits = o[O_REUSE].value != NULL;
    ev.readout = o[O_READ].value != NULL;
    gs_eval_readout_options_default(&ev.read_opts);
    if (o[O_READ_SHIFT].value && !ev.readout)
        return cli_usage_error(cmd, "--readout-shift goes with --readout");
    if ((rc = cli_parse_range(cmd, "--readout-shift", o[O_READ_SHIFT].value, 0.0, 8.0,
                              "pixels in [0, 8] (0: no alignment)",
                              &ev.read_opts.max_shift_px)))
        return rc;
    if (o[O_READ_SOFT].value && !ev.readout)
        return cli_usage_error(cmd, "--readout-soft goes with --readout");
    if ((rc = cli_parse_range(cmd, "--readout-soft", o[O_READ_SOFT].value, 0.0, 2.5,
                              "pixels in [0, 2.5] (0: off)",
                              &ev.read_opts.soft_max_px)))
        return rc;
    char line[2048];
    cli_command_line(line, sizeof line);
    eval_run_info info;
    memset(&info, 0, sizeof info);
    info.model = o[O_MODEL].value;
    info.estimator = o[O_EST].value;
    info.readout = ev.readout;
    info.readout_shift = ev.read_opts.max_shift_px;
    info.readout_soft = ev.read_opts.soft_max_px;
    info.pairs = o[O_PAIRS].value;
    info.command = line;
    info.threads = (int)threads;
    info.iters = (int)iters;
    info.fit_lr_code = ev.lr_code;
    info.fit_lr_colour = ev.lr_colour;
    info.true_code = ev.true_code;
    info.true_start = ev.true_start;
    info.bound_expression = ev.bound_expression;
    info.code_prior = ev.code_prior;
    info.id_prior = ev.id_prior;
    info.anneal = ev.anneal;
    info.fit_mirror = ev.fit_mirror;
    info.fit_eye_w = ev.fit_eye_w;
    info.feature_scale = 1.0;
    info.supersample = 1;
    info.ft_iters = ev.fo.iters;
    info.ft_parts = ev.fo.parts;
    info.ft_lr = ev.fo.lr;
    info.ft_eye_w = ev.ft_eye_w;
    info.ft_outline = ev.fo.outline_px;
    info.ft_mirror = ev.fo.mirror;
    return run_checked(o, &ev, limit, threads, &info);
}
