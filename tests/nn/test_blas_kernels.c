/* gs_nn_blas_select_kernels: on a CPU with AVX2 + FMA (or AVX-512) the
 * program ends up on OpenBLAS's fast kernels (unless OPENBLAS_CORETYPE was
 * set by the caller), and sgemm through them stays within float tolerance of
 * a double reference and gives the same bytes on every call.
 *
 *   test_blas_kernels [expected core name]
 *
 * ctest runs it twice: with OPENBLAS_CORETYPE unset (the selection), and
 * with OPENBLAS_CORETYPE=Prescott, the fallback kept by the user's choice. */
#define _POSIX_C_SOURCE 200809L
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "gazesplat/nn.h"
#include "gs_test.h"

static unsigned long long rng = 88172645463325252ULL;
static float urand(void)
{
    rng ^= rng << 13, rng ^= rng >> 7, rng ^= rng << 17;
    return (float)((rng >> 11) * (1.0 / 9007199254740992.0)) * 2.0f - 1.0f;
}

/* out[B,OC] = in[B,IC] . w[OC,IC]^T + b against a double loop; twice. */
static void check_linear(int B, int IC, int OC)
{
    size_t ni = (size_t)B * IC, nw = (size_t)OC * IC, no = (size_t)B * OC;
    float *in = malloc(ni * sizeof *in), *w = malloc(nw * sizeof *w);
    float *b = malloc((size_t)OC * sizeof *b);
    float *o1 = malloc(no * sizeof *o1), *o2 = malloc(no * sizeof *o2);
    CHECK(in && w && b && o1 && o2);
    for (size_t i = 0; i < ni; i++)
        in[i] = urand();
    for (size_t i = 0; i < nw; i++)
        w[i] = urand();
    for (int i = 0; i < OC; i++)
        b[i] = urand();
    CHECK_EQ_INT(gs_nn_linear_forward(o1, in, w, b, B, IC, OC), GS_OK);
    CHECK_EQ_INT(gs_nn_linear_forward(o2, in, w, b, B, IC, OC), GS_OK);
    double worst = 0.0;
    for (int r = 0; r < B; r++)
        for (int c = 0; c < OC; c++) {
            double s = b[c], mag = fabs(b[c]);
            for (int k = 0; k < IC; k++) {
                double p = (double)in[(size_t)r * IC + k] * w[(size_t)c * IC + k];
                s += p, mag += fabs(p);
            }
            double e = fabs(o1[(size_t)r * OC + c] - s) / (mag + 1e-30);
            worst = e > worst ? e : worst;
        }
    printf("  linear %dx%d -> %d: worst error %.2e of sum |terms|\n", B, IC, OC, worst);
    CHECK_MSG(worst < 1e-5, "linear %dx%dx%d off by %.3g", B, IC, OC, worst);
    CHECK_MSG(memcmp(o1, o2, no * sizeof *o1) == 0, "linear %dx%dx%d: two calls differ", B, IC,
              OC);
    free(in), free(w), free(b), free(o1), free(o2);
}

int main(int argc, char **argv)
{
    const char *preset = getenv("OPENBLAS_CORETYPE");
    int rc = gs_nn_blas_select_kernels(argv);
    const char *core = gs_nn_blas_core();
    printf("OPENBLAS_CORETYPE %s, select %d, kernels %s\n", preset ? preset : "(unset)", rc,
           core ? core : "?");
    CHECK_EQ_INT(rc, GS_OK);
    CHECK(getenv("OPENBLAS_CORETYPE") || !preset);
    if (argc > 1)
        CHECK_MSG(core && strcmp(core, argv[1]) == 0, "kernels %s, expected %s", core, argv[1]);
#if defined(__x86_64__)
    __builtin_cpu_init();
    if (!preset && __builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma"))
        CHECK_MSG(core && (strstr(core, "Haswell") || strstr(core, "Skylake") ||
                           strstr(core, "Zen") || strstr(core, "Cooperlake") ||
                           strstr(core, "Sapphire")),
                  "AVX2 CPU left on kernels %s", core);
#endif
    gs_nn_blas_set_threads(1);
    check_linear(1, 1, 1);
    check_linear(37, 53, 29);
    check_linear(256, 144, 32);
    check_linear(1024, 64, 128);
    GS_TEST_END();
}
