/* The live stage's engine on the real model (model.h public API only): fit
 * the subject on a normalized frame with the landmarks' head pose kept
 * fixed, render at the fitted head pose so that consecutive renders of the
 * subject differ only in gaze (the model reuses its face stream). */
#include <stdlib.h>
#include <string.h>

#include "gazesplat/live.h"
#include "gazesplat/redirect.h"

typedef struct engine_ctx {
    const gs_model *model;
    gs_model_info info;
    gs_model_ctx *mctx;
    gs_pool *pool;
    double budget_s;
} engine_ctx;

static int normalize(const engine_ctx *e, const gs_live_track_state *st, const double k[9],
                     gs_geom_norm *n, gs_error *err)
{
    int size = e->info.image_size;
    return gs_geom_normalize(k, st->pose.t, st->pose.R, e->info.distance_mm, e->info.focal,
                             size, size, n, err);
}

static int engine_fit(void *ctx, const gs_io_image *frame, const gs_live_track_state *st,
                      const double k[9], gs_live_subject *out, gs_error *err)
{
    engine_ctx *e = ctx;
    int size = e->info.image_size;
    gs_geom_norm n;
    int r = normalize(e, st, k, &n, err);
    if (r != GS_OK)
        return r;
    double uv_n[GS_FACE_LANDMARKS][2];
    for (int i = 0; i < GS_FACE_LANDMARKS; i++)
        gs_geom_norm_pixel(&n, st->uv[i], uv_n[i]);
    gs_io_image face = {0, 0, 0, NULL};
    uint8_t *mask = malloc((size_t)size * (size_t)size);
    if (!mask)
        return gs_error_set(err, GS_ERR_NOMEM, "live fit: out of memory");
    r = gs_face_normalize_image(frame, &n, &face, err);
    if (r == GS_OK)
        r = gs_redirect_face_mask((const double(*)[2])uv_n, size, mask, err);
    if (r == GS_OK) {
        /* The tracker's landmarks and pose in place of a photo's analysis;
         * the mask, the pose and the defaults every path fits with. */
        gs_fit_options o;
        gs_fit_options_default(&o);
        gs_redirect_fit_pose(&n, st->pose.R, &o);
        o.mask = mask;
        o.time_budget_s = e->budget_s;
        gs_fit_report rep;
        r = gs_model_fit(e->mctx, e->pool, face.data, face.stride, &o, &out->subject, &rep, err);
    }
    if (r == GS_OK) {
        static const int idx[4] = {36, 39, 42, 45};
        for (int i = 0; i < 4; i++)
            memcpy(out->corners_n[i], uv_n[idx[i]], sizeof out->corners_n[i]);
    }
    gs_io_image_free(&face);
    free(mask);
    return r;
}

static int engine_render(void *ctx, const gs_live_subject *s, double pitch, double yaw,
                         uint8_t *rgb, gs_error *err)
{
    engine_ctx *e = ctx;
    gs_view v;
    memset(&v, 0, sizeof v);
    v.gaze_pitch = pitch;
    v.gaze_yaw = yaw;
    return gs_redirect_render(e->mctx, e->pool, &s->subject, NULL, 0, NULL, &v, rgb,
                              3 * (size_t)e->info.image_size, err);
}

int gs_live_engine_model(const gs_model *m, gs_pool *pool, double fit_budget_s,
                         gs_live_engine *out, gs_error *err)
{
    if (!m || !out)
        return gs_error_set(err, GS_ERR_ARG, "live engine: NULL argument");
    engine_ctx *e = calloc(1, sizeof *e);
    if (!e)
        return gs_error_set(err, GS_ERR_NOMEM, "live engine: out of memory");
    e->model = m;
    gs_model_get_info(m, &e->info);
    e->mctx = gs_model_ctx_create(m);
    e->pool = pool;
    e->budget_s = fit_budget_s > 0 ? fit_budget_s : 30.0;
    if (!e->mctx) {
        free(e);
        return gs_error_set(err, GS_ERR_NOMEM, "live engine: model context");
    }
    out->ctx = e;
    out->image_size = e->info.image_size;
    out->fit = engine_fit;
    out->render = engine_render;
    return GS_OK;
}

void gs_live_engine_model_free(gs_live_engine *eng)
{
    if (!eng || !eng->ctx)
        return;
    engine_ctx *e = eng->ctx;
    gs_model_ctx_destroy(e->mctx);
    free(e);
    eng->ctx = NULL;
}
