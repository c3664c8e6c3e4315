/* The one monotonic clock (gazesplat/clock.h). */
#define _POSIX_C_SOURCE 200809L /* clock_gettime */
#include "gazesplat/clock.h"

#include <time.h>

int64_t gs_clock_ns(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (int64_t)ts.tv_sec * 1000000000 + ts.tv_nsec;
}

int64_t gs_clock_ms(void)
{
    return gs_clock_ns() / 1000000;
}

double gs_clock_s(void)
{
    return 1e-9 * (double)gs_clock_ns();
}
