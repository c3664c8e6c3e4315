/* Parameter table of a model: every tensor with its name, shape, place in
 * the one parameter array and optimizer group. The same table names the
 * tensors of the model file. This file owns a model's memory: allocation,
 * binding, destruction, the parameter id and the layout checks. */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "model_internal.h"
#include "hash64.h"

void gs_model_config_default(gs_model_config *c)
{
    memset(c, 0, sizeof *c);
    c->n_face = 0;          /* set from the template at creation */
    c->n_eye_each = 700;
    c->feat_dim = 32;
    c->id_dim = 32;
    c->hidden = 64;
    c->channels = 32;
    c->feat_size = 64;
    c->image_size = 256;
    c->guidance = GS_GUIDE_ADDITIVE;
    c->guide_source = GS_GUIDE_SRC_SOURCE;
    c->supersample = 1;
    c->eye_direct = 0;
    c->two_stream = 1;
    c->eye_rotation = 1;
    c->n_train_ids = 0;
    c->template_spacing_mm = 3.0;
    c->d_n_mm = 680.0;
    c->focal = 1600.0 * 256.0 / 512.0;
}

int gs_model_config_check(const gs_model_config *c, gs_error *err)
{
#define RANGE(f, lo, hi)                                                      \
    if (c->f < (lo) || c->f > (hi))                                           \
        return gs_error_set(err, GS_ERR_FORMAT,                               \
                            "model config: " #f " = %d outside [%d, %d]",     \
                            (int)c->f, (int)(lo), (int)(hi));
    RANGE(n_face, 1, 1000000)
    RANGE(n_eye_each, 1, 100000)
    RANGE(feat_dim, 1, 256)
    RANGE(id_dim, 1, GS_MODEL_MAX_CODE - GS_MODEL_EXPR_DIM - GS_MODEL_LIGHT_DIM)
    RANGE(hidden, 1, 1024)
    RANGE(channels, 3, GS_RASTER_MAX_CHANNELS)
    RANGE(feat_size, 8, 1024)
    RANGE(guidance, 0, 2)
    RANGE(guide_source, 0, 1)
    RANGE(two_stream, 0, 1)
    RANGE(eye_rotation, 0, 1)
    RANGE(n_train_ids, 0, 100000)
    RANGE(n_lid0, 0, c->n_face)
    RANGE(n_lid1, 0, c->n_face - c->n_lid0)
    RANGE(supersample, 1, 4)
    RANGE(eye_direct, 0, 1)
#undef RANGE
    if (c->eye_direct && !c->two_stream)
        return gs_error_set(err, GS_ERR_FORMAT,
                            "model config: eye_direct needs two streams");
    if (gs_model_n_lid(c) && !(c->two_stream && c->eye_rotation))
        return gs_error_set(err, GS_ERR_FORMAT,
                            "model config: lids need two streams and eye "
                            "rotation");
    if (c->image_size != 4 * c->feat_size)
        return gs_error_set(err, GS_ERR_FORMAT,
                            "model config: image_size %d != 4 x feat_size %d",
                            c->image_size, c->feat_size);
    if (!(c->template_spacing_mm >= 0.5 && c->template_spacing_mm <= 50.0))
        return gs_error_set(err, GS_ERR_FORMAT,
                            "model config: template spacing %g mm",
                            c->template_spacing_mm);
    if (!gs_code_prior_weight_ok(c->fit_code_prior))
        return gs_error_set(err, GS_ERR_FORMAT,
                            "model config: fit_code_prior %g outside [0, 10]",
                            c->fit_code_prior);
    if (!gs_code_rate_ok(c->fit_code_rate))
        return gs_error_set(err, GS_ERR_FORMAT,
                            "model config: fit_code_rate %g outside [0, 10]",
                            c->fit_code_rate);
    if (!(c->d_n_mm > 10.0 && c->d_n_mm < 1e5) ||
        !(c->focal > 1.0 && c->focal < 1e6))
        return gs_error_set(err, GS_ERR_FORMAT,
                            "model config: bad camera d_n %g focal %g",
                            c->d_n_mm, c->focal);
    return GS_OK;
}

typedef struct layout_builder {
    gs_model *m;
    size_t off;
    int overflow;
} layout_builder;

static void add_tensor(layout_builder *b, const char *name, int group,
                       int ndim, int64_t d0, int64_t d1, int64_t d2, int pad)
{
    gs_model *m = b->m;
    if (m->ntensors >= GS_MODEL_MAX_TENSORS) {
        b->overflow = 1;
        return;
    }
    gs_ptensor *t = &m->t[m->ntensors++];
    snprintf(t->name, sizeof t->name, "%s", name);
    t->ndim = ndim;
    t->shape[0] = d0;
    t->shape[1] = d1;
    t->shape[2] = d2;
    t->count = (size_t)d0 * (size_t)(ndim > 1 ? d1 : 1) *
               (size_t)(ndim > 2 ? d2 : 1);
    t->offset = b->off;
    t->group = group;
    /* Keep tensors 16-float aligned so SIMD loads stay aligned; the
     * renderer's tensors are packed (pad 0) as its own layout expects. */
    b->off += pad ? (t->count + 15) & ~(size_t)15 : t->count;
}

static void add(layout_builder *b, const char *name, int group, int ndim,
                int64_t d0, int64_t d1, int64_t d2)
{
    add_tensor(b, name, group, ndim, d0, d1, d2, 1);
}

static void add_mlp(layout_builder *b, const char *prefix, int nl,
                    const int *dims)
{
    char name[64];
    for (int l = 0; l < nl; l++) {
        snprintf(name, sizeof name, "%s.l%d.weight", prefix, l);
        add(b, name, GS_PG_MLP, 2, dims[l + 1], dims[l], 0);
        snprintf(name, sizeof name, "%s.l%d.bias", prefix, l);
        add(b, name, GS_PG_MLP, 1, dims[l + 1], 0, 0);
    }
}

static void mlp_dims(const gs_model_config *c, int which, int *nl, int *d)
{
    int C = c->channels, F = c->feat_dim, H = c->hidden;
    int D = gs_model_code_dim(c);
    switch (which) {
    case 0: /* face_e */
        *nl = 3; d[0] = F + D; d[1] = H; d[2] = H; d[3] = GS_FACE_OUT(C);
        break;
    case 1: /* face_p: in the single-stream ablation it also sees gaze */
        *nl = 2;
        d[0] = F + GS_PE_DIM(3) + (c->two_stream ? 0 : GS_PE_DIM(2));
        d[1] = H; d[2] = GS_FACE_OUT(C);
        break;
    case 2: /* eye */
        *nl = 3; d[0] = F + D + GS_PE_DIM(2); d[1] = H; d[2] = H;
        d[3] = GS_EYE_OUT(C);
        break;
    default: /* eye_rot */
        *nl = 2; d[0] = GS_PE_DIM(2); d[1] = 32; d[2] = 4;
        break;
    }
}

int gs_model_alloc(const gs_model_config *cfg, const char *what, gs_model **out,
                   gs_error *err)
{
    *out = NULL;
    gs_model *m = calloc(1, sizeof *m);
    int rc = m ? gs_model_layout(cfg, m, err)
               : gs_error_set(err, GS_ERR_NOMEM, "%s: out of memory", what);
    if (!rc && !(m->params = calloc(m->nparams, sizeof(float))))
        rc = gs_error_set(err, GS_ERR_NOMEM, "%s: out of memory", what);
    if (rc) {
        gs_model_destroy(m);
        return rc;
    }
    *out = m;
    return GS_OK;
}

const gs_ptensor *gs_model_find_tensor(const gs_model *m, const char *name)
{
    for (int j = 0; j < m->ntensors; j++)
        if (!strcmp(m->t[j].name, name))
            return &m->t[j];
    return NULL;
}

int gs_model_layout(const gs_model_config *cfg, gs_model *m, gs_error *err)
{
    int rc = gs_model_config_check(cfg, err);
    if (rc)
        return rc;
    m->cfg = *cfg;
    m->ntensors = 0;
    layout_builder b = {m, 0, 0};
    int C = cfg->channels, F = cfg->feat_dim, D = gs_model_code_dim(cfg);
    int64_t nf = cfg->n_face, ne = 2 * (int64_t)cfg->n_eye_each;

    add(&b, "face.xyz", GS_PG_GAUSS_XYZ, 2, nf, 3, 0);
    add(&b, "face.log_scale", GS_PG_GAUSS_ATTR, 2, nf, 3, 0);
    add(&b, "face.quat", GS_PG_GAUSS_ATTR, 2, nf, 4, 0);
    add(&b, "face.opacity", GS_PG_GAUSS_ATTR, 1, nf, 0, 0);
    add(&b, "face.colour", GS_PG_GAUSS_FEAT, 2, nf, C, 0);
    add(&b, "face.feat", GS_PG_GAUSS_FEAT, 2, nf, F, 0);
    add(&b, "face.lambda", GS_PG_FIXED, 1, nf, 0, 0);
    if (gs_model_n_lid(cfg)) {
        add(&b, "face.lid_k", GS_PG_GAUSS_XYZ, 3, 2, GS_LID_NV, GS_LID_NU);
        add(&b, "face.lid_uv", GS_PG_FIXED, 2, gs_model_n_lid(cfg), 2, 0);
    }
    add(&b, "eye.xyz", GS_PG_GAUSS_XYZ, 2, ne, 3, 0);
    add(&b, "eye.log_scale", GS_PG_GAUSS_ATTR, 1, ne, 0, 0);
    add(&b, "eye.opacity", GS_PG_GAUSS_ATTR, 1, ne, 0, 0);
    add(&b, "eye.colour", GS_PG_GAUSS_FEAT, 2, ne, C, 0);
    add(&b, "eye.feat", GS_PG_GAUSS_FEAT, 2, ne, F, 0);
    add(&b, "eye.centre", GS_PG_FIXED, 2, 2, 3, 0);
    add(&b, "eye.centre_w", GS_PG_MLP, 3, 2, 3, D);

    static const char *names[] = {"mlp.face_e", "mlp.face_p", "mlp.eye",
                                  "mlp.eye_rot0", "mlp.eye_rot1"};
    for (int k = 0; k < 5; k++) {
        int nl, d[5];
        mlp_dims(cfg, k < 3 ? k : 3, &nl, d);
        add_mlp(&b, names[k], nl, d);
    }

    m->rcfg.channels = C;
    m->rcfg.code_dim = D;
    m->rcfg.guidance = cfg->guidance;
    m->rcfg.guide_source = cfg->guide_source;
    m->rcfg.blocks = GS_RENDERER_BLOCKS;
    rc = gs_renderer_config_validate(&m->rcfg, err);
    if (rc)
        return rc;
    /* The renderer's tensors, packed in its own order so that one
     * gs_renderer_bind over the block carves them. */
    size_t r_begin = b.off;
    gs_renderer_tensor rt[GS_RENDERER_MAX_TENSORS];
    int nr = 0;
    gs_renderer_layout(&m->rcfg, rt, GS_RENDERER_MAX_TENSORS, &nr);
    for (int i = 0; i < nr; i++)
        add_tensor(&b, rt[i].name, GS_PG_RENDERER, rt[i].rank, rt[i].shape[0],
                   rt[i].rank > 1 ? rt[i].shape[1] : 0, 0, 0);
    if (b.off - r_begin != gs_renderer_param_count(&m->rcfg))
        return gs_error_set(err, GS_ERR_STATE, "model: renderer layout");
    b.off = (b.off + 15) & ~(size_t)15;
    m->rend_offset = r_begin;
    if (cfg->n_train_ids > 0)
        add(&b, "codes.train", GS_PG_CODES, 2, cfg->n_train_ids,
            cfg->id_dim, 0);
    add(&b, "codes.mean", GS_PG_FIXED, 1, D, 0, 0);
    if (b.overflow)
        return gs_error_set(err, GS_ERR_LIMIT, "model: too many tensors");
    m->nparams = b.off;
    return GS_OK;
}

static float *at(const gs_model *m, float *base, const char *name)
{
    const gs_ptensor *t = gs_model_find_tensor(m, name);
    return t ? base + t->offset : NULL;
}

static void bind_mlp(const gs_model *m, float *base, const char *prefix,
                     int which, gs_mlp *out)
{
    char name[64];
    mlp_dims(&m->cfg, which, &out->nl, out->dims);
    for (int l = 0; l < out->nl; l++) {
        snprintf(name, sizeof name, "%s.l%d.weight", prefix, l);
        out->w[l] = at(m, base, name);
        snprintf(name, sizeof name, "%s.l%d.bias", prefix, l);
        out->b[l] = at(m, base, name);
    }
}

void gs_model_bind(const gs_model *m, float *base, gs_model_params *p)
{
    memset(p, 0, sizeof *p);
    p->f_xyz = at(m, base, "face.xyz");
    p->f_scale = at(m, base, "face.log_scale");
    p->f_quat = at(m, base, "face.quat");
    p->f_opacity = at(m, base, "face.opacity");
    p->f_colour = at(m, base, "face.colour");
    p->f_feat = at(m, base, "face.feat");
    p->f_lambda = at(m, base, "face.lambda");
    p->lid_k = at(m, base, "face.lid_k");
    p->lid_uv = at(m, base, "face.lid_uv");
    p->e_xyz = at(m, base, "eye.xyz");
    p->e_scale = at(m, base, "eye.log_scale");
    p->e_opacity = at(m, base, "eye.opacity");
    p->e_colour = at(m, base, "eye.colour");
    p->e_feat = at(m, base, "eye.feat");
    p->eye_centre = at(m, base, "eye.centre");
    p->eye_centre_w = at(m, base, "eye.centre_w");
    bind_mlp(m, base, "mlp.face_e", 0, &p->face_e);
    bind_mlp(m, base, "mlp.face_p", 1, &p->face_p);
    bind_mlp(m, base, "mlp.eye", 2, &p->eye);
    bind_mlp(m, base, "mlp.eye_rot0", 3, &p->eye_rot[0]);
    bind_mlp(m, base, "mlp.eye_rot1", 3, &p->eye_rot[1]);
    gs_renderer_bind(&m->rcfg, base + m->rend_offset,
                     gs_renderer_param_count(&m->rcfg), &p->rend);
    p->codes = at(m, base, "codes.train");
    p->code_mean = at(m, base, "codes.mean");
}

/* ---- destruction, parameter ids, tensor parts and layouts: owned here with
 * allocation and binding ---- */

void gs_model_destroy(gs_model *m)
{
    if (!m)
        return;
    free(m->params);
    free(m);
}

uint64_t gs_model_param_id(const gs_model *m)
{
    hash64 h;
    hash_init(&h, 0x67617a6573706c74ULL);
    /* Per tensor a 128-byte record (whole blocks): its name (zero-padded),
     * offset, count and the hash of its values. The alignment padding
     * between tensors is not part of the model and not hashed. */
    for (int i = 0; i < m->ntensors; i++) {
        const gs_ptensor *t = &m->t[i];
        uint8_t rec[128];
        memset(rec, 0, sizeof rec);
        size_t nl = 0;
        while (nl < sizeof t->name - 1 && t->name[nl])
            nl++;
        memcpy(rec, t->name, nl);
        hash64 v;
        hash_init(&v, 0x76616c756573ULL);
        hash_bytes(&v, m->params + t->offset, t->count * sizeof(float));
        uint64_t f[3] = {t->offset, t->count, hash_final(&v)};
        memcpy(rec + 64, f, sizeof f);
        hash_bytes(&h, rec, sizeof rec);
    }
    return hash_final(&h);
}

unsigned gs_model_tensor_part(const gs_ptensor *t)
{
    const char *n = t->name;
    /* codes, fixed tensors, and the lids' share of the pitch: one image
     * shows one pitch, and k is how the lids follow a change of it */
    if (t->group == GS_PG_CODES || t->group == GS_PG_FIXED ||
        !strcmp(n, "face.lid_k"))
        return 0;
    if (!strcmp(n, "face.colour") || !strcmp(n, "face.feat"))
        return GS_FT_FACE;
    if (!strcmp(n, "eye.colour") || !strcmp(n, "eye.feat"))
        return GS_FT_EYE;
    if (t->group == GS_PG_RENDERER)
        return GS_FT_RENDERER;
    if (t->group == GS_PG_MLP)
        return GS_FT_MLP;
    /* xyz, scales, rotations, opacities; the face stream's (lids included)
     * belong to face-geometry too */
    if (!strncmp(n, "face.", 5))
        return GS_FT_GEOMETRY | GS_FT_FACE_GEOMETRY;
    return GS_FT_GEOMETRY;
}

int gs_model_same_layout(const gs_model *a, const gs_model *b)
{
    if (a->nparams != b->nparams || a->ntensors != b->ntensors)
        return 0;
    for (int i = 0; i < a->ntensors; i++)
        if (a->t[i].offset != b->t[i].offset || a->t[i].count != b->t[i].count ||
            strcmp(a->t[i].name, b->t[i].name))
            return 0;
    return 1;
}
