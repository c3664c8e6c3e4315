/* Timing and statistics shared by the benchmarks: wall and process CPU
 * time in milliseconds, and the median of a sample (sorted in place).
 * Include after defining _POSIX_C_SOURCE 200809L (clock_gettime). */
#ifndef GS_BENCH_UTIL_H
#define GS_BENCH_UTIL_H

#include <stdlib.h>
#include <time.h>

static inline double bench_clock_ms(clockid_t id)
{
    struct timespec ts;
    clock_gettime(id, &ts);
    return ts.tv_sec * 1e3 + ts.tv_nsec * 1e-6;
}

/* Wall clock (CLOCK_MONOTONIC). */
static inline double now_ms(void)
{
    return bench_clock_ms(CLOCK_MONOTONIC);
}

/* CPU time of the whole process, every thread of the pool: on a shared
 * machine wall time also counts the time other jobs held the cores. */
static inline double cpu_ms(void)
{
    return bench_clock_ms(CLOCK_PROCESS_CPUTIME_ID);
}

static inline int cmp_double(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

/* The median of v[0..n-1], n >= 1; v is left sorted. */
static inline double median(double *v, int n)
{
    qsort(v, (size_t)n, sizeof *v, cmp_double);
    return n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
}

#endif
