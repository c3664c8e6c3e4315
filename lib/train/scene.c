/* The training sampler's scenes and the codes they stand for: how a sample
 * is drawn (gs_train_sample_config, the options' defaults, the head range),
 * a scene's light and full code (gs_model_light_code, gs_model_scene_code)
 * and a training identity's subject. Training, the code prior's
 * computation (prior.c) and the evaluation read these; a program that
 * only fits and renders never does. */
#define _POSIX_C_SOURCE 200809L
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "../model/frame.h"
#include "gazesplat/synth.h"
#include "gazesplat/train.h"

void gs_train_sample_config(const gs_model *m, const gs_train_options *o,
                            gs_synth_gen_config *gen)
{
    gs_synth_gen_config_default(gen);
    gen->split = GS_SYNTH_TRAIN;
    gen->identities = (uint64_t)m->cfg.n_train_ids;
    gen->seed = o->seed;
    gen->size = m->cfg.image_size;
    gen->rig = GS_SYNTH_RIG_NORMALIZED;
    gen->supersample = 1;
    /* The model's documented range, a little inside the generator's,
     * unless the caller widens or narrows the head's. */
    gen->ranges.head_yaw =
        (o->head_yaw_deg > 0 ? o->head_yaw_deg : 40.0) * GS_MODEL_PI / 180;
    gen->ranges.head_pitch =
        (o->head_pitch_deg > 0 ? o->head_pitch_deg : 25.0) * GS_MODEL_PI / 180;
    gen->ranges.head_roll = 5.0 * GS_MODEL_PI / 180;
    gen->ranges.gaze_yaw = 40.0 * GS_MODEL_PI / 180;
    gen->ranges.gaze_pitch = 30.0 * GS_MODEL_PI / 180;
}

int gs_train_check_head_range(double yaw_deg, double pitch_deg, gs_error *err)
{
    if (!(yaw_deg == 0 || (yaw_deg >= 1 && yaw_deg <= GS_TRAIN_HEAD_YAW_MAX)) ||
        !(pitch_deg == 0 || (pitch_deg >= 1 && pitch_deg <= GS_TRAIN_HEAD_PITCH_MAX)))
        return gs_error_set(err, GS_ERR_ARG,
                            "train: head range yaw %g, pitch %g deg not within "
                            "1..%g and 1..%g",
                            yaw_deg, pitch_deg, GS_TRAIN_HEAD_YAW_MAX,
                            GS_TRAIN_HEAD_PITCH_MAX);
    return GS_OK;
}

void gs_train_options_default(gs_train_options *o)
{
    memset(o, 0, sizeof *o);
    o->steps = 2000;
    o->lr = 1e-3;
    o->seed = 1;
    o->checkpoint_every = 500;
    o->log_every = 50;
    o->gaze_weight = 0.1;
    o->fresh_from_step = -1;
    o->warmup = 200;
}

/* The 12 light values of a scene in its head frame: sum over lights of
 * rgb x direction (9) and the ambient colour (3). */
void gs_model_light_code(const gs_synth_scene *s, float out[12])
{
    memset(out, 0, 12 * sizeof(float));
    for (int l = 0; l < s->n_lights; l++) {
        double d[3], dh[3];
        for (int k = 0; k < 3; k++)
            d[k] = s->light[l].dir[k];
        gs_geom_mat3_tvec(s->head_R, d, dh);
        for (int c = 0; c < 3; c++)
            for (int k = 0; k < 3; k++)
                out[3 * c + k] += (float)(s->light[l].rgb[c] * dh[k]);
    }
    for (int c = 0; c < 3; c++)
        out[9 + c] = s->ambient[c];
}

int gs_model_training_subject(const gs_model *m, int k,
                              const gs_synth_scene *scene,
                              const gs_synth_labels *labels, gs_subject *s,
                              gs_error *err)
{
    if (!m || !scene || !labels || !s)
        return gs_error_set(err, GS_ERR_ARG, "training subject: NULL argument");
    const gs_model_config *mc = &m->cfg;
    if (!m->p.codes || mc->n_train_ids < 1)
        return gs_error_set(err, GS_ERR_ARG,
                            "training subject: the model has no training codes");
    if (k < 0 || k >= mc->n_train_ids)
        return gs_error_set(err, GS_ERR_ARG,
                            "training subject: identity %d of %d", k,
                            mc->n_train_ids);
    if (labels->identity.seed != gs_synth_split_seed(GS_SYNTH_TRAIN, (uint64_t)k))
        return gs_error_set(err, GS_ERR_ARG,
                            "training subject: the labels are not of training "
                            "identity %d", k);
    memset(s, 0, sizeof *s);
    s->code_dim = gs_model_code_dim(mc);
    memcpy(s->code, m->p.codes + (size_t)k * mc->id_dim,
           mc->id_dim * sizeof(float));
    gs_synth_expression_to_array(&labels->expr, s->code + mc->id_dim);
    gs_model_light_code(scene, s->code + mc->id_dim + GS_MODEL_EXPR_DIM);
    memcpy(s->head_R, labels->head_R, sizeof s->head_R);
    memcpy(s->head_t, labels->head_t, sizeof s->head_t);
    s->gaze_pitch = labels->gaze_head_pitch;
    s->gaze_yaw = labels->gaze_head_yaw;
    for (int c = 0; c < 3; c++)
        s->colour_gain[c] = 1.0f;
    return GS_OK;
}

int gs_model_scene_code(const gs_model *m, const gs_synth_scene *scene,
                        unsigned parts, float *code, uint8_t *fixed,
                        gs_error *err)
{
    if (!m || !scene || !code || !fixed)
        return gs_error_set(err, GS_ERR_ARG, "scene code: NULL argument");
    const unsigned all = GS_SCENE_CODE_EXPR | GS_SCENE_CODE_LIGHT | GS_SCENE_CODE_ID;
    if (parts == 0 || (parts & ~all))
        return gs_error_set(err, GS_ERR_ARG,
                            "scene code: parts 0x%x (want a combination of "
                            "expression 0x1, lights 0x2, identity 0x4)", parts);
    const gs_model_config *mc = &m->cfg;
    int k = -1; /* the training identity of the scene, for GS_SCENE_CODE_ID */
    for (int i = 0; (parts & GS_SCENE_CODE_ID) && m->p.codes && i < mc->n_train_ids; i++)
        if (scene->identity.seed == gs_synth_split_seed(GS_SYNTH_TRAIN, (uint64_t)i)) {
            k = i;
            break;
        }
    if ((parts & GS_SCENE_CODE_ID) && k < 0)
        return gs_error_set(err, GS_ERR_ARG,
                            "scene code: the scene's identity is not one of the "
                            "model's %d training identities",
                            m->p.codes ? mc->n_train_ids : 0);
    int D = gs_model_code_dim(mc);
    memcpy(code, m->p.code_mean, (size_t)D * sizeof(float));
    memset(fixed, 0, (size_t)D);
    if (k >= 0) {
        memcpy(code, m->p.codes + (size_t)k * mc->id_dim,
               (size_t)mc->id_dim * sizeof(float));
        memset(fixed, 1, (size_t)mc->id_dim);
    }
    if (parts & GS_SCENE_CODE_EXPR) {
        gs_synth_expression_to_array(&scene->expr, code + mc->id_dim);
        memset(fixed + mc->id_dim, 1, GS_MODEL_EXPR_DIM);
    }
    if (parts & GS_SCENE_CODE_LIGHT) {
        gs_model_light_code(scene, code + mc->id_dim + GS_MODEL_EXPR_DIM);
        memset(fixed + mc->id_dim + GS_MODEL_EXPR_DIM, 1, GS_MODEL_LIGHT_DIM);
    }
    return GS_OK;
}

