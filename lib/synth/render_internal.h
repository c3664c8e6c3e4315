/* Renderer state shared by render.c and sample.c. */
#ifndef GS_SYNTH_RENDER_INTERNAL_H
#define GS_SYNTH_RENDER_INTERNAL_H

#include "synth_internal.h"

#define SRGB_LUT 4096

typedef struct render_ctx {
    head_model head;
    v3 o;             /* camera centre, head frame */
    float A[9];       /* head-frame direction of pixel (u, v) = A (u, v, 1) */
    float px_angle;   /* ~ angular size of a pixel, radians */
    int nl;
    v3 ldir[2], lrgb[2]; /* toward the lights, head frame */
    v3 ambient, bg_top, bg_bottom;
    int specular;
    int width, height, ss;
    int rx0, ry0, rx1, ry1; /* tiles meeting this box are rendered */
    uint8_t lut[SRGB_LUT]; /* linear [0, 1] -> sRGB 8 bit */
    gs_synth_sample *out;
} render_ctx;

/* Fills everything but `head` and `out`. */
void gs_synth_render_setup(render_ctx *r, const gs_synth_scene *s,
                           const gs_synth_camera *cam, int ss);
void gs_synth_render_pixels(render_ctx *r, gs_pool *pool);

/* Labels of a scene seen by a camera, for an already built head. */
void gs_synth_labels_from_head(const gs_synth_scene *s,
                               const gs_synth_camera *cam,
                               const head_model *h, gs_synth_labels *l);

#endif
