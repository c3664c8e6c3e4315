/* A whole-frame gradient check shared by the model tests whose option
 * changes the frame's forward (supersampled maps, the eye at the image's
 * size): a fixed random linear function of the image, the merged map and
 * the face-only map (every path a loss takes), its gradient from
 * gs_frame_backward against central differences of the code (which moves,
 * scales and colours every Gaussian through the MLPs) and of sparse
 * directions in the colour, latent-feature and opacity tensors.
 *
 * Not the gaze: a turn of the eyes moves few Gaussians, and the jumps of
 * the rasterizer's cut-offs (alpha 1/255, 3 sigma) outweigh its small
 * smooth part in any difference step (test_model_streams checks it to the
 * Gaussians, tests/raster from there); sparse directions in the eye
 * positions or scales fail for the same reason. Not the head's
 * translation: the camera's focal follows |t|, which the backward leaves
 * out, so along the optical axis the image hardly moves while the
 * gradient says it does. */
#ifndef GS_FRAME_GRADCHECK_H
#define GS_FRAME_GRADCHECK_H

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "gs_test.h"
#include "model_test_util.h"

/* A tiny model of cfg (additive guidance from the face stream's map
 * recommended: every renderer path) with live guidance weights, or NULL
 * (printed). */
static gs_model *fg_model(const gs_model_config *cfg, uint64_t seed)
{
    gs_model *m = NULL;
    gs_error err;
    if (gs_model_create(cfg, seed, &m, &err) != GS_OK) {
        fprintf(stderr, "fg_model: %s\n", err.msg);
        return NULL;
    }
    for (int i = 0; i < cfg->channels * cfg->channels; i++)
        m->p.rend.value_w[i] = 0.02f * (float)((i * 7) % 11 - 5);
    return m;
}

typedef struct fg_objective {
    gs_model_ctx *c;
    float *w_rgb, *w_map, *w_face;
    size_t n_rgb, n_map;
} fg_objective;

static double fg_value(fg_objective *o, const gs_frame *fr)
{
    gs_error err = {0, ""};
    if (gs_frame_forward(o->c, NULL, fr, GS_STREAM_BOTH, 1, &err) != GS_OK)
        return NAN;
    double s = 0;
    for (size_t i = 0; i < o->n_rgb; i++)
        s += (double)o->w_rgb[i] * o->c->rgb[i];
    for (size_t i = 0; i < o->n_map; i++)
        s += (double)o->w_map[i] * o->c->fmap[i] +
             (double)o->w_face[i] * o->c->fmap_face[i];
    return s;
}

static float *fg_rand_weights(size_t n, unsigned *r)
{
    float *w = malloc(n * sizeof *w);
    for (size_t i = 0; i < n; i++) {
        *r = *r * 1103515245u + 12345u;
        w[i] = ((*r >> 8) & 0xffff) / 65536.0f - 0.5f;
    }
    return w;
}

/* Checks m's frame gradients as above; tag names the case in the output
 * and opacity_step is the difference step of the opacity logits (a wider
 * step averages over the cut-offs' jumps where a finer raster meets more
 * of them). Colours, linear in the map, are held to 0.5 % relative;
 * everything else to 3 %. Returns the mismatches (printed). */
static int frame_gradcheck(gs_model *m, const char *tag, double opacity_step)
{
    fg_objective o;
    o.c = gs_model_ctx_create(m);
    o.c->face_loss = 1; /* the face-only map takes its own gradient */
    int S = m->cfg.image_size, fs = o.c->fs;
    o.n_rgb = 3 * (size_t)S * S;
    o.n_map = (size_t)o.c->C * fs * fs;
    unsigned r = 4242;
    o.w_rgb = fg_rand_weights(o.n_rgb, &r);
    o.w_map = fg_rand_weights(o.n_map, &r);
    o.w_face = fg_rand_weights(o.n_map, &r);
    gs_frame fr;
    frame_default(m, &fr);
    double v0 = fg_value(&o, &fr);
    CHECK(isfinite(v0));
    float *grad = calloc(m->nparams, sizeof(float));
    gs_model_params g;
    gs_model_bind(m, grad, &g);
    gs_frame_grad fg;
    memset(&fg, 0, sizeof fg);
    gs_error err = {0, ""};
    CHECK(o.c->used_face_map);
    CHECK(gs_frame_backward(o.c, NULL, o.w_rgb, o.w_map, o.w_face, NULL, &g,
                            &fg, &err) == GS_OK);
    int bad = 0, n = 0;
    double worst = 0;
#define FG_COMPARE(what, ana, num, rel, abs_)                                 \
    do {                                                                      \
        double a_ = (ana), n_ = (num), e_ = fabs(a_ - n_);                    \
        double t_ = (rel) * fmax(fabs(a_), fabs(n_)) + (abs_);                \
        n++;                                                                  \
        worst = fmax(worst, e_ / t_);                                         \
        if (getenv("GS_VERBOSE"))                                             \
            printf("  %s %-28s analytic %+.5e numeric %+.5e\n", tag, what,    \
                   a_, n_);                                                   \
        if (e_ > t_ || !isfinite(n_)) {                                       \
            bad++;                                                            \
            printf("  %s MISMATCH %-28s analytic %+.5e numeric %+.5e\n", tag, \
                   what, a_, n_);                                             \
        }                                                                     \
    } while (0)
    char name[96];
    for (int i = 0; i < gs_model_code_dim(&m->cfg); i++) {
        gs_frame f2 = fr;
        float h = 2e-2f;
        f2.code[i] = fr.code[i] + h;
        double up = fg_value(&o, &f2);
        f2.code[i] = fr.code[i] - h;
        double dn = fg_value(&o, &f2);
        double hh = (double)(fr.code[i] + h) - (double)(fr.code[i] - h);
        snprintf(name, sizeof name, "code[%d]", i);
        FG_COMPARE(name, fg.code[i], (up - dn) / hh, 0.03, 1e-3);
    }
    for (int ti = 0; ti < m->ntensors; ti++) {
        const gs_ptensor *t = &m->t[ti];
        int opac = strstr(t->name, "opacity") != NULL;
        if (!strstr(t->name, "colour") && !strstr(t->name, ".feat") && !opac)
            continue;
        float *save = malloc(t->count * sizeof(float));
        memcpy(save, m->params + t->offset, t->count * sizeof(float));
        for (int rep = 0; rep < 3; rep++) {
            float *dir = calloc(t->count, sizeof(float));
            for (int j = 0; j < 16; j++) {
                r = r * 1103515245u + 12345u;
                dir[(r >> 4) % t->count] = ((r >> 16) & 1) ? 1.0f : -1.0f;
            }
            double ana = 0, h = opac ? opacity_step : 2e-2, fx[2];
            for (size_t i = 0; i < t->count; i++)
                ana += (double)dir[i] * grad[t->offset + i];
            for (int sgn = 0; sgn < 2; sgn++) {
                for (size_t i = 0; i < t->count; i++)
                    m->params[t->offset + i] =
                        save[i] + (float)((sgn ? -h : h) * dir[i]);
                fx[sgn] = fg_value(&o, &fr);
            }
            memcpy(m->params + t->offset, save, t->count * sizeof(float));
            snprintf(name, sizeof name, "%s #%d", t->name, rep);
            if (strstr(t->name, "colour"))
                FG_COMPARE(name, ana, (fx[0] - fx[1]) / (2 * h), 5e-3, 2e-5);
            else
                FG_COMPARE(name, ana, (fx[0] - fx[1]) / (2 * h), 0.03, 1.5e-3);
            free(dir);
        }
        free(save);
    }
#undef FG_COMPARE
    printf("%s: %d gradients, %d mismatches, worst error %.2f of the "
           "tolerance\n", tag, n, bad, worst);
    free(grad);
    free(o.w_rgb);
    free(o.w_map);
    free(o.w_face);
    gs_model_ctx_destroy(o.c);
    return bad;
}

#endif
