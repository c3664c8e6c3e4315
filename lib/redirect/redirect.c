/* Redirecting a face (redirect.h): inputs, the fit's options, fine-tuning,
 * rendering and paste-back, shared by the daemon, the CLI, live and eval. */
#include "gazesplat/redirect.h"

#include <stdlib.h>
#include <string.h>

#include "gazesplat/geom.h"

void gs_redirect_finetune_options(int steps, gs_finetune_options *o)
{
    gs_finetune_options_default(o);
    o->iters = steps;
    o->lr = GS_FINETUNE_LR_SERVED;
}

void gs_redirect_photo_opts_default(gs_redirect_photo_opts *o)
{
    memset(o, 0, sizeof *o);
    o->gate = 1;
}

int gs_redirect_face_mask(const double uv_n[][2], int size, uint8_t *mask, gs_error *err)
{
    return gs_face_mask(uv_n, GS_FACE_MASK_FACE, 0.0, 4.0, size, size, mask, err);
}

int gs_redirect_eye_opening(const double uv_n[][2], int size, uint8_t *mask, gs_error *err)
{
    double k = size / 256.0;
    return gs_face_mask(uv_n, GS_FACE_MASK_EYE_OPENINGS, GS_REDIRECT_OPENING_GROW * k,
                        GS_REDIRECT_OPENING_FEATHER * k, size, size, mask, err);
}

/* Puts "what: " before err's message (err may be NULL); returns rc. */
static int prefixed(gs_error *err, int rc, const char *what)
{
    if (!err)
        return rc;
    char m[sizeof err->msg];
    memcpy(m, err->msg, sizeof m);
    m[sizeof m - 1] = '\0';
    return gs_error_set(err, rc, "%s: %s", what, m);
}

/* The irises of a photo's normalized face (px_per_mm its scale at the
 * eyes), after its red-eye repair: those the localizer finds (status OK;
 * a partial one rests on the radius prior, so it anchors nothing) anchor
 * the transfer's proxy eyeballs (model.h, gs_xfer_eyes). */
static int photo_irises(gs_redirect_input *in, double px_per_mm, gs_face_iris found[2],
                        gs_error *err)
{
    gs_face_iris_opts io;
    gs_face_iris_opts_default(&io);
    gs_face_iris_opts_scale(&io, px_per_mm);
    in->n_iris = 0;
    for (int e = 0; e < 2; e++) {
        const gs_face_iris *ir = &found[e];
        int rc = gs_face_iris_locate(&in->norm, (const double(*)[2])in->face.uv_n[36 + 6 * e], &io,
                                     &found[e], err);
        if (rc != GS_OK)
            return rc;
        if (ir->status != GS_FACE_IRIS_OK)
            continue;
        double *d = in->iris[in->n_iris++];
        d[0] = ir->centre[0], d[1] = ir->centre[1], d[2] = ir->radius;
    }
    return GS_OK;
}

/* The gate's answer as an error: GS_OK, GS_ERR_ARG "face refused (NAME):
 * reason", or the gate's own failure ("face gate: ...", refusal reset to
 * usable so that callers do not report a refusal). */
static int gate_verdict(int rc, gs_face_gate *g, gs_error *err)
{
    if (rc != GS_OK) {
        g->refusal = GS_FACE_USABLE;
        return prefixed(err, rc, "face gate");
    }
    if (g->refusal != GS_FACE_USABLE)
        return gs_error_set(err, GS_ERR_ARG, "face refused (%s): %s", gs_face_refusal_name(g->refusal),
                            g->reason);
    return GS_OK;
}

/* Frees what in holds and keeps its gate's measures. */
static void input_drop(gs_redirect_input *in)
{
    gs_face_gate g = in->gate;
    gs_redirect_input_free(in);
    in->gate = g;
}

int gs_redirect_input_photo(gs_face_detector *det, const gs_face_shape_model *sp,
                            const gs_model_info *info, gs_io_image *photo,
                            const gs_redirect_photo_opts *o, gs_redirect_input *in, gs_error *err)
{
    gs_redirect_photo_opts def;
    if (!o) {
        gs_redirect_photo_opts_default(&def);
        o = &def;
    }
    memset(in, 0, sizeof *in);
    in->is_photo = 1;
    in->photo = *photo;
    memset(photo, 0, sizeof *photo);
    int S = info->image_size;
    gs_face_opts fo;
    gs_face_opts_default(&fo);
    fo.index = o->index;
    /* The model was trained on synthetic heads, whose labels use the
     * synthetic head frame: the pose is solved against the mean synthetic
     * head, so the normalization and the head angles are in that frame. */
    fo.pose_model = GS_FACE_POSE_SYNTH;
    fo.norm_size = S;
    fo.norm_distance_mm = info->distance_mm;
    fo.norm_focal = info->focal;
    if (o->use_k) {
        fo.use_k = 1;
        memcpy(fo.k, o->k, sizeof fo.k);
    }
    int rc = gs_face_analyze(det, sp, &in->photo, &fo, &in->face, err);
    if (rc != GS_OK) {
        if (rc == GS_ERR_ARG)
            in->gate.refusal = GS_FACE_REFUSED_NO_FACE;
        prefixed(err, rc, "photo");
        input_drop(in);
        return rc;
    }
    if (!(in->mask = malloc((size_t)S * S)) || !(in->opening = malloc((size_t)S * S)))
        rc = gs_error_set(err, GS_ERR_NOMEM, "photo normalization: out of memory");
    if (rc == GS_OK && (rc = gs_face_normalize_image(&in->photo, &in->face.norm, &in->norm, err)) == GS_OK)
        rc = gs_redirect_face_mask((const double(*)[2])in->face.uv_n, S, in->mask, err);
    if (rc == GS_OK)
        rc = gs_redirect_eye_opening((const double(*)[2])in->face.uv_n, S, in->opening, err);
    /* A red-eye pupil would stay where it was in the fit and the transfer
     * (a ghost beside the redirected iris): repaired before either. */
    if (rc == GS_OK && !o->keep_red_eye)
        rc = gs_face_red_eye_fix(&in->norm, (const double(*)[2])in->face.uv_n,
                                 info->focal / info->distance_mm, &in->red_eye_px, err);
    gs_face_iris found[2]; /* the gate's too: the same image, contours and scale */
    if (rc == GS_OK)
        rc = photo_irises(in, info->focal / info->distance_mm, found, err);
    if (rc != GS_OK && rc != GS_ERR_NOMEM)
        prefixed(err, rc, "photo normalization");
    if (rc == GS_OK && o->gate)
        rc = gate_verdict(gs_face_gate_photo_irises(&in->face, &in->norm, found, NULL, &in->gate, err),
                          &in->gate, err);
    if (rc != GS_OK)
        input_drop(in);
    return rc;
}

int gs_redirect_input_face(const gs_model_info *info, gs_io_image *face, int gate,
                           gs_redirect_input *in, gs_error *err)
{
    memset(in, 0, sizeof *in);
    in->norm = *face;
    memset(face, 0, sizeof *face);
    int S = info->image_size, rc = GS_OK;
    if (in->norm.width != S || in->norm.height != S)
        rc = gs_error_set(err, GS_ERR_ARG, "normalized face is %dx%d, the model wants %dx%d",
                          in->norm.width, in->norm.height, S, S);
    else if (gate)
        rc = gate_verdict(gs_face_gate_normalized(&in->norm, NULL, &in->gate, err), &in->gate, err);
    if (rc != GS_OK)
        input_drop(in);
    return rc;
}

void gs_redirect_input_free(gs_redirect_input *in)
{
    gs_io_image_free(&in->norm);
    gs_io_image_free(&in->photo);
    free(in->mask);
    free(in->opening);
    memset(in, 0, sizeof *in);
}

void gs_redirect_fit_head(const double R_n[9], double d_n, gs_fit_options *o)
{
    o->known_head = 1;
    memcpy(o->head_R, R_n, sizeof o->head_R);
    o->head_t[0] = o->head_t[1] = 0.0;
    o->head_t[2] = d_n;
}

void gs_redirect_fit_pose(const gs_geom_norm *n, const double R[9], gs_fit_options *o)
{
    double R_n[9];
    gs_geom_norm_rot(n, R, R_n);
    gs_redirect_fit_head(R_n, n->d_n_mm, o);
}

void gs_redirect_fit_options(const gs_redirect_input *in, gs_fit_options *o)
{
    gs_fit_options_default(o);
    o->max_iters = GS_REDIRECT_FIT_ITERS;
    o->mask = in->mask;
    if (in->is_photo)
        gs_redirect_fit_pose(&in->face.norm, in->face.pose.R, o);
}

int gs_redirect_finetune(gs_model **tuned, const gs_model *shared, gs_pool *pool,
                         const gs_subject *subs, const gs_fit_image *im, int n,
                         const gs_finetune_options *opt, gs_finetune_report *rep, gs_error *err)
{
    int made = !*tuned, rc;
    if (made)
        rc = gs_model_clone(shared, tuned, err);
    else
        rc = gs_model_tuned_apply(*tuned, shared, NULL, 0, err);
    if (rc != GS_OK) {
        if (made)
            *tuned = NULL;
        return rc;
    }
    gs_finetune_options fo = *opt;
    fo.mask = NULL; /* each image's is in im */
    rc = gs_model_finetune_images(*tuned, pool, subs, im, n, &fo, rep, err);
    if (rc != GS_OK && made) {
        gs_model_destroy(*tuned);
        *tuned = NULL;
    }
    return rc;
}

gs_xfer_eyes gs_redirect_eyes(const gs_redirect_input *in)
{
    gs_xfer_eyes e;
    memset(&e, 0, sizeof e);
    if (!in || !in->is_photo)
        return e;
    e.opening = in->opening;
    e.n_iris = in->n_iris;
    memcpy(e.iris, in->iris, sizeof e.iris);
    return e;
}

int gs_redirect_render(gs_model_ctx *c, gs_pool *pool, const gs_subject *sub,
                       const uint8_t *input, size_t in_stride, const gs_xfer_eyes *eyes,
                       const gs_view *v, uint8_t *out, size_t stride, gs_error *err)
{
    if (input)
        return gs_model_render_transfer_eyes(c, pool, sub, input, in_stride, eyes, v, out,
                                             stride, err);
    return gs_model_render(c, pool, sub, v, out, stride, err);
}

int gs_redirect_paste(const gs_redirect_input *in, gs_redirect_paste_state *ps, int whole_face,
                      const gs_io_image *norm, gs_error *err)
{
    if (!in->is_photo || !in->photo.data)
        return gs_error_set(err, GS_ERR_ARG, "paste-back: the input is not a photo");
    whole_face = !!whole_face;
    const gs_io_image *ph = &in->photo;
    size_t bytes = ph->stride * (size_t)ph->height, px = (size_t)ph->width * ph->height;
    if (!ps->mask[whole_face]) {
        if (!(ps->mask[whole_face] = malloc(px)))
            return gs_error_set(err, GS_ERR_NOMEM, "paste-back mask: out of memory");
        int rc = gs_face_paste_mask(&in->face, whole_face, ps->mask[whole_face], err);
        if (rc != GS_OK) {
            free(ps->mask[whole_face]);
            ps->mask[whole_face] = NULL;
            return prefixed(err, rc, "paste-back mask");
        }
    }
    if (!ps->out.data) {
        ps->out = *ph;
        if (!(ps->out.data = malloc(bytes)))
            return gs_error_set(err, GS_ERR_NOMEM, "paste-back: out of memory");
    }
    memcpy(ps->out.data, ph->data, bytes);
    int rc = gs_face_paste_back(&ps->out, norm, &in->face.norm, ps->mask[whole_face], err);
    if (rc != GS_OK)
        return prefixed(err, rc, "paste-back");
    return GS_OK;
}

void gs_redirect_paste_free(gs_redirect_paste_state *ps)
{
    free(ps->mask[0]);
    free(ps->mask[1]);
    free(ps->out.data);
    memset(ps, 0, sizeof *ps);
}
