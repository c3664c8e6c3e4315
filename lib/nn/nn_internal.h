/* Argument checks shared by the nn kernels. */
#ifndef GS_NN_INTERNAL_H
#define GS_NN_INTERNAL_H

#include <limits.h>
#include <stddef.h>

#include "gazesplat/error.h"

/* *out = a * b for a, b >= 1; 0 when the product does not fit an int, the
 * dimension type of BLAS, which bounds every size we pass to sgemm. */
static inline int nn_mul(int a, int b, int *out)
{
    if (a < 1 || b < 1 || a > INT_MAX / b)
        return 0;
    *out = a * b;
    return 1;
}

/* GS_OK when every size is >= 1, GS_ERR_ARG otherwise. */
static inline int nn_sizes_ok3(int a, int b, int c)
{
    return (a >= 1 && b >= 1 && c >= 1) ? GS_OK : GS_ERR_ARG;
}

/* Status for a product that nn_mul refused: a bad size or an overflow. */
static inline int nn_mul_status(int a, int b)
{
    return (a < 1 || b < 1) ? GS_ERR_ARG : GS_ERR_LIMIT;
}

#endif
