/* gs_st: safetensors files, the container of gazesplat model files.
 *
 * Layout (the huggingface spec): a u64 little-endian N, N bytes of UTF-8
 * JSON header, then the byte buffer. The header maps each tensor name to
 * {"dtype": "F32", "shape": [2, 3], "data_offsets": [begin, end]} (offsets
 * into the byte buffer) plus an optional "__metadata__" object of strings.
 *
 * The reader is strict: its own small JSON parser, every size and offset
 * checked, the tensors must tile the byte buffer exactly, and F32/F16 data
 * must be finite. It copies each tensor to its own 8-byte aligned slot, so
 * gs_st_tensor.data can be read as float/int32/int64 directly. Dtypes:
 * F32, F16, I32, I64, U8; other spec dtypes (F64, BF16, ...) are
 * GS_ERR_UNSUPPORTED.
 *
 * The writer writes what the Python library writes: tensors ordered by
 * element size (largest first) then name, compact JSON, the header padded
 * with spaces so the byte buffer starts 8-byte aligned. Same inputs, same
 * bytes.
 *
 * Calls return GS_OK or a negative gs_status; the optional gs_error says
 * what was wrong. Outputs are untouched on failure. */
#ifndef GAZESPLAT_SAFETENSORS_H
#define GAZESPLAT_SAFETENSORS_H

#include <stddef.h>
#include <stdint.h>

#include "gazesplat/error.h"

#ifdef __cplusplus
extern "C" {
#endif

typedef enum { GS_ST_F32, GS_ST_F16, GS_ST_I32, GS_ST_I64, GS_ST_U8 } gs_st_dtype;

#define GS_ST_MAX_DIMS 8
#define GS_ST_MAX_NAME 255 /* bytes of UTF-8 in a tensor name */

typedef struct gs_st_tensor {
    const char *name;  /* NUL-terminated UTF-8, owned by the file */
    gs_st_dtype dtype;
    int ndim;          /* 0 (a scalar, one element) .. GS_ST_MAX_DIMS */
    int64_t shape[GS_ST_MAX_DIMS];
    size_t offset;     /* begin of data_offsets, in the file's byte buffer */
    size_t nbytes;     /* product(shape) * element size */
    const void *data;  /* nbytes, 8-byte aligned, host byte order */
} gs_st_tensor;

/* A field of 0 means its default: 1 GiB, 16 MiB, 65536. */
typedef struct gs_st_limits {
    size_t max_file_bytes;   /* 8 + header + byte buffer */
    size_t max_header_bytes; /* N */
    int max_tensors;
} gs_st_limits;

#define GS_ST_DEFAULT_MAX_FILE ((size_t)1 << 30)
#define GS_ST_DEFAULT_MAX_HEADER ((size_t)16 << 20)
#define GS_ST_DEFAULT_MAX_TENSORS 65536

typedef struct gs_st_file gs_st_file; /* owns its bytes */

/* Bytes per element of dt (4, 2, 4, 8, 1); 0 for an unknown value. */
size_t gs_st_dtype_size(gs_st_dtype dt);
/* The spec's name of dt ("F32", ...); "?" for an unknown value. */
const char *gs_st_dtype_name(gs_st_dtype dt);

/* Reads and validates a whole file (the file size is checked before any
 * allocation). lim NULL = defaults. */
int gs_st_open(const char *path, const gs_st_limits *lim, gs_st_file **out, gs_error *err);
/* Same from memory; buf is copied and not kept. */
int gs_st_open_mem(const void *buf, size_t len, const gs_st_limits *lim, gs_st_file **out,
                   gs_error *err);
void gs_st_close(gs_st_file *f); /* NULL is fine */

int gs_st_count(const gs_st_file *f);
/* Tensor i in file order (by offset, then name); NULL if i is out of range. */
const gs_st_tensor *gs_st_at(const gs_st_file *f, int i);
/* NULL if absent. O(log n). */
const gs_st_tensor *gs_st_find(const gs_st_file *f, const char *name);
/* The __metadata__ value of key, or NULL. */
const char *gs_st_meta(const gs_st_file *f, const char *key);
int gs_st_meta_count(const gs_st_file *f);
/* Metadata entry i in key order (strcmp); key/value NULL if out of range. */
void gs_st_meta_at(const gs_st_file *f, int i, const char **key, const char **value);

/* For loaders: the tensor name, which must be F32 with exactly shape[ndim];
 * else GS_ERR_FORMAT with a message naming the tensor, the expected and the
 * actual dtype and shape. */
int gs_st_get_f32(const gs_st_file *f, const char *name, int ndim, const int64_t *shape,
                  const float **data, gs_error *err);

/* ---- writer ------------------------------------------------------------- */

typedef struct gs_st_writer gs_st_writer;

gs_st_writer *gs_st_writer_create(void); /* NULL when out of memory */
/* Adds or replaces a metadata entry (valid UTF-8, no NUL). */
int gs_st_writer_meta(gs_st_writer *w, const char *key, const char *value);
/* Copies shape[ndim] elements of data (host byte order). Refuses (GS_ERR_ARG)
 * a duplicate, empty, over-long, non-UTF-8 or reserved ("__metadata__")
 * name, ndim outside 0..8, a negative dimension; GS_ERR_LIMIT on an
 * overflowing size; GS_ERR_NONFINITE on NaN/Inf in F32/F16 data. */
int gs_st_writer_add(gs_st_writer *w, const char *name, gs_st_dtype dt, int ndim,
                     const int64_t *shape, const void *data);
/* Atomic: writes path.tmp.<pid>, fsyncs it, renames it over path. */
int gs_st_writer_save(gs_st_writer *w, const char *path, gs_error *err);
/* The file image in a malloc'd buffer (the caller frees it). */
int gs_st_writer_to_mem(gs_st_writer *w, uint8_t **buf, size_t *len, gs_error *err);
void gs_st_writer_destroy(gs_st_writer *w); /* NULL is fine */

#ifdef __cplusplus
}
#endif
#endif
