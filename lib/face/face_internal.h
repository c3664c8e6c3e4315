/* lib/face internals shared by its files (and white-box tests). */
#ifndef GS_FACE_INTERNAL_H
#define GS_FACE_INTERNAL_H

#include <stdint.h>

#include "gazesplat/face.h"

#define GS_FACE_MAX_PARTS 256
#define GS_FACE_MAX_FEATURES 4096

typedef struct gs_face_split {
    uint16_t idx1, idx2;  /* feature indices */
    float thresh;         /* go left when f[idx1] - f[idx2] > thresh */
} gs_face_split;

/* Uniform ensemble: n_cascades forests of n_trees complete trees of
 * n_splits splits (heap order, children 2n+1 and 2n+2) and n_leaves
 * leaves of dim = 2 n_parts floats. */
struct gs_face_shape_model {
    int n_parts, dim;
    int n_cascades, n_trees, n_splits, n_leaves, n_features;
    float initial[2 * GS_FACE_MAX_PARTS];  /* box-normalized mean shape */
    gs_face_split *splits;   /* [cascade][tree][split] */
    float *leaves;           /* [cascade][tree][leaf][dim] */
    uint16_t *anchor;        /* [cascade][feature] */
    float *delta;            /* [cascade][feature][2] */
};

/* Signed distance from (qx, qy) to the closed polygon pg (an eye's 6
 * contour points, geom.h pixels), negative inside (even-odd rule). */
double gs_face_contour_dist(const double pg[6][2], double qx, double qy);

#endif
