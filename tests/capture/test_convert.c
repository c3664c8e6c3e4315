/* YUYV <-> RGB (BT.601 limited range): reference values, round trips, the
 * MJPEG marker check. */
#include <stdlib.h>
#include <string.h>

#include "gazesplat/capture.h"
#include "gs_test.h"

static void test_reference_values(void)
{
    /* RGB -> Y Cb Cr by the BT.601 studio-swing equations. */
    static const uint8_t rgb[4][3] = {{255, 255, 255}, {0, 0, 0}, {255, 0, 0}, {0, 0, 255}};
    static const uint8_t yuv[4][3] = {{235, 128, 128}, {16, 128, 128}, {81, 90, 240},
                                      {41, 240, 110}};
    for (int i = 0; i < 4; i++) {
        uint8_t pair[6], out[4];
        memcpy(pair, rgb[i], 3);
        memcpy(pair + 3, rgb[i], 3);
        gs_cap_rgb_to_yuyv(pair, 6, 2, 1, out, 4);
        CHECK_MSG(out[0] == yuv[i][0] && out[2] == yuv[i][0] && out[1] == yuv[i][1] &&
                      out[3] == yuv[i][2],
                  "rgb %d,%d,%d -> Y %d Cb %d Cr %d, want %d %d %d", rgb[i][0], rgb[i][1],
                  rgb[i][2], out[0], out[1], out[3], yuv[i][0], yuv[i][1], yuv[i][2]);
        uint8_t back[6], in[4] = {yuv[i][0], yuv[i][1], yuv[i][0], yuv[i][2]};
        gs_cap_yuyv_to_rgb(in, 4, 2, 1, back, 6);
        for (int c = 0; c < 3; c++)
            CHECK_MSG(abs(back[c] - rgb[i][c]) <= 1 && back[c] == back[3 + c],
                      "Y %d Cb %d Cr %d -> channel %d = %d, want %d", in[0], in[1], in[3], c,
                      back[c], rgb[i][c]);
    }
    /* Below black and above white clamp. */
    uint8_t in[4] = {0, 128, 255, 128}, out[6];
    gs_cap_yuyv_to_rgb(in, 4, 2, 1, out, 6);
    CHECK(out[0] == 0 && out[3] == 255);
}

/* RGB with equal pixels in each pair survives RGB -> YUYV -> RGB within
 * the 8-bit quantization of Y'CbCr (limited range has 219 levels). */
static void test_round_trip(void)
{
    enum { W = 64, H = 32 };
    uint8_t rgb[W * H * 3], yuyv[W * H * 2], back[W * H * 3], again[W * H * 2];
    srand(7);
    for (int p = 0; p < W * H; p += 2)
        for (int c = 0; c < 3; c++)
            rgb[3 * p + c] = rgb[3 * p + 3 + c] = (uint8_t)(rand() & 255);
    gs_cap_rgb_to_yuyv(rgb, 3 * W, W, H, yuyv, 2 * W);
    gs_cap_yuyv_to_rgb(yuyv, 2 * W, W, H, back, 3 * W);
    int worst = 0, worst_i = 0;
    for (int i = 0; i < W * H * 3; i++)
        if (abs(back[i] - rgb[i]) > worst)
            worst = abs(back[i] - rgb[i]), worst_i = i;
    CHECK_MSG(worst <= 3, "RGB round trip differs by %d at %d (%d vs %d)", worst, worst_i,
              back[worst_i], rgb[worst_i]);
    /* YUYV that came from RGB comes back to the same YUYV within 1. */
    gs_cap_rgb_to_yuyv(back, 3 * W, W, H, again, 2 * W);
    worst = 0;
    for (int i = 0; i < W * H * 2; i++)
        if (abs(again[i] - yuyv[i]) > worst)
            worst = abs(again[i] - yuyv[i]), worst_i = i;
    CHECK_MSG(worst <= 1, "YUYV round trip differs by %d at %d", worst, worst_i);
    /* Strides larger than the row are honoured. */
    uint8_t wide[2][16] = {{0}}, rgbw[2][12];
    memset(wide, 128, sizeof wide);
    gs_cap_yuyv_to_rgb(&wide[0][0], 16, 2, 2, &rgbw[0][0], 12);
    CHECK(rgbw[1][0] == rgbw[0][0]);
}

static void test_mjpeg_markers(void)
{
    static const uint8_t ok[] = {0xFF, 0xD8, 1, 2, 3, 0xFF, 0xD9};
    static const uint8_t padded[] = {0xFF, 0xD8, 1, 2, 3, 0xFF, 0xD9, 0, 0, 0};
    static const uint8_t no_soi[] = {0xFF, 0xD9, 1, 2, 3, 0xFF, 0xD9};
    static const uint8_t cut[] = {0xFF, 0xD8, 1, 2, 3, 0xFF};
    CHECK(gs_cap_mjpeg_complete(ok, sizeof ok));
    CHECK(gs_cap_mjpeg_complete(padded, sizeof padded));
    CHECK(!gs_cap_mjpeg_complete(no_soi, sizeof no_soi));
    CHECK(!gs_cap_mjpeg_complete(cut, sizeof cut));
    CHECK(!gs_cap_mjpeg_complete(ok, 3));
}

int main(void)
{
    test_reference_values();
    test_round_trip();
    test_mjpeg_markers();
    GS_TEST_END();
}
