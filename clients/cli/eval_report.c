/* gazesplat eval: the per-pair CSV and the Markdown summary. */
#include <math.h>
#include <stdarg.h>
#include <stdlib.h>
#include <string.h>

#include "eval_report.h"
#include "gazesplat/train.h"

const char *const eval_method_names[EVAL_METHODS] = {
    "model", "warp", "identity", "transfer", "oracle"};
const char *const eval_metric_names[M_COUNT] = {
    "gaze_err_deg", "gaze_err_label_deg", "head_err_deg",
    "head_err_label_deg", "est_gt_gaze_err_deg", "est_gt_head_err_deg",
    "psnr", "ssim", "eye_psnr", "eye_ssim", "id_psnr", "id_ssim",
    "read_gaze_err_deg", "read_floor_gaze_deg", "read_pitch_deg",
    "read_yaw_deg", "target_pitch_deg", "target_yaw_deg",
    "target_head_pitch_deg", "target_head_yaw_deg", "read_soft_px"};

void eval_csv_header(FILE *f)
{
    fputs("method,pair,input,identity,gaze_change_deg,head_deg,head_change,"
          "head_change_deg,narrowed,harsh,status,fit_s,fit_psnr,render_ms",
          f);
    for (int k = 0; k < M_COUNT; k++)
        fprintf(f, ",%s", eval_metric_names[k]);
    fputc('\n', f);
}

static void put_num(FILE *f, double v, int prec)
{
    if (isfinite(v))
        fprintf(f, ",%.*f", prec, v);
    else
        fputs(isnan(v) ? "," : ",inf", f);
}

void eval_csv_row(FILE *f, const eval_row *r, const gs_eval_pair *p)
{
    static const char *const st[3] = {"ok", "diverged", "error"};
    fprintf(f, "%s,%d,%d,%d,%.3f,%.3f,%d,%.3f,%d,%d,%s",
            eval_method_names[r->method], r->pair, p->input, p->identity,
            p->gaze_change_deg, p->head_deg, p->head_change,
            p->head_change_deg, p->narrowed, p->harsh, st[r->status]);
    put_num(f, r->fit_s, 3);
    put_num(f, r->fit_psnr, 3);
    put_num(f, r->render_ms, 2);
    for (int k = 0; k < M_COUNT; k++)
        put_num(f, r->m[k], 4);
    fputc('\n', f);
}

/* Row groups of the summary: a predicate on the pair. */
enum { G_ALL, G_GAZE0, G_GAZE1, G_GAZE2, G_HEAD0, G_HEAD1, G_HEAD2, G_HEAD3,
       G_SAME_HEAD, G_NEW_HEAD, G_NARROWED, G_HARSH, G_COUNT };
static const char *const group_names[G_COUNT] = {
    "**all pairs**", "gaze change 0-15°", "gaze change 15-30°",
    "gaze change 30-50°", "head pose 0-15°", "head pose 15-30°",
    "head pose 30-50°", "head pose 50°+", "gaze only (same head pose)",
    "gaze and head pose change", "narrowed / blinking eyes",
    "harsh lighting"};

static int in_group(int g, const gs_eval_pair *p)
{
    switch (g) {
    case G_ALL: return 1;
    case G_GAZE0: case G_GAZE1: case G_GAZE2:
        return gs_eval_angle_bin(p->gaze_change_deg) == g - G_GAZE0;
    case G_HEAD0: case G_HEAD1: case G_HEAD2: case G_HEAD3:
        return gs_eval_angle_bin(p->head_deg) == g - G_HEAD0;
    case G_SAME_HEAD: return !p->head_change;
    case G_NEW_HEAD: return p->head_change;
    case G_NARROWED: return p->narrowed;
    case G_HARSH: return p->harsh;
    }
    return 0;
}

typedef struct stats {
    int n;                /* pairs in the group */
    int cnt[M_COUNT];     /* finite values per metric */
    double sum[M_COUNT];
} stats;

static void gather(const eval_row *rows, int n, const gs_eval_pairs *ps,
                   int method, int g, stats *s)
{
    memset(s, 0, sizeof *s);
    for (int i = 0; i < n; i++) {
        const eval_row *r = &rows[i];
        if (r->method != method || !in_group(g, &ps->p[r->pair]))
            continue;
        s->n++;
        for (int k = 0; k < M_COUNT; k++)
            if (isfinite(r->m[k])) {
                s->cnt[k]++;
                s->sum[k] += r->m[k];
            }
    }
}

static void put_mean(FILE *f, const stats *s, int k, int prec)
{
    if (s->cnt[k])
        fprintf(f, " %.*f |", prec, s->sum[k] / s->cnt[k]);
    else
        fputs(" – |", f);
}

/* The table's columns; the last two only with --readout. */
static const int table_metrics[] = {M_GAZE, M_GAZE_LABEL, M_FLOOR_GAZE,
                                    M_HEAD, M_HEAD_LABEL, M_FLOOR_HEAD,
                                    M_PSNR, M_SSIM, M_EYE_PSNR, M_EYE_SSIM,
                                    M_ID_PSNR, M_ID_SSIM, M_READ,
                                    M_READ_FLOOR};
#define NTABLE (int)(sizeof table_metrics / sizeof table_metrics[0])
#define NTABLE_PLAIN (NTABLE - 2)

static void table_header(FILE *f, const char *first, int readout)
{
    fprintf(f, "| %s | n | gaze° | gaze° vs label | floor gaze° | head° | "
               "head° vs label | floor head° | PSNR | SSIM | eye PSNR | "
               "eye SSIM | id PSNR | id SSIM |%s\n|---|---:|", first,
            readout ? " read gaze° | read floor° |" : "");
    for (int k = 0; k < (readout ? NTABLE : NTABLE_PLAIN); k++)
        fputs("---:|", f);
    fputc('\n', f);
}

static void table_row(FILE *f, const char *name, const stats *s, int readout)
{
    fprintf(f, "| %s | %d |", name, s->n);
    for (int k = 0; k < (readout ? NTABLE : NTABLE_PLAIN); k++) {
        int m = table_metrics[k];
        put_mean(f, s, m, m == M_SSIM || m == M_EYE_SSIM || m == M_ID_SSIM
                              ? 4 : 2);
    }
    fputc('\n', f);
}

static int cmp_double(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

/* --readout: the spread of the readout's errors, gaze only and with a
 * head change (means hide a few gross misses). */
static void read_line(FILE *f, const eval_row *rows, int n,
                      const gs_eval_pairs *ps, int method)
{
    double *v = malloc(sizeof *v * (size_t)(n + 1));
    if (!v)
        return;
    char part[2][160];
    int any = 0;
    for (int hc = 0; hc < 2; hc++) {
        int k = 0, w2 = 0, w5 = 0;
        for (int i = 0; i < n; i++) {
            const eval_row *r = &rows[i];
            if (r->method != method || ps->p[r->pair].head_change != hc ||
                !isfinite(r->m[M_READ]))
                continue;
            v[k++] = r->m[M_READ];
            w2 += r->m[M_READ] <= 2.0;
            w5 += r->m[M_READ] <= 5.0;
        }
        any += k;
        if (!k) {
            snprintf(part[hc], sizeof part[hc], "–");
            continue;
        }
        qsort(v, (size_t)k, sizeof *v, cmp_double);
        double med = k % 2 ? v[k / 2] : 0.5 * (v[k / 2 - 1] + v[k / 2]);
        snprintf(part[hc], sizeof part[hc], "median %.2f°, within 2° %.0f %%, "
                 "within 5° %.0f %% (%d pairs)", med, 100.0 * w2 / k,
                 100.0 * w5 / k, k);
    }
    if (any)
        fprintf(f, "- readout: gaze only %s; with a head change %s\n",
                part[0], part[1]);
    free(v);
}

/* Counts and timings of one method. */
static void method_counts(FILE *f, const eval_row *rows, int n,
                          const gs_eval_pairs *ps, int method)
{
    int pairs = 0, ok = 0, div = 0, errs = 0, nonf = 0, noeye = 0, nfit = 0;
    int nr[2] = {0, 0};
    double render = 0, rs[2] = {0, 0};
    double *fits = malloc(sizeof(double) * (size_t)(n + 1));
    for (int i = 0; i < n; i++) {
        const eval_row *r = &rows[i];
        if (r->method != method)
            continue;
        pairs++;
        ok += r->status == EVAL_ROW_OK;
        div += r->status == EVAL_ROW_DIVERGED;
        errs += r->status == EVAL_ROW_ERROR;
        nonf += r->nonfinite;
        noeye += r->no_eye;
        if (isfinite(r->render_ms)) {
            int hc = ps->p[r->pair].head_change != 0;
            render += r->render_ms;
            rs[hc] += r->render_ms;
            nr[hc]++;
        }
        if (fits && r->fit_row && isfinite(r->fit_s))
            fits[nfit++] = r->fit_s;
    }
    fprintf(f, "- pairs %d: evaluated %d, **diverged fits %d, errors %d, "
               "non-finite outputs %d** (goal: zero); closed eyes (no eye "
               "region, eye metrics n/a) %d\n", pairs, ok, div, errs, nonf,
            noeye);
    if (nfit) {
        qsort(fits, (size_t)nfit, sizeof *fits, cmp_double);
        double s = 0;
        for (int i = 0; i < nfit; i++)
            s += fits[i];
        fprintf(f, "- fit: %d fits, mean %.2f s, median %.2f s, max %.2f s\n",
                nfit, s / nfit, fits[nfit / 2], fits[nfit - 1]);
    }
    read_line(f, rows, n, ps, method);
    if (ok && render > 0 && method != EVAL_IDENTITY) {
        char g[32] = "–", h[32] = "–";
        if (nr[0])
            snprintf(g, sizeof g, "%.1f ms", rs[0] / nr[0]);
        if (nr[1])
            snprintf(h, sizeof h, "%.1f ms", rs[1] / nr[1]);
        fprintf(f, "- render: mean %.1f ms per image, %.1f images/s (gaze "
                   "only: %s; with a head change: %s)\n", render / ok,
                1000.0 * ok / render, g, h);
    }
    free(fits);
}

/* printf onto the end of the string in buf (n bytes), cut to fit. */
static void append(char *buf, size_t n, const char *fmt, ...)
    __attribute__((format(printf, 3, 4)));
static void append(char *buf, size_t n, const char *fmt, ...)
{
    size_t at = strlen(buf);
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(buf + at, n - at, fmt, ap);
    va_end(ap);
}

void eval_summary(FILE *f, const eval_run_info *info, const eval_row *rows,
                  int n, const gs_eval_pairs *ps, const int *methods,
                  int nmethods)
{
    fprintf(f, "# gazesplat eval\n\n```sh\n%s\n```\n\n", info->command);
    char prior[256] = "";
    if (info->code_prior > 0)
        append(prior, sizeof prior, ", code prior weight %g (%s)",
               info->code_prior,
               info->code_prior_model ? "the model's" : "--code-prior");
    if (info->id_prior > 0)
        append(prior, sizeof prior, ", identity prior weight %g (--id-prior)",
               info->id_prior);
    if (info->anneal > 0)
        append(prior, sizeof prior, ", the rates halved at a plateau up to %d "
               "times (--fit-anneal)", info->anneal);
    if (info->fit_mirror)
        append(prior, sizeof prior, ", with the mirrored view (--fit-mirror 1)");
    if (info->fit_eye_w != 1.0)
        append(prior, sizeof prior, ", the input's eyes weighted %g "
               "(--fit-eye-weight)", info->fit_eye_w);
    fprintf(f, "- model: `%s` (%d px); pairs: `%s`, %d inputs; fit "
               "iterations cap %d, rates %g (code%s) and %g (colour)%s%s; %d "
               "threads\n", info->model, info->image_size, info->pairs,
            info->inputs, info->iters, info->fit_lr_code,
            info->fit_lr_code_model ? ", the model's" : "", info->fit_lr_colour,
            info->bound_expression ? ", expression kept in its training "
                                     "range (--bound-expression)"
                                   : "",
            prior, info->threads);
    if (ps->n > 0 && gs_synth_seed_split(ps->p[0].identity_seed) == GS_SYNTH_TRAIN)
        fprintf(f, "- **training identities** (`--split train`): faces a model "
                   "trained on %d or more identities has seen; a diagnostic "
                   "of what it can draw, not a held-out figure\n",
                eval_pairs_identities(ps));
    /* the incremental path needs the model's point-sampled map */
    int full = info->feature_scale != 1 || info->supersample > 1;
    if (info->n_face > 0)
        fprintf(f, "- model renders: %d of %d face Gaussians (%.0f %%), "
                   "feature scale %.3g%s, %s\n", info->face_kept,
                info->n_face, 100.0 * info->face_kept / info->n_face,
                info->feature_scale,
                info->feature_scale > 1 ? " (supersampled)"
                : info->supersample > 1 && info->feature_scale == 1
                    ? " (the model's own: supersampled)"
                    : "",
                info->full_render ? "every render from scratch "
                                    "(--full-render)"
                : full ? "every render full"
                       : "incremental where possible");
    if (info->n_face > 0 && info->eye_direct)
        fputs("- the eye stream also drawn at the image's size over the "
              "renderer's image (config.eye_direct)\n", f);
    if (info->n_face > 0)
        fprintf(f, "- lights at another head pose: %s\n",
                info->light_on_head ? "kept on the head (--light-on-head)"
                                    : "kept in the camera, as in the ground truth");
    int has_transfer = 0;
    for (int k = 0; k < nmethods; k++)
        has_transfer |= methods[k] == EVAL_TRANSFER;
    if (info->n_face > 0 && has_transfer)
        fprintf(f, "- transfer at another head pose: smoothed skin residual "
                   "x %.3g (--transfer-head-weight)\n",
                info->transfer_head_weight);
    if (has_transfer)
        fprintf(f, "- transfer at another gaze: eyeball residual x %.3g once "
                   "the eye has turned a few degrees (--transfer-eye-weight)\n",
                info->transfer_eye_weight);
    if (has_transfer && info->transfer_eye_warp_deg > 0)
        fprintf(f, "- transfer at another gaze, same head pose: the input's "
                   "eyeball pixels turned inside the eye opening, x "
                   "exp(-(turn / %.3g deg)^2) (--transfer-eye-warp)\n",
                info->transfer_eye_warp_deg);
    if (has_transfer && info->transfer_eye_warp_deg > 0 && info->transfer_eye_warp_head)
        fprintf(f, "- transfer at another gaze and head pose: the same warp, "
                   "inside the eye opening the model shows at the target's "
                   "pose (--transfer-eye-warp-head 1)\n");
    else if (has_transfer)
        fprintf(f, "- transfer eyeball warp: off (--transfer-eye-warp 0)\n");
    if (info->ft_iters > 0) {
        char parts[96];
        gs_finetune_parts_name(info->ft_parts, parts, sizeof parts);
        fprintf(f, "- fine-tuned per input (--finetune %d, parts %s, rate %g, "
                   "eye weight %g, outline %d px, mirror %s): %d inputs, mean "
                   "%.2f s each (in the fit times), input PSNR %.2f -> %.2f dB "
                   "on average (weighted pixels)\n", info->ft_iters, parts,
                info->ft_lr, info->ft_eye_w, info->ft_outline,
                info->ft_mirror ? "on" : "off", info->ft_n, info->ft_s,
                info->ft_psnr_first, info->ft_psnr_best);
    }
    int has_oracle = 0;
    for (int k = 0; k < nmethods; k++)
        has_oracle |= methods[k] == EVAL_ORACLE;
    if (has_oracle)
        fputs("- oracle: the shared model with each training identity's "
              "learned code and the target's true expression and lights, "
              "at the target's view; no fit, no fine-tuning, no colour "
              "transform (what training drew)\n", f);
    if (info->true_code) {
        /* "expression, lights and identity code", "lights", ... */
        const char *names[3];
        int nn = 0;
        if (info->true_code & GS_SCENE_CODE_EXPR)
            names[nn++] = "expression";
        if (info->true_code & GS_SCENE_CODE_LIGHT)
            names[nn++] = "lights";
        if (info->true_code & GS_SCENE_CODE_ID)
            names[nn++] = "identity code (the one training learned)";
        fputs("- **a diagnostic, not a served figure** (--true-code): each fit "
              "was given the input's true ", f);
        for (int i = 0; i < nn; i++)
            fprintf(f, "%s%s", i == 0 ? "" : i == nn - 1 ? " and " : ", ", names[i]);
        if (info->true_start)
            fprintf(f, " as %s start, and moved %s as it moved the rest "
                       "(--true-code-start)\n",
                    nn == 1 ? "its" : "their", nn == 1 ? "it" : "them");
        else
            fprintf(f, " and kept %s\n", nn == 1 ? "it" : "them");
    }
    if (info->fits_reused)
        fprintf(f, "- %d fits reused from an earlier run (--reuse-fits): "
                   "their fit times are that run's\n", info->fits_reused);
    if (info->fits_stale)
        fprintf(f, "- %d cached fits were made with another model, other fit "
                   "options or another input (--reuse-fits): fitted again\n",
                info->fits_stale);
    if (info->estimator)
        fprintf(f, "- estimator: `%s`; floor = its error on the ground-truth "
                   "target against the true label\n", info->estimator);
    else
        fputs("- no estimator given: gaze and head errors are not "
              "measured\n", f);
    if (info->readout)
        fprintf(f, "- readout: read gaze° = the gaze the output shows, read by "
                   "synthesis (the target scene rendered at candidate gazes, "
                   "compared over the target's eyeballs after aligning, by a "
                   "shift of up to %g px, on the pixels no gaze changes; the "
                   "best match wins), against the target's true gaze; read "
                   "floor° = the same on the GT target itself; closed eyes "
                   "are not read\n", info->readout_shift);
    if (info->readout && info->readout_soft > 0)
        fprintf(f, "- readout softness (`--readout-soft %g`): each candidate "
                   "is also compared blurred as an output of softness up to "
                   "%g px would be (Gaussian sigma, steps of 0.25 px; the "
                   "alignment likewise), and keeps its best level, so a "
                   "soft eye is read by where it points, not by how sharp "
                   "it is; read_soft_px in pairs.csv is the level matched\n",
                info->readout_soft, info->readout_soft);
    fputs("- degrees: mean angular error; gaze°/head° = estimator(output) vs "
          "estimator(GT target); PSNR dB and SSIM against the GT target "
          "(white outside the head); eye = eye region; id = face without "
          "the eyes (identity consistency). docs/eval.md explains each.\n\n",
          f);
    fputs("## All methods, all pairs\n\n", f);
    table_header(f, "method", info->readout);
    for (int k = 0; k < nmethods; k++) {
        stats s;
        gather(rows, n, ps, methods[k], G_ALL, &s);
        table_row(f, eval_method_names[methods[k]], &s, info->readout);
    }
    for (int k = 0; k < nmethods; k++) {
        fprintf(f, "\n## %s\n\n", eval_method_names[methods[k]]);
        method_counts(f, rows, n, ps, methods[k]);
        fputc('\n', f);
        table_header(f, "pairs", info->readout);
        for (int g = 0; g < G_COUNT; g++) {
            stats s;
            gather(rows, n, ps, methods[k], g, &s);
            if (s.n || g == G_ALL)
                table_row(f, group_names[g], &s, info->readout);
        }
    }
}
