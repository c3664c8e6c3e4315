/* The protocol's fit of an input image (true head pose and gaze given) and
 * the on-disk cache of fitted subjects that `gazesplat eval` and
 * `gazesplat eval-downstream` share. */
#define _POSIX_C_SOURCE 200809L /* clock_gettime */
#include <stdio.h>
#include <string.h>
#include <time.h>

#include "gazesplat/clock.h"
#include "gazesplat/eval.h"

/* The options of the protocol's fit: base with the sample's labels. */
static void protocol_options(const gs_fit_options *base,
                             const gs_synth_sample *in, gs_fit_options *o)
{
    *o = *base;
    /* The dataset labels are given, as GazeNeRF's protocol uses
     * ETH-XGaze's: the fit only has to find the person. */
    o->known_gaze = 1;
    o->gaze_pitch = in->labels.gaze_head_pitch;
    o->gaze_yaw = in->labels.gaze_head_yaw;
    o->known_head = 1;
    memcpy(o->head_R, in->labels.head_R, sizeof o->head_R);
    memcpy(o->head_t, in->labels.head_t, sizeof o->head_t);
}

static void sample_options(int iters, double lr_code, double lr_colour,
                           gs_fit_options *o)
{
    gs_fit_options_default(o);
    o->max_iters = iters > 0 ? iters : 200;
    o->lr_code = lr_code;
    o->lr_colour = lr_colour;
}

int gs_eval_fit_sample(gs_model_ctx *c, gs_pool *pool,
                       const gs_synth_sample *in, int iters, double lr_code,
                       double lr_colour, gs_subject *sub, double *secs,
                       gs_error *err)
{
    gs_fit_options o;
    sample_options(iters, lr_code, lr_colour, &o);
    return gs_eval_fit_sample_with(c, pool, in, &o, sub, secs, err);
}

int gs_eval_fit_sample_with(gs_model_ctx *c, gs_pool *pool,
                            const gs_synth_sample *in,
                            const gs_fit_options *base, gs_subject *sub,
                            double *secs, gs_error *err)
{
    if (!c || !in || !base || !sub)
        return gs_error_set(err, GS_ERR_ARG, "eval fit: NULL argument");
    gs_fit_options o;
    protocol_options(base, in, &o);
    gs_fit_report rep;
    double t0 = gs_clock_s();
    int rc = gs_model_fit(c, pool, in->rgb, in->stride, &o, sub, &rep, err);
    if (secs)
        *secs = gs_clock_s() - t0;
    return rc;
}

int gs_eval_fit_samples(gs_model_ctx *c, gs_pool *pool,
                        const gs_synth_sample *in, int k, int iters,
                        double lr_code, double lr_colour, int free_gaze,
                        gs_subject *out, double *secs, gs_error *err)
{
    if (!c || !in || !out)
        return gs_error_set(err, GS_ERR_ARG, "eval fit: NULL argument");
    if (k < 1 || k > GS_FIT_IMAGES_MAX)
        return gs_error_set(err, GS_ERR_ARG, "eval fit: %d samples (want "
                            "1..%d)", k, GS_FIT_IMAGES_MAX);
    gs_fit_options o;
    sample_options(iters, lr_code, lr_colour, &o);
    gs_fit_image im[GS_FIT_IMAGES_MAX];
    for (int i = 0; i < k; i++) {
        gs_fit_options oi;
        protocol_options(&o, &in[i], &oi);
        if (free_gaze)
            oi.known_gaze = 0;
        gs_fit_image_from_options(&im[i], in[i].rgb, in[i].stride, &oi);
    }
    gs_fit_report rep;
    double t0 = gs_clock_s();
    int rc = gs_model_fit_images(c, pool, im, k, &o, out, &rep, err);
    if (secs)
        *secs = gs_clock_s() - t0;
    return rc;
}

uint64_t gs_eval_fit_key(const gs_model *m, const gs_fit_options *base,
                         const gs_synth_sample *in)
{
    gs_fit_options o;
    protocol_options(base, in, &o);
    return gs_model_fit_key(m, &o, in->rgb, in->stride);
}

uint64_t gs_eval_fit_sample_key(const gs_model *m, const gs_synth_sample *in,
                                int iters, double lr_code, double lr_colour)
{
    gs_fit_options o;
    sample_options(iters, lr_code, lr_colour, &o);
    return gs_eval_fit_key(m, &o, in);
}

#define CACHE_MAGIC "GSFITC2\n"
#define CACHE_HEAD 24 /* magic, key, seconds */

int gs_eval_fit_cache_read(const char *path, uint64_t key, gs_subject *sub,
                           double *secs, gs_error *err)
{
    uint8_t buf[CACHE_HEAD + GS_SUBJECT_ENCODED_MAX + 1];
    FILE *f = path ? fopen(path, "rb") : NULL;
    if (!f)
        return gs_error_set(err, GS_ERR_IO, "no fit cache file %s",
                            path ? path : "(null)");
    size_t n = fread(buf, 1, sizeof buf, f);
    fclose(f);
    gs_subject s;
    if (n > 8 && memcmp(buf, CACHE_MAGIC, 8) != 0 &&
        gs_subject_decode(buf + 8, n - 8, &s, NULL) == GS_OK)
        return gs_error_set(err, GS_ERR_STATE,
                            "%s: a fit cache file of an older version (not "
                            "keyed by what made it)", path);
    if (n <= CACHE_HEAD || memcmp(buf, CACHE_MAGIC, 8) != 0 ||
        gs_subject_decode(buf + CACHE_HEAD, n - CACHE_HEAD, &s, NULL) != GS_OK)
        return gs_error_set(err, GS_ERR_FORMAT, "%s: not a fit cache file",
                            path);
    uint64_t k = 0;
    for (int i = 0; i < 8; i++)
        k |= (uint64_t)buf[8 + i] << (8 * i);
    if (k != key)
        return gs_error_set(err, GS_ERR_STATE,
                            "%s: fitted with another model, other fit options "
                            "or another input", path);
    *sub = s;
    if (secs)
        memcpy(secs, buf + 16, 8);
    return GS_OK;
}

int gs_eval_fit_cache_write(const char *path, uint64_t key,
                            const gs_subject *sub, double secs,
                            gs_error *err)
{
    uint8_t buf[CACHE_HEAD + GS_SUBJECT_ENCODED_MAX];
    memcpy(buf, CACHE_MAGIC, 8);
    for (int i = 0; i < 8; i++)
        buf[8 + i] = (uint8_t)(key >> (8 * i));
    memcpy(buf + 16, &secs, 8);
    size_t n = CACHE_HEAD + gs_subject_encode(sub, buf + CACHE_HEAD,
                                              sizeof buf - CACHE_HEAD);
    char tmp[4200];
    if (!path || snprintf(tmp, sizeof tmp, "%s.tmp", path) >= (int)sizeof tmp)
        return gs_error_set(err, GS_ERR_ARG, "fit cache: bad path");
    FILE *f = fopen(tmp, "wb");
    int bad = !f || fwrite(buf, 1, n, f) != n;
    if (f && fclose(f))
        bad = 1;
    if (!bad && rename(tmp, path) != 0)
        bad = 1;
    if (bad) {
        remove(tmp);
        return gs_error_set(err, GS_ERR_IO, "cannot write %s", path);
    }
    return GS_OK;
}
