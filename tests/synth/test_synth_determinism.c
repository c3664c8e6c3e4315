/* Determinism: the same scene (or generator index) gives byte-identical
 * images, masks and labels whatever the thread count, and again after
 * other renders. */
#include <string.h>

#include "gs_test.h"
#include "synth_test_util.h"

enum { SIZE = 56 };

static uint64_t fnv1a(const uint8_t *p, size_t n, uint64_t h)
{
    for (size_t i = 0; i < n; i++) {
        h ^= p[i];
        h *= 0x100000001b3ULL;
    }
    return h;
}

/* Hash of pixels, masks and the numeric labels. */
static uint64_t sample_hash(const gs_synth_sample *s)
{
    uint64_t h = 0xcbf29ce484222325ULL;
    for (int y = 0; y < s->height; y++)
        h = fnv1a(s->rgb + (size_t)y * s->stride, 3 * (size_t)s->width, h);
    h = fnv1a(s->mask, GS_SYNTH_MASK_COUNT * (size_t)s->width * s->height, h);
    const gs_synth_labels *l = &s->labels;
    h = fnv1a((const uint8_t *)l->lm2d, sizeof l->lm2d, h);
    h = fnv1a((const uint8_t *)l->lm3d, sizeof l->lm3d, h);
    h = fnv1a((const uint8_t *)l->pupil_uv, sizeof l->pupil_uv, h);
    h = fnv1a((const uint8_t *)&l->gaze_norm_pitch, sizeof(double), h);
    return h;
}

/* A region render writes exactly the whole render's bytes in the 16 x 16
 * tiles meeting the region and leaves every other byte alone; bad regions
 * are refused. */
static void region_checks(gs_pool **pools)
{
    enum { W = 70, H = 52 };
    gs_synth_scene sc;
    gs_synth_scene_default(&sc, 600);
    sc.gaze_yaw = 0.3;
    gs_synth_camera cam;
    gs_synth_camera_single(W, 600, 200, &cam);
    cam.height = H;
    cam.K[5] = H / 2.0;
    gs_synth_sample whole, part;
    CHECK(gs_synth_sample_alloc(&whole, W, H, NULL) == GS_OK);
    CHECK(gs_synth_sample_alloc(&part, W, H, NULL) == GS_OK);
    gs_synth_render_opts o = {.supersample = 1};
    CHECK(gs_synth_render(&sc, &cam, &o, NULL, &whole, NULL) == GS_OK);
    /* [20, 37) x [17, 49): tiles x 16..48, y 16..52 (the last partial) */
    const int reg[4] = {20, 17, 37, 49};
    memcpy(o.region, reg, sizeof reg);
    for (int t = 0; t < 4; t++) {
        memset(part.rgb, 7, 3 * (size_t)W * H);
        memset(part.mask, 9, GS_SYNTH_MASK_COUNT * (size_t)W * H);
        CHECK(gs_synth_render(&sc, &cam, &o, pools[t], &part, NULL) == GS_OK);
        int bad = 0, inside = 0;
        for (int y = 0; y < H; y++)
            for (int x = 0; x < W; x++) {
                int in = x >= 16 && x < 48 && y >= 16;
                inside += in;
                for (int ch = 0; ch < 3; ch++) {
                    uint8_t v = part.rgb[(size_t)y * part.stride + 3 * x + ch];
                    uint8_t w = whole.rgb[(size_t)y * whole.stride + 3 * x + ch];
                    bad += in ? v != w : v != 7;
                }
                for (int m = 0; m < GS_SYNTH_MASK_COUNT; m++) {
                    size_t i = (size_t)m * W * H + (size_t)y * W + x;
                    bad += in ? part.mask[i] != whole.mask[i]
                              : part.mask[i] != 9;
                }
            }
        CHECK_MSG(bad == 0 && inside == 32 * 36,
                  "region render, %d threads: %d bytes differ", t + 1, bad);
        CHECK(memcmp(part.labels.lm2d, whole.labels.lm2d,
                     sizeof part.labels.lm2d) == 0 &&
              part.labels.gaze_norm_yaw == whole.labels.gaze_norm_yaw);
    }
    static const int badreg[][4] = {
        {-1, 0, 5, 5}, {0, 0, W + 1, 5}, {5, 0, 5, 5}, {0, 9, 4, 3},
        {0, 0, 4, H + 1}};
    for (size_t k = 0; k < sizeof badreg / sizeof badreg[0]; k++) {
        gs_error err = {0, ""};
        memcpy(o.region, badreg[k], sizeof o.region);
        CHECK(gs_synth_render(&sc, &cam, &o, NULL, &part, &err) ==
              GS_ERR_ARG);
        CHECK(strstr(err.msg, "region") != NULL);
    }
    gs_synth_sample_free(&whole);
    gs_synth_sample_free(&part);
}

int main(void)
{
    gs_synth_sample s;
    CHECK(gs_synth_sample_alloc(&s, SIZE, SIZE, NULL) == GS_OK);
    gs_pool *pools[4];
    for (int t = 0; t < 4; t++) {
        pools[t] = gs_pool_create(t + 1);
        CHECK(pools[t] != NULL);
    }
    for (int rig = 0; rig < 3; rig++)
        for (int ss = 1; ss <= 2; ss++) {
            gs_synth_gen_config c;
            gs_synth_gen_config_default(&c);
            c.size = SIZE;
            c.rig = (gs_synth_rig)rig;
            c.supersample = ss;
            c.split = GS_SYNTH_TEST;
            uint64_t index = 3 + (uint64_t)rig * 5;
            CHECK(gs_synth_gen_sample(&c, index, NULL, &s, NULL) == GS_OK);
            uint64_t ref = sample_hash(&s);
            for (int t = 0; t < 4; t++) {
                memset(s.rgb, 0, 3 * (size_t)SIZE * SIZE);
                CHECK(gs_synth_gen_sample(&c, index, pools[t], &s, NULL) == GS_OK);
                CHECK_MSG(sample_hash(&s) == ref,
                          "rig %d, supersample %d: %d threads differ from inline",
                          rig, ss, t + 1);
            }
            /* Another sample in between, then the same one again. */
            CHECK(gs_synth_gen_sample(&c, index + 1, pools[1], &s, NULL) == GS_OK);
            CHECK(sample_hash(&s) != ref);
            CHECK(gs_synth_gen_sample(&c, index, pools[2], &s, NULL) == GS_OK);
            CHECK_MSG(sample_hash(&s) == ref, "rig %d: not reproducible", rig);
        }
    /* Odd, non-square images (partial tiles) with any thread count. */
    gs_synth_sample odd;
    CHECK(gs_synth_sample_alloc(&odd, 37, 23, NULL) == GS_OK);
    gs_synth_scene sc;
    gs_synth_scene_default(&sc, 600);
    gs_synth_camera cam;
    gs_synth_camera_single(37, 600, 260, &cam);
    cam.height = 23;
    cam.K[5] = 11.5;
    gs_synth_render_opts o2 = {.supersample = 2};
    CHECK(gs_synth_render(&sc, &cam, &o2, NULL, &odd, NULL) == GS_OK);
    uint64_t ref = sample_hash(&odd);
    for (int t = 0; t < 4; t++) {
        CHECK(gs_synth_render(&sc, &cam, &o2, pools[t], &odd, NULL) == GS_OK);
        CHECK_MSG(sample_hash(&odd) == ref, "37x23: %d threads differ", t + 1);
    }
    gs_synth_sample_free(&odd);
    region_checks(pools);
    /* The dome's 18 views of a frame share one scene. */
    gs_synth_gen_config c;
    gs_synth_gen_config_default(&c);
    c.rig = GS_SYNTH_RIG_ETHX;
    gs_synth_scene s0, s1;
    gs_synth_camera c0, c1;
    CHECK(gs_synth_gen_scene(&c, 18, &s0, &c0, NULL) == GS_OK);
    for (uint64_t i = 19; i < 36; i++) {
        CHECK(gs_synth_gen_scene(&c, i, &s1, &c1, NULL) == GS_OK);
        CHECK(s1.identity.seed == s0.identity.seed && s1.gaze_yaw == s0.gaze_yaw &&
              memcmp(s1.head_R, s0.head_R, sizeof s0.head_R) == 0 &&
              memcmp(c1.R, c0.R, sizeof c0.R) != 0);
    }
    CHECK(gs_synth_gen_scene(&c, 36, &s1, &c1, NULL) == GS_OK);
    CHECK(s1.gaze_yaw != s0.gaze_yaw);
    for (int t = 0; t < 4; t++)
        gs_pool_destroy(pools[t]);
    gs_synth_sample_free(&s);
    GS_TEST_END();
}
