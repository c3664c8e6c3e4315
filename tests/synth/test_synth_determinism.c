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
    for (int t = 0; t < 4; t++)
        gs_pool_destroy(pools[t]);
    gs_synth_sample_free(&s);
    GS_TEST_END();
}
