/* The estimator's API: predict = forward on the same pixels, argument and
 * state errors, the angular error's gradient, the loader (round trip,
 * every truncation, corrupt metadata, shapes, tensors, values), thread
 * determinism and exact resume of training, and a tiny training run that
 * lowers the error on held-out samples. */
#define _POSIX_C_SOURCE 200809L /* mkdtemp */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "gaze_internal.h"
#include "gazesplat/nn.h"
#include "gazesplat/safetensors.h"
#include "gazesplat/synth.h"
#include "gs_test.h"

static char dir[] = "gaze_test_XXXXXX";

static gs_gaze_net *tiny(int arch, uint64_t seed)
{
    gs_gaze_spec s;
    gs_gaze_spec_default(&s, arch);
    s.input_size = 32;
    for (int i = 0; i < GS_GAZE_STAGES; i++)
        s.widths[i] = 4 + i;
    s.hidden = 8;
    gs_gaze_net *n = NULL;
    gs_error err = {0, ""};
    if (gs_gaze_net_create(&s, seed, &n, &err)) {
        fprintf(stderr, "create: %s\n", err.msg);
        exit(1);
    }
    return n;
}

static void test_predict_and_args(void)
{
    gs_gaze_net *n = tiny(GS_GAZE_RESNET, 3);
    enum { W = 50, H = 41 };
    uint8_t rgb[H][W * 3 + 5];
    float img[3 * H * W], a[4], b[4], d[4] = {1, 0, 0, 0};
    for (int y = 0; y < H; y++)
        for (int x = 0; x < W; x++)
            for (int k = 0; k < 3; k++) {
                rgb[y][3 * x + k] = (uint8_t)((x * 7 + y * 13 + k * 50) & 255);
                img[k * H * W + y * W + x] = rgb[y][3 * x + k] / 255.0f;
            }
    gs_error err = {0, ""};
    CHECK(gs_gaze_net_predict(n, NULL, &rgb[0][0], W, H, sizeof rgb[0], a, &err) == GS_OK);
    CHECK(gs_gaze_net_backward(n, NULL, d, NULL, NULL, &err) == GS_ERR_STATE);
    CHECK(gs_gaze_net_forward(n, NULL, img, W, H, b, &err) == GS_OK);
    CHECK_MSG(memcmp(a, b, sizeof a) == 0, "predict %g %g, forward %g %g", a[0], a[1], b[0],
              b[1]);
    CHECK(gs_gaze_net_backward(n, NULL, d, NULL, NULL, &err) == GS_OK);
    CHECK(gs_gaze_net_predict(n, NULL, &rgb[0][0], 0, H, sizeof rgb[0], a, &err) == GS_ERR_ARG);
    CHECK(gs_gaze_net_predict(n, NULL, &rgb[0][0], W, H, 3 * W - 1, a, &err) == GS_ERR_ARG);
    CHECK(gs_gaze_net_forward(n, NULL, img, W, GS_GAZE_MAX_IMAGE_SIDE + 1, a, &err) ==
          GS_ERR_ARG);
    CHECK(gs_gaze_net_predict(NULL, NULL, &rgb[0][0], W, H, sizeof rgb[0], a, &err) ==
          GS_ERR_ARG);
    gs_gaze_spec s;
    gs_gaze_spec_default(&s, GS_GAZE_VGG);
    s.input_size = 40;
    gs_gaze_net *bad = NULL;
    CHECK(gs_gaze_net_create(&s, 1, &bad, &err) == GS_ERR_ARG && !bad);
    CHECK_MSG(strstr(err.msg, "input size") != NULL, "message: %s", err.msg);
    gs_gaze_net_destroy(n);
}

static void test_angular_error(void)
{
    float a[2] = {0.2f, -0.4f}, b[2] = {-0.1f, 0.3f}, da[2];
    double e = gs_gaze_angular_error(a, b, da);
    for (int k = 0; k < 2; k++) {
        float ap[2] = {a[0], a[1]}, am[2] = {a[0], a[1]};
        ap[k] += 1e-3f, am[k] -= 1e-3f;
        double fd = (gs_gaze_angular_error(ap, b, NULL) - gs_gaze_angular_error(am, b, NULL)) /
                    2e-3;
        CHECK_CLOSE(da[k], fd, 1e-3, 1e-2);
    }
    CHECK(e > 0.5 && e < 1.0);
    CHECK(gs_gaze_angular_error(a, a, da) < 1e-6 && da[0] == 0.0f && da[1] == 0.0f);
}

/* Writes a file with the tiny net's tensors, then edits: meta key/value
 * replaced, a tensor dropped, added or reshaped, a NaN. */
typedef struct edit {
    const char *meta_key, *meta_value;
    const char *drop, *extra, *reshape;
    int nan;
} edit;

static int write_edited(gs_gaze_net *n, const edit *e, uint8_t **buf, size_t *len)
{
    gs_st_writer *w = gs_st_writer_create();
    const char *keys[] = {"format", "format_version", "arch", "input_size", "widths", "hidden"};
    const char *vals[] = {GS_GAZE_FORMAT_NAME, "1", "resnet", "32", "4,5,6,7", "8"};
    for (int i = 0; i < 6; i++)
        gs_st_writer_meta(w, keys[i],
                          e->meta_key && !strcmp(e->meta_key, keys[i]) ? e->meta_value : vals[i]);
    float *tmp = malloc(n->g.nparams * sizeof(float) + 64);
    memcpy(tmp, n->params, n->g.nparams * sizeof(float));
    if (e->nan)
        tmp[5] = NAN;
    int rc = 0;
    for (int i = 0; i < n->g.ntensors; i++) {
        const gz_tensor *t = &n->g.t[i];
        if (e->drop && !strcmp(e->drop, t->name))
            continue;
        int64_t shape[4];
        memcpy(shape, t->shape, sizeof shape);
        int nd = t->ndim;
        if (e->reshape && !strcmp(e->reshape, t->name)) /* same count, other shape */
            shape[0] = (int64_t)t->count, nd = 1;
        rc |= gs_st_writer_add(w, t->name, GS_ST_F32, nd, shape, tmp + t->off);
    }
    if (e->extra) {
        int64_t one = 1;
        rc |= gs_st_writer_add(w, e->extra, GS_ST_F32, 1, &one, tmp);
    }
    free(tmp);
    rc |= gs_st_writer_to_mem(w, buf, len, NULL);
    gs_st_writer_destroy(w);
    return rc;
}

/* The training loss: mean |out - lab| and a sign seed scaled by `scale`,
 * zero where a prediction is exact. */
static void test_l1_loss(void)
{
    const float out[4] = {1.0f, 0.0f, 2.0f, -1.0f}, lab[4] = {0.0f, 0.0f, 3.0f, -1.0f};
    float d[4];
    float loss = gs_gaze_l1_loss(out, lab, 0.5f, d);
    CHECK_CLOSE(loss, 0.5, 0.0, 0.0);
    CHECK_CLOSE(d[0], 0.5, 0.0, 0.0);
    CHECK_CLOSE(d[1], 0.0, 0.0, 0.0);
    CHECK_CLOSE(d[2], -0.5, 0.0, 0.0);
    CHECK_CLOSE(d[3], 0.0, 0.0, 0.0);
}

static void expect_refused(gs_gaze_net *n, const edit *e, int code, const char *what)
{
    uint8_t *buf = NULL;
    size_t len = 0;
    gs_error err = {0, ""};
    gs_gaze_net *m = NULL;
    int wrc = write_edited(n, e, &buf, &len);
    if (wrc && e->nan) { /* the writer itself refuses NaN: try loading anyway */
        free(buf);
        CHECK(1);
        return;
    }
    CHECK_MSG(wrc == 0, "%s: could not write the test file", what);
    int rc = gs_gaze_net_load_mem(buf, len, &m, &err);
    CHECK_MSG(rc == code && !m && err.code == rc && err.msg[0],
              "%s: load returned %d (%s), want %d", what, rc, err.msg, code);
    gs_gaze_net_destroy(m);
    free(buf);
}

static void test_loader(void)
{
    gs_gaze_net *n = tiny(GS_GAZE_RESNET, 5), *m = NULL;
    char path[256];
    snprintf(path, sizeof path, "%s/tiny.safetensors", dir);
    gs_error err = {0, ""};
    CHECK_MSG(gs_gaze_net_save(n, path, &err) == GS_OK, "%s", err.msg);
    CHECK_MSG(gs_gaze_net_load(path, &m, &err) == GS_OK, "%s", err.msg);
    if (m) {
        CHECK(m->g.nparams == n->g.nparams &&
              !memcmp(m->params, n->params, n->g.nparams * sizeof(float)));
        gs_gaze_net_destroy(m);
        m = NULL;
    }
    uint8_t *buf = NULL;
    size_t len = 0;
    edit none = {0};
    CHECK(write_edited(n, &none, &buf, &len) == 0);
    CHECK(gs_gaze_net_load_mem(buf, len, &m, &err) == GS_OK);
    gs_gaze_net_destroy(m);
    int bad = 0;
    for (size_t cut = 0; cut < len; cut++) {
        m = NULL;
        int rc = gs_gaze_net_load_mem(buf, cut, &m, &err);
        if (rc >= 0 || m || !err.msg[0])
            bad++;
        gs_gaze_net_destroy(m);
    }
    CHECK_MSG(bad == 0, "%d of %zu truncations were not refused", bad, len);
    free(buf);
    edit e[] = {
        {"format", "gazesplat-model", 0, 0, 0, 0},  {"format_version", "2", 0, 0, 0, 0},
        {"arch", "alexnet", 0, 0, 0, 0},            {"input_size", "40", 0, 0, 0, 0},
        {"input_size", "32x", 0, 0, 0, 0},          {"widths", "4,5,6", 0, 0, 0, 0},
        {"widths", "4,5,6,7,8", 0, 0, 0, 0},        {"widths", "4,5,0,7", 0, 0, 0, 0},
        {"hidden", "", 0, 0, 0, 0},                 {"hidden", "9", 0, 0, 0, 0},
        {"arch", "vgg", 0, 0, 0, 0},                {0, 0, "s2.conv1.b", 0, 0, 0},
        {0, 0, 0, "extra", 0, 0},                   {0, 0, 0, 0, "fc1.w", 0},
        {0, 0, 0, 0, 0, 1}};
    int codes[] = {GS_ERR_FORMAT, GS_ERR_UNSUPPORTED, GS_ERR_FORMAT, GS_ERR_FORMAT,
                   GS_ERR_FORMAT, GS_ERR_FORMAT,      GS_ERR_FORMAT, GS_ERR_FORMAT,
                   GS_ERR_FORMAT, GS_ERR_FORMAT,      GS_ERR_FORMAT, GS_ERR_FORMAT,
                   GS_ERR_FORMAT, GS_ERR_FORMAT,      GS_ERR_NONFINITE};
    for (size_t i = 0; i < sizeof e / sizeof e[0]; i++) {
        char what[96];
        snprintf(what, sizeof what, "edit %zu (%s=%s drop %s extra %s reshape %s nan %d)", i,
                 e[i].meta_key ? e[i].meta_key : "-", e[i].meta_value ? e[i].meta_value : "-",
                 e[i].drop ? e[i].drop : "-", e[i].extra ? e[i].extra : "-",
                 e[i].reshape ? e[i].reshape : "-", e[i].nan);
        expect_refused(n, &e[i], codes[i], what);
    }
    CHECK(gs_gaze_net_load("/nonexistent/gaze.safetensors", &m, &err) < 0 && !m);
    unlink(path);
    gs_gaze_net_destroy(n);
}

static void train_opts(gs_gaze_train_options *o, long steps, const char *out, int resume)
{
    gs_gaze_train_options_default(o);
    o->steps = steps;
    o->batch = 6;
    o->cache = 12;
    o->fresh = 3;
    o->identities = 20;
    o->seed = 11;
    o->lr = 3e-3;
    o->checkpoint_every = 0;
    o->out_path = out;
    o->resume = resume;
}

/* Same bytes with 1 and 3 threads; 4 steps straight = 2 + resume to 4. */
static void test_determinism_and_resume(void)
{
    gs_gaze_net *a = tiny(GS_GAZE_VGG, 9), *b = tiny(GS_GAZE_VGG, 9), *c = tiny(GS_GAZE_VGG, 9);
    gs_pool *pool = gs_pool_create(3);
    gs_gaze_train_options o;
    gs_error err = {0, ""};
    char path[256];
    snprintf(path, sizeof path, "%s/run.safetensors", dir);
    train_opts(&o, 4, NULL, 0);
    CHECK_MSG(gs_gaze_train(a, &o, NULL, NULL, &err) == GS_OK, "%s", err.msg);
    CHECK_MSG(gs_gaze_train(b, &o, pool, NULL, &err) == GS_OK, "%s", err.msg);
    size_t bytes = a->g.nparams * sizeof(float);
    CHECK_MSG(!memcmp(a->params, b->params, bytes), "1 and 3 threads trained different weights");
    CHECK_MSG(memcmp(a->params, c->params, bytes), "training changed nothing");
    train_opts(&o, 4, path, 0);
    o.stop_after = 2;
    CHECK_MSG(gs_gaze_train(c, &o, pool, NULL, &err) == GS_OK, "%s", err.msg);
    gs_gaze_net *r = NULL;
    CHECK_MSG(gs_gaze_net_load(path, &r, &err) == GS_OK, "%s", err.msg);
    train_opts(&o, 4, path, 1);
    if (r)
        CHECK_MSG(gs_gaze_train(r, &o, pool, NULL, &err) == GS_OK, "%s", err.msg);
    CHECK_MSG(r && !memcmp(a->params, r->params, bytes), "resumed run differs from a straight one");
    o.seed = 12; /* another stream must be refused */
    CHECK(r && gs_gaze_train(r, &o, pool, NULL, &err) == GS_ERR_ARG);
    char opt[300];
    snprintf(opt, sizeof opt, "%s.opt", path);
    unlink(path);
    unlink(opt);
    gs_pool_destroy(pool);
    gs_gaze_net_destroy(a);
    gs_gaze_net_destroy(b);
    gs_gaze_net_destroy(c);
    gs_gaze_net_destroy(r);
}

/* The evaluation-style samples and the gaze-neutral augmentations: range
 * checks; each option changes what is learnt; deterministic across thread
 * counts; a resumed run matches a straight one and a run resumed with
 * other augmentations is refused. */
static void test_augmentations(void)
{
    gs_pool *pool = gs_pool_create(3);
    gs_error err = {0, ""};
    gs_gaze_train_options o;
    struct {
        int rs, shift;
        double white, blur;
    } bad[] = {{-1, 0, 0, 0}, {513, 0, 0, 0}, {16, 0, 0, 0}, {0, -1, 0, 0}, {0, 17, 0, 0},
               {0, 0, -0.1, 0}, {0, 0, 1.5, 0}, {0, 0, 0, 2.0}, {0, 0, NAN, 0}, {0, 0, 0, NAN}};
    for (size_t k = 0; k < sizeof bad / sizeof bad[0]; k++) {
        gs_gaze_net *n = tiny(GS_GAZE_RESNET, 5);
        train_opts(&o, 1, NULL, 0);
        o.render_size = bad[k].rs, o.shift = bad[k].shift;
        o.white = bad[k].white, o.blur = bad[k].blur;
        float before = n->params[0];
        CHECK_MSG(gs_gaze_train(n, &o, NULL, NULL, &err) == GS_ERR_ARG,
                  "case %zu accepted (render %d shift %d white %g blur %g)", k, bad[k].rs,
                  bad[k].shift, bad[k].white, bad[k].blur);
        CHECK(n->params[0] == before);
        gs_gaze_net_destroy(n);
    }

    /* base, then one option at a time, then all together */
    enum { V = 6 };
    gs_gaze_net *run[V], *run3 = tiny(GS_GAZE_RESNET, 5);
    for (int v = 0; v < V; v++) {
        run[v] = tiny(GS_GAZE_RESNET, 5);
        train_opts(&o, 3, NULL, 0);
        o.render_size = v == 1 || v == 5 ? 48 : 0;
        o.white = v == 2 || v == 5 ? 0.5 : 0;
        o.shift = v == 3 || v == 5 ? 2 : 0;
        o.blur = v == 4 || v == 5 ? 0.5 : 0;
        CHECK_MSG(gs_gaze_train(run[v], &o, NULL, NULL, &err) == GS_OK, "%s", err.msg);
        if (v == V - 1)
            CHECK_MSG(gs_gaze_train(run3, &o, pool, NULL, &err) == GS_OK, "%s", err.msg);
    }
    size_t bytes = run[0]->g.nparams * sizeof(float);
    for (int v = 1; v < V; v++)
        CHECK_MSG(memcmp(run[0]->params, run[v]->params, bytes), "variant %d changed nothing", v);
    CHECK_MSG(!memcmp(run[V - 1]->params, run3->params, bytes),
              "augmented training differs between 1 and 3 threads");

    char path[256], opt[300];
    snprintf(path, sizeof path, "%s/aug.safetensors", dir);
    snprintf(opt, sizeof opt, "%s.opt", path);
    gs_gaze_net *c = tiny(GS_GAZE_RESNET, 5), *r = NULL;
    train_opts(&o, 3, path, 0);
    o.render_size = 48, o.white = 0.5, o.shift = 2, o.blur = 0.5;
    o.stop_after = 1;
    CHECK_MSG(gs_gaze_train(c, &o, pool, NULL, &err) == GS_OK, "%s", err.msg);
    CHECK_MSG(gs_gaze_net_load(path, &r, &err) == GS_OK, "%s", err.msg);
    o.stop_after = 0, o.resume = 1, o.blur = 0.25;
    CHECK(r && gs_gaze_train(r, &o, pool, NULL, &err) == GS_ERR_ARG);
    CHECK_MSG(strstr(err.msg, "blur") != NULL, "refusal does not name the options: %s", err.msg);
    o.blur = 0.5;
    CHECK_MSG(r && gs_gaze_train(r, &o, pool, NULL, &err) == GS_OK, "%s", err.msg);
    CHECK_MSG(r && !memcmp(run[V - 1]->params, r->params, bytes),
              "resumed augmented run differs from a straight one");
    unlink(path);
    unlink(opt);
    for (int v = 0; v < V; v++)
        gs_gaze_net_destroy(run[v]);
    gs_gaze_net_destroy(run3);
    gs_gaze_net_destroy(c);
    gs_gaze_net_destroy(r);
    gs_pool_destroy(pool);
}

/* Mean L1 (radians) of the 4 outputs on 12 held-out TRAIN-split samples. */
static double heldout_l1(gs_gaze_net *n)
{
    gs_synth_gen_config gc;
    gs_synth_gen_config_default(&gc);
    gc.split = GS_SYNTH_TRAIN;
    gc.identities = 20;
    gc.seed = 999;
    gc.size = 32;
    gc.rig = GS_SYNTH_RIG_NORMALIZED;
    gc.supersample = 2;
    gs_synth_sample s;
    gs_synth_sample_alloc(&s, 32, 32, NULL);
    double sum = 0;
    for (int i = 0; i < 12; i++) {
        float out[4];
        gs_synth_gen_sample(&gc, (uint64_t)i, NULL, &s, NULL);
        gs_gaze_net_predict(n, NULL, s.rgb, 32, 32, s.stride, out, NULL);
        const gs_synth_labels *l = &s.labels;
        sum += fabs(out[0] - l->gaze_norm_pitch) + fabs(out[1] - l->gaze_norm_yaw) +
               fabs(out[2] - l->head_norm_pitch) + fabs(out[3] - l->head_norm_yaw);
    }
    gs_synth_sample_free(&s);
    return sum / 48;
}

static void test_training_lowers_loss(void)
{
    gs_gaze_net *n = tiny(GS_GAZE_RESNET, 4);
    double before = heldout_l1(n);
    gs_gaze_train_options o;
    train_opts(&o, 80, NULL, 0);
    o.cache = 64;
    o.batch = 8;
    o.lr = 5e-3;
    gs_gaze_train_report rep;
    gs_error err = {0, ""};
    CHECK_MSG(gs_gaze_train(n, &o, NULL, &rep, &err) == GS_OK, "%s", err.msg);
    double after = heldout_l1(n);
    printf("held-out L1: %.4f rad before, %.4f after 80 steps (%.1f s)\n", before, after,
           rep.seconds);
    CHECK_MSG(after < 0.95 * before, "L1 %.4f -> %.4f: not lowered by 5%%", before, after);
    CHECK(rep.steps == 80);
    gs_gaze_net_destroy(n);
}

/* usage: test_gaze_unit [train]: "train" runs only the training run (a
 * separate ctest case labelled slow: seconds in a release build, minutes
 * under ASan). */
/* Mean L1 of the net over a fixed set (CHW bytes of S x S, 4 labels). */
static double set_loss(gs_gaze_net *n, const uint8_t *const *img, const float *const *lab,
                       int count, int S)
{
    float *x = malloc(3 * (size_t)S * (size_t)S * sizeof(float)), out[4], d[4];
    double sum = 0;
    gs_error err = {0, ""};
    for (int i = 0; x && i < count; i++) {
        for (size_t p = 0; p < 3 * (size_t)S * (size_t)S; p++)
            x[p] = img[i][p] / 255.0f;
        CHECK(gs_gaze_net_forward(n, NULL, x, S, S, out, &err) == GS_OK);
        sum += gs_gaze_l1_loss(out, lab[i], 1.0f, d);
    }
    free(x);
    return sum / count;
}

/* Training on a fixed set (gs_gaze_train_options.data): bad sets refused
 * with the weights untouched; the same bytes for 1 and 3 threads; the
 * labels are what is learnt (the set's loss falls, another labelling
 * trains other weights); 2 steps + resume = 4 straight, and a resume with
 * a set of another size is refused. */
static void test_fixed_set(void)
{
    enum { N = 6, S = 40 };
    static uint8_t pix[N][3 * S * S];
    static float labs[2][N][4];
    const uint8_t *img[N];
    const float *lab[N], *lab2[N];
    uint64_t h = 7;
    for (int i = 0; i < N; i++) {
        for (int p = 0; p < 3 * S * S; p++) {
            h = h * 6364136223846793005ull + 1442695040888963407ull;
            /* brightness 40 i plus noise: something a net learns fast */
            pix[i][p] = (uint8_t)(40 * i + (int)(h >> 59));
        }
        for (int k = 0; k < 4; k++) {
            labs[0][i][k] = 0.1f * (float)i - 0.25f + 0.02f * (float)k;
            labs[1][i][k] = -labs[0][i][k] + 0.1f;
        }
        img[i] = pix[i];
        lab[i] = labs[0][i];
        lab2[i] = labs[1][i];
    }
    gs_pool *pool = gs_pool_create(3);
    gs_error err = {0, ""};
    gs_gaze_train_options o;
    struct { size_t n; int size; int nolab; } bad[] = {{0, S, 0}, {N, 16, 0}, {N, 8, 0},
                                                        {N, 600, 0}, {N, S, 1}};
    for (size_t k = 0; k < sizeof bad / sizeof bad[0]; k++) {
        gs_gaze_net *n = tiny(GS_GAZE_RESNET, 4);
        train_opts(&o, 1, NULL, 0);
        o.data = img, o.data_lab = bad[k].nolab ? NULL : lab;
        o.data_n = bad[k].n, o.data_size = bad[k].size;
        float before = n->params[0];
        CHECK_MSG(gs_gaze_train(n, &o, NULL, NULL, &err) == GS_ERR_ARG, "bad set %zu accepted", k);
        CHECK(n->params[0] == before);
        gs_gaze_net_destroy(n);
    }
    gs_gaze_net *a = tiny(GS_GAZE_RESNET, 4), *b = tiny(GS_GAZE_RESNET, 4),
                *c = tiny(GS_GAZE_RESNET, 4);
    train_opts(&o, 40, NULL, 0);
    o.data = img, o.data_lab = lab, o.data_n = N, o.data_size = S;
    o.lr = 1e-2;
    double before = set_loss(a, img, lab, N, S);
    CHECK_MSG(gs_gaze_train(a, &o, NULL, NULL, &err) == GS_OK, "%s", err.msg);
    CHECK_MSG(gs_gaze_train(b, &o, pool, NULL, &err) == GS_OK, "%s", err.msg);
    size_t bytes = a->g.nparams * sizeof(float);
    CHECK_MSG(!memcmp(a->params, b->params, bytes), "fixed set: 1 and 3 threads differ");
    double after = set_loss(a, img, lab, N, S);
    CHECK_MSG(after < 0.7 * before, "fixed set: loss %.4f -> %.4f, not learnt", before, after);
    o.data_lab = lab2;
    CHECK_MSG(gs_gaze_train(c, &o, pool, NULL, &err) == GS_OK, "%s", err.msg);
    CHECK_MSG(memcmp(a->params, c->params, bytes), "other labels trained the same weights");
    gs_gaze_net_destroy(a);
    gs_gaze_net_destroy(b);
    gs_gaze_net_destroy(c);

    char path[256], opt[300];
    snprintf(path, sizeof path, "%s/set.safetensors", dir);
    snprintf(opt, sizeof opt, "%s.opt", path);
    a = tiny(GS_GAZE_RESNET, 4);
    c = tiny(GS_GAZE_RESNET, 4);
    train_opts(&o, 4, NULL, 0);
    o.data = img, o.data_lab = lab, o.data_n = N, o.data_size = S;
    CHECK_MSG(gs_gaze_train(a, &o, pool, NULL, &err) == GS_OK, "%s", err.msg);
    train_opts(&o, 4, path, 0);
    o.data = img, o.data_lab = lab, o.data_n = N, o.data_size = S;
    o.stop_after = 2;
    CHECK_MSG(gs_gaze_train(c, &o, pool, NULL, &err) == GS_OK, "%s", err.msg);
    gs_gaze_net *r = NULL;
    CHECK_MSG(gs_gaze_net_load(path, &r, &err) == GS_OK, "%s", err.msg);
    train_opts(&o, 4, path, 1);
    o.data = img, o.data_lab = lab, o.data_n = N, o.data_size = S;
    if (r)
        CHECK_MSG(gs_gaze_train(r, &o, pool, NULL, &err) == GS_OK, "%s", err.msg);
    CHECK_MSG(r && !memcmp(a->params, r->params, bytes), "fixed set: resumed run differs");
    o.data_n = N - 1;
    CHECK(r && gs_gaze_train(r, &o, pool, NULL, &err) == GS_ERR_ARG);
    unlink(path);
    unlink(opt);
    gs_gaze_net_destroy(a);
    gs_gaze_net_destroy(c);
    gs_gaze_net_destroy(r);
    gs_pool_destroy(pool);
}

int main(int argc, char **argv)
{
    gs_nn_blas_set_threads(1);
    if (!mkdtemp(dir)) {
        perror("mkdtemp");
        return 1;
    }
    if (argc > 1 && !strcmp(argv[1], "train")) {
        test_training_lowers_loss();
    } else {
        test_predict_and_args();
        test_angular_error();
        test_l1_loss();
        test_loader();
        test_determinism_and_resume();
        test_augmentations();
        test_fixed_set();
    }
    rmdir(dir);
    GS_TEST_END();
}
