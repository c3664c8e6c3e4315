/* gazesplat eval-downstream: how much redirected images help a gaze
 * estimator adapt to a new person (docs/eval.md "Downstream"). The
 * experiment is lib/eval's gs_eval_downstream_identity; this file runs it
 * over the identities and writes the CSV and the Markdown summary. */
#define _POSIX_C_SOURCE 200809L /* clock_gettime */

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <time.h>

#include "cli.h"
#include "gazesplat/eval.h"
#include "gazesplat/nn.h"

static int run_downstream(const cli_command *cmd, cli_opt *o);

static const cli_opt downstream_opts[] = {
    {"--model", 1, NULL}, {"--out", 1, NULL}, {"--estimator", 1, NULL}, {"--identities", 1, NULL},
    {"--test-images", 1, NULL}, {"--set-size", 1, NULL}, {"--max-k", 1, NULL},
    {"--steps", 1, NULL}, {"--batch", 1, NULL}, {"--lr", 1, NULL}, {"--real-fraction", 1, NULL},
    {"--iters", 1, NULL}, {"--fit-lr", 1, NULL}, {"--seed", 1, NULL}, {"--threads", 1, NULL},
    {"--reuse-fits", 0, NULL}, {"--first-identity", 1, NULL}, {"--kappa", 1, NULL},
    {"--subject-from-k", 0, NULL}, {"--calibrate", 0, NULL}, {"--ks", 1, NULL}};

const cli_command cli_eval_downstream_command = {
    "eval-downstream",
    "fine-tune a gaze estimator with real + redirected images, error vs k",
    "usage: gazesplat eval-downstream --model M --out DIR [options]\n"
    "\n"
    "Per held-out (test split) identity: 9 real images and --test-images\n"
    "images of the same person; the model is fitted on real image 1 and\n"
    "renders --set-size images at random gazes, the warp baseline warps\n"
    "that image to the same gazes. For k = 1..--max-k a copy of the\n"
    "estimator is fine-tuned on k real images alone, k real + the model's,\n"
    "k real + the warp's (set of --set-size) and its mean gaze error\n"
    "against the true labels of the test images is measured; k = 0 is the\n"
    "estimator as given.\n"
    "\n"
    "  --model FILE        the redirection model\n"
    "  --out DIR           writes DIR/downstream.csv, DIR/downstream.md and\n"
    "                      DIR/fits/ (created if needed); plot with\n"
    "                      bench/eval/downstream_plot.py DIR\n"
    "  --estimator FILE    the estimator to fine-tune\n"
    "                      (models/gaze-resnet.safetensors, here or as installed)\n"
    "  --identities N      test identities 0..N-1 (15)\n"
    "  --test-images N     test images per identity (50)\n"
    "  --set-size N        real + redirected images per mixed set (200)\n"
    "  --max-k N           largest k, 1..9 (9)\n"
    "  --steps N           fine-tuning steps (60)\n"
    "  --batch N           images per step (8)\n"
    "  --lr X              Adam learning rate, constant (1e-4)\n"
    "  --real-fraction X   mixed sets: real images fill at least this share\n"
    "                      of each batch, and at least k/set-size (0.25)\n"
    "  --iters N           fit iteration cap (200)\n"
    "  --fit-lr CODE[,COLOUR]  the fit's Adam rates for the latent code and\n"
    "                      the colour, each in (0, 10] (0.12,0.02; COLOUR\n"
    "                      defaults to CODE / 6)\n"
    "  --seed N            scenes, targets and batches (1)\n"
    "  --threads N         worker threads (2); the numbers are the same for\n"
    "                      any count, timings aside\n"
    "  --reuse-fits        take each identity's fit from DIR/fits/ when\n"
    "                      it was made with this model, --iters, --fit-lr\n"
    "                      and input (each file is keyed by them; any\n"
    "                      other is fitted again and rewritten)\n"
    "  --first-identity N  run identities N..N+--identities-1 (0): a long\n"
    "                      run split over several processes or sessions\n"
    "\n"
    "The calibration experiment (docs/eval.md \"Calibration\"):\n"
    "  --kappa SPEC        each identity gets its own angle kappa, as\n"
    "                      gazesplat synth --kappa (off, literature or\n"
    "                      H,HSD,V,VSD degrees); labels give the visual axis\n"
    "  --subject-from-k    for each k, fit one subject from the k real\n"
    "                      images together and redirect from them in turn\n"
    "                      (default: from real image 1 for every k)\n"
    "  --calibrate         the fits find each image's gaze (head pose given);\n"
    "                      the renders aim at target + the mean of fitted -\n"
    "                      labelled gaze over the fitted images, labelled the\n"
    "                      target; DIR/subjects.csv lists the offsets\n"
    "  --ks LIST           only these k, e.g. 1,3,9 (default 1..--max-k)\n",
    .opts = downstream_opts,
    .nopts = CLI_NOPTS(downstream_opts),
    .run_opts = run_downstream,
};

enum {
    O_MODEL, O_OUT, O_EST, O_IDS, O_TESTS, O_SET, O_MAXK, O_STEPS, O_BATCH,
    O_LR, O_FRAC, O_ITERS, O_FIT_LR, O_SEED, O_THREADS, O_REUSE, O_FIRST,
    O_KAPPA, O_FROM_K, O_CALIB, O_KS, O_N
};

typedef struct ds_cli {
    gs_eval_ds_options o;
    int identities, first, threads, reuse;
    const char *model, *est, *out;
    char line[2048];          /* the command as run */
    double fit_lr_code;       /* the code rate the fits run at (reported) */
    int fit_lr_code_model;    /* 1: it is the model file's */
} ds_cli;

static int make_dir(const char *path)
{
    struct stat st;
    return mkdir(path, 0777) == 0 ||
           (stat(path, &st) == 0 && S_ISDIR(st.st_mode));
}

/* An integer option in [lo, hi] into *v when given; -1 when bad. */
static int opt_int(const cli_opt *o, long lo, long hi, int *v)
{
    long x;
    if (!o->value)
        return 0;
    if (cli_parse_long(o->value, lo, hi, &x))
        return -1;
    *v = (int)x;
    return 0;
}

static int opt_real(const cli_opt *o, double lo, double hi, int open_lo,
                    double *v)
{
    float x;
    if (!o->value)
        return 0;
    if (cli_parse_floats(o->value, &x, 1) || x > hi || x < lo ||
        (open_lo && x == lo))
        return -1;
    *v = x;
    return 0;
}

/* --ks: a comma-separated list of k in 1..max_k into a bit set. */
static int parse_ks(const char *v, int max_k, unsigned *ks)
{
    *ks = 0;
    const char *p = v;
    for (;;) {
        char item[16];
        size_t n = strcspn(p, ",");
        long k;
        if (n == 0 || n >= sizeof item)
            return -1;
        memcpy(item, p, n);
        item[n] = '\0';
        if (cli_parse_long(item, 1, max_k, &k))
            return -1;
        *ks |= 1u << k;
        if (!p[n])
            return 0;
        p += n + 1;
    }
}

static int parse_calibration(const cli_opt *o, ds_cli *d)
{
    const cli_command *cmd = &cli_eval_downstream_command;
    if (opt_int(&o[O_FIRST], 0, 1000000, &d->first))
        return cli_usage_error(cmd, "--first-identity: want 0..1000000");
    if (o[O_KAPPA].value &&
        cli_parse_kappa(cmd, o[O_KAPPA].value, &d->o.kappa) != CLI_PARSED)
        return CLI_USAGE;
    d->o.subject_from_k = o[O_FROM_K].value != NULL;
    d->o.calibrate = o[O_CALIB].value != NULL;
    if (o[O_KS].value && parse_ks(o[O_KS].value, d->o.max_k, &d->o.ks))
        return cli_usage_error(cmd, "--ks: want a comma-separated list of k "
                               "in 1..%d (--max-k); got '%s'", d->o.max_k,
                               o[O_KS].value);
    return CLI_OK;
}

static int parse(const cli_opt *o, ds_cli *d)
{
    const cli_command *cmd = &cli_eval_downstream_command;
    gs_eval_ds_options *p = &d->o;
    long seed = 1;
    if (!o[O_MODEL].value || !o[O_OUT].value)
        return cli_usage_error(cmd, "--model and --out are needed");
    if (opt_int(&o[O_IDS], 1, 100000, &d->identities))
        return cli_usage_error(cmd, "--identities: want 1..100000");
    if (opt_int(&o[O_TESTS], 1, 100000, &p->test_images))
        return cli_usage_error(cmd, "--test-images: want 1..100000");
    if (opt_int(&o[O_MAXK], 1, GS_EVAL_DS_POOL, &p->max_k))
        return cli_usage_error(cmd, "--max-k: want 1..%d", GS_EVAL_DS_POOL);
    if (opt_int(&o[O_SET], p->max_k + 1, 100000, &p->set_size))
        return cli_usage_error(cmd, "--set-size: want %d..100000 (more "
                               "than --max-k)", p->max_k + 1);
    if (opt_int(&o[O_STEPS], 1, 1000000, &p->steps))
        return cli_usage_error(cmd, "--steps: want 1..1000000");
    if (opt_int(&o[O_BATCH], 1, 4096, &p->batch))
        return cli_usage_error(cmd, "--batch: want 1..4096");
    if (opt_real(&o[O_LR], 0, 1, 1, &p->lr))
        return cli_usage_error(cmd, "--lr: want a number in (0, 1]");
    if (opt_real(&o[O_FRAC], 0, 1, 0, &p->real_fraction))
        return cli_usage_error(cmd, "--real-fraction: want 0..1");
    if (opt_int(&o[O_ITERS], 1, 100000, &p->fit_iters))
        return cli_usage_error(cmd, "--iters: want 1..100000");
    if (o[O_FIT_LR].value && cli_parse_fit_lr(o[O_FIT_LR].value, &p->fit_lr_code,
                                              &p->fit_lr_colour))
        return cli_usage_error(cmd, "--fit-lr: want CODE[,COLOUR], each in "
                               "(0, 10]; got '%s'", o[O_FIT_LR].value);
    if (o[O_SEED].value && cli_parse_long(o[O_SEED].value, 0, 4294967295L,
                                          &seed))
        return cli_usage_error(cmd, "--seed: want 0..4294967295");
    p->seed = (uint64_t)seed;
    if (opt_int(&o[O_THREADS], 1, 256, &d->threads))
        return cli_usage_error(cmd, "--threads: want 1..256");
    d->model = o[O_MODEL].value;
    d->out = o[O_OUT].value;
    if (o[O_EST].value)
        d->est = o[O_EST].value;
    d->reuse = o[O_REUSE].value != NULL;
    return parse_calibration(o, d);
}

/* Whether row k is in the run: k = 0 and the k of --ks. */
static int row_runs(const gs_eval_ds_options *o, int k)
{
    return k == 0 || (k <= o->max_k && (!o->ks || (o->ks >> k & 1u)));
}

static void csv_rows(FILE *f, int id, const gs_eval_ds_result *r,
                     const gs_eval_ds_options *o)
{
    unsigned long long seed = gs_synth_split_seed(GS_SYNTH_TEST,
                                                  (uint64_t)id);
    for (int k = 0; k <= o->max_k; k++)
        for (int c = 0; c < GS_EVAL_DS_CONDITIONS && row_runs(o, k); c++)
            fprintf(f, "%d,%llu,%d,%s,%.4f\n", id, seed, k,
                    gs_eval_ds_condition_name(c), r->err[k][c]);
}

/* Mean over the identities that finished, per k and condition. */
/* One row per identity and k of the calibration's subjects: the kappa
 * drawn and the offset the renders aimed with. */
static void subjects_rows(FILE *f, int id, const gs_eval_ds_result *r,
                          const gs_eval_ds_options *o)
{
    for (int k = 1; k <= o->max_k; k++)
        if (row_runs(o, k))
            fprintf(f, "%d,%d,%.4f,%.4f,%.4f,%.4f\n", id, k, r->kappa_h_deg,
                    r->kappa_v_deg, r->offset_deg[k][0], r->offset_deg[k][1]);
}

static void md_table(FILE *f, const gs_eval_ds_result *res, const int *ok,
                     int n, const gs_eval_ds_options *o)
{
    fputs("| k | real only | real + ours | real + warp |\n"
          "|---:|---:|---:|---:|\n", f);
    for (int k = 0; k <= o->max_k; k++) {
        if (!row_runs(o, k))
            continue;
        fprintf(f, "| %d", k);
        for (int c = 0; c < GS_EVAL_DS_CONDITIONS; c++) {
            double s = 0;
            int m = 0;
            for (int i = 0; i < n; i++)
                if (ok[i])
                    s += res[i].err[k][c], m++;
            fprintf(f, " | %.2f", m ? s / m : NAN);
        }
        fputs(" |\n", f);
    }
}

static void md_write(FILE *f, const ds_cli *d, const gs_eval_ds_result *res,
                     const int *ok)
{
    const gs_eval_ds_options *o = &d->o;
    int n = d->identities, done = 0, reused = 0;
    double fit = 0, tune = 0, psnr = 0;
    long inc = 0, full = 0;
    for (int i = 0; i < n; i++)
        if (ok[i]) {
            done++, reused += res[i].fit_reused;
            fit += res[i].fit_s, tune += res[i].finetune_s;
            psnr += res[i].fit_psnr;
            inc += res[i].renders_incremental, full += res[i].renders_full;
        }
    fprintf(f, "# Downstream: fine-tuning a gaze estimator with redirected "
               "images\n\n```sh\n%s\n```\n\n", d->line);
    fprintf(f, "Model `%s`, estimator `%s`. %d test identities (%d "
               "finished), %d test images each, %d real images, sets of "
               "%d, %d steps of batch %d at lr %g, real images at least "
               "%.0f %% of each mixed batch, fit cap %d iterations at rates "
               "%g (code%s) and %g (colour), seed %llu.\n\n",
            d->model, d->est, n, done, o->test_images, GS_EVAL_DS_POOL,
            o->set_size, o->steps, o->batch, o->lr, 100 * o->real_fraction,
            o->fit_iters, d->fit_lr_code, d->fit_lr_code_model ? ", the model's" : "",
            o->fit_lr_colour,
            (unsigned long long)o->seed);
    if (d->first)
        fprintf(f, "Identities %d..%d.\n\n", d->first, d->first + n - 1);
    if (o->kappa.enabled || o->subject_from_k || o->calibrate)
        fprintf(f, "Calibration: kappa %s (h %.2f +- %.2f, v %.2f +- %.2f "
                   "deg); the subject of each k from %s; %s.\n\n",
                o->kappa.enabled ? "on" : "off", o->kappa.h_mean_deg,
                o->kappa.h_sd_deg, o->kappa.v_mean_deg, o->kappa.v_sd_deg,
                o->subject_from_k ? "its k real images" : "real image 1",
                o->calibrate ? "fits find the gaze, renders aim at target + "
                               "the mean fitted - labelled offset"
                             : "fits given the labelled gaze");
    fputs("Mean gaze angle (degrees) of the fine-tuned estimator against "
          "the true labels of each identity's test images, mean over "
          "identities; k = 0 is the estimator as given.\n\n", f);
    md_table(f, res, ok, n, o);
    if (done)
        fprintf(f, "\nPer identity: fit %.1f s (mean, %d reused), fit PSNR "
                   "%.2f dB; model renders %ld incremental, %ld full; one "
                   "fine-tune %.2f s (mean, %d threads).\n",
                fit / done, reused, psnr / done, inc, full, tune / done,
                d->threads);
    fprintf(f, "\nFailed identities: %d.\n", n - done);
}

static int write_md(const ds_cli *d, const gs_eval_ds_result *res,
                    const int *ok)
{
    char path[4200];
    snprintf(path, sizeof path, "%s/downstream.md", d->out);
    FILE *f = fopen(path, "w");
    if (!f)
        return cli_fail(&cli_eval_downstream_command, "cannot write %s",
                        path);
    md_write(f, d, res, ok);
    if (fclose(f))
        return cli_fail(&cli_eval_downstream_command, "cannot write %s",
                        path);
    return CLI_OK;
}

/* Runs every identity, appending its rows to the CSV as it finishes. */
static int run_all(const ds_cli *d, const gs_model *m, const gs_gaze_net *est,
                   gs_pool *pool, FILE *csv, FILE *subj, gs_eval_ds_result *res,
                   int *ok)
{
    const cli_command *cmd = &cli_eval_downstream_command;
    int failed = 0;
    double t0 = cli_now_s();
    for (int i = 0; i < d->identities; i++) {
        const int id = d->first + i;
        char fit[4300];
        snprintf(fit, sizeof fit, "%s/fits/seed%llu_%05d.bin", d->out,
                 (unsigned long long)d->o.seed, id);
        gs_error err = {0, ""};
        ok[i] = gs_eval_downstream_identity(m, est, &d->o, id, fit, d->reuse,
                                            pool, &res[i], &err) == GS_OK;
        if (!ok[i]) {
            fprintf(stderr, "gazesplat eval-downstream: identity %d: %s\n",
                    id, err.msg);
            failed++;
            continue;
        }
        if (res[i].cache_write_failed)
            fprintf(stderr, "gazesplat eval-downstream: cannot write %s\n",
                    fit);
        csv_rows(csv, id, &res[i], &d->o);
        fflush(csv);
        if (subj) {
            subjects_rows(subj, id, &res[i], &d->o);
            fflush(subj);
        }
        int kl = d->o.max_k;
        while (kl > 0 && !row_runs(&d->o, kl))
            kl--;
        fprintf(stderr, "gazesplat eval-downstream: identity %d (%d/%d): k=%d "
                "real %.2f ours %.2f warp %.2f (k=0 %.2f), fit %.0f s, "
                "%.2f s per fine-tune, %.0f s in all\n", id, i + 1,
                d->identities, kl, res[i].err[kl][0], res[i].err[kl][1],
                res[i].err[kl][2],
                res[i].err[0][0], res[i].fit_s, res[i].finetune_s,
                cli_now_s() - t0);
    }
    return failed ? cli_fail(cmd, "%d of %d identities failed", failed,
                             d->identities)
                  : CLI_OK;
}

static int run_loaded(const ds_cli *d, const gs_model *m,
                      const gs_gaze_net *est)
{
    const cli_command *cmd = &cli_eval_downstream_command;
    char path[4200];
    snprintf(path, sizeof path, "%s/downstream.csv", d->out);
    FILE *csv = fopen(path, "w");
    gs_eval_ds_result *res = calloc((size_t)d->identities, sizeof *res);
    int *ok = calloc((size_t)d->identities, sizeof *ok);
    gs_pool *pool = gs_pool_create(d->threads);
    int rc = CLI_OK;
    FILE *subj = NULL;
    if (csv && (d->o.kappa.enabled || d->o.calibrate)) {
        char sp[4200];
        snprintf(sp, sizeof sp, "%s/subjects.csv", d->out);
        if (!(subj = fopen(sp, "w")))
            rc = cli_fail(cmd, "cannot write %s", sp);
        else
            fputs("identity,k,kappa_h_deg,kappa_v_deg,offset_pitch_deg,"
                  "offset_yaw_deg\n", subj);
    }
    if (!csv)
        rc = cli_fail(cmd, "cannot write %s", path);
    else if (!res || !ok || !pool)
        rc = cli_fail(cmd, "out of memory");
    if (!rc) {
        fputs("identity,identity_seed,k,condition,gaze_err_deg\n", csv);
        rc = run_all(d, m, est, pool, csv, subj, res, ok);
    }
    if (subj && fclose(subj) && !rc)
        rc = cli_fail(cmd, "cannot write %s/subjects.csv", d->out);
    if (csv && fclose(csv) && !rc)
        rc = cli_fail(cmd, "cannot write %s", path);
    int md = res && ok ? write_md(d, res, ok) : CLI_FAIL;
    if (!rc && !md)
        printf("gazesplat eval-downstream: %d identities -> %s, "
               "%s/downstream.md\n", d->identities, path, d->out);
    gs_pool_destroy(pool);
    free(res);
    free(ok);
    return rc ? rc : md;
}

static int run_checked(ds_cli *d)
{
    const cli_command *cmd = &cli_eval_downstream_command;
    char fits[4200];
    snprintf(fits, sizeof fits, "%s/fits", d->out);
    if (!make_dir(d->out) || !make_dir(fits))
        return cli_fail(cmd, "cannot create %s", fits);
    gs_error err = {0, ""};
    gs_model *m = NULL;
    gs_gaze_net *est = NULL;
    int rc = CLI_OK;
    if (gs_model_load(d->model, &m, &err))
        rc = cli_fail(cmd, "%s: %s", d->model, err.msg);
    else if (gs_gaze_net_load(d->est, &est, &err))
        rc = cli_fail(cmd, "%s: %s", d->est, err.msg);
    if (!rc) {
        gs_model_info mi;
        gs_model_get_info(m, &mi);
        d->fit_lr_code_model = d->o.fit_lr_code <= 0 && mi.fit_code_rate > 0;
        d->fit_lr_code = gs_model_fit_code_rate(m, d->o.fit_lr_code);
        rc = run_loaded(d, m, est);
    }
    gs_gaze_net_destroy(est);
    gs_model_destroy(m);
    return rc;
}

_Static_assert(CLI_NOPTS(downstream_opts) == O_N, "downstream_opts: one entry per option index");

static int run_downstream(const cli_command *cmd, cli_opt *o)
{
    (void)cmd; /* parse and run_checked report as cli_eval_downstream_command */
    int rc = CLI_OK;
    ds_cli d;
    memset(&d, 0, sizeof d);
    gs_eval_ds_options_default(&d.o);
    d.identities = 15;
    d.threads = 2;
    d.est = cli_shipped_model("gaze-resnet.safetensors");
    rc = parse(o, &d);
    if (rc)
        return rc;
    cli_command_line(d.line, sizeof d.line);
    return run_checked(&d);
}
