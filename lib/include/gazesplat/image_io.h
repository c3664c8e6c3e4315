/* gs_io: arrays (.npy) and images (PNG, JPEG) in and out of memory and files.
 *
 * npy: float32 and uint8 arrays in C order, rank 0..GS_IO_NPY_MAX_RANK,
 * little-endian, format versions 1.0 (written) and 1.0, 2.0, 3.0 (read).
 *
 * Images at the API are 8-bit RGB, interleaved, row 0 at the top, with an
 * explicit stride in bytes. PNG and JPEG are decoded and encoded by libpng
 * and libjpeg(-turbo); every input is checked first (magic, chunk/segment
 * structure, truncation, dimensions against the limits) so the decoders
 * never see a file we would refuse. Grey, palette, 16-bit and alpha PNGs
 * decode to 8-bit RGB (alpha is dropped, 16-bit keeps the high byte); grey,
 * CMYK and YCCK JPEGs to RGB; the EXIF orientation (JPEG APP1, PNG eXIf) is
 * applied. Other formats are GS_ERR_UNSUPPORTED with their name.
 *
 * Every call returns GS_OK or a negative gs_status and, where a person needs
 * to know what was wrong, fills the optional gs_error. Outputs are untouched
 * on failure. */
#ifndef GAZESPLAT_IMAGE_IO_H
#define GAZESPLAT_IMAGE_IO_H

#include <stddef.h>

#include "gazesplat/error.h"

#ifdef __cplusplus
extern "C" {
#endif

/* ---- npy ---------------------------------------------------------------- */

#define GS_IO_NPY_MAX_RANK 4
#define GS_IO_NPY_MAX_HEADER 16384            /* header dictionary, bytes */
#define GS_IO_NPY_DEFAULT_MAX_BYTES ((size_t)1 << 31) /* array data */

typedef enum gs_io_dtype {
    GS_IO_F32 = 1, /* '<f4' */
    GS_IO_U8 = 2   /* '|u1' */
} gs_io_dtype;

/* An owning n-dimensional array; rank 0 is a scalar (one element). */
typedef struct gs_io_array {
    gs_io_dtype dtype;
    int rank;
    size_t shape[GS_IO_NPY_MAX_RANK];
    void *data;   /* C order; free with gs_io_array_free */
} gs_io_array;

/* Bytes per element of a dtype (4 or 1), 0 for an unknown value. */
size_t gs_io_dtype_size(gs_io_dtype dtype);

/* Number of elements (product of the shape; 1 for rank 0). */
size_t gs_io_array_count(const gs_io_array *a);

/* Frees a->data and zeroes *a. NULL and zeroed arrays are fine. */
void gs_io_array_free(gs_io_array *a);

/* Serializes shape[rank] elements of data as a version 1.0 .npy image in a
 * malloc'd buffer (*out, *out_len; the caller frees it with free()). */
int gs_io_npy_encode(gs_io_dtype dtype, int rank, const size_t *shape,
                     const void *data, void **out, size_t *out_len,
                     gs_error *err);

/* Same, to a file (created or truncated). */
int gs_io_npy_write(const char *path, gs_io_dtype dtype, int rank,
                    const size_t *shape, const void *data, gs_error *err);

/* Parses an .npy image of len bytes into *out (data copied). The data must
 * fill the rest of the buffer exactly. max_bytes limits the array data
 * (0: GS_IO_NPY_DEFAULT_MAX_BYTES). Errors: GS_ERR_FORMAT (bad magic,
 * header, size mismatch), GS_ERR_UNSUPPORTED (other dtype, Fortran order,
 * rank > 4, big-endian), GS_ERR_LIMIT, GS_ERR_NOMEM. */
int gs_io_npy_parse(const void *buf, size_t len, size_t max_bytes,
                    gs_io_array *out, gs_error *err);

/* Same, from a file; the size is checked before the data is allocated. */
int gs_io_npy_read(const char *path, size_t max_bytes, gs_io_array *out,
                   gs_error *err);

/* ---- images ------------------------------------------------------------- */

typedef enum gs_io_format {
    GS_IO_PNG = 1,
    GS_IO_JPEG = 2
} gs_io_format;

/* 8-bit RGB interleaved, row 0 at the top: pixel (x, y) channel c is
 * data[y * stride + 3 * x + c]. As an output of a decoder it owns data
 * (stride = 3 * width); free with gs_io_image_free. */
typedef struct gs_io_image {
    int width, height;
    size_t stride;
    unsigned char *data;
} gs_io_image;

/* Decoder limits, checked against the file's own header before any pixel
 * is decoded. */
typedef struct gs_io_image_limits {
    size_t max_bytes;   /* encoded input size */
    size_t max_pixels;  /* width * height */
    int max_side;       /* width and height each */
} gs_io_image_limits;

#define GS_IO_IMAGE_DEFAULT_MAX_BYTES ((size_t)64 << 20)
#define GS_IO_IMAGE_DEFAULT_MAX_PIXELS ((size_t)40 << 20)
#define GS_IO_IMAGE_DEFAULT_MAX_SIDE 16384

/* The defaults above, as a struct. */
gs_io_image_limits gs_io_image_limits_default(void);

void gs_io_image_free(gs_io_image *img);

/* The format a file name asks for, by extension (.png, .jpg, .jpeg, any
 * case); 0 when none. */
int gs_io_format_from_path(const char *path);

/* Detects the format of buf by its signature; 0 when neither. */
int gs_io_format_sniff(const void *buf, size_t len);

/* Decodes a PNG or JPEG held in memory. lim may be NULL (defaults).
 * Errors: GS_ERR_UNSUPPORTED (another format), GS_ERR_FORMAT (corrupt or
 * truncated), GS_ERR_LIMIT, GS_ERR_NOMEM. */
int gs_io_image_decode(const void *buf, size_t len,
                       const gs_io_image_limits *lim, gs_io_image *out,
                       gs_error *err);

/* Reads and decodes a file; its size is checked against lim->max_bytes
 * before it is read. */
int gs_io_image_read(const char *path, const gs_io_image_limits *lim,
                     gs_io_image *out, gs_error *err);

/* Encodes img into a malloc'd buffer (*out, *out_len; free with free()).
 * quality: JPEG 1..100, PNG the zlib level 1..9; 0 picks the default
 * (JPEG 95, PNG 3). PNG output is lossless. */
int gs_io_image_encode(const gs_io_image *img, gs_io_format format,
                       int quality, void **out, size_t *out_len,
                       gs_error *err);

/* Encodes and writes a file (created or truncated). */
int gs_io_image_write(const char *path, const gs_io_image *img,
                      gs_io_format format, int quality, gs_error *err);

#ifdef __cplusplus
}
#endif
#endif
