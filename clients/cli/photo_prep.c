/* The photo path's first half (photo_prep.h). */
#include <stdlib.h>
#include <string.h>

#include "photo_prep.h"
#include "gazesplat/geom.h"

static int refused(const gs_face_gate *g, gs_error *err)
{
    return gs_error_set(err, GS_ERR_ARG, "face refused (%s): %s", gs_face_refusal_name(g->refusal),
                        g->reason);
}

int cli_gate_normalized(const gs_io_image *face, gs_face_gate *g, gs_error *err)
{
    int rc = gs_face_gate_normalized(face, NULL, g, err);
    if (rc != GS_OK)
        g->refusal = GS_FACE_USABLE;
    else if (g->refusal != GS_FACE_USABLE)
        rc = refused(g, err);
    return rc;
}

int cli_photo_normalize(gs_face_detector *det, const gs_face_shape_model *sp,
                        const gs_io_image *photo, int index, const gs_model_info *info,
                        int gate, cli_photo_face *out, gs_error *err)
{
    memset(out, 0, sizeof *out);
    int S = info->image_size;
    gs_face_opts fo;
    gs_face_opts_default(&fo);
    fo.index = index;
    /* The model was trained on synthetic heads, whose labels use the
     * synthetic head frame: solve the pose against the mean synthetic head
     * so the normalization and the head angles are in that frame. */
    fo.pose_model = GS_FACE_POSE_SYNTH;
    fo.norm_size = S;
    fo.norm_distance_mm = info->distance_mm;
    fo.norm_focal = info->focal;
    int rc = gs_face_analyze(det, sp, photo, &fo, &out->res, err);
    if (rc == GS_ERR_ARG)
        out->gate.refusal = GS_FACE_REFUSED_NO_FACE;
    if (rc == GS_OK)
        rc = gs_face_normalize_image(photo, &out->res.norm, &out->norm, err);
    if (rc == GS_OK && gate &&
        (rc = gs_face_gate_photo(&out->res, &out->norm, NULL, &out->gate, err)) == GS_OK &&
        out->gate.refusal != GS_FACE_USABLE)
        rc = refused(&out->gate, err);
    if (rc == GS_OK && !(out->mask_n = malloc((size_t)S * S)))
        rc = gs_error_set(err, GS_ERR_NOMEM, "out of memory");
    if (rc == GS_OK)
        gs_face_mask((const double(*)[2])out->res.uv_n, GS_FACE_MASK_FACE, 0, 4, S, S,
                     out->mask_n, NULL);
    if (rc != GS_OK) {
        gs_face_gate g = out->gate;
        cli_photo_face_free(out);
        out->gate = g;
    }
    return rc;
}

void cli_photo_fit_options(const cli_photo_face *p, int iters, gs_fit_options *o)
{
    gs_fit_options_default(o);
    o->mask = p->mask_n;
    o->max_iters = iters;
    o->known_head = 1;
    gs_geom_norm_rot(&p->res.norm, p->res.pose.R, o->head_R);
    /* Normalization puts the face centre on the axis at d_n (the model's
     * distance), as the daemon and the live path fit it; the photo's own
     * distance |t| is not where the normalized face is. */
    o->head_t[2] = p->res.norm.d_n_mm;
}

void cli_photo_face_free(cli_photo_face *p)
{
    gs_io_image_free(&p->norm);
    free(p->mask_n);
    p->mask_n = NULL;
}
