/* gazesplat eval-range: estimators trained on a narrow source range, alone
 * and augmented by redirecting the same images across the model's range
 * (docs/eval.md "Range"). The experiment is lib/eval's gs_eval_range; this
 * file parses the options and writes the CSV and the Markdown summary. */
#define _POSIX_C_SOURCE 200809L

#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

#include "cli.h"
#include "gazesplat/eval.h"

static int run_range(const cli_command *cmd, cli_opt *o);

static const cli_opt range_opts[] = {
    {"--model", 1, NULL}, {"--out", 1, NULL}, {"--sources", 1, NULL}, {"--per-source", 1, NULL},
    {"--targets", 1, NULL}, {"--tests", 1, NULL}, {"--per-test", 1, NULL}, {"--steps", 1, NULL},
    {"--batch", 1, NULL}, {"--lr", 1, NULL}, {"--iters", 1, NULL}, {"--seed", 1, NULL},
    {"--threads", 1, NULL}, {"--save-estimators", 0, NULL}};

const cli_command cli_eval_range_command = {
    "eval-range",
    "train estimators on narrow data alone and augmented across the range",
    "usage: gazesplat eval-range --model M --out DIR [options]\n"
    "\n"
    "Source data: --sources identities (test split) x --per-source images\n"
    "with gaze within +-10 deg pitch, +-15 deg yaw (head frame) and head\n"
    "within +-10 deg. Each source identity is fitted on its first image and\n"
    "redirected --targets times across gaze +-30 pitch, +-40 yaw: with the\n"
    "head turned too (within +-20 pitch, +-30 yaw: ours), at the source\n"
    "images' own heads (ours-gaze), and by the 2-D warp (warp). A gaze\n"
    "estimator (the shipped resnet architecture) is trained from one\n"
    "initialisation on the source alone and on source + each set, then\n"
    "measured on --tests identities of the validation split (never in any\n"
    "set) over the whole range.\n"
    "\n"
    "  --model FILE        the redirection model\n"
    "  --out DIR           writes DIR/range.csv, DIR/range.md and, with\n"
    "                      --save-estimators, DIR/<condition>.safetensors\n"
    "  --sources N         source identities (20)\n"
    "  --per-source N      source images per identity (10)\n"
    "  --targets N         redirected images per source identity (100)\n"
    "  --tests N           test identities (20)\n"
    "  --per-test N        test images per identity (10)\n"
    "  --steps N           training steps per estimator (3000)\n"
    "  --batch N           images per step (16)\n"
    "  --lr X              peak learning rate, warm-up then cosine (1e-3)\n"
    "  --iters N           fit iteration cap (200)\n"
    "  --seed N            scenes, targets, initialisation, batches (1)\n"
    "  --threads N         worker threads (2); the numbers are the same for\n"
    "                      any count\n"
    "  --save-estimators   keep the four trained estimators\n",
    .opts = range_opts,
    .nopts = CLI_NOPTS(range_opts),
    .run_opts = run_range,
};

enum {
    O_MODEL, O_OUT, O_SOURCES, O_PER_SOURCE, O_TARGETS, O_TESTS, O_PER_TEST,
    O_STEPS, O_BATCH, O_LR, O_ITERS, O_SEED, O_THREADS, O_SAVE, O_N
};

static void log_line(void *ctx, const char *fmt, ...)
{
    (void)ctx;
    va_list ap;
    va_start(ap, fmt);
    fputs("gazesplat ", stderr);
    vfprintf(stderr, fmt, ap);
    fputc('\n', stderr);
    va_end(ap);
}

static int opt_long(const cli_opt *o, long lo, long hi, long *v)
{
    return o->value && cli_parse_long(o->value, lo, hi, v) ? -1 : 0;
}

static int parse(const cli_opt *o, gs_eval_range_options *p, int *threads)
{
    const cli_command *cmd = &cli_eval_range_command;
    long v[O_N];
    const struct { int opt; long lo, hi; } ints[] = {
        {O_SOURCES, 1, 10000}, {O_PER_SOURCE, 1, 1000}, {O_TARGETS, 1, 100000},
        {O_TESTS, 1, 10000},   {O_PER_TEST, 1, 1000},   {O_STEPS, 1, 10000000},
        {O_BATCH, 1, 4096},    {O_ITERS, 1, 100000},    {O_THREADS, 1, 256},
        {O_SEED, 0, 4294967295L}};
    v[O_SOURCES] = p->sources, v[O_PER_SOURCE] = p->per_source;
    v[O_TARGETS] = p->targets, v[O_TESTS] = p->tests;
    v[O_PER_TEST] = p->per_test, v[O_STEPS] = p->steps;
    v[O_BATCH] = p->batch, v[O_ITERS] = p->fit_iters;
    v[O_THREADS] = *threads, v[O_SEED] = (long)p->seed;
    for (size_t i = 0; i < sizeof ints / sizeof ints[0]; i++)
        if (opt_long(&o[ints[i].opt], ints[i].lo, ints[i].hi, &v[ints[i].opt]))
            return cli_usage_error(cmd, "%s: want an integer in %ld..%ld",
                                   o[ints[i].opt].name, ints[i].lo, ints[i].hi);
    p->sources = (int)v[O_SOURCES], p->per_source = (int)v[O_PER_SOURCE];
    p->targets = (int)v[O_TARGETS], p->tests = (int)v[O_TESTS];
    p->per_test = (int)v[O_PER_TEST], p->steps = v[O_STEPS];
    p->batch = (int)v[O_BATCH], p->fit_iters = (int)v[O_ITERS];
    *threads = (int)v[O_THREADS], p->seed = (uint64_t)v[O_SEED];
    if (o[O_LR].value) {
        float x;
        if (cli_parse_floats(o[O_LR].value, &x, 1) || !(x > 0 && x < 1))
            return cli_usage_error(cmd, "--lr: want a number in (0, 1)");
        p->lr = x;
    }
    return CLI_OK;
}

/* Mean of condition c over the rows whose in_source_range is `which`
 * (-1: every row). */
static double mean_of(const gs_eval_range_result *r, int c, int which, int *n)
{
    double s = 0;
    int m = 0;
    for (int i = 0; i < r->n; i++)
        if (which < 0 || r->rows[i].in_source_range == which)
            s += r->rows[i].err[c], m++;
    if (n)
        *n = m;
    return m ? s / m : NAN;
}

/* Two-sided 95 % Student t quantile for df degrees of freedom. */
static double t95(int df)
{
    static const double t[] = {12.706, 4.303, 3.182, 2.776, 2.571, 2.447,
                               2.365, 2.306, 2.262, 2.228, 2.201, 2.179,
                               2.160, 2.145, 2.131, 2.120, 2.110, 2.101,
                               2.093, 2.086, 2.080, 2.074, 2.069, 2.064,
                               2.060, 2.056, 2.052, 2.048, 2.045, 2.042};
    return df < 1 ? NAN : df <= 30 ? t[df - 1] : 1.96 + 2.4 / df;
}

/* Across test identities: the mean of (condition c - source) over each
 * identity's images, its mean and 95 % interval. */
static void paired(const gs_eval_range_result *r, int tests, int c,
                   double *mean, double *lo, double *hi)
{
    double s = 0, ss = 0;
    for (int id = 0; id < tests; id++) {
        double d = 0;
        int m = 0;
        for (int i = 0; i < r->n; i++)
            if (r->rows[i].identity == id)
                d += r->rows[i].err[c] - r->rows[i].err[GS_EVAL_RANGE_SOURCE], m++;
        d = m ? d / m : 0;
        s += d, ss += d * d;
    }
    *mean = s / tests;
    double var = tests > 1 ? (ss - tests * *mean * *mean) / (tests - 1) : NAN;
    double h = t95(tests - 1) * sqrt(var > 0 ? var : 0) / sqrt(tests);
    *lo = *mean - h;
    *hi = *mean + h;
}

static void md_write(FILE *f, const char *line, const char *model,
                     const gs_eval_range_options *o,
                     const gs_eval_range_result *r, int threads)
{
    fprintf(f, "# Range: estimators trained on narrow data, alone and "
               "augmented\n\n```sh\n%s\n```\n\n", line);
    fprintf(f, "Model `%s`. Source: %d identities x %d images, gaze within "
               "+-%.0f pitch, +-%.0f yaw, head within +-%.0f deg. Redirected: "
               "%d per source identity, gaze +-%.0f pitch, +-%.0f yaw; ours "
               "with the head within +-%.0f pitch, +-%.0f yaw. Tests: %d "
               "validation identities x %d images over the whole range. "
               "Estimators: resnet from one initialisation, %ld steps of "
               "batch %d, peak lr %g, seed %llu.\n\n",
            model, o->sources, o->per_source, o->src_gaze_pitch * 57.2957795,
            o->src_gaze_yaw * 57.2957795, o->src_head * 57.2957795, o->targets,
            o->gaze_pitch * 57.2957795, o->gaze_yaw * 57.2957795,
            o->head_pitch * 57.2957795, o->head_yaw * 57.2957795, o->tests,
            o->per_test, o->steps, o->batch, o->lr,
            (unsigned long long)o->seed);
    int nin, nout;
    mean_of(r, 0, 1, &nin);
    mean_of(r, 0, 0, &nout);
    fprintf(f, "Mean gaze angle (degrees) on the test images: all %d, the "
               "%d inside the source range, the %d outside it; against "
               "source alone, the mean over test identities of the "
               "per-identity difference and its 95 %% interval (t, %d "
               "identities).\n\n", r->n, nin, nout, o->tests);
    fputs("| training set | images | all | inside | outside | vs source (95 % interval) | change |\n"
          "|---|---:|---:|---:|---:|---|---:|\n", f);
    double base = mean_of(r, GS_EVAL_RANGE_SOURCE, -1, NULL);
    for (int c = 0; c < GS_EVAL_RANGE_CONDITIONS; c++) {
        double all = mean_of(r, c, -1, NULL), d, lo, hi;
        fprintf(f, "| %s | %ld | %.2f | %.2f | %.2f |", gs_eval_range_condition_name(c),
                r->set_size[c], all, mean_of(r, c, 1, NULL), mean_of(r, c, 0, NULL));
        if (c == GS_EVAL_RANGE_SOURCE) {
            fputs(" | |\n", f);
            continue;
        }
        paired(r, o->tests, c, &d, &lo, &hi);
        fprintf(f, " %+.2f (%+.2f to %+.2f) | %+.0f %% |\n", d, lo, hi,
                100.0 * (all - base) / base);
    }
    fprintf(f, "\nFits %.0f s (mean PSNR %.2f dB), renders and warps %.0f s; "
               "training", r->fit_s, r->fit_psnr, r->render_s);
    for (int c = 0; c < GS_EVAL_RANGE_CONDITIONS; c++)
        fprintf(f, " %s %.0f s (final loss %.4f)%s", gs_eval_range_condition_name(c),
                r->train_s[c], r->train_loss[c],
                c + 1 < GS_EVAL_RANGE_CONDITIONS ? "," : "");
    fprintf(f, "; %d threads.\n", threads);
}

static int write_outputs(const char *out, const char *line, const char *model,
                         const gs_eval_range_options *o,
                         const gs_eval_range_result *r, int threads)
{
    const cli_command *cmd = &cli_eval_range_command;
    char path[4200];
    snprintf(path, sizeof path, "%s/range.csv", out);
    FILE *f = fopen(path, "w");
    if (!f)
        return cli_fail(cmd, "cannot write %s", path);
    fputs("identity,index,gaze_pitch_deg,gaze_yaw_deg,head_pitch_deg,"
          "head_yaw_deg,in_source_range", f);
    for (int c = 0; c < GS_EVAL_RANGE_CONDITIONS; c++)
        fprintf(f, ",err_%s", gs_eval_range_condition_name(c));
    fputc('\n', f);
    for (int i = 0; i < r->n; i++) {
        const gs_eval_range_row *w = &r->rows[i];
        fprintf(f, "%d,%d,%.4f,%.4f,%.4f,%.4f,%d", w->identity, w->index,
                w->gaze_pitch, w->gaze_yaw, w->head_pitch, w->head_yaw,
                w->in_source_range);
        for (int c = 0; c < GS_EVAL_RANGE_CONDITIONS; c++)
            fprintf(f, ",%.4f", w->err[c]);
        fputc('\n', f);
    }
    if (fclose(f))
        return cli_fail(cmd, "cannot write %s", path);
    snprintf(path, sizeof path, "%s/range.md", out);
    if (!(f = fopen(path, "w")))
        return cli_fail(cmd, "cannot write %s", path);
    md_write(f, line, model, o, r, threads);
    if (fclose(f))
        return cli_fail(cmd, "cannot write %s", path);
    printf("gazesplat eval-range: %d test images -> %s/range.csv, %s\n", r->n,
           out, path);
    return CLI_OK;
}

_Static_assert(CLI_NOPTS(range_opts) == O_N, "range_opts: one entry per option index");

static int run_range(const cli_command *cmd, cli_opt *o)
{
    int rc = CLI_OK;
    if (!o[O_MODEL].value || !o[O_OUT].value)
        return cli_usage_error(cmd, "--model and --out are needed");
    gs_eval_range_options opt;
    gs_eval_range_options_default(&opt);
    int threads = 2;
    if ((rc = parse(o, &opt, &threads)) != CLI_OK)
        return rc;
    opt.log = log_line;
    const char *out = o[O_OUT].value, *model = o[O_MODEL].value;
    struct stat st;
    if (mkdir(out, 0777) != 0 && !(stat(out, &st) == 0 && S_ISDIR(st.st_mode)))
        return cli_fail(cmd, "cannot create %s", out);
    char line[2048];
    cli_command_line(line, sizeof line);
    gs_error err = {0, ""};
    gs_model *m = NULL;
    if (gs_model_load(model, &m, &err))
        return cli_fail(cmd, "%s: %s", model, err.msg);
    gs_pool *pool = gs_pool_create(threads);
    gs_eval_range_result res;
    rc = !pool ? cli_fail(cmd, "out of memory")
         : gs_eval_range(m, &opt, o[O_SAVE].value ? out : NULL, pool, &res, &err)
             ? cli_fail(cmd, "%s", err.msg)
             : write_outputs(out, line, model, &opt, &res, threads);
    if (pool)
        gs_eval_range_result_free(&res);
    gs_pool_destroy(pool);
    gs_model_destroy(m);
    return rc;
}
