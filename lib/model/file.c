/* Model files: safetensors with one F32 tensor per parameter tensor and the
 * configuration as __metadata__ strings ("format", "format_version",
 * "config.<field>"). docs/model.md lists every tensor. */
#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "gazesplat/safetensors.h"
#include "model_internal.h"

#define GS_MODEL_FORMAT_NAME "gazesplat-model"

typedef struct cfg_field {
    const char *key;
    int is_double;
    size_t off;
    int optional; /* added after format version 1 shipped */
    double dflt;  /* its value when absent (an int field: exact) */
} cfg_field;

#define I(f) {#f, 0, offsetof(gs_model_config, f), 0, 0}
#define D(f) {#f, 1, offsetof(gs_model_config, f), 0, 0}
#define OPT_I(f, v) {#f, 0, offsetof(gs_model_config, f), 1, v}
#define OPT_D(f, v) {#f, 1, offsetof(gs_model_config, f), 1, v}
static const cfg_field k_fields[] = {
    I(n_face), I(n_eye_each), I(feat_dim), I(id_dim), I(hidden),
    I(channels), I(feat_size), I(image_size), I(guidance), I(two_stream),
    I(eye_rotation), I(n_train_ids), D(template_spacing_mm), D(d_n_mm),
    D(focal), OPT_I(guide_source, GS_GUIDE_SRC_BLOCK), OPT_I(n_lid0, 0),
    OPT_I(n_lid1, 0), OPT_I(supersample, 1), OPT_I(eye_direct, 0),
    OPT_D(fit_code_prior, 0.0), OPT_D(fit_code_rate, 0.0)};
#undef I
#undef D
#undef OPT_I
#undef OPT_D
#define NFIELDS (int)(sizeof k_fields / sizeof k_fields[0])

static int write_meta(gs_st_writer *w, const gs_model_config *c)
{
    char key[64], val[64];
    int rc = gs_st_writer_meta(w, "format", GS_MODEL_FORMAT_NAME);
    snprintf(val, sizeof val, "%d", GS_MODEL_FORMAT_VERSION);
    rc = rc ? rc : gs_st_writer_meta(w, "format_version", val);
    for (int i = 0; i < NFIELDS && !rc; i++) {
        const unsigned char *base = (const unsigned char *)c + k_fields[i].off;
        if (k_fields[i].is_double) {
            double d;
            memcpy(&d, base, sizeof d);
            snprintf(val, sizeof val, "%.17g", d);
        } else {
            int x;
            memcpy(&x, base, sizeof x);
            snprintf(val, sizeof val, "%d", x);
        }
        snprintf(key, sizeof key, "config.%s", k_fields[i].key);
        rc = gs_st_writer_meta(w, key, val);
    }
    return rc;
}

int gs_model_save(const gs_model *m, const char *path, gs_error *err)
{
    gs_st_writer *w = gs_st_writer_create();
    if (!w)
        return gs_error_set(err, GS_ERR_NOMEM, "model save: out of memory");
    int rc = write_meta(w, &m->cfg);
    for (int i = 0; i < m->ntensors && !rc; i++) {
        const gs_ptensor *t = &m->t[i];
        rc = gs_st_writer_add(w, t->name, GS_ST_F32, t->ndim, t->shape,
                              m->params + t->offset);
        if (rc)
            gs_error_set(err, rc, "model save: tensor %s: %s", t->name,
                         gs_strerror(rc));
    }
    if (!rc)
        rc = gs_st_writer_save(w, path, err);
    gs_st_writer_destroy(w);
    return rc;
}

static int read_config(const gs_st_file *f, gs_model_config *c,
                       gs_error *err)
{
    const char *fmt = gs_st_meta(f, "format");
    if (!fmt || strcmp(fmt, GS_MODEL_FORMAT_NAME) != 0)
        return gs_error_set(err, GS_ERR_FORMAT,
                            "model: not a gazesplat model (format %s)",
                            fmt ? fmt : "missing");
    const char *ver = gs_st_meta(f, "format_version");
    if (!ver || strtol(ver, NULL, 10) != GS_MODEL_FORMAT_VERSION)
        return gs_error_set(err, GS_ERR_UNSUPPORTED,
                            "model: format version %s, this build reads %d",
                            ver ? ver : "missing", GS_MODEL_FORMAT_VERSION);
    memset(c, 0, sizeof *c);
    for (int i = 0; i < NFIELDS; i++) {
        char key[64];
        snprintf(key, sizeof key, "config.%s", k_fields[i].key);
        const char *v = gs_st_meta(f, key);
        unsigned char *base = (unsigned char *)c + k_fields[i].off;
        if (!v && k_fields[i].optional) {
            if (k_fields[i].is_double) {
                memcpy(base, &k_fields[i].dflt, sizeof(double));
            } else {
                int x = (int)k_fields[i].dflt;
                memcpy(base, &x, sizeof x);
            }
            continue;
        }
        if (!v || !*v)
            return gs_error_set(err, GS_ERR_FORMAT, "model: %s missing", key);
        char *end = NULL;
        errno = 0;
        if (k_fields[i].is_double) {
            double d = strtod(v, &end);
            memcpy(base, &d, sizeof d);
        } else {
            long x = strtol(v, &end, 10);
            if (x < -1000000000L || x > 1000000000L)
                errno = ERANGE;
            int xi = (int)x;
            memcpy(base, &xi, sizeof xi);
        }
        if (errno || *end)
            return gs_error_set(err, GS_ERR_FORMAT, "model: %s = '%.40s'",
                                key, v);
    }
    return gs_model_config_check(c, err);
}

static int load_from(gs_st_file *f, gs_model **out, gs_error *err)
{
    int rc;
    gs_model_config cfg;
    gs_model *m = NULL;
    rc = read_config(f, &cfg, err);
    if (!rc)
        rc = gs_model_alloc(&cfg, "model", &m, err);
    for (int i = 0; !rc && i < m->ntensors; i++) {
        const gs_ptensor *t = &m->t[i];
        const float *data = NULL;
        rc = gs_st_get_f32(f, t->name, t->ndim, t->shape, &data, err);
        if (!rc)
            memcpy(m->params + t->offset, data, t->count * sizeof(float));
    }
    if (!rc && gs_st_count(f) != m->ntensors)
        rc = gs_error_set(err, GS_ERR_FORMAT,
                          "model: %d tensors in the file, %d expected",
                          gs_st_count(f), m->ntensors);
    if (rc) {
        gs_model_destroy(m);
        return rc;
    }
    gs_model_bind(m, m->params, &m->p);
    m->id = gs_model_param_id(m);
    *out = m;
    return GS_OK;
}

int gs_model_load(const char *path, gs_model **out, gs_error *err)
{
    if (!path || !out)
        return gs_error_set(err, GS_ERR_ARG, "model load: NULL argument");
    gs_st_file *f = NULL;
    int rc = gs_st_open(path, NULL, &f, err);
    if (rc)
        return rc;
    rc = load_from(f, out, err);
    gs_st_close(f);
    return rc;
}

int gs_model_load_mem(const void *buf, size_t len, gs_model **out,
                      gs_error *err)
{
    if (!buf || !out)
        return gs_error_set(err, GS_ERR_ARG, "model load: NULL argument");
    gs_st_file *f = NULL;
    int rc = gs_st_open_mem(buf, len, NULL, &f, err);
    if (rc)
        return rc;
    rc = load_from(f, out, err);
    gs_st_close(f);
    return rc;
}
