/* The monotonic clock every timing in gazesplat reads (CLOCK_MONOTONIC):
 * durations, deadlines, progress and ETA lines. Not the time of day. */
#ifndef GAZESPLAT_CLOCK_H
#define GAZESPLAT_CLOCK_H

#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

int64_t gs_clock_ns(void); /* nanoseconds */
int64_t gs_clock_ms(void); /* whole milliseconds */
double gs_clock_s(void);   /* seconds, with the nanoseconds */

#ifdef __cplusplus
}
#endif
#endif
