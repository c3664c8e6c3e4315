/* gs_mlp forward/backward against central differences on a small batch
 * (every weight, bias and input), where float32 steps of 1e-3 cross no
 * LeakyReLU kink and stay far above rounding. */
#include <math.h>
#include <stdio.h>
#include <string.h>

#include "../../lib/model/model_internal.h"
#include "gs_test.h"

enum { N = 5, D0 = 6, D1 = 7, D2 = 5, D3 = 3 };

static float W[D0 * D1 + D1 * D2 + D2 * D3], B[D1 + D2 + D3];
static float GW[sizeof W / sizeof W[0]], GB[sizeof B / sizeof B[0]];
static float in[N * D0], wt[N * D3], out[N * D3], din[N * D0];
static float acts[1024], scratch[1024];

static double objective(const gs_mlp *m)
{
    gs_mlp_forward(m, in, N, acts, out);
    double s = 0;
    for (int i = 0; i < N * D3; i++)
        s += (double)wt[i] * out[i];
    return s;
}

static int compare(float *x, float g, const gs_mlp *m, const char *what,
                   int i)
{
    float save = *x;
    *x = save + 1e-3f;
    double up = objective(m);
    *x = save - 1e-3f;
    double dn = objective(m);
    *x = save;
    double num = (up - dn) / ((double)(save + 1e-3f) - (save - 1e-3f));
    if (fabs(num - g) > 2e-3 * fmax(fabs(num), fabs(g)) + 2e-5) {
        printf("  %s[%d]: analytic %+.6e numeric %+.6e\n", what, i, g, num);
        return 1;
    }
    return 0;
}

int main(void)
{
    gs_mlp m = {3, {D0, D1, D2, D3, 0}, {0}, {0}}, g = m;
    unsigned r = 99;
#define RND() (r = r * 1103515245u + 12345u, ((r >> 8) & 0xffff) / 65536.0f - 0.5f)
    size_t wo = 0, bo = 0;
    for (int l = 0; l < 3; l++) {
        m.w[l] = W + wo;
        g.w[l] = GW + wo;
        m.b[l] = B + bo;
        g.b[l] = GB + bo;
        wo += (size_t)m.dims[l] * m.dims[l + 1];
        bo += (size_t)m.dims[l + 1];
    }
    for (size_t i = 0; i < wo; i++)
        W[i] = RND();
    for (size_t i = 0; i < bo; i++)
        B[i] = RND();
    for (int i = 0; i < N * D0; i++)
        in[i] = RND();
    for (int i = 0; i < N * D3; i++)
        wt[i] = RND();
    CHECK(gs_mlp_act_size(&m, N) <= sizeof acts / sizeof acts[0]);
    CHECK(gs_mlp_scratch_size(&m, N) <= sizeof scratch / sizeof scratch[0]);
    objective(&m);
    gs_mlp_backward(&m, &g, in, N, acts, wt, din, scratch);
    int bad = 0;
    for (size_t i = 0; i < wo; i++)
        bad += compare(&W[i], GW[i], &m, "w", (int)i);
    for (size_t i = 0; i < bo; i++)
        bad += compare(&B[i], GB[i], &m, "b", (int)i);
    for (int i = 0; i < N * D0; i++)
        bad += compare(&in[i], din[i], &m, "in", i);
    printf("%zu weights, %zu biases, %d inputs checked\n", wo, bo, N * D0);
    CHECK_MSG(bad == 0, "%d MLP gradient mismatches", bad);
    /* Backward accumulates: a second call doubles every gradient. */
    float gw0 = GW[3];
    gs_mlp_backward(&m, &g, in, N, acts, wt, din, scratch);
    CHECK_CLOSE(GW[3], 2 * gw0, 1e-6, 1e-5);
    GS_TEST_END();
}
