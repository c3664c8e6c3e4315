/* The evaluation's gaze and head-pose estimator: lib/gaze's network. */
#include <stdlib.h>

#include "eval_estimator.h"
#include "gazesplat/gaze.h"

struct eval_estimator {
    gs_gaze_net *net;
};

int eval_estimator_load(const char *path, eval_estimator **out, gs_error *err)
{
    *out = calloc(1, sizeof **out);
    if (!*out)
        return gs_error_set(err, GS_ERR_NOMEM, "out of memory");
    int rc = gs_gaze_net_load(path, &(*out)->net, err);
    if (rc) {
        free(*out);
        *out = NULL;
    }
    return rc;
}

void eval_estimator_free(eval_estimator *e)
{
    if (e)
        gs_gaze_net_destroy(e->net);
    free(e);
}

int eval_estimator_predict(eval_estimator *e, gs_pool *pool,
                           const uint8_t *rgb, int w, int h, size_t stride,
                           float out[4], gs_error *err)
{
    return gs_gaze_net_predict(e->net, pool, rgb, w, h, stride, out, err);
}
