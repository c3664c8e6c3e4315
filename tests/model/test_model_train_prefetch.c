/* Training's samples made ahead on a second thread (gs_train_options.
 * sync_samples 0, the default) against each made at its step (1), on a
 * tiny model from one starting file. Checked: the weights and the optimizer
 * state are the same bytes with and without the producer, on no pool and on
 * a pool of two, and with each sample rendered on a pool of its own
 * (sample_threads 3, ahead and at its step); sample_threads out of its
 * bounds is refused; a run stopped after 7 steps and resumed to 12 (the
 * producer starts mid-stream) gives the bytes and the running mean loss of
 * the run without a stop (FILE.opt keeps the lights seen, for the saved
 * mean light, and the spike guard's running mean; a
 * FILE.opt whose lights are not 12 numbers is refused); a run of one
 * step
 * (nothing asked ahead) works; and the 12 steps did move the weights (so
 * the comparisons could fail). */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "gazesplat/nn.h"
#include "gazesplat/pool.h"
#include "gazesplat/safetensors.h"
#include "gazesplat/train.h"
#include "gs_test.h"
#include "model_test_util.h"

static char g_path[128], g_opt[160];
static gs_model *g_start; /* the starting point, kept in memory */

/* The bytes of a file (len), NULL when unreadable. */
static unsigned char *slurp(const char *path, size_t *len)
{
    FILE *f = fopen(path, "rb");
    if (!f)
        return NULL;
    fseek(f, 0, SEEK_END);
    long n = ftell(f);
    fseek(f, 0, SEEK_SET);
    unsigned char *b = n > 0 ? malloc((size_t)n) : NULL;
    if (b && fread(b, 1, (size_t)n, f) != (size_t)n) {
        free(b);
        b = NULL;
    }
    fclose(f);
    *len = b ? (size_t)n : 0;
    return b;
}

typedef struct run_out {
    float *params;
    unsigned char *opt;
    size_t opt_len;
    long steps;
    double final_loss; /* the running mean (the spike guard's) */
} run_out;

static void run_free(run_out *r)
{
    free(r->params);
    free(r->opt);
    memset(r, 0, sizeof *r);
}

/* Trains from the starting point to `steps` (stopping at `stop_at` first
 * and resuming from there when stop_at > 0). */
static int g_sample_threads; /* gs_train_options.sample_threads of run() */

static int run(int sync, gs_pool *pool, long stop_at, long steps, run_out *out)
{
    memset(out, 0, sizeof *out);
    gs_error err = {0, ""};
    if (gs_model_write(g_start, g_path, &err) != GS_OK)
        return -1;
    remove(g_opt);
    gs_model *m = NULL;
    if (gs_model_load(g_path, &m, &err) != GS_OK)
        return -1;
    gs_train_options o;
    gs_train_options_default(&o);
    o.out_path = g_path;
    o.checkpoint_every = 5;
    o.sync_samples = sync;
    o.sample_threads = g_sample_threads;
    gs_train_report rep;
    int rc = GS_OK;
    if (stop_at > 0) {
        o.steps = stop_at;
        rc = gs_train(m, &o, pool, &rep, &err);
        gs_model_destroy(m);
        m = NULL;
        if (rc == GS_OK)
            rc = gs_model_load(g_path, &m, &err);
        o.resume = 1;
    }
    if (rc == GS_OK) {
        o.steps = steps;
        rc = gs_train(m, &o, pool, &rep, &err);
    }
    CHECK_MSG(rc == GS_OK, "train (sync %d, stop %ld): %s", sync, stop_at, err.msg);
    if (rc == GS_OK) {
        out->steps = rep.steps;
        out->final_loss = rep.final_loss;
        out->params = malloc(m->nparams * sizeof(float));
        if (out->params)
            memcpy(out->params, m->params, m->nparams * sizeof(float));
        out->opt = slurp(g_opt, &out->opt_len);
    }
    gs_model_destroy(m);
    return rc;
}

static void same(const run_out *a, const run_out *b, size_t n, const char *what)
{
    CHECK_MSG(a->params && b->params &&
                  memcmp(a->params, b->params, n * sizeof(float)) == 0,
              "%s: the weights differ", what);
    CHECK_MSG(a->opt && b->opt && a->opt_len == b->opt_len &&
                  memcmp(a->opt, b->opt, a->opt_len) == 0,
              "%s: the optimizer states differ", what);
    CHECK_EQ_INT((int)a->steps, (int)b->steps);
    CHECK_MSG(a->final_loss == b->final_loss, "%s: running mean loss %.17g against %.17g",
              what, a->final_loss, b->final_loss);
}

/* A resume whose FILE.opt carries malformed lights or running means:
 * refused, naming them. */
static void bad_lights(void)
{
    const char *bad[] = {"1,2", "1,2,3,4,5,6,7,8,9,10,11,x", "1,2,3,4,5,6,7,8,9,10,11,12,13",
                         "nan,2,3,4,5,6,7,8,9,10,11,12", "1,2,3,4,5,6,7,8,9,10,11,12"};
    for (size_t i = 0; i < sizeof bad / sizeof bad[0]; i++) {
        int means = i == 4; /* good lights, a bad running mean */
        gs_error err = {0, ""};
        CHECK(gs_model_write(g_start, g_path, &err) == GS_OK);
        gs_st_writer *w = gs_st_writer_create();
        CHECK(w != NULL);
        if (!w)
            return;
        gs_st_writer_meta(w, "step", "7");
        gs_st_writer_meta(w, "adam_steps", "7");
        gs_st_writer_meta(w, "light_sum", bad[i]);
        gs_st_writer_meta(w, "light_n", "7");
        if (means) {
            gs_st_writer_meta(w, "loss_mean", "0.5x");
            gs_st_writer_meta(w, "gaze_mean", "0");
            gs_st_writer_meta(w, "mean_n", "7");
        }
        CHECK(gs_st_writer_save(w, g_opt, &err) == GS_OK);
        gs_st_writer_destroy(w);
        gs_model *m = NULL;
        CHECK(gs_model_load(g_path, &m, &err) == GS_OK);
        gs_train_options o;
        gs_train_options_default(&o);
        o.out_path = g_path;
        o.resume = 1;
        o.steps = 9;
        int rc = m ? gs_train(m, &o, NULL, NULL, &err) : GS_ERR_ARG;
        CHECK_MSG(rc == GS_ERR_FORMAT && strstr(err.msg, means ? "loss_mean" : "light_sum"),
                  "lights \"%s\": %d \"%s\"", bad[i], rc, err.msg);
        gs_model_destroy(m);
    }
}

int main(void)
{
    gs_nn_blas_set_threads(1);
    tiny_path(g_path, "test_model_train_prefetch");
    snprintf(g_opt, sizeof g_opt, "%s.opt", g_path);
    gs_model_spec spec;
    gs_model_spec_default(&spec);
    spec.preset = "tiny";
    spec.train_identities = 2;
    gs_error err = {0, ""};
    CHECK(gs_model_new(&spec, 5, &g_start, &err) == GS_OK);
    gs_pool *pool = gs_pool_create(2);
    CHECK(pool != NULL);
    if (!g_start || !pool)
        GS_TEST_END();
    size_t n = g_start->nparams;

    run_out sync, ahead, ahead2, resumed, one_sync, one_ahead;
    CHECK_EQ_INT(run(1, NULL, 0, 12, &sync), GS_OK);
    CHECK_EQ_INT(run(0, NULL, 0, 12, &ahead), GS_OK);
    CHECK_EQ_INT(run(0, pool, 0, 12, &ahead2), GS_OK);
    CHECK_EQ_INT(run(0, pool, 7, 12, &resumed), GS_OK);
    CHECK_EQ_INT(run(1, NULL, 0, 1, &one_sync), GS_OK);
    CHECK_EQ_INT(run(0, NULL, 0, 1, &one_ahead), GS_OK);
    run_out st_ahead, st_sync;
    g_sample_threads = 3;
    CHECK_EQ_INT(run(0, pool, 0, 12, &st_ahead), GS_OK);
    CHECK_EQ_INT(run(1, NULL, 0, 12, &st_sync), GS_OK);
    g_sample_threads = 0;

    size_t moved = 0;
    for (size_t i = 0; sync.params && i < n; i++)
        moved += sync.params[i] != g_start->params[i];
    CHECK_MSG(moved > n / 4, "12 steps moved %zu of %zu weights", moved, n);
    CHECK_EQ_INT((int)sync.steps, 12);
    same(&sync, &ahead, n, "made ahead, no pool");
    same(&sync, &ahead2, n, "made ahead, a pool of two");
    same(&sync, &resumed, n, "stopped at 7 and resumed");
    same(&one_sync, &one_ahead, n, "one step");
    same(&sync, &st_ahead, n, "samples on a pool of three, made ahead");
    same(&sync, &st_sync, n, "samples on a pool of three, made at their steps");
    for (int bad = -1; bad <= GS_TRAIN_SAMPLE_THREADS_MAX + 1; bad += GS_TRAIN_SAMPLE_THREADS_MAX + 2) {
        gs_train_options o;
        gs_train_options_default(&o);
        o.out_path = g_path;
        o.steps = 1;
        o.sample_threads = bad;
        gs_error e = {0, ""};
        int rc = gs_train(g_start, &o, NULL, NULL, &e);
        CHECK_MSG(rc == GS_ERR_ARG && strstr(e.msg, "sample threads"),
                  "sample_threads %d: %d \"%s\"", bad, rc, e.msg);
    }
    CHECK_MSG(one_sync.params && sync.params &&
                  memcmp(one_sync.params, sync.params, n * sizeof(float)) != 0,
              "one step and twelve gave the same weights");

    bad_lights();
    run_free(&sync);
    run_free(&ahead);
    run_free(&ahead2);
    run_free(&resumed);
    run_free(&one_sync);
    run_free(&one_ahead);
    run_free(&st_ahead);
    run_free(&st_sync);
    gs_pool_destroy(pool);
    gs_model_destroy(g_start);
    tiny_remove(g_path);
    GS_TEST_END();
}
