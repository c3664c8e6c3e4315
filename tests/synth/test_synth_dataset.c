/* The dataset writer in-process: images and masks read back through the
 * PNG decoder equal fresh renders of the same generator indices, one
 * labels line per image in index order, progress reported, bad
 * configurations refused. */
#define _POSIX_C_SOURCE 200809L
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "gazesplat/image_io.h"
#include "gs_test.h"
#include "synth_test_util.h"

static int calls;
static void progress(void *ctx, uint64_t done, uint64_t total)
{
    (void)ctx;
    calls++;
    CHECK(done >= 1 && done <= total);
}

int main(void)
{
    char dir[] = "/tmp/gs_synth_dataset_XXXXXX";
    CHECK(mkdtemp(dir) != NULL);
    gs_synth_gen_config c;
    gs_synth_gen_config_default(&c);
    c.size = 40;
    c.split = GS_SYNTH_TEST;
    gs_synth_dataset_opts o = {5, 3, 1, progress, NULL};
    gs_error err;
    CHECK_MSG(gs_synth_dataset_write(dir, &c, &o, NULL, &err) == GS_OK, "%s", err.msg);
    CHECK_EQ_INT(calls, 3);
    gs_synth_sample s;
    CHECK(gs_synth_sample_alloc(&s, 40, 40, NULL) == GS_OK);
    for (uint64_t i = 5; i < 8; i++) {
        char path[256];
        gs_io_image img, mask;
        snprintf(path, sizeof path, "%s/images/%08llu.png", dir, (unsigned long long)i);
        CHECK_MSG(gs_io_image_read(path, NULL, &img, &err) == GS_OK, "%s", err.msg);
        snprintf(path, sizeof path, "%s/masks/%08llu.png", dir, (unsigned long long)i);
        CHECK_MSG(gs_io_image_read(path, NULL, &mask, &err) == GS_OK, "%s", err.msg);
        CHECK(gs_synth_gen_sample(&c, i, NULL, &s, NULL) == GS_OK);
        int bad = 0, bad_mask = 0;
        size_t plane = 40 * 40;
        for (int y = 0; y < 40; y++) {
            bad += memcmp(img.data + (size_t)y * img.stride, s.rgb + (size_t)y * s.stride, 120) != 0;
            for (int x = 0; x < 40; x++) {
                const unsigned char *m = mask.data + (size_t)y * mask.stride + 3 * (size_t)x;
                size_t k = (size_t)y * 40 + (size_t)x;
                int b = s.mask[k + 2 * plane] ? 255 : (s.mask[k + 3 * plane] ? 128 : 0);
                bad_mask += m[0] != s.mask[k] || m[1] != s.mask[k + plane] || m[2] != b;
            }
        }
        CHECK_MSG(bad == 0 && bad_mask == 0, "image %llu: %d rows, %d mask pixels differ",
                  (unsigned long long)i, bad, bad_mask);
        gs_io_image_free(&img);
        gs_io_image_free(&mask);
    }
    /* labels.jsonl: three lines, indices 5..7. */
    char path[256], line[1 << 16];
    snprintf(path, sizeof path, "%s/labels.jsonl", dir);
    FILE *f = fopen(path, "r");
    CHECK(f != NULL);
    int lines = 0;
    while (f && fgets(line, sizeof line, f)) {
        char want[64];
        snprintf(want, sizeof want, "\"index\":%d,", 5 + lines);
        CHECK_MSG(strstr(line, want) != NULL, "line %d lacks %s", lines, want);
        CHECK(strstr(line, "\"split\":\"test\"") != NULL);
        lines++;
    }
    if (f)
        fclose(f);
    CHECK_EQ_INT(lines, 3);
    /* Refusals. */
    c.identities = 0;
    CHECK_EQ_INT(gs_synth_dataset_write(dir, &c, &o, NULL, &err), GS_ERR_ARG);
    c.identities = 5;
    CHECK_EQ_INT(gs_synth_dataset_write("/proc/no/such/dir", &c, &o, NULL, &err), GS_ERR_IO);
    /* JSON of a label set: the snprintf-like contract. */
    char small[16];
    int need = gs_synth_labels_json(&s.labels, "x\"y.png", small, sizeof small);
    CHECK(need > 1000 && small[15] == '\0');
    char *big = malloc((size_t)need + 1);
    CHECK(gs_synth_labels_json(&s.labels, "x\"y.png", big, (size_t)need + 1) == need);
    CHECK(strncmp(big, "{\"image\":\"x\\\"y.png\"", 19) == 0 && big[need - 1] == '}');
    free(big);
    gs_synth_sample_free(&s);
    /* Clean up. */
    char cmd[300];
    snprintf(cmd, sizeof cmd, "rm -rf '%s'", dir);
    CHECK(system(cmd) == 0);
    GS_TEST_END();
}
