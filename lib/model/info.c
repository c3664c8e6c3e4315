/* A model's description (gs_model_get_info), the settings a model file
 * carries for serving (supersampling, the eye renderer, the fit's code
 * prior and rate, the guidance source) and writing it out. */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "model_internal.h"

void gs_model_get_info(const gs_model *m, gs_model_info *info)
{
    memset(info, 0, sizeof *info);
    info->image_size = m->cfg.image_size;
    info->feat_size = m->cfg.feat_size;
    info->supersample = m->cfg.supersample;
    info->eye_direct = m->cfg.eye_direct;
    info->code_dim = gs_model_code_dim(&m->cfg);
    info->n_train_ids = m->p.codes ? m->cfg.n_train_ids : 0;
    info->n_face = m->cfg.n_face;
    info->n_eye = m->cfg.two_stream ? 2 * m->cfg.n_eye_each : 0;
    info->focal = m->cfg.focal;
    info->distance_mm = m->cfg.d_n_mm;
    info->param_bytes = m->nparams * sizeof(float);
    info->param_id = m->id;
    info->tuned_parts = m->tuned;
    info->fit_code_prior = m->cfg.fit_code_prior;
    info->fit_code_rate = m->cfg.fit_code_rate;
}

int gs_model_set_supersample(gs_model *m, int k, gs_error *err)
{
    if (!m || k < 1 || k > 4)
        return gs_error_set(err, GS_ERR_ARG, "supersample %d: want 1..4", k);
    m->cfg.supersample = k;
    return GS_OK;
}

int gs_model_set_eye_direct(gs_model *m, int on, gs_error *err)
{
    if (!m || (on != 0 && on != 1))
        return gs_error_set(err, GS_ERR_ARG, "eye direct %d: want 0 or 1", on);
    if (on && !m->cfg.two_stream)
        return gs_error_set(err, GS_ERR_ARG,
                            "eye direct: the model has no eye stream "
                            "(single-stream ablation)");
    m->cfg.eye_direct = on;
    return GS_OK;
}

int gs_model_set_fit_code_prior(gs_model *m, double weight, gs_error *err)
{
    if (!m || !gs_code_prior_weight_ok(weight))
        return gs_error_set(err, GS_ERR_ARG,
                            "fit code prior %g: want [0, 10], 0 for none",
                            weight);
    m->cfg.fit_code_prior = weight;
    return GS_OK;
}

int gs_model_set_fit_code_rate(gs_model *m, double rate, gs_error *err)
{
    if (!m || !gs_code_rate_ok(rate))
        return gs_error_set(err, GS_ERR_ARG,
                            "fit code rate %g: want [0, 10], 0 for the "
                            "default", rate);
    m->cfg.fit_code_rate = rate;
    return GS_OK;
}

double gs_model_fit_code_rate(const gs_model *m, double lr_code)
{
    return lr_code > 0 ? lr_code
           : m->cfg.fit_code_rate > 0 ? m->cfg.fit_code_rate
                                      : GS_FIT_LR_CODE_DEFAULT;
}

int gs_model_set_guide_source(gs_model *m, int source, gs_error *err)
{
    if (!m || (source != GS_GUIDE_SRC_BLOCK && source != GS_GUIDE_SRC_SOURCE))
        return gs_error_set(err, GS_ERR_ARG, "guide source %d: 0 or 1", source);
    m->cfg.guide_source = source;
    m->rcfg.guide_source = source;
    return GS_OK;
}

int gs_model_write(const gs_model *m, const char *path, gs_error *err)
{
    return gs_model_save(m, path, err);
}
