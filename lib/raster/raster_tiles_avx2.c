/* The fast compositing kernels built for AVX2 + FMA; chosen at run time. */
#define GS_KERNELS gs_raster_kernels_avx2
#include "raster_tiles.c"
