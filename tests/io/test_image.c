/* PNG/JPEG through gs_io: exact PNG round trips, JPEG quality, the channel
 * order and colour conversions on hand-made PNGs, and every structural
 * damage, truncation and limit refused before decoding. */
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "gazesplat/image_io.h"
#include "gs_test.h"

#define CHECK_ERR(rc, code, err, want)                                        \
    do {                                                                      \
        CHECK_EQ_INT(rc, code);                                               \
        CHECK_MSG(strstr((err).msg, (want)) != NULL, "message '%s' lacks '%s'", \
                  (err).msg, (want));                                         \
    } while (0)

/* ---- a minimal PNG writer (stored deflate blocks) for exact inputs ------ */

static uint32_t crc32_of(const unsigned char *p, size_t n)
{
    uint32_t c = 0xffffffffu;
    for (size_t i = 0; i < n; i++) {
        c ^= p[i];
        for (int k = 0; k < 8; k++)
            c = (c >> 1) ^ (0xedb88320u & (0u - (c & 1u)));
    }
    return c ^ 0xffffffffu;
}

static void put_be32(unsigned char *p, uint32_t v)
{
    p[0] = (unsigned char)(v >> 24);
    p[1] = (unsigned char)(v >> 16);
    p[2] = (unsigned char)(v >> 8);
    p[3] = (unsigned char)v;
}

typedef struct bytes {
    unsigned char *p;
    size_t n;
} bytes;

static void append(bytes *b, const void *src, size_t n)
{
    b->p = realloc(b->p, b->n + n);
    if (n)
        memcpy(b->p + b->n, src, n);
    b->n += n;
}

static void chunk(bytes *b, const char *type, const unsigned char *data, size_t n)
{
    unsigned char head[8], crc[4];
    unsigned char *t = malloc(n + 4);
    put_be32(head, (uint32_t)n);
    memcpy(head + 4, type, 4);
    memcpy(t, type, 4);
    if (n)
        memcpy(t + 4, data, n);
    put_be32(crc, crc32_of(t, n + 4));
    append(b, head, 8);
    append(b, data, n);
    append(b, crc, 4);
    free(t);
}

/* rows: h rows of rowlen bytes (no filter byte). */
static bytes make_png(int w, int h, int depth, int ctype, const unsigned char *rows,
                      size_t rowlen, const unsigned char *plte, size_t plte_len)
{
    static const unsigned char sig[8] = {0x89, 'P', 'N', 'G', '\r', '\n', 0x1a, '\n'};
    bytes b = {0}, raw = {0}, z = {0};
    unsigned char ihdr[13] = {0};
    put_be32(ihdr, (uint32_t)w);
    put_be32(ihdr + 4, (uint32_t)h);
    ihdr[8] = (unsigned char)depth;
    ihdr[9] = (unsigned char)ctype;
    append(&b, sig, 8);
    chunk(&b, "IHDR", ihdr, 13);
    if (plte)
        chunk(&b, "PLTE", plte, plte_len);
    for (int y = 0; y < h; y++) {
        unsigned char f = 0;
        append(&raw, &f, 1);
        append(&raw, rows + (size_t)y * rowlen, rowlen);
    }
    unsigned char zh[2] = {0x78, 0x01}, blk[5];
    uint32_t a = 1, bsum = 0;
    for (size_t i = 0; i < raw.n; i++) {
        a = (a + raw.p[i]) % 65521;
        bsum = (bsum + a) % 65521;
    }
    append(&z, zh, 2);
    blk[0] = 1; /* final stored block (raw.n < 65536 here) */
    blk[1] = (unsigned char)raw.n;
    blk[2] = (unsigned char)(raw.n >> 8);
    blk[3] = (unsigned char)~blk[1];
    blk[4] = (unsigned char)~blk[2];
    append(&z, blk, 5);
    append(&z, raw.p, raw.n);
    unsigned char ad[4];
    put_be32(ad, bsum << 16 | a);
    append(&z, ad, 4);
    chunk(&b, "IDAT", z.p, z.n);
    chunk(&b, "IEND", NULL, 0);
    free(raw.p);
    free(z.p);
    return b;
}

static int decode(const bytes *b, gs_io_image *img, gs_error *err)
{
    return gs_io_image_decode(b->p, b->n, NULL, img, err);
}

static void check_pixel(const gs_io_image *img, int x, int y, int r, int g, int bl, int tol)
{
    const unsigned char *p = img->data + (size_t)y * img->stride + 3 * (size_t)x;
    CHECK_MSG(abs(p[0] - r) <= tol && abs(p[1] - g) <= tol && abs(p[2] - bl) <= tol,
              "pixel (%d,%d) = (%d,%d,%d), want (%d,%d,%d) +- %d", x, y, p[0], p[1], p[2], r, g,
              bl, tol);
}

static void test_handmade_pngs(void)
{
    gs_io_image img;
    gs_error err = {0};
    /* RGB: the channel order at the API is R, G, B. */
    unsigned char rgb[2 * 6] = {255, 0, 0, 0, 255, 0, 0, 0, 255, 10, 20, 30};
    bytes b = make_png(2, 2, 8, 2, rgb, 6, NULL, 0);
    CHECK_EQ_INT(decode(&b, &img, &err), GS_OK);
    CHECK(img.width == 2 && img.height == 2 && img.stride == 6);
    check_pixel(&img, 0, 0, 255, 0, 0, 0);
    check_pixel(&img, 1, 0, 0, 255, 0, 0);
    check_pixel(&img, 0, 1, 0, 0, 255, 0);
    check_pixel(&img, 1, 1, 10, 20, 30, 0);
    gs_io_image_free(&img);
    /* Bytes after IEND are ignored. */
    append(&b, "junk", 4);
    CHECK_EQ_INT(decode(&b, &img, &err), GS_OK);
    gs_io_image_free(&img);
    free(b.p);
    /* Grey, grey + alpha, RGBA: replicated, alpha dropped. */
    unsigned char grey[3] = {0, 128, 255}, ga[6] = {7, 0, 200, 255, 99, 128};
    unsigned char rgba[8] = {1, 2, 3, 0, 250, 251, 252, 255};
    b = make_png(3, 1, 8, 0, grey, 3, NULL, 0);
    CHECK_EQ_INT(decode(&b, &img, &err), GS_OK);
    check_pixel(&img, 1, 0, 128, 128, 128, 0);
    check_pixel(&img, 2, 0, 255, 255, 255, 0);
    gs_io_image_free(&img);
    free(b.p);
    b = make_png(3, 1, 8, 4, ga, 6, NULL, 0);
    CHECK_EQ_INT(decode(&b, &img, &err), GS_OK);
    check_pixel(&img, 0, 0, 7, 7, 7, 0);
    check_pixel(&img, 1, 0, 200, 200, 200, 0);
    gs_io_image_free(&img);
    free(b.p);
    b = make_png(2, 1, 8, 6, rgba, 8, NULL, 0);
    CHECK_EQ_INT(decode(&b, &img, &err), GS_OK);
    check_pixel(&img, 0, 0, 1, 2, 3, 0);
    check_pixel(&img, 1, 0, 250, 251, 252, 0);
    gs_io_image_free(&img);
    free(b.p);
    /* 16-bit RGB keeps the high byte (+-1 for rounding). */
    unsigned char rgb16[6] = {0xab, 0x10, 0x12, 0x34, 0xff, 0xff};
    b = make_png(1, 1, 16, 2, rgb16, 6, NULL, 0);
    CHECK_EQ_INT(decode(&b, &img, &err), GS_OK);
    check_pixel(&img, 0, 0, 0xab, 0x12, 0xff, 1);
    gs_io_image_free(&img);
    free(b.p);
    /* Palette. */
    unsigned char plte[6] = {9, 8, 7, 100, 150, 200}, idx[2] = {1, 0};
    b = make_png(2, 1, 8, 3, idx, 2, plte, 6);
    CHECK_EQ_INT(decode(&b, &img, &err), GS_OK);
    check_pixel(&img, 0, 0, 100, 150, 200, 0);
    check_pixel(&img, 1, 0, 9, 8, 7, 0);
    gs_io_image_free(&img);
    free(b.p);
}

/* A smooth test picture with a padded stride. */
static gs_io_image make_picture(int w, int h, size_t pad)
{
    gs_io_image img = {w, h, (size_t)w * 3 + pad, NULL};
    img.data = malloc(img.stride * (size_t)h);
    memset(img.data, 0xee, img.stride * (size_t)h);
    for (int y = 0; y < h; y++) {
        unsigned char *row = img.data + (size_t)y * img.stride;
        for (int x = 0; x < w; x++) {
            row[3 * x + 0] = (unsigned char)(20 + 200 * x / w);
            row[3 * x + 1] = (unsigned char)(20 + 200 * y / h);
            row[3 * x + 2] = (unsigned char)(80 + 100 * (x + y) / (w + h));
        }
    }
    return img;
}

static double psnr(const gs_io_image *a, const gs_io_image *b)
{
    double se = 0;
    for (int y = 0; y < a->height; y++)
        for (int x = 0; x < 3 * a->width; x++) {
            double d = a->data[(size_t)y * a->stride + (size_t)x] - b->data[(size_t)y * b->stride + (size_t)x];
            se += d * d;
        }
    se /= 3.0 * a->width * a->height;
    return se == 0 ? 99.0 : 10 * log10(255.0 * 255.0 / se);
}

static void test_round_trips(void)
{
    static const int sizes[][2] = {{1, 1}, {7, 3}, {64, 48}, {33, 17}};
    for (size_t i = 0; i < sizeof sizes / sizeof sizes[0]; i++) {
        gs_io_image src = make_picture(sizes[i][0], sizes[i][1], 5), got;
        void *buf;
        size_t len;
        gs_error err = {0};
        CHECK_EQ_INT(gs_io_image_encode(&src, GS_IO_PNG, 0, &buf, &len, &err), GS_OK);
        CHECK_EQ_INT(gs_io_format_sniff(buf, len), GS_IO_PNG);
        CHECK_EQ_INT(gs_io_image_decode(buf, len, NULL, &got, &err), GS_OK);
        CHECK(got.width == src.width && got.height == src.height);
        CHECK_MSG(psnr(&src, &got) == 99.0, "png %dx%d not exact", src.width, src.height);
        gs_io_image_free(&got);
        free(buf);
        CHECK_EQ_INT(gs_io_image_encode(&src, GS_IO_JPEG, 95, &buf, &len, &err), GS_OK);
        CHECK_EQ_INT(gs_io_format_sniff(buf, len), GS_IO_JPEG);
        CHECK_EQ_INT(gs_io_image_decode(buf, len, NULL, &got, &err), GS_OK);
        CHECK(got.width == src.width && got.height == src.height);
        /* Tiny images lose more to 4:2:0 chroma subsampling at the edges. */
        double p = psnr(&src, &got), need = src.width >= 16 ? 30.0 : 20.0;
        CHECK_MSG(p > need, "jpeg %dx%d: PSNR %.1f dB <= %.0f", src.width, src.height, p, need);
        gs_io_image_free(&got);
        free(buf);
        free(src.data);
    }
}

static void test_files(void)
{
    gs_io_image src = make_picture(40, 30, 0), got;
    gs_error err = {0};
    gs_io_image_limits lim = gs_io_image_limits_default();
    const char *path = "test_image_tmp.png";
    CHECK_EQ_INT(gs_io_image_write(path, &src, GS_IO_PNG, 9, &err), GS_OK);
    CHECK_EQ_INT(gs_io_image_read(path, NULL, &got, &err), GS_OK);
    CHECK(psnr(&src, &got) == 99.0);
    gs_io_image_free(&got);
    lim.max_bytes = 10;
    CHECK_ERR(gs_io_image_read(path, &lim, &got, &err), GS_ERR_LIMIT, err, "over the limit");
    remove(path);
    CHECK_ERR(gs_io_image_read(path, NULL, &got, &err), GS_ERR_IO, err, "cannot open");
    CHECK_ERR(gs_io_image_read(".", NULL, &got, &err), GS_ERR_IO, err, "regular file");
    CHECK_ERR(gs_io_image_write("no/such/dir/x.png", &src, GS_IO_PNG, 0, &err), GS_ERR_IO, err,
              "cannot create");
    CHECK_EQ_INT(gs_io_format_from_path("a/b.PNG"), GS_IO_PNG);
    CHECK_EQ_INT(gs_io_format_from_path("x.jpeg"), GS_IO_JPEG);
    CHECK_EQ_INT(gs_io_format_from_path("x.Jpg"), GS_IO_JPEG);
    CHECK_EQ_INT(gs_io_format_from_path("x.npy"), 0);
    CHECK_EQ_INT(gs_io_format_from_path("png"), 0);
    /* Encoder arguments. */
    void *buf;
    size_t len;
    gs_io_image bad = src;
    bad.stride = 3 * 40 - 1;
    CHECK_ERR(gs_io_image_encode(&bad, GS_IO_PNG, 0, &buf, &len, &err), GS_ERR_ARG, err, "stride");
    bad = src;
    bad.width = 0;
    CHECK_ERR(gs_io_image_encode(&bad, GS_IO_PNG, 0, &buf, &len, &err), GS_ERR_ARG, err, "size");
    CHECK_ERR(gs_io_image_encode(&src, GS_IO_JPEG, 101, &buf, &len, &err), GS_ERR_ARG, err,
              "quality");
    CHECK_ERR(gs_io_image_encode(&src, GS_IO_PNG, 10, &buf, &len, &err), GS_ERR_ARG, err, "level");
    CHECK_ERR(gs_io_image_encode(&src, (gs_io_format)3, 0, &buf, &len, &err), GS_ERR_ARG, err,
              "format");
    free(src.data);
}

static bytes encoded(gs_io_format fmt, int w, int h)
{
    gs_io_image src = make_picture(w, h, 0);
    bytes b = {0};
    void *buf;
    CHECK_EQ_INT(gs_io_image_encode(&src, fmt, 0, &buf, &b.n, NULL), GS_OK);
    b.p = buf;
    free(src.data);
    return b;
}

static void test_png_damage(void)
{
    gs_io_image img;
    gs_error err = {0};
    bytes b = encoded(GS_IO_PNG, 100, 80);
    gs_io_image_limits lim = gs_io_image_limits_default();
    /* Every truncation is refused before decoding. */
    for (size_t n = 0; n < b.n; n++) {
        int rc = gs_io_image_decode(b.p, n, NULL, &img, &err);
        CHECK_MSG(rc == (n < 8 ? GS_ERR_UNSUPPORTED : GS_ERR_FORMAT), "prefix %zu: rc %d (%s)", n,
                  rc, err.msg);
    }
    CHECK_ERR(gs_io_image_decode(b.p, b.n - 1, NULL, &img, &err), GS_ERR_FORMAT, err, "truncated");
    /* Limits, from the header alone. */
    lim.max_side = 99;
    CHECK_ERR(gs_io_image_decode(b.p, b.n, &lim, &img, &err), GS_ERR_LIMIT, err, "100x80");
    lim = gs_io_image_limits_default();
    lim.max_pixels = 7999;
    CHECK_ERR(gs_io_image_decode(b.p, b.n, &lim, &img, &err), GS_ERR_LIMIT, err, "7999 pixels");
    lim = gs_io_image_limits_default();
    lim.max_bytes = b.n - 1;
    CHECK_ERR(gs_io_image_decode(b.p, b.n, &lim, &img, &err), GS_ERR_LIMIT, err, "bytes");
    /* A tiny file claiming 100000 x 100000 pixels. */
    unsigned char *p = malloc(b.n);
    memcpy(p, b.p, b.n);
    put_be32(p + 16, 100000);
    put_be32(p + 20, 100000);
    CHECK_ERR(gs_io_image_decode(p, b.n, NULL, &img, &err), GS_ERR_LIMIT, err, "100000x100000");
    put_be32(p + 16, 0);
    CHECK_ERR(gs_io_image_decode(p, b.n, NULL, &img, &err), GS_ERR_FORMAT, err, "bad size");
    memcpy(p, b.p, b.n);
    memcpy(p + 12, "IHDX", 4);
    CHECK_ERR(gs_io_image_decode(p, b.n, NULL, &img, &err), GS_ERR_FORMAT, err, "IHDR");
    memcpy(p, b.p, b.n);
    put_be32(p + 33, 0x80000000u);
    CHECK_ERR(gs_io_image_decode(p, b.n, NULL, &img, &err), GS_ERR_FORMAT, err, "chunk length");
    /* Damaged compressed data: the decoder's own error. */
    memcpy(p, b.p, b.n);
    for (size_t i = 45; i < 60; i++)
        p[i] ^= 0x5a;
    CHECK_ERR(gs_io_image_decode(p, b.n, NULL, &img, &err), GS_ERR_FORMAT, err, "corrupt");
    free(p);
    free(b.p);
    /* IHDR + IEND, no IDAT. */
    bytes e = {0};
    unsigned char ihdr[13] = {0, 0, 0, 1, 0, 0, 0, 1, 8, 2, 0, 0, 0};
    append(&e, "\x89PNG\r\n\x1a\n", 8);
    chunk(&e, "IHDR", ihdr, 13);
    chunk(&e, "IEND", NULL, 0);
    CHECK_ERR(decode(&e, &img, &err), GS_ERR_FORMAT, err, "IDAT");
    free(e.p);
    /* Other formats. */
    CHECK_ERR(gs_io_image_decode("BM\x36\0\0\0\0\0", 8, NULL, &img, &err), GS_ERR_UNSUPPORTED, err,
              "BMP is not supported");
    CHECK_ERR(gs_io_image_decode(NULL, 0, NULL, &img, &err), GS_ERR_UNSUPPORTED, err, "not a PNG");
}

/* Offset of the first marker m in a well-formed JPEG, or 0. */
static size_t find_marker(const bytes *b, unsigned m)
{
    size_t pos = 2;
    while (pos + 4 <= b->n && b->p[pos] == 0xff) {
        if (b->p[pos + 1] == m)
            return pos;
        if (b->p[pos + 1] == 0xda)
            return 0;
        pos += 2 + ((size_t)b->p[pos + 2] << 8 | b->p[pos + 3]);
    }
    return 0;
}

static void test_jpeg_damage(void)
{
    gs_io_image img;
    gs_error err = {0};
    bytes b = encoded(GS_IO_JPEG, 64, 48);
    size_t sof = find_marker(&b, 0xc0), sos = find_marker(&b, 0xda);
    CHECK(sof > 0 && b.p[b.n - 2] == 0xff && b.p[b.n - 1] == 0xd9);
    /* Every truncation (no EOI) is refused before decoding. */
    for (size_t n = 0; n < b.n; n++) {
        int rc = gs_io_image_decode(b.p, n, NULL, &img, &err);
        CHECK_MSG(rc == (n < 3 ? GS_ERR_UNSUPPORTED : GS_ERR_FORMAT), "prefix %zu: rc %d (%s)", n,
                  rc, err.msg);
    }
    CHECK_ERR(gs_io_image_decode(b.p, b.n - 2, NULL, &img, &err), GS_ERR_FORMAT, err, "no EOI");
    unsigned char *p = malloc(b.n + 64);
    /* Frame header says 60000 x 60000: refused from the header. */
    memcpy(p, b.p, b.n);
    p[sof + 5] = 0xea, p[sof + 6] = 0x60, p[sof + 7] = 0xea, p[sof + 8] = 0x60;
    CHECK_ERR(gs_io_image_decode(p, b.n, NULL, &img, &err), GS_ERR_LIMIT, err, "60000x60000");
    p[sof + 5] = 0, p[sof + 6] = 0;
    CHECK_ERR(gs_io_image_decode(p, b.n, NULL, &img, &err), GS_ERR_UNSUPPORTED, err, "DNL");
    /* A segment length running past the end. */
    memcpy(p, b.p, b.n);
    p[sof + 2] = 0xff;
    CHECK_ERR(gs_io_image_decode(p, b.n, NULL, &img, &err), GS_ERR_FORMAT, err, "segment");
    /* Garbage between segments. */
    memcpy(p, b.p, b.n);
    p[sof] = 0x12;
    CHECK_ERR(gs_io_image_decode(p, b.n, NULL, &img, &err), GS_ERR_FORMAT, err, "no marker");
    /* Frame header turned into a comment: scan without a frame. */
    memcpy(p, b.p, b.n);
    p[sof + 1] = 0xfe;
    CHECK_ERR(gs_io_image_decode(p, b.n, NULL, &img, &err), GS_ERR_FORMAT, err, "scan before");
    /* Two frame headers. */
    size_t seg = 2 + ((size_t)b.p[sof + 2] << 8 | b.p[sof + 3]);
    memcpy(p, b.p, sos);
    memcpy(p + sos, b.p + sof, seg);
    memcpy(p + sos + seg, b.p + sos, b.n - sos);
    CHECK_ERR(gs_io_image_decode(p, b.n + seg, NULL, &img, &err), GS_ERR_FORMAT, err, "two frame");
    /* Thousands of scans (a decoder CPU bomb) are refused. */
    size_t sos_len = 2 + ((size_t)b.p[sos + 2] << 8 | b.p[sos + 3]);
    unsigned char *q = malloc(b.n + 300 * (sos_len + 1));
    size_t k = sos;
    memcpy(q, b.p, sos);
    for (int i = 0; i < 300; i++, k += sos_len + 1) {
        memcpy(q + k, b.p + sos, sos_len);
        q[k + sos_len] = 0x00; /* one byte of scan data */
    }
    memcpy(q + k, b.p + sos, b.n - sos);
    CHECK_ERR(gs_io_image_decode(q, k + b.n - sos, NULL, &img, &err), GS_ERR_LIMIT, err,
              "more than 256 scans");
    free(q);
    /* EOI right after SOI. */
    CHECK_ERR(gs_io_image_decode("\xff\xd8\xff\xd9", 4, NULL, &img, &err), GS_ERR_FORMAT, err,
              "before any scan");
    free(p);
    free(b.p);
}

int main(void)
{
    test_handmade_pngs();
    test_round_trips();
    test_files();
    test_png_damage();
    test_jpeg_damage();
    GS_TEST_END();
}
