/* The safetensors code against an independent implementation of the spec
 * in Python (json + struct + numpy): the file we write parses there with
 * the right values and exactly the header bytes the Python library would
 * write; files written there (unsorted, misaligned, escaped names) read
 * back right here, and the damaged ones are refused.
 * usage: test_safetensors_py PYTHON SCRIPT */
#define _POSIX_C_SOURCE 200809L /* mkdtemp */

#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "gazesplat/safetensors.h"
#include "gs_test.h"

static char dir[] = "st_py_XXXXXX";

/* Same values as c_expected() in safetensors_py.py. */
static void write_c_file(void)
{
    float w[12], bias[3] = {1e-30f, -3.5f, 1e30f}, none = 0;
    uint16_t half[4] = {0x3C00, 0xB800, 0x7BFF, 0x0000}; /* 1, -0.5, 65504, 0 */
    int64_t ids[3] = {-7, 0, (int64_t)1 << 40};
    int32_t step = 12345;
    uint8_t mask[6] = {0, 255, 3, 4, 5, 6}, nine = 9;
    int64_t s34[2] = {3, 4}, s3[1] = {3}, s4[1] = {4}, s23[2] = {2, 3}, s07[2] = {0, 7}, s1[1] = {1};
    char path[256];
    gs_error err = {0, ""};
    for (int i = 0; i < 12; i++)
        w[i] = (float)i * 0.5f - 2.0f;
    gs_st_writer *wr = gs_st_writer_create();
    CHECK_EQ_INT(gs_st_writer_add(wr, "layer.0.weight", GS_ST_F32, 2, s34, w), GS_OK);
    CHECK_EQ_INT(gs_st_writer_add(wr, "layer.0.bias", GS_ST_F32, 1, s3, bias), GS_OK);
    CHECK_EQ_INT(gs_st_writer_add(wr, "half", GS_ST_F16, 1, s4, half), GS_OK);
    CHECK_EQ_INT(gs_st_writer_add(wr, "ids", GS_ST_I64, 1, s3, ids), GS_OK);
    CHECK_EQ_INT(gs_st_writer_add(wr, "step", GS_ST_I32, 0, NULL, &step), GS_OK);
    CHECK_EQ_INT(gs_st_writer_add(wr, "mask", GS_ST_U8, 2, s23, mask), GS_OK);
    CHECK_EQ_INT(gs_st_writer_add(wr, "none", GS_ST_F32, 2, s07, &none), GS_OK);
    CHECK_EQ_INT(gs_st_writer_add(wr, "caf\xc3\xa9 \"q\"\n", GS_ST_U8, 1, s1, &nine), GS_OK);
    CHECK_EQ_INT(gs_st_writer_meta(wr, "format", "gazesplat"), GS_OK);
    CHECK_EQ_INT(gs_st_writer_meta(wr, "version", "1"), GS_OK);
    CHECK_EQ_INT(gs_st_writer_meta(wr, "config", "{\"size\": [64, 64]}\xc3\xa9\t"), GS_OK);
    snprintf(path, sizeof path, "%s/c_model.safetensors", dir);
    CHECK_MSG(gs_st_writer_save(wr, path, &err) == GS_OK, "save: %s", err.msg);
    gs_st_writer_destroy(wr);
}

static const gs_st_tensor *expect_tensor(const gs_st_file *f, const char *name, gs_st_dtype dt,
                                         int ndim, const int64_t *shape)
{
    const gs_st_tensor *t = gs_st_find(f, name);
    CHECK_MSG(t != NULL, "py_model: no tensor '%s'", name);
    if (!t)
        return NULL;
    int same = t->dtype == dt && t->ndim == ndim;
    for (int i = 0; same && i < ndim; i++)
        same = t->shape[i] == shape[i];
    CHECK_MSG(same, "py_model '%s': dtype %s ndim %d", name, gs_st_dtype_name(t->dtype), t->ndim);
    CHECK_MSG(((uintptr_t)t->data & 7) == 0, "'%s' not 8-byte aligned", name);
    return same ? t : NULL;
}

/* Same values as py_model() in safetensors_py.py. */
static void check_py_model(void)
{
    char path[256];
    gs_st_file *f = NULL;
    gs_error err = {0, ""};
    snprintf(path, sizeof path, "%s/py_model.safetensors", dir);
    int rc = gs_st_open(path, NULL, &f, &err);
    CHECK_MSG(rc == GS_OK, "py_model: rc %d (%s)", rc, err.msg);
    if (rc)
        return;
    int64_t s3[1] = {3}, s23[2] = {2, 3}, s4[1] = {4}, s1[1] = {1}, s03[2] = {0, 3};
    const gs_st_tensor *t;
    CHECK_EQ_INT(gs_st_count(f), 7);
    if ((t = expect_tensor(f, "u8", GS_ST_U8, 1, s3)))
        CHECK(memcmp(t->data, "\1\2\3", 3) == 0);
    const float *w = NULL;
    CHECK_MSG(gs_st_get_f32(f, "weight", 2, s23, &w, &err) == GS_OK, "%s", err.msg);
    for (int i = 0; w && i < 6; i++)
        CHECK_CLOSE(w[i], (float)i * 0.25f - 1.0f, 0, 0);
    if ((t = expect_tensor(f, "idx", GS_ST_I64, 1, s4))) {
        const int64_t *v = t->data;
        CHECK(v[0] == -5 && v[1] == 0 && v[2] == 7 && v[3] == (int64_t)1 << 40);
    }
    if ((t = expect_tensor(f, "half", GS_ST_F16, 1, s3))) {
        const uint16_t *h = t->data;
        CHECK_MSG(h[0] == 0x3C00 && h[1] == 0xB800 && h[2] == 0x7BFF, "half %04x %04x %04x", h[0],
                  h[1], h[2]);
    }
    if ((t = expect_tensor(f, "count", GS_ST_I32, 0, NULL)))
        CHECK_EQ_INT(*(const int32_t *)t->data, 42);
    CHECK_MSG(gs_st_get_f32(f, "caf\xc3\xa9 \xf0\x9f\x98\x80", 1, s1, &w, &err) == GS_OK, "%s",
              err.msg);
    CHECK(w && w[0] == 3.5f);
    if ((t = expect_tensor(f, "empty", GS_ST_F32, 2, s03)))
        CHECK_EQ_INT(t->nbytes, 0);
    const char *v = gs_st_meta(f, "note");
    CHECK_MSG(v && strcmp(v, "\xc3\xa9\n") == 0, "note = %s", v ? v : "(null)");
    v = gs_st_meta(f, "format");
    CHECK(v && strcmp(v, "py") == 0);
    gs_st_close(f);
}

static void check_refused(const char *name, int code, const char *want)
{
    char path[256];
    gs_st_file *f = NULL;
    gs_error err = {0, ""};
    snprintf(path, sizeof path, "%s/%s.safetensors", dir, name);
    int rc = gs_st_open(path, NULL, &f, &err);
    CHECK_MSG(rc == code && strstr(err.msg, want), "%s: rc %d (%s), want %d '%s'", name, rc,
              err.msg, code, want);
    if (rc == GS_OK)
        gs_st_close(f);
    else
        printf("%s refused: %s\n", name, err.msg);
}

int main(int argc, char **argv)
{
    char cmd[1024];
    if (argc != 3) {
        fprintf(stderr, "usage: %s PYTHON SCRIPT\n", argv[0]);
        return 2;
    }
    if (!mkdtemp(dir)) {
        perror("mkdtemp");
        return 1;
    }
    write_c_file();
    snprintf(cmd, sizeof cmd, "'%s' '%s' '%s'", argv[1], argv[2], dir);
    CHECK_MSG(system(cmd) == 0, "%s failed", cmd);
    check_py_model();
    check_refused("py_nan", GS_ERR_NONFINITE, "element 1");
    check_refused("py_f64", GS_ERR_UNSUPPORTED, "F64");
    check_refused("py_hole", GS_ERR_FORMAT, "hole");
    check_refused("py_overlap", GS_ERR_FORMAT, "overlaps");
    check_refused("py_float_shape", GS_ERR_FORMAT, "not an integer");
    snprintf(cmd, sizeof cmd, "rm -rf '%s'", dir);
    if (system(cmd) != 0)
        fprintf(stderr, "could not remove %s\n", dir);
    GS_TEST_END();
}
