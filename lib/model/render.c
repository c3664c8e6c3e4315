/* Rendering a subject (gs_model_render) and the light at another view. */
#define _POSIX_C_SOURCE 200809L
#include <float.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "gazesplat/clock.h"
#include "frame.h"
#include "fit_internal.h"
#include "gazesplat/geom.h"
#include "gazesplat/nn.h"

/* ---- rendering ---- */

static float srgb_byte(float v)
{
    v = v < 0 ? 0 : v > 1 ? 1 : v;
    return floorf(v * 255.0f + 0.5f);
}

/* rgb8 over rows [y0, y1) of the image box b from the float image under
 * the colour transform tf (gain, bias); the first row with a non-finite
 * pixel, or -1. */
static int convert_rows(gs_model_ctx *c, const float tf[6], const int b[4],
                        int y0, int y1)
{
    int S = c->S;
    size_t plane = (size_t)S * S;
    for (int y = y0; y < y1; y++) {
        uint8_t *row = c->rgb8 + (size_t)y * 3 * S;
        for (int k = 0; k < 3; k++) {
            const float *src = c->rgb + k * plane + (size_t)y * S;
            int bad = 0;
            for (int x = b[0]; x < b[2]; x++) {
                float v = tf[k] * src[x] + tf[3 + k];
                bad |= !(fabsf(v) <= FLT_MAX); /* NaN or infinite */
                row[3 * x + k] = (uint8_t)srgb_byte(bad ? 0.0f : v);
            }
            if (bad)
                return y;
        }
    }
    return -1;
}

enum { CONVERT_ROWS = 16, CONVERT_TASKS = 64 }; /* rows per task at least, tasks at most */

typedef struct convert_job {
    gs_model_ctx *c;
    const float *tf;
    const int *b;
    int rows;                /* per task */
    int bad[CONVERT_TASKS];  /* per task: its first bad row, or -1 */
} convert_job;

static void convert_task(void *ctx, int t, int worker)
{
    (void)worker;
    convert_job *j = ctx;
    int y0 = j->b[1] + t * j->rows;
    int y1 = y0 + j->rows < j->b[3] ? y0 + j->rows : j->b[3];
    j->bad[t] = convert_rows(j->c, j->tf, j->b, y0, y1);
}

/* rgb8 over the image box b, rows split over the pool; refuses a
 * non-finite pixel (naming the first such row). */
static int convert_box(gs_model_ctx *c, gs_pool *pool, const float tf[6],
                       const int b[4], gs_error *err)
{
    int h = b[3] - b[1];
    convert_job j = {c, tf, b, (h + CONVERT_TASKS - 1) / CONVERT_TASKS, {0}};
    j.rows = j.rows < CONVERT_ROWS ? CONVERT_ROWS : j.rows;
    int tasks = (h + j.rows - 1) / j.rows;
    gs_pool_for(pool, tasks, convert_task, &j);
    for (int t = 0; t < tasks; t++)
        if (j.bad[t] >= 0)
            return gs_error_set(err, GS_ERR_NONFINITE,
                                "render: non-finite pixel in row %d", j.bad[t]);
    return GS_OK;
}

/* Writes the frame's image with the subject's colour transform; refuses a
 * non-finite pixel. The context keeps its 8-bit image: when the transform
 * is the last one, only what the render changed is converted again. */
static int write_image(gs_model_ctx *c, gs_pool *pool, const gs_subject *s,
                       uint8_t *rgb, size_t stride, gs_error *err)
{
    int S = c->S, all[4] = {0, 0, S, S};
    float tf[6];
    memcpy(tf, s->colour_gain, 3 * sizeof(float));
    memcpy(tf + 3, s->colour_bias, 3 * sizeof(float));
    const int *box = all;
    if (c->rgb8_valid && !memcmp(tf, c->rgb8_tf, sizeof tf))
        box = c->rgb_dirty;
    c->rgb8_valid = 0;
    if (box[0] < box[2] && box[1] < box[3]) {
        int rc = convert_box(c, pool, tf, box, err);
        if (rc)
            return rc;
    }
    c->rgb8_valid = 1;
    memcpy(c->rgb8_tf, tf, sizeof tf);
    memset(c->rgb_dirty, 0, sizeof c->rgb_dirty);
    for (int y = 0; y < S; y++)
        memcpy(rgb + (size_t)y * stride, c->rgb8 + (size_t)y * 3 * S,
               3 * (size_t)S);
    return GS_OK;
}

/* The light part of a code is in the head frame (training labels: the
 * scene's lights turned into the head). The lights stay where they are in
 * the camera when the head turns, so a view at another head pose sees them
 * turned the other way: each colour's direction vector goes from the
 * subject's head frame (R_s) to the view's (R_v), dh' = R_v^T R_s dh; the
 * ambient colour is the same in any frame. */
void gs_model_light_to_view(float *code, int code_dim, const double R_s[9],
                            const double R_v[9])
{
    float *l = code + code_dim - GS_MODEL_LIGHT_DIM;
    for (int c = 0; c < 3; c++) {
        double dh[3] = {l[3 * c], l[3 * c + 1], l[3 * c + 2]}, d[3], o[3];
        gs_geom_mat3_vec(R_s, dh, d);
        gs_geom_mat3_tvec(R_v, d, o);
        for (int k = 0; k < 3; k++)
            l[3 * c + k] = (float)o[k];
    }
}

void gs_model_frame_of(const gs_subject *s, const gs_view *v, gs_frame *fr)
{
    memset(fr, 0, sizeof *fr);
    memcpy(fr->code, s->code, sizeof(float) * (size_t)s->code_dim);
    const double *R = v && v->use_head ? v->head_R : s->head_R;
    const double *t = v && v->use_head ? v->head_t : s->head_t;
    if (v && !v->light_on_head && memcmp(R, s->head_R, sizeof fr->head_R))
        gs_model_light_to_view(fr->code, s->code_dim, s->head_R, R);
    memcpy(fr->head_R, R, sizeof fr->head_R);
    memcpy(fr->head_t, t, sizeof fr->head_t);
    fr->gaze[0] = v ? v->gaze_pitch : s->gaze_pitch;
    fr->gaze[1] = v ? v->gaze_yaw : s->gaze_yaw;
}

int gs_model_render(gs_model_ctx *c, gs_pool *pool, const gs_subject *s,
                    const gs_view *view, uint8_t *rgb, size_t stride,
                    gs_error *err)
{
    if (!c || !s || !view || !rgb)
        return gs_error_set(err, GS_ERR_ARG, "render: NULL argument");
    if (stride < 3 * (size_t)c->S)
        return gs_error_set(err, GS_ERR_ARG, "render: stride %zu < %d",
                            stride, 3 * c->S);
    int rc = gs_model_check_subject(c->m, s, err);
    if (!rc)
        rc = gs_model_check_gaze(view->gaze_pitch, view->gaze_yaw, err);
    if (!rc && view->use_head)
        rc = gs_model_check_pose(view->head_R, view->head_t, err);
    if (rc)
        return rc;
    gs_frame fr;
    gs_model_frame_of(s, view, &fr);
    /* A gaze-only render of a subject the context keeps no render of starts
     * with the subject at its own gaze: the anchor every later gaze of it
     * renders from (frame.h), so that the bytes of a render depend on the
     * model, the subject and the view alone, not on what the context
     * rendered before (one more incremental render, the first time). */
    if (!view->use_head && gs_frame_wants_anchor(c, &fr) &&
        (view->gaze_pitch != s->gaze_pitch || view->gaze_yaw != s->gaze_yaw)) {
        gs_frame own;
        gs_model_frame_of(s, NULL, &own);
        rc = gs_frame_render(c, pool, &own, NULL, err);
        if (rc)
            return rc;
    }
    rc = gs_frame_render(c, pool, &fr, NULL, err);
    if (rc)
        return rc;
    return write_image(c, pool, s, rgb, stride, err);
}
