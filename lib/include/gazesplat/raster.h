/* gs_raster: differentiable rasterization of 3D Gaussians into C-channel
 * feature maps, with alpha and depth, on the CPU.
 *
 * Semantics follow the widely used 3DGS rasterizers (gsplat v1.4 rules with
 * the stability fixes of its later versions). The constants below are frozen:
 * changing one changes pixels, so each is part of the format of a trained
 * model.
 *
 * Projection, per Gaussian (mean p, log-scale s, wxyz quaternion q, opacity
 * logit o, feature f[C]):
 *   R = rot(q / |q|), S = diag(exp s), Sigma = R S S^T R^T
 *   mean_c = V p + t (V, t: the 3x4 world-to-camera matrix)
 *   culled if z < GS_RASTER_NEAR or z > GS_RASTER_FAR
 *   J uses x/z, y/z clamped to the image extent widened by
 *   GS_RASTER_CLAMP_MARGIN of its size on each side (the mean itself is
 *   projected unclamped): J = [[fx/z, 0, -fx tx/z^2], [0, fy/z, -fy ty/z^2]]
 *   Sigma2 = J W Sigma W^T J^T + GS_RASTER_EPS2D * I
 *   culled if det(Sigma2) <= 0
 *   conic (a, b, c) = Sigma2^-1; opacity = sigmoid(o), multiplied by
 *   sqrt(det(Sigma2 - eps I) / det(Sigma2)) in antialiased mode
 *   radius = ceil(3 sqrt(lambda_max)), lambda_max floored as in gsplat;
 *   a Gaussian is binned to every 16x16 tile its radius box touches;
 *   culled if that box misses the image.
 * Compositing, per pixel with centre (x + 0.5, y + 0.5), d = mean2d - centre,
 * over the Gaussians of its tile sorted by (depth, index), front to back:
 *   sigma = 0.5 (a dx^2 + c dy^2) + b dx dy
 *   alpha = min(GS_RASTER_MAX_ALPHA, opacity exp(-sigma))
 *   skip if sigma < 0 or alpha < GS_RASTER_MIN_ALPHA
 *   stop, excluding this Gaussian, if T (1 - alpha) <= GS_RASTER_T_EPS
 *   F += f alpha T; D += z alpha T; T *= 1 - alpha
 *   out_feature = F + T bg, out_alpha = 1 - T, out_depth = D
 * (out_depth is the alpha-weighted depth sum; divide by out_alpha for the
 * expected depth of the covered part.)
 * Backward: exact gradients of the above, except that no gradient flows
 * through alpha where it was clamped at GS_RASTER_MAX_ALPHA, 1 - alpha is
 * floored at GS_RASTER_ONE_MINUS_ALPHA_FLOOR when dividing, and culled
 * Gaussians get zero. The quaternion gradient is with respect to the raw
 * (unnormalized) q.
 *
 * Layouts: features and background are C x H x W (channel planes), alpha and
 * depth H x W, all float32, row 0 at the top.
 *
 * Inputs are checked: non-finite parameters or camera values are refused
 * with GS_ERR_NONFINITE (never propagated into outputs); bad sizes with
 * GS_ERR_ARG. A zero quaternion is treated as the identity rotation (and
 * gets zero rotation gradient). */
#ifndef GAZESPLAT_RASTER_H
#define GAZESPLAT_RASTER_H

#include <stddef.h>

#include "gazesplat/error.h"
#include "gazesplat/pool.h"

#ifdef __cplusplus
extern "C" {
#endif

#define GS_RASTER_TILE 16                /* tile edge, pixels */
#define GS_RASTER_NEAR 0.01f             /* near plane, camera units */
#define GS_RASTER_FAR 1e10f              /* far plane */
#define GS_RASTER_EPS2D 0.3f             /* screen-space dilation, px^2 */
#define GS_RASTER_CLAMP_MARGIN 0.15f     /* Jacobian frustum clamp margin */
#define GS_RASTER_MAX_ALPHA 0.99f
#define GS_RASTER_MIN_ALPHA (1.0f / 255.0f)
#define GS_RASTER_T_EPS 1e-4f            /* transmittance stop (exclusive) */
#define GS_RASTER_ONE_MINUS_ALPHA_FLOOR 1e-6f
#define GS_RASTER_MAX_CHANNELS 64
#define GS_RASTER_MAX_SIZE 8192          /* width and height limit */

typedef struct gs_camera {
    float fx, fy, cx, cy;   /* pixels */
    int width, height;      /* pixels, 1..GS_RASTER_MAX_SIZE */
    float viewmat[12];      /* world-to-camera [R | t], 3x4 row-major */
} gs_camera;

/* N Gaussians, structure of arrays. Read-only for the rasterizer. */
typedef struct gs_gaussians {
    int n;
    int channels;                /* C, 1..GS_RASTER_MAX_CHANNELS */
    const float *means;          /* n x 3 */
    const float *log_scales;     /* n x 3 */
    const float *quats;          /* n x 4, wxyz, any norm */
    const float *opacity_logits; /* n */
    const float *features;       /* n x C */
} gs_gaussians;

/* Gradients, same shapes as gs_gaussians. Backward ADDS into them; a NULL
 * array is skipped. */
typedef struct gs_gaussian_grads {
    float *means;
    float *log_scales;
    float *quats;
    float *opacity_logits;
    float *features;
} gs_gaussian_grads;

typedef enum gs_raster_path {
    GS_RASTER_FAST = 0,   /* tiled, culled, SIMD where available, threaded */
    GS_RASTER_SCALAR = 1  /* plain scalar single-thread reference path */
} gs_raster_path;

typedef struct gs_raster_options {
    int antialiased;      /* 1: opacity compensation for the 0.3 px blur */
    gs_raster_path path;
    /* > 0: the outputs already hold this forward's result for Gaussians
     * [0, changed_from) of g alone (same camera, background and options):
     * the fast path then composites only the tiles that one of
     * [changed_from, n) is binned to, and leaves the others' pixels as they
     * are. A tile none of them reaches has the same list, in the same
     * (depth, index) order, as that forward's, so the result is the bits
     * of a whole forward. No backward follows such a forward, and depth is
     * not written for the tiles left. 0: every tile. */
    int changed_from;
} gs_raster_options;

/* Workspace and saved forward state. Reused across calls: buffers grow as
 * needed and are kept. One gs_raster per concurrent render. */
typedef struct gs_raster gs_raster;

gs_raster *gs_raster_create(void);
void gs_raster_destroy(gs_raster *r);

/* Renders g seen by cam. background: C x H x W, or NULL for zeros.
 * out_features (C x H x W) and out_alpha (H x W) are required; out_depth
 * may be NULL. opt may be NULL (defaults: not antialiased, fast path).
 * pool may be NULL (single thread). Results are bit-identical for any
 * thread count. g, cam and background must stay unchanged until the
 * matching gs_raster_backward. */
int gs_raster_forward(gs_raster *r, gs_pool *pool, const gs_camera *cam,
                      const gs_gaussians *g, const float *background,
                      const gs_raster_options *opt, float *out_features,
                      float *out_alpha, float *out_depth, gs_error *err);

/* Crops of a larger image: later forwards clamp the Jacobian (above) to
 * the frustum of `frustum` (its fx, fy, cx, cy, width and height) instead
 * of each call's camera; NULL restores that. Rendered through the image's
 * camera with cx, cy shifted by a tile-aligned offset (x0, y0) and sized to
 * the crop, with the image's camera here, a crop composites each of its
 * pixels from the same Gaussians, with the same footprints, as the whole
 * image does (to float rounding of the shifted centre). */
int gs_raster_set_frustum(gs_raster *r, const gs_camera *frustum,
                          gs_error *err);

/* Whether fast forwards keep the records of each pixel group's
 * contributions that the backward replays (on by default). Turn it off for
 * renders no backward follows: the forward then skips that work and its
 * memory (4 MB at 20k Gaussians, 128², 34 MB at 512²). Outputs are the same
 * bytes either way, and a backward after such a forward still gives the
 * same gradients, evaluating every tile again. */
void gs_raster_set_records(gs_raster *r, int on);
/* Frees the records and the backward's scratch (what training forwards
 * and backwards grew; forwards regrow them). A backward of the forward
 * before still gives the same gradients, evaluating every tile again. */
void gs_raster_trim(gs_raster *r);

/* The fast path's instruction set for later forwards: "avx512" (4 x 4
 * pixel groups, AVX-512 F/VL/DQ/BW with FMA), "avx2" (4 x 2 pixel groups,
 * AVX2 with FMA), "generic" (4 x 2, the compiler's baseline vectors) or
 * "auto" (the best this CPU runs; the default). A new workspace takes the
 * environment variable GS_RASTER_ISA when it is set; if that names a set
 * that is unknown or that this CPU cannot run, its forwards fail with an
 * error saying so. Each set is deterministic and bit-identical across
 * thread counts; sets differ from each other in rounding only (fused
 * multiply-adds, lane sums). A backward uses its forward's set.
 * gs_raster_set_isa returns GS_ERR_ARG for an unknown name and
 * GS_ERR_UNSUPPORTED for a set this CPU cannot run, and then leaves the
 * workspace's set as it was. */
int gs_raster_set_isa(gs_raster *r, const char *isa, gs_error *err);
/* The set the next forward uses. */
const char *gs_raster_isa(const gs_raster *r);

/* Gradients of the last forward. v_features (C x H x W) is required;
 * v_alpha and v_depth (H x W) may be NULL (zero). Adds into grads and
 * v_background (C x H x W, may be NULL). */
int gs_raster_backward(gs_raster *r, gs_pool *pool, const float *v_features,
                       const float *v_alpha, const float *v_depth,
                       gs_gaussian_grads *grads, float *v_background,
                       gs_error *err);

/* Statistics of the last forward, for benchmarks and tests. visible and
 * intersections are lower on the fast path, which also drops Gaussians and
 * tiles that cannot reach alpha 1/255; contributions is the same on both. */
typedef struct gs_raster_stats {
    int visible;            /* Gaussians that survived culling */
    size_t intersections;   /* (tile, Gaussian) pairs composited */
    size_t contributions;   /* (pixel, Gaussian) pairs with alpha >= 1/255
                               before the stop; a finite-difference test
                               uses it to see a threshold being crossed */
    /* Wall-clock milliseconds of the last forward's phases: projection
     * (and the list of visible Gaussians), depth sort, tile binning,
     * compositing. For benchmarks; never part of a result. */
    double ms_project, ms_sort, ms_bin, ms_composite;
} gs_raster_stats;
void gs_raster_get_stats(const gs_raster *r, gs_raster_stats *stats);

#ifdef __cplusplus
}
#endif
#endif
