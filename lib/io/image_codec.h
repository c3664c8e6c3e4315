/* The codecs behind image_io.c: libjpeg(-turbo) and libpng, called
 * directly. Internal to lib/io.
 *
 * Inputs reach the decoders already validated by image_io.c (format,
 * structure, dimensions within limits); the decoders check the dimensions
 * the library reports again before they allocate. Every libjpeg/libpng
 * error is caught (setjmp) and turned into a gs_status with the library's
 * message; warnings are not printed. */
#ifndef GS_IO_IMAGE_CODEC_H
#define GS_IO_IMAGE_CODEC_H

#include <stddef.h>

#include "gazesplat/error.h"
#include "gazesplat/image_io.h"

/* Decodes to 8-bit RGB in a malloc'd buffer (stride 3 * width); at most
 * max_pixels and max_side each way. JPEG: grey, YCbCr, RGB, CMYK and YCCK
 * (Adobe-inverted, as photo tools write it); the EXIF orientation is
 * applied. PNG: every colour type and depth; alpha is dropped, 16-bit
 * samples keep their high byte; the orientation of an eXIf chunk is
 * applied. */
int gs_jpeg_decode(const unsigned char *buf, size_t len, size_t max_pixels, int max_side,
                   gs_io_image *out, gs_error *err);
int gs_png_decode(const unsigned char *buf, size_t len, size_t max_pixels, int max_side,
                  gs_io_image *out, gs_error *err);

/* Encode RGB img into a malloc'd buffer; quality already resolved (JPEG
 * 1..100, PNG zlib level 1..9). */
int gs_jpeg_encode(const gs_io_image *img, int quality, unsigned char **out, size_t *out_len,
                   gs_error *err);
int gs_png_encode(const gs_io_image *img, int level, unsigned char **out, size_t *out_len,
                  gs_error *err);

/* The EXIF Orientation (IFD0 tag 0x0112) in the body of an APP1 segment
 * (from "Exif\0\0" on), 1..8; 1 when absent, malformed or out of range. */
int gs_exif_orientation(const unsigned char *app1, size_t len);

/* The same from a bare TIFF block (II or MM first), as a PNG eXIf chunk
 * holds it; offsets count from t. */
int gs_exif_tiff_orientation(const unsigned char *t, size_t n);

/* Replaces img (stride 3 * width) by its version displayed upright for
 * EXIF orientation 1..8 (2..8 flip or rotate it; 5..8 swap width and
 * height). */
int gs_image_orient(gs_io_image *img, int orientation, gs_error *err);

#endif
