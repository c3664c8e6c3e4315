/* gazesplat train-estimator / estimate / eval-estimator: the gaze and
 * head-pose estimator of lib/gaze. */
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "cli.h"
#include "gazesplat/gaze.h"
#include "gazesplat/geom.h"
#include "gazesplat/image_io.h"
#include "gazesplat/nn.h"
#include "gazesplat/synth.h"

#define DEG 57.29577951308232

static int run_train_est(const cli_command *cmd, cli_opt *o);
static int run_estimate(const cli_command *cmd, cli_opt *o);
static int run_eval_est(const cli_command *cmd, cli_opt *o);

static const cli_opt train_est_opts[] = {
    {"--arch", 1, NULL}, {"--out", 1, NULL}, {"--seed", 1, NULL}, {"--steps", 1, NULL},
    {"--batch", 1, NULL}, {"--lr", 1, NULL}, {"--input", 1, NULL}, {"--cache", 1, NULL},
    {"--fresh", 1, NULL}, {"--identities", 1, NULL}, {"--threads", 1, NULL},
    {"--checkpoint", 1, NULL}, {"--log-every", 1, NULL}, {"--resume", 0, NULL},
    {"--widths", 1, NULL}, {"--hidden", 1, NULL}, {"--render-size", 1, NULL}, {"--white", 1, NULL},
    {"--shift", 1, NULL}, {"--blur", 1, NULL}};

const cli_command cli_train_estimator_command = {
    "train-estimator",
    "train the gaze/head-pose estimator on synthetic faces",
    "usage: gazesplat train-estimator --arch resnet|vgg --out FILE [options]\n"
    "\n"
    "  --arch A            resnet (evaluation estimator) or vgg (loss estimator)\n"
    "  --out FILE          estimator file; checkpoints overwrite it atomically\n"
    "                      and FILE.opt keeps the optimizer state\n"
    "  --seed N            weight initialisation and sample stream (1)\n"
    "  --steps N           total steps (1000)\n"
    "  --batch N           images per step (16)\n"
    "  --lr X              peak Adam learning rate, cosine decay (1e-3)\n"
    "  --input N           net input size, 32..256, a multiple of 16 (64)\n"
    "  --widths A,B,C,D    channels of the 4 stages (12,24,48,64)\n"
    "  --hidden N          fully connected hidden units (96)\n"
    "  --cache N           rendered samples kept and re-drawn (2048)\n"
    "  --fresh N           new samples rendered per step (4)\n"
    "  --render-size N     render samples at N px, one sample per pixel, as\n"
    "                      the evaluation does (input..512; default: the\n"
    "                      input size with 2x2 supersampling)\n"
    "  --white P           share of samples made white outside the head, as\n"
    "                      the evaluation's targets are (0..1, default 0)\n"
    "  --shift N           random shift of each batch image, up to N px (0)\n"
    "  --blur P            share of batch images blurred by [1,2,1]/4 (0)\n"
    "  --identities N      training identities drawn from (20000)\n"
    "  --threads N         worker threads (2)\n"
    "  --checkpoint N      save every N steps (500)\n"
    "  --log-every N       progress line every N steps (50)\n"
    "  --resume            continue the run saved in FILE and FILE.opt\n",
    .opts = train_est_opts,
    .nopts = CLI_NOPTS(train_est_opts),
    .run_opts = run_train_est,
};

static const cli_opt estimate_opts[] = {
    {"--model", 1, NULL}, {"--image", 1, NULL}};

const cli_command cli_estimate_command = {
    "estimate",
    "print gaze and head pose of a normalized face image",
    "usage: gazesplat estimate --model FILE --image PNG|JPEG\n"
    "\n"
    "Prints gaze pitch, gaze yaw, head pitch, head yaw in degrees\n"
    "(normalized camera; pitch > 0 up, yaw > 0 toward image left).\n",
    .opts = estimate_opts,
    .nopts = CLI_NOPTS(estimate_opts),
    .run_opts = run_estimate,
};

static const cli_opt eval_est_opts[] = {
    {"--model", 1, NULL}, {"--split", 1, NULL}, {"--count", 1, NULL}, {"--size", 1, NULL},
    {"--seed", 1, NULL}, {"--threads", 1, NULL}, {"--csv", 1, NULL}, {"--white", 0, NULL}};

const cli_command cli_eval_estimator_command = {
    "eval-estimator",
    "error of an estimator on ground-truth synthetic images",
    "usage: gazesplat eval-estimator --model FILE[,FILE...] [options]\n"
    "\n"
    "  --model F[,F...]    up to 4 estimators, evaluated on the same images\n"
    "  --split S           test (default), val or train identities\n"
    "  --count N           images, each of its own identity (500)\n"
    "  --size N            image size, px (256, the model's)\n"
    "  --seed N            scene stream (7)\n"
    "  --threads N         render threads (2)\n"
    "  --csv FILE          per model and image: labels, predictions, errors\n"
    "  --white             white outside the head mask, as the evaluation's\n"
    "                      targets are (default: the rendered background)\n"
    "\n"
    "Prints mean, median and 90th percentile of the angular gaze and head\n"
    "errors in degrees (angle between the 3D directions).\n",
    .opts = eval_est_opts,
    .nopts = CLI_NOPTS(eval_est_opts),
    .run_opts = run_eval_est,
};

static void log_line(void *ctx, const char *fmt, ...)
{
    (void)ctx;
    va_list ap;
    va_start(ap, fmt);
    fputs("gazesplat train-estimator: ", stderr);
    vfprintf(stderr, fmt, ap);
    fputc('\n', stderr);
    va_end(ap);
}

enum { T_ARCH, T_OUT, T_SEED, T_STEPS, T_BATCH, T_LR, T_INPUT, T_CACHE, T_FRESH, T_IDS,
       T_THREADS, T_CKPT, T_LOG, T_RESUME, T_WIDTHS, T_HIDDEN, T_RSIZE, T_WHITE, T_SHIFT,
       T_BLUR, T_N };

/* Reads an optional integer option into *v; nonzero (usage printed) when bad. */
static int opt_long(const cli_command *cmd, const cli_opt *o, long lo, long hi, long *v)
{
    if (o->value && cli_parse_long(o->value, lo, hi, v)) {
        cli_usage_error(cmd, "%s: want %ld..%ld; got '%s'", o->name, lo, hi, o->value);
        return 1;
    }
    return 0;
}

_Static_assert(CLI_NOPTS(train_est_opts) == T_N, "train_est_opts: one entry per option index");

static int run_train_est(const cli_command *cmd, cli_opt *o)
{
    int rc = CLI_OK;
    if (!o[T_OUT].value)
        return cli_usage_error(cmd, "missing --out");
    int arch = gs_gaze_arch_from_name(o[T_ARCH].value);
    if (arch < 0)
        return cli_usage_error(cmd, "--arch: want resnet or vgg");
    gs_gaze_train_options t;
    gs_gaze_train_options_default(&t);
    long seed = 1, steps = t.steps, batch = t.batch, input = 64, cache = t.cache,
         fresh = t.fresh, ids = (long)t.identities, threads = 2, ckpt = t.checkpoint_every,
         logev = t.log_every, hidden = 96, rsize = 0, shift = 0;
    if (opt_long(cmd, &o[T_SEED], 0, 4294967295L, &seed) ||
        opt_long(cmd, &o[T_STEPS], 1, 100000000L, &steps) ||
        opt_long(cmd, &o[T_BATCH], 1, 4096, &batch) ||
        opt_long(cmd, &o[T_INPUT], 32, 256, &input) ||
        opt_long(cmd, &o[T_CACHE], 1, 1000000, &cache) ||
        opt_long(cmd, &o[T_FRESH], 1, 1000000, &fresh) ||
        opt_long(cmd, &o[T_IDS], 1, 1000000000L, &ids) ||
        opt_long(cmd, &o[T_THREADS], 1, 256, &threads) ||
        opt_long(cmd, &o[T_CKPT], 0, 100000000L, &ckpt) ||
        opt_long(cmd, &o[T_LOG], 0, 100000000L, &logev) ||
        opt_long(cmd, &o[T_HIDDEN], 1, 4096, &hidden) ||
        opt_long(cmd, &o[T_RSIZE], 32, 512, &rsize) || opt_long(cmd, &o[T_SHIFT], 0, 16, &shift))
        return CLI_USAGE;
    if (o[T_RSIZE].value && rsize < input)
        return cli_usage_error(cmd, "--render-size: want >= --input (%ld)", input);
    const int share_opt[2] = {T_WHITE, T_BLUR};
    double share[2] = {0, 0};
    for (int k = 0; k < 2; k++) {
        float v;
        const cli_opt *so = &o[share_opt[k]];
        if (!so->value)
            continue;
        if (cli_parse_floats(so->value, &v, 1) || !(v >= 0 && v <= 1))
            return cli_usage_error(cmd, "%s: want a share in 0..1; got '%s'", so->name,
                                   so->value);
        share[k] = v;
    }
    float wf[GS_GAZE_STAGES];
    if (o[T_WIDTHS].value && cli_parse_floats(o[T_WIDTHS].value, wf, GS_GAZE_STAGES))
        return cli_usage_error(cmd, "--widths: want 4 comma-separated integers");
    for (int i = 0; o[T_WIDTHS].value && i < GS_GAZE_STAGES; i++)
        if (!(wf[i] >= 1 && wf[i] <= 512) || wf[i] != (float)(int)wf[i])
            return cli_usage_error(cmd, "--widths: want integers in 1..512");
    if (input % 16)
        return cli_usage_error(cmd, "--input: want a multiple of 16");
    if (fresh > cache)
        return cli_usage_error(cmd, "--fresh: want <= --cache");
    if (o[T_LR].value) {
        float lr;
        if (cli_parse_floats(o[T_LR].value, &lr, 1) || !(lr > 0 && lr < 1))
            return cli_usage_error(cmd, "--lr: want 0 < X < 1");
        t.lr = lr;
    }
    t.steps = steps, t.batch = (int)batch, t.seed = (uint64_t)seed, t.cache = (int)cache;
    t.fresh = (int)fresh, t.identities = (uint64_t)ids, t.checkpoint_every = ckpt;
    t.log_every = logev, t.out_path = o[T_OUT].value, t.resume = o[T_RESUME].value != NULL;
    t.log = log_line;
    t.render_size = (int)rsize, t.white = share[0], t.shift = (int)shift, t.blur = share[1];

    gs_error err = {0, ""};
    gs_gaze_net *n = NULL;
    gs_gaze_spec spec;
    gs_gaze_spec_default(&spec, arch);
    spec.input_size = (int)input;
    spec.hidden = (int)hidden;
    for (int i = 0; o[T_WIDTHS].value && i < GS_GAZE_STAGES; i++)
        spec.widths[i] = (int)wf[i];
    rc = t.resume ? gs_gaze_net_load(t.out_path, &n, &err)
                  : gs_gaze_net_create(&spec, (uint64_t)seed, &n, &err);
    if (rc)
        return cli_fail(cmd, "%s", err.msg);
    gs_gaze_net_spec(n, &spec);
    if (t.resume && spec.arch != arch)
        return gs_gaze_net_destroy(n),
               cli_fail(cmd, "%s is a %s estimator, not %s", t.out_path,
                        gs_gaze_arch_name(spec.arch), gs_gaze_arch_name(arch));
    gs_pool *pool = threads > 1 ? gs_pool_create((int)threads) : NULL;
    gs_gaze_train_report rep;
    rc = gs_gaze_train(n, &t, pool, &rep, &err);
    gs_pool_destroy(pool);
    gs_gaze_net_destroy(n);
    if (rc)
        return cli_fail(cmd, "%s", err.msg);
    printf("gazesplat train-estimator: %ld steps in %.1f s, final loss %.4f rad -> %s\n",
           rep.steps, rep.seconds, rep.final_loss, t.out_path);
    return CLI_OK;
}

_Static_assert(CLI_NOPTS(estimate_opts) == 2, "estimate_opts: one entry per option index");

static int run_estimate(const cli_command *cmd, cli_opt *o)
{
    int rc = CLI_OK;
    if (!o[0].value || !o[1].value)
        return cli_usage_error(cmd, "need --model and --image");
    gs_error err = {0, ""};
    gs_gaze_net *n = NULL;
    gs_io_image img = {0};
    float out[4];
    rc = gs_gaze_net_load(o[0].value, &n, &err);
    if (!rc)
        rc = gs_io_image_read(o[1].value, NULL, &img, &err);
    if (!rc)
        rc = gs_gaze_net_predict(n, NULL, img.data, img.width, img.height, img.stride, out,
                                 &err);
    gs_io_image_free(&img);
    gs_gaze_net_destroy(n);
    if (rc)
        return cli_fail(cmd, "%s", err.msg);
    printf("gaze_pitch_deg %.2f\ngaze_yaw_deg %.2f\nhead_pitch_deg %.2f\nhead_yaw_deg %.2f\n",
           out[0] * DEG, out[1] * DEG, out[2] * DEG, out[3] * DEG);
    return CLI_OK;
}

/* ---- eval-estimator ------------------------------------------------------- */

static int cmp_double(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

/* Prints mean, median and p90 of v[n] (sorted in place), degrees. */
static void summary(const char *what, double *v, int n)
{
    double s = 0;
    for (int i = 0; i < n; i++)
        s += v[i];
    qsort(v, (size_t)n, sizeof *v, cmp_double);
    printf("%s error (deg): mean %.2f  median %.2f  p90 %.2f\n", what, s / n * DEG,
           v[n / 2] * DEG, v[(int)(0.9 * (n - 1))] * DEG);
}

static double angle_between(double p1, double y1, double p2, double y2)
{
    double a[3], b[3];
    gs_geom_pitchyaw_to_vec(p1, y1, a);
    gs_geom_pitchyaw_to_vec(p2, y2, b);
    return gs_geom_vec3_angle(a, b);
}

enum { E_MODEL, E_SPLIT, E_COUNT, E_SIZE, E_SEED, E_THREADS, E_CSV, E_WHITE, E_N };
enum { MAX_MODELS = 4 };

typedef struct eval_set {
    int nmodels;
    char path[MAX_MODELS][1024];
    gs_gaze_net *net[MAX_MODELS];
    double *eg[MAX_MODELS], *eh[MAX_MODELS]; /* [count] angular errors */
    int white; /* --white */
} eval_set;

/* One image: every model's prediction and errors, and its CSV rows. */
static int eval_image(eval_set *es, const gs_synth_sample *s, long i, FILE *csv, gs_error *err)
{
    const gs_synth_labels *l = &s->labels;
    for (int m = 0; m < es->nmodels; m++) {
        float out[4];
        int rc = gs_gaze_net_predict(es->net[m], NULL, s->rgb, s->width, s->height, s->stride,
                                     out, err);
        if (rc)
            return rc;
        es->eg[m][i] = angle_between(out[0], out[1], l->gaze_norm_pitch, l->gaze_norm_yaw);
        es->eh[m][i] = angle_between(out[2], out[3], l->head_norm_pitch, l->head_norm_yaw);
        if (csv)
            fprintf(csv, "%d,%ld,%.4f,%.4f,%.4f,%.4f,%.4f,%.4f,%.4f,%.4f,%.4f,%.4f\n", m, i,
                    l->gaze_norm_pitch * DEG, l->gaze_norm_yaw * DEG, l->head_norm_pitch * DEG,
                    l->head_norm_yaw * DEG, out[0] * DEG, out[1] * DEG, out[2] * DEG,
                    out[3] * DEG, es->eg[m][i] * DEG, es->eh[m][i] * DEG);
    }
    return GS_OK;
}

static int eval_loop(eval_set *es, const gs_synth_gen_config *gc, long count, gs_pool *pool,
                     FILE *csv, gs_error *err)
{
    gs_synth_sample s;
    int rc = gs_synth_sample_alloc(&s, gc->size, gc->size, err);
    for (long i = 0; !rc && i < count; i++) {
        rc = gs_synth_gen_sample(gc, (uint64_t)i, pool, &s, err);
        if (!rc && es->white) {
            const uint8_t *head = gs_synth_sample_mask(&s, GS_SYNTH_MASK_HEAD);
            for (int y = 0; y < s.height; y++)
                for (int x = 0; x < s.width; x++)
                    if (!head[(size_t)y * (size_t)s.width + (size_t)x])
                        memset(s.rgb + (size_t)y * s.stride + 3 * (size_t)x, 255, 3);
        }
        if (!rc)
            rc = eval_image(es, &s, i, csv, err);
        if (!rc && (i + 1) % 50 == 0)
            fprintf(stderr, "gazesplat eval-estimator: %ld/%ld\n", i + 1, count);
    }
    gs_synth_sample_free(&s);
    return rc;
}

/* Splits "A,B,..." into es->path; -1 when empty or too many. */
static int split_models(const char *list, eval_set *es)
{
    const char *p = list;
    es->nmodels = 0;
    while (*p) {
        const char *c = strchr(p, ',');
        size_t n = c ? (size_t)(c - p) : strlen(p);
        if (n == 0 || n >= sizeof es->path[0] || es->nmodels == MAX_MODELS)
            return -1;
        memcpy(es->path[es->nmodels], p, n);
        es->path[es->nmodels++][n] = '\0';
        p += n + (c ? 1 : 0);
        if (c && !*p)
            return -1;
    }
    return es->nmodels ? 0 : -1;
}

static void eval_free(eval_set *es)
{
    for (int m = 0; m < es->nmodels; m++) {
        gs_gaze_net_destroy(es->net[m]);
        free(es->eg[m]);
        free(es->eh[m]);
    }
}

static int eval_run(const cli_command *cmd, eval_set *es, const gs_synth_gen_config *gc,
                    long count, long threads, const char *csv_path, const char *split)
{
    gs_error err = {0, ""};
    for (int m = 0; m < es->nmodels; m++) {
        if (gs_gaze_net_load(es->path[m], &es->net[m], &err))
            return cli_fail(cmd, "%s", err.msg);
        es->eg[m] = malloc((size_t)count * sizeof(double));
        es->eh[m] = malloc((size_t)count * sizeof(double));
        if (!es->eg[m] || !es->eh[m])
            return cli_fail(cmd, "out of memory");
    }
    FILE *csv = csv_path ? fopen(csv_path, "w") : NULL;
    if (csv_path && !csv)
        return cli_fail(cmd, "cannot write %s", csv_path);
    if (csv)
        fputs("model,index,gaze_pitch_deg,gaze_yaw_deg,head_pitch_deg,head_yaw_deg,"
              "pred_gaze_pitch_deg,pred_gaze_yaw_deg,pred_head_pitch_deg,pred_head_yaw_deg,"
              "gaze_err_deg,head_err_deg\n", csv);
    gs_pool *pool = threads > 1 ? gs_pool_create((int)threads) : NULL;
    int rc = eval_loop(es, gc, count, pool, csv, &err);
    gs_pool_destroy(pool);
    if (csv)
        fclose(csv);
    if (rc)
        return cli_fail(cmd, "%s", err.msg);
    for (int m = 0; m < es->nmodels; m++) {
        printf("%s: %ld %s-split images of %d px (seed %llu)\n", es->path[m], count, split,
               gc->size, (unsigned long long)gc->seed);
        summary("gaze", es->eg[m], (int)count);
        summary("head", es->eh[m], (int)count);
    }
    return CLI_OK;
}

_Static_assert(CLI_NOPTS(eval_est_opts) == E_N, "eval_est_opts: one entry per option index");

static int run_eval_est(const cli_command *cmd, cli_opt *o)
{
    int rc = CLI_OK;
    static eval_set es;
    memset(&es, 0, sizeof es);
    if (!o[E_MODEL].value || split_models(o[E_MODEL].value, &es))
        return cli_usage_error(cmd, "--model: want FILE[,FILE...] (up to %d)", MAX_MODELS);
    long count = 500, size = 256, seed = 7, threads = 2;
    if (opt_long(cmd, &o[E_COUNT], 1, 1000000, &count) ||
        opt_long(cmd, &o[E_SIZE], 16, 4096, &size) ||
        opt_long(cmd, &o[E_SEED], 0, 4294967295L, &seed) ||
        opt_long(cmd, &o[E_THREADS], 1, 256, &threads))
        return CLI_USAGE;
    gs_synth_gen_config gc;
    gs_synth_gen_config_default(&gc);
    const char *sp = o[E_SPLIT].value ? o[E_SPLIT].value : "test";
    if (strcmp(sp, "test") == 0)
        gc.split = GS_SYNTH_TEST;
    else if (strcmp(sp, "val") == 0)
        gc.split = GS_SYNTH_VAL;
    else if (strcmp(sp, "train") == 0)
        gc.split = GS_SYNTH_TRAIN;
    else
        return cli_usage_error(cmd, "--split: want test, val or train; got '%s'", sp);
    gc.identities = (uint64_t)count;
    gc.seed = (uint64_t)seed;
    gc.size = (int)size;
    gc.rig = GS_SYNTH_RIG_NORMALIZED;
    gc.supersample = 1;
    es.white = o[E_WHITE].value != NULL;
    rc = eval_run(cmd, &es, &gc, count, threads, o[E_CSV].value, sp);
    eval_free(&es);
    return rc;
}
