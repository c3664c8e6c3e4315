/* Choosing OpenBLAS's kernels on CPUs it does not recognise.
 *
 * OpenBLAS (DYNAMIC_ARCH builds, as Debian ships) picks its kernels from the
 * CPU model when libopenblas is loaded, before main. A virtual CPU with an
 * unknown model gets the SSE3 "Prescott" sgemm even when it has AVX-512,
 * about four times slower. The only switch is OPENBLAS_CORETYPE, read at that
 * load, so a running process cannot change it: it has to start again with the
 * variable set. */
#define _POSIX_C_SOURCE 200809L /* setenv */
#include "gazesplat/nn.h"

#include <cblas.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

/* The core type the CPU's features allow, from CPUID (GCC's checks include
 * the operating system's support for the AVX and AVX-512 register state),
 * or NULL. OpenBLAS's SkylakeX kernels use AVX-512 F, CD, BW, DQ and VL. */
static const char *capable_coretype(void)
{
#if defined(__x86_64__) || defined(__i386__)
    __builtin_cpu_init();
    if (__builtin_cpu_supports("avx512f") && __builtin_cpu_supports("avx512cd") &&
        __builtin_cpu_supports("avx512bw") && __builtin_cpu_supports("avx512dq") &&
        __builtin_cpu_supports("avx512vl"))
        return "SkylakeX";
    if (__builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma"))
        return "Haswell";
#endif
    return NULL;
}

/* Core names OpenBLAS falls back to on a CPU it does not recognise. */
static int is_fallback(const char *core)
{
    static const char *const names[] = {"Prescott", "Core2", "Nehalem", "Penryn", "Dunnington",
                                        "Atom", "Katmai", "Coppermine", "Northwood"};
    if (!core)
        return 0;
    for (size_t i = 0; i < sizeof names / sizeof names[0]; i++)
        if (strcmp(core, names[i]) == 0)
            return 1;
    return 0;
}

const char *gs_nn_blas_core(void)
{
    return openblas_get_corename();
}

int gs_nn_blas_select_kernels(char **argv)
{
    if (getenv("OPENBLAS_CORETYPE"))
        return 0; /* chosen by the user, or by our own exec below */
    const char *want = capable_coretype();
    if (!want || !is_fallback(openblas_get_corename()))
        return 0;
    if (setenv("OPENBLAS_CORETYPE", want, 1) != 0)
        return GS_ERR_UNSUPPORTED;
    execv("/proc/self/exe", argv);
    unsetenv("OPENBLAS_CORETYPE"); /* exec failed: go on as we were */
    return GS_ERR_UNSUPPORTED;
}
