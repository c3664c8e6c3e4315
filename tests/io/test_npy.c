/* npy writer and reader: round trips of every rank and dtype, the exact
 * header layout, and every malformed header we refuse. */
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "gazesplat/image_io.h"
#include "gs_test.h"

/* Checks rc and that err.msg contains want (when want is not NULL). */
#define CHECK_ERR(rc, code, err, want)                                        \
    do {                                                                      \
        CHECK_EQ_INT(rc, code);                                               \
        if ((want) != NULL)                                                   \
            CHECK_MSG(strstr((err).msg, (want)) != NULL,                      \
                      "message '%s' lacks '%s'", (err).msg, (const char *)(want)); \
    } while (0)

/* An .npy image: version major.0, the dict text (padded and ended with
 * '\n' here), then data. */
static unsigned char *make_npy(int major, const char *dict, const void *data, size_t dlen,
                               size_t *len)
{
    size_t pre = major == 1 ? 10 : 12, hl = strlen(dict) + 1;
    unsigned char *b = malloc(pre + hl + dlen + 1);
    memcpy(b, "\x93NUMPY", 6);
    b[6] = (unsigned char)major;
    b[7] = 0;
    b[8] = (unsigned char)hl;
    b[9] = (unsigned char)(hl >> 8);
    if (major > 1)
        b[10] = b[11] = 0;
    memcpy(b + pre, dict, hl - 1);
    b[pre + hl - 1] = '\n';
    if (dlen)
        memcpy(b + pre + hl, data, dlen);
    *len = pre + hl + dlen;
    return b;
}

static int parse_dict(const char *dict, size_t dlen, size_t max_bytes, gs_io_array *a,
                      gs_error *err)
{
    static float zeros[64];
    size_t len;
    unsigned char *b = make_npy(1, dict, zeros, dlen, &len);
    int rc = gs_io_npy_parse(b, len, max_bytes, a, err);
    free(b);
    return rc;
}

static void test_round_trip_ranks(void)
{
    float v[2 * 3 * 4 * 5];
    for (int i = 0; i < 120; i++)
        v[i] = (float)i * 0.25f - 7.0f;
    size_t shapes[5][4] = {{0}, {120}, {10, 12}, {2, 3, 20}, {2, 3, 4, 5}};
    for (int rank = 0; rank <= 4; rank++) {
        void *buf = NULL;
        size_t len = 0;
        gs_io_array a;
        gs_error err = {0};
        CHECK_EQ_INT(gs_io_npy_encode(GS_IO_F32, rank, shapes[rank], v, &buf, &len, &err), GS_OK);
        CHECK_EQ_INT((len - (rank ? 120u : 1u) * 4) % 64, 0);
        CHECK_EQ_INT(gs_io_npy_parse(buf, len, 0, &a, &err), GS_OK);
        CHECK_EQ_INT(a.dtype, GS_IO_F32);
        CHECK_EQ_INT(a.rank, rank);
        for (int d = 0; d < rank; d++)
            CHECK_EQ_INT(a.shape[d], shapes[rank][d]);
        CHECK_EQ_INT(gs_io_array_count(&a), rank ? 120 : 1);
        CHECK(memcmp(a.data, v, gs_io_array_count(&a) * 4) == 0);
        gs_io_array_free(&a);
        free(buf);
    }
}

static void test_header_text(void)
{
    float v[6] = {0};
    size_t shape[2] = {2, 3}, shape1[1] = {6};
    void *buf;
    size_t len;
    const char *want2 = "{'descr': '<f4', 'fortran_order': False, 'shape': (2, 3), }";
    const char *want1 = "{'descr': '|u1', 'fortran_order': False, 'shape': (6,), }";
    CHECK_EQ_INT(gs_io_npy_encode(GS_IO_F32, 2, shape, v, &buf, &len, NULL), GS_OK);
    CHECK(memcmp(buf, "\x93NUMPY\x01\x00\x76\x00", 10) == 0);
    CHECK(memcmp((char *)buf + 10, want2, strlen(want2)) == 0);
    CHECK(((char *)buf)[127] == '\n' && ((char *)buf)[126] == ' ');
    CHECK_EQ_INT(len, 128 + 24);
    free(buf);
    CHECK_EQ_INT(gs_io_npy_encode(GS_IO_U8, 1, shape1, v, &buf, &len, NULL), GS_OK);
    CHECK(memcmp((char *)buf + 10, want1, strlen(want1)) == 0);
    CHECK_EQ_INT(len, 128 + 6);
    free(buf);
}

static void test_file_round_trip(void)
{
    unsigned char px[4 * 5 * 3];
    size_t shape[3] = {4, 5, 3}, zshape[2] = {0, 3};
    gs_io_array a;
    gs_error err = {0};
    for (int i = 0; i < 60; i++)
        px[i] = (unsigned char)(i * 13);
    const char *path = "test_npy_tmp.npy";
    CHECK_EQ_INT(gs_io_npy_write(path, GS_IO_U8, 3, shape, px, &err), GS_OK);
    CHECK_EQ_INT(gs_io_npy_read(path, 0, &a, &err), GS_OK);
    CHECK_EQ_INT(a.dtype, GS_IO_U8);
    CHECK_EQ_INT(a.rank, 3);
    CHECK(a.shape[0] == 4 && a.shape[1] == 5 && a.shape[2] == 3);
    CHECK(memcmp(a.data, px, 60) == 0);
    gs_io_array_free(&a);
    /* The file limit is checked before reading. */
    CHECK_ERR(gs_io_npy_read(path, 59, &a, &err), GS_ERR_LIMIT, err, "limit");
    /* Empty arrays are fine. */
    CHECK_EQ_INT(gs_io_npy_write(path, GS_IO_F32, 2, zshape, NULL, &err), GS_OK);
    CHECK_EQ_INT(gs_io_npy_read(path, 0, &a, &err), GS_OK);
    CHECK(a.rank == 2 && a.shape[0] == 0 && a.shape[1] == 3 && gs_io_array_count(&a) == 0);
    gs_io_array_free(&a);
    remove(path);
    CHECK_ERR(gs_io_npy_read("no/such/file.npy", 0, &a, &err), GS_ERR_IO, err, "cannot open");
    CHECK_ERR(gs_io_npy_write("no/such/dir/x.npy", GS_IO_U8, 3, shape, px, &err), GS_ERR_IO, err,
              "cannot create");
}

static void test_versions(void)
{
    float v[3] = {1.5f, -2.0f, 3.25f};
    for (int major = 1; major <= 3; major++) {
        size_t len;
        gs_io_array a;
        gs_error err = {0};
        unsigned char *b = make_npy(major, "{'shape': (3,), 'fortran_order': False, \"descr\": '<f4'}",
                                    v, sizeof v, &len);
        CHECK_EQ_INT(gs_io_npy_parse(b, len, 0, &a, &err), GS_OK);
        CHECK(a.rank == 1 && a.shape[0] == 3 && memcmp(a.data, v, sizeof v) == 0);
        gs_io_array_free(&a);
        free(b);
    }
}

static void test_bad_headers(void)
{
    static const struct {
        const char *dict;
        size_t dlen;
        int code;
        const char *msg;
    } cases[] = {
        {"{'descr': '<f4', 'fortran_order': False, 'shape': (2, 3), }", 24, GS_OK, NULL},
        {"{'descr': '<f8', 'fortran_order': False, 'shape': (3,), }", 24, GS_ERR_UNSUPPORTED, "'<f8'"},
        {"{'descr': '>f4', 'fortran_order': False, 'shape': (3,), }", 12, GS_ERR_UNSUPPORTED, "'>f4'"},
        {"{'descr': '<i4', 'fortran_order': False, 'shape': (3,), }", 12, GS_ERR_UNSUPPORTED, "dtype"},
        {"{'descr': '<f4', 'fortran_order': True, 'shape': (3,), }", 12, GS_ERR_UNSUPPORTED, "Fortran"},
        {"{'descr': '<f4', 'fortran_order': 0, 'shape': (3,), }", 12, GS_ERR_FORMAT, "bool"},
        {"{'descr': '<f4', 'fortran_order': False, 'shape': (1, 1, 1, 1, 3), }", 12,
         GS_ERR_UNSUPPORTED, "rank"},
        {"{'descr': '<f4', 'fortran_order': False, 'shape': (3,), }", 11, GS_ERR_FORMAT, "file has 11"},
        {"{'descr': '<f4', 'fortran_order': False, 'shape': (3,), }", 13, GS_ERR_FORMAT, "file has 13"},
        {"{'descr': '<f4', 'fortran_order': False, 'shape': (3), }", 12, GS_ERR_FORMAT, "comma"},
        {"{'descr': '<f4', 'fortran_order': False, 'shape': (-3,), }", 12, GS_ERR_FORMAT, "dimension"},
        {"{'descr': '<f4', 'fortran_order': False, 'shape': (3,,), }", 12, GS_ERR_FORMAT, "dimension"},
        {"{'descr': '<f4', 'fortran_order': False, 'shape': [3], }", 12, GS_ERR_FORMAT, "tuple"},
        {"{'descr': '<f4', 'fortran_order': False, 'shape': (99999999999999999999,), }", 12,
         GS_ERR_FORMAT, "dimension"},
        {"{'descr': '<f4', 'fortran_order': False, 'shape': (4294967296, 4294967296, 16), }", 12,
         GS_ERR_FORMAT, "overflow"},
        {"{'descr': '<f4', 'fortran_order': False}", 12, GS_ERR_FORMAT, "lacks 'shape'"},
        {"{'descr': '<f4', 'shape': (3,)}", 12, GS_ERR_FORMAT, "lacks 'fortran_order'"},
        {"{'descr': '<f4', 'descr': '<f4', 'fortran_order': False, 'shape': (3,)}", 12,
         GS_ERR_FORMAT, "twice"},
        {"{'descr': '<f4', 'fortran_order': False, 'shape': (3,), 'x': 1}", 12, GS_ERR_FORMAT,
         "unknown header key"},
        {"{'descr': '<f4', 'fortran_order': False, 'shape': (3,)} junk", 12, GS_ERR_FORMAT, "junk"},
        {"['descr']", 12, GS_ERR_FORMAT, "dictionary"},
        {"{'descr': '<f4' 'fortran_order': False, 'shape': (3,)}", 12, GS_ERR_FORMAT, "dictionary"},
        {"{'descr': '<f\\4', 'fortran_order': False, 'shape': (3,)}", 12, GS_ERR_FORMAT, "descr"},
        {"{'descr: '<f4', 'fortran_order': False, 'shape': (3,)}", 12, GS_ERR_FORMAT, NULL},
        {"", 12, GS_ERR_FORMAT, "dictionary"},
    };
    for (size_t i = 0; i < sizeof cases / sizeof cases[0]; i++) {
        gs_io_array a;
        gs_error err = {0};
        int rc = parse_dict(cases[i].dict, cases[i].dlen, 0, &a, &err);
        CHECK_MSG(rc == cases[i].code, "case %zu '%s': rc %d (%s), want %d", i, cases[i].dict, rc,
                  err.msg, cases[i].code);
        if (cases[i].msg)
            CHECK_MSG(strstr(err.msg, cases[i].msg) != NULL, "case %zu: message '%s' lacks '%s'", i,
                      err.msg, cases[i].msg);
        if (rc == GS_OK)
            gs_io_array_free(&a);
    }
}

static void test_prefix_and_limits(void)
{
    gs_io_array a;
    gs_error err = {0};
    float v[6] = {0};
    size_t shape[2] = {2, 3}, len;
    void *buf;
    CHECK_EQ_INT(gs_io_npy_encode(GS_IO_F32, 2, shape, v, &buf, &len, NULL), GS_OK);
    unsigned char *b = buf;
    /* Every proper prefix is refused as malformed. */
    for (size_t n = 0; n < len; n++) {
        int rc = gs_io_npy_parse(b, n, 0, &a, &err);
        CHECK_MSG(rc == GS_ERR_FORMAT, "prefix %zu: rc %d (%s)", n, rc, err.msg);
    }
    CHECK_ERR(gs_io_npy_parse(b, len, 23, &a, &err), GS_ERR_LIMIT, err, "24 data bytes");
    b[0] = 'X';
    CHECK_ERR(gs_io_npy_parse(b, len, 0, &a, &err), GS_ERR_FORMAT, err, "magic");
    b[0] = 0x93;
    b[6] = 4;
    CHECK_ERR(gs_io_npy_parse(b, len, 0, &a, &err), GS_ERR_UNSUPPORTED, err, "version 4.0");
    b[6] = 2; /* now bytes 8..11 read as a u32 header length: 0x20200076 */
    CHECK_ERR(gs_io_npy_parse(b, len, 0, &a, &err), GS_ERR_LIMIT, err, "header of");
    b[6] = 1;
    b[8] = 0xff; /* header length past the end */
    CHECK_ERR(gs_io_npy_parse(b, len, 0, &a, &err), GS_ERR_FORMAT, err, "truncated header");
    b[8] = 0x76;
    b[127] = ' '; /* no newline at the end of the header */
    CHECK_ERR(gs_io_npy_parse(b, len, 0, &a, &err), GS_ERR_FORMAT, err, "newline");
    free(buf);
    /* Argument checks of the writer. */
    size_t big[2] = {SIZE_MAX / 2, 3};
    CHECK_ERR(gs_io_npy_encode(GS_IO_F32, 5, shape, v, &buf, &len, &err), GS_ERR_ARG, err, "rank");
    CHECK_ERR(gs_io_npy_encode((gs_io_dtype)7, 2, shape, v, &buf, &len, &err), GS_ERR_ARG, err,
              "dtype");
    CHECK_ERR(gs_io_npy_encode(GS_IO_F32, 2, big, v, &buf, &len, &err), GS_ERR_LIMIT, err, "large");
    CHECK_ERR(gs_io_npy_encode(GS_IO_F32, 2, shape, NULL, &buf, &len, &err), GS_ERR_ARG, err,
              "NULL");
}

int main(void)
{
    test_round_trip_ranks();
    test_header_text();
    test_file_round_trip();
    test_versions();
    test_bad_headers();
    test_prefix_and_limits();
    GS_TEST_END();
}
