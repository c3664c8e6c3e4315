/* The fast compositing kernels built for AVX-512 (F, VL, DQ, BW) + FMA,
 * 16 pixels per group and per vector; chosen at run time. */
#define GS_KERNELS gs_raster_kernels_avx512
#define GS_LANES 16
#include "raster_tiles.c"
