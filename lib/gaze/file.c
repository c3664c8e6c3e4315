/* Estimator files: safetensors, one F32 tensor per weight and bias, the
 * spec in __metadata__ (format, format_version, arch, input_size, widths,
 * hidden). The loader accepts exactly the tensors the spec implies. */
#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "gazesplat/safetensors.h"
#include "gaze_internal.h"

static int write_meta(gs_st_writer *w, const gs_gaze_spec *s)
{
    char v[96];
    int rc = gs_st_writer_meta(w, "format", GS_GAZE_FORMAT_NAME);
    snprintf(v, sizeof v, "%d", GS_GAZE_FORMAT_VERSION);
    rc = rc ? rc : gs_st_writer_meta(w, "format_version", v);
    rc = rc ? rc : gs_st_writer_meta(w, "arch", gs_gaze_arch_name(s->arch));
    snprintf(v, sizeof v, "%d", s->input_size);
    rc = rc ? rc : gs_st_writer_meta(w, "input_size", v);
    snprintf(v, sizeof v, "%d,%d,%d,%d", s->widths[0], s->widths[1], s->widths[2],
             s->widths[3]);
    rc = rc ? rc : gs_st_writer_meta(w, "widths", v);
    snprintf(v, sizeof v, "%d", s->hidden);
    rc = rc ? rc : gs_st_writer_meta(w, "hidden", v);
    return rc;
}

static int make_writer(const gs_gaze_net *n, gs_st_writer **out, gs_error *err)
{
    gs_st_writer *w = gs_st_writer_create();
    if (!w)
        return gs_error_set(err, GS_ERR_NOMEM, "gaze save: out of memory");
    int rc = write_meta(w, &n->spec);
    if (rc)
        gs_error_set(err, rc, "gaze save: metadata: %s", gs_strerror(rc));
    for (int i = 0; i < n->g.ntensors && !rc; i++) {
        const gz_tensor *t = &n->g.t[i];
        rc = gs_st_writer_add(w, t->name, GS_ST_F32, t->ndim, t->shape, n->params + t->off);
        if (rc)
            gs_error_set(err, rc, "gaze save: tensor %s: %s", t->name, gs_strerror(rc));
    }
    if (rc) {
        gs_st_writer_destroy(w);
        return rc;
    }
    *out = w;
    return GS_OK;
}

int gs_gaze_net_save(const gs_gaze_net *n, const char *path, gs_error *err)
{
    if (!n || !path)
        return gs_error_set(err, GS_ERR_ARG, "gaze save: NULL argument");
    gs_st_writer *w = NULL;
    int rc = make_writer(n, &w, err);
    if (!rc)
        rc = gs_st_writer_save(w, path, err);
    gs_st_writer_destroy(w);
    return rc;
}

/* A decimal int in [lo, hi] with nothing after it. */
static int parse_int(const char *s, int lo, int hi, int *out)
{
    if (!s || !*s)
        return -1;
    char *end = NULL;
    errno = 0;
    long v = strtol(s, &end, 10);
    if (errno || *end || v < lo || v > hi)
        return -1;
    *out = (int)v;
    return 0;
}

/* "a,b,c,d": GS_GAZE_STAGES ints in 1..512. */
static int parse_widths(const char *s, int *w)
{
    char buf[96];
    if (!s || strlen(s) >= sizeof buf)
        return -1;
    strcpy(buf, s);
    char *p = buf;
    for (int i = 0; i < GS_GAZE_STAGES; i++) {
        char *comma = strchr(p, ',');
        if ((i < GS_GAZE_STAGES - 1) != (comma != NULL))
            return -1;
        if (comma)
            *comma = '\0';
        if (parse_int(p, 1, 512, &w[i]))
            return -1;
        p = comma ? comma + 1 : p;
    }
    return 0;
}

static int read_spec(const gs_st_file *f, gs_gaze_spec *s, gs_error *err)
{
    const char *fmt = gs_st_meta(f, "format");
    if (!fmt || strcmp(fmt, GS_GAZE_FORMAT_NAME) != 0)
        return gs_error_set(err, GS_ERR_FORMAT, "gaze: not a gaze estimator (format %.40s)",
                            fmt ? fmt : "missing");
    const char *ver = gs_st_meta(f, "format_version");
    int v;
    if (parse_int(ver, 0, 1000000, &v) || v != GS_GAZE_FORMAT_VERSION)
        return gs_error_set(err, GS_ERR_UNSUPPORTED,
                            "gaze: format version %.20s, this build reads %d",
                            ver ? ver : "missing", GS_GAZE_FORMAT_VERSION);
    memset(s, 0, sizeof *s);
    const char *arch = gs_st_meta(f, "arch");
    s->arch = gs_gaze_arch_from_name(arch);
    if (s->arch < 0)
        return gs_error_set(err, GS_ERR_FORMAT, "gaze: arch '%.40s'",
                            arch ? arch : "missing");
    const char *in = gs_st_meta(f, "input_size"), *w = gs_st_meta(f, "widths"),
               *h = gs_st_meta(f, "hidden");
    if (parse_int(in, 1, 1 << 20, &s->input_size))
        return gs_error_set(err, GS_ERR_FORMAT, "gaze: input_size '%.40s'", in ? in : "missing");
    if (parse_widths(w, s->widths))
        return gs_error_set(err, GS_ERR_FORMAT, "gaze: widths '%.40s'", w ? w : "missing");
    if (parse_int(h, 1, 1 << 20, &s->hidden))
        return gs_error_set(err, GS_ERR_FORMAT, "gaze: hidden '%.40s'", h ? h : "missing");
    gs_error e;
    if (gz_spec_check(s, &e))
        return gs_error_set(err, GS_ERR_FORMAT, "%s (in the file)", e.msg);
    return GS_OK;
}

static int load_from(gs_st_file *f, gs_gaze_net **out, gs_error *err)
{
    gs_gaze_spec s;
    gs_gaze_net *n = NULL;
    int rc = read_spec(f, &s, err);
    if (!rc)
        rc = gz_net_alloc(&s, &n, err);
    for (int i = 0; !rc && i < n->g.ntensors; i++) {
        const gz_tensor *t = &n->g.t[i];
        const float *data = NULL;
        rc = gs_st_get_f32(f, t->name, t->ndim, t->shape, &data, err);
        if (!rc)
            memcpy(n->params + t->off, data, t->count * sizeof(float));
    }
    if (!rc && gs_st_count(f) != n->g.ntensors)
        rc = gs_error_set(err, GS_ERR_FORMAT, "gaze: %d tensors in the file, %d expected",
                          gs_st_count(f), n->g.ntensors);
    if (rc) {
        gs_gaze_net_destroy(n);
        return rc;
    }
    *out = n;
    return GS_OK;
}

int gs_gaze_net_load(const char *path, gs_gaze_net **out, gs_error *err)
{
    if (!path || !out)
        return gs_error_set(err, GS_ERR_ARG, "gaze load: NULL argument");
    gs_st_file *f = NULL;
    int rc = gs_st_open(path, NULL, &f, err);
    if (!rc)
        rc = load_from(f, out, err);
    gs_st_close(f);
    return rc;
}

int gs_gaze_net_load_mem(const void *buf, size_t len, gs_gaze_net **out, gs_error *err)
{
    if (!buf || !out)
        return gs_error_set(err, GS_ERR_ARG, "gaze load: NULL argument");
    gs_st_file *f = NULL;
    int rc = gs_st_open_mem(buf, len, NULL, &f, err);
    if (!rc)
        rc = load_from(f, out, err);
    gs_st_close(f);
    return rc;
}
