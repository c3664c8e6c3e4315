/* OpenCV for lib/face (cv_face_shim.cpp): cascades, solvePnP and the
 * perspective warp. Internal. Every C++ exception becomes a gs_status. */
#ifndef GS_FACE_CV_SHIM_H
#define GS_FACE_CV_SHIM_H

#include "gazesplat/error.h"
#include "gazesplat/image_io.h"

#ifdef __cplusplus
extern "C" {
#endif

typedef struct gs_cvf_cascade gs_cvf_cascade;

int gs_cvf_cascade_load(const char *path, gs_cvf_cascade **out, gs_error *err);
void gs_cvf_cascade_free(gs_cvf_cascade *c);

/* Faces of an RGB image as x, y, w, h (OpenCV pixels) in a malloc'd array
 * of 4 * *n ints (NULL when none). The image is turned grey and its
 * histogram equalized first. */
int gs_cvf_detect(gs_cvf_cascade *c, const gs_io_image *img, double scale_factor,
                  int min_neighbors, int min_size, int **rects, int *n, gs_error *err);

/* solvePnP of n points, no distortion: EPnP, then the iterative
 * Levenberg-Marquardt refinement from it. rvec, tvec: the result. */
int gs_cvf_solve_pnp(const double (*obj)[3], const double (*img)[2], int n, const double k[9],
                     double rvec[3], double tvec[3], gs_error *err);

/* dst(x, y) = src(M (x, y, 1)) for every pixel of dst (OpenCV pixels:
 * centres at integers), bilinear, 0 outside src. M is row-major 3x3. */
int gs_cvf_warp(const gs_io_image *src, gs_io_image *dst, const double m[9], gs_error *err);

#ifdef __cplusplus
}
#endif
#endif
