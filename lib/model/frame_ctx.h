/* The frame context's buffers (frame_ctx.c). */
#ifndef GS_MODEL_FRAME_CTX_H
#define GS_MODEL_FRAME_CTX_H

#include "frame_state.h"

/* Makes c's buffers for model m: GS_OK or GS_ERR_NOMEM. */
int gs_frame_ctx_init(gs_model_ctx *c, const gs_model *m);

/* The fit's and training's buffers (rows kept for a backward):
 * GS_OK or GS_ERR_NOMEM. */
int gs_ctx_train_alloc(gs_model_ctx *c);
/* The renderer's buffer of a forward: the training one when the context
 * has it (it also serves renders), else the scratch's forward-only one. */
int gs_ctx_render_acts(gs_model_ctx *c, float **acts, size_t *len);
/* A render's face stream: each pool thread's floats of scratch for one
 * block's MLP inputs and activations, and that scratch for `threads`. */
size_t gs_ctx_face_scratch_each(const gs_model_ctx *c);
int gs_ctx_face_scratch(gs_model_ctx *c, int threads);

/* Until called again with NULL, gs_frame_backward gives the Gaussians'
 * features (colours: feat[k]) only the gradient of the feature-map pixels
 * where mask [fs, fs] (kept by the caller) is 1; their positions, scales,
 * rotations and opacities still take the whole map's. Costs one more
 * rasterizer backward. GS_ERR_NOMEM when its scratch cannot be had. */
int gs_frame_set_feature_mask(gs_model_ctx *c, const float *mask,
                              gs_error *err);

#endif
