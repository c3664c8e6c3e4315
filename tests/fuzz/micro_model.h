/* The smallest valid model (2 face Gaussians, 1 per eye, 1-dimensional
 * codes and features, 8^2 features -> 32^2 images), every parameter 0.25:
 * the model loader's fuzz seed and the base model of the tuned-block
 * target. Built with lib/model's internal layout. */
#ifndef GS_FUZZ_MICRO_MODEL_H
#define GS_FUZZ_MICRO_MODEL_H

#include <stdlib.h>

#include "../../lib/model/model_internal.h"

static inline int micro_model(gs_model *m, gs_error *err)
{
    gs_model_config c;
    gs_model_config_default(&c);
    c.n_face = 2;
    c.n_eye_each = 1;
    c.feat_dim = 1;
    c.id_dim = 1;
    c.hidden = 2;
    c.channels = 3;
    c.feat_size = 8;
    c.image_size = 32;
    c.n_train_ids = 1;
    int rc = gs_model_layout(&c, m, err);
    if (rc)
        return rc;
    m->params = calloc(m->nparams, sizeof(float));
    if (!m->params)
        return gs_error_set(err, GS_ERR_NOMEM, "micro model: out of memory");
    gs_model_bind(m, m->params, &m->p);
    for (int i = 0; i < m->ntensors; i++) /* the padding stays zero */
        for (size_t k = 0; k < m->t[i].count; k++)
            m->params[m->t[i].offset + k] = 0.25f;
    m->id = gs_model_param_id(m);
    return GS_OK;
}

#endif
