/* Helpers shared by the nn tests: a seeded generator and buffers. */
#ifndef NN_TEST_UTIL_H
#define NN_TEST_UTIL_H

#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* splitmix64: a small deterministic generator. */
typedef struct { uint64_t s; } nn_rng;

static inline uint64_t nn_rng_next(nn_rng *r)
{
    uint64_t z = (r->s += 0x9E3779B97F4A7C15ull);
    z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
    z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
    return z ^ (z >> 31);
}

/* Uniform in [lo, hi). */
static inline float nn_rng_uniform(nn_rng *r, float lo, float hi)
{
    double u = (double)(nn_rng_next(r) >> 11) * (1.0 / 9007199254740992.0);
    return (float)(lo + (hi - lo) * u);
}

static inline void nn_fill(nn_rng *r, float *x, size_t n, float lo, float hi)
{
    for (size_t i = 0; i < n; i++)
        x[i] = nn_rng_uniform(r, lo, hi);
}

/* Uniform magnitudes in [lo, hi) with random signs: values kept away from
 * zero, where kinks (ReLU, |x|) would spoil finite differences. */
static inline void nn_fill_away(nn_rng *r, float *x, size_t n, float lo,
                                float hi)
{
    for (size_t i = 0; i < n; i++) {
        float m = nn_rng_uniform(r, lo, hi);
        x[i] = (nn_rng_next(r) & 1) ? m : -m;
    }
}

/* calloc that aborts the test on failure. */
static inline float *nn_alloc(size_t n)
{
    float *p = calloc(n ? n : 1, sizeof(float));
    if (!p) {
        fprintf(stderr, "out of memory (%zu floats)\n", n);
        exit(2);
    }
    return p;
}

#endif
