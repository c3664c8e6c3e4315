/* The shape model loader: a small model serialized here in dlib's format
 * parses and predicts; every truncation of it, corrupt fields, and
 * truncated copies of the real model are refused with GS_ERR_FORMAT. */
#include <stdlib.h>
#include <string.h>

#include "face_internal.h"
#include "face_photos.h"
#include "gs_test.h"

typedef struct buf {
    unsigned char *p;
    size_t n, cap;
} buf;

static void put(buf *b, unsigned char c)
{
    if (b->n == b->cap) {
        b->cap = b->cap ? 2 * b->cap : 256;
        b->p = realloc(b->p, b->cap);
    }
    b->p[b->n++] = c;
}

/* dlib integer: control byte (sign, byte count) + little-endian bytes. */
static void put_int(buf *b, long long v)
{
    unsigned long long m = v < 0 ? (unsigned long long)-v : (unsigned long long)v;
    unsigned char bytes[8];
    int n = 0;
    while (m) {
        bytes[n++] = (unsigned char)m;
        m >>= 8;
    }
    put(b, (unsigned char)(n | (v < 0 ? 0x80 : 0)));
    for (int i = 0; i < n; i++)
        put(b, bytes[i]);
}

/* dlib float: mantissa, exponent (values here are k / 64). */
static void put_float(buf *b, float v)
{
    put_int(b, (long long)(v * 64.0f));
    put_int(b, -6);
}

enum { PARTS = 3, CASCADES = 2, TREES = 2, FEATS = 5 };

static buf small_model(void)
{
    buf b = {0};
    put_int(&b, 1); /* version */
    put_int(&b, -2 * PARTS);
    put_int(&b, -1);
    for (int i = 0; i < 2 * PARTS; i++)
        put_float(&b, 0.25f + 0.25f * (float)(i % 3));
    put_int(&b, CASCADES);
    for (int c = 0; c < CASCADES; c++) {
        put_int(&b, TREES);
        for (int t = 0; t < TREES; t++) {
            put_int(&b, 1); /* one split */
            put_int(&b, c);
            put_int(&b, 4);
            put_float(&b, 1.5f);
            put_int(&b, 2); /* two leaves */
            for (int l = 0; l < 2; l++) {
                put_int(&b, -2 * PARTS);
                put_int(&b, -1);
                for (int i = 0; i < 2 * PARTS; i++)
                    put_float(&b, l ? 0.015625f : -0.015625f);
            }
        }
    }
    put_int(&b, CASCADES);
    for (int c = 0; c < CASCADES; c++) {
        put_int(&b, FEATS);
        for (int i = 0; i < FEATS; i++)
            put_int(&b, i % PARTS);
    }
    put_int(&b, CASCADES);
    for (int c = 0; c < CASCADES; c++) {
        put_int(&b, FEATS);
        for (int i = 0; i < 2 * FEATS; i++)
            put_float(&b, 0.0625f * (float)(i - 4));
    }
    return b;
}

static void small_model_tests(void)
{
    buf b = small_model();
    gs_face_shape_model *m = NULL;
    gs_error err;
    CHECK_MSG(gs_face_shape_model_parse(b.p, b.n, &m, &err) == GS_OK, "%s", err.msg);
    if (m) {
        CHECK_EQ_INT(gs_face_shape_model_parts(m), PARTS);
        CHECK_EQ_INT(m->n_cascades, CASCADES);
        CHECK_EQ_INT(m->n_trees, TREES);
        CHECK_EQ_INT(m->n_splits, 1);
        CHECK_EQ_INT(m->n_features, FEATS);
        unsigned char px[3 * 64 * 64];
        for (int i = 0; i < (int)sizeof px; i++)
            px[i] = (unsigned char)(i * 7);
        gs_io_image img = {64, 64, 192, px};
        int pts[2 * PARTS];
        CHECK(gs_face_shape_predict(m, &img, (gs_face_box){8, 8, 55, 55}, pts, NULL, &err) ==
              GS_OK);
        CHECK(gs_face_shape_predict(m, &img, (gs_face_box){8, 8, 8, 55}, pts, NULL, &err) ==
              GS_ERR_ARG);
        gs_face_shape_model_destroy(m);
    }
    /* Every proper prefix is refused. */
    int refused = 0;
    for (size_t n = 0; n < b.n; n++) {
        m = NULL;
        int rc = gs_face_shape_model_parse(b.p, n, &m, &err);
        refused += rc == GS_ERR_FORMAT && m == NULL;
        if (rc == GS_OK)
            gs_face_shape_model_destroy(m);
    }
    CHECK_MSG(refused == (int)b.n, "%d of %zu truncations refused", refused, b.n);
    /* Trailing bytes, a wrong version, a bad control byte. */
    buf t = small_model();
    put(&t, 0);
    CHECK(gs_face_shape_model_parse(t.p, t.n, &m, &err) == GS_ERR_FORMAT);
    t.p[1] = 2;
    CHECK(gs_face_shape_model_parse(t.p, t.n - 1, &m, &err) == GS_ERR_FORMAT);
    t.p[1] = 1;
    t.p[2] = 0x7f;
    CHECK(gs_face_shape_model_parse(t.p, t.n - 1, &m, &err) == GS_ERR_FORMAT);
    free(t.p);
    /* Every byte flipped in turn: refused or parsed, never a crash (the
     * sanitizer build checks the memory accesses). */
    for (size_t i = 0; i < b.n; i++) {
        b.p[i] ^= 0xa5;
        m = NULL;
        if (gs_face_shape_model_parse(b.p, b.n, &m, &err) == GS_OK) {
            unsigned char px[3 * 16 * 16] = {0};
            gs_io_image img = {16, 16, 48, px};
            int pts[2 * 256];
            (void)gs_face_shape_predict(m, &img, (gs_face_box){0, 0, 15, 15}, pts, NULL, &err);
            gs_face_shape_model_destroy(m);
        }
        b.p[i] ^= 0xa5;
    }
    free(b.p);
    CHECK(gs_face_shape_model_load("/nonexistent/model.dat", &m, &err) == GS_ERR_IO);
}

/* Truncated copies of the real model, parsed from memory. */
static int real_model_tests(void)
{
    FILE *f = fopen(GS_FACE_SHAPE_MODEL_DEFAULT, "rb");
    if (!f) {
        printf("SKIP: %s missing\n", GS_FACE_SHAPE_MODEL_DEFAULT);
        return GS_TEST_SKIP;
    }
    fseek(f, 0, SEEK_END);
    size_t len = (size_t)ftell(f);
    fseek(f, 0, SEEK_SET);
    unsigned char *p = malloc(len);
    CHECK(p && fread(p, 1, len, f) == len);
    fclose(f);
    const size_t cuts[] = {0, 1, 10, 600, len / 3, len - 1};
    for (size_t i = 0; i < sizeof cuts / sizeof cuts[0]; i++) {
        gs_face_shape_model *m = NULL;
        gs_error err;
        int rc = gs_face_shape_model_parse(p, cuts[i], &m, &err);
        CHECK_MSG(rc == GS_ERR_FORMAT && !m, "cut at %zu: rc %d", cuts[i], rc);
        if (i == 3)
            printf("truncated model: %s\n", err.msg);
    }
    gs_face_shape_model *m = NULL;
    gs_error err;
    CHECK_MSG(gs_face_shape_model_parse(p, len, &m, &err) == GS_OK, "%s", err.msg);
    if (m) {
        CHECK_EQ_INT(m->n_parts, 68);
        CHECK_EQ_INT(m->n_cascades, 15);
        CHECK_EQ_INT(m->n_trees, 500);
        CHECK_EQ_INT(m->n_splits, 15);
        CHECK_EQ_INT(m->n_features, 500);
        gs_face_shape_model_destroy(m);
    }
    free(p);
    return 0;
}

int main(void)
{
    small_model_tests();
    int rc = real_model_tests();
    if (rc == GS_TEST_SKIP && !gs_test_failures)
        return rc;
    GS_TEST_END();
}
