/* The range experiment: does redirecting narrow source data across the
 * model's range help an estimator trained on it (issue 48; docs/eval.md
 * "Range")? On synthetic heads, where every label is exact:
 *
 *   source     sources x per_source images of a narrow gaze and head range
 *   ours       per source identity, `targets` renders of its subject (fitted
 *              on its first image) at gazes and head poses across the
 *              model's range
 *   ours-gaze  the same gazes at the source images' own head poses
 *   warp       the source images warped to those gazes (a 2-D warp cannot
 *              turn a head)
 *
 * An estimator is trained from the same initialisation, seed and schedule
 * on source alone and on source + each set, and measured on identities no
 * set holds, over the whole range. Every step is deterministic, so the
 * numbers are the same for any thread count. */
#define _POSIX_C_SOURCE 200809L /* clock_gettime */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "gazesplat/clock.h"
#include "gazesplat/eval.h"
#include "eval_internal.h"

#define TAG_SRC 0x7267737263ull   /* "rgsrc" */
#define TAG_TGT 0x726774676dull   /* "rgtgm" */
#define TAG_TEST 0x7267747374ull  /* "rgtst" */
#define TAG_INIT 0x7267696e74ull  /* "rgint" */
#define RG_DEG (3.14159265358979323846 / 180.0)

static uint64_t splitmix(uint64_t x)
{
    x += 0x9E3779B97F4A7C15ull;
    x = (x ^ (x >> 30)) * 0xBF58476D1CE4E5B9ull;
    x = (x ^ (x >> 27)) * 0x94D049BB133111EBull;
    return x ^ (x >> 31);
}

static uint64_t mix3(uint64_t a, uint64_t b, uint64_t c, uint64_t d)
{
    return splitmix(splitmix(splitmix(splitmix(a) ^ b) ^ c) ^ d);
}

const char *gs_eval_range_condition_name(int c)
{
    static const char *const names[GS_EVAL_RANGE_CONDITIONS] = {
        "source", "source+ours", "source+ours-gaze", "source+warp"};
    return c >= 0 && c < GS_EVAL_RANGE_CONDITIONS ? names[c] : "?";
}

void gs_eval_range_options_default(gs_eval_range_options *o)
{
    memset(o, 0, sizeof *o);
    o->sources = 20;
    o->per_source = 10;
    o->targets = 100;
    o->src_gaze_pitch = 10 * RG_DEG;
    o->src_gaze_yaw = 15 * RG_DEG;
    o->src_head = 10 * RG_DEG;
    o->gaze_pitch = 30 * RG_DEG;
    o->gaze_yaw = 40 * RG_DEG;
    o->head_pitch = 20 * RG_DEG;
    o->head_yaw = 30 * RG_DEG;
    o->tests = 20;
    o->per_test = 10;
    o->steps = 3000;
    o->batch = 16;
    o->lr = 1e-3;
    o->fit_iters = 200;
    o->seed = 1;
}

static int in_angle(double a, double hi)
{
    return isfinite(a) && a >= 0 && a <= hi;
}

int gs_eval_range_options_check(const gs_eval_range_options *o, gs_error *err)
{
    const char *what = NULL;
    if (!o)
        what = "NULL options";
    else if (o->sources < 1 || o->sources > 10000 || o->per_source < 1 ||
             o->per_source > 1000 || o->targets < 1 || o->targets > 100000)
        what = "sources 1..10000, per_source 1..1000, targets 1..100000";
    else if (o->tests < 1 || o->tests > 10000 || o->per_test < 1 ||
             o->per_test > 1000)
        what = "tests 1..10000, per_test 1..1000";
    else if (!in_angle(o->src_gaze_pitch, o->gaze_pitch) ||
             !in_angle(o->src_gaze_yaw, o->gaze_yaw) ||
             !in_angle(o->src_head, fmin(o->head_pitch, o->head_yaw)))
        what = "the source ranges must lie inside the target ranges";
    else if (!in_angle(o->gaze_pitch, 40 * RG_DEG) ||
             !in_angle(o->gaze_yaw, 50 * RG_DEG) ||
             !in_angle(o->head_pitch, 25 * RG_DEG) ||
             !in_angle(o->head_yaw, 40 * RG_DEG))
        what = "target ranges beyond the model's (gaze 40/50, head 25/40 "
               "deg pitch/yaw)";
    else if (o->steps < 1 || o->steps > 10000000 || o->batch < 1 ||
             o->batch > 4096 || !(o->lr > 0 && o->lr < 1))
        what = "steps 1..1e7, batch 1..4096, lr in (0, 1)";
    else if (o->fit_iters < 1 || o->fit_iters > 100000)
        what = "fit_iters 1..100000";
    return what ? gs_error_set(err, GS_ERR_ARG, "eval-range: %s", what)
                : GS_OK;
}

void gs_eval_range_result_free(gs_eval_range_result *r)
{
    if (r) {
        free(r->rows);
        memset(r, 0, sizeof *r);
    }
}

/* ---- image sets: CHW bytes and the estimator's 4 labels ---- */

typedef struct rset {
    size_t n, cap, len; /* images, capacity, bytes per image */
    uint8_t *chw;
    float *lab;
} rset;

static int rset_alloc(rset *s, size_t cap, int S)
{
    s->n = 0;
    s->cap = cap;
    s->len = 3 * (size_t)S * (size_t)S;
    s->chw = malloc(cap * s->len);
    s->lab = malloc(cap * 4 * sizeof(float));
    return s->chw && s->lab ? GS_OK : GS_ERR_NOMEM;
}

static void rset_free(rset *s)
{
    free(s->chw);
    free(s->lab);
    memset(s, 0, sizeof *s);
}

/* Appends an RGB image (rows of stride bytes) and its labels. */
static void rset_add(rset *s, const uint8_t *rgb, size_t stride, int S,
                     const gs_synth_labels *l)
{
    uint8_t *dst = s->chw + s->n * s->len;
    size_t plane = (size_t)S * (size_t)S;
    for (int y = 0; y < S; y++)
        for (int x = 0; x < S; x++)
            for (int k = 0; k < 3; k++)
                dst[k * plane + (size_t)y * S + x] =
                    rgb[(size_t)y * stride + 3 * (size_t)x + k];
    float *lab = s->lab + 4 * s->n;
    lab[0] = (float)l->gaze_norm_pitch;
    lab[1] = (float)l->gaze_norm_yaw;
    lab[2] = (float)l->head_norm_pitch;
    lab[3] = (float)l->head_norm_yaw;
    s->n++;
}

typedef struct range_run {
    const gs_eval_range_options *o;
    int S;
    double focal, d_n;
    gs_pool *pool;
    gs_synth_sample *src_smp;  /* [sources * per_source] */
    gs_synth_scene *src_sc;
    rset set[GS_EVAL_RANGE_CONDITIONS]; /* [SOURCE] the source images, the
                                           others what is added to them */
    rset test;
    uint8_t *out;              /* one S x S RGB render */
    gs_eval_range_result *res;
} range_run;

static void ranges_of(const gs_eval_range_options *o, int narrow,
                      gs_synth_ranges *r)
{
    gs_eval_ranges(r);
    r->gaze_pitch = narrow ? o->src_gaze_pitch : o->gaze_pitch;
    r->gaze_yaw = narrow ? o->src_gaze_yaw : o->gaze_yaw;
    r->head_pitch = narrow ? o->src_head : o->head_pitch;
    r->head_yaw = narrow ? o->src_head : o->head_yaw;
}

static void log_step(const range_run *r, const char *what, int i, int n)
{
    if (r->o->log)
        r->o->log(r->o->log_ctx, "eval-range: %s %d of %d", what, i, n);
}

/* The source images: identity i (TEST split), image j, narrow ranges. */
static int make_sources(range_run *r, gs_error *err)
{
    const gs_eval_range_options *o = r->o;
    gs_synth_ranges nr;
    ranges_of(o, 1, &nr);
    int rc = GS_OK;
    for (int i = 0; !rc && i < o->sources; i++)
        for (int j = 0; !rc && j < o->per_source; j++) {
            size_t q = (size_t)i * (size_t)o->per_source + (size_t)j;
            gs_synth_scene_random(gs_synth_split_seed(GS_SYNTH_TEST, (uint64_t)i),
                                  mix3(o->seed, TAG_SRC, (uint64_t)i, (uint64_t)j),
                                  &nr, &r->src_sc[q]);
            rc = gs_eval_render_scene(&r->src_sc[q], r->S, r->d_n, r->focal,
                                      r->pool, &r->src_smp[q], err);
            if (!rc)
                rset_add(&r->set[GS_EVAL_RANGE_SOURCE], r->src_smp[q].rgb,
                         r->src_smp[q].stride, r->S, &r->src_smp[q].labels);
        }
    return rc;
}

/* Labels of a scene through the normalized camera, without rendering. */
static int scene_labels(const range_run *r, const gs_synth_scene *sc,
                        gs_synth_labels *l, gs_error *err)
{
    gs_synth_camera cam;
    int rc = gs_eval_scene_camera(sc, r->S, r->d_n, r->focal, &cam, err);
    return rc ? rc : gs_synth_labels_compute(sc, &cam, l, err);
}

/* Target t of source identity i: a gaze and head pose drawn over the
 * target ranges; the source image it starts from is t mod per_source. */
static void target_scene(const range_run *r, int i, int t, gs_synth_scene *w)
{
    gs_synth_ranges wr;
    ranges_of(r->o, 0, &wr);
    gs_synth_scene_random(gs_synth_split_seed(GS_SYNTH_TEST, (uint64_t)i),
                          mix3(r->o->seed, TAG_TGT, (uint64_t)i, (uint64_t)t),
                          &wr, w);
}

/* One target of the three redirected sets. */
static int redirect_one(range_run *r, gs_model_ctx *c, const gs_subject *sub,
                        size_t q, const gs_synth_scene *w, gs_error *err)
{
    const size_t st = 3 * (size_t)r->S;
    const gs_synth_sample *in = &r->src_smp[q];
    /* ours: the source scene turned to the target's head pose and gaze */
    gs_synth_scene sc = r->src_sc[q];
    memcpy(sc.head_R, w->head_R, sizeof sc.head_R);
    memcpy(sc.head_t, w->head_t, sizeof sc.head_t);
    sc.gaze_pitch = w->gaze_pitch;
    sc.gaze_yaw = w->gaze_yaw;
    gs_synth_labels l;
    int rc = scene_labels(r, &sc, &l, err);
    gs_view v = {0};
    v.gaze_pitch = w->gaze_pitch;
    v.gaze_yaw = w->gaze_yaw;
    v.use_head = 1;
    memcpy(v.head_R, l.head_R, sizeof v.head_R);
    memcpy(v.head_t, l.head_t, sizeof v.head_t);
    if (!rc)
        rc = gs_model_render(c, r->pool, sub, &v, r->out, st, err);
    if (!rc)
        rset_add(&r->set[GS_EVAL_RANGE_OURS], r->out, st, r->S, &l);
    /* ours-gaze and warp: the target's gaze at the source image's head */
    sc = r->src_sc[q];
    sc.gaze_pitch = w->gaze_pitch;
    sc.gaze_yaw = w->gaze_yaw;
    if (!rc)
        rc = scene_labels(r, &sc, &l, err);
    memcpy(v.head_R, in->labels.head_R, sizeof v.head_R);
    memcpy(v.head_t, in->labels.head_t, sizeof v.head_t);
    if (!rc)
        rc = gs_model_render(c, r->pool, sub, &v, r->out, st, err);
    if (!rc)
        rset_add(&r->set[GS_EVAL_RANGE_OURS_GAZE], r->out, st, r->S, &l);
    if (!rc)
        rc = gs_eval_warp_redirect(in, w->gaze_pitch, w->gaze_yaw, r->out, st,
                                   err);
    if (!rc)
        rset_add(&r->set[GS_EVAL_RANGE_WARP], r->out, st, r->S, &l);
    return rc;
}

/* Per source identity: the fit on its first image, then its targets,
 * grouped by the source image they start from. */
static int make_redirected(range_run *r, const gs_model *m, gs_error *err)
{
    const gs_eval_range_options *o = r->o;
    gs_model_ctx *c = gs_model_ctx_create(m);
    if (!c)
        return gs_error_set(err, GS_ERR_NOMEM, "eval-range: out of memory");
    int rc = GS_OK;
    for (int i = 0; !rc && i < o->sources; i++) {
        size_t q0 = (size_t)i * (size_t)o->per_source;
        gs_subject sub;
        double secs = 0, t0;
        rc = gs_eval_fit_samples(c, r->pool, &r->src_smp[q0], 1, o->fit_iters,
                                 0, GS_FIT_LR_COLOUR_DEFAULT, 0, &sub, &secs,
                                 err);
        r->res->fit_s += secs;
        if (!rc)
            r->res->fit_psnr += sub.fit_psnr / o->sources;
        t0 = gs_clock_s();
        for (int j = 0; !rc && j < o->per_source; j++)
            for (int t = j; !rc && t < o->targets; t += o->per_source) {
                gs_synth_scene w;
                target_scene(r, i, t, &w);
                rc = redirect_one(r, c, &sub, q0 + (size_t)j, &w, err);
            }
        r->res->render_s += gs_clock_s() - t0;
        log_step(r, "fitted and redirected source identity", i + 1,
                 o->sources);
    }
    gs_model_ctx_destroy(c);
    return rc;
}

/* The test images: VAL identities, the whole target range. */
static int make_tests(range_run *r, gs_error *err)
{
    const gs_eval_range_options *o = r->o;
    gs_synth_ranges wr;
    ranges_of(o, 0, &wr);
    int rc = GS_OK;
    for (int i = 0; !rc && i < o->tests; i++)
        for (int j = 0; !rc && j < o->per_test; j++) {
            gs_synth_scene sc;
            gs_synth_sample smp = {0};
            gs_synth_scene_random(gs_synth_split_seed(GS_SYNTH_VAL, (uint64_t)i),
                                  mix3(o->seed, TAG_TEST, (uint64_t)i, (uint64_t)j),
                                  &wr, &sc);
            rc = gs_eval_render_scene(&sc, r->S, r->d_n, r->focal, r->pool,
                                      &smp, err);
            if (rc)
                break;
            rset_add(&r->test, smp.rgb, smp.stride, r->S, &smp.labels);
            gs_eval_range_row *row = &r->res->rows[r->test.n - 1];
            const gs_synth_labels *l = &smp.labels;
            row->identity = i;
            row->index = j;
            row->gaze_pitch = l->gaze_norm_pitch / RG_DEG;
            row->gaze_yaw = l->gaze_norm_yaw / RG_DEG;
            row->head_pitch = l->head_norm_pitch / RG_DEG;
            row->head_yaw = l->head_norm_yaw / RG_DEG;
            /* inside: the gaze (head frame) within the source's range,
             * whatever the head */
            row->in_source_range = fabs(sc.gaze_pitch) <= o->src_gaze_pitch &&
                                   fabs(sc.gaze_yaw) <= o->src_gaze_yaw;
            gs_synth_sample_free(&smp);
        }
    return rc;
}

/* Trains condition c's estimator from scratch and measures it. */
static int train_and_test(range_run *r, int c, const char *est_dir,
                          gs_error *err)
{
    const gs_eval_range_options *o = r->o;
    const rset *src = &r->set[GS_EVAL_RANGE_SOURCE];
    const rset *add = c == GS_EVAL_RANGE_SOURCE ? NULL : &r->set[c];
    size_t n = src->n + (add ? add->n : 0);
    const uint8_t **img = malloc(n * sizeof *img);
    const float **lab = malloc(n * sizeof *lab);
    float *x = malloc(r->test.len * sizeof(float));
    gs_gaze_net *net = NULL;
    int rc = img && lab && x ? GS_OK
                             : gs_error_set(err, GS_ERR_NOMEM, "eval-range: "
                                            "out of memory");
    for (size_t i = 0; !rc && i < n; i++) {
        const rset *s = i < src->n ? src : add;
        size_t k = i < src->n ? i : i - src->n;
        img[i] = s->chw + k * s->len;
        lab[i] = s->lab + 4 * k;
    }
    gs_gaze_spec spec;
    gs_gaze_spec_default(&spec, GS_GAZE_RESNET);
    if (!rc)
        rc = gs_gaze_net_create(&spec, splitmix(o->seed ^ TAG_INIT), &net, err);
    gs_gaze_train_options to;
    gs_gaze_train_options_default(&to);
    to.steps = o->steps;
    to.batch = o->batch;
    to.lr = o->lr;
    to.seed = o->seed;
    to.checkpoint_every = 0;
    to.log_every = o->steps >= 10 ? o->steps / 10 : 1;
    to.log = o->log;
    to.log_ctx = o->log_ctx;
    to.data = img;
    to.data_lab = lab;
    to.data_n = n;
    to.data_size = r->S;
    gs_gaze_train_report rep = {0};
    double t0 = gs_clock_s();
    if (!rc)
        rc = gs_gaze_train(net, &to, r->pool, &rep, err);
    r->res->train_s[c] = gs_clock_s() - t0;
    r->res->train_loss[c] = rep.final_loss;
    r->res->set_size[c] = (long)n;
    for (size_t t = 0; !rc && t < r->test.n; t++) {
        for (size_t p = 0; p < r->test.len; p++)
            x[p] = r->test.chw[t * r->test.len + p] / 255.0f;
        float out[4];
        const float *tl = r->test.lab + 4 * t;
        rc = gs_gaze_net_forward(net, r->pool, x, r->S, r->S, out, err);
        r->res->rows[t].err[c] = gs_eval_angle_deg(out[0], out[1], tl[0], tl[1]);
    }
    if (!rc && est_dir) {
        char path[4200];
        snprintf(path, sizeof path, "%s/%s.safetensors", est_dir,
                 gs_eval_range_condition_name(c));
        rc = gs_gaze_net_save(net, path, err);
    }
    gs_gaze_net_destroy(net);
    free(img);
    free(lab);
    free(x);
    return rc;
}

static int run_alloc(range_run *r)
{
    const gs_eval_range_options *o = r->o;
    size_t ns = (size_t)o->sources * (size_t)o->per_source;
    size_t nt = (size_t)o->sources * (size_t)o->targets;
    size_t ntest = (size_t)o->tests * (size_t)o->per_test;
    r->src_smp = calloc(ns, sizeof *r->src_smp);
    r->src_sc = calloc(ns, sizeof *r->src_sc);
    r->out = malloc(3 * (size_t)r->S * (size_t)r->S);
    r->res->rows = calloc(ntest, sizeof *r->res->rows);
    r->res->n = (int)ntest;
    if (!r->src_smp || !r->src_sc || !r->out || !r->res->rows ||
        rset_alloc(&r->set[GS_EVAL_RANGE_SOURCE], ns, r->S) ||
        rset_alloc(&r->test, ntest, r->S))
        return GS_ERR_NOMEM;
    for (int c = 1; c < GS_EVAL_RANGE_CONDITIONS; c++)
        if (rset_alloc(&r->set[c], nt, r->S))
            return GS_ERR_NOMEM;
    for (size_t t = 0; t < ntest; t++)
        for (int c = 0; c < GS_EVAL_RANGE_CONDITIONS; c++)
            r->res->rows[t].err[c] = NAN;
    return GS_OK;
}

static void run_free(range_run *r)
{
    size_t ns = (size_t)r->o->sources * (size_t)r->o->per_source;
    for (size_t i = 0; r->src_smp && i < ns; i++)
        gs_synth_sample_free(&r->src_smp[i]);
    free(r->src_smp);
    free(r->src_sc);
    free(r->out);
    for (int c = 0; c < GS_EVAL_RANGE_CONDITIONS; c++)
        rset_free(&r->set[c]);
    rset_free(&r->test);
}

int gs_eval_range(const gs_model *m, const gs_eval_range_options *o,
                  const char *est_dir, gs_pool *pool,
                  gs_eval_range_result *res, gs_error *err)
{
    if (!m || !res)
        return gs_error_set(err, GS_ERR_ARG, "eval-range: NULL argument");
    memset(res, 0, sizeof *res);
    int rc = gs_eval_range_options_check(o, err);
    if (rc)
        return rc;
    gs_model_info mi;
    gs_model_get_info(m, &mi);
    range_run r;
    memset(&r, 0, sizeof r);
    r.o = o;
    r.S = mi.image_size;
    r.focal = mi.focal;
    r.d_n = mi.distance_mm;
    r.pool = pool;
    r.res = res;
    if (run_alloc(&r))
        rc = gs_error_set(err, GS_ERR_NOMEM, "eval-range: out of memory");
    if (!rc)
        rc = make_sources(&r, err);
    if (!rc)
        rc = make_redirected(&r, m, err);
    if (!rc)
        rc = make_tests(&r, err);
    for (int c = 0; !rc && c < GS_EVAL_RANGE_CONDITIONS; c++) {
        log_step(&r, "training estimator", c + 1, GS_EVAL_RANGE_CONDITIONS);
        rc = train_and_test(&r, c, est_dir, err);
    }
    run_free(&r);
    if (rc)
        gs_eval_range_result_free(res);
    return rc;
}
