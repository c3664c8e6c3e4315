/* 3DGS .ply reader and writer (see ply.h for the format).
 *
 * The reader parses the ASCII header into a table of properties, maps each
 * known property name to a (field, index) slot of the scene, checks the
 * whole layout and the data size against the limits and the input length,
 * and only then allocates. The data are decoded column by column through
 * the same slot table the writer uses, so the two cannot disagree. */
#define _POSIX_C_SOURCE 200809L /* fileno, fstat */

#include "gazesplat/ply.h"

#include <errno.h>
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

/* Slots of a scene a property can fill. */
enum ply_field { F_POS, F_NORMAL, F_DC, F_REST, F_OPACITY, F_SCALE, F_ROT, F_FEAT, F_COUNT };

#define PLY_MAX_REST 45 /* SH degree 3: 3 * (16 - 1) */
#define PLY_NAME_MAX 64
#define PLY_MAX_COLUMNS (3 + 3 + GS_RASTER_MAX_CHANNELS + 1 + 3 + 4 + PLY_MAX_REST)

static const int field_cap[F_COUNT] = {3, 3, 3, PLY_MAX_REST, 1, 3, 4, GS_RASTER_MAX_CHANNELS};
static const char *const field_prefix[F_COUNT] = {NULL,    NULL,    "f_dc_", "f_rest_",
                                                  NULL,    "scale_", "rot_", "feat_"};

/* f_rest count for each SH degree. */
static const int rest_for_degree[GS_PLY_MAX_SH_DEGREE + 1] = {0, 9, 24, 45};

static void field_name(int field, int idx, char *buf, size_t cap)
{
    static const char *const pos[3] = {"x", "y", "z"}, *const nrm[3] = {"nx", "ny", "nz"};
    if (field == F_POS)
        snprintf(buf, cap, "%s", pos[idx]);
    else if (field == F_NORMAL)
        snprintf(buf, cap, "%s", nrm[idx]);
    else if (field == F_OPACITY)
        snprintf(buf, cap, "opacity");
    else
        snprintf(buf, cap, "%s%d", field_prefix[field], idx);
}

/* Decimal index without sign or leading zeros; -1 if s is not one. */
static int parse_index(const char *s)
{
    int v = 0;
    if (!*s || (s[0] == '0' && s[1]) || strlen(s) > 4)
        return -1;
    for (; *s; s++) {
        if (*s < '0' || *s > '9')
            return -1;
        v = v * 10 + (*s - '0');
    }
    return v;
}

/* Maps a property name to its slot. Returns 1 (known, in range), 0
 * (unknown name), -1 (a known prefix with an index out of range). */
static int field_of(const char *name, int *field, int *idx)
{
    static const char *const exact[] = {"x", "y", "z", "nx", "ny", "nz", "opacity"};
    static const int exact_field[] = {F_POS, F_POS, F_POS, F_NORMAL, F_NORMAL, F_NORMAL, F_OPACITY};
    static const int exact_idx[] = {0, 1, 2, 0, 1, 2, 0};
    for (size_t i = 0; i < sizeof exact / sizeof exact[0]; i++) {
        if (strcmp(name, exact[i]) == 0) {
            *field = exact_field[i];
            *idx = exact_idx[i];
            return 1;
        }
    }
    for (int f = 0; f < F_COUNT; f++) {
        size_t plen = field_prefix[f] ? strlen(field_prefix[f]) : 0;
        if (!plen || strncmp(name, field_prefix[f], plen) != 0)
            continue;
        int k = parse_index(name + plen);
        if (k < 0)
            return 0;
        *field = f;
        *idx = k;
        return k < field_cap[f] ? 1 : -1;
    }
    return 0;
}

/* ---- scene memory ------------------------------------------------------- */

static float *scene_slot(const gs_ply_scene *s, int field, int *width)
{
    switch (field) {
    case F_POS: *width = 3; return s->means;
    case F_NORMAL: *width = 3; return s->normals;
    case F_DC: *width = 3; return s->f_dc;
    case F_REST: *width = s->n_rest; return s->f_rest;
    case F_OPACITY: *width = 1; return s->opacity_logits;
    case F_SCALE: *width = 3; return s->log_scales;
    case F_ROT: *width = 4; return s->quats;
    default: *width = s->channels; return s->features;
    }
}

/* One allocation; arrays carved out in a fixed order. */
static int scene_alloc(gs_ply_scene *s, gs_ply_kind kind, int n, int channels, int degree,
                       int with_normals, gs_error *err)
{
    gs_ply_scene t;
    memset(&t, 0, sizeof t);
    t.kind = kind;
    t.n = n;
    t.channels = channels;
    t.sh_degree = degree;
    t.n_rest = degree >= 0 ? rest_for_degree[degree] : 0; /* features: -1 */
    size_t per = 3 + 3 + 4 + 1 + (size_t)channels + (with_normals ? 3 : 0) +
                 (kind == GS_PLY_SH ? 3 + (size_t)t.n_rest : 0);
    size_t total = per * (size_t)n;
    float *p = calloc(total ? total : 1, sizeof(float));
    if (!p)
        return gs_error_set(err, GS_ERR_NOMEM, "ply: cannot allocate %d Gaussians", n);
    t.block = p;
    t.means = p;
    p += 3 * (size_t)n;
    if (with_normals) {
        t.normals = p;
        p += 3 * (size_t)n;
    }
    t.log_scales = p;
    p += 3 * (size_t)n;
    t.quats = p;
    p += 4 * (size_t)n;
    t.opacity_logits = p;
    p += (size_t)n;
    t.features = p;
    p += (size_t)channels * (size_t)n;
    if (kind == GS_PLY_SH) {
        t.f_dc = p;
        p += 3 * (size_t)n;
        t.f_rest = t.n_rest ? p : NULL;
    }
    *s = t;
    return GS_OK;
}

int gs_ply_alloc_sh(gs_ply_scene *s, int n, int sh_degree, int with_normals, gs_error *err)
{
    if (!s || n < 0 || sh_degree < 0 || sh_degree > GS_PLY_MAX_SH_DEGREE)
        return gs_error_set(err, GS_ERR_ARG, "ply: bad scene (n %d, SH degree %d)", n, sh_degree);
    return scene_alloc(s, GS_PLY_SH, n, 3, sh_degree, with_normals, err);
}

int gs_ply_alloc_features(gs_ply_scene *s, int n, int channels, int with_normals, gs_error *err)
{
    if (!s || n < 0 || channels < 1 || channels > GS_RASTER_MAX_CHANNELS)
        return gs_error_set(err, GS_ERR_ARG, "ply: bad scene (n %d, %d channels)", n, channels);
    return scene_alloc(s, GS_PLY_FEATURES, n, channels, -1, with_normals, err);
}

void gs_ply_free(gs_ply_scene *s)
{
    if (s) {
        free(s->block);
        memset(s, 0, sizeof *s);
    }
}

void gs_ply_features_from_sh(gs_ply_scene *s)
{
    if (!s || s->kind != GS_PLY_SH || !s->f_dc || !s->features)
        return;
    for (size_t i = 0; i < 3 * (size_t)s->n; i++)
        s->features[i] = (float)GS_PLY_SH_C0 * s->f_dc[i] + 0.5f;
}

void gs_ply_gaussians(const gs_ply_scene *s, gs_gaussians *g)
{
    g->n = s->n;
    g->channels = s->channels;
    g->means = s->means;
    g->log_scales = s->log_scales;
    g->quats = s->quats;
    g->opacity_logits = s->opacity_logits;
    g->features = s->features;
}

/* ---- header ------------------------------------------------------------- */

typedef struct ply_prop {
    char name[PLY_NAME_MAX];
    size_t offset;  /* within a vertex record */
    int field, idx; /* slot, field -1 when unknown */
} ply_prop;

typedef struct ply_header {
    size_t data_off; /* first byte after end_header\n */
    size_t n;        /* vertices */
    size_t stride;   /* bytes per vertex record */
    int nprops;
    int saw_format, saw_element;
    size_t max_vertices;
    ply_prop props[GS_PLY_MAX_PROPERTIES];
    int where[F_COUNT][GS_RASTER_MAX_CHANNELS]; /* prop index or -1 */
} ply_header;

typedef struct ply_tok {
    const char *p;
    size_t n;
} ply_tok;

#define PLY_MAX_TOKENS 4

static int tok_is(ply_tok t, const char *s)
{
    return strlen(s) == t.n && memcmp(t.p, s, t.n) == 0;
}

/* Splits a line on spaces; returns the token count, PLY_MAX_TOKENS + 1 if
 * there are more. */
static int tokenize(const char *p, size_t n, ply_tok *t)
{
    int k = 0;
    size_t i = 0;
    while (i < n) {
        while (i < n && (p[i] == ' ' || p[i] == '\t'))
            i++;
        if (i == n)
            break;
        if (k == PLY_MAX_TOKENS)
            return PLY_MAX_TOKENS + 1;
        t[k].p = p + i;
        while (i < n && p[i] != ' ' && p[i] != '\t')
            i++;
        t[k].n = (size_t)(p + i - t[k].p);
        k++;
    }
    return k;
}

static int scalar_size(ply_tok t, int *is_float)
{
    static const char *const names[] = {"char", "int8", "uchar", "uint8", "short", "int16",
                                        "ushort", "uint16", "int", "int32", "uint", "uint32",
                                        "float", "float32", "double", "float64"};
    static const int sizes[] = {1, 1, 1, 1, 2, 2, 2, 2, 4, 4, 4, 4, 4, 4, 8, 8};
    for (size_t i = 0; i < sizeof names / sizeof names[0]; i++) {
        if (tok_is(t, names[i])) {
            *is_float = i == 12 || i == 13;
            return sizes[i];
        }
    }
    return 0;
}

static int line_format(ply_header *h, const ply_tok *t, int nt, gs_error *err)
{
    if (h->saw_format++ || nt != 3)
        return gs_error_set(err, GS_ERR_FORMAT, "ply: bad or repeated format line");
    if (tok_is(t[1], "ascii") || tok_is(t[1], "binary_big_endian"))
        return gs_error_set(err, GS_ERR_UNSUPPORTED,
                            "ply: format '%.*s' not supported (binary_little_endian only)",
                            (int)t[1].n, t[1].p);
    if (!tok_is(t[1], "binary_little_endian"))
        return gs_error_set(err, GS_ERR_FORMAT, "ply: unknown format '%.*s'", (int)t[1].n, t[1].p);
    if (!tok_is(t[2], "1.0"))
        return gs_error_set(err, GS_ERR_UNSUPPORTED, "ply: format version '%.*s'", (int)t[2].n,
                            t[2].p);
    return GS_OK;
}

static int line_element(ply_header *h, const ply_tok *t, int nt, gs_error *err)
{
    if (!h->saw_format || nt != 3)
        return gs_error_set(err, GS_ERR_FORMAT, "ply: bad element line");
    if (h->saw_element++ || !tok_is(t[1], "vertex"))
        return gs_error_set(err, GS_ERR_UNSUPPORTED,
                            "ply: element '%.*s' not supported (one 'vertex' element only)",
                            (int)t[1].n, t[1].p);
    uint64_t n = 0;
    for (size_t i = 0; i < t[2].n; i++) {
        char c = t[2].p[i];
        if (c < '0' || c > '9')
            return gs_error_set(err, GS_ERR_FORMAT, "ply: bad vertex count '%.*s'", (int)t[2].n,
                                t[2].p);
        n = n * 10 + (uint64_t)(c - '0'); /* n <= max_vertices < 2^31 before */
        if (n > h->max_vertices)
            return gs_error_set(err, GS_ERR_LIMIT, "ply: vertex count '%.*s' over the limit %zu",
                                (int)t[2].n, t[2].p, h->max_vertices);
    }
    h->n = (size_t)n;
    return GS_OK;
}

/* Records a property after checking its type and name. */
static int line_property(ply_header *h, const ply_tok *t, int nt, gs_error *err)
{
    int is_float = 0, field = -1, idx = 0;
    if (!h->saw_element)
        return gs_error_set(err, GS_ERR_FORMAT, "ply: property before element");
    if (nt >= 2 && tok_is(t[1], "list"))
        return gs_error_set(err, GS_ERR_UNSUPPORTED, "ply: list properties not supported");
    if (nt != 3 || t[2].n >= PLY_NAME_MAX)
        return gs_error_set(err, GS_ERR_FORMAT, "ply: bad property line");
    int size = scalar_size(t[1], &is_float);
    if (!size)
        return gs_error_set(err, GS_ERR_FORMAT, "ply: unknown property type '%.*s'", (int)t[1].n,
                            t[1].p);
    if (h->nprops == GS_PLY_MAX_PROPERTIES)
        return gs_error_set(err, GS_ERR_LIMIT, "ply: more than %d properties",
                            GS_PLY_MAX_PROPERTIES);
    ply_prop *p = &h->props[h->nprops];
    memcpy(p->name, t[2].p, t[2].n);
    p->name[t[2].n] = '\0';
    for (int i = 0; i < h->nprops; i++)
        if (strcmp(h->props[i].name, p->name) == 0)
            return gs_error_set(err, GS_ERR_FORMAT, "ply: property '%s' twice", p->name);
    int known = field_of(p->name, &field, &idx);
    if (known < 0)
        return gs_error_set(err, field == F_REST || field == F_FEAT ? GS_ERR_UNSUPPORTED
                                                                    : GS_ERR_FORMAT,
                            "ply: property '%s' out of range (SH degree <= 3, <= %d features)",
                            p->name, GS_RASTER_MAX_CHANNELS);
    if (known && !is_float)
        return gs_error_set(err, GS_ERR_FORMAT, "ply: property '%s' has type %.*s, expected float",
                            p->name, (int)t[1].n, t[1].p);
    p->field = known ? field : -1;
    p->idx = idx;
    p->offset = h->stride;
    if (known)
        h->where[field][idx] = h->nprops;
    h->stride += (size_t)size;
    h->nprops++;
    return GS_OK;
}

/* One header line (without its newline). Sets *done on end_header. */
static int header_line(ply_header *h, const char *line, size_t len, int lineno, int *done,
                       gs_error *err)
{
    ply_tok t[PLY_MAX_TOKENS];
    if (len && line[len - 1] == '\r')
        len--;
    for (size_t i = 0; i < len; i++)
        if (((unsigned char)line[i] < 0x20 && line[i] != '\t') || line[i] == 0x7f)
            return gs_error_set(err, GS_ERR_FORMAT, "ply: control character in header line %d",
                                lineno);
    if (lineno == 1)
        return len == 3 && memcmp(line, "ply", 3) == 0
                   ? GS_OK
                   : gs_error_set(err, GS_ERR_FORMAT, "ply: not a PLY file (no 'ply' line)");
    int nt = tokenize(line, len, t);
    if (nt == 0)
        return gs_error_set(err, GS_ERR_FORMAT, "ply: empty header line %d", lineno);
    if (tok_is(t[0], "comment") || tok_is(t[0], "obj_info"))
        return GS_OK;
    if (tok_is(t[0], "format"))
        return line_format(h, t, nt, err);
    if (tok_is(t[0], "element"))
        return line_element(h, t, nt, err);
    if (tok_is(t[0], "property"))
        return line_property(h, t, nt, err);
    if (tok_is(t[0], "end_header") && nt == 1) {
        *done = 1;
        return h->saw_element ? GS_OK
                              : gs_error_set(err, GS_ERR_FORMAT, "ply: no vertex element");
    }
    return gs_error_set(err, GS_ERR_FORMAT, "ply: unknown header line %d '%.*s'", lineno,
                        (int)t[0].n, t[0].p);
}

/* Size of the contiguous group of slots 0..k-1 a field has; -1 after
 * setting an error naming the first gap. */
static int group_count(const ply_header *h, int field, gs_error *err)
{
    int hi = -1;
    for (int i = 0; i < field_cap[field]; i++)
        if (h->where[field][i] >= 0)
            hi = i;
    for (int i = 0; i < hi; i++) {
        if (h->where[field][i] < 0) {
            char name[PLY_NAME_MAX];
            field_name(field, i, name, sizeof name);
            gs_error_set(err, GS_ERR_FORMAT, "ply: missing property '%s'", name);
            return -1;
        }
    }
    return hi + 1;
}

static int require_all(const ply_header *h, int field, gs_error *err)
{
    for (int i = 0; i < field_cap[field]; i++) {
        if (h->where[field][i] < 0) {
            char name[PLY_NAME_MAX];
            field_name(field, i, name, sizeof name);
            return gs_error_set(err, GS_ERR_FORMAT, "ply: missing property '%s'", name);
        }
    }
    return GS_OK;
}

/* Checks the set of properties and returns the scene shape. */
static int check_layout(const ply_header *h, gs_ply_kind *kind, int *param, int *normals,
                        gs_error *err)
{
    static const int required[] = {F_POS, F_OPACITY, F_SCALE, F_ROT};
    int counts[F_COUNT];
    for (size_t i = 0; i < sizeof required / sizeof required[0]; i++) {
        int rc = require_all(h, required[i], err);
        if (rc)
            return rc;
    }
    for (int f = 0; f < F_COUNT; f++)
        if ((counts[f] = group_count(h, f, err)) < 0)
            return GS_ERR_FORMAT;
    int nn = counts[F_NORMAL], ndc = counts[F_DC], nrest = counts[F_REST], nfeat = counts[F_FEAT];
    if (nn != 0 && nn != 3)
        return require_all(h, F_NORMAL, err);
    *normals = nn == 3;
    if (nfeat && (ndc || nrest))
        return gs_error_set(err, GS_ERR_FORMAT, "ply: both feat_* and f_dc_*/f_rest_* properties");
    if (nfeat) {
        *kind = GS_PLY_FEATURES;
        *param = nfeat;
        return GS_OK;
    }
    if (ndc == 0)
        return gs_error_set(err, GS_ERR_FORMAT, "ply: missing property 'f_dc_0' (or 'feat_0')");
    if (ndc != 3)
        return require_all(h, F_DC, err);
    for (int d = 0; d <= GS_PLY_MAX_SH_DEGREE; d++) {
        if (rest_for_degree[d] == nrest) {
            *kind = GS_PLY_SH;
            *param = d;
            return GS_OK;
        }
    }
    return gs_error_set(err, GS_ERR_FORMAT, "ply: %d f_rest properties (0, 9, 24 or 45 expected)",
                        nrest);
}

/* Parses the header from buf (avail bytes present, total bytes in the
 * whole input). */
static int parse_header(const unsigned char *buf, size_t avail, size_t total, size_t max_vertices,
                        ply_header *h, gs_error *err)
{
    memset(h, 0, sizeof *h);
    memset(h->where, 0xff, sizeof h->where);
    h->max_vertices = max_vertices;
    size_t lim = avail < GS_PLY_MAX_HEADER ? avail : GS_PLY_MAX_HEADER;
    size_t pos = 0;
    int done = 0;
    for (int lineno = 1; !done; lineno++) {
        const unsigned char *nl = memchr(buf + pos, '\n', lim - pos);
        if (!nl)
            return total > GS_PLY_MAX_HEADER
                       ? gs_error_set(err, GS_ERR_LIMIT, "ply: no end_header in the first %d bytes",
                                      GS_PLY_MAX_HEADER)
                       : gs_error_set(err, GS_ERR_FORMAT, "ply: truncated header");
        int rc = header_line(h, (const char *)buf + pos, (size_t)(nl - buf) - pos, lineno, &done,
                             err);
        if (rc)
            return rc;
        pos = (size_t)(nl - buf) + 1;
    }
    h->data_off = pos;
    return GS_OK;
}

/* The vertex data must fill the input exactly (stride > 0: the layout was
 * checked). */
static int check_data_size(const ply_header *h, size_t total, gs_error *err)
{
    size_t have = total - h->data_off;
    if (h->n > have / h->stride)
        return gs_error_set(err, GS_ERR_FORMAT,
                            "ply: truncated: %zu vertices of %zu bytes need %zu bytes, %zu present",
                            h->n, h->stride, h->n * h->stride, have);
    if (have != h->n * h->stride)
        return gs_error_set(err, GS_ERR_FORMAT, "ply: %zu bytes after the vertex data",
                            have - h->n * h->stride);
    return GS_OK;
}

/* ---- data --------------------------------------------------------------- */

/* A float column of a vertex record and where it goes in the scene. */
typedef struct ply_col {
    size_t offset;    /* in the record */
    float *dst;       /* slot base + index */
    int width;        /* floats per vertex in the slot */
    const char *name; /* for messages */
} ply_col;

static int reader_columns(const ply_header *h, const gs_ply_scene *s, ply_col *cols)
{
    int nc = 0;
    for (int i = 0; i < h->nprops; i++) {
        const ply_prop *p = &h->props[i];
        if (p->field < 0)
            continue;
        cols[nc].offset = p->offset;
        cols[nc].dst = scene_slot(s, p->field, &cols[nc].width) + p->idx;
        cols[nc].name = p->name;
        nc++;
    }
    return nc;
}

static float get_le_float(const unsigned char *p)
{
    uint32_t u = (uint32_t)p[0] | (uint32_t)p[1] << 8 | (uint32_t)p[2] << 16 | (uint32_t)p[3] << 24;
    float f;
    memcpy(&f, &u, sizeof f);
    return f;
}

static void put_le_float(unsigned char *p, float f)
{
    uint32_t u;
    memcpy(&u, &f, sizeof u);
    p[0] = (unsigned char)u;
    p[1] = (unsigned char)(u >> 8);
    p[2] = (unsigned char)(u >> 16);
    p[3] = (unsigned char)(u >> 24);
}

/* Decodes count records starting at vertex first. */
static int decode_records(const ply_col *cols, int nc, size_t stride, const unsigned char *src,
                          size_t first, size_t count, int allow_nonfinite, gs_error *err)
{
    for (size_t i = 0; i < count; i++, src += stride) {
        size_t v = first + i;
        for (int c = 0; c < nc; c++) {
            float f = get_le_float(src + cols[c].offset);
            if (!allow_nonfinite && !isfinite(f))
                return gs_error_set(err, GS_ERR_NONFINITE, "ply: vertex %zu: '%s' is %s", v,
                                    cols[c].name, isnan(f) ? "NaN" : "infinite");
            cols[c].dst[v * (size_t)cols[c].width] = f;
        }
    }
    return GS_OK;
}

static int resolve_options(const gs_ply_options *opt, size_t *max_vertices, int *allow,
                           gs_error *err)
{
    *max_vertices = GS_PLY_DEFAULT_MAX_VERTICES;
    *allow = 0;
    if (opt) {
        if (opt->max_vertices < 0)
            return gs_error_set(err, GS_ERR_ARG, "ply: max_vertices %d < 0", opt->max_vertices);
        if (opt->max_vertices)
            *max_vertices = (size_t)opt->max_vertices;
        *allow = opt->allow_nonfinite != 0;
    }
    return GS_OK;
}

/* Checks the layout and size of a parsed header, then allocates. */
static int alloc_for_header(const ply_header *h, size_t total, gs_ply_scene *s, gs_error *err)
{
    gs_ply_kind kind = GS_PLY_SH;
    int param = 0, normals = 0;
    int rc = check_layout(h, &kind, &param, &normals, err);
    if (!rc)
        rc = check_data_size(h, total, err);
    if (rc)
        return rc;
    return kind == GS_PLY_SH ? scene_alloc(s, kind, (int)h->n, 3, param, normals, err)
                             : scene_alloc(s, kind, (int)h->n, param, -1, normals, err);
}

int gs_ply_parse(const void *buf, size_t len, const gs_ply_options *opt, gs_ply_scene *out,
                 gs_error *err)
{
    ply_header *h;
    ply_col cols[PLY_MAX_COLUMNS];
    gs_ply_scene s;
    size_t max_vertices;
    int allow;
    if (!out || (!buf && len))
        return gs_error_set(err, GS_ERR_ARG, "ply: NULL argument");
    int rc = resolve_options(opt, &max_vertices, &allow, err);
    if (rc)
        return rc;
    if (!(h = malloc(sizeof *h)))
        return gs_error_set(err, GS_ERR_NOMEM, "ply: out of memory");
    rc = parse_header(buf, len, len, max_vertices, h, err);
    if (!rc)
        rc = alloc_for_header(h, len, &s, err);
    if (!rc) {
        int nc = reader_columns(h, &s, cols);
        rc = decode_records(cols, nc, h->stride, (const unsigned char *)buf + h->data_off, 0, h->n,
                            allow, err);
        if (rc)
            gs_ply_free(&s);
    }
    free(h);
    if (rc)
        return rc;
    gs_ply_features_from_sh(&s);
    *out = s;
    return GS_OK;
}

/* ---- file reader -------------------------------------------------------- */

#define PLY_CHUNK_BYTES (1u << 20)

/* Reads the vertex records in chunks straight into the scene. */
static int read_records(FILE *f, const char *path, const ply_header *h, gs_ply_scene *s, int allow,
                        gs_error *err)
{
    ply_col cols[PLY_MAX_COLUMNS];
    int nc = reader_columns(h, s, cols);
    size_t per_chunk = PLY_CHUNK_BYTES / h->stride ? PLY_CHUNK_BYTES / h->stride : 1;
    unsigned char *chunk = malloc(per_chunk * h->stride);
    if (!chunk)
        return gs_error_set(err, GS_ERR_NOMEM, "ply: out of memory");
    int rc = fseek(f, (long)h->data_off, SEEK_SET)
                 ? gs_error_set(err, GS_ERR_IO, "ply: %s: seek failed", path)
                 : GS_OK;
    for (size_t v = 0; !rc && v < h->n; v += per_chunk) {
        size_t k = h->n - v < per_chunk ? h->n - v : per_chunk;
        if (fread(chunk, h->stride, k, f) != k)
            rc = gs_error_set(err, GS_ERR_IO, "ply: %s: read failed", path);
        else
            rc = decode_records(cols, nc, h->stride, chunk, v, k, allow, err);
    }
    free(chunk);
    return rc;
}

int gs_ply_read(const char *path, const gs_ply_options *opt, gs_ply_scene *out, gs_error *err)
{
    struct stat st;
    gs_ply_scene s;
    size_t max_vertices;
    int allow;
    if (!path || !out)
        return gs_error_set(err, GS_ERR_ARG, "ply: NULL argument");
    int rc = resolve_options(opt, &max_vertices, &allow, err);
    if (rc)
        return rc;
    FILE *f = fopen(path, "rb");
    if (!f)
        return gs_error_set(err, GS_ERR_IO, "ply: cannot open %s: %s", path, strerror(errno));
    ply_header *h = malloc(sizeof *h);
    unsigned char *head = malloc(GS_PLY_MAX_HEADER);
    if (!h || !head)
        rc = gs_error_set(err, GS_ERR_NOMEM, "ply: out of memory");
    else if (fstat(fileno(f), &st) != 0 || !S_ISREG(st.st_mode))
        rc = gs_error_set(err, GS_ERR_IO, "ply: %s is not a regular file", path);
    if (!rc) {
        size_t got = fread(head, 1, GS_PLY_MAX_HEADER, f);
        rc = parse_header(head, got, (size_t)st.st_size, max_vertices, h, err);
    }
    if (!rc)
        rc = alloc_for_header(h, (size_t)st.st_size, &s, err);
    if (!rc && (rc = read_records(f, path, h, &s, allow, err)) != GS_OK)
        gs_ply_free(&s);
    free(head);
    free(h);
    fclose(f);
    if (rc)
        return rc;
    gs_ply_features_from_sh(&s);
    *out = s;
    return GS_OK;
}

/* ---- writer ------------------------------------------------------------- */

typedef struct ply_wcol {
    char name[PLY_NAME_MAX];
    const float *src; /* slot base + index */
    int width;
} ply_wcol;

static int add_group(const gs_ply_scene *s, int field, int count, ply_wcol *cols, int nc)
{
    for (int i = 0; i < count; i++, nc++) {
        field_name(field, i, cols[nc].name, sizeof cols[nc].name);
        cols[nc].src = scene_slot(s, field, &cols[nc].width) + i;
    }
    return nc;
}

/* The writer's layout: x y z [nx ny nz] colour opacity scale rot. */
static int writer_columns(const gs_ply_scene *s, ply_wcol *cols)
{
    int nc = add_group(s, F_POS, 3, cols, 0);
    if (s->normals)
        nc = add_group(s, F_NORMAL, 3, cols, nc);
    if (s->kind == GS_PLY_SH) {
        nc = add_group(s, F_DC, 3, cols, nc);
        nc = add_group(s, F_REST, s->n_rest, cols, nc);
    } else {
        nc = add_group(s, F_FEAT, s->channels, cols, nc);
    }
    nc = add_group(s, F_OPACITY, 1, cols, nc);
    nc = add_group(s, F_SCALE, 3, cols, nc);
    return add_group(s, F_ROT, 4, cols, nc);
}

static int check_scene(const gs_ply_scene *s, gs_error *err)
{
    if (!s || s->n < 0)
        return gs_error_set(err, GS_ERR_ARG, "ply: no scene");
    if (s->kind == GS_PLY_SH) {
        if (s->sh_degree < 0 || s->sh_degree > GS_PLY_MAX_SH_DEGREE ||
            s->n_rest != rest_for_degree[s->sh_degree])
            return gs_error_set(err, GS_ERR_ARG, "ply: SH degree %d with %d f_rest", s->sh_degree,
                                s->n_rest);
        if (s->n && (!s->f_dc || (s->n_rest && !s->f_rest)))
            return gs_error_set(err, GS_ERR_ARG, "ply: SH scene without f_dc/f_rest");
    } else if (s->kind == GS_PLY_FEATURES) {
        if (s->channels < 1 || s->channels > GS_RASTER_MAX_CHANNELS || (s->n && !s->features))
            return gs_error_set(err, GS_ERR_ARG, "ply: bad feature scene (%d channels)",
                                s->channels);
    } else {
        return gs_error_set(err, GS_ERR_ARG, "ply: unknown scene kind %d", (int)s->kind);
    }
    if (s->n && (!s->means || !s->log_scales || !s->quats || !s->opacity_logits))
        return gs_error_set(err, GS_ERR_ARG, "ply: scene arrays missing");
    return GS_OK;
}

/* Writes the header into buf (cap bytes); returns its length or 0. */
static size_t write_header(const gs_ply_scene *s, const ply_wcol *cols, int nc, char *buf,
                           size_t cap)
{
    size_t k = (size_t)snprintf(buf, cap, "ply\nformat binary_little_endian 1.0\nelement vertex %d\n",
                                s->n);
    for (int c = 0; c < nc && k < cap; c++)
        k += (size_t)snprintf(buf + k, cap - k, "property float %s\n", cols[c].name);
    if (k < cap)
        k += (size_t)snprintf(buf + k, cap - k, "end_header\n");
    return k < cap ? k : 0;
}

static void encode_records(const ply_wcol *cols, int nc, size_t first, size_t count,
                           unsigned char *dst)
{
    for (size_t v = first; v < first + count; v++)
        for (int c = 0; c < nc; c++, dst += 4)
            put_le_float(dst, cols[c].src[v * (size_t)cols[c].width]);
}

#define PLY_HEADER_CAP (128 + PLY_MAX_COLUMNS * (PLY_NAME_MAX + 16))

int gs_ply_encode(const gs_ply_scene *s, void **out, size_t *out_len, gs_error *err)
{
    ply_wcol cols[PLY_MAX_COLUMNS];
    char head[PLY_HEADER_CAP];
    int rc = check_scene(s, err);
    if (rc)
        return rc;
    if (!out || !out_len)
        return gs_error_set(err, GS_ERR_ARG, "ply: NULL output");
    int nc = writer_columns(s, cols);
    size_t hlen = write_header(s, cols, nc, head, sizeof head);
    size_t total = hlen + (size_t)s->n * (size_t)nc * 4;
    unsigned char *buf = malloc(total);
    if (!buf)
        return gs_error_set(err, GS_ERR_NOMEM, "ply: cannot allocate %zu bytes", total);
    memcpy(buf, head, hlen);
    encode_records(cols, nc, 0, (size_t)s->n, buf + hlen);
    *out = buf;
    *out_len = total;
    return GS_OK;
}

int gs_ply_write(const char *path, const gs_ply_scene *s, gs_error *err)
{
    ply_wcol cols[PLY_MAX_COLUMNS];
    char head[PLY_HEADER_CAP];
    int rc = check_scene(s, err);
    if (rc)
        return rc;
    int nc = writer_columns(s, cols);
    size_t hlen = write_header(s, cols, nc, head, sizeof head);
    size_t stride = (size_t)nc * 4, per_chunk = PLY_CHUNK_BYTES / stride;
    unsigned char *chunk = malloc(per_chunk * stride);
    FILE *f = chunk ? fopen(path, "wb") : NULL;
    if (!f) {
        rc = chunk ? gs_error_set(err, GS_ERR_IO, "ply: cannot create %s: %s", path,
                                  strerror(errno))
                   : gs_error_set(err, GS_ERR_NOMEM, "ply: out of memory");
        free(chunk);
        return rc;
    }
    int ok = fwrite(head, 1, hlen, f) == hlen;
    for (size_t v = 0; ok && v < (size_t)s->n; v += per_chunk) {
        size_t k = (size_t)s->n - v < per_chunk ? (size_t)s->n - v : per_chunk;
        encode_records(cols, nc, v, k, chunk);
        ok = fwrite(chunk, stride, k, f) == k;
    }
    ok = (fclose(f) == 0) && ok;
    free(chunk);
    if (!ok)
        return gs_error_set(err, GS_ERR_IO, "ply: cannot write %s: %s", path, strerror(errno));
    return GS_OK;
}
