/* The warping baseline: the pupil moves by the displacement asked for on a
 * synthetic eye, the displacement has the right direction and size for a
 * gaze change, and on a rendered head the dark iris moves that way. */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "gazesplat/eval.h"
#include "gs_test.h"

#define W 40
#define H 30

/* Centroid of the pixels darker than thr inside the mask. */
static int dark_centroid(const uint8_t *img, size_t st, int w, int h,
                         const uint8_t *mask, int thr, double c[2])
{
    double sx = 0, sy = 0;
    int n = 0;
    for (int y = 0; y < h; y++)
        for (int x = 0; x < w; x++) {
            const uint8_t *p = img + (size_t)y * st + 3 * x;
            if ((mask && !mask[y * w + x]) || p[0] + p[1] + p[2] >= 3 * thr)
                continue;
            sx += x + 0.5;
            sy += y + 0.5;
            n++;
        }
    c[0] = n ? sx / n : NAN;
    c[1] = n ? sy / n : NAN;
    return n;
}

static void toy_eye(void)
{
    uint8_t src[3 * W * H], dst[3 * W * H], mask[W * H];
    memset(src, 90, sizeof src); /* skin */
    memset(mask, 0, sizeof mask);
    for (int y = 0; y < H; y++)
        for (int x = 0; x < W; x++) {
            double ex = (x + 0.5 - 20) / 14, ey = (y + 0.5 - 15) / 9;
            double px = x + 0.5 - 20, py = y + 0.5 - 15;
            if (ex * ex + ey * ey > 1)
                continue;
            mask[y * W + x] = 255;
            memset(src + 3 * (y * W + x), px * px + py * py <= 9 ? 10 : 240, 3);
        }
    memcpy(dst, src, sizeof dst);
    const double disp[2] = {4, -2};
    const uint8_t white[3] = {240, 240, 240};
    gs_error err = {0, ""};
    CHECK(gs_eval_warp_eye(src, 3 * W, dst, 3 * W, W, H, mask, disp, 3, white,
                           &err) == GS_OK);
    double c0[2], c1[2];
    int n0 = dark_centroid(src, 3 * W, W, H, NULL, 50, c0);
    int n1 = dark_centroid(dst, 3 * W, W, H, NULL, 50, c1);
    CHECK_EQ_INT(n1, n0);
    CHECK_CLOSE(c1[0] - c0[0], 4, 1e-9, 0);
    CHECK_CLOSE(c1[1] - c0[1], -2, 1e-9, 0);
    /* Outside the mask nothing changes; the border ring stays put. */
    int outside_same = 1;
    for (int i = 0; i < W * H; i++)
        if (!mask[i])
            outside_same &= memcmp(src + 3 * i, dst + 3 * i, 3) == 0;
    CHECK(outside_same);
    /* A fractional shift moves the centroid by about as much. */
    const double half[2] = {-2.5, 1.5};
    gs_eval_warp_eye(src, 3 * W, dst, 3 * W, W, H, mask, half, 3, white, &err);
    double c2[2];
    dark_centroid(dst, 3 * W, W, H, NULL, 50, c2);
    CHECK_CLOSE(c2[0] - c0[0], -2.5, 0.3, 0);
    CHECK_CLOSE(c2[1] - c0[1], 1.5, 0.3, 0);
    const double nan_d[2] = {NAN, 0};
    CHECK(gs_eval_warp_eye(src, 3 * W, dst, 3 * W, W, H, mask, nan_d, 3, white,
                           &err) == GS_ERR_NONFINITE);
    CHECK(gs_eval_warp_eye(src, 3 * W, dst, 3 * W, W, H, mask, disp, 0, white,
                           &err) == GS_ERR_ARG);
}

static void rendered_head(void)
{
    gs_synth_scene sc;
    gs_synth_scene_default(&sc, 650);
    sc.identity.p[GS_SYNTH_ID_IRIS_BRIGHTNESS] = -1; /* a dark iris */
    gs_synth_sample in;
    gs_error err = {0, ""};
    int S = 160;
    CHECK_MSG(gs_eval_render_scene(&sc, S, 680, 1600.0 * S / 512, NULL, &in,
                                   &err) == GS_OK, "%s", err.msg);
    const gs_synth_labels *l = &in.labels;
    /* Looking 20 deg toward image-left and 10 up from (0, 0): both pupils
     * move left and up by about f L sin(angle) / z. */
    double yaw = 20 * 3.14159265358979323846 / 180, pitch = 10 * 3.14159265358979323846 / 180;
    for (int e = 0; e < 2; e++) {
        double d[2];
        CHECK(gs_eval_pupil_shift(l, e, 0, yaw, d, &err) == GS_OK);
        double L = 0, z = l->eye_centre[e][2];
        for (int k = 0; k < 3; k++)
            L += pow(l->pupil_centre[e][k] - l->eye_centre[e][k], 2);
        double want = l->K[0] * sqrt(L) * sin(yaw) / z;
        CHECK_MSG(d[0] < 0 && fabs(fabs(d[0]) - want) < 0.15 * want &&
                      fabs(d[1]) < 0.2 * want,
                  "eye %d: shift %.2f,%.2f px, want about -%.2f,0", e, d[0],
                  d[1], want);
        CHECK(gs_eval_pupil_shift(l, e, pitch, 0, d, &err) == GS_OK);
        CHECK_MSG(d[1] < 0 && fabs(d[0]) < 0.3, "eye %d: up shift %.2f,%.2f",
                  e, d[0], d[1]);
    }
    /* The warped image: the dark (iris) pixels of each eye move left. */
    uint8_t *out = malloc(3 * (size_t)S * S);
    CHECK(gs_eval_warp_redirect(&in, 0, yaw, out, 3 * (size_t)S, &err) ==
          GS_OK);
    for (int e = 0; e < 2; e++) {
        const uint8_t *m = gs_synth_sample_mask(
            &in, e == 0 ? GS_SYNTH_MASK_RIGHT_EYE : GS_SYNTH_MASK_LEFT_EYE);
        double c0[2], c1[2], d[2];
        gs_eval_pupil_shift(l, e, 0, yaw, d, &err);
        int n0 = dark_centroid(in.rgb, in.stride, S, S, m, 100, c0);
        int n1 = dark_centroid(out, 3 * (size_t)S, S, S, m, 100, c1);
        CHECK_MSG(n0 > 5 && n1 > 5, "eye %d: %d / %d dark pixels", e, n0, n1);
        double dx = c1[0] - c0[0];
        CHECK_MSG(dx < 0 && fabs(dx - d[0]) < 0.5 * fabs(d[0]),
                  "eye %d: dark centroid moved %.2f px, pupil shift %.2f", e,
                  dx, d[0]);
    }
    /* Outside the eyes the output is the input. */
    const uint8_t *le = gs_synth_sample_mask(&in, GS_SYNTH_MASK_LEFT_EYE);
    const uint8_t *re = gs_synth_sample_mask(&in, GS_SYNTH_MASK_RIGHT_EYE);
    int same = 1;
    for (int i = 0; i < S * S; i++)
        if (!le[i] && !re[i])
            same &= memcmp(out + 3 * i, in.rgb + 3 * i, 3) == 0;
    CHECK(same);
    free(out);
    gs_synth_sample_free(&in);
}

int main(void)
{
    toy_eye();
    rendered_head();
    GS_TEST_END();
}
