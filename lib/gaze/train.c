/* Training on synthetic normalized faces rendered on the fly.
 *
 * Rendering costs far more than a training pass, so samples live in a ring
 * of `cache` slots: step s renders `fresh` new samples (generator indices
 * s*fresh .. s*fresh+fresh-1, slot = index % cache) and draws its batch
 * from the filled slots with a hash of (seed, step, b). The ring at any
 * step is a pure function of the options, which makes resume exact.
 * Per-sample gradients go to their own slots and are summed in batch
 * order: the same bytes for any thread count. */
#define _POSIX_C_SOURCE 200809L /* clock_gettime */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "gazesplat/clock.h"
#include "gazesplat/nn.h"
#include "gazesplat/safetensors.h"
#include "gazesplat/synth.h"
#include "gaze_internal.h"

void gs_gaze_train_options_default(gs_gaze_train_options *o)
{
    memset(o, 0, sizeof *o);
    o->steps = 1000;
    o->batch = 16;
    o->lr = 1e-3;
    o->seed = 1;
    o->identities = 20000;
    o->cache = 2048;
    o->fresh = 4;
    o->checkpoint_every = 500;
    o->log_every = 50;
}

typedef struct trainer {
    gs_gaze_net *n;
    const gs_gaze_train_options *o;
    gs_pool *pool;
    int threads, S;
    size_t img_len, np;
    gs_synth_gen_config gen;
    uint8_t *ring;        /* [cache][3*S*S] CHW bytes */
    float *ring_lab;      /* [cache][4] */
    gs_synth_sample *smp; /* [threads] render targets */
    gz_ctx *ctx;          /* [threads] */
    float *img;           /* [threads][3*S*S] */
    float *tmp;           /* [threads][3*S*S]: the blur's first pass */
    float *sgrad;         /* [batch][np] */
    float *sloss, *serr;  /* [batch] L1 and gaze angle */
    int *task_rc;         /* [max(batch, cache)] */
    float *grad;          /* [np] */
    gs_nn_adam *adam;
    long step;            /* the step being run */
    uint64_t first, count;/* generator indices of a render pass */
} trainer;

float gs_gaze_l1_loss(const float out[4], const float lab[4], float scale,
                      float dout[4])
{
    float loss = 0.0f;
    for (int k = 0; k < 4; k++) {
        float e = out[k] - lab[k];
        loss += fabsf(e);
        dout[k] = e > 0 ? scale : e < 0 ? -scale : 0.0f;
    }
    return loss / 4.0f;
}

static uint64_t mix(uint64_t a, uint64_t b)
{
    uint64_t z = a * 0x9E3779B97F4A7C15ull + b + 0x632BE59BD9B4E019ull;
    z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
    z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
    return z ^ (z >> 31);
}

/* Renders generator index first + task into its ring slot. */
static void render_task(void *ctx, int task, int worker)
{
    trainer *t = ctx;
    uint64_t g = t->first + (uint64_t)task;
    gs_synth_sample *s = &t->smp[worker];
    t->task_rc[task] = gs_synth_gen_sample(&t->gen, g, NULL, s, NULL);
    if (t->task_rc[task])
        return;
    /* White outside the head for a `white` share of the samples, chosen by
     * the sample's index (so a resumed run makes the same choice). */
    if (t->o->white > 0 &&
        (double)(mix(t->o->seed ^ 0x57484954ull, g) >> 11) * 0x1.0p-53 < t->o->white) {
        const uint8_t *head = gs_synth_sample_mask(s, GS_SYNTH_MASK_HEAD);
        for (int y = 0; y < t->S; y++)
            for (int x = 0; x < t->S; x++)
                if (!head[(size_t)y * (size_t)t->S + (size_t)x])
                    memset(s->rgb + (size_t)y * s->stride + 3 * (size_t)x, 255, 3);
    }
    size_t slot = (size_t)(g % (uint64_t)t->o->cache), plane = (size_t)t->S * t->S;
    uint8_t *dst = t->ring + slot * t->img_len;
    for (int y = 0; y < t->S; y++)
        for (int x = 0; x < t->S; x++)
            for (int k = 0; k < 3; k++)
                dst[k * plane + (size_t)y * t->S + x] = s->rgb[(size_t)y * s->stride + 3 * x + k];
    const gs_synth_labels *l = &s->labels;
    float *lab = t->ring_lab + 4 * slot;
    lab[0] = (float)l->gaze_norm_pitch;
    lab[1] = (float)l->gaze_norm_yaw;
    lab[2] = (float)l->head_norm_pitch;
    lab[3] = (float)l->head_norm_yaw;
}

/* Renders indices [first, first + count) (count <= cache); nothing with a
 * fixed set. */
static int render(trainer *t, uint64_t first, uint64_t count, gs_error *err)
{
    if (t->o->data)
        return GS_OK;
    t->first = first;
    gs_pool_for(t->pool, (int)count, render_task, t);
    for (uint64_t i = 0; i < count; i++)
        if (t->task_rc[i])
            return gs_error_set(err, t->task_rc[i], "train-estimator: rendering sample %llu: %s",
                                (unsigned long long)(first + i), gs_strerror(t->task_rc[i]));
    return GS_OK;
}

/* Slot and flip of batch element b of the current step. */
static size_t pick(const trainer *t, int b, int *flip)
{
    uint64_t filled = (uint64_t)(t->step + 1) * (uint64_t)t->o->fresh;
    if (t->o->data)
        filled = (uint64_t)t->o->data_n;
    else if (filled > (uint64_t)t->o->cache)
        filled = (uint64_t)t->o->cache;
    uint64_t h = mix(mix(t->o->seed, (uint64_t)t->step), (uint64_t)b);
    *flip = (int)(h >> 63);
    return (size_t)((h & 0xFFFFFFFFull) % filled);
}

static int clampi(int v, int lo, int hi)
{
    return v < lo ? lo : v > hi ? hi : v;
}

/* [1,2,1]/4 along rows then columns, edges repeated: src -> tmp -> src. */
static void blur121(float *img, float *tmp, int S)
{
    size_t plane = (size_t)S * (size_t)S;
    for (int k = 0; k < 3; k++) {
        float *p = img + k * plane, *q = tmp + k * plane;
        for (int y = 0; y < S; y++)
            for (int x = 0; x < S; x++) {
                const float *r = p + (size_t)y * (size_t)S;
                q[(size_t)y * (size_t)S + (size_t)x] =
                    0.25f * (r[clampi(x - 1, 0, S - 1)] + 2.0f * r[x] + r[clampi(x + 1, 0, S - 1)]);
            }
        for (int y = 0; y < S; y++)
            for (int x = 0; x < S; x++)
                p[(size_t)y * (size_t)S + (size_t)x] =
                    0.25f * (q[(size_t)clampi(y - 1, 0, S - 1) * (size_t)S + (size_t)x] +
                             2.0f * q[(size_t)y * (size_t)S + (size_t)x] +
                             q[(size_t)clampi(y + 1, 0, S - 1) * (size_t)S + (size_t)x]);
    }
}

/* One batch element: forward, L1 loss, backward into its gradient slot. */
static void batch_task(void *ctx, int b, int worker)
{
    trainer *t = ctx;
    int flip, S = t->S;
    size_t slot = pick(t, b, &flip), plane = (size_t)S * S;
    const uint8_t *src = t->o->data ? t->o->data[slot] : t->ring + slot * t->img_len;
    float *img = t->img + (size_t)worker * t->img_len, lab[4], out[4], d[4];
    /* The shift and blur of this element: fixed by (seed, step, b). */
    uint64_t h = mix(mix(mix(t->o->seed, (uint64_t)t->step), (uint64_t)b), 0x5348494654ull);
    int span = 2 * t->o->shift + 1;
    int sx = (int)(h % (uint64_t)span) - t->o->shift;
    int sy = (int)((h >> 16) % (uint64_t)span) - t->o->shift;
    int blur = t->o->blur > 0 && (double)(h >> 32) * 0x1.0p-32 < t->o->blur;
    for (int k = 0; k < 3; k++)
        for (int y = 0; y < S; y++) {
            int ys = clampi(y - sy, 0, S - 1);
            for (int x = 0; x < S; x++) {
                int xs = clampi((flip ? S - 1 - x : x) - sx, 0, S - 1);
                img[k * plane + (size_t)y * S + x] = src[k * plane + (size_t)ys * S + xs] / 255.0f;
            }
        }
    if (blur)
        blur121(img, t->tmp + (size_t)worker * t->img_len, S);
    memcpy(lab, t->o->data ? t->o->data_lab[slot] : t->ring_lab + 4 * slot, sizeof lab);
    if (flip) /* a mirror image looks the other way: yaws change sign */
        lab[1] = -lab[1], lab[3] = -lab[3];
    float *g = t->sgrad + (size_t)b * t->np;
    memset(g, 0, t->np * sizeof *g);
    t->task_rc[b] = gz_forward(&t->n->g, t->n->params, &t->ctx[worker], img, S, S, out);
    if (t->task_rc[b])
        return;
    t->sloss[b] = gs_gaze_l1_loss(out, lab, 1.0f / (4.0f * (float)t->o->batch), d);
    t->serr[b] = (float)gs_gaze_angular_error(out, lab, NULL);
    t->task_rc[b] = gz_backward(&t->n->g, t->n->params, &t->ctx[worker], d, NULL, g);
}

static int trainer_init(trainer *t, gs_gaze_net *n, const gs_gaze_train_options *o,
                        gs_pool *pool, gs_error *err)
{
    memset(t, 0, sizeof *t);
    t->n = n, t->o = o, t->pool = pool;
    t->threads = gs_pool_threads(pool);
    t->S = o->data ? o->data_size : o->render_size > 0 ? o->render_size : n->spec.input_size;
    t->img_len = 3 * (size_t)t->S * t->S;
    t->np = n->g.nparams;
    gs_synth_gen_config_default(&t->gen);
    t->gen.split = GS_SYNTH_TRAIN;
    t->gen.identities = o->identities;
    t->gen.seed = o->seed;
    t->gen.size = t->S;
    t->gen.rig = GS_SYNTH_RIG_NORMALIZED;
    t->gen.supersample = o->render_size > 0 ? 1 : 2;
    size_t ncache = o->data ? 1 : (size_t)o->cache; /* a fixed set needs no ring */
    size_t ntask = (size_t)o->batch > ncache ? (size_t)o->batch : ncache;
    t->ring = malloc(ncache * t->img_len);
    t->ring_lab = malloc(ncache * 4 * sizeof(float));
    t->smp = calloc((size_t)t->threads, sizeof *t->smp);
    t->ctx = calloc((size_t)t->threads, sizeof *t->ctx);
    t->img = malloc((size_t)t->threads * t->img_len * sizeof(float));
    t->tmp = malloc((size_t)t->threads * t->img_len * sizeof(float));
    t->sgrad = malloc((size_t)o->batch * t->np * sizeof(float));
    t->sloss = malloc((size_t)o->batch * sizeof(float));
    t->serr = malloc((size_t)o->batch * sizeof(float));
    t->task_rc = calloc(ntask, sizeof(int));
    t->grad = calloc(t->np, sizeof(float));
    if (!t->ring || !t->ring_lab || !t->smp || !t->ctx || !t->img || !t->tmp || !t->sgrad ||
        !t->sloss || !t->serr || !t->task_rc || !t->grad)
        return gs_error_set(err, GS_ERR_NOMEM, "train-estimator: out of memory");
    for (int i = 0; i < t->threads; i++) {
        int rc = gs_synth_sample_alloc(&t->smp[i], t->S, t->S, err);
        if (rc)
            return rc;
        if (gz_ctx_init(&t->ctx[i], &n->g))
            return gs_error_set(err, GS_ERR_NOMEM, "train-estimator: out of memory");
    }
    gs_nn_param_group grp = {n->params, t->grad, t->np, 1.0};
    gs_nn_adam_config ac = gs_nn_adam_default_config();
    ac.max_grad_norm = 5.0;
    return gs_nn_adam_create(&t->adam, &grp, 1, &ac, err);
}

static void trainer_free(trainer *t)
{
    for (int i = 0; t->smp && t->ctx && i < t->threads; i++) {
        gs_synth_sample_free(&t->smp[i]);
        gz_ctx_free(&t->ctx[i]);
    }
    free(t->ring);
    free(t->ring_lab);
    free(t->smp);
    free(t->ctx);
    free(t->img);
    free(t->tmp);
    free(t->sgrad);
    free(t->sloss);
    free(t->serr);
    free(t->task_rc);
    free(t->grad);
    gs_nn_adam_destroy(t->adam);
}

/* ---- checkpoints: the net file plus PATH.opt (Adam moments, step) ------ */

/* What fixes the sample stream, which a resumed run must share. */
static void stream_id(const gs_gaze_train_options *o, char *v, size_t n)
{
    if (o->data) /* a fixed set: its size stands for it */
        snprintf(v, n, "%llu/%d/set%zu@%d/%d/%g", (unsigned long long)o->seed, o->batch,
                 o->data_n, o->data_size, o->shift, o->blur);
    else
        snprintf(v, n, "%llu/%d/%d/%d/%llu/%d/%g/%d/%g", (unsigned long long)o->seed, o->batch,
                 o->cache, o->fresh, (unsigned long long)o->identities, o->render_size,
                 o->white, o->shift, o->blur);
}

static int save_opt(trainer *t, const char *path, long step, gs_error *err)
{
    char name[4096], v[160];
    if (snprintf(name, sizeof name, "%s.opt", path) >= (int)sizeof name)
        return gs_error_set(err, GS_ERR_ARG, "train-estimator: path too long");
    float *m, *vv;
    gs_nn_adam_moments(t->adam, 0, &m, &vv);
    gs_st_writer *w = gs_st_writer_create();
    if (!w)
        return gs_error_set(err, GS_ERR_NOMEM, "train-estimator: out of memory");
    int64_t shape[1] = {(int64_t)t->np};
    int rc = gs_st_writer_meta(w, "format", "gazesplat-gaze-estimator-optimizer");
    snprintf(v, sizeof v, "%ld", step);
    rc = rc ? rc : gs_st_writer_meta(w, "step", v);
    snprintf(v, sizeof v, "%ld", gs_nn_adam_steps(t->adam));
    rc = rc ? rc : gs_st_writer_meta(w, "adam_steps", v);
    stream_id(t->o, v, sizeof v);
    rc = rc ? rc : gs_st_writer_meta(w, "stream", v);
    rc = rc ? rc : gs_st_writer_add(w, "adam.m", GS_ST_F32, 1, shape, m);
    rc = rc ? rc : gs_st_writer_add(w, "adam.v", GS_ST_F32, 1, shape, vv);
    if (rc)
        gs_error_set(err, rc, "train-estimator: optimizer state: %s", gs_strerror(rc));
    else
        rc = gs_gaze_net_save(t->n, path, err);
    if (!rc)
        rc = gs_st_writer_save(w, name, err);
    gs_st_writer_destroy(w);
    return rc;
}

static int load_opt(trainer *t, const char *path, long *step, gs_error *err)
{
    char name[4096], v[160];
    if (snprintf(name, sizeof name, "%s.opt", path) >= (int)sizeof name)
        return gs_error_set(err, GS_ERR_ARG, "train-estimator: path too long");
    gs_st_file *f = NULL;
    int rc = gs_st_open(name, NULL, &f, err);
    if (rc)
        return rc;
    const float *m = NULL, *vv = NULL;
    int64_t shape[1] = {(int64_t)t->np};
    const char *s = gs_st_meta(f, "step"), *a = gs_st_meta(f, "adam_steps"),
               *stream = gs_st_meta(f, "stream");
    stream_id(t->o, v, sizeof v);
    rc = gs_st_get_f32(f, "adam.m", 1, shape, &m, err);
    rc = rc ? rc : gs_st_get_f32(f, "adam.v", 1, shape, &vv, err);
    char *e1 = NULL, *e2 = NULL;
    long st = s ? strtol(s, &e1, 10) : -1, as = a ? strtol(a, &e2, 10) : -1;
    if (!rc && (!s || *e1 || !a || *e2 || st < 0 || as < 0))
        rc = gs_error_set(err, GS_ERR_FORMAT, "train-estimator: %s: bad step", name);
    if (!rc && (!stream || strcmp(stream, v) != 0))
        rc = gs_error_set(err, GS_ERR_ARG,
                          "train-estimator: %s was made with seed/batch/cache/fresh/"
                          "identities/render-size/white/shift/blur %s, not %s",
                          name, stream ? stream : "?", v);
    if (!rc) {
        float *dm, *dv;
        gs_nn_adam_moments(t->adam, 0, &dm, &dv);
        memcpy(dm, m, t->np * sizeof(float));
        memcpy(dv, vv, t->np * sizeof(float));
        gs_nn_adam_set_steps(t->adam, as);
        *step = st;
    }
    gs_st_close(f);
    return rc;
}

/* Refills the ring as it was before step s: slot i holds the last index
 * g < s*fresh with g % cache == i. */
static int refill(trainer *t, long s, gs_error *err)
{
    uint64_t G = (uint64_t)s * (uint64_t)t->o->fresh, C = (uint64_t)t->o->cache;
    if (G == 0)
        return GS_OK;
    uint64_t first = G > C ? G - C : 0;
    return render(t, first, G - first, err);
}

/* ---- the loop ------------------------------------------------------------ */

static double lr_at(const gs_gaze_train_options *o, long s)
{
    long w = o->steps / 10 < 100 ? o->steps / 10 : 100; /* warm-up steps */
    double warm = s < w ? (double)(s + 1) / (double)w : 1.0;
    double cosv = 0.5 * (1.0 + cos(3.141592653589793 * (double)s / (double)o->steps));
    return o->lr * warm * (0.02 + 0.98 * cosv);
}

static int run_step(trainer *t, double *loss, double *gerr, gs_error *err)
{
    int rc = render(t, (uint64_t)t->step * (uint64_t)t->o->fresh, (uint64_t)t->o->fresh, err);
    if (rc)
        return rc;
    gs_pool_for(t->pool, t->o->batch, batch_task, t);
    *loss = *gerr = 0.0;
    for (int b = 0; b < t->o->batch; b++) {
        if (t->task_rc[b])
            return gs_error_set(err, t->task_rc[b], "train-estimator: pass failed: %s",
                                gs_strerror(t->task_rc[b]));
        *loss += t->sloss[b] / t->o->batch;
        *gerr += t->serr[b] / t->o->batch;
    }
    memset(t->grad, 0, t->np * sizeof(float));
    for (int b = 0; b < t->o->batch; b++) {
        const float *g = t->sgrad + (size_t)b * t->np;
        for (size_t i = 0; i < t->np; i++)
            t->grad[i] += g[i];
    }
    rc = gs_nn_adam_step(t->adam, lr_at(t->o, t->step), NULL);
    if (rc == GS_ERR_NONFINITE && t->o->log)
        t->o->log(t->o->log_ctx, "step %ld skipped: non-finite gradient", t->step);
    return rc == GS_ERR_NONFINITE ? GS_OK : rc;
}

static int options_check(const gs_gaze_train_options *o, gs_error *err)
{
    if (o->steps < 1 || o->batch < 1 || o->batch > 4096 || !(o->lr > 0) ||
        o->identities < 1 || o->identities > GS_SYNTH_SEED_SPLIT_COUNT || o->cache < 1 ||
        o->cache > 1000000 || o->fresh < 1 || o->fresh > o->cache ||
        o->checkpoint_every < 0 || o->log_every < 0 || o->stop_after < 0 ||
        o->render_size < 0 || o->render_size > 512 || !(o->white >= 0 && o->white <= 1) ||
        o->shift < 0 || o->shift > 16 || !(o->blur >= 0 && o->blur <= 1))
        return gs_error_set(err, GS_ERR_ARG, "train-estimator: option out of range");
    if (o->data && (!o->data_lab || o->data_n < 1 || o->data_n > (size_t)1 << 31 ||
                    o->data_size < 16 || o->data_size > 512))
        return gs_error_set(err, GS_ERR_ARG, "train-estimator: bad fixed set");
    if ((o->checkpoint_every || o->resume) && !o->out_path)
        return gs_error_set(err, GS_ERR_ARG, "train-estimator: checkpoints need out_path");
    return GS_OK;
}

int gs_gaze_train(gs_gaze_net *n, const gs_gaze_train_options *o, gs_pool *pool,
                  gs_gaze_train_report *rep, gs_error *err)
{
    if (!n || !o)
        return gs_error_set(err, GS_ERR_ARG, "train-estimator: NULL argument");
    int rc = options_check(o, err);
    if (rc)
        return rc;
    if (o->data && o->data_size < n->spec.input_size)
        return gs_error_set(err, GS_ERR_ARG,
                            "train-estimator: set image size %d below the net's input %d",
                            o->data_size, n->spec.input_size);
    if (o->render_size && o->render_size < n->spec.input_size)
        return gs_error_set(err, GS_ERR_ARG,
                            "train-estimator: render size %d below the net's input %d",
                            o->render_size, n->spec.input_size);
    trainer t;
    long start = 0;
    rc = trainer_init(&t, n, o, pool, err);
    if (!rc && o->resume)
        rc = load_opt(&t, o->out_path, &start, err);
    if (!rc)
        rc = refill(&t, start, err);
    double t0 = gs_clock_s(), tl = t0, wl = 0, we = 0, last = 0;
    long wn = 0, done = 0;
    long end = o->stop_after > 0 && o->stop_after < o->steps ? o->stop_after : o->steps;
    for (t.step = start; !rc && t.step < end; t.step++) {
        double loss, gerr;
        rc = run_step(&t, &loss, &gerr, err);
        if (rc)
            break;
        done++, wn++, wl += loss, we += gerr;
        if (o->log && o->log_every > 0 && (t.step + 1) % o->log_every == 0) {
            double el = gs_clock_s() - t0;
            o->log(o->log_ctx,
                   "step %ld/%ld loss %.4f rad  gaze %.2f deg  lr %.2e  %.0f ms/step  eta %.0f s",
                   t.step + 1, o->steps, wl / wn, we / wn * 57.29577951308232,
                   lr_at(o, t.step), 1000.0 * (gs_clock_s() - tl) / wn,
                   (double)(o->steps - t.step - 1) * el / (double)done);
            last = wl / wn;
            wl = we = 0, wn = 0, tl = gs_clock_s();
        }
        if (o->checkpoint_every > 0 && (t.step + 1) % o->checkpoint_every == 0)
            rc = save_opt(&t, o->out_path, t.step + 1, err);
    }
    if (!rc && o->out_path)
        rc = save_opt(&t, o->out_path, t.step, err);
    if (rep) {
        rep->steps = done;
        rep->seconds = gs_clock_s() - t0;
        rep->final_loss = wn ? wl / wn : last;
    }
    trainer_free(&t);
    return rc;
}
