/* Per-image fine-tuning (gs_model_finetune, gs_model_finetune_images):
 * Adam over chosen parts of a clone of the model, the subject fixed. */
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

/* ---- per-image fine-tuning ---- */

void gs_finetune_options_default(gs_finetune_options *o)
{
    memset(o, 0, sizeof *o);
    o->iters = 50;
    o->lr = 1e-3;
    o->parts = GS_FT_DEFAULT;
    o->mirror = 1;
}

static const struct {
    const char *name;
    unsigned bit;
} ft_names[] = {{"face", GS_FT_FACE}, {"eye", GS_FT_EYE}, {"renderer", GS_FT_RENDERER},
                {"mlp", GS_FT_MLP}, {"geometry", GS_FT_GEOMETRY},
                {"face-geometry", GS_FT_FACE_GEOMETRY}};
#define N_FT_NAMES (sizeof ft_names / sizeof ft_names[0])

int gs_finetune_parts_parse(const char *s, unsigned *parts, gs_error *err)
{
    if (!s || !parts)
        return gs_error_set(err, GS_ERR_ARG, "finetune parts: NULL argument");
    unsigned bits = 0;
    const char *p = s;
    for (;;) {
        size_t n = strcspn(p, ",");
        size_t k = 0;
        while (k < N_FT_NAMES && !(strlen(ft_names[k].name) == n && !strncmp(p, ft_names[k].name, n)))
            k++;
        if (n == 0)
            return gs_error_set(err, GS_ERR_ARG, "finetune parts: an empty name in '%.64s'", s);
        if (k == N_FT_NAMES)
            return gs_error_set(err, GS_ERR_ARG,
                                "finetune parts: '%.*s' in '%.64s' is none of face, eye, renderer, "
                                "mlp, geometry, face-geometry", (int)(n < 32 ? n : 32), p, s);
        bits |= ft_names[k].bit;
        p += n;
        if (*p == '\0')
            break;
        p++; /* a comma: another name must follow */
    }
    *parts = bits;
    return GS_OK;
}

const char *gs_finetune_parts_name(unsigned parts, char *buf, size_t cap)
{
    size_t n = 0;
    if (cap)
        buf[0] = '\0';
    for (size_t k = 0; k < N_FT_NAMES; k++)
        if ((parts & ft_names[k].bit) && n < cap) {
            int w = snprintf(buf + n, cap - n, "%s%s", n ? "," : "", ft_names[k].name);
            n += w > 0 ? (size_t)w : 0;
        }
    return buf;
}

/* Learning-rate multipliers of the training run (train.c). */
static double part_lr(int group)
{
    switch (group) {
    case GS_PG_GAUSS_XYZ: return 10.0;
    case GS_PG_GAUSS_FEAT: return 5.0;
    default: return 1.0;
    }
}

typedef struct ft_run {
    gs_model *m;
    gs_model_ctx *c;
    float *grad, *orig, *best; /* grad: all parameters; orig/best: tuned */
    int idx[GS_MODEL_MAX_TENSORS], n;
    size_t tuned;
    gs_model_params g;
    gs_nn_adam *adam;
} ft_run;

/* Copies the tuned tensors between the model and a packed buffer. */
static void ft_pack(ft_run *r, float *buf, int to_model)
{
    size_t o = 0;
    for (int i = 0; i < r->n; i++) {
        const gs_ptensor *t = &r->m->t[r->idx[i]];
        float *p = r->m->params + t->offset;
        if (to_model)
            memcpy(p, buf + o, t->count * sizeof(float));
        else
            memcpy(buf + o, p, t->count * sizeof(float));
        o += t->count;
    }
}

static void ft_free(ft_run *r)
{
    gs_model_ctx_destroy(r->c);
    gs_nn_adam_destroy(r->adam);
    free(r->grad);
    free(r->orig);
    free(r->best);
}

/* Unbinds from g the gradients a fine-tune of `parts` never reads and the
 * backward knows to skip: the renderer's weights (gs_frame_backward
 * computes the renderer's input gradients alone) and the MLPs' (the face
 * stream's blocks, the eye MLPs and the eyeball shift). What is left
 * unbound stays zero in the gradient array, which is what Adam saw of it
 * before; the tuned parts' gradients are the same bits. */
static void ft_unbind_untuned(gs_model_params *g, unsigned parts)
{
    if (!(parts & GS_FT_RENDERER))
        memset(&g->rend, 0, sizeof g->rend);
    if (!(parts & GS_FT_MLP)) {
        memset(&g->face_e, 0, sizeof g->face_e);
        memset(&g->face_p, 0, sizeof g->face_p);
        memset(&g->eye, 0, sizeof g->eye);
        memset(g->eye_rot, 0, sizeof g->eye_rot);
        g->eye_centre_w = NULL;
    }
}

static int ft_init(ft_run *r, gs_model *m, unsigned parts, gs_error *err)
{
    memset(r, 0, sizeof *r);
    r->m = m;
    gs_nn_param_group groups[GS_MODEL_MAX_TENSORS];
    for (int i = 0; i < m->ntensors; i++)
        if (gs_model_tensor_part(&m->t[i]) & parts) {
            r->idx[r->n++] = i;
            r->tuned += m->t[i].count;
        }
    if (!r->n)
        return gs_error_set(err, GS_ERR_ARG,
                            "finetune: parts 0x%x name no tensor", parts);
    r->c = gs_model_ctx_create(m);
    r->grad = calloc(m->nparams, sizeof(float));
    r->orig = malloc(r->tuned * sizeof(float));
    r->best = malloc(r->tuned * sizeof(float));
    if (!r->c || !r->grad || !r->orig || !r->best)
        return gs_error_set(err, GS_ERR_NOMEM, "finetune: out of memory");
    gs_model_bind(m, r->grad, &r->g);
    ft_unbind_untuned(&r->g, parts);
    for (int i = 0; i < r->n; i++) {
        const gs_ptensor *t = &m->t[r->idx[i]];
        groups[i].param = m->params + t->offset;
        groups[i].grad = r->grad + t->offset;
        groups[i].n = t->count;
        groups[i].lr_mult = part_lr(t->group);
    }
    gs_nn_adam_config ac = gs_nn_adam_default_config();
    int rc = gs_nn_adam_create(&r->adam, groups, r->n, &ac, err);
    if (rc)
        return rc;
    ft_pack(r, r->orig, 0);
    memcpy(r->best, r->orig, r->tuned * sizeof(float));
    return GS_OK;
}

/* Feature pixels within r of the outline of a coverage map [fs, fs]
 * (coverage under 0.5 there) get 0, the rest 1 (gs_finetune_options.
 * outline_px): the colours learn inside the model's own outline only. On
 * the outline, the input's background may fall on Gaussians seen edge-on,
 * which would take its colour over a surface that faces the camera at
 * another head pose (docs/model.md, "Per-image fine-tuning"). */
static void outline_mask(const float *alpha, int fs, int r, float *inner)
{
    for (int y = 0; y < fs; y++)
        for (int x = 0; x < fs; x++) {
            int in = 1;
            for (int dy = -r; dy <= r && in; dy++)
                for (int dx = -r; dx <= r && in; dx++) {
                    int yy = y + dy, xx = x + dx;
                    in = yy >= 0 && xx >= 0 && yy < fs && xx < fs &&
                         alpha[yy * fs + xx] >= 0.5f;
                }
            inner[y * fs + x] = (float)in;
        }
}

int gs_model_finetune(gs_model *m, gs_pool *pool, const gs_subject *s,
                      const uint8_t *rgb, size_t stride,
                      const gs_finetune_options *opt,
                      gs_finetune_report *report, gs_error *err)
{
    if (!m || !s || !rgb)
        return gs_error_set(err, GS_ERR_ARG, "finetune: NULL argument");
    gs_finetune_options o;
    if (opt)
        o = *opt;
    else
        gs_finetune_options_default(&o);
    gs_fit_image im;
    gs_fit_image_from_options(&im, rgb, stride, NULL);
    im.mask = o.mask;
    o.mask = NULL;
    return gs_model_finetune_images(m, pool, s, &im, 1, &o, report, err);
}

/* What a fine-tune over several images keeps per (subject, image) pair. */
typedef struct ft_one {
    fit_state fs;   /* the subject's colour transform, for gs_fit_image_loss */
    fit_bufs b, bm; /* bm: the mirrored view's (o.mirror) */
    gs_frame fr, frm;
    float *inner, *inner_m; /* outline masks (o.outline_px) */
} ft_one;

static void ft_ones_free(ft_one *f, int k)
{
    for (int i = 0; f && i < k; i++) {
        gs_fit_bufs_free(&f[i].b);
        gs_fit_bufs_free(&f[i].bm);
        free(f[i].inner);
        free(f[i].inner_m);
    }
    free(f);
}

/* Pair f's gradient at the context's current forward (its own), added
 * to r->g, and its mirror's (o->mirror). */
static int ft_pair_backward(ft_run *r, gs_pool *pool, ft_one *f,
                            const gs_finetune_options *o, int masked, int it,
                            gs_error *err)
{
    gs_frame_grad fg;
    memset(&fg, 0, sizeof fg);
    int rc = gs_frame_backward(r->c, pool, f->b.dpred, NULL, NULL, NULL, &r->g,
                               &fg, err);
    if (!rc && o->mirror) { /* the mirrored view adds its gradient */
        double dgm[3], dbm[3];
        rc = gs_frame_forward(r->c, pool, &f->frm, GS_STREAM_BOTH, 1, err);
        if (!rc && !isfinite(gs_fit_image_loss(r->c, pool, &f->bm, &f->fs, dgm, dbm)))
            rc = gs_error_set(err, GS_ERR_NONFINITE,
                              "finetune: mirrored view diverged at step %d", it);
        if (!rc && masked) { /* its own outline, from its first view */
            if (it == 0)
                outline_mask(r->c->alpha, r->c->fs, o->outline_px, f->inner_m);
            rc = gs_frame_set_feature_mask(r->c, f->inner_m, err);
        }
        memset(&fg, 0, sizeof fg);
        if (!rc)
            rc = gs_frame_backward(r->c, pool, f->bm.dpred, NULL, NULL, NULL,
                                   &r->g, &fg, err);
        if (!rc && masked)
            rc = gs_frame_set_feature_mask(r->c, f->inner, err);
    }
    return rc;
}

/* Pair f's loss at the model's current parameters and the PSNR of its
 * composite; its gradient too when `backward` (else the context keeps its
 * forward for ft_pair_backward). */
static int ft_pair_step(ft_run *r, gs_pool *pool, ft_one *f,
                        const gs_finetune_options *o, int masked, int it,
                        int backward, double *loss, double *psnr,
                        gs_error *err)
{
    int rc = gs_frame_forward(r->c, pool, &f->fr, GS_STREAM_BOTH, 1, err);
    if (!rc && masked) {
        if (it == 0)
            outline_mask(r->c->alpha, r->c->fs, o->outline_px, f->inner);
        rc = gs_frame_set_feature_mask(r->c, f->inner, err);
    }
    if (rc)
        return rc;
    double dg[3], db[3];
    *loss = gs_fit_image_loss(r->c, pool, &f->b, &f->fs, dg, db);
    *psnr = gs_fit_weighted_psnr(&f->b, r->c->S);
    if (!backward || !isfinite(*loss))
        return GS_OK;
    return ft_pair_backward(r, pool, f, o, masked, it, err);
}

/* The options' and pairs' checks; the steps, rate and parts they ask for. */
static int ft_check(const gs_model *m, const gs_subject *s, const gs_fit_image *im, int k,
                    const gs_finetune_options *o, int *iters_out, double *lr, unsigned *parts_out,
                    gs_error *err)
{
    int iters = o->iters > 0 ? o->iters : 50;
    unsigned parts = o->parts ? o->parts : GS_FT_DEFAULT;
    *iters_out = iters;
    *lr = o->lr > 0 ? o->lr : 1e-3;
    *parts_out = parts;
    if (!isfinite(o->lr) || o->lr > 1.0 || iters > 100000 || !isfinite(o->plateau_rel) ||
        isnan(o->time_budget_s) ||
        (parts & ~GS_FT_ALL_PARTS))
        return gs_error_set(err, GS_ERR_ARG,
                            "finetune: lr %g (want <= 1), iterations %d "
                            "(<= 100000) or parts 0x%x out of range",
                            o->lr, o->iters, parts);
    if (o->mirror != 0 && o->mirror != 1)
        return gs_error_set(err, GS_ERR_ARG, "finetune: mirror %d: want 0 or 1",
                            o->mirror);
    if (o->outline_px < 0 || o->outline_px > 8)
        return gs_error_set(err, GS_ERR_ARG,
                            "finetune: outline %d px: want 0..8", o->outline_px);
    int rc = GS_OK;
    for (int i = 0; i < k; i++) {
        if (!im[i].rgb)
            return gs_error_set(err, GS_ERR_ARG, "finetune: image %d is NULL", i);
        if ((rc = gs_model_check_subject(m, &s[i], err)))
            return rc;
        if ((size_t)m->cfg.image_size * 3 > im[i].stride)
            return gs_error_set(err, GS_ERR_ARG, "finetune: stride %zu < %d",
                                im[i].stride, 3 * m->cfg.image_size);
    }
    return rc;
}

/* Each pair's buffers, outline masks, fixed colour transform and frames
 * (and their mirrors); GS_ERR_NOMEM when out of memory. */
static int ft_ones_init(const ft_run *r, ft_one *f, const gs_subject *s, const gs_fit_image *im,
                        int k, int mirror)
{
    int rc = GS_OK;
    size_t fplane = (size_t)r->c->fs * r->c->fs;
    for (int i = 0; !rc && i < k; i++) {
        ft_one *p = &f[i];
        if (gs_fit_image_bufs(r->c, &im[i], mirror, i ? &f[0].b : NULL, &p->b, &p->bm))
            rc = GS_ERR_NOMEM;
        p->inner = malloc(fplane * sizeof(float));
        p->inner_m = malloc(fplane * sizeof(float));
        if (!p->inner || !p->inner_m)
            rc = GS_ERR_NOMEM;
        /* The subject's colour transform, fixed: gs_fit_image_loss reads it here. */
        for (int c3 = 0; c3 < 3; c3++) {
            p->fs.x[V_GAIN + c3] = s[i].colour_gain[c3];
            p->fs.x[V_BIAS + c3] = s[i].colour_bias[c3];
        }
        gs_model_frame_of(&s[i], NULL, &p->fr);
        gs_frame_mirror(&p->fr, s[i].code_dim, &p->frm);
    }
    return rc;
}

int gs_model_finetune_images(gs_model *m, gs_pool *pool, const gs_subject *s,
                             const gs_fit_image *im, int k,
                             const gs_finetune_options *opt,
                             gs_finetune_report *report, gs_error *err)
{
    if (!m || !s || !im)
        return gs_error_set(err, GS_ERR_ARG, "finetune: NULL argument");
    if (k < 1 || k > GS_FIT_IMAGES_MAX)
        return gs_error_set(err, GS_ERR_ARG, "finetune: %d images: want 1..%d",
                            k, GS_FIT_IMAGES_MAX);
    gs_finetune_options o;
    if (opt)
        o = *opt;
    else
        gs_finetune_options_default(&o);
    if (o.mask)
        return gs_error_set(err, GS_ERR_ARG,
                            "finetune: several images take their masks from "
                            "gs_fit_image, not from the options");
    int iters;
    double lr;
    unsigned parts;
    int rc = ft_check(m, s, im, k, &o, &iters, &lr, &parts, err);
    if (rc)
        return rc;
    ft_run r;
    ft_one *f = calloc((size_t)k, sizeof *f);
    rc = f ? ft_init(&r, m, parts, err)
           : gs_error_set(err, GS_ERR_NOMEM, "finetune: out of memory");
    if (rc) {
        free(f);
        return rc;
    }
    int masked = o.outline_px > 0 && (parts & (GS_FT_FACE | GS_FT_EYE | GS_FT_MLP));
    rc = ft_ones_init(&r, f, s, im, k, o.mirror);
    if (rc)
        rc = gs_error_set(err, GS_ERR_NOMEM, "finetune: out of memory");
    gs_opt_watch w;
    gs_opt_watch_start(&w, o.plateau_rel, o.time_budget_s, gs_clock_s());
    float psnr_first = NAN, psnr_best = NAN;
    int it = 0, stopped_on_time = 0, plateaued = 0;
    for (; !rc && it <= iters; it++) {
        if (o.cancel && o.cancel(o.cancel_arg)) {
            rc = gs_error_set(err, GS_ERR_CANCELLED,
                              "finetune cancelled at step %d", it);
            break;
        }
        /* The pairs' gradients accumulate: every pair but the last has its
         * gradient taken at once (one forward at a time), the last's waits
         * for the stopping tests, as one image's always did. */
        gs_nn_adam_zero_grad(r.adam);
        double loss = 0, psnr = 0;
        for (int i = 0; !rc && i < k && isfinite(loss); i++) {
            double li = 0, pi = 0;
            rc = ft_pair_step(&r, pool, &f[i], &o, masked, it, i < k - 1, &li,
                              &pi, err);
            loss += li;
            psnr += pi;
        }
        if (rc)
            break;
        float psnr_now = (float)(psnr / k);
        if (!isfinite(loss)) {
            rc = gs_error_set(err, GS_ERR_NONFINITE,
                              "finetune diverged at step %d (loss %g, "
                              "first %g)", it, loss, w.first);
            break;
        }
        if (it == 0)
            psnr_first = psnr_now;
        if (gs_opt_watch_best(&w, it, loss)) {
            psnr_best = psnr_now;
            if (it > 0)
                ft_pack(&r, r.best, 0);
        }
        if (it == iters)
            break; /* the last step's result is measured, not stepped from */
        if (gs_opt_watch_plateau(&w, it, loss)) {
            plateaued = 1;
            break;
        }
        if (gs_opt_watch_over_time(&w, gs_clock_s())) {
            stopped_on_time = 1;
            break;
        }
        rc = ft_pair_backward(&r, pool, &f[k - 1], &o, masked, it, err);
        if (rc)
            break;
        double gn = 0;
        rc = gs_nn_adam_step(r.adam, lr, &gn);
        if (rc == GS_ERR_NONFINITE) {
            rc = gs_error_set(err, GS_ERR_NONFINITE,
                              "finetune: non-finite gradient at step %d "
                              "(loss %g)", it, loss);
            break;
        }
        if (rc) {
            rc = gs_error_set(err, rc, "finetune: optimizer step failed");
            break;
        }
    }
    /* The best iterate, or on any error the parameters of before. */
    ft_pack(&r, rc ? r.orig : r.best, 1);
    if (!rc)
        m->tuned |= parts;
    if (report) {
        *report = (gs_finetune_report){.iters = it, .seconds = gs_clock_s() - w.t0,
                                       .loss_first = w.first, .loss_best = w.best,
                                       .psnr_first = psnr_first, .psnr_best = psnr_best,
                                       .params_tuned = r.tuned, .stopped_on_time = stopped_on_time,
                                       .stopped_on_plateau = plateaued};
    }
    ft_free(&r);
    ft_ones_free(f, k);
    return rc;
}
