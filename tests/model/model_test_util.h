/* Shared helpers of the model tests: a tiny model built in milliseconds. */
#ifndef GS_MODEL_TEST_UTIL_H
#define GS_MODEL_TEST_UTIL_H

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "../../lib/model/frame.h"
#include "gazesplat/geom.h"
#include "gazesplat/synth.h"
#include "gazesplat/train.h"

/* A small model: coarse template, few eye Gaussians, narrow MLPs, 16^2
 * features -> 64^2 images. */
static inline void tiny_config(gs_model_config *cfg)
{
    gs_model_config_default(cfg);
    cfg->template_spacing_mm = 6.0;
    cfg->n_eye_each = 40;
    cfg->feat_dim = 8;
    cfg->id_dim = 4;
    cfg->hidden = 16;
    cfg->channels = 8;
    cfg->feat_size = 32;
    cfg->image_size = 128;
    cfg->focal = 1600.0 * 128 / 512;
    cfg->n_train_ids = 3;
}

static inline gs_model *tiny_model(int guidance, uint64_t seed)
{
    gs_model_config cfg;
    tiny_config(&cfg);
    cfg.guidance = guidance;
    gs_model *m = NULL;
    gs_error err;
    if (gs_model_create(&cfg, seed, &m, &err) != GS_OK) {
        fprintf(stderr, "tiny_model: %s\n", err.msg);
        return NULL;
    }
    return m;
}

/* m with lids (gs_model_add_lids, the default radius), the knots of the
 * lids' share of the pitch set to a spread of values in [-0.6, 1.2] so
 * that they move; m is consumed. NULL on failure. */
static inline gs_model *with_lids(gs_model *m)
{
    gs_model *l = NULL;
    gs_error err;
    if (!m || gs_model_add_lids(m, GS_MODEL_LID_RADIUS_MM, &l, &err) != GS_OK) {
        fprintf(stderr, "with_lids: %s\n", m ? err.msg : "no model");
        gs_model_destroy(m);
        return NULL;
    }
    gs_model_destroy(m);
    for (int j = 0; j < 2 * GS_LID_NU * GS_LID_NV; j++)
        l->p.lid_k[j] = -0.6f + 1.8f * (float)((j * 37) % 17) / 16.0f;
    return l;
}

static inline void frame_default(const gs_model *m, gs_frame *fr)
{
    memset(fr, 0, sizeof *fr);
    gs_geom_rot_from_pitchyaw(0.1, -0.2, 0.05, fr->head_R);
    fr->head_t[2] = m->cfg.d_n_mm;
    fr->gaze[0] = 0.15;
    fr->gaze[1] = -0.25;
    for (int k = 0; k < gs_model_code_dim(&m->cfg); k++)
        fr->code[k] = 0.1f * (float)((k * 7) % 5 - 2);
}
/* The subject of frame_default's code and head pose, gain 1, bias 0. */
static inline gs_subject frame_subject(const gs_model *m)
{
    gs_frame fr;
    frame_default(m, &fr);
    gs_subject s;
    memset(&s, 0, sizeof s);
    s.code_dim = gs_model_code_dim(&m->cfg);
    memcpy(s.code, fr.code, sizeof(float) * (size_t)s.code_dim);
    memcpy(s.head_R, fr.head_R, sizeof s.head_R);
    memcpy(s.head_t, fr.head_t, sizeof s.head_t);
    for (int k = 0; k < 3; k++)
        s.colour_gain[k] = 1.0f;
    return s;
}

/* How far c's last map (c->fmap, and c->alpha unless NULL) is from the
 * k x k means of the same Gaussians rasterized at k times the size
 * through the view at head_t: the largest differences into *map and
 * *alpha. -1 when the reference raster fails. */
static inline int supersample_error(gs_model_ctx *c, const double head_t[3],
                                    int k, double *map, double *alpha)
{
    int fs = c->fs, C = c->C, hs = k * fs;
    size_t hp = (size_t)hs * hs;
    float *hi = malloc(sizeof(float) * ((size_t)C + 1) * hp);
    float *bg = malloc(sizeof(float) * (size_t)C * hp);
    if (!hi || !bg) {
        free(hi);
        free(bg);
        return -1;
    }
    for (int ch = 0; ch < C; ch++)
        for (size_t i = 0; i < hp; i++)
            bg[ch * hp + i] = c->bg[(size_t)ch * fs * fs];
    gs_camera cam;
    gs_frame_camera(c->m, head_t, &cam);
    cam.fx *= (float)k, cam.fy *= (float)k;
    cam.cx *= (float)k, cam.cy *= (float)k;
    cam.width = cam.height = hs;
    gs_gaussians g = {.n = c->n, .channels = C, .means = c->g_mean,
                      .log_scales = c->g_scale, .quats = c->g_quat,
                      .opacity_logits = c->g_opac, .features = c->g_feat};
    gs_raster_options ro = {.antialiased = 0, .path = GS_RASTER_FAST};
    gs_raster *r = gs_raster_create();
    gs_error err;
    int rc = r && gs_raster_forward(r, NULL, &cam, &g, bg, &ro, hi, hi + C * hp,
                                    NULL, &err) == GS_OK
                 ? 0
                 : -1;
    *map = *alpha = 0;
    for (int ch = 0; !rc && ch <= C; ch++) /* channel C: alpha */
        for (int y = 0; y < fs; y++)
            for (int x = 0; x < fs; x++) {
                double want = 0;
                for (int dy = 0; dy < k; dy++)
                    for (int dx = 0; dx < k; dx++)
                        want += hi[ch * hp + (size_t)(k * y + dy) * hs +
                                   k * x + dx];
                want /= k * k;
                size_t at = (size_t)y * fs + x;
                if (ch < C)
                    *map = fmax(*map, fabs(c->fmap[(size_t)ch * fs * fs + at] -
                                           want));
                else if (c->alpha)
                    *alpha = fmax(*alpha, fabs(c->alpha[at] - want));
            }
    gs_raster_destroy(r);
    free(hi);
    free(bg);
    return rc;
}

/* The tiny preset (2 training identities, seed 5) trained for `steps`
 * steps; checkpoints go to path and path.opt. NULL on failure (err). */
static inline gs_model *trained_tiny(const char *path, int steps,
                                     gs_train_report *rep, gs_error *err)
{
    gs_model_spec spec;
    gs_model_spec_default(&spec);
    spec.preset = "tiny";
    spec.train_identities = 2;
    gs_model *m = NULL;
    if (gs_model_new(&spec, 5, &m, err) != GS_OK)
        return NULL;
    gs_train_options to;
    gs_train_options_default(&to);
    to.out_path = path;
    to.steps = steps;
    to.checkpoint_every = 0;
    if (gs_train(m, &to, NULL, rep, err) != GS_OK) {
        gs_model_destroy(m);
        return NULL;
    }
    return m;
}

/* The checkpoint file a test trains its tiny model into: NAME_PID.safetensors
 * in the working directory (path: 128 bytes). */
static inline void tiny_path(char path[128], const char *name)
{
    snprintf(path, 128, "%s_%d.safetensors", name, (int)getpid());
}

/* Removes what trained_tiny wrote: path and path.opt. */
static inline void tiny_remove(const char *path)
{
    char opt[160];
    unlink(path);
    snprintf(opt, sizeof opt, "%s.opt", path);
    unlink(opt);
}

/* Sample `index` of the held-out identities: a normalized S x S face with
 * its labels (smp allocated here). */
static inline int held_out_face(int S, uint64_t index, gs_synth_sample *smp,
                                gs_error *err)
{
    gs_synth_gen_config g;
    gs_synth_gen_config_default(&g);
    g.split = GS_SYNTH_TEST;
    g.size = S;
    g.rig = GS_SYNTH_RIG_NORMALIZED;
    int rc = gs_synth_sample_alloc(smp, S, S, err);
    return rc ? rc : gs_synth_gen_sample(&g, index, NULL, smp, err);
}

/* held_out_face, then a fit of it (iters iterations, its true head pose)
 * through c into *sub. */
static inline int fit_held_out(gs_model_ctx *c, int S, uint64_t index, int iters,
                               gs_synth_sample *smp, gs_subject *sub, gs_error *err)
{
    int rc = held_out_face(S, index, smp, err);
    if (rc)
        return rc;
    gs_fit_options fo;
    gs_fit_options_default(&fo);
    fo.max_iters = iters;
    fo.known_head = 1;
    memcpy(fo.head_R, smp->labels.head_R, sizeof fo.head_R);
    memcpy(fo.head_t, smp->labels.head_t, sizeof fo.head_t);
    return gs_model_fit(c, NULL, smp->rgb, smp->stride, &fo, sub, NULL, err);
}
#endif
