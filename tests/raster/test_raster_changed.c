/* gs_raster_options.changed_from: when the outputs already hold the
 * forward of the first k Gaussians, a forward of all n with changed_from = k
 * composites only the tiles that one of [k, n) is binned to, and gives the
 * bits of a whole forward of all n (the model's render starts its merged
 * map from the face-only map and composites the eyes' tiles only).
 *
 * The scene: k "face" Gaussians over the whole image and n - k "eye"
 * Gaussians in a small box, their depths interleaved with the face's (some
 * in front, some behind, one at a face Gaussian's exact depth), a non-zero
 * background, 32 channels (the model's), on the calling thread and on a
 * pool of 2. Tiles the eyes do not reach are shown to be left alone (a NaN
 * fill stays there), so the test fails if the option composites everything
 * or nothing. */
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "gazesplat/pool.h"
#include "gazesplat/raster.h"
#include "gs_test.h"

enum { W = 80, H = 64, C = 32, NF = 400, NE = 60, N = NF + NE, TS = GS_RASTER_TILE };

static float means[N * 3], scales[N * 3], quats[N * 4], opac[N], feat[N * C];
static float bg[C * W * H];

static uint64_t g_s = 0x243F6A8885A308D3ull;

static double urand(void)
{
    g_s = g_s * 6364136223846793005ull + 1442695040888963407ull;
    return (double)(g_s >> 11) / 9007199254740992.0;
}

/* Gaussian i at image position (u, v), depth z. */
static void put(int i, double u, double v, double z, double s)
{
    means[3 * i] = (float)((u - 0.5 * W) * z / 120.0);
    means[3 * i + 1] = (float)((v - 0.5 * H) * z / 120.0);
    means[3 * i + 2] = (float)z;
    for (int k = 0; k < 3; k++)
        scales[3 * i + k] = (float)log(s * (0.6 + 0.8 * urand()));
    double a = urand() * 3.0;
    quats[4 * i] = (float)cos(a), quats[4 * i + 1] = (float)(0.3 * sin(a));
    quats[4 * i + 3] = (float)(0.9 * sin(a));
    opac[i] = (float)(4.0 * urand() - 1.0);
    for (int k = 0; k < C; k++)
        feat[(size_t)i * C + k] = (float)(urand() - 0.3);
}

static int fwd(gs_raster *r, gs_pool *pool, const gs_camera *cam, int n, int from,
               float *out, float *alpha)
{
    gs_gaussians g = {n, C, means, scales, quats, opac, feat};
    gs_raster_options o = {.antialiased = 0, .path = GS_RASTER_FAST, .changed_from = from};
    gs_error err;
    int rc = gs_raster_forward(r, pool, cam, &g, bg, &o, out, alpha, NULL, &err);
    if (rc)
        fprintf(stderr, "forward: %s\n", err.msg);
    return rc;
}

static void run(gs_pool *pool, const char *name)
{
    gs_camera cam;
    memset(&cam, 0, sizeof cam);
    cam.fx = cam.fy = 120.0f;
    cam.cx = 0.5f * W, cam.cy = 0.5f * H;
    cam.width = W, cam.height = H;
    cam.viewmat[0] = cam.viewmat[5] = cam.viewmat[10] = 1.0f;
    size_t nf = (size_t)C * W * H, na = (size_t)W * H;
    float *ref = malloc(nf * sizeof(float)), *refa = malloc(na * sizeof(float));
    float *out = malloc(nf * sizeof(float)), *outa = malloc(na * sizeof(float));
    gs_raster *r = gs_raster_create();
    CHECK(ref && refa && out && outa && r);
    if (!ref || !refa || !out || !outa || !r)
        return;
    CHECK(fwd(r, pool, &cam, N, 0, ref, refa) == GS_OK);
    /* the first NF alone, then all with changed_from = NF */
    CHECK(fwd(r, pool, &cam, NF, 0, out, outa) == GS_OK);
    CHECK(fwd(r, pool, &cam, N, NF, out, outa) == GS_OK);
    CHECK_MSG(!memcmp(out, ref, nf * sizeof(float)) && !memcmp(outa, refa, na * sizeof(float)),
              "%s: changed_from gives other bits than a whole forward", name);
    /* which tiles it composited: a NaN fill stays where the eyes do not
     * reach, and is overwritten where they do */
    for (size_t i = 0; i < nf; i++)
        out[i] = NAN;
    for (size_t i = 0; i < na; i++)
        outa[i] = NAN;
    CHECK(fwd(r, pool, &cam, N, NF, out, outa) == GS_OK);
    int tx = (W + TS - 1) / TS, ty = (H + TS - 1) / TS, left = 0, done = 0, mixed = 0;
    for (int t = 0; t < tx * ty; t++) {
        int x0 = t % tx * TS, y0 = t / tx * TS, nan = 0, px = 0, same = 1;
        for (int y = y0; y < y0 + TS && y < H; y++)
            for (int x = x0; x < x0 + TS && x < W; x++, px++) {
                nan += isnan(outa[y * W + x]);
                for (int k = 0; k < C; k++) {
                    size_t i = ((size_t)k * H + y) * W + x;
                    same &= !memcmp(&out[i], &ref[i], sizeof(float));
                }
            }
        left += nan == px;
        done += nan == 0 && same;
        mixed += nan != px && !(nan == 0 && same);
    }
    printf("%s: %d tiles composited, %d left as filled, of %d; bits of the whole forward\n",
           name, done, left, tx * ty);
    CHECK_MSG(left > 0 && done > 0 && mixed == 0,
              "%s: %d tiles composited, %d left, %d neither", name, done, left, mixed);
    /* nothing changed: nothing composited */
    CHECK(fwd(r, pool, &cam, N, N, out, outa) == GS_OK);
    CHECK_MSG(isnan(outa[0]) && isnan(out[nf - 1]), "%s: changed_from = n wrote pixels", name);
    /* no backward after a forward of some tiles; a whole forward allows it again */
    gs_gaussians g = {N, C, means, scales, quats, opac, feat};
    float *vm = calloc((size_t)N * 3, sizeof(float)), *vs = calloc((size_t)N * 3, sizeof(float));
    float *vq = calloc((size_t)N * 4, sizeof(float)), *vo = calloc(N, sizeof(float));
    float *vf = calloc((size_t)N * C, sizeof(float));
    gs_gaussian_grads gg = {vm, vs, vq, vo, vf};
    gs_error err;
    CHECK(gs_raster_backward(r, pool, ref, NULL, NULL, &gg, NULL, &err) != GS_OK);
    CHECK(fwd(r, pool, &cam, N, 0, out, outa) == GS_OK);
    CHECK(gs_raster_backward(r, pool, ref, NULL, NULL, &gg, NULL, &err) == GS_OK);
    /* out of range */
    gs_raster_options o = {.antialiased = 0, .path = GS_RASTER_FAST, .changed_from = N + 1};
    CHECK(gs_raster_forward(r, pool, &cam, &g, bg, &o, out, outa, NULL, &err) == GS_ERR_ARG);
    o.changed_from = -1;
    CHECK(gs_raster_forward(r, pool, &cam, &g, bg, &o, out, outa, NULL, &err) == GS_ERR_ARG);
    free(vm), free(vs), free(vq), free(vo), free(vf);
    gs_raster_destroy(r);
    free(ref), free(refa), free(out), free(outa);
}

int main(void)
{
    for (int i = 0; i < NF; i++) /* the face: everywhere, depth 80..120 */
        put(i, urand() * W, urand() * H, 80.0 + 40.0 * urand(), 0.25 + 0.5 * urand());
    for (int i = NF; i < N; i++) /* the eyes: a box of two by one tiles */
        put(i, 20.0 + 24.0 * urand(), 20.0 + 8.0 * urand(), 70.0 + 60.0 * urand(), 0.08);
    means[3 * NF + 2] = means[3 * 7 + 2]; /* a tie in depth with a face Gaussian */
    for (size_t i = 0; i < sizeof bg / sizeof bg[0]; i++)
        bg[i] = (float)(i % 7) * 0.1f;
    run(NULL, "one thread");
    gs_pool *pool = gs_pool_create(2);
    CHECK(pool != NULL);
    run(pool, "2 threads");
    gs_pool_destroy(pool);
    GS_TEST_END();
}
