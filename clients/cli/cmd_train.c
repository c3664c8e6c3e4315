/* gazesplat train: makes a model and trains it on synthetic heads. */
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "cli.h"
#include "gazesplat/gaze.h"
#include "gazesplat/nn.h"
#include "gazesplat/train.h"

static int run_train(const cli_command *cmd, cli_opt *o);

static const cli_opt train_opts[] = {
    {"--out", 1, NULL}, {"--preset", 1, NULL}, {"--steps", 1, NULL}, {"--identities", 1, NULL},
    {"--lr", 1, NULL}, {"--seed", 1, NULL}, {"--threads", 1, NULL}, {"--resume", 0, NULL},
    {"--checkpoint", 1, NULL}, {"--log-every", 1, NULL}, {"--guidance", 1, NULL},
    {"--single-stream", 0, NULL}, {"--no-eye-rotation", 0, NULL}, {"--guide-source", 1, NULL},
    {"--gaze-loss", 1, NULL}, {"--gaze-weight", 1, NULL}, {"--fresh-optimizer", 1, NULL},
    {"--cosine", 0, NULL}, {"--lids", 0, NULL}, {"--eye-cover-loss", 1, NULL},
    {"--supersample", 1, NULL}, {"--eye-weight", 1, NULL}, {"--head-range", 1, NULL},
    {"--eye-direct", 1, NULL}, {"--sync-samples", 0, NULL}, {"--clip-grad-norm", 1, NULL},
    {"--sample-threads", 1, NULL}};

const cli_command cli_train_command = {
    "train",
    "train a GazeGaussian model on synthetic heads generated on the fly",
    "usage: gazesplat train --out MODEL.safetensors [options]\n"
    "\n"
    "  --out FILE          model file; checkpoints overwrite it (atomically)\n"
    "                      and FILE.opt keeps the optimizer state\n"
    "  --preset NAME       cpu (default), tiny (tests), paper\n"
    "  --steps N           total steps (default 2000)\n"
    "  --identities N      training identities, each with its own code (64);\n"
    "                      with --resume --fresh-optimizer, more than the\n"
    "                      model's adds new ones (codes from the mean)\n"
    "  --lr X              base Adam learning rate (1e-3)\n"
    "  --seed N            model initialisation and sample stream (1)\n"
    "  --threads N         worker threads (2); a thread more makes each\n"
    "                      step's sample while the step before runs\n"
    "  --sample-threads N  threads of that sample's synthetic render (1);\n"
    "                      more for a machine of many cores, where a step\n"
    "                      takes less than a sample (the same bytes)\n"
    "  --clip-grad-norm X  scale the gradients so that their global L2\n"
    "                      norm is at most X before each step (0, the\n"
    "                      default: no clipping)\n"
    "  --sync-samples      make each sample at its step instead, on the\n"
    "                      workers' first thread (the same bytes; slower)\n"
    "  --resume            continue a run from FILE and FILE.opt\n"
    "  --fresh-optimizer STEP\n"
    "                      with --resume, for a FILE without FILE.opt (a\n"
    "                      shipped model): continue its weights from step\n"
    "                      STEP with a new optimizer, the learning rate\n"
    "                      ramping up over the first 200 steps\n"
    "  --cosine            learning rate from --lr down to --lr/20 at --steps\n"
    "                      along a half cosine (default: constant)\n"
    "  --checkpoint N      save every N steps (500)\n"
    "  --log-every N       progress line every N steps (50)\n"
    "  --guidance MODE     none | additive | paper (renderer guidance)\n"
    "  --guide-source S    face (default: one guidance vector from the face\n"
    "                      stream's map, exact incremental gaze sweeps) |\n"
    "                      block (each block attends over its own features);\n"
    "                      with --resume, switches a model's source\n"
    "  --single-stream     ablation: one stream, gaze through the pose MLP\n"
    "  --no-eye-rotation   ablation: eyes deformed like the face\n"
    "  --lids              lids that follow the gaze's pitch (docs/model.md);\n"
    "                      with --resume --fresh-optimizer, adds them to a\n"
    "                      model without\n"
    "  --gaze-loss FILE    add the gaze loss: angular error of this gaze\n"
    "                      estimator (gazesplat train-estimator) on the render\n"
    "  --gaze-weight X     its weight (0.1, the paper's)\n"
    "  --eye-weight W      weight of the eye pixels in the image loss and of\n"
    "                      the eye stream's own feature loss (1..100, 5)\n"
    "  --head-range Y,P    head poses of the samples: yaw within +-Y, pitch\n"
    "                      within +-P degrees (Y 1..60, P 1..40; 40,25: the\n"
    "                      model's documented range, the default; the\n"
    "                      evaluation's scenes reach 50,30)\n"
    "  --eye-direct 0|1    1: the eye stream is also drawn at the image's\n"
    "                      size and composited over the renderer's image\n"
    "                      (docs/model.md); with --resume, switches a\n"
    "                      model (same tensors)\n"
    "  --eye-cover-loss X  add X times the L1 of the eye stream's coverage\n"
    "                      of the feature map against the visible eyeballs\n"
    "                      (where the lids are; docs/model.md); 0 (default)\n"
    "  --supersample K     rasterize the feature map at K times its size and\n"
    "                      give each pixel the mean of K x K samples (1..4;\n"
    "                      1, point-sampled, is the default); with --resume,\n"
    "                      switches a model's sampling (not with\n"
    "                      --eye-cover-loss)\n",
    .opts = train_opts,
    .nopts = CLI_NOPTS(train_opts),
    .run_opts = run_train,
};

static void log_line(void *ctx, const char *fmt, ...)
{
    (void)ctx;
    va_list ap;
    va_start(ap, fmt);
    fputs("gazesplat train: ", stderr);
    vfprintf(stderr, fmt, ap);
    fputc('\n', stderr);
    va_end(ap);
}

enum { O_OUT, O_PRESET, O_STEPS, O_IDS, O_LR, O_SEED, O_THREADS, O_RESUME,
       O_CKPT, O_LOG, O_GUIDE, O_SINGLE, O_NOEYE, O_GSRC, O_GLOSS, O_GW,
       O_FRESH, O_COS, O_LIDS, O_COVER, O_SS, O_EYEW, O_HEAD, O_EDIR, O_SYNC,
       O_CLIP, O_STHREADS, O_N };

_Static_assert(CLI_NOPTS(train_opts) == O_N, "train_opts: one entry per option index");

static int run_train(const cli_command *cmd, cli_opt *o)
{
    int rc = CLI_OK;
    if (!o[O_OUT].value)
        return cli_usage_error(cmd, "missing --out");
    gs_model_spec spec;
    gs_model_spec_default(&spec);
    gs_train_options t;
    gs_train_options_default(&t);
    t.out_path = o[O_OUT].value;
    t.sync_samples = o[O_SYNC].value != NULL;
    if (o[O_CLIP].value) {
        char *end = NULL;
        t.max_grad_norm = strtod(o[O_CLIP].value, &end);
        if (!end || *end || !(t.max_grad_norm >= 0 && t.max_grad_norm <= 1e6))
            return cli_usage_error(cmd, "--clip-grad-norm: want 0..1e6");
    }
    long v, threads = 2, seed = 1;
    if (o[O_STHREADS].value) {
        if (cli_parse_long(o[O_STHREADS].value, 1, GS_TRAIN_SAMPLE_THREADS_MAX, &v))
            return cli_usage_error(cmd, "--sample-threads: want 1..%d",
                                   GS_TRAIN_SAMPLE_THREADS_MAX);
        t.sample_threads = (int)v;
    }
    if (o[O_PRESET].value)
        spec.preset = o[O_PRESET].value;
    if (o[O_STEPS].value) {
        if (cli_parse_long(o[O_STEPS].value, 1, 100000000L, &v))
            return cli_usage_error(cmd, "--steps: want 1..1e8");
        t.steps = v;
    }
    if (o[O_IDS].value) {
        if (cli_parse_long(o[O_IDS].value, 1, 100000L, &v))
            return cli_usage_error(cmd, "--identities: want 1..100000");
        spec.train_identities = (int)v;
    }
    if (o[O_LR].value) {
        float lr;
        if (cli_parse_floats(o[O_LR].value, &lr, 1) || !(lr > 0 && lr < 1))
            return cli_usage_error(cmd, "--lr: want 0 < X < 1");
        t.lr = lr;
    }
    if (o[O_SEED].value &&
        cli_parse_long(o[O_SEED].value, 0, 4294967295L, &seed))
        return cli_usage_error(cmd, "--seed: want 0..4294967295");
    t.seed = (uint64_t)seed;
    if (o[O_THREADS].value &&
        cli_parse_long(o[O_THREADS].value, 1, 256, &threads))
        return cli_usage_error(cmd, "--threads: want 1..256");
    if (o[O_CKPT].value) {
        if (cli_parse_long(o[O_CKPT].value, 1, 100000000L, &v))
            return cli_usage_error(cmd, "--checkpoint: want >= 1");
        t.checkpoint_every = v;
    }
    if (o[O_LOG].value) {
        if (cli_parse_long(o[O_LOG].value, 1, 100000000L, &v))
            return cli_usage_error(cmd, "--log-every: want >= 1");
        t.log_every = v;
    }
    if (o[O_GUIDE].value) {
        const char *g = o[O_GUIDE].value;
        spec.guidance = strcmp(g, "none") == 0       ? 0
                        : strcmp(g, "additive") == 0 ? 1
                        : strcmp(g, "paper") == 0    ? 2
                                                     : -2;
        if (spec.guidance == -2)
            return cli_usage_error(cmd, "--guidance: none, additive or paper");
    }
    if (o[O_GSRC].value) {
        const char *g = o[O_GSRC].value;
        spec.guide_source = strcmp(g, "block") == 0  ? 0
                            : strcmp(g, "face") == 0 ? 1
                                                     : -2;
        if (spec.guide_source == -2)
            return cli_usage_error(cmd, "--guide-source: face or block");
    }
    if (o[O_GW].value) {
        char *end = NULL;
        t.gaze_weight = strtod(o[O_GW].value, &end);
        if (!end || *end || !(t.gaze_weight >= 0 && t.gaze_weight <= 100))
            return cli_usage_error(cmd, "--gaze-weight: want 0..100");
    }
    if (o[O_SINGLE].value)
        spec.two_stream = 0;
    if (o[O_NOEYE].value)
        spec.eye_rotation = 0;
    t.resume = o[O_RESUME].value != NULL;
    if (o[O_FRESH].value) {
        if (!t.resume)
            return cli_usage_error(cmd, "--fresh-optimizer needs --resume");
        if (cli_parse_long(o[O_FRESH].value, 0, 100000000L, &v))
            return cli_usage_error(cmd, "--fresh-optimizer: want a step 0..1e8");
        if (v >= t.steps)
            return cli_usage_error(cmd, "--fresh-optimizer: step %ld is not below --steps %ld",
                                   v, t.steps);
        t.fresh_from_step = v;
    }
    t.cosine = o[O_COS].value != NULL;
    if (o[O_LIDS].value)
        spec.lids = 1;
    if (o[O_COVER].value) {
        char *end = NULL;
        t.eye_cover_weight = strtod(o[O_COVER].value, &end);
        if (!end || *end || !(t.eye_cover_weight >= 0 && t.eye_cover_weight <= 1000))
            return cli_usage_error(cmd, "--eye-cover-loss: want 0..1000");
    }
    if (o[O_EYEW].value) {
        char *end = NULL;
        t.eye_weight = strtod(o[O_EYEW].value, &end);
        if (!end || end == o[O_EYEW].value || *end ||
            !(t.eye_weight >= 1 && t.eye_weight <= 100))
            return cli_usage_error(cmd, "--eye-weight: want 1..100");
    }
    if (o[O_HEAD].value) {
        const char *s = o[O_HEAD].value;
        char *end = NULL;
        t.head_yaw_deg = strtod(s, &end);
        int ok = end && end != s && *end == ',';
        if (ok) {
            s = end + 1;
            t.head_pitch_deg = strtod(s, &end);
            ok = end && end != s && !*end;
        }
        if (!ok || t.head_yaw_deg == 0 || t.head_pitch_deg == 0 ||
            gs_train_check_head_range(t.head_yaw_deg, t.head_pitch_deg, NULL))
            return cli_usage_error(cmd, "--head-range: want YAW,PITCH in "
                                        "degrees, YAW 1..60, PITCH 1..40");
    }
    if (o[O_EDIR].value) {
        if (strcmp(o[O_EDIR].value, "0") && strcmp(o[O_EDIR].value, "1"))
            return cli_usage_error(cmd, "--eye-direct: want 0 or 1");
        spec.eye_direct = o[O_EDIR].value[0] - '0';
        if (spec.eye_direct && o[O_SINGLE].value)
            return cli_usage_error(cmd, "--eye-direct 1 needs the eye stream "
                                        "(not --single-stream)");
    }
    if (o[O_SS].value) {
        char *end = NULL;
        long k = strtol(o[O_SS].value, &end, 10);
        if (!end || end == o[O_SS].value || *end || k < 1 || k > 4)
            return cli_usage_error(cmd, "--supersample: want 1..4");
        spec.supersample = (int)k;
    }
    if (spec.supersample > 1 && t.eye_cover_weight > 0)
        return cli_usage_error(cmd, "--eye-cover-loss does not go with "
                                    "--supersample");
    t.log = log_line;

    gs_error err = {0, ""};
    gs_model *m = NULL;
    rc = t.resume ? gs_model_load(t.out_path, &m, &err)
                  : gs_model_new(&spec, (uint64_t)seed, &m, &err);
    if (!rc && t.resume && spec.guide_source >= 0)
        rc = gs_model_set_guide_source(m, spec.guide_source, &err);
    if (!rc && t.resume && spec.supersample >= 1)
        rc = gs_model_set_supersample(m, spec.supersample, &err);
    if (!rc && t.resume && spec.eye_direct >= 0)
        rc = gs_model_set_eye_direct(m, spec.eye_direct, &err);
    if (!rc && t.resume && spec.lids == 1 && !gs_model_has_lids(m)) {
        if (t.fresh_from_step < 0) {
            gs_model_destroy(m);
            return cli_usage_error(cmd, "--lids adds lids to this model only "
                                        "with --fresh-optimizer STEP (the face "
                                        "stream is reordered; FILE.opt would "
                                        "not fit)");
        }
        gs_model *l = NULL;
        rc = gs_model_add_lids(m, GS_MODEL_LID_RADIUS_MM, &l, &err);
        gs_model_destroy(m);
        m = l;
    }
    if (!rc && t.resume && o[O_IDS].value) {
        gs_model_info mi;
        gs_model_get_info(m, &mi);
        const char *why = NULL;
        if (spec.train_identities < mi.n_train_ids)
            why = "a resume keeps every identity the model has";
        else if (spec.train_identities > mi.n_train_ids && t.fresh_from_step < 0)
            why = "more identities only with --fresh-optimizer STEP (the "
                  "codes grow; FILE.opt would not fit)";
        if (why) {
            gs_model_destroy(m);
            return cli_usage_error(cmd, "--identities %d: the model has %d; %s",
                                   spec.train_identities, mi.n_train_ids, why);
        }
        if (spec.train_identities > mi.n_train_ids) {
            gs_model *g = NULL;
            rc = gs_model_add_identities(m, spec.train_identities, &g, &err);
            gs_model_destroy(m);
            m = g;
        }
    }
    if (rc) {
        gs_model_destroy(m);
        return cli_fail(cmd, "%s", err.msg);
    }
    gs_gaze_net *gnet = NULL;
    if (o[O_GLOSS].value) {
        rc = gs_gaze_net_load(o[O_GLOSS].value, &gnet, &err);
        if (rc) {
            gs_model_destroy(m);
            return cli_fail(cmd, "%s", err.msg);
        }
        t.gaze_net = gnet;
    }
    gs_pool *pool = threads > 1 ? gs_pool_create((int)threads) : NULL;
    /* The bytes of a run depend on OpenBLAS's kernels (docs/model.md,
     * "Training"): named so that runs on other machines can be compared. */
    fprintf(stderr, "gazesplat train: %ld threads, OpenBLAS kernels %s\n", threads,
            gs_nn_blas_core());
    gs_train_report rep;
    rc = gs_train(m, &t, pool, &rep, &err);
    gs_pool_destroy(pool);
    gs_gaze_net_destroy(gnet);
    gs_model_destroy(m);
    if (rc)
        return cli_fail(cmd, "%s", err.msg);
    printf("gazesplat train: %ld steps (%ld skipped) in %.1f s, final loss "
           "%.4f -> %s\n",
           rep.steps, rep.skipped, rep.seconds, rep.final_loss, t.out_path);
    return CLI_OK;
}
