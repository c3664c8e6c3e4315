/* The former OpenCV imgcodecs path (cv_old.cpp), for bench_image only.
 * Both return 0 or -1; buffers are malloc'd. */
#ifndef GS_BENCH_CV_OLD_H
#define GS_BENCH_CV_OLD_H

#include <stddef.h>

#include "gazesplat/image_io.h"

#ifdef __cplusplus
extern "C" {
#endif

int cvold_decode(const unsigned char *buf, size_t len, gs_io_image *out);
int cvold_encode(const gs_io_image *img, gs_io_format format, int quality,
                 unsigned char **out, size_t *out_len);

#ifdef __cplusplus
}
#endif
#endif
