/* Public entry points: sample buffers, rendering, labels, cameras. */
#include <stdlib.h>
#include <string.h>

#include "render_internal.h"

#define MAX_SIZE 8192

int gs_synth_sample_alloc(gs_synth_sample *s, int width, int height,
                          gs_error *err)
{
    memset(s, 0, sizeof *s);
    if (width < 1 || height < 1 || width > MAX_SIZE || height > MAX_SIZE)
        return gs_error_set(err, GS_ERR_ARG,
                            "synth: image size %dx%d outside 1..%d", width,
                            height, MAX_SIZE);
    size_t plane = (size_t)width * (size_t)height;
    s->rgb = malloc(3 * plane);
    s->mask = malloc(GS_SYNTH_MASK_COUNT * plane);
    if (!s->rgb || !s->mask) {
        gs_synth_sample_free(s);
        return gs_error_set(err, GS_ERR_NOMEM, "synth: out of memory for "
                            "%dx%d sample", width, height);
    }
    s->width = width;
    s->height = height;
    s->stride = 3 * (size_t)width;
    return GS_OK;
}

void gs_synth_sample_free(gs_synth_sample *s)
{
    free(s->rgb);
    free(s->mask);
    s->rgb = NULL;
    s->mask = NULL;
}

static int finite_all(const double *v, int n)
{
    for (int i = 0; i < n; i++)
        if (!isfinite(v[i]))
            return 0;
    return 1;
}

static int check_inputs(const gs_synth_scene *s, const gs_synth_camera *c,
                        gs_error *err)
{
    if (!finite_all(s->head_R, 9) || !finite_all(s->head_t, 3) ||
        !isfinite(s->gaze_pitch) || !isfinite(s->gaze_yaw) ||
        (s->kappa && (!isfinite(s->kappa_h) || !isfinite(s->kappa_v))) ||
        !finite_all(c->K, 9) || !finite_all(c->R, 9) || !finite_all(c->t, 3))
        return gs_error_set(err, GS_ERR_NONFINITE,
                            "synth: non-finite scene or camera value");
    for (int i = 0; i < GS_SYNTH_ID_COUNT; i++)
        if (!isfinite(s->identity.p[i]))
            return gs_error_set(err, GS_ERR_NONFINITE,
                                "synth: identity parameter %s is not finite",
                                gs_synth_identity_name(i));
    if (c->width < 1 || c->height < 1 || c->width > MAX_SIZE ||
        c->height > MAX_SIZE)
        return gs_error_set(err, GS_ERR_ARG, "synth: camera size %dx%d",
                            c->width, c->height);
    if (!(c->K[0] > 0.0) || !(c->K[4] > 0.0))
        return gs_error_set(err, GS_ERR_ARG, "synth: focal lengths must be > 0");
    return GS_OK;
}

int gs_synth_labels_compute(const gs_synth_scene *scene,
                            const gs_synth_camera *cam, gs_synth_labels *lab,
                            gs_error *err)
{
    int rc = check_inputs(scene, cam, err);
    if (rc != GS_OK)
        return rc;
    head_model *h = malloc(sizeof *h);
    if (!h)
        return gs_error_set(err, GS_ERR_NOMEM, "synth: out of memory");
    gs_synth_head_build_scene(scene, h);
    gs_synth_labels_from_head(scene, cam, h, lab);
    free(h);
    return GS_OK;
}

int gs_synth_render(const gs_synth_scene *scene, const gs_synth_camera *cam,
                    const gs_synth_render_opts *opts, gs_pool *pool,
                    gs_synth_sample *out, gs_error *err)
{
    int rc = check_inputs(scene, cam, err);
    if (rc != GS_OK)
        return rc;
    int ss = opts && opts->supersample == 2 ? 2 : 1;
    if (opts && opts->supersample != 1 && opts->supersample != 2 &&
        opts->supersample != 0)
        return gs_error_set(err, GS_ERR_ARG, "synth: supersample must be 1 or 2");
    if (opts && (opts->region[2] > opts->region[0] ||
                 opts->region[3] > opts->region[1]) &&
        (opts->region[0] < 0 || opts->region[1] < 0 ||
         opts->region[2] <= opts->region[0] ||
         opts->region[3] <= opts->region[1] ||
         opts->region[2] > cam->width || opts->region[3] > cam->height))
        return gs_error_set(err, GS_ERR_ARG, "synth: region [%d, %d) x "
                            "[%d, %d) is empty or leaves the %dx%d image",
                            opts->region[0], opts->region[2],
                            opts->region[1], opts->region[3], cam->width,
                            cam->height);
    if (!out->rgb || !out->mask || out->width != cam->width ||
        out->height != cam->height || out->stride < 3 * (size_t)cam->width)
        return gs_error_set(err, GS_ERR_ARG,
                            "synth: sample buffers do not match the camera "
                            "(%dx%d)", cam->width, cam->height);
    render_ctx *r = malloc(sizeof *r);
    if (!r)
        return gs_error_set(err, GS_ERR_NOMEM, "synth: out of memory");
    gs_synth_head_build_scene(scene, &r->head);
    if (opts && opts->open_lids)
        gs_synth_head_open_lids(&r->head);
    gs_synth_render_setup(r, scene, cam, ss);
    if (opts && opts->region[2] > opts->region[0]) {
        r->rx0 = opts->region[0];
        r->ry0 = opts->region[1];
        r->rx1 = opts->region[2];
        r->ry1 = opts->region[3];
    }
    r->out = out;
    gs_synth_render_pixels(r, pool);
    gs_synth_labels_from_head(scene, cam, &r->head, &out->labels);
    free(r);
    return GS_OK;
}
