/* safetensors writer: collects copies of the tensors, then writes them the
 * way the Python library does (tensors by element size, largest first, then
 * by name; compact JSON; the header padded with spaces to a multiple of 8
 * bytes), so the same inputs always give the same bytes and every tensor of
 * a given size class starts aligned to its element size. */
#define _POSIX_C_SOURCE 200809L /* fileno, fsync, getpid */

#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "safetensors_internal.h"

typedef struct st_entry {
    char *name;
    gs_st_dtype dt;
    int ndim;
    int64_t shape[GS_ST_MAX_DIMS];
    size_t nbytes;
    unsigned char *data; /* little-endian file bytes */
} st_entry;

typedef struct st_meta {
    char *key, *value;
} st_meta;

struct gs_st_writer {
    st_entry *e;
    int n, cap;
    int *slots;   /* open-addressing set of names: entry index + 1, 0 free */
    size_t nslots; /* a power of two, at least twice n */
    st_meta *meta;
    int nmeta, cap_meta;
};

gs_st_writer *gs_st_writer_create(void)
{
    return calloc(1, sizeof(gs_st_writer));
}

void gs_st_writer_destroy(gs_st_writer *w)
{
    if (!w)
        return;
    for (int i = 0; i < w->n; i++) {
        free(w->e[i].name);
        free(w->e[i].data);
    }
    for (int i = 0; i < w->nmeta; i++) {
        free(w->meta[i].key);
        free(w->meta[i].value);
    }
    free(w->e);
    free(w->slots);
    free(w->meta);
    free(w);
}

/* ---- name set: duplicate checks in O(1), even for 65536 tensors ------------ */

static size_t hash_name(const char *s)
{
    uint64_t h = 1469598103934665603u; /* FNV-1a */
    for (; *s; s++)
        h = (h ^ (unsigned char)*s) * 1099511628211u;
    return (size_t)h;
}

/* The slot holding name, or the free slot where it would go. */
static size_t name_slot(const gs_st_writer *w, const char *name)
{
    size_t mask = w->nslots - 1, i = hash_name(name) & mask;
    while (w->slots[i] && strcmp(w->e[w->slots[i] - 1].name, name) != 0)
        i = (i + 1) & mask;
    return i;
}

/* Makes room for one more name. */
static int reserve_slot(gs_st_writer *w)
{
    if ((size_t)w->n + 1 <= w->nslots / 2)
        return GS_OK;
    size_t nslots = w->nslots ? 2 * w->nslots : 64;
    int *slots = calloc(nslots, sizeof *slots), *old = w->slots;
    if (!slots)
        return GS_ERR_NOMEM;
    w->slots = slots;
    w->nslots = nslots;
    for (int i = 0; i < w->n; i++)
        w->slots[name_slot(w, w->e[i].name)] = i + 1;
    free(old);
    return GS_OK;
}

static int valid_utf8(const char *s, size_t *len)
{
    size_t n = strlen(s);
    for (size_t i = 0; i < n;) {
        size_t k = st_utf8_len((const unsigned char *)s + i, n - i);
        if (!k)
            return 0;
        i += k;
    }
    *len = n;
    return 1;
}

static char *dup_str(const char *s)
{
    size_t n = strlen(s) + 1;
    char *d = malloc(n);
    if (d)
        memcpy(d, s, n);
    return d;
}

int gs_st_writer_meta(gs_st_writer *w, const char *key, const char *value)
{
    size_t n;
    if (!w || !key || !value || !valid_utf8(key, &n) || !valid_utf8(value, &n))
        return GS_ERR_ARG;
    char *v = dup_str(value);
    if (!v)
        return GS_ERR_NOMEM;
    for (int i = 0; i < w->nmeta; i++)
        if (strcmp(w->meta[i].key, key) == 0) {
            free(w->meta[i].value);
            w->meta[i].value = v;
            return GS_OK;
        }
    if (w->nmeta == w->cap_meta) {
        int cap = w->cap_meta ? 2 * w->cap_meta : 8;
        st_meta *m = realloc(w->meta, (size_t)cap * sizeof *m);
        if (!m) {
            free(v);
            return GS_ERR_NOMEM;
        }
        w->meta = m;
        w->cap_meta = cap;
    }
    char *k = dup_str(key);
    if (!k) {
        free(v);
        return GS_ERR_NOMEM;
    }
    w->meta[w->nmeta].key = k;
    w->meta[w->nmeta++].value = v;
    return GS_OK;
}

/* Checks name, dtype and shape; *nbytes the data size. */
static int check_add(const char *name, gs_st_dtype dt, int ndim,
                     const int64_t *shape, size_t *nbytes)
{
    size_t len, esize = gs_st_dtype_size(dt);
    uint64_t count = 1;
    if (!name || !valid_utf8(name, &len) || len == 0 || len > GS_ST_MAX_NAME ||
        strcmp(name, "__metadata__") == 0 || !esize || ndim < 0 || ndim > GS_ST_MAX_DIMS ||
        (ndim && !shape))
        return GS_ERR_ARG;
    for (int i = 0; i < ndim; i++) {
        if (shape[i] < 0)
            return GS_ERR_ARG;
        if (shape[i] && count > (uint64_t)INT64_MAX / (uint64_t)shape[i])
            return GS_ERR_LIMIT;
        count *= (uint64_t)shape[i];
    }
    if (count > (uint64_t)INT64_MAX / esize || count * esize > SIZE_MAX)
        return GS_ERR_LIMIT;
    *nbytes = (size_t)(count * esize);
    return GS_OK;
}

int gs_st_writer_add(gs_st_writer *w, const char *name, gs_st_dtype dt, int ndim,
                     const int64_t *shape, const void *data)
{
    size_t nbytes = 0;
    if (!w)
        return GS_ERR_ARG;
    int rc = check_add(name, dt, ndim, shape, &nbytes);
    if (rc)
        return rc;
    if (nbytes && !data)
        return GS_ERR_ARG;
    if ((rc = reserve_slot(w)) != GS_OK)
        return rc;
    size_t slot = name_slot(w, name);
    if (w->slots[slot])
        return GS_ERR_ARG; /* duplicate */
    if (nbytes && st_first_nonfinite(dt, data, nbytes) != SIZE_MAX)
        return GS_ERR_NONFINITE;
    if (w->n == w->cap) {
        if (w->cap > INT32_MAX / 2)
            return GS_ERR_LIMIT;
        int cap = w->cap ? 2 * w->cap : 16;
        st_entry *e = realloc(w->e, (size_t)cap * sizeof *e);
        if (!e)
            return GS_ERR_NOMEM;
        w->e = e;
        w->cap = cap;
    }
    st_entry *e = &w->e[w->n];
    memset(e, 0, sizeof *e);
    e->name = dup_str(name);
    e->data = nbytes ? malloc(nbytes) : NULL;
    if (!e->name || (nbytes && !e->data)) {
        free(e->name);
        free(e->data);
        return GS_ERR_NOMEM;
    }
    if (nbytes) {
        memcpy(e->data, data, nbytes);
        st_swap_to_le(e->data, nbytes, gs_st_dtype_size(dt));
    }
    e->dt = dt;
    e->ndim = ndim;
    for (int i = 0; i < ndim; i++)
        e->shape[i] = shape[i];
    e->nbytes = nbytes;
    w->slots[slot] = ++w->n;
    return GS_OK;
}

/* ---- serialization ------------------------------------------------------ */

typedef struct sbuf {
    char *p;
    size_t len, cap;
    int oom;
} sbuf;

static void put_mem(sbuf *b, const char *s, size_t n)
{
    if (b->oom)
        return;
    if (b->len + n > b->cap) {
        size_t cap = b->cap ? b->cap : 256;
        while (cap < b->len + n)
            cap *= 2;
        char *p = realloc(b->p, cap);
        if (!p) {
            b->oom = 1;
            return;
        }
        b->p = p;
        b->cap = cap;
    }
    memcpy(b->p + b->len, s, n);
    b->len += n;
}

static void put(sbuf *b, const char *s)
{
    put_mem(b, s, strlen(s));
}

/* A JSON string as serde_json writes it: \" \\ \b \f \n \r \t, other
 * control characters as \u00xx, everything else (UTF-8) as is. */
static void put_json_string(sbuf *b, const char *s)
{
    put(b, "\"");
    for (const char *run = s;; s++) {
        unsigned char c = (unsigned char)*s;
        if (c >= 0x20 && c != '"' && c != '\\')
            continue;
        put_mem(b, run, (size_t)(s - run));
        if (!c)
            break;
        char esc[8];
        const char *short_form = strchr("\"\\\b\f\n\r\t", c);
        if (short_form)
            snprintf(esc, sizeof esc, "\\%c", "\"\\bfnrt"[short_form - "\"\\\b\f\n\r\t"]);
        else
            snprintf(esc, sizeof esc, "\\u%04x", c);
        put(b, esc);
        run = s + 1;
    }
    put(b, "\"");
}

/* Larger elements first (the Python library's order: I64, F32, I32, F16,
 * U8), then names in byte order. */
static int dtype_rank(gs_st_dtype dt)
{
    static const int rank[] = {[GS_ST_I64] = 0, [GS_ST_F32] = 1, [GS_ST_I32] = 2,
                               [GS_ST_F16] = 3, [GS_ST_U8] = 4};
    return rank[dt];
}

static int cmp_entry(const void *a, const void *b)
{
    const st_entry *const *x = a, *const *y = b;
    int rx = dtype_rank((*x)->dt), ry = dtype_rank((*y)->dt);
    return rx != ry ? rx - ry : strcmp((*x)->name, (*y)->name);
}

static int cmp_meta(const void *a, const void *b)
{
    return strcmp(((const st_meta *)a)->key, ((const st_meta *)b)->key);
}

/* The padded JSON header (b) and the tensors in file order (*order,
 * malloc'd); *data_len the byte buffer's size. */
static int build(gs_st_writer *w, sbuf *b, st_entry ***order, size_t *data_len, gs_error *err)
{
    st_entry **o = malloc((size_t)(w->n ? w->n : 1) * sizeof *o);
    char num[64];
    size_t at = 0;
    if (!o)
        return gs_error_set(err, GS_ERR_NOMEM, ST_ERR "out of memory");
    for (int i = 0; i < w->n; i++)
        o[i] = &w->e[i];
    if (w->n)
        qsort(o, (size_t)w->n, sizeof *o, cmp_entry);
    if (w->nmeta)
        qsort(w->meta, (size_t)w->nmeta, sizeof *w->meta, cmp_meta);
    put(b, "{");
    if (w->nmeta) {
        put(b, "\"__metadata__\":{");
        for (int i = 0; i < w->nmeta; i++) {
            put(b, i ? "," : "");
            put_json_string(b, w->meta[i].key);
            put(b, ":");
            put_json_string(b, w->meta[i].value);
        }
        put(b, "}");
    }
    for (int i = 0; i < w->n; i++) {
        const st_entry *e = o[i];
        put(b, i || w->nmeta ? "," : "");
        put_json_string(b, e->name);
        put(b, ":{\"dtype\":\"");
        put(b, gs_st_dtype_name(e->dt));
        put(b, "\",\"shape\":[");
        for (int d = 0; d < e->ndim; d++) {
            snprintf(num, sizeof num, "%s%lld", d ? "," : "", (long long)e->shape[d]);
            put(b, num);
        }
        if (e->nbytes > SIZE_MAX - at) {
            free(o);
            return gs_error_set(err, GS_ERR_LIMIT, ST_ERR "tensors over %zu bytes", SIZE_MAX);
        }
        snprintf(num, sizeof num, "],\"data_offsets\":[%zu,%zu]}", at, at + e->nbytes);
        put(b, num);
        at += e->nbytes;
    }
    put(b, "}");
    while (b->len % 8)
        put(b, " ");
    if (b->oom) {
        free(o);
        return gs_error_set(err, GS_ERR_NOMEM, ST_ERR "out of memory");
    }
    *order = o;
    *data_len = at;
    return GS_OK;
}

static void u64le(unsigned char *out, uint64_t v)
{
    for (int i = 0; i < 8; i++)
        out[i] = (unsigned char)(v >> (8 * i));
}

int gs_st_writer_to_mem(gs_st_writer *w, uint8_t **buf, size_t *len, gs_error *err)
{
    sbuf b = {0};
    st_entry **order;
    size_t data_len;
    if (!w || !buf || !len)
        return gs_error_set(err, GS_ERR_ARG, ST_ERR "NULL argument");
    int rc = build(w, &b, &order, &data_len, err);
    if (rc) {
        free(b.p);
        return rc;
    }
    if (data_len > SIZE_MAX - 8 - b.len) {
        free(b.p);
        free(order);
        return gs_error_set(err, GS_ERR_LIMIT, ST_ERR "file over %zu bytes", SIZE_MAX);
    }
    size_t total = 8 + b.len + data_len;
    uint8_t *out = malloc(total);
    if (!out) {
        free(b.p);
        free(order);
        return gs_error_set(err, GS_ERR_NOMEM, ST_ERR "cannot allocate %zu bytes", total);
    }
    u64le(out, b.len);
    memcpy(out + 8, b.p, b.len);
    size_t at = 8 + b.len;
    for (int i = 0; i < w->n; i++) {
        if (order[i]->nbytes)
            memcpy(out + at, order[i]->data, order[i]->nbytes);
        at += order[i]->nbytes;
    }
    free(b.p);
    free(order);
    *buf = out;
    *len = total;
    return GS_OK;
}

static int write_all(FILE *f, const sbuf *b, st_entry *const *order, int n)
{
    unsigned char prefix[8];
    u64le(prefix, b->len);
    int ok = fwrite(prefix, 1, 8, f) == 8 && fwrite(b->p, 1, b->len, f) == b->len;
    for (int i = 0; ok && i < n; i++)
        ok = !order[i]->nbytes || fwrite(order[i]->data, 1, order[i]->nbytes, f) == order[i]->nbytes;
    return ok && fflush(f) == 0 && fsync(fileno(f)) == 0;
}

int gs_st_writer_save(gs_st_writer *w, const char *path, gs_error *err)
{
    sbuf b = {0};
    st_entry **order;
    size_t data_len;
    char tmp[4096];
    if (!w || !path)
        return gs_error_set(err, GS_ERR_ARG, ST_ERR "NULL argument");
    if (snprintf(tmp, sizeof tmp, "%s.tmp.%ld", path, (long)getpid()) >= (int)sizeof tmp)
        return gs_error_set(err, GS_ERR_ARG, ST_ERR "path too long");
    int rc = build(w, &b, &order, &data_len, err);
    if (rc) {
        free(b.p);
        return rc;
    }
    FILE *f = fopen(tmp, "wb");
    if (!f) {
        rc = gs_error_set(err, GS_ERR_IO, ST_ERR "cannot create %s: %s", tmp, strerror(errno));
    } else {
        int ok = write_all(f, &b, order, w->n);
        int saved = errno;
        if (fclose(f) != 0 && ok)
            ok = 0, saved = errno;
        if (ok && rename(tmp, path) != 0)
            ok = 0, saved = errno;
        if (!ok) {
            remove(tmp);
            rc = gs_error_set(err, GS_ERR_IO, ST_ERR "cannot write %s: %s", path,
                              strerror(saved));
        }
    }
    free(b.p);
    free(order);
    return rc;
}
