/* lib/eval internals shared by its files. */
#ifndef GS_EVAL_INTERNAL_H
#define GS_EVAL_INTERNAL_H

#include "gazesplat/eval.h"

/* The normalized camera a scene is rendered through by
 * gs_eval_render_scene (labels of the same view without rendering). */
int gs_eval_scene_camera(const gs_synth_scene *scene, int size, double d_n_mm,
                         double f_n, gs_synth_camera *cam, gs_error *err);

#endif
