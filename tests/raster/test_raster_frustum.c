/* gs_raster_set_frustum: a tile-aligned crop rendered through the image's
 * camera shifted to the crop, with the image's frustum for the Jacobian
 * clamp, equals the whole image over the crop (to float rounding). Without
 * it, a Gaussian centred outside the crop's own clamp frustum (0.15 of the
 * crop's size beyond its edges) but reaching into the crop gets another
 * footprint: the test shows that difference too, so it can fail. */
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "gazesplat/raster.h"
#include "gs_test.h"

enum { W = 64, H = 64, C = 3, N = 40 };

static float means[N * 3], scales[N * 3], quats[N * 4], opac[N], feat[N * C];

/* Gaussian i at image position (u, v), depth z, log-scales (sx, sy, sz). */
static void put(int i, double u, double v, double z, double sx, double sy,
                double sz, float f)
{
    means[3 * i] = (float)((u - 32.0) * z / 200.0);
    means[3 * i + 1] = (float)((v - 32.0) * z / 200.0);
    means[3 * i + 2] = (float)z;
    scales[3 * i] = (float)sx, scales[3 * i + 1] = (float)sy;
    scales[3 * i + 2] = (float)sz;
    /* tilted about y: the depth axis leans into x, where the clamp acts */
    quats[4 * i] = 0.92f, quats[4 * i + 2] = 0.39f;
    opac[i] = 2.0f;
    for (int k = 0; k < C; k++)
        feat[i * C + k] = f * (float)(k + 1) / C;
}

static double crop_diff(gs_raster *r, const gs_camera *full,
                        const float *img, int x0, int y0, int w, int h)
{
    gs_camera cam = *full;
    cam.cx -= (float)x0, cam.cy -= (float)y0;
    cam.width = w, cam.height = h;
    gs_gaussians g = {N, C, means, scales, quats, opac, feat};
    float *out = calloc((size_t)C * w * h, sizeof(float));
    float *alpha = calloc((size_t)w * h, sizeof(float));
    gs_error err;
    double worst = -1.0;
    if (out && alpha &&
        gs_raster_forward(r, NULL, &cam, &g, NULL, NULL, out, alpha, NULL,
                          &err) == GS_OK) {
        worst = 0.0;
        for (int k = 0; k < C; k++)
            for (int y = 0; y < h; y++)
                for (int x = 0; x < w; x++) {
                    double a = out[((size_t)k * h + y) * w + x];
                    double b = img[((size_t)k * H + y + y0) * W + x + x0];
                    worst = fmax(worst, fabs(a - b));
                }
    }
    free(out);
    free(alpha);
    return worst;
}

int main(void)
{
    gs_camera full;
    memset(&full, 0, sizeof full);
    full.fx = full.fy = 200.0f;
    full.cx = full.cy = 32.0f;
    full.width = W, full.height = H;
    full.viewmat[0] = full.viewmat[5] = full.viewmat[10] = 1.0f;
    /* long Gaussians centred left of the crop [16, 48) x [16, 32), beyond
     * its clamp frustum (x < 16 - 0.15 * 32), reaching into it */
    for (int i = 0; i < 8; i++)
        put(i, 6.0 + i, 18.0 + 1.5 * i, 100.0, log(0.6), log(0.3), log(6.0),
            0.9f);
    uint64_t s = 7;
    for (int i = 8; i < N; i++) { /* small ones anywhere */
        s = s * 6364136223846793005ull + 1442695040888963407ull;
        double u = (double)(s >> 40) / (1 << 24) * W;
        s = s * 6364136223846793005ull + 1442695040888963407ull;
        double v = (double)(s >> 40) / (1 << 24) * H;
        put(i, u, v, 90.0 + i, log(0.4), log(0.3), log(0.2), 0.3f);
    }
    gs_gaussians g = {N, C, means, scales, quats, opac, feat};
    float *img = calloc((size_t)C * W * H, sizeof(float));
    float *alpha = calloc((size_t)W * H, sizeof(float));
    gs_raster *r = gs_raster_create();
    gs_error err;
    CHECK(img && alpha && r);
    CHECK(gs_raster_forward(r, NULL, &full, &g, NULL, NULL, img, alpha, NULL,
                            &err) == GS_OK);
    double plain = crop_diff(r, &full, img, 16, 16, 32, 16);
    CHECK(gs_raster_set_frustum(r, &full, &err) == GS_OK);
    double framed = crop_diff(r, &full, img, 16, 16, 32, 16);
    double whole = crop_diff(r, &full, img, 0, 0, W, H);
    CHECK(gs_raster_set_frustum(r, NULL, &err) == GS_OK);
    double again = crop_diff(r, &full, img, 16, 16, 32, 16);
    printf("crop vs image: own frustum %.3g, image's frustum %.3g (whole "
           "image %.3g), reset %.3g\n", plain, framed, whole, again);
    CHECK_MSG(framed >= 0 && framed <= 1e-5,
              "crop with the image's frustum differs by %.3g", framed);
    CHECK_MSG(whole == 0.0, "the image through set_frustum differs by %.3g",
              whole);
    CHECK_MSG(plain > 1e-3 && again == plain,
              "the scene does not exercise the clamp (%.3g, %.3g)", plain,
              again);
    gs_camera bad = full;
    bad.width = 0;
    CHECK(gs_raster_set_frustum(r, &bad, &err) == GS_ERR_ARG);
    bad = full;
    bad.cx = NAN;
    CHECK(gs_raster_set_frustum(r, &bad, &err) == GS_ERR_ARG);
    CHECK(gs_raster_set_frustum(NULL, &full, &err) == GS_ERR_ARG);
    gs_raster_destroy(r);
    free(img);
    free(alpha);
    GS_TEST_END();
}
