/* Test photos of the face tests and the dlib reference program. */
#ifndef GS_FACE_PHOTOS_H
#define GS_FACE_PHOTOS_H

#include "gazesplat/face.h"
#include "gazesplat/image_io.h"

#define GS_TEST_SKIP 77

/* The photos: "astronaut", "camera" (skimage) and "sample1".."sample6"
 * (face-api). */
#define GS_PHOTO_SAMPLES 6

/* Path of a photo, or NULL when the file is missing. */
const char *photo_path(const char *name, char *buf, size_t cap);
/* Decodes a photo; returns 0, or GS_TEST_SKIP (after saying so) when it is
 * missing, or 1 on a decode failure. */
int photo_load(const char *name, gs_io_image *img);

/* The shared landmark model, parsed once per process (NULL on failure,
 * after printing why). */
const gs_face_shape_model *photo_shape_model(void);

/* Runs `dlib_ref landmarks` once for n_img images, n[i] boxes each (boxes
 * concatenated); pts gets 68 x 2 ints per box, in order. Returns 0 or -1. */
int dlib_landmarks(const char *dlib_ref, const gs_io_image *imgs, int n_img, const int *n,
                   const gs_face_box *boxes, int *pts);
/* Runs `dlib_ref hog` (one upsampling); returns the number of boxes (up to
 * cap written) or -1. */
int dlib_hog(const char *dlib_ref, const gs_io_image *img, gs_face_box *boxes, int cap);

#endif
