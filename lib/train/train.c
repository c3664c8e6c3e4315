/* Training on synthetic heads generated on the fly (normalized face images
 * of many views per identity), auto-decoder codes per training identity.
 *
 * Per step: one sample; tau = [code of its identity | its expression | its
 * light]; loss = L1 (eye region weighted 5x) + 0.1 (1 - SSIM) on the image
 * with a white background outside the head mask, plus L1 of the feature
 * map's first 3 channels against the 4x area-downsampled target. Adam with
 * per-group learning rates; a step whose loss or gradient is non-finite,
 * or whose loss spikes above 4x the running mean, is skipped and counted.
 *
 * A sample (the synthetic image, its targets and masks) is a pure function
 * of its index: nothing a step changes goes into it. So a producer thread
 * makes step i + 1's sample while step i runs (two slots), and the bytes
 * are those of making each in turn (gs_train_options.sync_samples). What
 * a sample takes from the model, its identity's code, is read at its
 * step, after the step before has updated it. */
#define _POSIX_C_SOURCE 200809L
#include <math.h>
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "gazesplat/clock.h"
#include "../model/frame.h"
#include "gazesplat/gaze.h"
#include "gazesplat/nn.h"
#include "gazesplat/safetensors.h"
#include "gazesplat/synth.h"
#include "gazesplat/train.h"

static int identity_index(int n_ids, uint64_t seed)
{
    for (int k = 0; k < n_ids; k++)
        if (gs_synth_split_seed(GS_SYNTH_TRAIN, (uint64_t)k) == seed)
            return k;
    return -1;
}

/* What making a sample reads: fixed for the run, the producer's copy. */
typedef struct item_maker {
    gs_synth_gen_config gen;
    int n_ids;    /* training identities */
    int S, fs;    /* image and feature map sizes */
    int g;        /* the face-only mask's margin around the eyes, feature px */
    float eye_w;  /* eye pixels' weight in the image L1 */
    gs_pool *pool; /* renders the synthetic image (sample_threads > 1), or NULL */
} item_maker;

/* One sample and its targets, made ahead of its step. */
typedef struct train_item {
    uint64_t index;
    int filled;               /* index's sample is here */
    gs_synth_scene scene;
    gs_synth_sample sample;
    int ident;                /* its training identity */
    float *target, *wl1;      /* [3 S^2] white outside the head; [S^2] */
    float *ftarget;           /* [3 fs^2] area-downsampled target */
    float *fmask, *emask;     /* [fs^2] face-only mask; eye share */
    gs_error err;             /* why the last making failed */
} train_item;

typedef struct trainer {
    gs_model *m;
    gs_model_ctx *c;
    float *grad;
    gs_model_params g;
    gs_nn_adam *adam;
    item_maker mk;
    train_item item[2];        /* step i's sample is in item[i & 1] */
    train_item *cur;           /* this step's */
    /* the producer: fills item[want] with sample want_index */
    pthread_t producer;
    int producer_on;
    pthread_mutex_t lock;
    pthread_cond_t cv;
    int want, busy, quit;
    uint64_t want_index;
    float *dimg, *dfmap, *ssim;
    float *dfmap_face;         /* face-only render's gradient */
    float *dfmap_eye;          /* eye-only render's gradient */
    float *dcover;             /* the eye coverage's gradient [fs^2] */
    double cover_w;            /* its weight (eye_cover_weight) */
    float eye_w;               /* eye pixels' and eye map's weight (5) */
    float gaze_label[2];       /* normalized-camera gaze of the sample */
    gs_gaze_net *gnet;         /* the loss estimator, or NULL */
    double gaze_w, gaze_rad;   /* its weight; the last angle */
    size_t ssim_len;
    double light_sum[GS_MODEL_LIGHT_DIM];
    long light_n;
    long sched_first;          /* the learning-rate curve's first step */
    /* the running means of the loss (the spike guard's) and of the loss
     * estimator's angle, over mean_n steps; kept in FILE.opt */
    double loss_mean, gaze_mean;
    long mean_n;
} trainer;

static double group_lr(int group)
{
    switch (group) {
    case GS_PG_GAUSS_XYZ: return 10.0;  /* mm */
    case GS_PG_GAUSS_ATTR: return 1.0;
    case GS_PG_GAUSS_FEAT: return 5.0;
    case GS_PG_MLP: return 1.0;
    case GS_PG_RENDERER: return 1.0;
    case GS_PG_CODES: return 10.0;
    default: return 0.0;
    }
}

static int trainer_init(trainer *t, gs_model *m, const gs_train_options *o,
                        gs_error *err)
{
    memset(t, 0, sizeof *t);
    t->m = m;
    t->gnet = o->gaze_net;
    t->gaze_w = o->gaze_weight;
    t->c = gs_model_ctx_create(m);
    t->grad = calloc(m->nparams, sizeof(float));
    if (!t->c || !t->grad)
        return gs_error_set(err, GS_ERR_NOMEM, "train: out of memory");
    t->c->face_loss = 1; /* the face-only and eye-only renders are */
    t->c->eye_loss = 1;  /* supervised too */
    gs_model_bind(m, t->grad, &t->g);
    gs_nn_param_group groups[GS_MODEL_MAX_TENSORS];
    int ng = 0;
    for (int i = 0; i < m->ntensors; i++) {
        double mult = group_lr(m->t[i].group);
        if (mult <= 0)
            continue;
        groups[ng].param = m->params + m->t[i].offset;
        groups[ng].grad = t->grad + m->t[i].offset;
        groups[ng].n = m->t[i].count;
        groups[ng].lr_mult = mult;
        ng++;
    }
    gs_nn_adam_config ac = gs_nn_adam_default_config();
    ac.max_grad_norm = o->max_grad_norm;
    int rc = gs_nn_adam_create(&t->adam, groups, ng, &ac, err);
    if (rc)
        return rc;
    size_t S = (size_t)m->cfg.image_size, fs = (size_t)m->cfg.feat_size;
    t->cover_w = o->eye_cover_weight;
    t->eye_w = o->eye_weight > 0 ? (float)o->eye_weight : 5.0f;
    item_maker *mk = &t->mk;
    gs_train_sample_config(m, o, &mk->gen);
    mk->n_ids = m->cfg.n_train_ids;
    mk->S = (int)S;
    mk->fs = (int)fs;
    /* the eyes are missing from the face-only render; with lids, which it
     * leaves out too, 3: the lids reach 2-4 mm beyond the eye's opening, a
     * feature pixel is about 3.4 mm */
    mk->g = t->c->nl ? 3 : 1;
    mk->eye_w = t->eye_w;
    if (o->sample_threads > 1) {
        /* its own pool: the workers' is busy with the step before; no
         * spinning between its jobs, which come once a step */
        mk->pool = gs_pool_create(o->sample_threads);
        if (!mk->pool)
            return gs_error_set(err, GS_ERR_NOMEM,
                                "train: cannot start %d sample threads",
                                o->sample_threads);
        gs_pool_set_spin_us(mk->pool, 0);
    }
    for (int i = 0; i < 2; i++) {
        train_item *it = &t->item[i];
        rc = gs_synth_sample_alloc(&it->sample, mk->gen.size, mk->gen.size, err);
        if (rc)
            return rc;
        it->target = malloc(3 * S * S * sizeof(float));
        it->wl1 = malloc(S * S * sizeof(float));
        it->ftarget = malloc(3 * fs * fs * sizeof(float));
        it->fmask = malloc(fs * fs * sizeof(float));
        it->emask = malloc(fs * fs * sizeof(float));
        if (!it->target || !it->wl1 || !it->ftarget || !it->fmask || !it->emask)
            return gs_error_set(err, GS_ERR_NOMEM, "train: out of memory");
    }
    t->ssim_len = gs_nn_ssim_fused_scratch_size(3, (int)S, (int)S, GS_NN_SSIM_ZERO);
    t->dimg = malloc(3 * S * S * sizeof(float));
    t->dfmap = calloc((size_t)m->cfg.channels * fs * fs, sizeof(float));
    t->dfmap_face = calloc((size_t)m->cfg.channels * fs * fs, sizeof(float));
    t->dfmap_eye = calloc((size_t)m->cfg.channels * fs * fs, sizeof(float));
    t->dcover = calloc(fs * fs, sizeof(float));
    t->ssim = malloc(t->ssim_len * sizeof(float));
    if (!t->dimg || !t->dfmap || !t->ssim || !t->dfmap_face || !t->dfmap_eye ||
        !t->dcover)
        return gs_error_set(err, GS_ERR_NOMEM, "train: out of memory");
    return GS_OK;
}

static void producer_stop(trainer *t);

static void trainer_free(trainer *t)
{
    producer_stop(t);
    gs_pool_destroy(t->mk.pool);
    gs_model_ctx_destroy(t->c);
    free(t->grad);
    gs_nn_adam_destroy(t->adam);
    for (int i = 0; i < 2; i++) {
        train_item *it = &t->item[i];
        gs_synth_sample_free(&it->sample);
        free(it->target);
        free(it->wl1);
        free(it->ftarget);
        free(it->fmask);
        free(it->emask);
    }
    free(t->dimg);
    free(t->dfmap);
    free(t->dfmap_face);
    free(t->dfmap_eye);
    free(t->dcover);
    free(t->ssim);
}

/* Makes sample `index` and its targets into it (any thread: reads only mk). */
static int make_item(const item_maker *mk, uint64_t index, train_item *it)
{
    it->filled = 0;
    it->index = index;
    gs_error *err = &it->err;
    gs_synth_camera cam;
    int rc = gs_synth_gen_scene(&mk->gen, index, &it->scene, &cam, err);
    if (!rc)
        rc = gs_synth_gen_sample(&mk->gen, index, mk->pool, &it->sample, err);
    if (!rc) {
        it->ident = identity_index(mk->n_ids, it->sample.labels.identity.seed);
        if (it->ident < 0)
            rc = gs_error_set(err, GS_ERR_STATE, "train: unknown identity");
    }
    if (rc)
        return rc;
    /* Targets: white outside the head; eyes weighted eye_w in the L1. */
    int S = mk->S, fs = mk->fs;
    size_t plane = (size_t)S * S;
    const gs_synth_sample *sm = &it->sample;
    const uint8_t *head = gs_synth_sample_mask(sm, GS_SYNTH_MASK_HEAD);
    const uint8_t *le = gs_synth_sample_mask(sm, GS_SYNTH_MASK_LEFT_EYE);
    const uint8_t *re = gs_synth_sample_mask(sm, GS_SYNTH_MASK_RIGHT_EYE);
    for (int y = 0; y < S; y++)
        for (int x = 0; x < S; x++) {
            size_t i = (size_t)y * S + x;
            float hm = head[i] / 255.0f;
            for (int ch = 0; ch < 3; ch++) {
                float v = sm->rgb[(size_t)y * sm->stride + 3 * x + ch] / 255.0f;
                it->target[ch * plane + i] = hm * v + (1 - hm);
            }
            it->wl1[i] = 1.0f + (mk->eye_w - 1.0f) * (float)((le[i] | re[i]) != 0);
        }
    int f = S / fs, g = mk->g;
    /* face-only mask: feature pixels with no eye pixel within g feature
     * pixels */
    for (int y = 0; y < fs; y++)
        for (int x = 0; x < fs; x++) {
            int eye = 0;
            for (int yy = (y - g) * f; yy < (y + g + 1) * f && !eye; yy++)
                for (int xx = (x - g) * f; xx < (x + g + 1) * f && !eye; xx++)
                    if (yy >= 0 && yy < S && xx >= 0 && xx < S)
                        eye = (le[(size_t)yy * S + xx] | re[(size_t)yy * S + xx]) != 0;
            it->fmask[(size_t)y * fs + x] = eye ? 0.0f : 1.0f;
            int in_eye = 0; /* share of the feature pixel that is eye */
            for (int yy = y * f; yy < (y + 1) * f; yy++)
                for (int xx = x * f; xx < (x + 1) * f; xx++)
                    in_eye += (le[(size_t)yy * S + xx] | re[(size_t)yy * S + xx]) != 0;
            it->emask[(size_t)y * fs + x] = (float)in_eye / (float)(f * f);
        }
    for (int ch = 0; ch < 3; ch++)
        for (int y = 0; y < fs; y++)
            for (int x = 0; x < fs; x++) {
                double sum = 0;
                for (int dy = 0; dy < f; dy++)
                    for (int dx = 0; dx < f; dx++)
                        sum += it->target[ch * plane +
                                          (size_t)(y * f + dy) * S + x * f + dx];
                it->ftarget[(size_t)ch * fs * fs + (size_t)y * fs + x] =
                    (float)(sum / (f * f));
            }
    it->filled = 1;
    return GS_OK;
}

static void *producer_main(void *arg)
{
    trainer *t = arg;
    pthread_mutex_lock(&t->lock);
    for (;;) {
        while (!t->quit && t->want < 0)
            pthread_cond_wait(&t->cv, &t->lock);
        if (t->quit)
            break;
        int slot = t->want;
        uint64_t index = t->want_index;
        t->want = -1;
        t->busy = 1;
        pthread_mutex_unlock(&t->lock);
        make_item(&t->mk, index, &t->item[slot]);
        pthread_mutex_lock(&t->lock);
        t->busy = 0;
        pthread_cond_broadcast(&t->cv);
    }
    pthread_mutex_unlock(&t->lock);
    return NULL;
}

/* Starts the producer; without one (sync, or no thread to be had) every
 * sample is made at its step on the calling thread. */
static void producer_start(trainer *t, int sync)
{
    t->want = -1;
    t->busy = t->quit = 0;
    if (sync || pthread_mutex_init(&t->lock, NULL))
        return;
    if (pthread_cond_init(&t->cv, NULL)) {
        pthread_mutex_destroy(&t->lock);
        return;
    }
    if (pthread_create(&t->producer, NULL, producer_main, t)) {
        pthread_cond_destroy(&t->cv);
        pthread_mutex_destroy(&t->lock);
        return;
    }
    t->producer_on = 1;
}

/* Lets the sample in the making finish, then ends the producer. */
static void producer_stop(trainer *t)
{
    if (!t->producer_on)
        return;
    pthread_mutex_lock(&t->lock);
    t->quit = 1;
    pthread_cond_broadcast(&t->cv);
    pthread_mutex_unlock(&t->lock);
    pthread_join(t->producer, NULL);
    pthread_cond_destroy(&t->cv);
    pthread_mutex_destroy(&t->lock);
    t->producer_on = 0;
}

/* Sample `index` into t->cur (the producer's, when it made it; else made
 * here), and sample `next` asked of the producer unless next is
 * UINT64_MAX. */
static int take_item(trainer *t, uint64_t index, uint64_t next, gs_error *err)
{
    train_item *it = &t->item[index & 1];
    if (t->producer_on) {
        pthread_mutex_lock(&t->lock);
        while (t->want >= 0 || t->busy)
            pthread_cond_wait(&t->cv, &t->lock);
        pthread_mutex_unlock(&t->lock);
    }
    /* (a sample the producer failed to make is made again here, and its
     * error reported) */
    if (!(it->filled && it->index == index)) {
        int rc = make_item(&t->mk, index, it);
        if (rc)
            return gs_error_set(err, rc, "%s", it->err.msg);
    }
    if (t->producer_on && next != UINT64_MAX) {
        pthread_mutex_lock(&t->lock);
        t->item[next & 1].filled = 0;
        t->want = (int)(next & 1);
        t->want_index = next;
        pthread_cond_broadcast(&t->cv);
        pthread_mutex_unlock(&t->lock);
    }
    t->cur = it;
    return GS_OK;
}

/* The frame of this step's sample: its identity's code as the model holds
 * it now, its expression, light, head pose and gaze. */
static int prepare(trainer *t, gs_frame *fr, int *ident, gs_error *err)
{
    const train_item *it = t->cur;
    const gs_synth_labels *lab = &it->sample.labels;
    int k = it->ident;
    *ident = k;
    const gs_model_config *mc = &t->m->cfg;
    gs_subject sub; /* the training subject, as a render at its view sees it */
    int rc = gs_model_training_subject(t->m, k, &it->scene, lab, &sub, err);
    if (rc)
        return rc;
    memset(fr, 0, sizeof *fr);
    memcpy(fr->code, sub.code, sizeof(float) * (size_t)sub.code_dim);
    const float *light = fr->code + mc->id_dim + GS_MODEL_EXPR_DIM;
    for (int i = 0; i < GS_MODEL_LIGHT_DIM; i++)
        t->light_sum[i] += light[i];
    t->light_n++;
    memcpy(fr->head_R, sub.head_R, sizeof fr->head_R);
    memcpy(fr->head_t, sub.head_t, sizeof fr->head_t);
    fr->gaze[0] = sub.gaze_pitch;
    fr->gaze[1] = sub.gaze_yaw;
    t->gaze_label[0] = (float)lab->gaze_norm_pitch;
    t->gaze_label[1] = (float)lab->gaze_norm_yaw;
    return GS_OK;
}

/* The gaze loss: gaze_w x the angle between the estimator's gaze on the
 * render and the label; its image gradient added into t->dimg. NAN when
 * the estimator fails (the step is then skipped as non-finite). */
static double gaze_loss(trainer *t, gs_pool *pool)
{
    gs_model_ctx *c = t->c;
    float out[4], da[2];
    if (gs_gaze_net_forward(t->gnet, pool, c->rgb, c->S, c->S, out, NULL))
        return NAN;
    t->gaze_rad = gs_gaze_angular_error(out, t->gaze_label, da);
    float dout[4] = {(float)t->gaze_w * da[0], (float)t->gaze_w * da[1], 0, 0};
    if (gs_gaze_net_backward(t->gnet, pool, dout, t->dimg, NULL, NULL))
        return NAN;
    return t->gaze_w * t->gaze_rad;
}

/* Loss of the current frame and its gradients into t->dimg / t->dfmap. */
static double losses(trainer *t, gs_pool *pool, double *psnr)
{
    gs_model_ctx *c = t->c;
    const train_item *it = t->cur; /* this step's targets */
    int S = c->S, fs = c->fs;
    size_t plane = (size_t)S * S, fplane = (size_t)fs * fs;
    float l1 = 0, ls = 0, lf = 0;
    gs_nn_l1_forward(&l1, c->rgb, it->target, it->wl1, 3, (int)plane);
    gs_nn_l1_forward(&lf, c->fmap, it->ftarget, NULL, 3, (int)fplane);
    float lface = 0; /* the face stream alone, away from the eyes */
    if (c->used_face_map) {
        gs_nn_l1_forward(&lface, c->fmap_face, it->ftarget, it->fmask, 3,
                         (int)fplane);
        memset(t->dfmap_face, 0, 3 * fplane * sizeof(float));
        gs_nn_l1_backward(t->dfmap_face, 1.0f, c->fmap_face, it->ftarget,
                          it->fmask, 3, (int)fplane);
    }
    memset(t->dimg, 0, 3 * plane * sizeof(float));
    gs_nn_l1_backward(t->dimg, 1.0f, c->rgb, it->target, it->wl1, 3,
                      (int)plane);
    /* the SSIM's loss and gradient in one pass, on the pool */
    gs_nn_ssim_loss_fused(pool, &ls, t->dimg, 0.1f, c->rgb, it->target, 3, S, S,
                          GS_NN_SSIM_ZERO, t->ssim, t->ssim_len);
    memset(t->dfmap, 0, 3 * fplane * sizeof(float));
    gs_nn_l1_backward(t->dfmap, 1.0f, c->fmap, it->ftarget, NULL, 3,
                      (int)fplane);
    double se = 0;
    for (size_t i = 0; i < 3 * plane; i++) {
        double e = c->rgb[i] - it->target[i];
        se += e * e;
    }
    double mse = se / (3.0 * plane);
    *psnr = mse > 1e-12 ? -10 * log10(mse) : 120;
    float leye = 0; /* the eye stream alone, over the visible eyes, x eye_w */
    if (c->used_eye_map) {
        gs_nn_l1_forward(&leye, c->fmap_eye, it->ftarget, it->emask, 3,
                         (int)fplane);
        memset(t->dfmap_eye, 0, 3 * fplane * sizeof(float));
        gs_nn_l1_backward(t->dfmap_eye, t->eye_w, c->fmap_eye, it->ftarget,
                          it->emask, 3, (int)fplane);
    }
    double lg = t->gnet ? gaze_loss(t, pool) : 0.0;
    double lc = 0; /* the eye stream's coverage against the visible eyes */
    c->cover_grad = NULL;
    if (t->cover_w > 0 && gs_frame_eye_cover(c, pool, NULL) == GS_OK) {
        /* (gs_train refuses the weight without an eye stream) */
        double w = t->cover_w / (double)fplane;
        for (size_t i = 0; i < fplane; i++) {
            double d = (double)c->cover[i] - it->emask[i];
            lc += fabs(d);
            t->dcover[i] = (float)(d > 0 ? w : d < 0 ? -w : 0.0);
        }
        lc *= w;
        c->cover_grad = t->dcover;
    }
    return (double)l1 + 0.1 * ls + lf + lface + t->eye_w * leye + lg + lc;
}

static int save_checkpoint(trainer *t, const char *path, long step,
                           gs_error *err)
{
    /* The mean code (starting point of fits): mean identity code, neutral
     * expression, mean training light. */
    gs_model *m = t->m;
    int D = gs_model_code_dim(&m->cfg), id = m->cfg.id_dim;
    memset(m->p.code_mean, 0, D * sizeof(float));
    for (int k = 0; k < m->cfg.n_train_ids; k++)
        for (int j = 0; j < id; j++)
            m->p.code_mean[j] += m->p.codes[(size_t)k * id + j] /
                                 m->cfg.n_train_ids;
    if (t->light_n)
        for (int i = 0; i < GS_MODEL_LIGHT_DIM; i++)
            m->p.code_mean[id + GS_MODEL_EXPR_DIM + i] =
                (float)(t->light_sum[i] / t->light_n);
    int rc = gs_model_save(m, path, err);
    if (rc)
        return rc;
    /* Optimizer state next to it, for resuming. */
    gs_st_writer *w = gs_st_writer_create();
    if (!w)
        return gs_error_set(err, GS_ERR_NOMEM, "train: out of memory");
    char key[80], val[32];
    snprintf(val, sizeof val, "%ld", step);
    gs_st_writer_meta(w, "step", val);
    snprintf(val, sizeof val, "%ld", gs_nn_adam_steps(t->adam));
    gs_st_writer_meta(w, "adam_steps", val);
    snprintf(val, sizeof val, "%ld", t->sched_first);
    gs_st_writer_meta(w, "schedule_first", val);
    /* the lights seen so far, so that a resumed run's mean light counts
     * every sample since the run's start, as a run without a stop does */
    char lights[GS_MODEL_LIGHT_DIM * 26];
    size_t at = 0;
    for (int i = 0; i < GS_MODEL_LIGHT_DIM; i++)
        at += (size_t)snprintf(lights + at, sizeof lights - at, "%s%.17g",
                               i ? "," : "", t->light_sum[i]);
    gs_st_writer_meta(w, "light_sum", lights);
    snprintf(val, sizeof val, "%ld", t->light_n);
    gs_st_writer_meta(w, "light_n", val);
    /* the spike guard's running mean, so that a resumed run skips what a
     * run without a stop skips */
    snprintf(lights, sizeof lights, "%.17g", t->loss_mean);
    gs_st_writer_meta(w, "loss_mean", lights);
    snprintf(lights, sizeof lights, "%.17g", t->gaze_mean);
    gs_st_writer_meta(w, "gaze_mean", lights);
    snprintf(val, sizeof val, "%ld", t->mean_n);
    gs_st_writer_meta(w, "mean_n", val);
    int gi = 0;
    for (int i = 0; i < m->ntensors && !rc; i++) {
        if (group_lr(m->t[i].group) <= 0)
            continue;
        float *m1, *v1;
        gs_nn_adam_moments(t->adam, gi++, &m1, &v1);
        int64_t n = (int64_t)m->t[i].count;
        snprintf(key, sizeof key, "m.%s", m->t[i].name);
        rc = gs_st_writer_add(w, key, GS_ST_F32, 1, &n, m1);
        snprintf(key, sizeof key, "v.%s", m->t[i].name);
        if (!rc)
            rc = gs_st_writer_add(w, key, GS_ST_F32, 1, &n, v1);
    }
    char opath[4096];
    snprintf(opath, sizeof opath, "%s.opt", path);
    if (!rc)
        rc = gs_st_writer_save(w, opath, err);
    gs_st_writer_destroy(w);
    return rc;
}

double gs_train_lr(const gs_train_options *o, long first, long step, long done)
{
    double lr = o->lr;
    if (o->cosine && o->steps > first) {
        double u = (double)(step - first) / (double)(o->steps - first);
        u = u < 0 ? 0 : u > 1 ? 1 : u;
        lr *= 0.05 + 0.95 * 0.5 * (1.0 + cos(GS_MODEL_PI * u));
    }
    if (done >= 0 && o->warmup > 0 && done < o->warmup)
        lr *= (double)(done + 1) / (double)o->warmup;
    return lr;
}

static int load_optimizer(trainer *t, const char *path, long *step,
                          gs_error *err)
{
    char opath[4096];
    snprintf(opath, sizeof opath, "%s.opt", path);
    gs_st_file *f = NULL;
    gs_error e2 = {0, ""};
    int rc = gs_st_open(opath, NULL, &f, &e2);
    if (rc)
        return gs_error_set(err, rc,
                            "train: cannot resume without the optimizer state: %s (a model "
                            "without it continues with a new optimizer: fresh_from_step, "
                            "--fresh-optimizer STEP)",
                            e2.msg);
    const char *s = gs_st_meta(f, "step"), *a = gs_st_meta(f, "adam_steps");
    if (!s || !a) {
        gs_st_close(f);
        return gs_error_set(err, GS_ERR_FORMAT, "train: %s lacks steps",
                            opath);
    }
    *step = atol(s);
    gs_nn_adam_set_steps(t->adam, atol(a));
    const char *sf = gs_st_meta(f, "schedule_first"); /* absent before the cosine: 0 */
    t->sched_first = sf ? atol(sf) : 0;
    /* the lights seen before the stop (absent in older files: none) */
    const char *ls = gs_st_meta(f, "light_sum"), *ln = gs_st_meta(f, "light_n");
    if (ls && ln) {
        const char *q = ls;
        for (int i = 0; i < GS_MODEL_LIGHT_DIM; i++) {
            char *end = NULL;
            t->light_sum[i] = strtod(q, &end);
            if (end == q || !isfinite(t->light_sum[i]) ||
                *end != (i + 1 < GS_MODEL_LIGHT_DIM ? ',' : '\0')) {
                gs_st_close(f);
                return gs_error_set(err, GS_ERR_FORMAT,
                                    "train: %s: light_sum is not %d numbers",
                                    opath, GS_MODEL_LIGHT_DIM);
            }
            q = end + 1;
        }
        t->light_n = atol(ln);
        if (t->light_n < 0) {
            gs_st_close(f);
            return gs_error_set(err, GS_ERR_FORMAT, "train: %s: light_n %s",
                                opath, ln);
        }
    }
    /* the running means (absent in older files: they start again) */
    const char *lm = gs_st_meta(f, "loss_mean"), *gm = gs_st_meta(f, "gaze_mean"),
               *mn = gs_st_meta(f, "mean_n");
    if (lm && gm && mn) {
        char *end_l = NULL, *end_g = NULL;
        t->loss_mean = strtod(lm, &end_l);
        t->gaze_mean = strtod(gm, &end_g);
        t->mean_n = atol(mn);
        if (end_l == lm || *end_l || end_g == gm || *end_g || !isfinite(t->loss_mean) ||
            !isfinite(t->gaze_mean) || t->mean_n < 0) {
            gs_st_close(f);
            return gs_error_set(err, GS_ERR_FORMAT,
                                "train: %s: loss_mean, gaze_mean or mean_n is "
                                "not a number", opath);
        }
    }
    int gi = 0;
    const gs_model *m = t->m;
    for (int i = 0; i < m->ntensors && !rc; i++) {
        if (group_lr(m->t[i].group) <= 0)
            continue;
        float *m1, *v1;
        const float *d1, *d2;
        gs_nn_adam_moments(t->adam, gi++, &m1, &v1);
        int64_t n = (int64_t)m->t[i].count;
        char key[80];
        snprintf(key, sizeof key, "m.%s", m->t[i].name);
        rc = gs_st_get_f32(f, key, 1, &n, &d1, err);
        snprintf(key, sizeof key, "v.%s", m->t[i].name);
        if (!rc)
            rc = gs_st_get_f32(f, key, 1, &n, &d2, err);
        if (!rc) {
            memcpy(m1, d1, (size_t)n * sizeof(float));
            memcpy(v1, d2, (size_t)n * sizeof(float));
        }
    }
    gs_st_close(f);
    return rc;
}

/* The model and options gs_train can run with: GS_OK or GS_ERR_ARG. */
static int train_check(const gs_model *m, const gs_train_options *o, gs_error *err)
{
    if (!m || !o || !o->out_path)
        return gs_error_set(err, GS_ERR_ARG, "train: NULL argument");
    if (m->cfg.n_train_ids < 1 || !m->p.codes)
        return gs_error_set(err, GS_ERR_ARG,
                            "train: the model has no training codes");
    if (o->gaze_net && !(o->gaze_weight >= 0 && o->gaze_weight <= 100))
        return gs_error_set(err, GS_ERR_ARG, "train: gaze weight %g not in 0..100",
                            o->gaze_weight);
    if (!(o->eye_weight == 0 || (o->eye_weight >= 1 && o->eye_weight <= 100)))
        return gs_error_set(err, GS_ERR_ARG, "train: eye weight %g not in 1..100",
                            o->eye_weight);
    int hrc = gs_train_check_head_range(o->head_yaw_deg, o->head_pitch_deg, err);
    if (hrc)
        return hrc;
    if (!(o->max_grad_norm >= 0 && o->max_grad_norm <= 1e6))
        return gs_error_set(err, GS_ERR_ARG,
                            "train: gradient-norm clip %g not in 0..1e6",
                            o->max_grad_norm);
    if (!(o->sample_threads >= 0 && o->sample_threads <= GS_TRAIN_SAMPLE_THREADS_MAX))
        return gs_error_set(err, GS_ERR_ARG,
                            "train: sample threads %d not in 0..%d",
                            o->sample_threads, GS_TRAIN_SAMPLE_THREADS_MAX);
    if (!(o->eye_cover_weight >= 0 && o->eye_cover_weight <= 1000))
        return gs_error_set(err, GS_ERR_ARG,
                            "train: eye-cover weight %g not in 0..1000",
                            o->eye_cover_weight);
    if (o->eye_cover_weight > 0 && m->cfg.supersample > 1)
        return gs_error_set(err, GS_ERR_ARG,
                            "train: the eye-cover loss needs a point-sampled "
                            "model (supersample 1)");
    if (o->eye_cover_weight > 0 && !m->cfg.two_stream)
        return gs_error_set(err, GS_ERR_ARG,
                            "train: the eye-cover loss needs the eye stream "
                            "(not the single-stream ablation)");
    return GS_OK;
}

int gs_train(gs_model *m, const gs_train_options *o, gs_pool *pool,
             gs_train_report *rep, gs_error *err)
{
    int rc = train_check(m, o, err);
    if (rc)
        return rc;
    trainer t;
    rc = trainer_init(&t, m, o, err);
    long step = 0;
    t.sched_first = 0;
    if (!rc && o->resume && o->fresh_from_step >= 0)
        step = t.sched_first = o->fresh_from_step;
    else if (!rc && o->resume)
        rc = load_optimizer(&t, o->out_path, &step, err);
    if (!rc)
        producer_start(&t, o->sync_samples);
    int ramp = o->resume && o->fresh_from_step >= 0 && o->warmup > 0;
    double t0 = gs_clock_s(), last_log = t0;
    long skipped = 0, done = 0;
    double lr = o->lr; /* this step's learning rate */
    double psnr_acc = 0, loss_acc = 0, gaze_acc = 0;
    int acc_n = 0;
    for (; !rc && step < o->steps; step++) {
        gs_frame fr;
        int k = 0;
        rc = take_item(&t, (uint64_t)step,
                       step + 1 < o->steps ? (uint64_t)step + 1 : UINT64_MAX, err);
        if (!rc)
            rc = prepare(&t, &fr, &k, err);
        if (rc)
            break;
        rc = gs_frame_forward(t.c, pool, &fr, GS_STREAM_BOTH, 1, err);
        if (rc)
            break;
        double psnr;
        double loss = losses(&t, pool, &psnr);
        int skip = !isfinite(loss) || (t.mean_n > 50 && loss > 4 * t.loss_mean);
        if (!skip) {
            gs_nn_adam_zero_grad(t.adam);
            gs_frame_grad fg;
            memset(&fg, 0, sizeof fg);
            rc = gs_frame_backward(t.c, pool, t.dimg, t.dfmap,
                                   t.c->used_face_map ? t.dfmap_face : NULL,
                                   t.c->used_eye_map ? t.dfmap_eye : NULL,
                                   &t.g, &fg, err);
            if (rc)
                break;
            float *dc = t.g.codes + (size_t)k * m->cfg.id_dim;
            for (int j = 0; j < m->cfg.id_dim; j++)
                dc[j] += fg.code[j];
            double gn;
            lr = gs_train_lr(o, t.sched_first, step, ramp ? done : -1);
            int arc = gs_nn_adam_step_pool(t.adam, pool, lr, &gn);
            if (arc == GS_ERR_NONFINITE)
                skip = 1;
            else if (arc) {
                rc = gs_error_set(err, arc, "train: optimizer step failed");
                break;
            }
        }
        if (skip) {
            skipped++;
            if (o->log)
                o->log(o->log_ctx, "step %ld skipped (loss %g, mean %g)",
                       step, loss, t.loss_mean);
            continue;
        }
        done++;
        t.mean_n++;
        t.loss_mean = t.mean_n == 1 ? loss : 0.98 * t.loss_mean + 0.02 * loss;
        psnr_acc += psnr;
        loss_acc += loss;
        gaze_acc += t.gaze_rad;
        t.gaze_mean = t.mean_n == 1 ? t.gaze_rad : 0.98 * t.gaze_mean + 0.02 * t.gaze_rad;
        acc_n++;
        if (o->log && o->log_every > 0 && (step + 1) % o->log_every == 0) {
            double el = gs_clock_s() - t0, rate = done / el;
            char gz[48] = "";
            if (t.gnet)
                snprintf(gz, sizeof gz, "  gaze %.2f deg",
                         gaze_acc / acc_n * 180.0 / GS_MODEL_PI);
            o->log(o->log_ctx,
                   "step %ld/%ld loss %.4f psnr %.2f dB%s  lr %.2e  %.0f ms/step  "
                   "eta %.0f s  skipped %ld",
                   step + 1, o->steps, loss_acc / acc_n, psnr_acc / acc_n, gz, lr,
                   1000.0 * (gs_clock_s() - last_log) / acc_n,
                   (o->steps - step - 1) / (rate > 0 ? rate : 1), skipped);
            last_log = gs_clock_s();
            psnr_acc = loss_acc = gaze_acc = 0;
            acc_n = 0;
        }
        if (o->checkpoint_every > 0 && (step + 1) % o->checkpoint_every == 0)
            rc = save_checkpoint(&t, o->out_path, step + 1, err);
    }
    if (!rc)
        rc = save_checkpoint(&t, o->out_path, step, err);
    if (rep) {
        rep->steps = step;
        rep->skipped = skipped;
        rep->seconds = gs_clock_s() - t0;
        rep->final_loss = t.loss_mean;
        rep->final_gaze_deg = t.gaze_mean * 180.0 / GS_MODEL_PI;
    }
    trainer_free(&t);
    m->id = gs_model_param_id(m); /* the parameters it now holds */
    return rc;
}

int gs_model_add_identities(const gs_model *m, int n, gs_model **out,
                            gs_error *err)
{
    if (!m || !out)
        return gs_error_set(err, GS_ERR_ARG, "identities: NULL argument");
    int had = m->cfg.n_train_ids;
    if (!m->p.codes || had < 1)
        return gs_error_set(err, GS_ERR_ARG,
                            "identities: the model has no training codes");
    if (n <= had || n > 100000)
        return gs_error_set(err, GS_ERR_ARG,
                            "identities: %d for a model of %d (want more, "
                            "up to 100000)", n, had);
    gs_model_config cfg = m->cfg;
    cfg.n_train_ids = n;
    gs_model *o = NULL;
    int rc = gs_model_alloc(&cfg, "identities", &o, err);
    for (int i = 0; !rc && i < o->ntensors; i++) {
        const gs_ptensor *d = &o->t[i];
        const gs_ptensor *s = gs_model_find_tensor(m, d->name);
        int codes = !strcmp(d->name, "codes.train");
        if (!s || (!codes && s->count != d->count)) {
            rc = gs_error_set(err, GS_ERR_STATE, "identities: tensor %s",
                              d->name);
            break;
        }
        memcpy(o->params + d->offset, m->params + s->offset,
               s->count * sizeof(float));
    }
    if (rc) {
        gs_model_destroy(o);
        return rc;
    }
    o->rcfg = m->rcfg;
    gs_model_bind(o, o->params, &o->p);
    /* the new identities start at the mean of the learned codes (where a
     * fit of a new face starts too) */
    int id = cfg.id_dim;
    for (int j = 0; j < id; j++) {
        double mean = 0;
        for (int k = 0; k < had; k++)
            mean += m->p.codes[(size_t)k * id + j];
        mean /= had;
        for (int k = had; k < n; k++)
            o->p.codes[(size_t)k * id + j] = (float)mean;
    }
    o->id = gs_model_param_id(o);
    *out = o;
    return GS_OK;
}
