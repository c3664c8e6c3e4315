/* Placeholder until lib/gaze lands: no estimator in this build. */
#include "eval_estimator.h"

int eval_estimator_load(const char *path, eval_estimator **out, gs_error *err)
{
    (void)path;
    *out = NULL;
    return gs_error_set(err, GS_ERR_UNSUPPORTED,
                        "this build has no gaze estimator (lib/gaze)");
}

void eval_estimator_free(eval_estimator *e)
{
    (void)e;
}

int eval_estimator_predict(eval_estimator *e, gs_pool *pool,
                           const uint8_t *rgb, int w, int h, size_t stride,
                           float out[4], gs_error *err)
{
    (void)e, (void)pool, (void)rgb, (void)w, (void)h, (void)stride, (void)out;
    return gs_error_set(err, GS_ERR_UNSUPPORTED, "no gaze estimator");
}
