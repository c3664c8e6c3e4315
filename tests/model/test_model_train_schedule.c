/* The training's learning-rate schedule and its fresh-optimizer resume
 * (gs_train_options.cosine, fresh_from_step, warmup), on a tiny model.
 * Checked: the curve's values (lr at its first step, lr / 20 at the last,
 * the half-way point, clamped outside, the ramp's (done + 1) / warmup);
 * a resume without FILE.opt is refused with a message naming the way out;
 * a fresh-optimizer resume trains from the given step, writes the step and
 * the curve's first step into FILE.opt, moves the weights, and gives the
 * same bytes twice; a plain resume of that run continues the same curve
 * (FILE.opt's first step is kept); a huge ramp moves the weights far less
 * than no ramp; a head range out of bounds is refused; gradient-norm
 * clipping (max_grad_norm) changes the run when it bites, gives the bytes
 * of no clipping when the bound is never reached, and bad bounds are
 * refused. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "gazesplat/nn.h"
#include "gazesplat/safetensors.h"
#include "gazesplat/train.h"
#include "gs_test.h"
#include "model_test_util.h"

static char g_path[128], g_opt[160];

static long opt_meta(const char *key)
{
    gs_st_file *f = NULL;
    gs_error err = {0, ""};
    if (gs_st_open(g_opt, NULL, &f, &err) != GS_OK)
        return -2;
    const char *v = gs_st_meta(f, key);
    long r = v ? atol(v) : -1;
    gs_st_close(f);
    return r;
}

/* Parameters that moved by more than 1e-6 (the saved light statistics
 * change whatever the learning rate: a handful). */
static size_t moved(const float *a, const gs_model *m)
{
    size_t k = 0;
    for (size_t i = 0; i < m->nparams; i++)
        k += fabs((double)a[i] - (double)m->params[i]) > 1e-6;
    return k;
}

static void curve(void)
{
    gs_train_options o;
    gs_train_options_default(&o);
    CHECK(o.fresh_from_step == -1 && o.cosine == 0 && o.warmup == 200);
    o.lr = 1e-3;
    o.steps = 1100;
    CHECK_CLOSE(gs_train_lr(&o, 100, 600, -1), 1e-3, 0, 0); /* constant */
    o.cosine = 1;
    CHECK_CLOSE(gs_train_lr(&o, 100, 100, -1), 1e-3, 1e-15, 0);
    CHECK_CLOSE(gs_train_lr(&o, 100, 1100, -1), 5e-5, 1e-15, 0);
    CHECK_CLOSE(gs_train_lr(&o, 100, 600, -1), 1e-3 * (0.05 + 0.95 * 0.5), 1e-15, 0);
    CHECK_CLOSE(gs_train_lr(&o, 100, 50, -1), 1e-3, 1e-15, 0);    /* before: clamped */
    CHECK_CLOSE(gs_train_lr(&o, 100, 5000, -1), 5e-5, 1e-15, 0);  /* after: clamped */
    double prev = 1;
    int falls = 1;
    for (long s = 100; s <= 1100; s += 50) {
        double lr = gs_train_lr(&o, 100, s, -1);
        falls &= lr < prev;
        prev = lr;
    }
    CHECK_MSG(falls, "the cosine does not fall step after step");
    o.cosine = 0;
    CHECK_CLOSE(gs_train_lr(&o, 0, 7, 0), 1e-3 / 200, 1e-18, 0);
    CHECK_CLOSE(gs_train_lr(&o, 0, 7, 99), 1e-3 * 100 / 200, 1e-15, 0);
    CHECK_CLOSE(gs_train_lr(&o, 0, 7, 200), 1e-3, 0, 0);
}

/* Trains m (loaded from g_path) with o; returns the status. */
static int train_file(gs_train_options *o, gs_model **out, gs_train_report *rep,
                      gs_error *err)
{
    gs_model *m = NULL;
    int rc = gs_model_load(g_path, &m, err);
    if (rc == GS_OK)
        rc = gs_train(m, o, NULL, rep, err);
    *out = m;
    return rc;
}

static void fresh_resume(void)
{
    gs_error err = {0, ""};
    gs_train_report rep;
    gs_model *m0 = trained_tiny(g_path, 1, &rep, &err); /* the starting point */
    CHECK_MSG(m0 != NULL, "tiny model: %s", err.msg);
    if (!m0)
        return;
    CHECK(gs_model_write(m0, g_path, &err) == GS_OK);
    remove(g_opt);

    gs_train_options o;
    gs_train_options_default(&o);
    o.out_path = g_path;
    o.checkpoint_every = 0;
    o.resume = 1;
    o.steps = 13;
    gs_model *m = NULL;
    int rc = train_file(&o, &m, &rep, &err);
    CHECK_MSG(rc != GS_OK && strstr(err.msg, "optimizer state") && strstr(err.msg, "fresh"),
              "resume without FILE.opt: %d \"%s\"", rc, err.msg);
    gs_model_destroy(m);

    /* fresh from step 10 to 13, twice from the same file: same bytes */
    o.fresh_from_step = 10;
    o.cosine = 1;
    o.warmup = 2;
    float *a = NULL;
    size_t n = m0->nparams;
    for (int run = 0; run < 2; run++) {
        CHECK(gs_model_write(m0, g_path, &err) == GS_OK);
        remove(g_opt);
        CHECK_EQ_INT(train_file(&o, &m, &rep, &err), GS_OK);
        CHECK_EQ_INT((int)rep.steps, 13);
        CHECK_EQ_INT((int)opt_meta("step"), 13);
        CHECK_EQ_INT((int)opt_meta("schedule_first"), 10);
        CHECK_EQ_INT((int)opt_meta("adam_steps"), 3);
        if (m && run == 0) {
            CHECK_MSG(moved(m0->params, m) > n / 4, "three steps moved %zu of %zu parameters",
                      moved(m0->params, m), n);
            a = malloc(n * sizeof(float));
            memcpy(a, m->params, n * sizeof(float));
        } else if (m && a) {
            CHECK_MSG(memcmp(a, m->params, n * sizeof(float)) == 0,
                      "two fresh resumes differ");
        }
        gs_model_destroy(m);
        m = NULL;
    }

    /* a plain resume of it continues the curve that starts at 10 */
    o.fresh_from_step = -1;
    o.steps = 15;
    CHECK_EQ_INT(train_file(&o, &m, &rep, &err), GS_OK);
    CHECK_EQ_INT((int)opt_meta("step"), 15);
    CHECK_EQ_INT((int)opt_meta("schedule_first"), 10);
    CHECK_EQ_INT((int)opt_meta("adam_steps"), 5);
    gs_model_destroy(m);

    /* one step with a ramp of a million steps against one without */
    o.fresh_from_step = 0;
    o.cosine = 0;
    o.steps = 1;
    size_t d_ramp = 0, d_none = 0;
    for (int k = 0; k < 2; k++) {
        o.warmup = k == 0 ? 1000000 : 0;
        CHECK(gs_model_write(m0, g_path, &err) == GS_OK);
        remove(g_opt);
        CHECK_EQ_INT(train_file(&o, &m, &rep, &err), GS_OK);
        if (m)
            *(k == 0 ? &d_ramp : &d_none) = moved(m0->params, m);
        gs_model_destroy(m);
        m = NULL;
    }
    printf("one step: %zu of %zu parameters moved by > 1e-6 with no ramp, %zu with a ramp "
           "of 1e6 steps\n", d_none, n, d_ramp);
    CHECK_MSG(d_none > n / 4 && d_ramp * 100 < d_none,
              "ramp: %zu moved against %zu without", d_ramp, d_none);
    free(a);
    gs_model_destroy(m0);
}

/* A run of `steps` from m0: m0 written to g_path without FILE.opt, the
 * default options but for no checkpoints. */
static void from_m0(const gs_model *m0, long steps, gs_train_options *o, gs_error *err)
{
    CHECK(gs_model_write(m0, g_path, err) == GS_OK);
    remove(g_opt);
    gs_train_options_default(o);
    o->out_path = g_path;
    o->checkpoint_every = 0;
    o->steps = steps;
}

/* The sample stream's head range: 0 is the default's 40,25, a set range
 * is taken; ranges outside 1..60 (yaw) and 1..40 (pitch) degrees, or not
 * a number, are refused before a step, the model untouched. */
static void head_range(void)
{
    gs_error err = {0, ""};
    gs_train_report rep;
    gs_model *m0 = trained_tiny(g_path, 1, &rep, &err);
    CHECK_MSG(m0 != NULL, "tiny model: %s", err.msg);
    if (!m0)
        return;
    /* the sample stream takes the range (and the model's identities) */
    {
        gs_train_options o;
        gs_train_options_default(&o);
        gs_synth_gen_config gen;
        gs_train_sample_config(m0, &o, &gen);
        CHECK_CLOSE(gen.ranges.head_yaw, 40 * GS_MODEL_PI / 180, 1e-12, 0);
        CHECK_CLOSE(gen.ranges.head_pitch, 25 * GS_MODEL_PI / 180, 1e-12, 0);
        CHECK(gen.split == GS_SYNTH_TRAIN && gen.seed == 1 &&
              gen.identities == (uint64_t)m0->cfg.n_train_ids &&
              gen.size == m0->cfg.image_size);
        o.head_yaw_deg = 50, o.head_pitch_deg = 30, o.seed = 9;
        gs_train_sample_config(m0, &o, &gen);
        CHECK_CLOSE(gen.ranges.head_yaw, 50 * GS_MODEL_PI / 180, 1e-12, 0);
        CHECK_CLOSE(gen.ranges.head_pitch, 30 * GS_MODEL_PI / 180, 1e-12, 0);
        CHECK(gen.seed == 9);
    }
    const double bad[][2] = {{61, 25}, {0.5, 25}, {-40, 25}, {40, 41},
                             {40, 0.5}, {NAN, 25}, {40, INFINITY}};
    /* the one check behind them (and the CLI's and the bench's) */
    CHECK(gs_train_check_head_range(0, 0, NULL) == GS_OK);
    CHECK(gs_train_check_head_range(60, 40, NULL) == GS_OK);
    CHECK(gs_train_check_head_range(1, 1, NULL) == GS_OK);
    for (size_t i = 0; i < sizeof bad / sizeof bad[0]; i++) {
        gs_error e = {0, ""};
        CHECK(gs_train_check_head_range(bad[i][0], bad[i][1], &e) == GS_ERR_ARG &&
              strstr(e.msg, "head range") && strstr(e.msg, "1..60"));
    }
    for (size_t i = 0; i < sizeof bad / sizeof bad[0]; i++) {
        gs_train_options o;
        from_m0(m0, 1, &o, &err);
        CHECK(o.head_yaw_deg == 0 && o.head_pitch_deg == 0);
        o.head_yaw_deg = bad[i][0];
        o.head_pitch_deg = bad[i][1];
        gs_model *m = NULL;
        int rc = train_file(&o, &m, &rep, &err);
        CHECK_MSG(rc == GS_ERR_ARG && strstr(err.msg, "head range"),
                  "head range %g,%g: %d \"%s\"", bad[i][0], bad[i][1], rc, err.msg);
        if (m)
            CHECK_MSG(moved(m0->params, m) == 0, "a refused head range moved the model");
        gs_model_destroy(m);
    }
    gs_model_destroy(m0);
}

/* Six steps from the tiny model m0 with max_grad_norm `clip`: the
 * weights (malloc'd), or NULL when the run fails (its status in *rc). */
static float *clipped_run(const gs_model *m0, double clip, int *rc, gs_error *err)
{
    gs_train_report rep;
    gs_train_options o;
    from_m0(m0, 6, &o, err);
    o.max_grad_norm = clip;
    gs_model *m = NULL;
    *rc = train_file(&o, &m, &rep, err);
    float *w = NULL;
    if (*rc == GS_OK && m) {
        w = malloc(m->nparams * sizeof(float));
        if (w)
            memcpy(w, m->params, m->nparams * sizeof(float));
    }
    gs_model_destroy(m);
    return w;
}

static void clip(void)
{
    gs_error err = {0, ""};
    gs_train_report rep;
    gs_model *m0 = trained_tiny(g_path, 1, &rep, &err);
    CHECK_MSG(m0 != NULL, "tiny model: %s", err.msg);
    if (!m0)
        return;
    gs_train_options d;
    gs_train_options_default(&d);
    CHECK(d.max_grad_norm == 0);
    size_t n = m0->nparams;
    int rc;
    float *none = clipped_run(m0, 0, &rc, &err);
    float *huge = clipped_run(m0, 1e6, &rc, &err);
    float *tight = clipped_run(m0, 1e-4, &rc, &err);
    CHECK_MSG(none && huge && tight, "clip runs: %s", err.msg);
    if (none && huge && tight) {
        CHECK_MSG(memcmp(none, huge, n * sizeof(float)) == 0,
                  "a bound never reached changed the run");
        CHECK_MSG(memcmp(none, tight, n * sizeof(float)) != 0,
                  "a bound of 1e-4 did not change the run");
        CHECK_MSG(moved(tight, m0) > n / 4, "the clipped run moved %zu of %zu weights",
                  moved(tight, m0), n);
    }
    free(none);
    free(huge);
    free(tight);
    const double bad[] = {-1, 2e6, NAN, INFINITY};
    for (size_t i = 0; i < sizeof bad / sizeof bad[0]; i++) {
        float *w = clipped_run(m0, bad[i], &rc, &err);
        CHECK_MSG(!w && rc == GS_ERR_ARG && strstr(err.msg, "clip"),
                  "clip %g: %d \"%s\"", bad[i], rc, err.msg);
        free(w);
    }
    gs_model_destroy(m0);
}

int main(void)
{
    gs_nn_blas_set_threads(1);
    tiny_path(g_path, "test_model_train_schedule");
    snprintf(g_opt, sizeof g_opt, "%s.opt", g_path);
    curve();
    fresh_resume();
    head_range();
    clip();
    tiny_remove(g_path);
    GS_TEST_END();
}
