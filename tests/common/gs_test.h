/* Minimal test harness: checks print what differed and count failures;
 * GS_TEST_END returns non-zero if any check failed. */
#ifndef GS_TEST_H
#define GS_TEST_H

#include <math.h>
#include <stdio.h>
#include <stdlib.h>

static int gs_test_failures;
static int gs_test_checks;

#define CHECK(cond)                                                           \
    do {                                                                      \
        gs_test_checks++;                                                     \
        if (!(cond)) {                                                        \
            gs_test_failures++;                                               \
            fprintf(stderr, "%s:%d: CHECK failed: %s\n", __FILE__, __LINE__,  \
                    #cond);                                                   \
        }                                                                     \
    } while (0)

#define CHECK_MSG(cond, ...)                                                  \
    do {                                                                      \
        gs_test_checks++;                                                     \
        if (!(cond)) {                                                        \
            gs_test_failures++;                                               \
            fprintf(stderr, "%s:%d: CHECK failed: %s: ", __FILE__, __LINE__,  \
                    #cond);                                                   \
            fprintf(stderr, __VA_ARGS__);                                     \
            fputc('\n', stderr);                                              \
        }                                                                     \
    } while (0)

#define CHECK_EQ_INT(a, b)                                                    \
    do {                                                                      \
        long long va_ = (long long)(a), vb_ = (long long)(b);                 \
        CHECK_MSG(va_ == vb_, "%s = %lld, %s = %lld", #a, va_, #b, vb_);      \
    } while (0)

/* |a - b| <= atol + rtol |b|, and both finite. */
#define CHECK_CLOSE(a, b, atol, rtol)                                         \
    do {                                                                      \
        double va_ = (double)(a), vb_ = (double)(b);                          \
        CHECK_MSG(isfinite(va_) && isfinite(vb_) &&                           \
                      fabs(va_ - vb_) <= (atol) + (rtol)*fabs(vb_),           \
                  "%s = %.9g, %s = %.9g, diff %.3g (atol %g, rtol %g)", #a,   \
                  va_, #b, vb_, fabs(va_ - vb_), (double)(atol),              \
                  (double)(rtol));                                            \
    } while (0)

/* Compares n floats; reports the count over tolerance, the worst index and
 * the first few mismatches. Returns the number of mismatches. */
static inline int gs_check_arrays(const char *what, const float *got,
                                  const float *want, size_t n, double atol,
                                  double rtol)
{
    size_t bad = 0, worst = 0;
    double worst_excess = -1.0, max_abs = 0.0;
    for (size_t i = 0; i < n; i++) {
        double g = got[i], w = want[i], d = fabs(g - w);
        double tol = atol + rtol * fabs(w);
        if (d > max_abs || !isfinite(d))
            max_abs = isfinite(d) ? d : INFINITY;
        if (!(d <= tol)) {
            if (bad < 5)
                fprintf(stderr, "  %s[%zu]: got %.9g want %.9g (diff %.3g, tol %.3g)\n",
                        what, i, g, w, d, tol);
            if (!isfinite(d) || d - tol > worst_excess) {
                worst_excess = isfinite(d) ? d - tol : INFINITY;
                worst = i;
            }
            bad++;
        }
    }
    gs_test_checks++;
    if (bad) {
        gs_test_failures++;
        fprintf(stderr, "%s: %zu of %zu values over tolerance (atol %g, rtol %g); "
                "max |diff| %.3g; worst at %zu: got %.9g want %.9g\n",
                what, bad, n, atol, rtol, max_abs, worst, got[worst], want[worst]);
    }
    return (int)bad;
}

#define GS_TEST_END()                                                         \
    do {                                                                      \
        if (gs_test_failures) {                                               \
            fprintf(stderr, "FAILED: %d of %d checks\n", gs_test_failures,    \
                    gs_test_checks);                                          \
            return 1;                                                         \
        }                                                                     \
        printf("ok: %d checks\n", gs_test_checks);                            \
        return 0;                                                             \
    } while (0)

#endif
