/* safetensors reader: a strict parser for exactly the header the spec
 * describes (no general JSON tree), then the layout checks, then one copy
 * of each tensor into its own 8-byte aligned slot.
 *
 * Header grammar accepted (JSON whitespace between tokens, only spaces
 * after the closing brace, the first byte must be '{'):
 *   header  = '{' [ entry (',' entry)* ] '}'
 *   entry   = string ':' ( tensor | meta )   -- meta when the key is "__metadata__"
 *   tensor  = '{' "dtype": string, "shape": '[' uint,* ']', "data_offsets": '[' uint ',' uint ']' '}'
 *             (the three keys once each, in any order, no others)
 *   meta    = '{' [ string ':' string (',' ...)* ] '}'
 *   uint    = '0' | [1-9][0-9]*  (at most INT64_MAX) */
#define _POSIX_C_SOURCE 200809L /* fileno, fstat */

#include <errno.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

#include "safetensors_internal.h"

typedef struct st_kv {
    const char *key, *value;
} st_kv;

struct gs_st_file {
    gs_st_tensor *t;            /* file order */
    const gs_st_tensor **by_name;
    int n;
    st_kv *meta;                /* key order */
    int nmeta;
    char *strings;              /* every name, key and value, NUL-terminated */
    unsigned char *data;        /* the tensors' aligned slots */
};

/* ---- dtypes ------------------------------------------------------------- */

static const char *const dtype_names[] = {"F32", "F16", "I32", "I64", "U8"};
static const size_t dtype_sizes[] = {4, 2, 4, 8, 1};
/* In the spec, valid elsewhere, not here. */
static const char *const other_dtypes[] = {"F64", "BF16", "I8", "I16", "U16", "U32", "U64",
                                           "BOOL", "F8_E4M3", "F8_E5M2", "F8_E8M0", "F4",
                                           "F6_E2M3", "F6_E3M2", "C64"};

size_t gs_st_dtype_size(gs_st_dtype dt)
{
    return (unsigned)dt < 5 ? dtype_sizes[dt] : 0;
}

const char *gs_st_dtype_name(gs_st_dtype dt)
{
    return (unsigned)dt < 5 ? dtype_names[dt] : "?";
}

/* ---- header parser ------------------------------------------------------ */

typedef struct st_parser {
    const unsigned char *p, *begin, *end;
    char *arena;        /* decoded strings; never outgrows the header */
    size_t arena_used;
    size_t data_len;    /* bytes after the header */
    int max_tensors, cap_t, cap_m, have_meta;
    gs_st_file *f;
    gs_error *err;
} st_parser;

static int perr(st_parser *ps, int code, const char *fmt, ...) __attribute__((format(printf, 3, 4)));
static int perr(st_parser *ps, int code, const char *fmt, ...)
{
    char msg[200];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(msg, sizeof msg, fmt, ap);
    va_end(ap);
    return gs_error_set(ps->err, code, ST_ERR "header byte %zu: %s",
                        (size_t)(ps->p - ps->begin), msg);
}

static void skip_ws(st_parser *ps)
{
    while (ps->p < ps->end &&
           (*ps->p == ' ' || *ps->p == '\t' || *ps->p == '\n' || *ps->p == '\r'))
        ps->p++;
}

static int expect(st_parser *ps, char ch)
{
    skip_ws(ps);
    if (ps->p >= ps->end)
        return perr(ps, GS_ERR_FORMAT, "expected '%c', found the end of the header", ch);
    if (*ps->p != (unsigned char)ch)
        return perr(ps, GS_ERR_FORMAT, "expected '%c', found '%c'", ch,
                    *ps->p >= 0x20 && *ps->p < 0x7F ? *ps->p : '?');
    ps->p++;
    return GS_OK;
}

static int hex4(st_parser *ps, uint32_t *out)
{
    uint32_t v = 0;
    if (ps->end - ps->p < 4)
        return perr(ps, GS_ERR_FORMAT, "truncated \\u escape");
    for (int i = 0; i < 4; i++) {
        unsigned c = ps->p[i];
        int d = c >= '0' && c <= '9' ? (int)c - '0'
              : c >= 'a' && c <= 'f' ? (int)c - 'a' + 10
              : c >= 'A' && c <= 'F' ? (int)c - 'A' + 10 : -1;
        if (d < 0)
            return perr(ps, GS_ERR_FORMAT, "bad hex digit in \\u escape");
        v = v << 4 | (uint32_t)d;
    }
    ps->p += 4;
    *out = v;
    return GS_OK;
}

static void put_utf8(st_parser *ps, uint32_t cp)
{
    char *o = ps->arena + ps->arena_used;
    if (cp < 0x80) {
        o[0] = (char)cp, ps->arena_used += 1;
    } else if (cp < 0x800) {
        o[0] = (char)(0xC0 | cp >> 6), o[1] = (char)(0x80 | (cp & 0x3F));
        ps->arena_used += 2;
    } else if (cp < 0x10000) {
        o[0] = (char)(0xE0 | cp >> 12), o[1] = (char)(0x80 | (cp >> 6 & 0x3F));
        o[2] = (char)(0x80 | (cp & 0x3F));
        ps->arena_used += 3;
    } else {
        o[0] = (char)(0xF0 | cp >> 18), o[1] = (char)(0x80 | (cp >> 12 & 0x3F));
        o[2] = (char)(0x80 | (cp >> 6 & 0x3F)), o[3] = (char)(0x80 | (cp & 0x3F));
        ps->arena_used += 4;
    }
}

/* After the backslash of \uXXXX: one code point, a surrogate pair joined;
 * lone surrogates and U+0000 (it would cut a C string) are refused. */
static int unicode_escape(st_parser *ps)
{
    uint32_t cp, lo;
    int rc = hex4(ps, &cp);
    if (rc)
        return rc;
    if (cp >= 0xDC00 && cp <= 0xDFFF)
        return perr(ps, GS_ERR_FORMAT, "lone low surrogate in \\u escape");
    if (cp >= 0xD800 && cp <= 0xDBFF) {
        if (ps->end - ps->p < 2 || ps->p[0] != '\\' || ps->p[1] != 'u')
            return perr(ps, GS_ERR_FORMAT, "high surrogate without its low half");
        ps->p += 2;
        if ((rc = hex4(ps, &lo)) != GS_OK)
            return rc;
        if (lo < 0xDC00 || lo > 0xDFFF)
            return perr(ps, GS_ERR_FORMAT, "high surrogate without its low half");
        cp = 0x10000 + ((cp - 0xD800) << 10) + (lo - 0xDC00);
    }
    if (cp == 0)
        return perr(ps, GS_ERR_FORMAT, "\\u0000 in a string");
    put_utf8(ps, cp);
    return GS_OK;
}

static int escape(st_parser *ps)
{
    static const char from[] = "\"\\/bfnrt", to[] = "\"\\/\b\f\n\r\t";
    if (ps->p >= ps->end)
        return perr(ps, GS_ERR_FORMAT, "unterminated string");
    unsigned char c = *ps->p++;
    if (c == 'u')
        return unicode_escape(ps);
    const char *hit = c ? strchr(from, c) : NULL;
    if (!hit) {
        ps->p--;
        return perr(ps, GS_ERR_FORMAT, "bad escape in string");
    }
    ps->arena[ps->arena_used++] = to[hit - from];
    return GS_OK;
}

/* A JSON string, decoded into the arena: *out (NUL-terminated), *len. The
 * decoded bytes plus NUL never exceed the encoded bytes with quotes, so the
 * arena (header length + 1) cannot overflow. */
static int parse_string(st_parser *ps, const char **out, size_t *len)
{
    int rc = expect(ps, '"');
    if (rc)
        return rc;
    size_t start = ps->arena_used;
    for (;;) {
        if (ps->p >= ps->end)
            return perr(ps, GS_ERR_FORMAT, "unterminated string");
        unsigned char c = *ps->p;
        if (c == '"') {
            ps->p++;
            break;
        }
        if (c < 0x20)
            return perr(ps, GS_ERR_FORMAT, "control character 0x%02x in a string", c);
        if (c == '\\') {
            ps->p++;
            if ((rc = escape(ps)) != GS_OK)
                return rc;
            continue;
        }
        size_t k = st_utf8_len(ps->p, (size_t)(ps->end - ps->p));
        if (!k)
            return perr(ps, GS_ERR_FORMAT, "invalid UTF-8 in a string");
        memcpy(ps->arena + ps->arena_used, ps->p, k);
        ps->arena_used += k;
        ps->p += k;
    }
    ps->arena[ps->arena_used] = '\0';
    *out = ps->arena + start;
    *len = ps->arena_used - start;
    ps->arena_used++;
    return GS_OK;
}

static int parse_uint(st_parser *ps, int64_t *out)
{
    skip_ws(ps);
    if (ps->p < ps->end && *ps->p == '-')
        return perr(ps, GS_ERR_FORMAT, "negative integer");
    if (ps->p >= ps->end || *ps->p < '0' || *ps->p > '9')
        return perr(ps, GS_ERR_FORMAT, "expected an integer");
    int64_t v = 0;
    const unsigned char *start = ps->p;
    while (ps->p < ps->end && *ps->p >= '0' && *ps->p <= '9') {
        int d = *ps->p - '0';
        if (v > (INT64_MAX - d) / 10)
            return perr(ps, GS_ERR_FORMAT, "integer larger than 2^63-1");
        v = v * 10 + d;
        ps->p++;
    }
    if (*start == '0' && ps->p - start > 1)
        return perr(ps, GS_ERR_FORMAT, "integer with a leading zero");
    if (ps->p < ps->end && (*ps->p == '.' || *ps->p == 'e' || *ps->p == 'E'))
        return perr(ps, GS_ERR_FORMAT, "not an integer (fraction or exponent)");
    *out = v;
    return GS_OK;
}

/* '[' uint,* ']' into v[0..max); *n the count. More than max is refused
 * with too_many_code (GS_ERR_LIMIT for shapes, GS_ERR_FORMAT for offsets). */
static int parse_uint_array(st_parser *ps, int64_t *v, int max, int *n, int too_many_code,
                            const char *name, const char *what)
{
    int rc = expect(ps, '[');
    if (rc)
        return rc;
    *n = 0;
    skip_ws(ps);
    if (ps->p < ps->end && *ps->p == ']') {
        ps->p++;
        return GS_OK;
    }
    for (;;) {
        if (*n == max)
            return perr(ps, too_many_code, "tensor '%s': %s has more than %d entries", name, what,
                        max);
        if ((rc = parse_uint(ps, &v[(*n)++])) != GS_OK)
            return rc;
        skip_ws(ps);
        if (ps->p < ps->end && *ps->p == ',') {
            ps->p++;
            continue;
        }
        return expect(ps, ']');
    }
}

static int parse_dtype(st_parser *ps, const char *name, gs_st_dtype *dt)
{
    const char *s;
    size_t len;
    int rc = parse_string(ps, &s, &len);
    if (rc)
        return rc;
    for (int i = 0; i < 5; i++)
        if (strcmp(s, dtype_names[i]) == 0) {
            *dt = (gs_st_dtype)i;
            return GS_OK;
        }
    for (size_t i = 0; i < sizeof other_dtypes / sizeof *other_dtypes; i++)
        if (strcmp(s, other_dtypes[i]) == 0)
            return perr(ps, GS_ERR_UNSUPPORTED, "tensor '%s': dtype %s not supported "
                        "(F32, F16, I32, I64, U8)", name, s);
    return perr(ps, GS_ERR_FORMAT, "tensor '%s': unknown dtype '%.32s'", name, s);
}

/* The element count and byte size of t's shape; every product checked. */
static int check_sizes(st_parser *ps, gs_st_tensor *t, int64_t begin, int64_t end)
{
    uint64_t count = 1, esize = dtype_sizes[t->dtype];
    for (int i = 0; i < t->ndim; i++) {
        uint64_t d = (uint64_t)t->shape[i];
        if (d && count > (uint64_t)INT64_MAX / d)
            return perr(ps, GS_ERR_FORMAT, "tensor '%s': shape product overflows", t->name);
        count *= d;
    }
    if (count > (uint64_t)INT64_MAX / esize || count * esize > SIZE_MAX)
        return perr(ps, GS_ERR_FORMAT, "tensor '%s': byte size overflows", t->name);
    if (begin > end)
        return perr(ps, GS_ERR_FORMAT, "tensor '%s': data_offsets [%lld, %lld] begin after end",
                    t->name, (long long)begin, (long long)end);
    if ((uint64_t)end > ps->data_len)
        return perr(ps, GS_ERR_FORMAT, "tensor '%s': data_offsets [%lld, %lld] beyond the "
                    "byte buffer (%zu bytes)", t->name, (long long)begin, (long long)end,
                    ps->data_len);
    if ((uint64_t)(end - begin) != count * esize)
        return perr(ps, GS_ERR_FORMAT, "tensor '%s': data_offsets span %lld bytes, shape and "
                    "dtype %s need %llu", t->name, (long long)(end - begin),
                    dtype_names[t->dtype], (unsigned long long)(count * esize));
    t->offset = (size_t)begin;
    t->nbytes = (size_t)(end - begin);
    return GS_OK;
}

static int grow(void **arr, int *cap, int need, size_t elem)
{
    if (need <= *cap)
        return GS_OK;
    if (*cap > INT32_MAX / 2)
        return GS_ERR_NOMEM;
    int ncap = *cap ? *cap * 2 : 16;
    void *p = realloc(*arr, (size_t)ncap * elem);
    if (!p)
        return GS_ERR_NOMEM;
    *arr = p;
    *cap = ncap;
    return GS_OK;
}

/* Body of one tensor entry: the object after "name":. */
static int parse_tensor(st_parser *ps, const char *name, size_t name_len)
{
    gs_st_file *f = ps->f;
    if (name_len == 0)
        return perr(ps, GS_ERR_FORMAT, "empty tensor name");
    if (name_len > GS_ST_MAX_NAME)
        return perr(ps, GS_ERR_LIMIT, "tensor name of %zu bytes (at most %d): '%.40s...'",
                    name_len, GS_ST_MAX_NAME, name);
    if (f->n >= ps->max_tensors)
        return perr(ps, GS_ERR_LIMIT, "more than %d tensors", ps->max_tensors);
    if (grow((void **)&f->t, &ps->cap_t, f->n + 1, sizeof *f->t))
        return perr(ps, GS_ERR_NOMEM, "out of memory");
    gs_st_tensor *t = &f->t[f->n];
    memset(t, 0, sizeof *t);
    t->name = name;
    int64_t off[2];
    int seen = 0, rc, k;
    if ((rc = expect(ps, '{')) != GS_OK)
        return rc;
    for (;;) {
        const char *key;
        size_t klen;
        int bit;
        if ((rc = parse_string(ps, &key, &klen)) || (rc = expect(ps, ':')))
            return rc;
        bit = !strcmp(key, "dtype") ? 1 : !strcmp(key, "shape") ? 2
            : !strcmp(key, "data_offsets") ? 4 : 0;
        if (!bit)
            return perr(ps, GS_ERR_FORMAT, "tensor '%s': unknown key '%.32s'", name, key);
        if (seen & bit)
            return perr(ps, GS_ERR_FORMAT, "tensor '%s': duplicate key '%s'", name, key);
        seen |= bit;
        if (bit == 1)
            rc = parse_dtype(ps, name, &t->dtype);
        else if (bit == 2)
            rc = parse_uint_array(ps, t->shape, GS_ST_MAX_DIMS, &t->ndim, GS_ERR_LIMIT, name,
                                  "shape");
        else if ((rc = parse_uint_array(ps, off, 2, &k, GS_ERR_FORMAT, name, "data_offsets")) == GS_OK &&
                 k != 2)
            rc = perr(ps, GS_ERR_FORMAT, "tensor '%s': data_offsets needs 2 entries", name);
        if (rc)
            return rc;
        skip_ws(ps);
        if (ps->p < ps->end && *ps->p == ',') {
            ps->p++;
            continue;
        }
        if ((rc = expect(ps, '}')) != GS_OK)
            return rc;
        break;
    }
    if (seen != 7)
        return perr(ps, GS_ERR_FORMAT, "tensor '%s': no '%s'", name,
                    !(seen & 1) ? "dtype" : !(seen & 2) ? "shape" : "data_offsets");
    if ((rc = check_sizes(ps, t, off[0], off[1])) != GS_OK)
        return rc;
    f->n++;
    return GS_OK;
}

/* The object after "__metadata__":, string values only. */
static int parse_meta(st_parser *ps)
{
    gs_st_file *f = ps->f;
    int rc;
    if (ps->have_meta)
        return perr(ps, GS_ERR_FORMAT, "duplicate key '__metadata__'");
    ps->have_meta = 1;
    if ((rc = expect(ps, '{')) != GS_OK)
        return rc;
    skip_ws(ps);
    if (ps->p < ps->end && *ps->p == '}') {
        ps->p++;
        return GS_OK;
    }
    for (;;) {
        const char *key, *value;
        size_t klen, vlen;
        if ((rc = parse_string(ps, &key, &klen)) || (rc = expect(ps, ':')))
            return rc;
        skip_ws(ps);
        if (ps->p < ps->end && *ps->p != '"')
            return perr(ps, GS_ERR_FORMAT, "__metadata__ value of '%.40s' is not a string", key);
        if ((rc = parse_string(ps, &value, &vlen)) != GS_OK)
            return rc;
        if (grow((void **)&f->meta, &ps->cap_m, f->nmeta + 1, sizeof *f->meta))
            return perr(ps, GS_ERR_NOMEM, "out of memory");
        f->meta[f->nmeta].key = key;
        f->meta[f->nmeta++].value = value;
        skip_ws(ps);
        if (ps->p < ps->end && *ps->p == ',') {
            ps->p++;
            continue;
        }
        return expect(ps, '}');
    }
}

static int parse_header(st_parser *ps)
{
    int rc;
    if (ps->p >= ps->end || *ps->p != '{')
        return perr(ps, GS_ERR_FORMAT, "the header does not start with '{'");
    ps->p++;
    skip_ws(ps);
    if (ps->p < ps->end && *ps->p == '}') {
        ps->p++;
    } else {
        for (;;) {
            const char *key;
            size_t klen;
            if ((rc = parse_string(ps, &key, &klen)) || (rc = expect(ps, ':')))
                return rc;
            rc = strcmp(key, "__metadata__") == 0 ? parse_meta(ps) : parse_tensor(ps, key, klen);
            if (rc)
                return rc;
            skip_ws(ps);
            if (ps->p < ps->end && *ps->p == ',') {
                ps->p++;
                continue;
            }
            if ((rc = expect(ps, '}')) != GS_OK)
                return rc;
            break;
        }
    }
    while (ps->p < ps->end && *ps->p == ' ')
        ps->p++;
    if (ps->p != ps->end)
        return perr(ps, GS_ERR_FORMAT, "bytes after the header object (only spaces may pad it)");
    return GS_OK;
}

/* ---- layout ------------------------------------------------------------- */

static int cmp_offset(const void *a, const void *b)
{
    const gs_st_tensor *x = a, *y = b;
    if (x->offset != y->offset)
        return x->offset < y->offset ? -1 : 1;
    if (x->nbytes != y->nbytes)
        return x->nbytes < y->nbytes ? -1 : 1;
    return strcmp(x->name, y->name);
}

static int cmp_name(const void *a, const void *b)
{
    const gs_st_tensor *const *x = a, *const *y = b;
    return strcmp((*x)->name, (*y)->name);
}

static int cmp_key(const void *a, const void *b)
{
    return strcmp(((const st_kv *)a)->key, ((const st_kv *)b)->key);
}

/* Sorts, refuses duplicates, and checks that the tensors tile the byte
 * buffer [0, data_len) exactly: no hole, no overlap, nothing left over. */
static int check_layout(gs_st_file *f, size_t data_len, gs_error *err)
{
    if (f->n)
        qsort(f->t, (size_t)f->n, sizeof *f->t, cmp_offset);
    if (f->nmeta)
        qsort(f->meta, (size_t)f->nmeta, sizeof *f->meta, cmp_key);
    for (int i = 1; i < f->nmeta; i++)
        if (strcmp(f->meta[i - 1].key, f->meta[i].key) == 0)
            return gs_error_set(err, GS_ERR_FORMAT, ST_ERR "duplicate __metadata__ key '%.60s'",
                                f->meta[i].key);
    f->by_name = malloc((size_t)(f->n ? f->n : 1) * sizeof *f->by_name);
    if (!f->by_name)
        return gs_error_set(err, GS_ERR_NOMEM, ST_ERR "out of memory");
    for (int i = 0; i < f->n; i++)
        f->by_name[i] = &f->t[i];
    if (f->n)
        qsort(f->by_name, (size_t)f->n, sizeof *f->by_name, cmp_name);
    for (int i = 1; i < f->n; i++)
        if (strcmp(f->by_name[i - 1]->name, f->by_name[i]->name) == 0)
            return gs_error_set(err, GS_ERR_FORMAT, ST_ERR "duplicate tensor name '%.60s'",
                                f->by_name[i]->name);
    size_t at = 0;
    for (int i = 0; i < f->n; i++) {
        const gs_st_tensor *t = &f->t[i];
        if (t->offset > at)
            return gs_error_set(err, GS_ERR_FORMAT, ST_ERR "hole in the byte buffer: bytes "
                                "[%zu, %zu) before tensor '%.60s' belong to no tensor", at,
                                t->offset, t->name);
        if (t->offset < at)
            return gs_error_set(err, GS_ERR_FORMAT, ST_ERR "tensor '%.60s' at [%zu, %zu) "
                                "overlaps '%.60s' before it, which ends at %zu", t->name,
                                t->offset, t->offset + t->nbytes, f->t[i - 1].name, at);
        at = t->offset + t->nbytes;
    }
    if (at != data_len)
        return gs_error_set(err, GS_ERR_FORMAT, ST_ERR "the byte buffer has %zu bytes but the "
                            "tensors cover %zu", data_len, at);
    return GS_OK;
}

/* ---- loading ------------------------------------------------------------ */

/* Where the byte buffer comes from: memory, or a file read front to back
 * (the tensors tile the buffer in offset order, so reads are sequential). */
typedef struct st_source {
    const unsigned char *mem;
    FILE *file;
    const char *path;
} st_source;

static int read_bytes(const st_source *src, size_t off, void *dst, size_t n, gs_error *err)
{
    if (!n)
        return GS_OK;
    if (src->mem) {
        memcpy(dst, src->mem + off, n);
        return GS_OK;
    }
    if (fread(dst, 1, n, src->file) != n)
        return gs_error_set(err, GS_ERR_IO, ST_ERR "%s: read failed or file shrank: %s",
                            src->path, ferror(src->file) ? strerror(errno) : "early end");
    return GS_OK;
}

static size_t round8(size_t n)
{
    return (n + 7) & ~(size_t)7;
}

/* Copies one tensor into dst, converts byte order and checks its floats,
 * a chunk at a time so the check reads what the copy left in cache. */
#define ST_CHUNK ((size_t)256 << 10) /* a multiple of every element size */

static int load_tensor(const gs_st_tensor *t, unsigned char *dst, const st_source *src,
                       gs_error *err)
{
    size_t esize = dtype_sizes[t->dtype];
    for (size_t k = 0; k < t->nbytes; k += ST_CHUNK) {
        size_t c = t->nbytes - k < ST_CHUNK ? t->nbytes - k : ST_CHUNK;
        int rc = read_bytes(src, t->offset + k, dst + k, c, err);
        if (rc)
            return rc;
        st_swap_to_le(dst + k, c, esize);
        size_t bad = st_first_nonfinite(t->dtype, dst + k, c);
        if (bad != SIZE_MAX)
            return gs_error_set(err, GS_ERR_NONFINITE, ST_ERR "tensor '%.60s' (%s): element %zu "
                                "is NaN or Inf", t->name, dtype_names[t->dtype], k / esize + bad);
    }
    return GS_OK;
}

/* Gives every tensor its 8-byte aligned slot in one allocation and loads it. */
static int load_data(gs_st_file *f, const st_source *src, gs_error *err)
{
    size_t total = 0;
    for (int i = 0; i < f->n; i++)
        total += round8(f->t[i].nbytes); /* <= data_len + 7n: no overflow */
    f->data = malloc(total ? total : 1);
    if (!f->data)
        return gs_error_set(err, GS_ERR_NOMEM, ST_ERR "cannot allocate %zu bytes", total);
    size_t slot = 0;
    for (int i = 0; i < f->n; i++) {
        gs_st_tensor *t = &f->t[i];
        int rc = load_tensor(t, f->data + slot, src, err);
        if (rc)
            return rc;
        t->data = f->data + slot;
        slot += round8(t->nbytes);
    }
    return GS_OK;
}

static void resolve_limits(const gs_st_limits *lim, gs_st_limits *out)
{
    out->max_file_bytes = lim && lim->max_file_bytes ? lim->max_file_bytes : GS_ST_DEFAULT_MAX_FILE;
    out->max_header_bytes =
        lim && lim->max_header_bytes ? lim->max_header_bytes : GS_ST_DEFAULT_MAX_HEADER;
    out->max_tensors = lim && lim->max_tensors > 0 ? lim->max_tensors : GS_ST_DEFAULT_MAX_TENSORS;
}

static uint64_t read_u64le(const unsigned char *b)
{
    uint64_t v = 0;
    for (int i = 7; i >= 0; i--)
        v = v << 8 | b[i];
    return v;
}

/* Checks the file length and header length N (from its 8 bytes). */
static int check_prefix(size_t len, const unsigned char *prefix, const gs_st_limits *lim,
                        size_t *hlen, gs_error *err)
{
    if (len > lim->max_file_bytes)
        return gs_error_set(err, GS_ERR_LIMIT, ST_ERR "file of %zu bytes over the limit of %zu",
                            len, lim->max_file_bytes);
    if (len < 8)
        return gs_error_set(err, GS_ERR_FORMAT, ST_ERR "file of %zu bytes, shorter than its "
                            "8-byte header length", len);
    uint64_t n = read_u64le(prefix);
    if (n > lim->max_header_bytes)
        return gs_error_set(err, GS_ERR_LIMIT, ST_ERR "header length %llu over the limit of %zu",
                            (unsigned long long)n, lim->max_header_bytes);
    if (n > len - 8)
        return gs_error_set(err, GS_ERR_FORMAT, ST_ERR "header length %llu beyond the end of "
                            "the file (%zu bytes)", (unsigned long long)n, len);
    *hlen = (size_t)n;
    return GS_OK;
}

/* Parses the header (hlen bytes), checks the layout, loads the data. */
static int load(const unsigned char *header, size_t hlen, size_t data_len, int max_tensors,
                const st_source *src, gs_st_file **out, gs_error *err)
{
    gs_st_file *f = calloc(1, sizeof *f);
    st_parser ps = {.p = header, .begin = header, .end = header + hlen, .data_len = data_len,
                    .max_tensors = max_tensors, .f = f, .err = err};
    int rc = GS_ERR_NOMEM;
    if (f)
        f->strings = ps.arena = malloc(hlen + 1);
    if (!f || !f->strings)
        gs_error_set(err, rc, ST_ERR "out of memory");
    else if ((rc = parse_header(&ps)) == GS_OK && (rc = check_layout(f, data_len, err)) == GS_OK)
        rc = load_data(f, src, err);
    if (rc) {
        gs_st_close(f);
        return rc;
    }
    *out = f;
    return GS_OK;
}

int gs_st_open_mem(const void *buf, size_t len, const gs_st_limits *lim, gs_st_file **out,
                   gs_error *err)
{
    gs_st_limits L;
    size_t hlen;
    const unsigned char *b = buf;
    if (!out || (!buf && len))
        return gs_error_set(err, GS_ERR_ARG, ST_ERR "NULL argument");
    resolve_limits(lim, &L);
    int rc = check_prefix(len, b, &L, &hlen, err);
    if (rc)
        return rc;
    st_source src = {b + 8 + hlen, NULL, NULL};
    return load(b + 8, hlen, len - 8 - hlen, L.max_tensors, &src, out, err);
}

int gs_st_open(const char *path, const gs_st_limits *lim, gs_st_file **out, gs_error *err)
{
    gs_st_limits L;
    struct stat st;
    unsigned char prefix[8];
    size_t hlen = 0, len;
    if (!path || !out)
        return gs_error_set(err, GS_ERR_ARG, ST_ERR "NULL argument");
    resolve_limits(lim, &L);
    FILE *fp = fopen(path, "rb");
    if (!fp)
        return gs_error_set(err, GS_ERR_IO, ST_ERR "cannot open %s: %s", path, strerror(errno));
    int rc;
    if (fstat(fileno(fp), &st) != 0 || !S_ISREG(st.st_mode)) {
        rc = gs_error_set(err, GS_ERR_IO, ST_ERR "%s is not a regular file", path);
    } else if ((uintmax_t)st.st_size > SIZE_MAX) {
        rc = gs_error_set(err, GS_ERR_LIMIT, ST_ERR "%s is too large", path);
    } else {
        len = (size_t)st.st_size;
        memset(prefix, 0, sizeof prefix);
        rc = len >= 8 && fread(prefix, 1, 8, fp) != 8
                 ? gs_error_set(err, GS_ERR_IO, ST_ERR "cannot read %s", path)
                 : check_prefix(len, prefix, &L, &hlen, err);
        unsigned char *header = rc ? NULL : malloc(hlen ? hlen : 1);
        if (!rc && !header)
            rc = gs_error_set(err, GS_ERR_NOMEM, ST_ERR "cannot allocate %zu bytes", hlen);
        if (!rc && fread(header, 1, hlen, fp) != hlen)
            rc = gs_error_set(err, GS_ERR_IO, ST_ERR "cannot read the header of %s", path);
        if (!rc) {
            st_source src = {NULL, fp, path};
            rc = load(header, hlen, len - 8 - hlen, L.max_tensors, &src, out, err);
        }
        free(header);
    }
    fclose(fp);
    return rc;
}

void gs_st_close(gs_st_file *f)
{
    if (!f)
        return;
    free(f->t);
    free(f->by_name);
    free(f->meta);
    free(f->strings);
    free(f->data);
    free(f);
}

/* ---- queries ------------------------------------------------------------ */

int gs_st_count(const gs_st_file *f)
{
    return f ? f->n : 0;
}

const gs_st_tensor *gs_st_at(const gs_st_file *f, int i)
{
    return f && i >= 0 && i < f->n ? &f->t[i] : NULL;
}

const gs_st_tensor *gs_st_find(const gs_st_file *f, const char *name)
{
    if (!f || !name)
        return NULL;
    int lo = 0, hi = f->n;
    while (lo < hi) {
        int mid = lo + (hi - lo) / 2, c = strcmp(f->by_name[mid]->name, name);
        if (c == 0)
            return f->by_name[mid];
        if (c < 0)
            lo = mid + 1;
        else
            hi = mid;
    }
    return NULL;
}

const char *gs_st_meta(const gs_st_file *f, const char *key)
{
    if (!f || !key)
        return NULL;
    int lo = 0, hi = f->nmeta;
    while (lo < hi) {
        int mid = lo + (hi - lo) / 2, c = strcmp(f->meta[mid].key, key);
        if (c == 0)
            return f->meta[mid].value;
        if (c < 0)
            lo = mid + 1;
        else
            hi = mid;
    }
    return NULL;
}

int gs_st_meta_count(const gs_st_file *f)
{
    return f ? f->nmeta : 0;
}

void gs_st_meta_at(const gs_st_file *f, int i, const char **key, const char **value)
{
    int ok = f && i >= 0 && i < f->nmeta;
    if (key)
        *key = ok ? f->meta[i].key : NULL;
    if (value)
        *value = ok ? f->meta[i].value : NULL;
}

static void format_shape(char *buf, size_t cap, int ndim, const int64_t *shape)
{
    size_t k = (size_t)snprintf(buf, cap, "[");
    for (int i = 0; i < ndim && k < cap; i++)
        k += (size_t)snprintf(buf + k, cap - k, "%s%lld", i ? ", " : "", (long long)shape[i]);
    if (k < cap)
        snprintf(buf + k, cap - k, "]");
}

int gs_st_get_f32(const gs_st_file *f, const char *name, int ndim, const int64_t *shape,
                  const float **data, gs_error *err)
{
    char want[160], got[160];
    if (!f || !name || !data || ndim < 0 || ndim > GS_ST_MAX_DIMS || (ndim && !shape))
        return gs_error_set(err, GS_ERR_ARG, ST_ERR "bad argument to gs_st_get_f32");
    const gs_st_tensor *t = gs_st_find(f, name);
    if (!t)
        return gs_error_set(err, GS_ERR_FORMAT, ST_ERR "no tensor '%.60s'", name);
    int same = t->dtype == GS_ST_F32 && t->ndim == ndim;
    for (int i = 0; same && i < ndim; i++)
        same = t->shape[i] == shape[i];
    if (!same) {
        format_shape(want, sizeof want, ndim, shape);
        format_shape(got, sizeof got, t->ndim, t->shape);
        return gs_error_set(err, GS_ERR_FORMAT, ST_ERR "tensor '%.60s': expected F32 %s, got %s %s",
                            name, want, dtype_names[t->dtype], got);
    }
    *data = t->data;
    return GS_OK;
}
