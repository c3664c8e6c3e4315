/* .npy arrays: float32 and uint8, C order, rank <= 4.
 *
 * Layout: "\x93NUMPY", major, minor, header length (u16 LE for 1.x, u32 LE
 * for 2.x/3.x), a Python dict literal with exactly the keys descr,
 * fortran_order and shape, padded with spaces and ended by '\n', then the
 * raw data filling the rest of the file. */
#define _POSIX_C_SOURCE 200809L /* fileno, fstat, strcasecmp */

#include "gazesplat/image_io.h"

#include <errno.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

#if defined(__BYTE_ORDER__) && __BYTE_ORDER__ != __ORDER_LITTLE_ENDIAN__
#error "npy I/O copies float32 data as is: little-endian hosts only"
#endif

#define NPY_MAGIC "\x93NUMPY"
#define NPY_MAGIC_LEN 6
#define NPY_PREFIX_MAX 12 /* magic + version + u32 header length */

size_t gs_io_dtype_size(gs_io_dtype dtype)
{
    switch (dtype) {
    case GS_IO_F32: return 4;
    case GS_IO_U8: return 1;
    default: return 0;
    }
}

size_t gs_io_array_count(const gs_io_array *a)
{
    size_t n = 1;
    for (int i = 0; i < a->rank; i++)
        n *= a->shape[i];
    return n;
}

void gs_io_array_free(gs_io_array *a)
{
    if (a) {
        free(a->data);
        memset(a, 0, sizeof *a);
    }
}

/* Element count of a shape with overflow check; 0 on overflow sets *ovf. */
static size_t shape_count(int rank, const size_t *shape, int *ovf)
{
    size_t n = 1;
    *ovf = 0;
    for (int i = 0; i < rank; i++) {
        if (shape[i] != 0 && n > SIZE_MAX / shape[i]) {
            *ovf = 1;
            return 0;
        }
        n *= shape[i];
    }
    return n;
}

/* ---- writer ------------------------------------------------------------- */

/* Builds the 1.0 prefix + padded header; returns its length (a multiple of
 * 64, as numpy writes it) or 0 if it does not fit in buf. */
static size_t build_header(gs_io_dtype dtype, int rank, const size_t *shape,
                           char *buf, size_t cap)
{
    char dict[256];
    int k = snprintf(dict, sizeof dict, "{'descr': '%s', 'fortran_order': False, 'shape': (",
                     dtype == GS_IO_F32 ? "<f4" : "|u1");
    for (int i = 0; i < rank; i++)
        k += snprintf(dict + k, sizeof dict - (size_t)k, "%s%zu", i ? ", " : "", shape[i]);
    k += snprintf(dict + k, sizeof dict - (size_t)k, "%s), }", rank == 1 ? "," : "");
    size_t dlen = (size_t)k;
    size_t total = (10 + dlen + 1 + 63) / 64 * 64;
    if (dlen >= sizeof dict || total > cap)
        return 0;
    memcpy(buf, NPY_MAGIC, NPY_MAGIC_LEN);
    buf[6] = 1;
    buf[7] = 0;
    size_t hlen = total - 10;
    buf[8] = (char)(hlen & 0xff);
    buf[9] = (char)(hlen >> 8);
    memcpy(buf + 10, dict, dlen);
    memset(buf + 10 + dlen, ' ', total - 10 - dlen - 1);
    buf[total - 1] = '\n';
    return total;
}

static int check_write_args(gs_io_dtype dtype, int rank, const size_t *shape,
                            const void *data, size_t *nbytes, gs_error *err)
{
    size_t esize = gs_io_dtype_size(dtype);
    int ovf;
    if (!esize)
        return gs_error_set(err, GS_ERR_ARG, "npy: unknown dtype %d", (int)dtype);
    if (rank < 0 || rank > GS_IO_NPY_MAX_RANK || (rank && !shape))
        return gs_error_set(err, GS_ERR_ARG, "npy: rank %d outside 0..%d", rank,
                            GS_IO_NPY_MAX_RANK);
    size_t n = shape_count(rank, shape, &ovf);
    if (ovf || n > SIZE_MAX / esize)
        return gs_error_set(err, GS_ERR_LIMIT, "npy: shape too large");
    if (n && !data)
        return gs_error_set(err, GS_ERR_ARG, "npy: NULL data");
    *nbytes = n * esize;
    return GS_OK;
}

int gs_io_npy_encode(gs_io_dtype dtype, int rank, const size_t *shape,
                     const void *data, void **out, size_t *out_len,
                     gs_error *err)
{
    char head[256];
    size_t nbytes, hlen;
    int rc = check_write_args(dtype, rank, shape, data, &nbytes, err);
    if (rc)
        return rc;
    if (!out || !out_len)
        return gs_error_set(err, GS_ERR_ARG, "npy: NULL output");
    hlen = build_header(dtype, rank, shape, head, sizeof head);
    if (!hlen || nbytes > SIZE_MAX - hlen)
        return gs_error_set(err, GS_ERR_LIMIT, "npy: header too long");
    unsigned char *buf = malloc(hlen + nbytes);
    if (!buf)
        return gs_error_set(err, GS_ERR_NOMEM, "npy: cannot allocate %zu bytes",
                            hlen + nbytes);
    memcpy(buf, head, hlen);
    if (nbytes)
        memcpy(buf + hlen, data, nbytes);
    *out = buf;
    *out_len = hlen + nbytes;
    return GS_OK;
}

int gs_io_npy_write(const char *path, gs_io_dtype dtype, int rank,
                    const size_t *shape, const void *data, gs_error *err)
{
    char head[256];
    size_t nbytes, hlen;
    int rc = check_write_args(dtype, rank, shape, data, &nbytes, err);
    if (rc)
        return rc;
    hlen = build_header(dtype, rank, shape, head, sizeof head);
    if (!hlen)
        return gs_error_set(err, GS_ERR_LIMIT, "npy: header too long");
    FILE *f = fopen(path, "wb");
    if (!f)
        return gs_error_set(err, GS_ERR_IO, "npy: cannot create %s: %s", path,
                            strerror(errno));
    int ok = fwrite(head, 1, hlen, f) == hlen;
    if (ok && nbytes)
        ok = fwrite(data, 1, nbytes, f) == nbytes;
    if (fclose(f) != 0)
        ok = 0;
    if (!ok)
        return gs_error_set(err, GS_ERR_IO, "npy: cannot write %s: %s", path,
                            strerror(errno));
    return GS_OK;
}

/* ---- header parser ------------------------------------------------------ */

typedef struct npy_cursor {
    const char *p, *end;
} npy_cursor;

static void skip_spaces(npy_cursor *c)
{
    while (c->p < c->end && (*c->p == ' ' || *c->p == '\t'))
        c->p++;
}

static int accept_char(npy_cursor *c, char ch)
{
    skip_spaces(c);
    if (c->p < c->end && *c->p == ch) {
        c->p++;
        return 1;
    }
    return 0;
}

/* A quoted Python string without escapes, up to cap-1 characters. */
static int parse_string(npy_cursor *c, char *out, size_t cap)
{
    skip_spaces(c);
    if (c->p >= c->end || (*c->p != '\'' && *c->p != '"'))
        return 0;
    char q = *c->p++;
    size_t n = 0;
    while (c->p < c->end && *c->p != q) {
        if (*c->p == '\\' || n + 1 >= cap)
            return 0;
        out[n++] = *c->p++;
    }
    if (c->p >= c->end)
        return 0;
    c->p++;
    out[n] = '\0';
    return 1;
}

static int accept_word(npy_cursor *c, const char *w)
{
    size_t n = strlen(w);
    skip_spaces(c);
    if ((size_t)(c->end - c->p) >= n && memcmp(c->p, w, n) == 0) {
        c->p += n;
        return 1;
    }
    return 0;
}

/* Decimal size_t (an optional 'L' suffix of old Python 2 files). */
static int parse_dim(npy_cursor *c, size_t *out)
{
    skip_spaces(c);
    size_t v = 0;
    const char *start = c->p;
    while (c->p < c->end && *c->p >= '0' && *c->p <= '9') {
        size_t d = (size_t)(*c->p - '0');
        if (v > (SIZE_MAX - d) / 10)
            return 0;
        v = v * 10 + d;
        c->p++;
    }
    if (c->p == start)
        return 0;
    if (c->p < c->end && *c->p == 'L')
        c->p++;
    *out = v;
    return 1;
}

/* "(a, b, ...)" with an optional trailing comma; "()" is rank 0. */
static int parse_shape(npy_cursor *c, gs_io_array *a, gs_error *err)
{
    if (!accept_char(c, '('))
        return gs_error_set(err, GS_ERR_FORMAT, "npy: shape is not a tuple");
    a->rank = 0;
    while (!accept_char(c, ')')) {
        size_t d;
        if (!parse_dim(c, &d))
            return gs_error_set(err, GS_ERR_FORMAT, "npy: bad dimension in shape");
        if (a->rank == GS_IO_NPY_MAX_RANK)
            return gs_error_set(err, GS_ERR_UNSUPPORTED, "npy: rank over %d",
                                GS_IO_NPY_MAX_RANK);
        a->shape[a->rank++] = d;
        if (!accept_char(c, ',')) {
            if (!accept_char(c, ')'))
                return gs_error_set(err, GS_ERR_FORMAT, "npy: bad shape tuple");
            if (a->rank == 1)
                return gs_error_set(err, GS_ERR_FORMAT, "npy: 1-tuple without comma");
            break;
        }
    }
    return GS_OK;
}

static int parse_descr(const char *descr, gs_io_array *a, gs_error *err)
{
    if (strcmp(descr, "<f4") == 0)
        a->dtype = GS_IO_F32;
    else if (strcmp(descr, "|u1") == 0 || strcmp(descr, "<u1") == 0 ||
             strcmp(descr, ">u1") == 0 || strcmp(descr, "u1") == 0)
        a->dtype = GS_IO_U8;
    else
        return gs_error_set(err, GS_ERR_UNSUPPORTED,
                            "npy: dtype '%s' not supported (float32 '<f4' or uint8 '|u1')",
                            descr);
    return GS_OK;
}

/* One "'key': value" entry of the header dict; seen[] flags duplicates. */
static int parse_entry(npy_cursor *c, gs_io_array *a, int seen[3], gs_error *err)
{
    char key[32], val[32];
    if (!parse_string(c, key, sizeof key) || !accept_char(c, ':'))
        return gs_error_set(err, GS_ERR_FORMAT, "npy: bad header dictionary key");
    int idx = strcmp(key, "descr") == 0           ? 0
              : strcmp(key, "fortran_order") == 0 ? 1
              : strcmp(key, "shape") == 0         ? 2
                                                  : -1;
    if (idx < 0)
        return gs_error_set(err, GS_ERR_FORMAT, "npy: unknown header key '%s'", key);
    if (seen[idx]++)
        return gs_error_set(err, GS_ERR_FORMAT, "npy: header key '%s' twice", key);
    if (idx == 0) {
        if (!parse_string(c, val, sizeof val))
            return gs_error_set(err, GS_ERR_FORMAT, "npy: descr is not a simple string");
        return parse_descr(val, a, err);
    }
    if (idx == 1) {
        if (accept_word(c, "False"))
            return GS_OK;
        if (accept_word(c, "True"))
            return gs_error_set(err, GS_ERR_UNSUPPORTED, "npy: Fortran order not supported");
        return gs_error_set(err, GS_ERR_FORMAT, "npy: fortran_order is not a bool");
    }
    return parse_shape(c, a, err);
}

/* Parses the dict text; the array's dtype, rank and shape are filled. */
static int parse_dict(const char *text, size_t len, gs_io_array *a, gs_error *err)
{
    npy_cursor c = {text, text + len};
    int seen[3] = {0, 0, 0};
    if (len == 0 || text[len - 1] != '\n')
        return gs_error_set(err, GS_ERR_FORMAT, "npy: header does not end with a newline");
    c.end--;
    if (!accept_char(&c, '{'))
        return gs_error_set(err, GS_ERR_FORMAT, "npy: header is not a dictionary");
    while (!accept_char(&c, '}')) {
        int rc = parse_entry(&c, a, seen, err);
        if (rc)
            return rc;
        if (!accept_char(&c, ',')) {
            if (!accept_char(&c, '}'))
                return gs_error_set(err, GS_ERR_FORMAT, "npy: bad header dictionary");
            break;
        }
    }
    skip_spaces(&c);
    if (c.p != c.end)
        return gs_error_set(err, GS_ERR_FORMAT, "npy: junk after header dictionary");
    if (!seen[0] || !seen[1] || !seen[2])
        return gs_error_set(err, GS_ERR_FORMAT, "npy: header lacks '%s'",
                            !seen[0] ? "descr" : !seen[1] ? "fortran_order" : "shape");
    return GS_OK;
}

/* Reads the fixed prefix: sets *dict_off and *dict_len. Needs up to
 * NPY_PREFIX_MAX bytes in buf (len is what is available). */
static int parse_prefix(const unsigned char *buf, size_t len, size_t *dict_off,
                        size_t *dict_len, gs_error *err)
{
    if (len < 10 || memcmp(buf, NPY_MAGIC, NPY_MAGIC_LEN) != 0)
        return gs_error_set(err, GS_ERR_FORMAT, "npy: bad magic (not an .npy file)");
    int major = buf[6], minor = buf[7];
    if (major < 1 || major > 3 || minor != 0)
        return gs_error_set(err, GS_ERR_UNSUPPORTED, "npy: format version %d.%d", major, minor);
    if (major == 1) {
        *dict_off = 10;
        *dict_len = (size_t)buf[8] | (size_t)buf[9] << 8;
    } else {
        if (len < 12)
            return gs_error_set(err, GS_ERR_FORMAT, "npy: truncated header");
        *dict_off = 12;
        *dict_len = (size_t)buf[8] | (size_t)buf[9] << 8 | (size_t)buf[10] << 16 |
                    (size_t)buf[11] << 24;
    }
    if (*dict_len > GS_IO_NPY_MAX_HEADER)
        return gs_error_set(err, GS_ERR_LIMIT, "npy: header of %zu bytes over %d",
                            *dict_len, GS_IO_NPY_MAX_HEADER);
    return GS_OK;
}

/* Checks the data size implied by the header against what the file holds
 * (avail bytes after the header) and the limit; returns it in *nbytes. */
static int check_data_size(const gs_io_array *a, size_t avail, size_t max_bytes,
                           size_t *nbytes, gs_error *err)
{
    int ovf;
    size_t n = shape_count(a->rank, a->shape, &ovf);
    size_t esize = gs_io_dtype_size(a->dtype);
    if (!max_bytes)
        max_bytes = GS_IO_NPY_DEFAULT_MAX_BYTES;
    if (ovf || n > SIZE_MAX / esize)
        return gs_error_set(err, GS_ERR_FORMAT, "npy: shape product overflows");
    if (n * esize != avail)
        return gs_error_set(err, GS_ERR_FORMAT,
                            "npy: shape needs %zu data bytes, file has %zu", n * esize, avail);
    if (n * esize > max_bytes)
        return gs_error_set(err, GS_ERR_LIMIT, "npy: %zu data bytes over the limit %zu",
                            n * esize, max_bytes);
    *nbytes = n * esize;
    return GS_OK;
}

int gs_io_npy_parse(const void *buf, size_t len, size_t max_bytes,
                    gs_io_array *out, gs_error *err)
{
    const unsigned char *b = buf;
    gs_io_array a;
    size_t off, dlen, nbytes;
    memset(&a, 0, sizeof a);
    if (!out || (!buf && len))
        return gs_error_set(err, GS_ERR_ARG, "npy: NULL argument");
    int rc = parse_prefix(b, len, &off, &dlen, err);
    if (rc)
        return rc;
    if (dlen > len - off)
        return gs_error_set(err, GS_ERR_FORMAT, "npy: truncated header");
    rc = parse_dict((const char *)b + off, dlen, &a, err);
    if (!rc)
        rc = check_data_size(&a, len - off - dlen, max_bytes, &nbytes, err);
    if (rc)
        return rc;
    a.data = malloc(nbytes ? nbytes : 1);
    if (!a.data)
        return gs_error_set(err, GS_ERR_NOMEM, "npy: cannot allocate %zu bytes", nbytes);
    memcpy(a.data, b + off + dlen, nbytes);
    *out = a;
    return GS_OK;
}

/* ---- file reader -------------------------------------------------------- */

static int read_exact(FILE *f, void *dst, size_t n, const char *path, gs_error *err)
{
    if (fread(dst, 1, n, f) != n)
        return gs_error_set(err, ferror(f) ? GS_ERR_IO : GS_ERR_FORMAT,
                            "npy: %s: %s", path, ferror(f) ? strerror(errno) : "truncated");
    return GS_OK;
}

/* Reads the header of an open file; fills a (without data) and the offset
 * of the data. */
static int read_header(FILE *f, const char *path, gs_io_array *a, size_t *data_off,
                       gs_error *err)
{
    unsigned char prefix[NPY_PREFIX_MAX];
    size_t off, dlen;
    size_t got = fread(prefix, 1, sizeof prefix, f);
    int rc = parse_prefix(prefix, got, &off, &dlen, err);
    if (rc)
        return rc;
    char *dict = malloc(dlen + 1);
    if (!dict)
        return gs_error_set(err, GS_ERR_NOMEM, "npy: out of memory");
    rc = fseek(f, (long)off, SEEK_SET) ? gs_error_set(err, GS_ERR_IO, "npy: %s: seek failed", path)
                                       : read_exact(f, dict, dlen, path, err);
    if (!rc)
        rc = parse_dict(dict, dlen, a, err);
    free(dict);
    *data_off = off + dlen;
    return rc;
}

int gs_io_npy_read(const char *path, size_t max_bytes, gs_io_array *out, gs_error *err)
{
    gs_io_array a;
    struct stat st;
    size_t data_off = 0, nbytes = 0;
    memset(&a, 0, sizeof a);
    if (!path || !out)
        return gs_error_set(err, GS_ERR_ARG, "npy: NULL argument");
    FILE *f = fopen(path, "rb");
    if (!f)
        return gs_error_set(err, GS_ERR_IO, "npy: cannot open %s: %s", path, strerror(errno));
    int rc = fstat(fileno(f), &st) || !S_ISREG(st.st_mode)
                 ? gs_error_set(err, GS_ERR_IO, "npy: %s is not a regular file", path)
                 : read_header(f, path, &a, &data_off, err);
    if (!rc && (size_t)st.st_size < data_off)
        rc = gs_error_set(err, GS_ERR_FORMAT, "npy: %s: truncated header", path);
    if (!rc)
        rc = check_data_size(&a, (size_t)st.st_size - data_off, max_bytes, &nbytes, err);
    if (!rc && !(a.data = malloc(nbytes ? nbytes : 1)))
        rc = gs_error_set(err, GS_ERR_NOMEM, "npy: cannot allocate %zu bytes", nbytes);
    if (!rc)
        rc = read_exact(f, a.data, nbytes, path, err);
    fclose(f);
    if (rc) {
        free(a.data);
        return rc;
    }
    *out = a;
    return GS_OK;
}
