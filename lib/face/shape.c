/* Ensemble of regression trees (Kazemi & Sullivan 2014) as serialized by
 * dlib's shape_predictor, and its inference, step for step as dlib does it
 * so that the points are identical (float where dlib uses float, double
 * where it uses double, the same rounding).
 *
 * dlib's serialization (dlib/serialize.h):
 *   integer  control byte (bit 7: negative, low 4 bits: n) + n bytes, LE
 *   float    integer mantissa (int64) then integer exponent (int16): m 2^e;
 *            exponents 32000..32002 mean inf, -inf, NaN (refused here)
 *   vector   size, items;  matrix  rows, cols (negated), items
 * shape_predictor: version (1), initial_shape (matrix 2P x 1), forests
 * (vector of vector of trees; tree = vector of splits (idx1, idx2, thresh)
 * + vector of leaf matrices 2P x 1), anchor_idx (vector of vector of
 * ulong), deltas (vector of vector of points (float x, float y)). */
#include <limits.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "face_internal.h"

#define MAX_BYTES ((size_t)1 << 30)
#define MAX_CASCADES 64
#define MAX_SPLITS 255

/* ---- reader ---- */

typedef struct reader {
    const unsigned char *start, *p, *end;
    gs_error *err;
    int failed;
    const char *what;  /* field being read, for messages */
} reader;

static int fail(reader *r, int code, const char *msg)
{
    if (!r->failed)
        gs_error_set(r->err, code, "shape model: %s (%s, at byte %td)", msg, r->what,
                     r->p - r->start);
    r->failed = code;
    return code;
}

/* One dlib integer: *neg and the magnitude, at most max_bytes bytes. */
static int read_int_raw(reader *r, int max_bytes, int *neg, uint64_t *mag)
{
    if (r->p >= r->end)
        return fail(r, GS_ERR_FORMAT, "truncated");
    unsigned c = *r->p++;
    int n = (int)(c & 0x0f);
    if ((c & 0x70) || n > max_bytes)
        return fail(r, GS_ERR_FORMAT, "bad integer control byte");
    if (r->end - r->p < n)
        return fail(r, GS_ERR_FORMAT, "truncated");
    uint64_t v = 0;
    for (int i = 0; i < n; i++)
        v |= (uint64_t)r->p[i] << (8 * i);
    r->p += n;
    *neg = (c & 0x80) != 0;
    *mag = v;
    return GS_OK;
}

static int read_u64(reader *r, uint64_t *out)
{
    int neg;
    if (read_int_raw(r, 8, &neg, out))
        return r->failed;
    if (neg)
        return fail(r, GS_ERR_FORMAT, "negative unsigned integer");
    return GS_OK;
}

static int read_i64(reader *r, int max_bytes, int64_t *out)
{
    int neg;
    uint64_t mag;
    if (read_int_raw(r, max_bytes, &neg, &mag))
        return r->failed;
    if (mag > (uint64_t)INT64_MAX)
        return fail(r, GS_ERR_FORMAT, "integer out of range");
    *out = neg ? -(int64_t)mag : (int64_t)mag;
    return GS_OK;
}

/* A dlib float: ldexp((float)mantissa, exponent), finite only. */
static int read_float(reader *r, float *out)
{
    int64_t m, e;
    if (r->p < r->end && (*r->p & 0x70))
        return fail(r, GS_ERR_UNSUPPORTED, "old ASCII float format");
    if (read_i64(r, 8, &m) || read_i64(r, 2, &e))
        return r->failed;
    if (e >= 32000 || e < -32768)
        return fail(r, GS_ERR_FORMAT, "non-finite float");
    float v = ldexpf((float)m, (int)e);
    if (!isfinite(v))
        return fail(r, GS_ERR_FORMAT, "float out of range");
    *out = v;
    return GS_OK;
}

/* A vector size that the remaining bytes can hold at min_item bytes each
 * (so a corrupt size is refused before anything is allocated). */
static int read_size(reader *r, uint64_t max, size_t min_item, size_t *out)
{
    uint64_t n;
    if (read_u64(r, &n))
        return r->failed;
    if (n > max)
        return fail(r, GS_ERR_FORMAT, "size out of range");
    if (n * min_item > (uint64_t)(r->end - r->p))
        return fail(r, GS_ERR_FORMAT, "truncated");
    *out = (size_t)n;
    return GS_OK;
}

/* A column matrix<float,0,1> of exactly `len` floats (len 0: any, returned
 * in *got, at most max). */
static int read_column(reader *r, size_t len, size_t max, float *dst, size_t *got)
{
    int64_t nr, nc;
    if (read_i64(r, 8, &nr) || read_i64(r, 8, &nc))
        return r->failed;
    if (nr < 0)
        nr = -nr;
    if (nc < 0)
        nc = -nc;
    if (nc != 1 || nr < 1 || (uint64_t)nr > max || (len && (size_t)nr != len))
        return fail(r, GS_ERR_FORMAT, "unexpected matrix shape");
    if ((uint64_t)nr * 2 > (uint64_t)(r->end - r->p))
        return fail(r, GS_ERR_FORMAT, "truncated");
    if (got)
        *got = (size_t)nr;
    for (int64_t i = 0; i < nr; i++)
        if (read_float(r, &dst[i]))
            return r->failed;
    return GS_OK;
}

/* ---- model ---- */

void gs_face_shape_model_destroy(gs_face_shape_model *m)
{
    if (!m)
        return;
    free(m->splits);
    free(m->leaves);
    free(m->anchor);
    free(m->delta);
    free(m);
}

int gs_face_shape_model_parts(const gs_face_shape_model *m)
{
    return m ? m->n_parts : 0;
}

static int alloc_arrays(reader *r, gs_face_shape_model *m)
{
    size_t trees = (size_t)m->n_cascades * m->n_trees;
    size_t leaf_floats = trees * (size_t)m->n_leaves * (size_t)m->dim;
    if (leaf_floats > MAX_BYTES / sizeof(float))
        return fail(r, GS_ERR_LIMIT, "leaves over 1 GiB");
    /* Two bytes per float at least: the file must hold them all. */
    if (leaf_floats * 2 > (size_t)(r->end - r->p))
        return fail(r, GS_ERR_FORMAT, "truncated");
    m->splits = calloc(trees * (size_t)m->n_splits, sizeof *m->splits);
    m->leaves = malloc(leaf_floats * sizeof(float));
    if (!m->splits || !m->leaves)
        return fail(r, GS_ERR_NOMEM, "out of memory");
    return GS_OK;
}

static int read_tree(reader *r, gs_face_shape_model *m, size_t tree)
{
    size_t ns, nl;
    r->what = "tree splits";
    if (read_size(r, MAX_SPLITS, 3, &ns))
        return r->failed;
    if (!m->splits) {
        /* The first tree fixes the depth of all. */
        if (ns < 1 || ((ns + 1) & ns))
            return fail(r, GS_ERR_UNSUPPORTED, "tree not complete (splits != 2^k - 1)");
        m->n_splits = (int)ns;
        m->n_leaves = (int)ns + 1;
        if (alloc_arrays(r, m))
            return r->failed;
    } else if ((int)ns != m->n_splits) {
        return fail(r, GS_ERR_UNSUPPORTED, "trees of different depths");
    }
    gs_face_split *sp = m->splits + tree * (size_t)m->n_splits;
    for (size_t i = 0; i < ns; i++) {
        uint64_t a, b;
        float th;
        if (read_u64(r, &a) || read_u64(r, &b) || read_float(r, &th))
            return r->failed;
        /* Feature counts are checked against anchor_idx after parsing. */
        if (a > 65535 || b > 65535)
            return fail(r, GS_ERR_FORMAT, "split feature index out of range");
        sp[i].idx1 = (uint16_t)a;
        sp[i].idx2 = (uint16_t)b;
        sp[i].thresh = th;
    }
    r->what = "tree leaves";
    if (read_size(r, MAX_SPLITS + 1, 2, &nl))
        return r->failed;
    if ((int)nl != m->n_leaves)
        return fail(r, GS_ERR_FORMAT, "leaves != splits + 1");
    float *leaf = m->leaves + tree * (size_t)m->n_leaves * (size_t)m->dim;
    for (size_t i = 0; i < nl; i++)
        if (read_column(r, (size_t)m->dim, (size_t)m->dim, leaf + i * (size_t)m->dim, NULL))
            return r->failed;
    return GS_OK;
}

static int read_forests(reader *r, gs_face_shape_model *m)
{
    size_t nc;
    r->what = "forests";
    if (read_size(r, MAX_CASCADES, 1, &nc))
        return r->failed;
    if (nc < 1)
        return fail(r, GS_ERR_FORMAT, "no cascades");
    m->n_cascades = (int)nc;
    for (size_t c = 0; c < nc; c++) {
        size_t nt;
        r->what = "forest";
        if (read_size(r, 1u << 20, 4, &nt))
            return r->failed;
        if (c == 0) {
            if (nt < 1)
                return fail(r, GS_ERR_FORMAT, "empty forest");
            m->n_trees = (int)nt;
        } else if ((int)nt != m->n_trees) {
            return fail(r, GS_ERR_UNSUPPORTED, "forests of different sizes");
        }
        for (size_t t = 0; t < nt; t++)
            if (read_tree(r, m, c * nt + t))
                return r->failed;
    }
    return GS_OK;
}

/* anchor_idx and deltas: n_cascades vectors of n_features each. */
static int read_features(reader *r, gs_face_shape_model *m)
{
    size_t n;
    r->what = "anchor_idx";
    if (read_size(r, MAX_CASCADES, 1, &n))
        return r->failed;
    if ((int)n != m->n_cascades)
        return fail(r, GS_ERR_FORMAT, "anchor_idx count != cascades");
    for (int c = 0; c < m->n_cascades; c++) {
        size_t nf;
        if (read_size(r, GS_FACE_MAX_FEATURES, 1, &nf))
            return r->failed;
        if (c == 0) {
            if (nf < 1)
                return fail(r, GS_ERR_FORMAT, "no features");
            m->n_features = (int)nf;
            m->anchor = malloc((size_t)m->n_cascades * nf * sizeof *m->anchor);
            m->delta = malloc((size_t)m->n_cascades * nf * 2 * sizeof *m->delta);
            if (!m->anchor || !m->delta)
                return fail(r, GS_ERR_NOMEM, "out of memory");
        } else if ((int)nf != m->n_features) {
            return fail(r, GS_ERR_UNSUPPORTED, "cascades with different feature counts");
        }
        for (size_t i = 0; i < nf; i++) {
            uint64_t a;
            if (read_u64(r, &a))
                return r->failed;
            if (a >= (uint64_t)m->n_parts)
                return fail(r, GS_ERR_FORMAT, "anchor index out of range");
            m->anchor[(size_t)c * nf + i] = (uint16_t)a;
        }
    }
    r->what = "deltas";
    if (read_size(r, MAX_CASCADES, 1, &n))
        return r->failed;
    if ((int)n != m->n_cascades)
        return fail(r, GS_ERR_FORMAT, "deltas count != cascades");
    for (int c = 0; c < m->n_cascades; c++) {
        size_t nf;
        if (read_size(r, GS_FACE_MAX_FEATURES, 4, &nf))
            return r->failed;
        if ((int)nf != m->n_features)
            return fail(r, GS_ERR_FORMAT, "deltas count != anchor_idx count");
        float *d = m->delta + (size_t)c * nf * 2;
        for (size_t i = 0; i < 2 * nf; i++)
            if (read_float(r, &d[i]))
                return r->failed;
    }
    return GS_OK;
}

static int check_splits(reader *r, const gs_face_shape_model *m)
{
    size_t n = (size_t)m->n_cascades * m->n_trees * m->n_splits;
    for (size_t i = 0; i < n; i++)
        if (m->splits[i].idx1 >= m->n_features || m->splits[i].idx2 >= m->n_features)
            return fail(r, GS_ERR_FORMAT, "split feature index past the features");
    return GS_OK;
}

static int parse(reader *r, gs_face_shape_model *m)
{
    int64_t version;
    size_t dim;
    r->what = "version";
    if (read_i64(r, 4, &version))
        return r->failed;
    if (version != 1)
        return fail(r, GS_ERR_FORMAT, "not a version 1 shape_predictor");
    r->what = "initial_shape";
    if (read_column(r, 0, 2 * GS_FACE_MAX_PARTS, m->initial, &dim))
        return r->failed;
    if (dim % 2)
        return fail(r, GS_ERR_FORMAT, "odd initial shape length");
    m->dim = (int)dim;
    m->n_parts = (int)dim / 2;
    if (read_forests(r, m) || read_features(r, m) || check_splits(r, m))
        return r->failed;
    if (r->p != r->end)
        return fail(r, GS_ERR_FORMAT, "trailing bytes");
    return GS_OK;
}

int gs_face_shape_model_parse(const void *buf, size_t len, gs_face_shape_model **out,
                              gs_error *err)
{
    if (!buf || !out)
        return gs_error_set(err, GS_ERR_ARG, "shape model: NULL argument");
    if (len > MAX_BYTES)
        return gs_error_set(err, GS_ERR_LIMIT, "shape model: %zu bytes over 1 GiB", len);
    gs_face_shape_model *m = calloc(1, sizeof *m);
    if (!m)
        return gs_error_set(err, GS_ERR_NOMEM, "shape model: out of memory");
    const unsigned char *b = buf;
    reader r = {b, b, b + len, err, 0, "start"};
    int rc = parse(&r, m);
    if (rc) {
        gs_face_shape_model_destroy(m);
        return rc;
    }
    *out = m;
    return GS_OK;
}

int gs_face_shape_model_load(const char *path, gs_face_shape_model **out, gs_error *err)
{
    if (!path)
        path = GS_FACE_SHAPE_MODEL_DEFAULT;
    FILE *f = fopen(path, "rb");
    if (!f)
        return gs_error_set(err, GS_ERR_IO, "shape model: cannot open %.200s", path);
    long len = -1;
    if (fseek(f, 0, SEEK_END) == 0)
        len = ftell(f);
    if (len < 0 || fseek(f, 0, SEEK_SET) != 0) {
        fclose(f);
        return gs_error_set(err, GS_ERR_IO, "shape model: cannot size %.200s", path);
    }
    if ((unsigned long)len > MAX_BYTES) {
        fclose(f);
        return gs_error_set(err, GS_ERR_LIMIT, "shape model: %.200s over 1 GiB", path);
    }
    unsigned char *buf = malloc(len ? (size_t)len : 1);
    if (!buf) {
        fclose(f);
        return gs_error_set(err, GS_ERR_NOMEM, "shape model: out of memory");
    }
    size_t got = fread(buf, 1, (size_t)len, f);
    fclose(f);
    int rc;
    if (got != (size_t)len)
        rc = gs_error_set(err, GS_ERR_IO, "shape model: short read of %.200s", path);
    else
        rc = gs_face_shape_model_parse(buf, got, out, err);
    free(buf);
    return rc;
}

/* ---- inference ---- */

/* 2x2 part of the least-squares similarity from shape `from` to `to`
 * (dlib's find_tform_between_shapes, Umeyama; for a similarity without
 * reflection it is [[a, -b], [b, a]] with these closed forms), computed in
 * double and rounded to float as dlib does. */
static void similarity(const float *from, const float *to, int n, float mf[4])
{
    double fx = 0, fy = 0, tx = 0, ty = 0;
    for (int i = 0; i < n; i++) {
        fx += from[2 * i];
        fy += from[2 * i + 1];
        tx += to[2 * i];
        ty += to[2 * i + 1];
    }
    fx /= n;
    fy /= n;
    tx /= n;
    ty /= n;
    double pp = 0, a = 0, b = 0;
    for (int i = 0; i < n; i++) {
        double px = from[2 * i] - fx, py = from[2 * i + 1] - fy;
        double qx = to[2 * i] - tx, qy = to[2 * i + 1] - ty;
        pp += px * px + py * py;
        a += px * qx + py * qy;
        b += px * qy - py * qx;
    }
    if (pp > 0) {
        a /= pp;
        b /= pp;
    } else {
        a = 1;
        b = 0;
    }
    mf[0] = (float)a;
    mf[1] = (float)-b;
    mf[2] = (float)b;
    mf[3] = (float)a;
}

/* Grey value (r + g + b) / 3 of the pixel nearest to normalized shape
 * point (ux, uy), 0 outside the image (dlib's get_pixel_intensity on an
 * rgb_pixel and its point rounding floor(v + 0.5)). */
static float sample(const gs_io_image *img, const double box[4], float ux, float uy)
{
    double x = box[0] + (double)ux * box[2];
    double y = box[1] + (double)uy * box[3];
    double fx = floor(x + 0.5), fy = floor(y + 0.5);
    if (!(fx >= 0 && fy >= 0 && fx < img->width && fy < img->height))
        return 0.0f;
    const unsigned char *p = img->data + (size_t)fy * img->stride + 3 * (size_t)fx;
    return (float)(((int)p[0] + p[1] + p[2]) / 3);
}

/* Features of cascade c: pixel values at the anchor points of the current
 * shape, each moved by its delta through the similarity initial -> cur. */
static void features(const gs_face_shape_model *m, int c, const gs_io_image *img,
                     const double box[4], const float *cur, float *feat)
{
    float mf[4];
    similarity(m->initial, cur, m->n_parts, mf);
    const uint16_t *anchor = m->anchor + (size_t)c * m->n_features;
    const float *delta = m->delta + (size_t)c * m->n_features * 2;
    for (int i = 0; i < m->n_features; i++) {
        float dx = delta[2 * i], dy = delta[2 * i + 1];
        float ux = mf[0] * dx + mf[1] * dy;
        float uy = mf[2] * dx + mf[3] * dy;
        ux += cur[2 * anchor[i]];
        uy += cur[2 * anchor[i] + 1];
        feat[i] = sample(img, box, ux, uy);
    }
}

/* cur (dim) += the leaf each tree of cascade c picks for feat. */
static void apply_forest(const gs_face_shape_model *m, int c, const float *feat, float *cur)
{
    const int ns = m->n_splits, dim = m->dim;
    const size_t leaf_stride = (size_t)m->n_leaves * dim;
    for (int t = 0; t < m->n_trees; t++) {
        size_t tree = (size_t)c * m->n_trees + t;
        const gs_face_split *sp = m->splits + tree * ns;
        int n = 0;
        while (n < ns)
            n = feat[sp[n].idx1] - feat[sp[n].idx2] > sp[n].thresh ? 2 * n + 1 : 2 * n + 2;
        const float *leaf = m->leaves + tree * leaf_stride + (size_t)(n - ns) * dim;
        for (int k = 0; k < dim; k++)
            cur[k] += leaf[k];
    }
}

int gs_face_shape_predict(const gs_face_shape_model *m, const gs_io_image *img,
                          gs_face_box box, int *pts, double *uv, gs_error *err)
{
    if (!m || !img || !img->data || img->width < 1 || img->height < 1)
        return gs_error_set(err, GS_ERR_ARG, "landmarks: no model or empty image");
    if (box.right <= box.left || box.bottom <= box.top)
        return gs_error_set(err, GS_ERR_ARG, "landmarks: empty box (%d,%d)-(%d,%d)",
                            box.left, box.top, box.right, box.bottom);
    /* dlib's unnormalizing transform: (0,0) -> top-left corner, (1,1) ->
     * bottom-right corner (inclusive corners, so the span is right - left). */
    const double b[4] = {box.left, box.top, (double)box.right - box.left,
                         (double)box.bottom - box.top};
    float cur[2 * GS_FACE_MAX_PARTS];
    float feat[GS_FACE_MAX_FEATURES];
    memcpy(cur, m->initial, (size_t)m->dim * sizeof(float));
    for (int c = 0; c < m->n_cascades; c++) {
        features(m, c, img, b, cur, feat);
        apply_forest(m, c, feat, cur);
    }
    for (int i = 0; i < m->n_parts; i++) {
        double x = b[0] + (double)cur[2 * i] * b[2];
        double y = b[1] + (double)cur[2 * i + 1] * b[3];
        if (pts) {
            pts[2 * i] = (int)floor(x + 0.5);
            pts[2 * i + 1] = (int)floor(y + 0.5);
        }
        if (uv) {
            uv[2 * i] = x + 0.5;
            uv[2 * i + 1] = y + 0.5;
        }
    }
    return GS_OK;
}
