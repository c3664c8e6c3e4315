/* Model files: save -> load round trip (every tensor, the configuration),
 * and refusal of truncated, corrupt and inconsistent files. */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "gazesplat/safetensors.h"
#include "gs_test.h"
#include "model_test_util.h"

static char path[256];

static char *find(uint8_t *buf, size_t len, const char *needle)
{
    size_t n = strlen(needle);
    for (size_t i = 0; i + n <= len; i++)
        if (memcmp(buf + i, needle, n) == 0)
            return (char *)buf + i;
    return NULL;
}

static int load_bytes(const uint8_t *buf, size_t len, int *code)
{
    char p2[300];
    snprintf(p2, sizeof p2, "%s.bad", path);
    FILE *f = fopen(p2, "wb");
    fwrite(buf, 1, len, f);
    fclose(f);
    gs_model *m = NULL;
    gs_error err = {0, ""};
    *code = gs_model_load(p2, &m, &err);
    if (*code == GS_OK)
        gs_model_destroy(m);
    else if (!err.msg[0])
        return 0; /* every refusal must say why */
    unlink(p2);
    return 1;
}

int main(void)
{
    snprintf(path, sizeof path, "test_model_file_%d.safetensors", (int)getpid());
    gs_model *m = tiny_model(2, 3);
    CHECK(m != NULL);
    gs_error err = {0, ""};
    CHECK(gs_model_save(m, path, &err) == GS_OK);
    gs_model *l = NULL;
    CHECK_MSG(gs_model_load(path, &l, &err) == GS_OK, "%s", err.msg);
    CHECK(l->nparams == m->nparams);
    CHECK(memcmp(&l->cfg, &m->cfg, sizeof m->cfg) == 0);
    int same = 1;
    for (int i = 0; i < m->ntensors; i++)
        same &= memcmp(l->params + m->t[i].offset, m->params + m->t[i].offset,
                       m->t[i].count * sizeof(float)) == 0;
    CHECK_MSG(same, "a tensor differs after the round trip");
    gs_model_destroy(l);

    FILE *f = fopen(path, "rb");
    fseek(f, 0, SEEK_END);
    size_t len = (size_t)ftell(f);
    fseek(f, 0, SEEK_SET);
    uint8_t *buf = malloc(len);
    CHECK(fread(buf, 1, len, f) == len);
    fclose(f);
    int code;
    /* truncations */
    size_t cuts[] = {0, 7, 8, 100, len / 2, len - 1};
    for (size_t i = 0; i < sizeof cuts / sizeof cuts[0]; i++) {
        CHECK(load_bytes(buf, cuts[i], &code));
        CHECK_MSG(code == GS_ERR_FORMAT || code == GS_ERR_IO,
                  "cut at %zu: code %d", cuts[i], code);
    }
    /* a flipped byte in the header's config */
    uint8_t *bad = malloc(len);
    memcpy(bad, buf, len);
    char *hit = find(bad, len, "\"config.hidden\":\"16\"");
    CHECK(hit != NULL);
    if (hit) {
        hit[18] = '9'; /* hidden 96: shapes no longer match */
        CHECK(load_bytes(bad, len, &code));
        CHECK_MSG(code == GS_ERR_FORMAT, "bad config: code %d", code);
    }
    memcpy(bad, buf, len);
    hit = find(bad, len, "gazesplat-model");
    CHECK(hit != NULL);
    if (hit) {
        hit[0] = 'G';
        CHECK(load_bytes(bad, len, &code));
        CHECK_MSG(code == GS_ERR_FORMAT, "bad format name: code %d", code);
    }
    /* a NaN parameter */
    memcpy(bad, buf, len);
    uint32_t nan = 0x7fc00000u;
    memcpy(bad + len - 4, &nan, 4);
    CHECK(load_bytes(bad, len, &code));
    CHECK_MSG(code == GS_ERR_NONFINITE, "NaN tensor: code %d", code);
    /* a missing tensor: rewrite without one */
    gs_st_file *sf = NULL;
    CHECK(gs_st_open(path, NULL, &sf, &err) == GS_OK);
    gs_st_writer *w = gs_st_writer_create();
    for (int i = 0; i < gs_st_meta_count(sf); i++) {
        const char *k, *v;
        gs_st_meta_at(sf, i, &k, &v);
        gs_st_writer_meta(w, k, v);
    }
    for (int i = 0; i < gs_st_count(sf); i++) {
        const gs_st_tensor *t = gs_st_at(sf, i);
        if (strcmp(t->name, "eye.centre") == 0)
            continue;
        gs_st_writer_add(w, t->name, t->dtype, t->ndim, t->shape, t->data);
    }
    uint8_t *mb = NULL;
    size_t ml = 0;
    CHECK(gs_st_writer_to_mem(w, &mb, &ml, &err) == GS_OK);
    CHECK(load_bytes(mb, ml, &code));
    CHECK_MSG(code == GS_ERR_FORMAT, "missing tensor: code %d", code);
    free(mb);
    gs_st_writer_destroy(w);
    gs_st_close(sf);
    free(bad);
    free(buf);
    unlink(path);
    gs_model_destroy(m);
    GS_TEST_END();
}
