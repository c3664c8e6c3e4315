/* gs_ply: 3D Gaussian splatting scenes in .ply files.
 *
 * Format: binary_little_endian 1.0, one element `vertex`, one float32
 * property per value:
 *   x y z                  position
 *   nx ny nz               normals (optional; written as read)
 *   f_dc_0..2              SH degree-0 colour, or, for C-channel feature
 *   f_rest_0..R-1          scenes, feat_0..feat_{C-1} instead of both;
 *                          R = 0, 9, 24, 45 for SH degree 0..3, stored
 *                          channel-major: coefficient j of channel c is
 *                          f_rest_{c * R/3 + j}
 *   opacity                logit
 *   scale_0..2             log scale
 *   rot_0..3               quaternion, w first, any norm
 * The reader accepts the properties in any order and skips unknown ones of
 * any scalar type; a required property of a type other than float, list
 * properties, other elements, ASCII and big-endian files are refused.
 *
 * For SH files the scene's features are the degree-0 colour,
 * RGB = GS_PLY_SH_C0 * f_dc + 0.5 (C = 3); f_dc and f_rest are kept too, so
 * writing a scene read from a file gives back the same bytes when the file
 * had the writer's layout (the order above, no comments, no extra
 * properties: what the reference 3DGS code writes). */
#ifndef GAZESPLAT_PLY_H
#define GAZESPLAT_PLY_H

#include <stddef.h>

#include "gazesplat/error.h"
#include "gazesplat/raster.h"

#ifdef __cplusplus
extern "C" {
#endif

#define GS_PLY_SH_C0 0.28209479177387814
#define GS_PLY_DEFAULT_MAX_VERTICES 10000000
#define GS_PLY_MAX_HEADER 65536   /* bytes, up to and including end_header */
#define GS_PLY_MAX_PROPERTIES 256
#define GS_PLY_MAX_SH_DEGREE 3

typedef enum gs_ply_kind {
    GS_PLY_SH = 1,       /* f_dc / f_rest colours, C = 3 */
    GS_PLY_FEATURES = 2  /* feat_0..C-1 */
} gs_ply_kind;

typedef struct gs_ply_options {
    int max_vertices;    /* 0: GS_PLY_DEFAULT_MAX_VERTICES */
    int allow_nonfinite; /* 0: refuse NaN/Inf in any value read, with
                            GS_ERR_NONFINITE; 1: keep them (the
                            rasterizer refuses them later) */
} gs_ply_options;

/* A scene, structure of arrays (n rows each). Made by the reader or by
 * gs_ply_alloc_*; free with gs_ply_free. */
typedef struct gs_ply_scene {
    gs_ply_kind kind;
    int n;
    int channels;          /* C: 3 for SH scenes */
    int sh_degree;         /* SH: 0..3; features: -1 */
    int n_rest;            /* f_rest values per Gaussian; 0 for features */
    float *means;          /* n x 3 */
    float *normals;        /* n x 3, NULL when the file had none */
    float *log_scales;     /* n x 3 */
    float *quats;          /* n x 4, wxyz */
    float *opacity_logits; /* n */
    float *features;       /* n x C */
    float *f_dc;           /* n x 3, SH only (else NULL) */
    float *f_rest;         /* n x n_rest, SH only, NULL when n_rest = 0 */
    void *block;           /* the one allocation behind the arrays */
} gs_ply_scene;

/* Allocates a zeroed scene of n SH Gaussians of the given degree. After
 * filling f_dc, call gs_ply_features_from_sh. */
int gs_ply_alloc_sh(gs_ply_scene *s, int n, int sh_degree, int with_normals,
                    gs_error *err);

/* Allocates a zeroed scene of n Gaussians with C feature channels. */
int gs_ply_alloc_features(gs_ply_scene *s, int n, int channels,
                          int with_normals, gs_error *err);

/* Frees what the scene owns and zeroes it. NULL is fine. */
void gs_ply_free(gs_ply_scene *s);

/* SH scenes: features = GS_PLY_SH_C0 * f_dc + 0.5. No-op otherwise. */
void gs_ply_features_from_sh(gs_ply_scene *s);

/* A view of the scene for the rasterizer (pointers into s). */
void gs_ply_gaussians(const gs_ply_scene *s, gs_gaussians *g);

/* Parses a whole .ply file held in memory. opt may be NULL (defaults).
 * Errors: GS_ERR_FORMAT (malformed header, truncated or trailing data,
 * missing or mistyped property), GS_ERR_UNSUPPORTED (ASCII, big-endian,
 * lists, other elements, SH degree > 3, more than
 * GS_RASTER_MAX_CHANNELS features), GS_ERR_LIMIT (vertex count, header
 * length, property count), GS_ERR_NONFINITE, GS_ERR_NOMEM. */
int gs_ply_parse(const void *buf, size_t len, const gs_ply_options *opt,
                 gs_ply_scene *out, gs_error *err);

/* Same, from a file, read in pieces after its size was checked. */
int gs_ply_read(const char *path, const gs_ply_options *opt,
                gs_ply_scene *out, gs_error *err);

/* Serializes a scene in the writer's layout into a malloc'd buffer
 * (*out, *out_len; free with free()). */
int gs_ply_encode(const gs_ply_scene *s, void **out, size_t *out_len,
                  gs_error *err);

/* Same, to a file (created or truncated). */
int gs_ply_write(const char *path, const gs_ply_scene *s, gs_error *err);

#ifdef __cplusplus
}
#endif
#endif
