/* The only door to OpenCV (cv_shim.cpp). Internal to lib/io.
 *
 * Inputs reach these functions already validated by image_io.c (format,
 * structure, dimensions within limits). The shim turns every C++ exception
 * into a gs_status and converts between OpenCV's BGR and our RGB. */
#ifndef GS_IO_CV_SHIM_H
#define GS_IO_CV_SHIM_H

#include <stddef.h>

#include "gazesplat/error.h"
#include "gazesplat/image_io.h"

#ifdef __cplusplus
extern "C" {
#endif

/* Decodes a PNG or JPEG of len bytes to 8-bit RGB in a malloc'd buffer
 * (stride 3 * width). max_pixels bounds the decoded result. */
int gs_cv_decode(const unsigned char *buf, size_t len, size_t max_pixels,
                 gs_io_image *out, gs_error *err);

/* Encodes RGB img; *out is malloc'd. quality as gs_io_image_encode, already
 * resolved (never 0). */
int gs_cv_encode(const gs_io_image *img, gs_io_format format, int quality,
                 unsigned char **out, size_t *out_len, gs_error *err);

#ifdef __cplusplus
}
#endif
#endif
