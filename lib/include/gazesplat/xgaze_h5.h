/* gs_h5: ETH-XGaze-style HDF5 files of normalized face patches (libhdf5's
 * C API).
 *
 * The layout, as the ETH-XGaze and GazeNeRF tools write it:
 *   face_patch      N x H x W x 3 uint8, the normalized face images. The
 *                   ETH-XGaze files hold them in OpenCV's channel order,
 *                   BGR; this module moves bytes and never swaps channels
 *                   (the caller does).
 *   face_gaze       N x 2 float, (pitch, yaw) radians: the gaze in the
 *                   normalized camera frame (geom.h's ETH-XGaze signs).
 *   face_head_pose  N x 2 float, (pitch, yaw) radians: the head angles in
 *                   the normalized camera (geom.h: those of R e_z).
 * face_gaze and face_head_pose are optional on reading (ETH-XGaze's test
 * subjects have no gaze); any float class is read (converted to float),
 * and every label read is checked to be finite.
 *
 * Written files hold exactly these three datasets, float32 labels,
 * contiguous, without object timestamps, so that the same rows give the
 * same bytes. */
#ifndef GAZESPLAT_XGAZE_H5_H
#define GAZESPLAT_XGAZE_H5_H

#include <stddef.h>
#include <stdint.h>

#include "gazesplat/error.h"

#ifdef __cplusplus
extern "C" {
#endif

#define GS_H5_MAX_SIDE 4096
#define GS_H5_MAX_ROWS ((size_t)1 << 31)

typedef struct gs_h5_reader gs_h5_reader;

typedef struct gs_h5_info {
    size_t rows;        /* N */
    int height, width;  /* H, W of face_patch */
    int has_gaze;       /* face_gaze present (N x 2) */
    int has_head;       /* face_head_pose present (N x 2) */
} gs_h5_info;

/* Opens path read-only and checks the layout: face_patch of rank 4 with 3
 * channels of an 8-bit unsigned integer type, H and W in
 * [1, GS_H5_MAX_SIDE]; face_gaze / face_head_pose, if present, of shape
 * N x 2 and a float class. GS_ERR_IO (cannot open, not HDF5) or
 * GS_ERR_FORMAT (a dataset missing or of the wrong shape or type; the
 * message names it). */
int gs_h5_open(const char *path, gs_h5_reader **out, gs_h5_info *info,
               gs_error *err);

/* Row `row` of face_patch into patch (H*W*3 bytes, as stored) and, when
 * present (else NaN), its labels. GS_ERR_ARG for a row out of range,
 * GS_ERR_IO for a failed read, GS_ERR_NONFINITE for a NaN/Inf label (the
 * message names the dataset and row). gaze and head may be NULL. */
int gs_h5_read_row(gs_h5_reader *r, size_t row, uint8_t *patch, float gaze[2],
                   float head[2], gs_error *err);

void gs_h5_close(gs_h5_reader *r);

typedef struct gs_h5_writer gs_h5_writer;

/* Creates (truncates) path with the three datasets for `rows` rows of
 * size x size patches. */
int gs_h5_create(const char *path, size_t rows, int size, gs_h5_writer **out,
                 gs_error *err);

/* Writes rows [row0, row0 + count): patches (count * size*size*3 bytes),
 * gaze and head (count * 2 floats each). */
int gs_h5_write_rows(gs_h5_writer *w, size_t row0, size_t count,
                     const uint8_t *patches, const float *gaze,
                     const float *head, gs_error *err);

/* Closes the file; GS_ERR_STATE unless every row was written once,
 * GS_ERR_IO when HDF5 could not flush it (a full disk). Frees w either
 * way. */
int gs_h5_finish(gs_h5_writer *w, gs_error *err);

/* Closes and frees w without the checks (after a failure). */
void gs_h5_abort(gs_h5_writer *w);

#ifdef __cplusplus
}
#endif
#endif
