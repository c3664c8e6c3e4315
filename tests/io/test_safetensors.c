/* safetensors: writer -> reader round trips (every dtype, scalars, empty
 * tensors, metadata), byte-exact re-saves, accepted oddities of other
 * writers, and one refused file per validation rule, each checked for its
 * code and message. Run under ASan, a leak on any error path fails. */
#define _POSIX_C_SOURCE 200809L /* mkdtemp */

#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "gazesplat/safetensors.h"
#include "gs_test.h"

/* ---- helpers ------------------------------------------------------------ */

/* u64le(strlen(json)) + json + data: a file image in a malloc'd buffer. */
static uint8_t *image_of(const char *json, const void *data, size_t dlen, size_t *len)
{
    size_t n = strlen(json);
    uint8_t *b = malloc(8 + n + dlen + 1);
    for (int i = 0; i < 8; i++)
        b[i] = (uint8_t)((uint64_t)n >> (8 * i));
    memcpy(b + 8, json, n);
    if (dlen)
        memcpy(b + 8 + n, data, dlen);
    *len = 8 + n + dlen;
    return b;
}

/* Opens the image and expects code with want in the message. */
static void expect_refused(const char *label, const uint8_t *buf, size_t len,
                           const gs_st_limits *lim, int code, const char *want)
{
    gs_st_file *f = NULL;
    gs_error err = {0, ""};
    int rc = gs_st_open_mem(buf, len, lim, &f, &err);
    CHECK_MSG(rc == code && err.code == rc && f == NULL, "%s: rc %d (%s), want %d", label, rc,
              err.msg, code);
    CHECK_MSG(strstr(err.msg, want) != NULL, "%s: message '%s' lacks '%s'", label, err.msg, want);
    if (rc == GS_OK)
        gs_st_close(f);
    else
        printf("%-24s %s\n", label, err.msg);
}

static void refused_json(const char *label, const char *json, size_t dlen, int code,
                         const char *want)
{
    uint8_t zeros[64] = {0};
    size_t len;
    uint8_t *b = image_of(json, zeros, dlen, &len);
    expect_refused(label, b, len, NULL, code, want);
    free(b);
}

static gs_st_file *open_ok(const char *label, const uint8_t *buf, size_t len)
{
    gs_st_file *f = NULL;
    gs_error err = {0, ""};
    int rc = gs_st_open_mem(buf, len, NULL, &f, &err);
    CHECK_MSG(rc == GS_OK && f, "%s: rc %d (%s)", label, rc, err.msg);
    return rc == GS_OK ? f : NULL;
}

/* ---- round trip --------------------------------------------------------- */

static float f32v[6] = {1.5f, -2.25f, 0.0f, 3.0e-38f, -1.0e30f, 7.0f};
static uint16_t f16v[4] = {0x3C00, 0xC000, 0x0001, 0x7BFF}; /* 1, -2, subnormal, max */
static int32_t i32v = -123456;
static int64_t i64v[3] = {INT64_MIN, 0, INT64_MAX};
static uint8_t u8v[5] = {0, 1, 127, 128, 255};

static gs_st_writer *sample_writer(void)
{
    gs_st_writer *w = gs_st_writer_create();
    int64_t s23[2] = {2, 3}, s4[1] = {4}, s3[1] = {3}, s5[1] = {5}, s0[1] = {0}, s203[3] = {2, 0, 3};
    CHECK(w != NULL);
    CHECK_EQ_INT(gs_st_writer_add(w, "w.f32", GS_ST_F32, 2, s23, f32v), GS_OK);
    CHECK_EQ_INT(gs_st_writer_add(w, "h", GS_ST_F16, 1, s4, f16v), GS_OK);
    CHECK_EQ_INT(gs_st_writer_add(w, "scalar", GS_ST_I32, 0, NULL, &i32v), GS_OK);
    CHECK_EQ_INT(gs_st_writer_add(w, "big", GS_ST_I64, 1, s3, i64v), GS_OK);
    CHECK_EQ_INT(gs_st_writer_add(w, "bytes", GS_ST_U8, 1, s5, u8v), GS_OK);
    CHECK_EQ_INT(gs_st_writer_add(w, "empty", GS_ST_F32, 1, s0, NULL), GS_OK);
    CHECK_EQ_INT(gs_st_writer_add(w, "empty3", GS_ST_U8, 3, s203, NULL), GS_OK);
    CHECK_EQ_INT(gs_st_writer_add(w, "nom \"quoted\"\n\xc3\xa9", GS_ST_U8, 1, s5, u8v), GS_OK);
    CHECK_EQ_INT(gs_st_writer_meta(w, "format", "gazesplat"), GS_OK);
    CHECK_EQ_INT(gs_st_writer_meta(w, "config", "{\"width\": 64,\n\t\"x\": \"\\u\"}"), GS_OK);
    CHECK_EQ_INT(gs_st_writer_meta(w, "version", "0"), GS_OK);
    CHECK_EQ_INT(gs_st_writer_meta(w, "version", "1"), GS_OK); /* replaces */
    return w;
}

static void check_tensor(const gs_st_file *f, const char *name, gs_st_dtype dt, int ndim,
                         const int64_t *shape, const void *want, size_t nbytes)
{
    const gs_st_tensor *t = gs_st_find(f, name);
    CHECK_MSG(t != NULL, "tensor '%s' missing", name);
    if (!t)
        return;
    CHECK_MSG(t->dtype == dt && t->ndim == ndim && t->nbytes == nbytes,
              "%s: dtype %d ndim %d nbytes %zu", name, t->dtype, t->ndim, t->nbytes);
    for (int i = 0; i < ndim && i < t->ndim; i++)
        CHECK_MSG(t->shape[i] == shape[i], "%s: dim %d %lld", name, i, (long long)t->shape[i]);
    CHECK_MSG(((uintptr_t)t->data & 7) == 0, "%s: data %p not 8-aligned", name, t->data);
    CHECK_MSG(nbytes == 0 || memcmp(t->data, want, nbytes) == 0, "%s: data differs", name);
}

static void check_sample(const gs_st_file *f)
{
    int64_t s23[2] = {2, 3}, s4[1] = {4}, s3[1] = {3}, s5[1] = {5}, s0[1] = {0}, s203[3] = {2, 0, 3};
    CHECK_EQ_INT(gs_st_count(f), 8);
    check_tensor(f, "w.f32", GS_ST_F32, 2, s23, f32v, sizeof f32v);
    check_tensor(f, "h", GS_ST_F16, 1, s4, f16v, sizeof f16v);
    check_tensor(f, "scalar", GS_ST_I32, 0, NULL, &i32v, 4);
    check_tensor(f, "big", GS_ST_I64, 1, s3, i64v, sizeof i64v);
    check_tensor(f, "bytes", GS_ST_U8, 1, s5, u8v, 5);
    check_tensor(f, "empty", GS_ST_F32, 1, s0, NULL, 0);
    check_tensor(f, "empty3", GS_ST_U8, 3, s203, NULL, 0);
    check_tensor(f, "nom \"quoted\"\n\xc3\xa9", GS_ST_U8, 1, s5, u8v, 5);
    CHECK(gs_st_find(f, "absent") == NULL);
    CHECK(gs_st_at(f, -1) == NULL && gs_st_at(f, 8) == NULL);
    const char *v = gs_st_meta(f, "config");
    CHECK_MSG(v && strcmp(v, "{\"width\": 64,\n\t\"x\": \"\\u\"}") == 0, "config = %s", v);
    v = gs_st_meta(f, "version");
    CHECK_MSG(v && strcmp(v, "1") == 0, "version = %s", v);
    CHECK(gs_st_meta(f, "absent") == NULL);
    CHECK_EQ_INT(gs_st_meta_count(f), 3);
    /* File order: by offset, covering the buffer. */
    size_t at = 0;
    for (int i = 0; i < gs_st_count(f); i++) {
        const gs_st_tensor *t = gs_st_at(f, i);
        CHECK_MSG(t->offset == at, "tensor %d '%s' at %zu, want %zu", i, t->name, t->offset, at);
        at = t->offset + t->nbytes;
    }
}

/* Writes every tensor and metadata entry of f into a new writer. */
static gs_st_writer *copy_to_writer(const gs_st_file *f)
{
    gs_st_writer *w = gs_st_writer_create();
    for (int i = 0; i < gs_st_count(f); i++) {
        const gs_st_tensor *t = gs_st_at(f, i);
        CHECK_EQ_INT(gs_st_writer_add(w, t->name, t->dtype, t->ndim, t->shape, t->data), GS_OK);
    }
    for (int i = 0; i < gs_st_meta_count(f); i++) {
        const char *k, *v;
        gs_st_meta_at(f, i, &k, &v);
        CHECK_EQ_INT(gs_st_writer_meta(w, k, v), GS_OK);
    }
    return w;
}

static uint8_t *read_file(const char *path, size_t *len)
{
    FILE *fp = fopen(path, "rb");
    uint8_t *b = NULL;
    if (!fp)
        return NULL;
    fseek(fp, 0, SEEK_END);
    *len = (size_t)ftell(fp);
    fseek(fp, 0, SEEK_SET);
    b = malloc(*len + 1);
    if (fread(b, 1, *len, fp) != *len) {
        free(b);
        b = NULL;
    }
    fclose(fp);
    return b;
}

static void test_round_trip(const char *dir)
{
    gs_st_writer *w = sample_writer();
    uint8_t *buf = NULL, *buf2 = NULL;
    size_t len = 0, len2 = 0;
    gs_error err = {0, ""};
    CHECK_EQ_INT(gs_st_writer_to_mem(w, &buf, &len, &err), GS_OK);
    uint64_t n = 0;
    for (int i = 7; i >= 0; i--)
        n = n << 8 | buf[i];
    CHECK_MSG(n % 8 == 0 && buf[8] == '{', "header length %llu", (unsigned long long)n);
    /* Larger elements first: I64, F32, I32, F16, then U8 by name. */
    const char *order[] = {"big", "empty", "w.f32", "scalar", "h", "bytes", "empty3",
                           "nom \"quoted\"\n\xc3\xa9"};
    gs_st_file *f = open_ok("round trip", buf, len);
    if (f) {
        check_sample(f);
        for (int i = 0; i < 8; i++)
            CHECK_MSG(strcmp(gs_st_at(f, i)->name, order[i]) == 0, "tensor %d is '%s', want '%s'",
                      i, gs_st_at(f, i)->name, order[i]);
        gs_st_writer *w2 = copy_to_writer(f);
        CHECK_EQ_INT(gs_st_writer_to_mem(w2, &buf2, &len2, &err), GS_OK);
        CHECK_MSG(len2 == len && memcmp(buf, buf2, len) == 0, "re-save differs (%zu vs %zu bytes)",
                  len2, len);
        gs_st_writer_destroy(w2);
        gs_st_close(f);
    }
    /* The file path: same bytes, same tensors, no temporary left. */
    char path[512], tmp[600];
    size_t flen = 0;
    snprintf(path, sizeof path, "%s/model.safetensors", dir);
    CHECK_EQ_INT(gs_st_writer_save(w, path, &err), GS_OK);
    CHECK_EQ_INT(gs_st_writer_save(w, path, &err), GS_OK); /* over an existing file */
    snprintf(tmp, sizeof tmp, "%s.tmp.%ld", path, (long)getpid());
    CHECK_MSG(access(tmp, F_OK) != 0, "%s left behind", tmp);
    uint8_t *fbytes = read_file(path, &flen);
    CHECK_MSG(fbytes && flen == len && memcmp(fbytes, buf, len) == 0, "saved file differs");
    free(fbytes);
    f = NULL;
    CHECK_EQ_INT(gs_st_open(path, NULL, &f, &err), GS_OK);
    if (f) {
        check_sample(f);
        const float *p = NULL;
        int64_t s23[2] = {2, 3}, s32[2] = {3, 2};
        CHECK_EQ_INT(gs_st_get_f32(f, "w.f32", 2, s23, &p, &err), GS_OK);
        CHECK(p && p[1] == -2.25f);
        CHECK_EQ_INT(gs_st_get_f32(f, "w.f32", 2, s32, &p, &err), GS_ERR_FORMAT);
        CHECK_MSG(strstr(err.msg, "'w.f32'") && strstr(err.msg, "expected F32 [3, 2], got F32 [2, 3]"),
                  "message: %s", err.msg);
        CHECK_EQ_INT(gs_st_get_f32(f, "h", 1, s23, &p, &err), GS_ERR_FORMAT);
        CHECK_MSG(strstr(err.msg, "expected F32 [2], got F16 [4]"), "message: %s", err.msg);
        CHECK_EQ_INT(gs_st_get_f32(f, "nope", 0, NULL, &p, &err), GS_ERR_FORMAT);
        CHECK_MSG(strstr(err.msg, "no tensor 'nope'"), "message: %s", err.msg);
        gs_st_close(f);
    }
    free(buf);
    free(buf2);
    gs_st_writer_destroy(w);
    /* An empty writer: "{}" padded to 8 bytes, and back. */
    w = gs_st_writer_create();
    CHECK_EQ_INT(gs_st_writer_to_mem(w, &buf, &len, &err), GS_OK);
    CHECK_MSG(len == 16 && memcmp(buf + 8, "{}      ", 8) == 0, "empty file of %zu bytes", len);
    f = open_ok("empty writer", buf, len);
    CHECK(f && gs_st_count(f) == 0 && gs_st_meta_count(f) == 0);
    gs_st_close(f);
    free(buf);
    gs_st_writer_destroy(w);
}

static void test_writer_refuses(void)
{
    gs_st_writer *w = gs_st_writer_create();
    int64_t s2[1] = {2}, s9[9] = {1, 1, 1, 1, 1, 1, 1, 1, 1}, neg[1] = {-1};
    int64_t huge[2] = {INT64_MAX / 2, 3};
    float nan2[2] = {1.0f, NAN}, ok2[2] = {1, 2};
    uint16_t inf16[2] = {0, 0x7C00};
    char long_name[300];
    memset(long_name, 'a', 256);
    long_name[256] = '\0';
    CHECK_EQ_INT(gs_st_writer_add(w, "a", GS_ST_F32, 1, s2, ok2), GS_OK);
    CHECK_EQ_INT(gs_st_writer_add(w, "a", GS_ST_F32, 1, s2, ok2), GS_ERR_ARG);
    CHECK_EQ_INT(gs_st_writer_add(w, "", GS_ST_F32, 1, s2, ok2), GS_ERR_ARG);
    CHECK_EQ_INT(gs_st_writer_add(w, "__metadata__", GS_ST_F32, 1, s2, ok2), GS_ERR_ARG);
    CHECK_EQ_INT(gs_st_writer_add(w, long_name, GS_ST_F32, 1, s2, ok2), GS_ERR_ARG);
    long_name[255] = '\0';
    CHECK_EQ_INT(gs_st_writer_add(w, long_name, GS_ST_F32, 1, s2, ok2), GS_OK);
    CHECK_EQ_INT(gs_st_writer_add(w, "bad\xff", GS_ST_F32, 1, s2, ok2), GS_ERR_ARG);
    CHECK_EQ_INT(gs_st_writer_add(w, "b", (gs_st_dtype)7, 1, s2, ok2), GS_ERR_ARG);
    CHECK_EQ_INT(gs_st_writer_add(w, "b", GS_ST_F32, 9, s9, ok2), GS_ERR_ARG);
    CHECK_EQ_INT(gs_st_writer_add(w, "b", GS_ST_F32, 1, neg, ok2), GS_ERR_ARG);
    CHECK_EQ_INT(gs_st_writer_add(w, "b", GS_ST_F32, 2, huge, ok2), GS_ERR_LIMIT);
    CHECK_EQ_INT(gs_st_writer_add(w, "b", GS_ST_F32, 1, s2, NULL), GS_ERR_ARG);
    CHECK_EQ_INT(gs_st_writer_add(w, "b", GS_ST_F32, 1, s2, nan2), GS_ERR_NONFINITE);
    CHECK_EQ_INT(gs_st_writer_add(w, "b", GS_ST_F16, 1, s2, inf16), GS_ERR_NONFINITE);
    CHECK_EQ_INT(gs_st_writer_meta(w, "k", "bad\xc0\x80"), GS_ERR_ARG);
    CHECK_EQ_INT(gs_st_writer_meta(w, NULL, "v"), GS_ERR_ARG);
    gs_error err = {0, ""};
    CHECK_EQ_INT(gs_st_writer_save(w, "no-such-dir/x.safetensors", &err), GS_ERR_IO);
    CHECK_MSG(strstr(err.msg, "no-such-dir"), "message: %s", err.msg);
    gs_st_writer_destroy(w);
    gs_st_writer_destroy(NULL);
    gs_st_close(NULL);
}

/* Many tensors: the writer's name set and the reader's binary search. */
static void test_many(void)
{
    enum { N = 5000 };
    gs_st_writer *w = gs_st_writer_create();
    char name[32];
    int64_t s1[1] = {1};
    for (int i = 0; i < N; i++) {
        float v = (float)i;
        snprintf(name, sizeof name, "t%d", (i * 7919) % N);
        CHECK_EQ_INT(gs_st_writer_add(w, name, GS_ST_F32, 1, s1, &v), GS_OK);
    }
    CHECK_EQ_INT(gs_st_writer_add(w, "t4999", GS_ST_F32, 1, s1, s1), GS_ERR_ARG);
    uint8_t *buf = NULL;
    size_t len = 0;
    gs_error err = {0, ""};
    CHECK_EQ_INT(gs_st_writer_to_mem(w, &buf, &len, &err), GS_OK);
    gs_st_file *f = open_ok("5000 tensors", buf, len);
    int bad = 0;
    for (int i = 0; f && i < N; i++) {
        const float *p = NULL;
        snprintf(name, sizeof name, "t%d", (i * 7919) % N);
        if (gs_st_get_f32(f, name, 1, s1, &p, &err) != GS_OK || *p != (float)i)
            bad++;
    }
    CHECK_MSG(bad == 0, "%d of %d tensors wrong", bad, N);
    gs_st_limits lim = {0, 0, N - 1};
    expect_refused("5000 over a limit of 4999", buf, len, &lim, GS_ERR_LIMIT, "more than 4999");
    gs_st_close(f);
    free(buf);
    gs_st_writer_destroy(w);
}

/* ---- what other writers may do, and we accept --------------------------- */

static void test_accepts(void)
{
    /* Whitespace between tokens, keys in any order, unsorted tensors, an
     * F32 at an odd offset after 3 bytes, escapes in names, spaces after. */
    const char *json =
        "{ \"b\\u00e9\\ud83d\\ude00\\t\" :\n\t{\"data_offsets\": [3, 11], \"shape\":[2],"
        "\"dtype\":\"F32\"},\r\n \"a\": {\"shape\": [3], \"dtype\": \"U8\", "
        "\"data_offsets\": [0, 3]}, \"__metadata__\": {} , \"z\":{\"dtype\":\"I64\","
        "\"shape\":[0,5],\"data_offsets\":[11,11]}}   ";
    uint8_t data[11] = {9, 8, 7};
    float two[2] = {0.5f, -4.0f};
    memcpy(data + 3, two, 8);
    size_t len;
    uint8_t *b = image_of(json, data, sizeof data, &len);
    gs_st_file *f = open_ok("accepts", b, len);
    if (f) {
        const gs_st_tensor *t = gs_st_find(f, "b\xc3\xa9\xf0\x9f\x98\x80\t");
        CHECK_MSG(t && t->dtype == GS_ST_F32 && t->offset == 3, "escaped name not found");
        CHECK(t && ((uintptr_t)t->data & 7) == 0 && memcmp(t->data, two, 8) == 0);
        CHECK(gs_st_count(f) == 3 && strcmp(gs_st_at(f, 0)->name, "a") == 0);
        CHECK(gs_st_meta_count(f) == 0);
        t = gs_st_find(f, "z");
        CHECK(t && t->nbytes == 0 && t->ndim == 2 && t->shape[1] == 5);
        gs_st_close(f);
    }
    free(b);
    /* No tensors and no data. */
    b = image_of("{}", NULL, 0, &len);
    f = open_ok("empty", b, len);
    CHECK(f && gs_st_count(f) == 0);
    gs_st_close(f);
    free(b);
}

/* ---- one refusal per rule ------------------------------------------------ */

#define T1(dtype, shape, offs) "{\"t\":{\"dtype\":\"" dtype "\",\"shape\":" shape ",\"data_offsets\":" offs "}}"

static void test_refuses_json(void)
{
    static const struct {
        const char *label, *json;
        size_t dlen;
        int code;
        const char *msg;
    } cases[] = {
        {"not an object", " {}", 0, GS_ERR_FORMAT, "does not start with '{'"},
        {"array", "[]", 0, GS_ERR_FORMAT, "does not start with '{'"},
        {"empty header", "", 0, GS_ERR_FORMAT, "does not start"},
        {"missing colon", "{\"t\" {}}", 0, GS_ERR_FORMAT, "expected ':'"},
        {"unterminated object", "{\"t\":{\"dtype\":\"F32\"", 0, GS_ERR_FORMAT, "end of the header"},
        {"unterminated string", "{\"t", 0, GS_ERR_FORMAT, "unterminated string"},
        {"bad escape", "{\"\\x\":{}}", 0, GS_ERR_FORMAT, "bad escape"},
        {"short \\u", "{\"\\u12", 0, GS_ERR_FORMAT, "truncated \\u"},
        {"bad hex", "{\"\\u12g4\":{}}", 0, GS_ERR_FORMAT, "bad hex digit"},
        {"lone high surrogate", "{\"\\ud800x\":{}}", 0, GS_ERR_FORMAT, "high surrogate"},
        {"lone low surrogate", "{\"\\udc00\":{}}", 0, GS_ERR_FORMAT, "lone low surrogate"},
        {"\\u0000", "{\"a\\u0000\":{}}", 0, GS_ERR_FORMAT, "\\u0000"},
        {"control char", "{\"a\tb\":{}}", 0, GS_ERR_FORMAT, "control character 0x09"},
        {"invalid UTF-8", "{\"a\xff\":{}}", 0, GS_ERR_FORMAT, "invalid UTF-8"},
        {"overlong UTF-8", "{\"a\xc0\xaf\":{}}", 0, GS_ERR_FORMAT, "invalid UTF-8"},
        {"UTF-8 surrogate", "{\"a\xed\xa0\x80\":{}}", 0, GS_ERR_FORMAT, "invalid UTF-8"},
        {"truncated UTF-8", "{\"a\xe2\x82\":{}}", 0, GS_ERR_FORMAT, "invalid UTF-8"},
        {"trailing garbage", "{} x", 0, GS_ERR_FORMAT, "bytes after the header"},
        {"trailing newline", "{}\n", 0, GS_ERR_FORMAT, "bytes after the header"},
        {"two objects", "{}{}", 0, GS_ERR_FORMAT, "bytes after the header"},
        {"trailing comma", "{\"__metadata__\":{},}", 0, GS_ERR_FORMAT, "expected '\"'"},
        {"float in shape", T1("F32", "[2.0]", "[0,8]"), 8, GS_ERR_FORMAT, "not an integer"},
        {"exponent in offsets", T1("F32", "[2]", "[0,8e0]"), 8, GS_ERR_FORMAT, "not an integer"},
        {"negative dim", T1("F32", "[-2]", "[0,8]"), 8, GS_ERR_FORMAT, "negative integer"},
        {"negative offset", T1("U8", "[1]", "[-1,0]"), 1, GS_ERR_FORMAT, "negative integer"},
        {"leading zero", T1("U8", "[01]", "[0,1]"), 1, GS_ERR_FORMAT, "leading zero"},
        {"huge integer", T1("U8", "[99999999999999999999]", "[0,1]"), 1, GS_ERR_FORMAT, "larger than"},
        {"string in shape", T1("U8", "[\"1\"]", "[0,1]"), 1, GS_ERR_FORMAT, "expected an integer"},
        {"shape not an array", T1("U8", "1", "[0,1]"), 1, GS_ERR_FORMAT, "expected '['"},
        {"tensor not an object", "{\"t\":[1]}", 0, GS_ERR_FORMAT, "expected '{'"},
        {"duplicate key", "{\"t\":{\"dtype\":\"U8\",\"dtype\":\"U8\"}}", 0, GS_ERR_FORMAT,
         "duplicate key 'dtype'"},
        {"unknown key", "{\"t\":{\"dtype\":\"U8\",\"strides\":[1]}}", 0, GS_ERR_FORMAT,
         "unknown key 'strides'"},
        {"missing offsets", "{\"t\":{\"dtype\":\"U8\",\"shape\":[1]}}", 1, GS_ERR_FORMAT,
         "no 'data_offsets'"},
        {"missing dtype", "{\"t\":{\"shape\":[1],\"data_offsets\":[0,1]}}", 1, GS_ERR_FORMAT,
         "no 'dtype'"},
        {"three offsets", T1("U8", "[1]", "[0,1,1]"), 1, GS_ERR_FORMAT, "more than 2"},
        {"one offset", T1("U8", "[1]", "[1]"), 1, GS_ERR_FORMAT, "needs 2 entries"},
        {"duplicate tensor", "{\"t\":{\"dtype\":\"U8\",\"shape\":[1],\"data_offsets\":[0,1]},"
         "\"t\":{\"dtype\":\"U8\",\"shape\":[1],\"data_offsets\":[1,2]}}", 2, GS_ERR_FORMAT,
         "duplicate tensor name 't'"},
        {"duplicate __metadata__", "{\"__metadata__\":{},\"__metadata__\":{}}", 0, GS_ERR_FORMAT,
         "duplicate key '__metadata__'"},
        {"duplicate metadata key", "{\"__metadata__\":{\"k\":\"1\",\"k\":\"2\"}}", 0, GS_ERR_FORMAT,
         "duplicate __metadata__ key 'k'"},
        {"metadata number", "{\"__metadata__\":{\"k\":1}}", 0, GS_ERR_FORMAT, "not a string"},
        {"metadata object", "{\"__metadata__\":{\"k\":{}}}", 0, GS_ERR_FORMAT, "not a string"},
        {"metadata null", "{\"__metadata__\":{\"k\":null}}", 0, GS_ERR_FORMAT, "not a string"},
        {"metadata not object", "{\"__metadata__\":\"x\"}", 0, GS_ERR_FORMAT, "expected '{'"},
        {"unknown dtype", T1("F99", "[1]", "[0,4]"), 4, GS_ERR_FORMAT, "unknown dtype 'F99'"},
        {"unsupported dtype", T1("BF16", "[1]", "[0,2]"), 2, GS_ERR_UNSUPPORTED, "BF16 not supported"},
        {"ndim 9", T1("U8", "[1,1,1,1,1,1,1,1,1]", "[0,1]"), 1, GS_ERR_LIMIT, "more than 8"},
        {"shape overflow", T1("U8", "[4294967296,4294967296]", "[0,1]"), 1, GS_ERR_FORMAT,
         "shape product overflows"},
        {"byte size overflow", T1("F32", "[4611686018427387904]", "[0,4]"), 4, GS_ERR_FORMAT,
         "byte size overflows"},
        {"size mismatch", T1("F32", "[2]", "[0,4]"), 4, GS_ERR_FORMAT, "need 8"},
        {"scalar mismatch", T1("I64", "[]", "[0,4]"), 4, GS_ERR_FORMAT, "need 8"},
        {"offsets out of range", T1("U8", "[100]", "[0,100]"), 8, GS_ERR_FORMAT, "beyond the byte buffer"},
        {"begin after end", T1("U8", "[0]", "[8,4]"), 8, GS_ERR_FORMAT, "begin after end"},
        {"overlap", "{\"a\":{\"dtype\":\"U8\",\"shape\":[8],\"data_offsets\":[0,8]},"
         "\"b\":{\"dtype\":\"U8\",\"shape\":[8],\"data_offsets\":[4,12]}}", 12, GS_ERR_FORMAT,
         "'b' at [4, 12) overlaps 'a'"},
        {"same region twice", "{\"a\":{\"dtype\":\"U8\",\"shape\":[4],\"data_offsets\":[0,4]},"
         "\"b\":{\"dtype\":\"U8\",\"shape\":[4],\"data_offsets\":[0,4]}}", 4, GS_ERR_FORMAT, "overlaps"},
        {"hole", "{\"a\":{\"dtype\":\"U8\",\"shape\":[4],\"data_offsets\":[0,4]},"
         "\"b\":{\"dtype\":\"U8\",\"shape\":[4],\"data_offsets\":[8,12]}}", 12, GS_ERR_FORMAT,
         "hole in the byte buffer: bytes [4, 8)"},
        {"hole at start", T1("U8", "[4]", "[4,8]"), 8, GS_ERR_FORMAT, "bytes [0, 4)"},
        {"extra data", T1("U8", "[4]", "[0,4]"), 8, GS_ERR_FORMAT, "has 8 bytes but the tensors cover 4"},
        {"data without tensors", "{}", 8, GS_ERR_FORMAT, "cover 0"},
        {"empty name", "{\"\":{}}", 0, GS_ERR_FORMAT, "empty tensor name"},
    };
    for (size_t i = 0; i < sizeof cases / sizeof *cases; i++)
        refused_json(cases[i].label, cases[i].json, cases[i].dlen, cases[i].code, cases[i].msg);
}

static void test_refuses_other(void)
{
    uint8_t zeros[16] = {0};
    size_t len;
    uint8_t *b;
    /* Shorter than 8 bytes, and header lengths past the file or limit. */
    expect_refused("5 bytes", zeros, 5, NULL, GS_ERR_FORMAT, "shorter than its 8-byte");
    expect_refused("0 bytes", NULL, 0, NULL, GS_ERR_FORMAT, "shorter than its 8-byte");
    b = image_of("{}", NULL, 0, &len);
    b[0] = 100;
    expect_refused("header past the end", b, len, NULL, GS_ERR_FORMAT, "beyond the end of the file");
    b[0] = 0, b[3] = 2; /* 32 MiB */
    expect_refused("header over the limit", b, len, NULL, GS_ERR_LIMIT, "over the limit");
    b[3] = 0, b[7] = 0x80; /* 2^63: no wrap-around */
    expect_refused("header 2^63", b, len, NULL, GS_ERR_LIMIT, "over the limit");
    b[7] = 0, b[0] = 2;
    gs_st_limits small = {8, 0, 0};
    expect_refused("file over the limit", b, len, &small, GS_ERR_LIMIT, "file of 10 bytes over");
    small = (gs_st_limits){0, 1, 0};
    expect_refused("header over a set limit", b, len, &small, GS_ERR_LIMIT, "header length 2 over");
    free(b);
    /* Name of 256 bytes; 255 is fine. */
    char json[600], name[300];
    memset(name, 'n', 256);
    name[256] = '\0';
    snprintf(json, sizeof json, "{\"%s\":{\"dtype\":\"U8\",\"shape\":[],\"data_offsets\":[0,1]}}", name);
    refused_json("name of 256 bytes", json, 1, GS_ERR_LIMIT, "name of 256 bytes");
    name[255] = '\0';
    snprintf(json, sizeof json, "{\"%s\":{\"dtype\":\"U8\",\"shape\":[],\"data_offsets\":[0,1]}}", name);
    b = image_of(json, zeros, 1, &len);
    gs_st_close(open_ok("name of 255 bytes", b, len));
    free(b);
    /* Tensor count limit. */
    b = image_of("{\"a\":{\"dtype\":\"U8\",\"shape\":[1],\"data_offsets\":[0,1]},"
                 "\"b\":{\"dtype\":\"U8\",\"shape\":[1],\"data_offsets\":[1,2]}}", zeros, 2, &len);
    small = (gs_st_limits){0, 0, 1};
    expect_refused("too many tensors", b, len, &small, GS_ERR_LIMIT, "more than 1 tensors");
    free(b);
    /* Non-finite floats, named with their index. */
    float fv[3] = {1.0f, 2.0f, NAN};
    b = image_of(T1("F32", "[3]", "[0,12]"), fv, 12, &len);
    expect_refused("NaN", b, len, NULL, GS_ERR_NONFINITE, "tensor 't' (F32): element 2");
    free(b);
    fv[2] = 0, fv[0] = -INFINITY;
    b = image_of(T1("F32", "[3]", "[0,12]"), fv, 12, &len);
    expect_refused("-Inf", b, len, NULL, GS_ERR_NONFINITE, "element 0");
    free(b);
    /* Past the check's blocks (256) and the loader's chunks (256 KiB). */
    static const size_t where[] = {0, 255, 256, 300, 65535, 65536, 70001, 99999};
    float *big = calloc(100000, sizeof *big);
    char want[64];
    snprintf(json, sizeof json, T1("F32", "[100000]", "[0,400000]"));
    for (size_t k = 0; k < sizeof where / sizeof *where; k++) {
        big[where[k]] = k % 2 ? INFINITY : NAN;
        b = image_of(json, big, 400000, &len);
        snprintf(want, sizeof want, "element %zu is", where[k]);
        expect_refused("NaN/Inf in a large tensor", b, len, NULL, GS_ERR_NONFINITE, want);
        free(b);
        big[where[k]] = 0;
    }
    uint16_t *big16 = (uint16_t *)big;
    snprintf(json, sizeof json, T1("F16", "[200000]", "[0,400000]"));
    big16[131073] = 0x7C01;
    b = image_of(json, big, 400000, &len);
    expect_refused("F16 NaN in a large tensor", b, len, NULL, GS_ERR_NONFINITE, "element 131073 is");
    free(b);
    big16[131073] = 0x7BFF; /* the largest finite half */
    b = image_of(json, big, 400000, &len);
    gs_st_close(open_ok("large finite F16", b, len));
    free(b);
    free(big);
    uint16_t hv[2] = {0x3C00, 0xFE00};
    b = image_of(T1("F16", "[2]", "[0,4]"), hv, 4, &len);
    expect_refused("F16 NaN", b, len, NULL, GS_ERR_NONFINITE, "(F16): element 1");
    free(b);
}

static void test_files(const char *dir)
{
    gs_st_file *f = NULL;
    gs_error err = {0, ""};
    char path[512];
    CHECK_EQ_INT(gs_st_open("no-such-file.safetensors", NULL, &f, &err), GS_ERR_IO);
    CHECK_EQ_INT(gs_st_open(dir, NULL, &f, &err), GS_ERR_IO);
    CHECK_MSG(strstr(err.msg, "not a regular file"), "message: %s", err.msg);
    /* A truncated file on disk. */
    gs_st_writer *w = sample_writer();
    uint8_t *buf;
    size_t len;
    CHECK_EQ_INT(gs_st_writer_to_mem(w, &buf, &len, &err), GS_OK);
    snprintf(path, sizeof path, "%s/cut.safetensors", dir);
    FILE *fp = fopen(path, "wb");
    CHECK(fp && fwrite(buf, 1, len - 3, fp) == len - 3);
    fclose(fp);
    CHECK_EQ_INT(gs_st_open(path, NULL, &f, &err), GS_ERR_FORMAT);
    CHECK_MSG(strstr(err.msg, "beyond the byte buffer") || strstr(err.msg, "cover"), "message: %s",
              err.msg);
    CHECK(f == NULL);
    /* Every prefix of a valid image is refused, never crashes. */
    for (size_t n = 0; n < len; n++) {
        int rc = gs_st_open_mem(buf, n, NULL, &f, &err);
        CHECK_MSG(rc == GS_ERR_FORMAT && f == NULL, "prefix of %zu bytes: rc %d", n, rc);
    }
    gs_st_limits tight = {len, 0, 8};
    CHECK_EQ_INT(gs_st_open_mem(buf, len, &tight, &f, &err), GS_OK);
    gs_st_close(f);
    remove(path);
    free(buf);
    gs_st_writer_destroy(w);
}

int main(void)
{
    char dir[] = "st_test_XXXXXX", cmd[64];
    if (!mkdtemp(dir)) {
        perror("mkdtemp");
        return 1;
    }
    test_round_trip(dir);
    test_writer_refuses();
    test_many();
    test_accepts();
    test_refuses_json();
    test_refuses_other();
    test_files(dir);
    snprintf(cmd, sizeof cmd, "rm -rf '%s'", dir);
    if (system(cmd) != 0)
        fprintf(stderr, "could not remove %s\n", dir);
    GS_TEST_END();
}
