/* The frame's context: its buffers (made for a model, grown for training
 * and renders, trimmed and freed), the render scratch contexts may share,
 * the render options and the statistics. The forward and backward that
 * use them are in frame.c, the sweep cache in frame_sweep.c. */
#include <limits.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "frame_ctx.h"
#include "frame_sweep.h"
#include "gazesplat/nn.h"

/* ---- context ---- */


/* ---- the face stream in blocks ----
 *
 * The face Gaussians go through the MLPs in fixed blocks of rows, one pool
 * task each, from the inputs to the camera-frame Gaussians (forward) and
 * from their gradients back to the parameters (backward). The blocks
 * depend only on the face count (at least GS_FACE_BLOCK_MIN rows, at most
 * GS_FACE_BLOCKS_MAX blocks), so the bytes do not depend on the thread
 * count. A block's MLP activations lie at its first row's offset in
 * fe_act / fp_act (block-major: gs_mlp_act_size(m, 1) floats a row), its
 * MLP scratch at 2 r0 widest floats in the MLP part of c->scratch. Sums
 * over Gaussians (the MLP weights' gradients, the code's, the gaze
 * encoding's) are taken per block and then added block by block. */
#define GS_FACE_BLOCK_MIN 1024
#define GS_FACE_BLOCKS_MAX 16

static int face_block_rows(int nf)
{
    int r = (nf + GS_FACE_BLOCKS_MAX - 1) / GS_FACE_BLOCKS_MAX;
    return r > GS_FACE_BLOCK_MIN ? r : GS_FACE_BLOCK_MIN;
}

int gs_frame_ctx_init(gs_model_ctx *c, const gs_model *m)
{
    const gs_model_config *k = &m->cfg;
    const gs_model_params *p = &m->p;
    int fail = 0;
    c->m = m;
    c->nf = k->n_face;
    c->ne = k->two_stream ? 2 * k->n_eye_each : 0;
    c->n = c->nf + c->ne;
    c->nl = gs_model_n_lid(k);
    c->nl0 = k->n_lid0;
    c->nm = c->nf - c->nl;
    c->F = k->feat_dim;
    c->D = gs_model_code_dim(k);
    c->C = k->channels;
    c->fs = k->feat_size;
    c->S = k->image_size;
    size_t nf = (size_t)c->nf, ne = (size_t)(c->ne ? c->ne : 1),
           n = (size_t)c->n;
    c->fe_out = gs_ctx_falloc(nf * GS_FACE_OUT(c->C), &fail);
    c->fp_out = gs_ctx_falloc(nf * GS_FACE_OUT(c->C), &fail);
    c->fblk = face_block_rows(c->nf);
    c->nfblk = c->nf > 0 ? (c->nf + c->fblk - 1) / c->fblk : 0;
    c->e_in = gs_ctx_falloc(ne * p->eye.dims[0], &fail);
    c->e_act = gs_ctx_falloc(gs_mlp_act_size(&p->eye, (int)ne), &fail);
    c->e_out = gs_ctx_falloc(ne * GS_EYE_OUT(c->C), &fail);
    for (int e = 0; e < 2; e++)
        c->er_act[e] = gs_ctx_falloc(gs_mlp_act_size(&p->eye_rot[e], 1), &fail);
    c->g_mean = gs_ctx_falloc(n * 3, &fail);
    c->g_scale = gs_ctx_falloc(n * 3, &fail);
    c->g_quat = gs_ctx_falloc(n * 4, &fail);
    c->g_opac = gs_ctx_falloc(n, &fail);
    c->g_feat = gs_ctx_falloc(n * c->C, &fail);
    c->x_head = gs_ctx_falloc(n * 3, &fail);
    c->q_head = gs_ctx_falloc(nf * 4, &fail);
    size_t fsz = (size_t)c->fs * c->fs, isz = (size_t)c->S * c->S;
    c->bg = gs_ctx_falloc(fsz * c->C, &fail);
    c->fmap = gs_ctx_falloc(fsz * c->C, &fail);
    c->v_fmap = gs_ctx_falloc(fsz * c->C, &fail);
    c->alpha = gs_ctx_falloc(fsz, &fail);
    c->rgb = gs_ctx_falloc(isz * 3, &fail);
    c->v_rgb = gs_ctx_falloc(isz * 3, &fail);
    c->scr = calloc(1, sizeof *c->scr);
    if (c->scr)
        c->scr->refs = 1;
    else
        fail = 1;
    c->fmap_face = gs_ctx_falloc(fsz * c->C, &fail);
    c->v_fmap_face = gs_ctx_falloc(fsz * c->C, &fail);
    c->alpha_face = gs_ctx_falloc(fsz, &fail);
    c->bg_crop = gs_ctx_falloc(fsz * c->C, &fail);
    c->gvec = gs_ctx_falloc((size_t)c->C, &fail);
    c->rgb8 = malloc(isz * 3);
    c->fbox = calloc(nf ? nf : 1, 4 * sizeof(int16_t));
    c->k_mean = gs_ctx_falloc(n * 3, &fail);
    c->k_scale = gs_ctx_falloc(n * 3, &fail);
    c->k_quat = gs_ctx_falloc(n * 4, &fail);
    c->k_opac = gs_ctx_falloc(n, &fail);
    c->k_feat = gs_ctx_falloc(n * c->C, &fail);
    c->sweep_n = GS_MODEL_SWEEP_CACHE_DEFAULT;
    c->ss = m->cfg.supersample > 1 ? m->cfg.supersample : 1;
    c->render_fs = c->face_map_fs = c->ss * c->fs;
    c->xfer_head_w = GS_XFER_HEAD_WEIGHT_DEFAULT;
    c->xfer_eye_w = GS_XFER_EYE_WEIGHT_DEFAULT;
    c->xfer_warp_deg = GS_XFER_EYE_WARP_DEG_DEFAULT;
    c->xfer_warp_given_deg = GS_XFER_EYE_WARP_GIVEN_DEG_DEFAULT;
    c->xfer_lid = GS_XFER_LID_FOLLOW_DEFAULT;
    c->xfer_warp_head = GS_XFER_EYE_WARP_HEAD_DEFAULT;
    int h0 = p->eye.dims[1], fd = c->F + c->D;
    c->eye_w0 = gs_ctx_falloc((size_t)h0 * fd, &fail);
    c->eye_base = gs_ctx_falloc(ne * h0, &fail);
    c->eye_v = gs_ctx_falloc((size_t)h0, &fail);
    for (int o = 0; c->eye_w0 && o < h0; o++) /* W0's [f | tau] columns */
        memcpy(c->eye_w0 + (size_t)o * fd, p->eye.w[0] + (size_t)o * p->eye.dims[0],
               (size_t)fd * sizeof(float));
    c->raster = gs_raster_create();
    c->raster_face = gs_raster_create();
    c->raster_crop = gs_raster_create();
    c->raster_eye = gs_raster_create();
    if (fail || !c->rgb8 || !c->fbox || !c->raster || !c->raster_face || !c->raster_crop ||
        !c->raster_eye)
        return GS_ERR_NOMEM;
    const gs_renderer_config *rc = &m->rcfg;
    c->src_mode = c->ne > 0 && rc->guidance != GS_GUIDE_NONE &&
                  rc->guide_source == GS_GUIDE_SRC_SOURCE;
    /* the incremental path rasterizes crops at fs: point-sampled maps only */
    c->eye_direct = c->ne > 0 && m->cfg.eye_direct;
    c->inc_ok = c->ne > 0 && (rc->guidance == GS_GUIDE_NONE || c->src_mode) &&
                c->ss == 1;
    /* White RGB background, zero for the other channels. */
    for (size_t i = 0; i < 3 * fsz; i++)
        c->bg[i] = 1.0f;
    c->face_valid = 0;
    c->fe_valid = 0;
    return GS_OK;
}

/* ---- what only fitting and training use ----
 *
 * A context renders with the buffers gs_frame_ctx_init makes. A backward
 * needs more: the face MLPs' inputs and activations of every row (a render
 * runs each block through a scratch of its pool thread instead), the
 * Gaussians' and the blocks' gradients, the backward's scratch, the
 * eye-only map and the renderer's full activation buffer (a render's
 * forward keeps nothing: gs_renderer_fwd_size). gs_ctx_train_alloc makes them at
 * the first training forward; gs_model_ctx_trim frees them. Either way a
 * render computes the same bytes. */
static void train_free(gs_model_ctx *c)
{
    float **b[] = {&c->fe_in, &c->fe_act, &c->fp_in, &c->fp_act,
                   &c->v_mean, &c->v_scale, &c->v_quat, &c->v_opac,
                   &c->v_feat, &c->blk_grad, &c->blk_red,
                   &c->scratch, &c->fmap_eye, &c->v_fmap_eye, &c->alpha_eye,
                   &c->lid_save, &c->r_act};
    for (size_t i = 0; i < sizeof b / sizeof b[0]; i++) {
        free(*b[i]);
        *b[i] = NULL;
    }
    c->r_act_len = 0;
    c->train_ready = 0;
    c->train_bytes = 0;
    c->face_saved = 0; /* the face cache's activations went with them */
}

/* falloc, counting the floats into *tb */
static float *talloc(size_t n, size_t *tb, int *fail)
{
    *tb += n;
    return gs_ctx_falloc(n, fail);
}

int gs_ctx_train_alloc(gs_model_ctx *c)
{
    if (c->train_ready)
        return GS_OK;
    const gs_model *m = c->m;
    const gs_model_params *p = &m->p;
    size_t nf = (size_t)c->nf, ne = (size_t)(c->ne ? c->ne : 1),
           n = (size_t)c->n, fsz = (size_t)c->fs * c->fs;
    int fail = 0;
    size_t tb = 0; /* floats */
    c->fe_in = talloc(nf * p->face_e.dims[0], &tb, &fail);
    c->fe_act = talloc(gs_mlp_act_size(&p->face_e, c->nf), &tb, &fail);
    c->fp_in = talloc(nf * p->face_p.dims[0], &tb, &fail);
    c->fp_act = talloc(gs_mlp_act_size(&p->face_p, c->nf), &tb, &fail);
    size_t pe = gs_mlp_param_count(&p->face_e), pp = gs_mlp_param_count(&p->face_p);
    c->blk_grad_len = pe > pp ? pe : pp;
    c->blk_grad = talloc((size_t)c->nfblk * c->blk_grad_len, &tb, &fail);
    c->blk_red = talloc((size_t)c->nfblk * (size_t)(c->D + GS_PE_DIM(2)), &tb, &fail);
    c->v_mean = talloc(n * 3, &tb, &fail);
    c->v_scale = talloc(n * 3, &tb, &fail);
    c->v_quat = talloc(n * 4, &tb, &fail);
    c->v_opac = talloc(n, &tb, &fail);
    c->v_feat = talloc(n * c->C, &tb, &fail);
    size_t sc = gs_mlp_scratch_size(&p->face_e, c->nf);
    size_t s2 = gs_mlp_scratch_size(&p->face_p, c->nf);
    size_t s3 = gs_mlp_scratch_size(&p->eye, (int)ne);
    sc = sc > s2 ? sc : s2;
    sc = sc > s3 ? sc : s3;
    size_t blk = nf * (size_t)p->face_e.dims[0];
    size_t cand[] = {nf * (size_t)p->face_p.dims[0],
                     ne * (size_t)p->eye.dims[0],
                     nf * (size_t)GS_FACE_OUT(c->C),
                     ne * (size_t)GS_EYE_OUT(c->C)};
    for (int i = 0; i < 4; i++)
        blk = cand[i] > blk ? cand[i] : blk;
    c->scratch_blk = blk;
    c->scratch_len = sc + 2 * blk;
    c->scratch = talloc(c->scratch_len, &tb, &fail);
    c->fmap_eye = talloc(fsz * c->C, &tb, &fail);
    c->v_fmap_eye = talloc(fsz * c->C, &tb, &fail);
    c->alpha_eye = talloc(fsz, &tb, &fail);
    c->lid_save = talloc((size_t)(c->nl ? c->nl : 1) * 7, &tb, &fail);
    c->r_act_len = gs_renderer_act_size(&m->rcfg, c->fs, c->fs);
    c->r_act = talloc(c->r_act_len, &tb, &fail);
    if (fail) {
        train_free(c);
        return GS_ERR_NOMEM;
    }
    c->train_ready = 1;
    c->train_bytes = tb * sizeof(float);
    return GS_OK;
}

int gs_model_ctx_trim(gs_model_ctx *c)
{
    if (!c)
        return GS_OK;
    train_free(c);
    /* the records training forwards kept for their backwards */
    gs_raster *r[] = {c->raster, c->raster_face, c->raster_eye, c->raster_crop,
                      c->raster_cov, c->raster_dir};
    for (size_t i = 0; i < sizeof r / sizeof r[0]; i++)
        gs_raster_trim(r[i]);
    return GS_OK;
}

/* ---- a render's scratch ----
 * A render (no backward follows) needs the renderer's forward-only buffer
 * and, for the face stream, each pool thread's scratch for one block's MLP
 * inputs and activations; nothing in them outlives the call, so contexts
 * that are never used at the same time can share them
 * (gs_model_ctx_share_scratch). Made, or grown, at first need. */
static int scratch_grow(float **buf, size_t *len, size_t need)
{
    if (*len >= need)
        return GS_OK;
    float *b = calloc(need ? need : 1, sizeof(float));
    if (!b)
        return GS_ERR_NOMEM;
    free(*buf);
    *buf = b;
    *len = need;
    return GS_OK;
}

static void scratch_release(gs_ctx_scratch *s)
{
    if (s && --s->refs == 0) {
        free(s->act);
        free(s->face);
        free(s);
    }
}

/* The renderer's buffer of a forward: the training one when the context
 * has it (it also serves renders), else the scratch's forward-only one. */
int gs_ctx_render_acts(gs_model_ctx *c, float **acts, size_t *len)
{
    if (c->r_act) {
        *acts = c->r_act, *len = c->r_act_len;
        return GS_OK;
    }
    gs_ctx_scratch *s = c->scr;
    if (scratch_grow(&s->act, &s->act_len, gs_renderer_fwd_size(&c->m->rcfg, c->fs, c->fs)))
        return GS_ERR_NOMEM;
    *acts = s->act, *len = s->act_len;
    return GS_OK;
}

int gs_model_ctx_share_scratch(gs_model_ctx *c, gs_model_ctx *with)
{
    if (!c || !with)
        return GS_ERR_ARG;
    if (c->scr == with->scr)
        return GS_OK;
    scratch_release(c->scr);
    c->scr = with->scr;
    c->scr->refs++;
    return GS_OK;
}

/* A render's face stream: each pool thread's scratch for one block's MLP
 * inputs and activations (the context keeps no rows for a backward). */
size_t gs_ctx_face_scratch_each(const gs_model_ctx *c)
{
    const gs_model_params *p = &c->m->p;
    return (size_t)c->fblk * (size_t)(p->face_e.dims[0] + p->face_p.dims[0]) +
           gs_mlp_act_size(&p->face_e, c->fblk) +
           gs_mlp_act_size(&p->face_p, c->fblk);
}

int gs_ctx_face_scratch(gs_model_ctx *c, int threads)
{
    gs_ctx_scratch *s = c->scr;
    return scratch_grow(&s->face, &s->face_len, (size_t)threads * gs_ctx_face_scratch_each(c));
}

void gs_model_ctx_destroy(gs_model_ctx *c)
{
    if (!c)
        return;
    train_free(c);
    float **bufs[] = {&c->fe_in, &c->fe_act, &c->fe_out, &c->fp_in,
                      &c->fp_act, &c->fp_out, &c->e_in, &c->e_act, &c->e_out,
                      &c->er_act[0], &c->er_act[1], &c->g_mean, &c->g_scale,
                      &c->g_quat, &c->g_opac, &c->g_feat, &c->x_head,
                      &c->q_head, &c->v_mean, &c->v_scale, &c->v_quat,
                      &c->v_opac, &c->v_feat, &c->bg, &c->fmap, &c->v_fmap,
                      &c->alpha, &c->rgb, &c->v_rgb,
                      &c->scratch, &c->fmap_face, &c->v_fmap_face,
                      &c->alpha_face, &c->bg_crop, &c->gvec, &c->fmap_eye,
                      &c->v_fmap_eye, &c->alpha_eye, &c->k_mean,
                      &c->k_scale, &c->k_quat, &c->k_opac, &c->k_feat,
                      &c->eye_w0, &c->eye_base, &c->eye_v,
                      &c->v_fmap_m, &c->v_fmap_face_m, &c->v_feat_keep,
                      &c->blk_grad, &c->blk_red};
    for (size_t i = 0; i < sizeof bufs / sizeof bufs[0]; i++)
        free(*bufs[i]);
    free(c->rgb8);
    free(c->fbox);
    scratch_release(c->scr);
    free(c->cov_ind), free(c->cov_bg), free(c->cover), free(c->v_ind);
    free(c->ss_buf);
    free(c->dir_feat), free(c->dir_vfeat), free(c->dir_out), free(c->dir_alpha);
    free(c->dir_bg), free(c->rgb_main), free(c->dir_dmain), free(c->dir_d);
    free(c->anc_fmap), free(c->anc_rgb);
    gs_raster_destroy(c->raster_dir);
    gs_raster_destroy(c->raster_cov);
    for (int i = 0; c->slots && i < c->sweep_n - 1; i++)
        gs_sweep_slot_free(&c->slots[i]);
    free(c->slots);
    gs_raster_destroy(c->raster);
    gs_raster_destroy(c->raster_face);
    gs_raster_destroy(c->raster_crop);
    gs_raster_destroy(c->raster_eye);
    if (c->xfer)
        c->xfer_free(c->xfer);
    free(c);
}

gs_model_ctx *gs_model_ctx_create(const gs_model *m)
{
    if (!m)
        return NULL;
    gs_model_ctx *c = calloc(1, sizeof *c);
    if (!c)
        return NULL;
    if (gs_frame_ctx_init(c, m) != GS_OK) {
        gs_model_ctx_destroy(c);
        return NULL;
    }
    return c;
}


void gs_model_render_options_default(gs_model_render_options *o)
{
    memset(o, 0, sizeof *o);
    o->feature_scale = 1.0;
    o->transfer_head_weight = GS_XFER_HEAD_WEIGHT_DEFAULT;
    o->transfer_eye_weight = GS_XFER_EYE_WEIGHT_DEFAULT;
    o->transfer_eye_warp_deg = GS_XFER_EYE_WARP_DEG_DEFAULT;
    o->transfer_eye_warp_given_deg = GS_XFER_EYE_WARP_GIVEN_DEG_DEFAULT;
    o->transfer_lid_follow = GS_XFER_LID_FOLLOW_DEFAULT;
    o->transfer_eye_warp_head = GS_XFER_EYE_WARP_HEAD_DEFAULT;
}

int gs_model_ctx_set_render_options(gs_model_ctx *c,
                                    const gs_model_render_options *o,
                                    gs_error *err)
{
    if (!c || !o)
        return gs_error_set(err, GS_ERR_ARG, "render options: NULL argument");
    double s = o->feature_scale;
    long fsr = s > 0 && s <= 1 ? lround(s * c->fs) : 0;
    if (s == 1) /* the model's own sampling */
        fsr = (long)c->ss * c->fs;
    if (s == 2 || s == 3 || s == 4) /* supersampled: s x s per pixel */
        fsr = (long)s * c->fs;
    if (fsr < 4 || (s < 1 && fsr > c->fs))
        return gs_error_set(err, GS_ERR_ARG,
                            "feature scale %g: want (0, 1] and at least 4 "
                            "of the %d feature pixels, or 2, 3 or 4 "
                            "(supersampled)", s, c->fs);
    double hw = o->transfer_head_weight;
    if (!(hw >= 0 && hw <= 1))
        return gs_error_set(err, GS_ERR_ARG,
                            "transfer head weight %g: want [0, 1]", hw);
    double ew = o->transfer_eye_weight;
    if (!(ew >= 0 && ew <= 1))
        return gs_error_set(err, GS_ERR_ARG,
                            "transfer eye weight %g: want [0, 1]", ew);
    double wd = o->transfer_eye_warp_deg;
    if (!(wd >= 0 && wd <= 90))
        return gs_error_set(err, GS_ERR_ARG,
                            "transfer eye warp %g deg: want [0, 90] (0: off)",
                            wd);
    double gd = o->transfer_eye_warp_given_deg;
    if (!(gd > 0 && gd <= 90))
        return gs_error_set(err, GS_ERR_ARG,
                            "transfer eye warp with a given opening %g deg: want (0, 90]",
                            gd);
    double lf = o->transfer_lid_follow;
    if (!(lf >= 0 && lf <= 1.5))
        return gs_error_set(err, GS_ERR_ARG,
                            "transfer lid follow %g: want [0, 1.5] (0: lids stay)", lf);
    if (o->transfer_eye_warp_head != 0 && o->transfer_eye_warp_head != 1)
        return gs_error_set(err, GS_ERR_ARG,
                            "transfer eye warp at a head change %d: want 0 "
                            "or 1", o->transfer_eye_warp_head);
    gs_sweep_drop(c); /* kept renders were made with the old settings */
    c->render_fs = (int)fsr;
    c->xfer_head_w = (float)hw;
    c->xfer_eye_w = (float)ew;
    c->xfer_warp_deg = wd;
    c->xfer_warp_given_deg = gd;
    c->xfer_lid = lf;
    c->xfer_warp_head = o->transfer_eye_warp_head;
    c->render_full = o->full != 0;
    return GS_OK;
}

void gs_model_ctx_reset(gs_model_ctx *c)
{
    if (!c)
        return;
    gs_sweep_drop(c);
    c->face_valid = 0;
    c->face_map_valid = 0;
    c->rgb8_valid = 0;
}

void gs_model_ctx_get_stats(const gs_model_ctx *c, gs_model_ctx_stats *st)
{
    memset(st, 0, sizeof *st);
    if (!c)
        return;
    st->renders_full = c->n_full;
    st->renders_incremental = c->n_inc;
    st->last_incremental = c->last_inc;
    st->transfers_full = c->n_xfer_full;
    st->transfers_incremental = c->n_xfer_inc;
    st->last_transfer_incremental = c->last_xfer_inc;
    for (int i = 0; c->slots && i < c->sweep_n - 1; i++)
        st->sweep_kept += c->slots[i].valid;
    st->sweep_kept += c->inc_valid;
    st->train_bytes = c->train_bytes;
    st->face_expr_kept = c->n_fe_kept;
}

int gs_frame_set_feature_mask(gs_model_ctx *c, const float *mask,
                              gs_error *err)
{
    c->feat_mask = NULL;
    if (!mask)
        return GS_OK;
    size_t fsz = (size_t)c->fs * c->fs * c->C;
    int fail = 0;
    if (!c->v_fmap_m)
        c->v_fmap_m = gs_ctx_falloc(fsz, &fail);
    if (!c->v_fmap_face_m)
        c->v_fmap_face_m = gs_ctx_falloc(fsz, &fail);
    if (!c->v_feat_keep)
        c->v_feat_keep = gs_ctx_falloc((size_t)c->n * c->C, &fail);
    if (fail)
        return gs_error_set(err, GS_ERR_NOMEM, "model: out of memory");
    c->feat_mask = mask;
    return GS_OK;
}
