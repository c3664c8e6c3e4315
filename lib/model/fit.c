/* Fitting a subject to one or several images (gs_model_fit,
 * gs_model_fit_images): Adam over the code, colour, gaze and head pose. */
#define _POSIX_C_SOURCE 200809L
#include <float.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "gazesplat/clock.h"
#include "frame.h"
#include "fit_internal.h"
#include "gazesplat/geom.h"
#include "gazesplat/nn.h"

/* ---- fitting ---- */

void gs_fit_options_default(gs_fit_options *o)
{
    memset(o, 0, sizeof *o);
    o->max_iters = 200;
    o->plateau_rel = 1e-3;
    o->code_prior = GS_FIT_CODE_PRIOR_MODEL;
    gs_geom_mat3_identity(o->head_R);
}

static void adam_update(fit_state *s, int t)
{
    const double b1 = 0.9, b2 = 0.999, eps = 1e-8;
    for (int i = 0; i < s->n; i++) {
        s->m1[i] = b1 * s->m1[i] + (1 - b1) * s->g[i];
        s->m2[i] = b2 * s->m2[i] + (1 - b2) * s->g[i] * s->g[i];
        double mh = s->m1[i] / (1 - pow(b1, t));
        double vh = s->m2[i] / (1 - pow(b2, t));
        s->x[i] -= s->lr[i] * mh / (sqrt(vh) + eps);
    }
}

/* Image loss of the current frame against target under weights w:
 * pred' = w (gain pred + bias) + (1 - w) target, loss = L1 + 0.1 SSIM.
 * Fills d_rgb (d loss / d pred) and the colour gradients. */
double gs_fit_image_loss(gs_model_ctx *c, gs_pool *pool, fit_bufs *b, const fit_state *s,
                         double *dgain, double *dbias)
{
    int S = c->S;
    size_t plane = (size_t)S * S;
    for (int k = 0; k < 3; k++) {
        double gn = s->x[V_GAIN + k], bi = s->x[V_BIAS + k];
        for (size_t i = 0; i < plane; i++) {
            float w = b->w[i];
            float v = (float)(gn * c->rgb[k * plane + i] + bi);
            b->pred[k * plane + i] = w * v + (1 - w) * b->target[k * plane + i];
        }
    }
    float l1 = 0, ls = 0;
    gs_nn_l1_forward(&l1, b->pred, b->target, NULL, 3, (int)plane);
    memset(b->dpred, 0, 3 * plane * sizeof(float));
    gs_nn_l1_backward(b->dpred, 1.0f, b->pred, b->target, NULL, 3, (int)plane);
    /* the SSIM's loss and gradient in one pass, on the pool: the bytes of
     * its forward and backward run one after the other */
    gs_nn_ssim_loss_fused(pool, &ls, b->dpred, 0.1f, b->pred, b->target, 3, S, S,
                          GS_NN_SSIM_ZERO, b->ssim_scratch, b->ssim_len);
    for (int k = 0; k < 3; k++) {
        double gn = s->x[V_GAIN + k];
        double sg = 0, sb = 0;
        for (size_t i = 0; i < plane; i++) {
            float d = b->dpred[k * plane + i] * b->w[i];
            sg += (double)d * c->rgb[k * plane + i];
            sb += d;
            b->dpred[k * plane + i] = (float)(d * gn);
        }
        dgain[k] = sg;
        dbias[k] = sb;
    }
    return (double)l1 + 0.1 * (double)ls;
}

static void state_to_frame(const gs_model_ctx *c, const fit_state *s,
                           const double R0[9], gs_frame *fr)
{
    memset(fr, 0, sizeof *fr);
    for (int k = 0; k < c->D; k++)
        fr->code[k] = (float)s->x[V_CODE + k];
    double dR[9];
    gs_geom_rodrigues(s->x + V_ROT, dR);
    gs_geom_mat3_mul(dR, R0, fr->head_R);
    for (int k = 0; k < 3; k++)
        fr->head_t[k] = s->x[V_TRANS + k];
    fr->gaze[0] = s->x[V_GAZE];
    fr->gaze[1] = s->x[V_GAZE + 1];
}

/* The image (planar, 0..1) and the mask's weights a fit's loss compares
 * against. */
static void fit_target_fill(fit_bufs *b, int S, const uint8_t *rgb, size_t stride,
                            const uint8_t *mask)
{
    size_t plane = (size_t)S * S;
    for (int y = 0; y < S; y++)
        for (int x = 0; x < S; x++) {
            size_t i = (size_t)y * S + x;
            for (int k = 0; k < 3; k++)
                b->target[k * plane + i] = rgb[(size_t)y * stride + 3 * x + k] / 255.0f;
            b->w[i] = mask ? mask[i] / 255.0f : 1.0f;
        }
}

static int fit_bufs_init(fit_bufs *b, const gs_model_ctx *c,
                         const uint8_t *rgb, size_t stride,
                         const uint8_t *mask)
{
    int S = c->S;
    size_t plane = (size_t)S * S;
    b->ssim_len = gs_nn_ssim_fused_scratch_size(3, S, S, GS_NN_SSIM_ZERO);
    b->target = malloc(3 * plane * sizeof(float));
    b->w = malloc(plane * sizeof(float));
    b->pred = malloc(3 * plane * sizeof(float));
    b->dpred = malloc(3 * plane * sizeof(float));
    b->ssim_scratch = malloc(b->ssim_len * sizeof(float));
    if (!b->target || !b->w || !b->pred || !b->dpred || !b->ssim_scratch)
        return GS_ERR_NOMEM;
    fit_target_fill(b, S, rgb, stride, mask);
    return GS_OK;
}

void gs_fit_bufs_free(fit_bufs *b)
{
    free(b->target);
    free(b->w);
    if (b->shared)
        return;
    free(b->pred);
    free(b->dpred);
    free(b->ssim_scratch);
}

static void fit_init(const gs_model_ctx *c, const gs_fit_options *o,
                     fit_state *s)
{
    memset(s, 0, sizeof *s);
    s->n = V_CODE + c->D;
    s->x[V_GAZE] = o->known_gaze ? o->gaze_pitch : 0.0;
    s->x[V_GAZE + 1] = o->known_gaze ? o->gaze_yaw : 0.0;
    for (int k = 0; k < 3; k++) {
        s->x[V_TRANS + k] = o->known_head ? o->head_t[k] : 0.0;
        s->x[V_GAIN + k] = 1.0;
    }
    if (!o->known_head)
        s->x[V_TRANS + 2] = c->m->cfg.d_n_mm;
    for (int k = 0; k < c->D; k++)
        s->x[V_CODE + k] = o->code_start ? o->code_start[k]
                                         : c->m->p.code_mean[k];
    for (int k = 0; k < 2; k++)
        s->lr[V_GAZE + k] = o->known_gaze ? 0.0 : 0.01;
    for (int k = 0; k < 3; k++) {
        s->lr[V_ROT + k] = o->known_head ? 0.0 : 0.004;
        s->lr[V_TRANS + k] = o->known_head ? 0.0 : 1.0;
        s->lr[V_GAIN + k] = o->lr_colour > 0 ? o->lr_colour : GS_FIT_LR_COLOUR_DEFAULT;
        s->lr[V_BIAS + k] = s->lr[V_GAIN + k];
    }
    const double lr_code = gs_model_fit_code_rate(c->m, o->lr_code);
    for (int k = 0; k < c->D; k++)
        s->lr[V_CODE + k] = o->code_fixed && o->code_fixed[k] ? 0.0 : lr_code;
}

/* PSNR over the weighted pixels of the composite in b->pred. */
float gs_fit_weighted_psnr(const fit_bufs *b, int S)
{
    size_t plane = (size_t)S * S;
    double se = 0, wsum = 0;
    for (int k = 0; k < 3; k++)
        for (size_t i = 0; i < plane; i++) {
            double e = b->pred[k * plane + i] - b->target[k * plane + i];
            se += e * e;
            wsum += b->w[i];
        }
    double mse = wsum > 0 ? se / wsum : 0;
    return (float)(mse > 1e-12 ? -10.0 * log10(mse) : 120.0);
}

/* The image flipped left to right, packed (S x S x 3); NULL when out of
 * memory. */
static uint8_t *mirror_image(const uint8_t *rgb, size_t stride, int S)
{
    uint8_t *f = malloc(3 * (size_t)S * S);
    if (f)
        for (int y = 0; y < S; y++)
            for (int x = 0; x < S; x++)
                memcpy(f + 3 * ((size_t)y * S + x),
                       rgb + (size_t)y * stride + 3 * (size_t)(S - 1 - x), 3);
    return f;
}

/* Pixel weights of the mirrored image from the input's mask. */
static void mirror_weights(const uint8_t *mask, int S, float *w)
{
    for (int y = 0; y < S; y++)
        for (int x = 0; x < S; x++)
            w[(size_t)y * S + x] = mask[(size_t)y * S + (S - 1 - x)] / 255.0f;
}

/* The mirrored view's gradient, in the fit's variables: the view is
 * gs_frame_mirror of the fit's frame (S = diag(-1, 1, 1): rotation S R S,
 * so a left perturbation w becomes -S w; translation S t; the gaze's yaw
 * and the lights' x negated), and each map is its own inverse. */
static void add_mirrored_grad(const gs_model_ctx *c, const gs_frame_grad *fm,
                              const double *dgain, const double *dbias,
                              double *g)
{
    g[V_GAZE] += fm->gaze[0];
    g[V_GAZE + 1] -= fm->gaze[1];
    g[V_ROT] += fm->rot[0];
    g[V_ROT + 1] -= fm->rot[1];
    g[V_ROT + 2] -= fm->rot[2];
    g[V_TRANS] -= fm->trans[0];
    g[V_TRANS + 1] += fm->trans[1];
    g[V_TRANS + 2] += fm->trans[2];
    for (int k = 0; k < 3; k++) {
        g[V_GAIN + k] += dgain[k];
        g[V_BIAS + k] += dbias[k];
    }
    float code[GS_MODEL_MAX_CODE];
    memcpy(code, fm->code, (size_t)c->D * sizeof code[0]);
    gs_frame_mirror_code(code, c->D);
    for (int k = 0; k < c->D; k++)
        g[V_CODE + k] += code[k];
}

/* Buffers of image i > 0 share image 0's scratch (pred, dpred, SSIM):
 * the context holds one forward at a time, so the images' losses run one
 * after another. Only the target and the weights are the image's own. */
static int fit_bufs_init_with(fit_bufs *b, const fit_bufs *with,
                              const gs_model_ctx *c, const uint8_t *rgb,
                              size_t stride, const uint8_t *mask)
{
    if (!with)
        return fit_bufs_init(b, c, rgb, stride, mask);
    fit_bufs own = *with;
    own.target = malloc(3 * (size_t)c->S * c->S * sizeof(float));
    own.w = malloc((size_t)c->S * c->S * sizeof(float));
    *b = own;
    b->shared = 1;
    if (!own.target || !own.w)
        return GS_ERR_NOMEM;
    fit_target_fill(b, c->S, rgb, stride, mask);
    return GS_OK;
}

/* One image's buffers (and its mirror's, o->mirror); 0 or GS_ERR_NOMEM. */
int gs_fit_image_bufs(const gs_model_ctx *c, const gs_fit_image *im,
                          int mirror, const fit_bufs *with, fit_bufs *b,
                          fit_bufs *bm)
{
    if (fit_bufs_init_with(b, with, c, im->rgb, im->stride, im->mask))
        return GS_ERR_NOMEM;
    if (!mirror)
        return GS_OK;
    uint8_t *flip = mirror_image(im->rgb, im->stride, c->S);
    int rc = flip ? fit_bufs_init_with(bm, with ? with : b, c, flip,
                                       3 * (size_t)c->S, NULL)
                  : GS_ERR_NOMEM;
    free(flip); /* bm holds it as floats */
    if (!rc && im->mask)
        mirror_weights(im->mask, c->S, bm->w);
    return rc;
}

void gs_fit_image_from_options(gs_fit_image *im, const uint8_t *rgb,
                               size_t stride, const gs_fit_options *o)
{
    memset(im, 0, sizeof *im);
    im->rgb = rgb;
    im->stride = stride;
    gs_geom_mat3_identity(im->head_R);
    if (!o)
        return;
    im->mask = o->mask;
    im->known_gaze = o->known_gaze;
    im->gaze_pitch = o->gaze_pitch;
    im->gaze_yaw = o->gaze_yaw;
    im->known_head = o->known_head;
    memcpy(im->head_R, o->head_R, sizeof im->head_R);
    memcpy(im->head_t, o->head_t, sizeof im->head_t);
}

/* What the fit of several images keeps per image. */
typedef struct fit_one {
    fit_state s, best;
    fit_bufs b, bm; /* bm: the mirrored view's (o.mirror) */
    gs_frame_grad fg, fgm;
    double R0[9];
    double dgain[3], dbias[3], dgm[3], dbm[3];
    double gprior[GS_CODE_PRIOR_DIM];
} fit_one;

static void fit_ones_free(fit_one *f, int k)
{
    for (int i = 0; f && i < k; i++) {
        gs_fit_bufs_free(&f[i].b);
        gs_fit_bufs_free(&f[i].bm);
    }
    free(f);
}

/* The options' checks shared by both fits; the prior weight resolved. */
static int fit_check_options(const gs_model_ctx *c, gs_fit_options *o,
                             gs_error *err)
{
    int rc = GS_OK;
    if (!(o->lr_code >= 0 && o->lr_code <= 10 && o->lr_colour >= 0 &&
          o->lr_colour <= 10))
        rc = gs_error_set(err, GS_ERR_ARG,
                          "fit: rates %g (code) and %g (colour): want [0, 10], "
                          "0 for the defaults", o->lr_code, o->lr_colour);
    if (o->code_prior == GS_FIT_CODE_PRIOR_MODEL)
        o->code_prior = c->m->cfg.fit_code_prior;
    if (!rc && !gs_code_prior_weight_ok(o->code_prior))
        rc = gs_error_set(err, GS_ERR_ARG,
                          "fit: code prior weight %g: want [0, 10], 0 for "
                          "none, -1 for the model's",
                          o->code_prior);
    if (!rc && !gs_code_prior_weight_ok(o->id_prior))
        rc = gs_error_set(err, GS_ERR_ARG,
                          "fit: identity prior weight %g: want [0, 10], 0 for "
                          "none", o->id_prior);
    if (!rc && o->mirror != 0 && o->mirror != 1)
        rc = gs_error_set(err, GS_ERR_ARG, "fit: mirror %d: want 0 or 1",
                          o->mirror);
    if (!rc && (o->anneal < 0 || o->anneal > GS_FIT_ANNEAL_MAX))
        rc = gs_error_set(err, GS_ERR_ARG,
                          "fit: anneal %d: want 0..%d halvings of the rates",
                          o->anneal, GS_FIT_ANNEAL_MAX);
    for (int k = 0; !rc && o->code_start && k < c->D; k++)
        if (!isfinite(o->code_start[k]))
            rc = gs_error_set(err, GS_ERR_ARG,
                              "fit: code_start[%d] is not finite", k);
    return rc;
}

static int fit_check_images(const gs_model_ctx *c, const gs_fit_image *im,
                            int k, gs_error *err)
{
    if (k < 1 || k > GS_FIT_IMAGES_MAX)
        return gs_error_set(err, GS_ERR_ARG, "fit: %d images: want 1..%d", k,
                            GS_FIT_IMAGES_MAX);
    for (int i = 0; i < k; i++) {
        int rc = GS_OK;
        if (!im[i].rgb)
            return gs_error_set(err, GS_ERR_ARG, "fit: image %d is NULL", i);
        if (im[i].stride < 3 * (size_t)c->S)
            return gs_error_set(err, GS_ERR_ARG, "fit: image %d: stride %zu < %d",
                                i, im[i].stride, 3 * c->S);
        if (im[i].known_gaze)
            rc = gs_model_check_gaze(im[i].gaze_pitch, im[i].gaze_yaw, err);
        if (!rc && im[i].known_head)
            rc = gs_model_check_pose(im[i].head_R, im[i].head_t, err);
        if (rc && k > 1 && err) { /* name the image, keep the reason */
            char why[sizeof err->msg];
            snprintf(why, sizeof why, "%s", err->msg);
            gs_error_set(err, rc, "fit: image %d: %s", i, why);
        }
        if (rc)
            return rc;
    }
    return GS_OK;
}

/* The fitted subject of image f (its best iterate), rendered once more for
 * its figures. */
static int fit_result(gs_model_ctx *c, gs_pool *pool, fit_one *f,
                      gs_subject *out, gs_error *err)
{
    gs_frame fr;
    state_to_frame(c, &f->best, f->R0, &fr);
    int rc = gs_frame_forward(c, pool, &fr, GS_STREAM_BOTH, 0, err);
    if (rc)
        return rc;
    /* Composites the best render into b.pred for the figures. */
    double dg[3], db[3];
    gs_fit_image_loss(c, pool, &f->b, &f->best, dg, db);
    int S = c->S;
    float ls = 0;
    gs_nn_ssim_loss_fused(pool, &ls, NULL, 0.0f, f->b.pred, f->b.target, 3, S, S,
                          GS_NN_SSIM_ZERO, f->b.ssim_scratch, f->b.ssim_len);
    gs_subject r;
    memset(&r, 0, sizeof r);
    r.code_dim = c->D;
    for (int k = 0; k < c->D; k++)
        r.code[k] = fr.code[k];
    memcpy(r.head_R, fr.head_R, sizeof r.head_R);
    memcpy(r.head_t, fr.head_t, sizeof r.head_t);
    r.gaze_pitch = fr.gaze[0];
    r.gaze_yaw = fr.gaze[1];
    for (int k = 0; k < 3; k++) {
        r.colour_gain[k] = (float)f->best.x[V_GAIN + k];
        r.colour_bias[k] = (float)f->best.x[V_BIAS + k];
    }
    r.fit_psnr = gs_fit_weighted_psnr(&f->b, S);
    r.fit_ssim = 1.0f - ls;
    *out = r;
    return GS_OK;
}

/* Image f's gradient in the fit's variables, from its view's (and its
 * mirror's) frame gradient, colours and code prior. */
static void fit_gradient(const gs_model_ctx *c, fit_one *f, int use_prior,
                         int V_PRIOR, const double *gid, int mirror)
{
    fit_state *s = &f->s;
    memset(s->g, 0, sizeof s->g);
    s->g[V_GAZE] = f->fg.gaze[0];
    s->g[V_GAZE + 1] = f->fg.gaze[1];
    for (int k = 0; k < 3; k++) {
        s->g[V_ROT + k] = f->fg.rot[k];
        s->g[V_TRANS + k] = f->fg.trans[k];
        s->g[V_GAIN + k] = f->dgain[k];
        s->g[V_BIAS + k] = f->dbias[k];
    }
    for (int k = 0; k < c->D; k++)
        s->g[V_CODE + k] = f->fg.code[k];
    for (int k = 0; use_prior && k < GS_CODE_PRIOR_DIM; k++)
        s->g[V_PRIOR + k] += f->gprior[k];
    for (int k = 0; gid && k < c->m->cfg.id_dim; k++)
        s->g[V_CODE + k] += gid[k];
    if (mirror)
        add_mirrored_grad(c, &f->fgm, f->dgm, f->dbm, s->g);
}

/* Image f's loss at its current state (and its gradient when `backward`),
 * with its code prior and, for gid != NULL, the identity prior. */
static int fit_image_step(gs_model_ctx *c, gs_pool *pool, fit_one *f,
                          const gs_fit_options *o, const gs_code_prior *prior,
                          int V_PRIOR, const gs_id_prior *idp, double *gid,
                          int backward, double *loss, gs_error *err)
{
    gs_frame fr;
    state_to_frame(c, &f->s, f->R0, &fr);
    int rc = gs_frame_forward(c, pool, &fr, GS_STREAM_BOTH, 0, err);
    if (rc)
        return rc;
    double l = gs_fit_image_loss(c, pool, &f->b, &f->s, f->dgain, f->dbias);
    memset(f->gprior, 0, sizeof f->gprior);
    if (prior)
        l += gs_code_prior_eval(prior, o->code_prior, f->s.x + V_PRIOR,
                                f->gprior);
    if (idp)
        l += gs_id_prior_eval(idp, o->id_prior, f->s.x + V_CODE, gid);
    /* The mirrored view: the input's gradient first (the context holds
     * one forward at a time), then the mirrored view's loss and
     * gradient, so the loss the fit tracks is the sum of both. */
    if ((o->mirror || backward) && isfinite(l)) {
        memset(&f->fg, 0, sizeof f->fg);
        rc = gs_frame_backward(c, pool, f->b.dpred, NULL, NULL, NULL, NULL,
                               &f->fg, err);
    }
    if (!rc && o->mirror && isfinite(l)) {
        memset(&f->fgm, 0, sizeof f->fgm);
        gs_frame frm;
        gs_frame_mirror(&fr, c->D, &frm);
        rc = gs_frame_forward(c, pool, &frm, GS_STREAM_BOTH, 0, err);
        if (!rc)
            l += gs_fit_image_loss(c, pool, &f->bm, &f->s, f->dgm, f->dbm);
        if (!rc && isfinite(l))
            rc = gs_frame_backward(c, pool, f->bm.dpred, NULL, NULL, NULL,
                                   NULL, &f->fgm, err);
    }
    *loss = l;
    return rc;
}

int gs_model_fit(gs_model_ctx *c, gs_pool *pool, const uint8_t *rgb,
                 size_t stride, const gs_fit_options *opt, gs_subject *out,
                 gs_fit_report *report, gs_error *err)
{
    if (!c || !rgb || !out)
        return gs_error_set(err, GS_ERR_ARG, "fit: NULL argument");
    if (stride < 3 * (size_t)c->S)
        return gs_error_set(err, GS_ERR_ARG, "fit: stride %zu < %d", stride,
                            3 * c->S);
    gs_fit_options o;
    if (opt)
        o = *opt;
    else
        gs_fit_options_default(&o);
    gs_fit_image im;
    gs_fit_image_from_options(&im, rgb, stride, &o);
    o.known_gaze = o.known_head = 0;
    o.mask = NULL;
    return gs_model_fit_images(c, pool, &im, 1, &o, out, report, err);
}

void gs_fit_options_of_image(const gs_fit_options *base, const gs_fit_image *im,
                             gs_fit_options *o)
{
    *o = *base;
    o->known_gaze = im->known_gaze;
    o->gaze_pitch = im->gaze_pitch;
    o->gaze_yaw = im->gaze_yaw;
    o->known_head = im->known_head;
    memcpy(o->head_R, im->head_R, sizeof o->head_R);
    memcpy(o->head_t, im->head_t, sizeof o->head_t);
}

/* Each image's start: the options with the image's own labels. */
static void fit_images_init(const gs_model_ctx *c, const gs_fit_image *im, int k,
                            const gs_fit_options *base, fit_one *f)
{
    for (int i = 0; i < k; i++) {
        gs_fit_options oi;
        gs_fit_options_of_image(base, &im[i], &oi);
        fit_init(c, &oi, &f[i].s);
        if (im[i].known_head)
            memcpy(f[i].R0, im[i].head_R, sizeof f[i].R0);
        else
            gs_geom_mat3_identity(f[i].R0);
    }
}

/* One step of all k images after their losses: the last image's backward
 * (the others took theirs at once), the gradients, the shared identity's
 * sum, then Adam and the bounds. gid: the identity prior's gradient, or
 * NULL. */
static int fit_images_update(gs_model_ctx *c, gs_pool *pool, fit_one *f, int k,
                             const gs_fit_options *o, int use_prior, int V_PRIOR,
                             const double *gid, int it, gs_error *err)
{
    int rc = GS_OK;
    const int id_dim = c->m->cfg.id_dim;
    fit_one *last = &f[k - 1];
    if (!o->mirror) {
        memset(&last->fg, 0, sizeof last->fg);
        rc = gs_frame_backward(c, pool, last->b.dpred, NULL, NULL, NULL,
                               NULL, &last->fg, err);
        if (rc)
            return rc;
    }
    for (int i = 0; i < k; i++)
        fit_gradient(c, &f[i], use_prior, V_PRIOR, i == 0 ? gid : NULL,
                     o->mirror);
    /* One identity: its gradient is the sum over the images, in their
     * order, and every image's copy takes the same Adam step from the
     * same start, so the copies stay equal bit for bit. */
    for (int j = 0; k > 1 && j < id_dim; j++) {
        double sum = f[0].s.g[V_CODE + j];
        for (int i = 1; i < k; i++)
            sum += f[i].s.g[V_CODE + j];
        for (int i = 0; i < k; i++)
            f[i].s.g[V_CODE + j] = sum;
    }
    for (int i = 0; i < k; i++)
        for (int j = 0; j < f[i].s.n; j++)
            if (!isfinite(f[i].s.g[j]))
                return gs_error_set(err, GS_ERR_NONFINITE,
                                    "fit: non-finite gradient at iteration "
                                    "%d", it);
    for (int i = 0; i < k; i++) {
        fit_state *s = &f[i].s;
        adam_update(s, it + 1);
        /* bound_expression: the expression stays where training put it. */
        for (int e = 0; o->bound_expression && e < GS_MODEL_EXPR_DIM; e++) {
            double *v = &s->x[V_CODE + id_dim + e];
            *v = fmax(gs_model_expr_lo[e], fmin(gs_model_expr_hi[e], *v));
        }
        /* The gaze stays inside the model's documented range. */
        s->x[V_GAZE] = fmax(-GS_MODEL_MAX_GAZE_PITCH,
                            fmin(GS_MODEL_MAX_GAZE_PITCH, s->x[V_GAZE]));
        s->x[V_GAZE + 1] = fmax(-GS_MODEL_MAX_GAZE_YAW,
                                fmin(GS_MODEL_MAX_GAZE_YAW, s->x[V_GAZE + 1]));
    }
    return rc;
}

int gs_model_fit_images(gs_model_ctx *c, gs_pool *pool, const gs_fit_image *im,
                        int k, const gs_fit_options *opt, gs_subject *out,
                        gs_fit_report *report, gs_error *err)
{
    if (!c || !im || !out)
        return gs_error_set(err, GS_ERR_ARG, "fit: NULL argument");
    gs_fit_options o;
    if (opt)
        o = *opt;
    else
        gs_fit_options_default(&o);
    if (o.known_gaze || o.known_head || o.mask)
        return gs_error_set(err, GS_ERR_ARG,
                            "fit: several images take their labels and masks "
                            "from gs_fit_image, not from the options");
    int rc = fit_check_images(c, im, k, err);
    if (!rc)
        rc = fit_check_options(c, &o, err);
    /* the prior (weight > 0): its slots are [expression | lights] after
     * the identity */
    const gs_code_prior *prior = o.code_prior > 0 ? &gs_code_prior_table : NULL;
    const int V_PRIOR = V_CODE + c->m->cfg.id_dim;
    if (rc)
        return rc;
    gs_id_prior *idp = NULL; /* the identity prior (weight > 0) */
    if (o.id_prior > 0 && (rc = gs_id_prior_make(c->m, &idp, err)))
        return rc;
    int iters = o.max_iters > 0 ? o.max_iters : 200;
    double plateau = o.plateau_rel > 0 ? o.plateau_rel : 1e-3;

    fit_one *f = calloc((size_t)k, sizeof *f);
    gs_subject *res = calloc((size_t)k, sizeof *res);
    for (int i = 0; f && res && !rc && i < k; i++)
        rc = gs_fit_image_bufs(c, &im[i], o.mirror, i ? &f[0].b : NULL, &f[i].b,
                            &f[i].bm);
    if (!f || !res || rc) {
        fit_ones_free(f, f ? k : 0);
        free(res);
        gs_id_prior_free(idp);
        return gs_error_set(err, GS_ERR_NOMEM, "fit: out of memory");
    }
    fit_images_init(c, im, k, &o, f);
    gs_opt_watch w;
    gs_opt_watch_start(&w, plateau, o.time_budget_s, gs_clock_s());
    int it = 0, plateaued = 0, halvings = 0, on_time = 0;
    for (; it < iters; it++) {
        if (o.cancel && o.cancel(o.cancel_arg)) {
            rc = gs_error_set(err, GS_ERR_CANCELLED,
                              "fit cancelled at iteration %d", it);
            break;
        }
        /* The sum of the images' losses; every image but the last has its
         * gradient taken at once (one forward at a time), the last's waits
         * for the stopping tests, as a fit of one image always did. */
        double loss = 0, gid[GS_MODEL_MAX_CODE] = {0};
        for (int i = 0; !rc && i < k && isfinite(loss); i++) {
            double li = 0;
            rc = fit_image_step(c, pool, &f[i], &o, prior,
                                V_PRIOR, i == 0 ? idp : NULL, gid, i < k - 1,
                                &li, err);
            loss += li;
        }
        if (rc)
            break;
        if (!isfinite(loss)) {
            rc = gs_error_set(err, GS_ERR_NONFINITE,
                              "fit diverged at iteration %d (loss %g, first "
                              "%g)", it, loss, w.first);
            break;
        }
        if (gs_opt_watch_best(&w, it, loss))
            for (int i = 0; i < k; i++)
                f[i].best = f[i].s;
        if (gs_opt_watch_plateau(&w, it, loss)) {
            if (halvings == o.anneal) {
                plateaued = 1;
                break;
            }
            /* anneal: the steps shrink and the fit goes on from here */
            halvings++;
            gs_opt_watch_restart(&w, it);
            for (int i = 0; i < k; i++)
                for (int j = 0; j < f[i].s.n; j++)
                    f[i].s.lr[j] *= 0.5;
        }
        if (gs_opt_watch_over_time(&w, gs_clock_s())) {
            on_time = it + 1 < iters;
            break;
        }
        rc = fit_images_update(c, pool, f, k, &o, prior != NULL, V_PRIOR, idp ? gid : NULL, it, err);
        if (rc)
            break;
    }
    for (int i = 0; !rc && i < k; i++)
        rc = fit_result(c, pool, &f[i], &res[i], err);
    if (!rc)
        memcpy(out, res, (size_t)k * sizeof *out);
    if (report) {
        memset(report, 0, sizeof *report);
        report->iters = it;
        report->seconds = gs_clock_s() - w.t0;
        report->loss_first = w.first;
        report->loss_last = w.best;
        report->stopped_on_plateau = plateaued;
        report->stopped_on_time = on_time;
        report->halvings = halvings;
    }
    fit_ones_free(f, k);
    free(res);
    gs_id_prior_free(idp);
    return rc;
}
