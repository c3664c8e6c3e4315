/* Pruning the face stream: fewer Gaussians, a faster render.
 *
 * Importance of a face Gaussian i: sum over a few normalized views v and
 * feature pixels p of T_i,p alpha_i,p, its blending weight (the share of
 * pixel p's feature it supplies). Why this and not sigmoid(opacity) x
 * projected area: the weight counts occlusion (a Gaussian under the skin's
 * outer layer, or on the back of the head, supplies nothing however opaque
 * and large it is) and the footprint at the resolution the model renders
 * at, in the views it is used for; and it comes exactly from the
 * rasterizer: d(sum_p out_p) / d feature_i = sum_p T_i,p alpha_i,p, one
 * backward with a gradient of ones on one channel. The eye stream is
 * rasterized too (it hides the face Gaussians behind the eyeballs) and
 * always kept. */
#include <stdlib.h>
#include <string.h>

#include "frame.h"
#include "gazesplat/geom.h"

/* Head pitch and yaw of the views (radians): the training range's
 * centre and corners (docs/model.md). */
static const double k_pitch[3] = {-0.2618, 0.0, 0.2618}; /* +-15 deg */
static const double k_yaw[3] = {-0.5236, 0.0, 0.5236};   /* +-30 deg */

/* Adds the face Gaussians' blending weights of one view into imp. */
static int view_weights(gs_model_ctx *c, gs_pool *pool, const gs_frame *fr,
                        float *ones, double *imp, gs_error *err)
{
    int rc = gs_frame_forward(c, pool, fr, GS_STREAM_BOTH, 1, err);
    if (rc)
        return rc;
    gs_frame_clear_gaussian_grads(c);
    gs_gaussian_grads gg = {c->v_mean, c->v_scale, c->v_quat, c->v_opac,
                            c->v_feat};
    rc = gs_raster_backward(c->raster, pool, ones, NULL, NULL, &gg, NULL,
                            err);
    if (rc)
        return rc;
    for (int i = 0; i < c->nf; i++) /* channel 0's feature gradient */
        imp[i] += c->v_feat[(size_t)i * c->C];
    return GS_OK;
}

int gs_model_face_importance(const gs_model *m, gs_pool *pool, double *out,
                             gs_error *err)
{
    if (!m || !out)
        return gs_error_set(err, GS_ERR_ARG, "importance: NULL argument");
    gs_model_ctx *c = gs_model_ctx_create(m);
    size_t fsz = (size_t)m->cfg.feat_size * m->cfg.feat_size;
    /* d out / d features: ones on channel 0, zero on the others */
    float *ones = calloc(fsz * m->cfg.channels, sizeof(float));
    if (!c || !ones) {
        gs_model_ctx_destroy(c);
        free(ones);
        return gs_error_set(err, GS_ERR_NOMEM, "importance: out of memory");
    }
    for (size_t i = 0; i < fsz; i++)
        ones[i] = 1.0f;
    memset(out, 0, (size_t)m->cfg.n_face * sizeof(double));
    gs_frame fr;
    memset(&fr, 0, sizeof fr);
    memcpy(fr.code, m->p.code_mean,
           (size_t)gs_model_code_dim(&m->cfg) * sizeof(float));
    fr.head_t[2] = m->cfg.d_n_mm;
    int rc = GS_OK;
    for (int v = 0; v < GS_MODEL_PRUNE_VIEWS && !rc; v++) {
        double ry[9], rx[9];
        gs_geom_rot_y(k_yaw[v % 3], ry);
        gs_geom_rot_x(k_pitch[v / 3], rx);
        gs_geom_mat3_mul(ry, rx, fr.head_R);
        rc = view_weights(c, pool, &fr, ones, out, err);
    }
    gs_model_ctx_destroy(c);
    free(ones);
    return rc;
}

typedef struct ranked {
    double imp;
    int index;
} ranked;

/* Most important first; ties by index (a total order: qsort's result is
 * unique). */
static int by_importance(const void *a, const void *b)
{
    const ranked *x = a, *y = b;
    if (x->imp != y->imp)
        return x->imp > y->imp ? -1 : 1;
    return (x->index > y->index) - (x->index < y->index);
}

/* keep[i] = 1 for the k most important face Gaussians. */
static int choose(const gs_model *m, gs_pool *pool, int k, unsigned char *keep,
                  gs_error *err)
{
    int n = m->cfg.n_face;
    double *imp = malloc((size_t)n * sizeof *imp);
    ranked *r = malloc((size_t)n * sizeof *r);
    int rc = imp && r ? GS_OK
                      : gs_error_set(err, GS_ERR_NOMEM, "prune: out of memory");
    if (!rc)
        rc = gs_model_face_importance(m, pool, imp, err);
    if (!rc) { /* lids (the last ones) are always kept, like the eyes */
        int nm = n - gs_model_n_lid(&m->cfg);
        for (int i = 0; i < nm; i++)
            r[i] = (ranked){imp[i], i};
        qsort(r, (size_t)nm, sizeof *r, by_importance);
        memset(keep, 0, (size_t)n);
        for (int i = 0; i < k - (n - nm); i++)
            keep[r[i].index] = 1;
        memset(keep + nm, 1, (size_t)(n - nm));
    }
    free(imp);
    free(r);
    return rc;
}

/* The pruned model's tensors from m's: face rows where keep is set. */
static void copy_tensors(const gs_model *m, const unsigned char *keep,
                         gs_model *o)
{
    for (int t = 0; t < o->ntensors; t++) {
        const gs_ptensor *d = &o->t[t], *s = &m->t[t]; /* same table order */
        float *dst = o->params + d->offset;
        const float *src = m->params + s->offset;
        if (strncmp(d->name, "face.", 5) != 0 ||
            !strncmp(d->name, "face.lid_", 9)) { /* lids: all kept */
            memcpy(dst, src, s->count * sizeof(float));
            continue;
        }
        size_t row = s->count / (size_t)m->cfg.n_face;
        for (int i = 0; i < m->cfg.n_face; i++)
            if (!keep || keep[i]) {
                memcpy(dst, src + (size_t)i * row, row * sizeof(float));
                dst += row;
            }
    }
}

int gs_model_prune(const gs_model *m, gs_pool *pool, int keep_face,
                   gs_model **out, gs_error *err)
{
    if (!m || !out)
        return gs_error_set(err, GS_ERR_ARG, "prune: NULL argument");
    if (keep_face < 1)
        return gs_error_set(err, GS_ERR_ARG,
                            "prune: keep %d face Gaussians (want >= 1)",
                            keep_face);
    int n = m->cfg.n_face, k = keep_face < n ? keep_face : n;
    int nl = gs_model_n_lid(&m->cfg);
    if (k < nl + 1) /* the lids and at least one other */
        k = nl + 1 < n ? nl + 1 : n;
    unsigned char *keep = NULL;
    if (k < n) {
        keep = malloc((size_t)n);
        if (!keep)
            return gs_error_set(err, GS_ERR_NOMEM, "prune: out of memory");
        int rc = choose(m, pool, k, keep, err);
        if (rc) {
            free(keep);
            return rc;
        }
    }
    gs_model_config cfg = m->cfg;
    cfg.n_face = k;
    gs_model *o = NULL;
    int rc = gs_model_alloc(&cfg, "prune", &o, err);
    if (!rc && o->ntensors != m->ntensors)
        rc = gs_error_set(err, GS_ERR_STATE, "prune: tensor tables differ");
    if (rc) {
        free(keep);
        gs_model_destroy(o);
        return rc;
    }
    o->rcfg = m->rcfg;
    copy_tensors(m, keep, o);
    gs_model_bind(o, o->params, &o->p);
    if (k < n) {
        o->id = gs_model_param_id(o);
    } else { /* a clone: the same parameters, tuned or not */
        o->id = m->id;
        o->tuned = m->tuned;
    }
    free(keep);
    *out = o;
    return GS_OK;
}

int gs_model_clone(const gs_model *m, gs_model **out, gs_error *err)
{
    if (!m || !out)
        return gs_error_set(err, GS_ERR_ARG, "clone: NULL argument");
    /* Keeping every face Gaussian copies each tensor whole (no scores). */
    return gs_model_prune(m, NULL, m->cfg.n_face, out, err);
}

int gs_model_copy_params(gs_model *dst, const gs_model *src, gs_error *err)
{
    if (!dst || !src)
        return gs_error_set(err, GS_ERR_ARG, "copy params: NULL argument");
    if (!gs_model_same_layout(dst, src))
        return gs_error_set(err, GS_ERR_ARG,
                            "copy params: the models' layouts differ");
    memcpy(dst->params, src->params, src->nparams * sizeof(float));
    dst->id = src->id;
    dst->tuned = src->tuned;
    return GS_OK;
}
