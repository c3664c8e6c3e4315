/* Private state shared by the rasterizer's translation units. */
#ifndef GS_RASTER_INTERNAL_H
#define GS_RASTER_INTERNAL_H

#include <stddef.h>
#include <stdint.h>

#include "gazesplat/raster.h"

/* Per-Gaussian projection results, indexed by Gaussian id. */
typedef struct gs_proj {
    float *mean2d;  /* n x 2, pixels */
    float *conic;   /* n x 3: (a, b, c) of the inverse blurred 2D covariance */
    float *depth;   /* n, camera z */
    float *opacity; /* n, sigmoid(logit), times comp when antialiased */
    float *comp;    /* n, sqrt(det Sigma2 / det(Sigma2 + eps I)) */
    float *radius;  /* n, pixels; 0 = culled */
} gs_proj;

/* What the fast compositing reads of Gaussian i, in one cache line, so a
 * tile's walk through its list costs one miss per Gaussian (plus its
 * features) instead of one per array. Fast path only. */
typedef struct gs_splat {
    float mx, my;  /* mean2d */
    float a, b, c; /* conic */
    float op, z;   /* opacity, depth */
    float thr;     /* ln(255 op) widened: alpha >= 1/255 needs sigma <= thr */
    float ex, ey;  /* half-extent of the sigma <= thr ellipse, widened */
    int32_t tiles[4]; /* tile box [x0, x1) x [y0, y1) that the ellipse's box meets */
    float pad[2];
} gs_splat;

/* Projection-space gradients, gathered from the compositing pass. */
typedef struct gs_proj_grad {
    float *mean2d;  /* n x 2 */
    float *conic;   /* n x 3 */
    float *opacity; /* n */
    float *depth;   /* n */
} gs_proj_grad;

/* Gradients per (tile, Gaussian) intersection in the fast backward, so that
 * sums never depend on thread scheduling: mean2d 2, conic 3, opacity 1,
 * depth 1, then 1 when the pair changed a pixel (0: the rest is unset and
 * the gather skips it), then C feature values. */
#define GS_SLOT_HEAD 8

/* The forward's record of what each tile composited, replayed by the fast
 * backward instead of evaluating the Gaussians again: one record per
 * (Gaussian, L-pixel group) pair with at least one contributing pixel.
 * Each worker appends the records of the tiles it composites to its own
 * arena; a tile whose records do not fit (GS_RASTER_REC_BUDGET) or whose
 * list is too long to encode is evaluated again by the backward, with the
 * same results. The layout belongs to the kernel table that wrote it
 * (raster_tiles.c): L is 8 or 16 lanes. */
typedef struct gs_rec_arena {
    uint32_t *hdr; /* per record: pair in the tile's list << group bits | group */
    float *vis;    /* per record: exp(-sigma) of the group's L pixels, -1 where
                      a pixel did not contribute */
    size_t n, cap;
} gs_rec_arena;

/* Bytes of records kept per forward, all workers together (4 + 4 L per
 * record). */
#define GS_RASTER_REC_BUDGET ((size_t)64 << 20)
#define GS_REC_NONE UINT32_MAX

typedef struct gs_tile_rec {
    uint32_t worker, n; /* n: GS_REC_NONE when the tile was not recorded */
    size_t off;         /* first record in the worker's arena */
} gs_tile_rec;

struct gs_raster {
    int have_forward;
    gs_camera cam;
    float clamp_lim[4];   /* x/z, y/z limits of the Jacobian clamp */
    int has_frustum;      /* gs_raster_set_frustum: clamp to frustum's */
    gs_camera frustum;
    gs_gaussians g;
    const float *background;
    gs_raster_options opt;
    int tiles_x, tiles_y;

    gs_proj proj;
    gs_proj_grad pgrad;
    size_t cap_n;
    void *n_block;
    gs_splat *splats;     /* n, 64-byte aligned; fast path */
    size_t cap_splats;

    uint32_t *order, *order_tmp; /* visible ids sorted by (depth, id) */
    uint32_t *keys, *keys_tmp;
    size_t cap_order;

    uint32_t *bin_counts; /* binning: pairs per (chunk of Gaussians, tile) */
    size_t cap_bin_counts;
    uint32_t *tile_off;   /* tiles + 1 offsets into isect */
    uint32_t *tile_order; /* fast path: tiles by decreasing list length */
    size_t cap_tile_order;
    uint64_t *tile_keys;  /* its sort keys */
    size_t cap_tile_keys;
    size_t cap_tiles;
    uint32_t *isect;      /* Gaussian id per intersection, per tile by depth */
    size_t n_isect, cap_isect;

    float *t_final;       /* H x W transmittance after compositing */
    uint32_t *last;       /* H x W: 1 + list position of the last contributor */
    size_t cap_pix, cap_last;

    void *scratch;        /* per-worker tile buffers of the fast path */
    size_t cap_scratch;

    float *slots;         /* fast backward scratch */
    size_t cap_slots;

    gs_rec_arena *arenas; /* one per worker of the last fast forward */
    int n_arenas;
    gs_tile_rec *tile_rec; /* per tile */
    size_t cap_tile_rec;
    size_t rec_budget;    /* bytes of records in all; 0: GS_RASTER_REC_BUDGET */
    int no_records;       /* gs_raster_set_records(r, 0): forwards keep none */

    const struct gs_raster_kernels *kern;     /* fast path's set for the next forward */
    const struct gs_raster_kernels *fwd_kern; /* the set the last fast forward used */
    char isa_error[64];   /* GS_RASTER_ISA named no usable set: forwards fail */

    int visible;
    size_t contributions;
    double ms_phase[4]; /* last forward: projection, sort, binning, compositing */
};

/* Growth helper: ensures *buf holds at least want elements of size elem. */
int gs_raster_reserve(void **buf, size_t *cap, size_t want, size_t elem);

/* Scalar reference compositing (raster_scalar.c). */
void gs_raster_scalar_forward(gs_raster *r, const float *bg, float *out_f,
                              float *out_alpha, float *out_depth);
void gs_raster_scalar_backward(gs_raster *r, const float *v_f,
                               const float *v_alpha, const float *v_depth,
                               float *v_features, float *v_bg);

/* Fast compositing (raster_tiles.c, built per instruction set). */
typedef struct gs_raster_kernels {
    const char *name; /* "avx512", "avx2", "generic" */
    int (*forward)(gs_raster *r, gs_pool *pool, const float *bg, float *out_f,
                   float *out_alpha, float *out_depth);
    /* Composites tiles [t0, t1) backward into r->slots. */
    int (*backward)(gs_raster *r, gs_pool *pool, int t0, int t1,
                     size_t slot0, const float *v_f, const float *v_alpha,
                     const float *v_depth, float *v_bg);
    int (*all_finite)(const float *x, size_t n);
    /* Projection of Gaussians [i0, i1) and its gradient; i0 a multiple of 8. */
    void (*project)(gs_raster *r, int i0, int i1);
    void (*project_backward)(gs_raster *r, int i0, int i1, gs_gaussian_grads *grads);
} gs_raster_kernels;

extern const gs_raster_kernels gs_raster_kernels_generic;
extern const gs_raster_kernels gs_raster_kernels_avx2;
extern const gs_raster_kernels gs_raster_kernels_avx512;

#endif
