/* Shared by the model benchmarks: the model to time and a plain subject. */
#ifndef GS_BENCH_MODEL_H
#define GS_BENCH_MODEL_H

#include <string.h>

#include "gazesplat/geom.h"
#include "gazesplat/model.h"
#include "gazesplat/train.h"

/* The model file at path, or without one a cpu-preset model as initialised
 * (seed 3: render timings do not depend on training). */
static inline int bench_model_open(const char *path, gs_model **m, gs_error *err)
{
    if (path)
        return gs_model_load(path, m, err);
    gs_model_spec spec;
    gs_model_spec_default(&spec);
    return gs_model_new(&spec, 3, m, err);
}

/* A subject with the mean code, looking ahead, head at (pitch, yaw) at the
 * normalized distance, neutral colour. */
static inline void bench_subject(const gs_model_info *info, double pitch, double yaw,
                                 gs_subject *s)
{
    memset(s, 0, sizeof *s);
    s->code_dim = info->code_dim;
    gs_geom_rot_from_pitchyaw(pitch, yaw, 0.0, s->head_R);
    s->head_t[2] = info->distance_mm;
    for (int k = 0; k < 3; k++)
        s->colour_gain[k] = 1.0f;
}
#endif
