/* Metric maths on known images: PSNR of a known offset, SSIM of identical
 * images, masks and regions. */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "gazesplat/eval.h"
#include "gs_test.h"

#define W 40
#define H 30

static void fill_pattern(uint8_t *img, size_t stride, int seed)
{
    for (int y = 0; y < H; y++)
        for (int x = 0; x < W; x++)
            for (int c = 0; c < 3; c++)
                img[(size_t)y * stride + 3 * x + c] =
                    (uint8_t)(40 + (x * 7 + y * 13 + c * 29 + seed) % 170);
}

int main(void)
{
    size_t sa = 3 * W, sb = 3 * W + 5; /* different strides on purpose */
    uint8_t *a = calloc(sa * H, 1), *b = calloc(sb * H, 1);
    uint8_t mask[W * H];
    gs_error err = {0, ""};
    fill_pattern(a, sa, 0);
    fill_pattern(b, sb, 0);

    /* Identical: PSNR capped at 100 dB, SSIM exactly 1. */
    CHECK_CLOSE(gs_eval_psnr(a, sa, b, sb, W, H, NULL), 100, 0, 0);
    CHECK_CLOSE(gs_eval_ssim(a, sa, b, sb, W, H, NULL, &err), 1.0, 1e-12, 0);

    /* A constant offset of 10: MSE 100, PSNR 20 log10(255 / 10). */
    for (int y = 0; y < H; y++)
        for (int x = 0; x < 3 * W; x++)
            b[(size_t)y * sb + x] = (uint8_t)(a[(size_t)y * sa + x] + 10);
    CHECK_CLOSE(gs_eval_psnr(a, sa, b, sb, W, H, NULL),
                20 * log10(255.0 / 10.0), 1e-9, 0);
    double s_off = gs_eval_ssim(a, sa, b, sb, W, H, NULL, &err);
    CHECK(s_off < 1 && s_off > 0.9); /* structure kept, luminance shifted */

    /* Masks: only the masked pixels count. Left half identical, right half
     * off by 20. */
    memset(mask, 0, sizeof mask);
    for (int y = 0; y < H; y++)
        for (int x = 0; x < W; x++) {
            for (int c = 0; c < 3; c++)
                b[(size_t)y * sb + 3 * x + c] =
                    (uint8_t)(a[(size_t)y * sa + 3 * x + c] + (x < W / 2 ? 0 : 20));
            mask[y * W + x] = x >= W / 2 ? 255 : 0;
        }
    CHECK_CLOSE(gs_eval_psnr(a, sa, b, sb, W, H, mask),
                20 * log10(255.0 / 20.0), 1e-9, 0);
    CHECK_CLOSE(gs_eval_psnr(a, sa, b, sb, W, H, NULL),
                10 * log10(255.0 * 255.0 / 200.0), 1e-9, 0);
    for (int i = 0; i < W * H; i++)
        mask[i] = mask[i] ? 0 : 255;
    CHECK_CLOSE(gs_eval_psnr(a, sa, b, sb, W, H, mask), 100, 0, 0);
    /* SSIM far from the seam (windows see only identical pixels) is 1. */
    memset(mask, 0, sizeof mask);
    for (int y = 0; y < H; y++)
        for (int x = 0; x < W / 2 - 6; x++)
            mask[y * W + x] = 255;
    CHECK_CLOSE(gs_eval_ssim(a, sa, b, sb, W, H, mask, &err), 1.0, 1e-9, 0);
    /* An empty mask has no value. */
    memset(mask, 0, sizeof mask);
    CHECK(isnan(gs_eval_psnr(a, sa, b, sb, W, H, mask)));
    CHECK(isnan(gs_eval_ssim(a, sa, b, sb, W, H, mask, &err)));

    /* Noise lowers SSIM: a pattern against an unrelated one. */
    fill_pattern(b, sb, 77);
    for (int y = 0; y < H; y++)
        for (int x = 0; x < 3 * W; x++)
            b[(size_t)y * sb + x] = (uint8_t)((b[(size_t)y * sb + x] * 37 + y) % 251);
    CHECK(gs_eval_ssim(a, sa, b, sb, W, H, NULL, &err) < 0.5);

    /* Dilation by r grows a single pixel into a (2r+1)^2 square. */
    uint8_t d[W * H];
    memset(mask, 0, sizeof mask);
    mask[10 * W + 20] = 255;
    CHECK(gs_eval_mask_dilate(mask, W, H, 2, d) == GS_OK);
    CHECK_EQ_INT(gs_eval_mask_count(d, W, H), 25);
    CHECK(d[8 * W + 18] && d[12 * W + 22] && !d[7 * W + 20] && !d[10 * W + 23]);
    mask[0] = 255; /* clipped at the corner: 3 x 3 */
    gs_eval_mask_dilate(mask, W, H, 2, d);
    CHECK_EQ_INT(gs_eval_mask_count(d, W, H), 25 + 9);

    /* Regions of a synthetic head: eyes and face-without-eyes disjoint,
     * the eye region covers both eyeballs. */
    gs_synth_scene sc;
    gs_synth_scene_default(&sc, 650);
    gs_synth_sample smp;
    CHECK_MSG(gs_eval_render_scene(&sc, 96, 680, 300, NULL, &smp, &err) ==
              GS_OK, "%s", err.msg);
    uint8_t eye[96 * 96], face[96 * 96];
    CHECK(gs_eval_regions(&smp, eye, face) == GS_OK);
    const uint8_t *le = gs_synth_sample_mask(&smp, GS_SYNTH_MASK_LEFT_EYE);
    const uint8_t *re = gs_synth_sample_mask(&smp, GS_SYNTH_MASK_RIGHT_EYE);
    const uint8_t *head = gs_synth_sample_mask(&smp, GS_SYNTH_MASK_HEAD);
    int overlap = 0, covered = 1, eyes = 0, white = 1;
    for (int i = 0; i < 96 * 96; i++) {
        overlap += eye[i] && face[i];
        covered &= !(le[i] || re[i]) || eye[i];
        eyes += le[i] != 0 || re[i] != 0;
        if (!head[i])
            white &= smp.rgb[3 * i] == 255 && smp.rgb[3 * i + 1] == 255 &&
                     smp.rgb[3 * i + 2] == 255;
    }
    CHECK(overlap == 0 && covered && eyes > 10 && white);
    CHECK(gs_eval_mask_count(eye, 96, 96) > (size_t)eyes);
    CHECK(gs_eval_mask_count(face, 96, 96) > 500);
    gs_synth_sample_free(&smp);
    free(a);
    free(b);
    GS_TEST_END();
}
