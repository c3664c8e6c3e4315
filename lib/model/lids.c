/* Lids that follow the gaze (docs/model.md): a model's face Gaussians
 * around each eyeball made into lids. */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "model_internal.h"

/* The eye (0, 1) whose rest centre lies within r of face Gaussian i, the
 * nearer one; -1 when none does. */
static int lid_eye(const gs_model *m, int i, double r)
{
    const float *x = m->p.f_xyz + 3 * (size_t)i, *c = m->p.eye_centre;
    double best = r * r;
    int e = -1;
    for (int k = 0; k < 2; k++) {
        double d = 0;
        for (int j = 0; j < 3; j++) {
            double t = (double)x[j] - c[3 * k + j];
            d += t * t;
        }
        if (d < best)
            best = d, e = k;
    }
    return e;
}

int gs_model_add_lids(const gs_model *m, double radius_mm, gs_model **out,
                      gs_error *err)
{
    if (!m || !out)
        return gs_error_set(err, GS_ERR_ARG, "lids: NULL argument");
    if (!m->cfg.two_stream || !m->cfg.eye_rotation)
        return gs_error_set(err, GS_ERR_ARG,
                            "lids: the model needs two streams and explicit "
                            "eye rotation");
    if (gs_model_n_lid(&m->cfg))
        return gs_error_set(err, GS_ERR_ARG, "lids: the model has lids");
    if (!(radius_mm > 0.0 && radius_mm < 100.0))
        return gs_error_set(err, GS_ERR_ARG, "lids: radius %g mm", radius_mm);
    int n = m->cfg.n_face;
    int *order = malloc((size_t)n * sizeof *order);
    signed char *eye = malloc((size_t)n);
    if (!order || !eye) {
        free(order);
        free(eye);
        return gs_error_set(err, GS_ERR_NOMEM, "lids: out of memory");
    }
    int cnt[2] = {0, 0}, k = 0;
    for (int i = 0; i < n; i++) {
        eye[i] = (signed char)lid_eye(m, i, radius_mm);
        if (eye[i] < 0)
            order[k++] = i;
        else
            cnt[(int)eye[i]]++;
    }
    for (int e = 0; e < 2; e++)
        for (int i = 0; i < n; i++)
            if (eye[i] == e)
                order[k++] = i;
    free(eye);
    gs_model_config cfg = m->cfg;
    cfg.n_lid0 = cnt[0];
    cfg.n_lid1 = cnt[1];
    gs_model *o = NULL;
    int rc = gs_model_alloc(&cfg, "lids", &o, err);
    for (int t = 0; !rc && t < o->ntensors; t++) {
        const gs_ptensor *d = &o->t[t];
        if (!strncmp(d->name, "face.lid_", 9))
            continue; /* k 0: the lids start where they were; places below */
        const gs_ptensor *s = gs_model_find_tensor(m, d->name);
        if (!s || s->count != d->count) {
            rc = gs_error_set(err, GS_ERR_STATE, "lids: tensor %s", d->name);
            break;
        }
        float *dst = o->params + d->offset;
        const float *src = m->params + s->offset;
        if (strncmp(d->name, "face.", 5) != 0) {
            memcpy(dst, src, s->count * sizeof(float));
            continue;
        }
        size_t row = s->count / (size_t)n;
        for (int i = 0; i < n; i++)
            memcpy(dst + (size_t)i * row, src + (size_t)order[i] * row,
                   row * sizeof(float));
    }
    free(order);
    if (rc) {
        gs_model_destroy(o);
        return rc;
    }
    o->rcfg = m->rcfg;
    gs_model_bind(o, o->params, &o->p);
    for (int j = 0; j < cnt[0] + cnt[1]; j++) { /* grid places */
        int i = n - cnt[0] - cnt[1] + j, e = j < cnt[0] ? 0 : 1;
        const float *x = o->p.f_xyz + 3 * (size_t)i, *c = m->p.eye_centre + 3 * e;
        double r[3] = {(double)x[0] - c[0], (double)x[1] - c[1], (double)x[2] - c[2]};
        double az = atan2(r[0], -r[2]) * 180.0 / GS_MODEL_PI;
        double el = atan2(-r[1], -r[2]) * 180.0 / GS_MODEL_PI;
        az = az < -90 ? -90 : az > 90 ? 90 : az;
        el = el < -90 ? -90 : el > 90 ? 90 : el;
        o->p.lid_uv[2 * j] = (float)((az + 90.0) / GS_LID_DU_DEG);
        o->p.lid_uv[2 * j + 1] = (float)((el + 90.0) / GS_LID_DV_DEG);
    }
    o->id = gs_model_param_id(o);
    *out = o;
    return GS_OK;
}

int gs_model_has_lids(const gs_model *m)
{
    return m && gs_model_n_lid(&m->cfg) > 0;
}
