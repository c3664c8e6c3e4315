/* Downstream use of redirected images: how much do they help a gaze
 * estimator adapt to a new person (GazeGaussian's and GazeNeRF's
 * gaze-estimation figure), on synthetic heads where the truth is known.
 *
 * Per identity: render the real pool and the test images, fit the model on
 * real sample 1, make set_size redirected images of that sample with the
 * model (one subject and head pose: the incremental sweep path) and with
 * the warp baseline, then fine-tune a fresh copy of the estimator for each
 * k and condition and measure it on the test images. Per-sample gradients
 * go to their own slots and are summed in batch order, so the numbers are
 * the same bytes for any thread count. */
#define _POSIX_C_SOURCE 200809L /* clock_gettime */
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "gazesplat/clock.h"
#include "gazesplat/eval.h"
#include "gazesplat/nn.h"
#include "eval_internal.h"

/* Stream tags: independent hash streams for scenes, targets, batches. */
#define TAG_SCENE 0x6473736365ull  /* "dssce" */
#define TAG_TARGET 0x647374676dull /* "dstgm" */
#define TAG_BATCH 0x6473626174ull  /* "dsbat" */

#define GS_DS_DEG (180.0 / 3.14159265358979323846) /* degrees per radian */
#define OFFSET_MAX (15.0 / GS_DS_DEG) /* largest calibration offset */

static uint64_t splitmix(uint64_t x)
{
    x += 0x9E3779B97F4A7C15ull;
    x = (x ^ (x >> 30)) * 0xBF58476D1CE4E5B9ull;
    x = (x ^ (x >> 27)) * 0x94D049BB133111EBull;
    return x ^ (x >> 31);
}

static uint64_t mix(uint64_t a, uint64_t b)
{
    return splitmix(splitmix(a) ^ b);
}

/* Uniform in [0, 1) from the top 53 bits. */
static double unit(uint64_t h)
{
    return (double)(h >> 11) * (1.0 / 9007199254740992.0);
}

const char *gs_eval_ds_condition_name(int c)
{
    static const char *const names[GS_EVAL_DS_CONDITIONS] = {
        "real", "real+ours", "real+warp"};
    return c >= 0 && c < GS_EVAL_DS_CONDITIONS ? names[c] : "?";
}

void gs_eval_ds_options_default(gs_eval_ds_options *o)
{
    o->test_images = 50;
    o->set_size = 200;
    o->max_k = GS_EVAL_DS_POOL;
    o->steps = 60;
    o->batch = 8;
    o->lr = 1e-4;
    o->real_fraction = 0.25;
    o->fit_iters = 200;
    o->fit_lr_code = 0; /* the model's rate, else GS_FIT_LR_CODE_DEFAULT */
    o->fit_lr_colour = GS_FIT_LR_COLOUR_DEFAULT;
    o->seed = 1;
    memset(&o->kappa, 0, sizeof o->kappa);
    o->subject_from_k = 0;
    o->calibrate = 0;
    o->ks = 0;
}

/* Whether k is one of the run's k. */
static int k_runs(const gs_eval_ds_options *o, int k)
{
    return k >= 1 && k <= o->max_k && (!o->ks || (o->ks >> k & 1u));
}

int gs_eval_ds_options_check(const gs_eval_ds_options *o, gs_error *err)
{
    const char *what = NULL;
    if (!o)
        what = "NULL options";
    else if (o->max_k < 1 || o->max_k > GS_EVAL_DS_POOL)
        what = "max_k outside 1..9";
    else if (o->set_size <= o->max_k || o->set_size > 100000)
        what = "set_size not in max_k+1..100000";
    else if (o->test_images < 1 || o->test_images > 100000)
        what = "test_images outside 1..100000";
    else if (o->steps < 1 || o->steps > 1000000)
        what = "steps outside 1..1000000";
    else if (o->batch < 1 || o->batch > 4096)
        what = "batch outside 1..4096";
    else if (!(o->lr > 0 && o->lr <= 1))
        what = "lr outside (0, 1]";
    else if (!(o->real_fraction >= 0 && o->real_fraction <= 1))
        what = "real_fraction outside [0, 1]";
    else if (o->fit_iters < 1 || o->fit_iters > 100000)
        what = "fit_iters outside 1..100000";
    else if (!(o->fit_lr_code >= 0 && o->fit_lr_code <= 10 &&
               o->fit_lr_colour >= 0 && o->fit_lr_colour <= 10))
        what = "fit rates outside [0, 10]";
    else if (o->ks & ~(((2u << o->max_k) - 1u) & ~1u))
        what = "ks names a k outside 1..max_k";
    if (!what && o->kappa.enabled && gs_synth_kappa_check(&o->kappa, err))
        return GS_ERR_ARG;
    return what ? gs_error_set(err, GS_ERR_ARG, "eval-downstream: %s", what)
                : GS_OK;
}

void gs_eval_ds_scene(uint64_t seed, int identity, int index,
                      gs_synth_scene *s)
{
    gs_synth_ranges r;
    gs_eval_ranges(&r);
    uint64_t id_seed = gs_synth_split_seed(GS_SYNTH_TEST, (uint64_t)identity);
    uint64_t scene = mix(mix(mix(seed, TAG_SCENE), (uint64_t)identity),
                         (uint64_t)index);
    gs_synth_scene_random(id_seed, scene, &r, s);
}

void gs_eval_ds_target(uint64_t seed, int identity, int j, double *pitch,
                       double *yaw)
{
    gs_synth_ranges r;
    gs_eval_ranges(&r);
    uint64_t h = mix(mix(mix(seed, TAG_TARGET), (uint64_t)identity),
                     (uint64_t)j);
    *pitch = r.gaze_pitch * (2.0 * unit(h) - 1.0);
    *yaw = r.gaze_yaw * (2.0 * unit(splitmix(h)) - 1.0);
}

/* ---- the images of one identity ---- */

/* n images of S x S RGB (stride 3 S) and their labels: normalized gaze
 * pitch, yaw, head pitch, yaw (the estimator's outputs). */
typedef struct image_set {
    int n;
    uint8_t *rgb;   /* [n][S*S*3] */
    float *lab;     /* [n][4] */
} image_set;

static int set_alloc(image_set *s, int n, int S)
{
    s->n = n;
    s->rgb = malloc((size_t)n * 3 * (size_t)S * (size_t)S);
    s->lab = malloc((size_t)n * 4 * sizeof(float));
    return s->rgb && s->lab ? GS_OK : GS_ERR_NOMEM;
}

static void set_free(image_set *s)
{
    free(s->rgb);
    free(s->lab);
    memset(s, 0, sizeof *s);
}

static uint8_t *set_image(const image_set *s, int i, int S)
{
    return s->rgb + (size_t)i * 3 * (size_t)S * (size_t)S;
}

static void labels_of(const gs_synth_labels *l, float lab[4])
{
    lab[0] = (float)l->gaze_norm_pitch;
    lab[1] = (float)l->gaze_norm_yaw;
    lab[2] = (float)l->head_norm_pitch;
    lab[3] = (float)l->head_norm_yaw;
}

/* Everything one identity's experiment holds. */
typedef struct ds_run {
    const gs_eval_ds_options *o;
    int identity, S, threads;
    double focal, d_n;
    gs_pool *pool;
    gs_synth_sample src[GS_EVAL_DS_POOL];  /* the real pool (fit, warp
                                              inputs); src[0] = sample 1 */
    gs_synth_scene src_scene[GS_EVAL_DS_POOL];
    image_set real, test, ours, warp;
    long renders_incremental, renders_full;
    double fit_s;
    /* fine-tuning */
    gs_gaze_net *tuned;        /* the copy being fine-tuned */
    gs_gaze_net **work;        /* [threads] copies running the passes */
    const float *base;         /* the estimator's parameters as given */
    size_t np, img_len;
    float *img;                /* [threads][3 S S] */
    float *sgrad;              /* [batch][np] per-sample gradients */
    float *grad;               /* [np] */
    double *serr;              /* [test images] angle, degrees */
    int *rc;                   /* [max(batch, test images)] */
    /* the fine-tune in progress */
    const image_set *syn;      /* NULL: real only */
    int k, real_slots;
    long step;
} ds_run;

/* Renders sample `index` of the identity into set slot i; keep: the
 * sample and its scene are kept as real pool image `index`. */
static int render_into(ds_run *r, int index, image_set *set, int i,
                       int keep, gs_error *err)
{
    gs_synth_scene sc;
    gs_synth_sample smp = {0};
    gs_eval_ds_scene(r->o->seed, r->identity, index, &sc);
    if (r->o->kappa.enabled)
        gs_synth_scene_set_kappa(&r->o->kappa, &sc);
    int rc = gs_eval_render_scene(&sc, r->S, r->d_n, r->focal, r->pool, &smp,
                                  err);
    if (rc)
        return rc;
    uint8_t *dst = set_image(set, i, r->S);
    for (int y = 0; y < r->S; y++)
        memcpy(dst + (size_t)y * 3 * r->S, smp.rgb + (size_t)y * smp.stride,
               3 * (size_t)r->S);
    labels_of(&smp.labels, set->lab + 4 * i);
    if (keep) {
        r->src[index] = smp;
        r->src_scene[index] = sc;
    } else {
        gs_synth_sample_free(&smp);
    }
    return GS_OK;
}

static int render_ground_truth(ds_run *r, gs_error *err)
{
    int rc = GS_OK;
    for (int i = 0; !rc && i < GS_EVAL_DS_POOL; i++)
        rc = render_into(r, i, &r->real, i, 1, err);
    for (int i = 0; !rc && i < r->o->test_images; i++)
        rc = render_into(r, GS_EVAL_DS_POOL + i, &r->test, i, 0, err);
    return rc;
}

/* Labels of real pool image s with the gaze turned to (pitch, yaw), head
 * frame: the scene's labels through the same camera, without rendering. */
static int target_labels(ds_run *r, int s, double pitch, double yaw,
                         float lab[4], gs_error *err)
{
    gs_synth_scene sc = r->src_scene[s];
    sc.gaze_pitch = pitch;
    sc.gaze_yaw = yaw;
    gs_synth_camera cam;
    gs_synth_labels l;
    int rc = gs_eval_scene_camera(&sc, r->S, r->d_n, r->focal, &cam, err);
    if (!rc)
        rc = gs_synth_labels_compute(&sc, &cam, &l, err);
    if (!rc)
        labels_of(&l, lab);
    return rc;
}

/* The subjects of real images 1..n (n = 1, or k with subject_from_k),
 * fitted together, and with calibrate the offset the renders aim with.
 * The fit of real sample 1 alone with its gaze given is cached in path. */
static int fit(ds_run *r, const gs_model *m, gs_model_ctx *c, int n,
               const char *path, int reuse, gs_subject *sub, double off[2],
               gs_eval_ds_result *res, gs_error *err)
{
    const gs_eval_ds_options *o = r->o;
    const int cache = path && n == 1 && !o->calibrate;
    /* the key hashes the model's parameters: only with a cache */
    const uint64_t key = cache ? gs_eval_fit_sample_key(m, &r->src[0],
                                                        o->fit_iters,
                                                        o->fit_lr_code,
                                                        o->fit_lr_colour)
                               : 0;
    double secs = 0;
    if (cache && reuse &&
        gs_eval_fit_cache_read(path, key, sub, &secs, NULL) == GS_OK) {
        res->fit_reused = 1;
    } else {
        int rc = gs_eval_fit_samples(c, r->pool, r->src, n, o->fit_iters,
                                     o->fit_lr_code, o->fit_lr_colour,
                                     o->calibrate, sub, &secs, err);
        if (rc)
            return rc;
        if (cache && gs_eval_fit_cache_write(path, key, sub, secs, NULL))
            res->cache_write_failed = 1;
    }
    r->fit_s += secs;
    off[0] = off[1] = 0;
    for (int i = 0; o->calibrate && i < n; i++) {
        off[0] += (sub[i].gaze_pitch - r->src[i].labels.gaze_head_pitch) / n;
        off[1] += (sub[i].gaze_yaw - r->src[i].labels.gaze_head_yaw) / n;
    }
    /* Beyond kappa's range (|mean| <= 15 deg, gs_synth_kappa_check) an
     * offset is the fit's error, not the person's: it is held there, and
     * every aimed gaze stays inside the model's range. */
    for (int a = 0; a < 2; a++)
        off[a] = fmax(-OFFSET_MAX, fmin(OFFSET_MAX, off[a]));
    if (n == 1 || !res->fit_psnr)
        res->fit_psnr = sub[0].fit_psnr;
    return GS_OK;
}

/* The model's and the warp's `count` images, redirected from the n real
 * images: target j from image j mod n, at its head pose. The model's are
 * made image by image (one subject and head pose: after the first render
 * only the eyes are redone, the sweep path). */
static int redirect(ds_run *r, gs_model_ctx *c, const gs_subject *sub,
                    int n, const double off[2], int count, gs_error *err)
{
    size_t st = 3 * (size_t)r->S;
    int rc = GS_OK;
    for (int s = 0; !rc && s < n; s++)
        for (int j = s; !rc && j < count; j += n) {
            double p, y;
            gs_eval_ds_target(r->o->seed, r->identity, j, &p, &y);
            rc = target_labels(r, s, p, y, r->ours.lab + 4 * j, err);
            if (rc)
                break;
            memcpy(r->warp.lab + 4 * j, r->ours.lab + 4 * j,
                   4 * sizeof(float));
            gs_view v = {0};
            v.gaze_pitch = p + off[0];
            v.gaze_yaw = y + off[1];
            rc = gs_model_render(c, r->pool, &sub[s], &v,
                                 set_image(&r->ours, j, r->S), st, err);
            if (!rc)
                rc = gs_eval_warp_redirect(&r->src[s], p, y,
                                           set_image(&r->warp, j, r->S), st,
                                           err);
        }
    return rc;
}

/* Fits the subjects for k (k = 0: the one subject of every k) and makes
 * the redirected sets the fine-tunes of that k draw from. */
static int make_sets(ds_run *r, const gs_model *m, int k, const char *path,
                     int reuse, gs_eval_ds_result *res, gs_error *err)
{
    gs_model_ctx *c = gs_model_ctx_create(m);
    if (!c)
        return gs_error_set(err, GS_ERR_NOMEM, "eval-downstream: out of "
                            "memory");
    const int n = k ? k : 1;
    gs_subject sub[GS_EVAL_DS_POOL];
    double off[2] = {0, 0};
    int rc = fit(r, m, c, n, path, reuse, sub, off, res, err);
    if (!rc)
        rc = redirect(r, c, sub, n, off, k ? r->o->set_size - k
                                           : r->o->set_size, err);
    for (int kk = k ? k : 1; kk <= (k ? k : GS_EVAL_DS_POOL); kk++) {
        res->offset_deg[kk][0] = off[0] * GS_DS_DEG;
        res->offset_deg[kk][1] = off[1] * GS_DS_DEG;
    }
    gs_model_ctx_stats cs;
    gs_model_ctx_get_stats(c, &cs);
    r->renders_incremental += (long)cs.renders_incremental;
    r->renders_full += (long)cs.renders_full;
    gs_model_ctx_destroy(c);
    return rc;
}

/* ---- fine-tuning ---- */

/* CHW floats in [0, 1] of an RGB image (the estimator's float path). */
static void to_chw(const uint8_t *rgb, int S, float *img)
{
    size_t plane = (size_t)S * (size_t)S;
    for (size_t p = 0; p < plane; p++)
        for (int k = 0; k < 3; k++)
            img[k * plane + p] = rgb[3 * p + (size_t)k] / 255.0f;
}

/* The image batch slot b of the current step trains on. Real slots (the
 * first real_slots of a batch, every slot in the real-only condition)
 * draw one of the k real images, the others one of the set_size - k
 * redirected ones, by a hash of (seed, identity, k, step, b): every
 * condition draws the same real images in its real slots. */
static void pick(const ds_run *r, int b, const uint8_t **rgb,
                 const float **lab)
{
    uint64_t h = mix(mix(mix(mix(mix(r->o->seed, TAG_BATCH),
                                 (uint64_t)r->identity), (uint64_t)r->k),
                         (uint64_t)r->step), (uint64_t)b);
    if (!r->syn || b < r->real_slots) {
        int i = (int)(h % (uint64_t)r->k);
        *rgb = set_image(&r->real, i, r->S);
        *lab = r->real.lab + 4 * i;
    } else {
        int i = (int)(h % (uint64_t)(r->o->set_size - r->k));
        *rgb = set_image(r->syn, i, r->S);
        *lab = r->syn->lab + 4 * i;
    }
}

/* One batch element: forward, L1 on the 4 angles (the estimator's training
 * loss), backward into its gradient slot. */
static void batch_task(void *ctx, int b, int worker)
{
    ds_run *r = ctx;
    const uint8_t *rgb;
    const float *lab;
    pick(r, b, &rgb, &lab);
    float *img = r->img + (size_t)worker * r->img_len, out[4], d[4];
    float *g = r->sgrad + (size_t)b * r->np;
    to_chw(rgb, r->S, img);
    memset(g, 0, r->np * sizeof *g);
    r->rc[b] = gs_gaze_net_forward(r->work[worker], NULL, img, r->S, r->S,
                                   out, NULL);
    if (r->rc[b])
        return;
    gs_gaze_l1_loss(out, lab, 1.0f / (4.0f * (float)r->o->batch), d);
    r->rc[b] = gs_gaze_net_backward(r->work[worker], NULL, d, NULL, g, NULL);
}

/* Test image t: the angle between the predicted and the true gaze. */
static void test_task(void *ctx, int t, int worker)
{
    ds_run *r = ctx;
    float *img = r->img + (size_t)worker * r->img_len, out[4];
    const float *lab = r->test.lab + 4 * t;
    to_chw(set_image(&r->test, t, r->S), r->S, img);
    r->rc[t] = gs_gaze_net_forward(r->work[worker], NULL, img, r->S, r->S,
                                   out, NULL);
    r->serr[t] = r->rc[t] ? NAN : gs_eval_angle_deg(out[0], out[1], lab[0],
                                                     lab[1]);
}

/* Every worker's copy takes the tuned weights. */
static void sync_work(ds_run *r)
{
    const float *p = gs_gaze_net_params(r->tuned);
    for (int w = 0; w < r->threads; w++)
        memcpy(gs_gaze_net_params(r->work[w]), p, r->np * sizeof(float));
}

static int first_failure(const int *rc, int n, gs_error *err)
{
    for (int i = 0; i < n; i++)
        if (rc[i])
            return gs_error_set(err, rc[i], "eval-downstream: estimator "
                                "pass: %s", gs_strerror(rc[i]));
    return GS_OK;
}

/* Mean gaze angle of the tuned net over the test images, degrees; the sum
 * runs in image order. */
static int measure(ds_run *r, double *mean, gs_error *err)
{
    sync_work(r);
    gs_pool_for(r->pool, r->o->test_images, test_task, r);
    int rc = first_failure(r->rc, r->o->test_images, err);
    double s = 0;
    for (int t = 0; t < r->o->test_images; t++)
        s += r->serr[t];
    *mean = s / r->o->test_images;
    return rc;
}

/* Real slots per batch of the mixed conditions: at least real_fraction of
 * the batch and at least the real images' share of the set. */
static int real_slots(const gs_eval_ds_options *o, int k)
{
    int share = (int)ceil((double)o->batch * k / o->set_size);
    int frac = (int)ceil(o->batch * o->real_fraction - 1e-9);
    int n = share > frac ? share : frac;
    return n < o->batch ? n : o->batch;
}

/* Fine-tunes a fresh copy of the estimator on condition c with k real
 * images and measures it. */
static int finetune(ds_run *r, int k, int c, double *mean, gs_error *err)
{
    memcpy(gs_gaze_net_params(r->tuned), r->base, r->np * sizeof(float));
    r->k = k;
    r->syn = c == GS_EVAL_DS_OURS ? &r->ours
             : c == GS_EVAL_DS_WARP ? &r->warp : NULL;
    r->real_slots = real_slots(r->o, k);
    gs_nn_param_group grp = {gs_gaze_net_params(r->tuned), r->grad, r->np,
                             1.0};
    gs_nn_adam_config ac = gs_nn_adam_default_config();
    ac.max_grad_norm = 5.0; /* as the estimator was trained */
    gs_nn_adam *adam = NULL;
    int rc = gs_nn_adam_create(&adam, &grp, 1, &ac, err);
    for (r->step = 0; !rc && r->step < r->o->steps; r->step++) {
        sync_work(r);
        gs_pool_for(r->pool, r->o->batch, batch_task, r);
        rc = first_failure(r->rc, r->o->batch, err);
        if (rc)
            break;
        memset(r->grad, 0, r->np * sizeof(float));
        for (int b = 0; b < r->o->batch; b++) {
            const float *g = r->sgrad + (size_t)b * r->np;
            for (size_t i = 0; i < r->np; i++)
                r->grad[i] += g[i];
        }
        rc = gs_nn_adam_step(adam, r->o->lr, NULL);
        if (rc == GS_ERR_NONFINITE) /* skipped, as in training */
            rc = GS_OK;
    }
    gs_nn_adam_destroy(adam);
    return rc ? rc : measure(r, mean, err);
}

static int run_alloc(ds_run *r, const gs_gaze_net *est, gs_error *err)
{
    const gs_eval_ds_options *o = r->o;
    int rc = gs_gaze_net_clone(est, &r->tuned, err);
    if (rc)
        return rc;
    r->np = gs_gaze_net_param_count(r->tuned);
    r->img_len = 3 * (size_t)r->S * (size_t)r->S;
    r->work = calloc((size_t)r->threads, sizeof *r->work);
    for (int w = 0; !rc && r->work && w < r->threads; w++)
        rc = gs_gaze_net_clone(est, &r->work[w], err);
    if (rc)
        return rc;
    int ntask = o->batch > o->test_images ? o->batch : o->test_images;
    r->img = malloc((size_t)r->threads * r->img_len * sizeof(float));
    r->sgrad = malloc((size_t)o->batch * r->np * sizeof(float));
    r->grad = calloc(r->np, sizeof(float));
    r->serr = calloc((size_t)o->test_images, sizeof(double));
    r->rc = calloc((size_t)ntask, sizeof(int));
    float *base = malloc(r->np * sizeof(float));
    if (base)
        memcpy(base, gs_gaze_net_params(r->tuned), r->np * sizeof(float));
    r->base = base;
    if (!r->work || !r->img || !r->sgrad || !r->grad || !r->serr || !r->rc ||
        !r->base || set_alloc(&r->real, GS_EVAL_DS_POOL, r->S) ||
        set_alloc(&r->test, o->test_images, r->S) ||
        set_alloc(&r->ours, o->set_size, r->S) ||
        set_alloc(&r->warp, o->set_size, r->S))
        return gs_error_set(err, GS_ERR_NOMEM, "eval-downstream: out of "
                            "memory");
    return GS_OK;
}

static void run_free(ds_run *r)
{
    gs_gaze_net_destroy(r->tuned);
    for (int w = 0; r->work && w < r->threads; w++)
        gs_gaze_net_destroy(r->work[w]);
    free(r->work);
    free(r->img);
    free(r->sgrad);
    free(r->grad);
    free(r->serr);
    free(r->rc);
    free((void *)r->base);
    set_free(&r->real);
    set_free(&r->test);
    set_free(&r->ours);
    set_free(&r->warp);
    for (int i = 0; i < GS_EVAL_DS_POOL; i++)
        gs_synth_sample_free(&r->src[i]);
}

/* The fine-tunes of every k and condition, k = 0 first; with
 * subject_from_k the sets of each k are made before its fine-tunes. */
static int finetune_all(ds_run *r, const gs_model *m, const char *path,
                        int reuse, gs_eval_ds_result *res, gs_error *err)
{
    double k0, tune = 0;
    int rc = measure(r, &k0, err), runs = 0;
    for (int c = 0; c < GS_EVAL_DS_CONDITIONS; c++)
        res->err[0][c] = k0;
    if (!rc && !r->o->subject_from_k)
        rc = make_sets(r, m, 0, path, reuse, res, err);
    for (int k = 1; !rc && k <= r->o->max_k; k++) {
        if (!k_runs(r->o, k)) {
            res->offset_deg[k][0] = res->offset_deg[k][1] = NAN;
            continue;
        }
        if (r->o->subject_from_k)
            rc = make_sets(r, m, k, path, reuse, res, err);
        double t0 = gs_clock_s();
        for (int c = 0; !rc && c < GS_EVAL_DS_CONDITIONS; c++, runs++)
            rc = finetune(r, k, c, &res->err[k][c], err);
        tune += gs_clock_s() - t0;
    }
    res->finetune_s = runs ? tune / runs : NAN;
    res->fit_s = r->fit_s;
    res->renders_incremental = r->renders_incremental;
    res->renders_full = r->renders_full;
    return rc;
}

int gs_eval_downstream_identity(const gs_model *m, const gs_gaze_net *est,
                                const gs_eval_ds_options *o, int identity,
                                const char *fit_path, int reuse_fit,
                                gs_pool *pool, gs_eval_ds_result *res,
                                gs_error *err)
{
    if (!m || !est || !res)
        return gs_error_set(err, GS_ERR_ARG, "eval-downstream: NULL "
                            "argument");
    int rc = gs_eval_ds_options_check(o, err);
    if (rc)
        return rc;
    if (identity < 0)
        return gs_error_set(err, GS_ERR_ARG, "eval-downstream: identity %d",
                            identity);
    memset(res, 0, sizeof *res);
    for (int k = 0; k <= GS_EVAL_DS_POOL; k++)
        for (int c = 0; c < GS_EVAL_DS_CONDITIONS; c++)
            res->err[k][c] = NAN;
    gs_model_info mi;
    gs_model_get_info(m, &mi);
    ds_run r;
    memset(&r, 0, sizeof r);
    r.o = o;
    r.identity = identity;
    r.S = mi.image_size;
    r.focal = mi.focal;
    r.d_n = mi.distance_mm;
    r.pool = pool;
    r.threads = pool ? gs_pool_threads(pool) : 1;
    rc = run_alloc(&r, est, err);
    if (!rc)
        rc = render_ground_truth(&r, err);
    if (!rc) {
        res->kappa_h_deg = r.src_scene[0].kappa_h * GS_DS_DEG;
        res->kappa_v_deg = r.src_scene[0].kappa_v * GS_DS_DEG;
        rc = finetune_all(&r, m, fit_path, reuse_fit, res, err);
    }
    run_free(&r);
    return rc;
}
