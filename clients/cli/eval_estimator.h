/* gazesplat eval: the gaze and head-pose estimator behind one small
 * interface (lib/gaze when the build has it). */
#ifndef GS_CLI_EVAL_ESTIMATOR_H
#define GS_CLI_EVAL_ESTIMATOR_H

#include <stddef.h>
#include <stdint.h>

#include "gazesplat/error.h"
#include "gazesplat/pool.h"

typedef struct eval_estimator eval_estimator;

int eval_estimator_load(const char *path, eval_estimator **out, gs_error *err);
void eval_estimator_free(eval_estimator *e);
/* out = gaze pitch, gaze yaw, head pitch, head yaw (radians, normalized
 * camera) of a normalized face image. */
int eval_estimator_predict(eval_estimator *e, gs_pool *pool,
                           const uint8_t *rgb, int w, int h, size_t stride,
                           float out[4], gs_error *err);

#endif
