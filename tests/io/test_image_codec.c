/* The libjpeg/libpng codecs behind gs_io_image_decode, on inputs written
 * here with libjpeg and libpng themselves (exact control of colour space,
 * depth, interlacing, markers): grey, CMYK and YCCK JPEGs, progressive
 * JPEG, EXIF orientations 1..8 in both byte orders, 16-bit, palette,
 * grey+alpha, low-depth and interlaced PNGs, alpha dropped, corrupt data
 * refused with the library's message, JPEG quality semantics, and the EXIF
 * parser on malformed and cut-off segments.
 *
 * usage: test_image_codec [DIR]  (with DIR, also writes every fixture
 * there, e.g. for bench_image compare) */
#include <setjmp.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <jpeglib.h>
#include <png.h>

#include "gazesplat/image_io.h"
#include "gs_test.h"
#include "image_codec.h"

static const char *dump_dir;

typedef struct bytes {
    unsigned char *p;
    size_t n;
} bytes;

static void dump(const char *name, const bytes *b)
{
    if (!dump_dir)
        return;
    char path[1024];
    snprintf(path, sizeof path, "%s/%s", dump_dir, name);
    FILE *f = fopen(path, "wb");
    CHECK_MSG(f != NULL, "cannot create %s", path);
    if (f) {
        CHECK(fwrite(b->p, 1, b->n, f) == b->n);
        fclose(f);
    }
}

/* ---- JPEG writer ---------------------------------------------------------- */

typedef struct jpeg_spec {
    int w, h, comps;           /* input components: 1, 3 or 4 */
    J_COLOR_SPACE in, stored;  /* input space, space in the file */
    int quality, progressive, subsample; /* subsample: 4:2:0 (else 4:4:4) */
    int arith;                           /* arithmetic coding (SOF9) */
    const unsigned char *app1[2];        /* APP1 bodies written in order */
    size_t app1_len[2];
} jpeg_spec;

static bytes write_jpeg(const jpeg_spec *s, const unsigned char *pix)
{
    struct jpeg_compress_struct ci;
    struct jpeg_error_mgr jerr;
    unsigned char *out = NULL;
    unsigned long len = 0;
    ci.err = jpeg_std_error(&jerr);
    jpeg_create_compress(&ci);
    jpeg_mem_dest(&ci, &out, &len);
    ci.image_width = (JDIMENSION)s->w;
    ci.image_height = (JDIMENSION)s->h;
    ci.input_components = s->comps;
    ci.in_color_space = s->in;
    jpeg_set_defaults(&ci);
    jpeg_set_colorspace(&ci, s->stored);
    jpeg_set_quality(&ci, s->quality, TRUE);
    if (!s->subsample)
        for (int c = 0; c < ci.num_components; c++)
            ci.comp_info[c].h_samp_factor = ci.comp_info[c].v_samp_factor = 1;
    if (s->progressive)
        jpeg_simple_progression(&ci);
    ci.arith_code = s->arith ? TRUE : FALSE;
    jpeg_start_compress(&ci, TRUE);
    for (int i = 0; i < 2; i++)
        if (s->app1[i])
            jpeg_write_marker(&ci, JPEG_APP0 + 1, s->app1[i], (unsigned)s->app1_len[i]);
    for (int y = 0; y < s->h; y++) {
        JSAMPROW r = (JSAMPROW)(pix + (size_t)y * (size_t)s->w * (size_t)s->comps);
        jpeg_write_scanlines(&ci, &r, 1);
    }
    jpeg_finish_compress(&ci);
    jpeg_destroy_compress(&ci);
    bytes b = {malloc(len), len};
    memcpy(b.p, out, len);
    free(out);
    return b;
}

/* ---- PNG writer ----------------------------------------------------------- */

typedef struct png_spec {
    int w, h, depth, ctype, interlace;
    const png_color *plte;
    int nplte;
    const unsigned char *trns;
    int ntrns;
    const unsigned char *exif; /* an eXIf chunk (a bare TIFF block) */
    size_t exif_len;
    int exif_after;            /* after the image data instead of before */
} png_spec;

static void png_put(png_structp png, png_bytep src, size_t n)
{
    bytes *b = png_get_io_ptr(png);
    b->p = realloc(b->p, b->n + n);
    memcpy(b->p + b->n, src, n);
    b->n += n;
}

static void png_nop(png_structp png)
{
    (void)png;
}

/* rows: h rows of packed samples, 16-bit ones big-endian as in the file. */
static bytes write_png(const png_spec *s, const unsigned char *rows, size_t rowlen)
{
    bytes b = {0};
    png_structp png = png_create_write_struct(PNG_LIBPNG_VER_STRING, NULL, NULL, NULL);
    png_infop info = png_create_info_struct(png);
    if (setjmp(png_jmpbuf(png))) {
        CHECK_MSG(0, "libpng refused to write a fixture");
        png_destroy_write_struct(&png, &info);
        return b;
    }
    png_set_write_fn(png, &b, png_put, png_nop);
    png_set_IHDR(png, info, (png_uint_32)s->w, (png_uint_32)s->h, s->depth, s->ctype,
                 s->interlace ? PNG_INTERLACE_ADAM7 : PNG_INTERLACE_NONE,
                 PNG_COMPRESSION_TYPE_DEFAULT, PNG_FILTER_TYPE_DEFAULT);
    if (s->plte)
        png_set_PLTE(png, info, s->plte, s->nplte);
    if (s->trns)
        png_set_tRNS(png, info, s->trns, s->ntrns, NULL);
    if (s->exif && !s->exif_after)
        png_set_eXIf_1(png, info, (png_uint_32)s->exif_len, (png_bytep)s->exif);
    png_write_info(png, info);
    if (s->exif && s->exif_after)
        png_set_eXIf_1(png, info, (png_uint_32)s->exif_len, (png_bytep)s->exif);
    int passes = png_set_interlace_handling(png);
    for (int p = 0; p < passes; p++)
        for (int y = 0; y < s->h; y++)
            png_write_row(png, rows + (size_t)y * rowlen);
    png_write_end(png, info);
    png_destroy_write_struct(&png, &info);
    return b;
}

/* ---- helpers -------------------------------------------------------------- */

static int decode(const bytes *b, gs_io_image *img, gs_error *err)
{
    memset(img, 0, sizeof *img);
    return gs_io_image_decode(b->p, b->n, NULL, img, err);
}

static void check_rgb(const char *what, const gs_io_image *img, int x, int y, int r, int g,
                      int bl, int tol)
{
    const unsigned char *p = img->data + (size_t)y * img->stride + 3 * (size_t)x;
    CHECK_MSG(abs(p[0] - r) <= tol && abs(p[1] - g) <= tol && abs(p[2] - bl) <= tol,
              "%s (%d,%d): got %d %d %d, want %d %d %d (tol %d)", what, x, y, p[0], p[1], p[2],
              r, g, bl, tol);
}

#define CHECK_ERR(rc, code, err, want)                                          \
    do {                                                                        \
        CHECK_EQ_INT(rc, code);                                                 \
        CHECK_MSG(strstr((err).msg, (want)) != NULL, "message '%s' lacks '%s'", \
                  (err).msg, (want));                                           \
    } while (0)

/* ---- JPEG colour spaces --------------------------------------------------- */

/* Four flat 16x16 blocks in a row. */
#define NB 4
static const unsigned char block_rgb[NB][3] = {
    {200, 30, 40}, {20, 180, 60}, {30, 50, 220}, {128, 128, 128}};

static void test_jpeg_grey(void)
{
    unsigned char pix[16 * 64];
    for (int y = 0; y < 16; y++)
        for (int x = 0; x < 64; x++)
            pix[y * 64 + x] = (unsigned char)(x < 32 ? 40 : 210);
    jpeg_spec s = {64, 16, 1, JCS_GRAYSCALE, JCS_GRAYSCALE, 100, 0, 0, 0, {NULL, NULL}, {0, 0}};
    bytes b = write_jpeg(&s, pix);
    dump("grey.jpg", &b);
    gs_io_image img;
    gs_error err = {0, ""};
    CHECK_EQ_INT(decode(&b, &img, &err), GS_OK);
    if (img.data) {
        CHECK(img.width == 64 && img.height == 16 && img.stride == 64 * 3);
        check_rgb("grey jpeg", &img, 8, 8, 40, 40, 40, 1);
        check_rgb("grey jpeg", &img, 50, 8, 210, 210, 210, 1);
    }
    gs_io_image_free(&img);
    free(b.p);
}

/* Adobe-inverted CMYK stored as CMYK (Adobe transform 0) or YCCK
 * (transform 2): each block's inverted C, M, Y from its RGB, K' = 255 - K
 * with K = 20 (so the decoder's multiply by K matters). */
static void test_jpeg_cmyk(J_COLOR_SPACE stored, const char *name)
{
    unsigned char pix[16 * 64 * 4];
    const int kinv = 255 - 20;
    for (int y = 0; y < 16; y++)
        for (int x = 0; x < 64; x++) {
            unsigned char *p = pix + 4 * (y * 64 + x);
            const unsigned char *c = block_rgb[x / 16];
            p[0] = c[0]; /* inverted C = R where K is 0 */
            p[1] = c[1];
            p[2] = c[2];
            p[3] = (unsigned char)kinv;
        }
    jpeg_spec s = {64, 16, 4, JCS_CMYK, stored, 100, 0, 0, 0, {NULL, NULL}, {0, 0}};
    bytes b = write_jpeg(&s, pix);
    dump(name, &b);
    gs_io_image img;
    gs_error err = {0, ""};
    CHECK_MSG(decode(&b, &img, &err) == GS_OK, "%s: %s", name, err.msg);
    if (img.data) {
        CHECK(img.width == 64 && img.height == 16);
        for (int i = 0; i < NB; i++) {
            /* R = K' - ((255 - C') K' >> 8), the rounding OpenCV used */
            int want[3];
            for (int c = 0; c < 3; c++)
                want[c] = kinv - ((255 - block_rgb[i][c]) * kinv >> 8);
            check_rgb(name, &img, 16 * i + 8, 8, want[0], want[1], want[2], 3);
        }
    }
    gs_io_image_free(&img);
    free(b.p);
}

static unsigned char *blocks_rgb(int w, int h)
{
    unsigned char *pix = malloc((size_t)w * (size_t)h * 3);
    for (int y = 0; y < h; y++)
        for (int x = 0; x < w; x++)
            memcpy(pix + 3 * ((size_t)y * (size_t)w + (size_t)x), block_rgb[(x / 16) % NB], 3);
    return pix;
}

static void test_jpeg_progressive(void)
{
    unsigned char *pix = blocks_rgb(64, 32);
    jpeg_spec s = {64, 32, 3, JCS_RGB, JCS_YCbCr, 95, 1, 1, 0, {NULL, NULL}, {0, 0}};
    bytes prog = write_jpeg(&s, pix);
    s.progressive = 0;
    bytes base = write_jpeg(&s, pix);
    s.arith = 1;
    bytes arith = write_jpeg(&s, pix);
    s.arith = 0;
    dump("progressive.jpg", &prog);
    dump("arithmetic.jpg", &arith);
    gs_io_image c;
    gs_error aerr = {0, ""};
    CHECK_MSG(decode(&arith, &c, &aerr) == GS_OK, "arithmetic: %s", aerr.msg);
    if (c.data)
        for (int i = 0; i < NB; i++)
            check_rgb("arithmetic", &c, 16 * i + 8, 16, block_rgb[i][0], block_rgb[i][1],
                      block_rgb[i][2], 6);
    gs_io_image_free(&c);
    free(arith.p);
    gs_io_image a, b;
    gs_error err = {0, ""};
    CHECK_MSG(decode(&prog, &a, &err) == GS_OK, "progressive: %s", err.msg);
    CHECK_EQ_INT(decode(&base, &b, &err), GS_OK);
    if (a.data && b.data) {
        int m = 0;
        for (size_t i = 0; i < 64 * 32 * 3; i++)
            m = abs(a.data[i] - b.data[i]) > m ? abs(a.data[i] - b.data[i]) : m;
        CHECK_MSG(m <= 2, "progressive vs baseline: max diff %d", m);
        for (int i = 0; i < NB; i++)
            check_rgb("progressive", &a, 16 * i + 8, 16, block_rgb[i][0], block_rgb[i][1],
                      block_rgb[i][2], 6);
    }
    gs_io_image_free(&a);
    gs_io_image_free(&b);
    free(prog.p);
    free(base.p);
    free(pix);
}

/* ---- EXIF orientation ----------------------------------------------------- */

/* An APP1 body: "Exif\0\0", a TIFF header in the given byte order, IFD0
 * with a Make tag then Orientation (type SHORT, count 1). */
static size_t exif_body(unsigned char *p, int le, int orientation, unsigned type)
{
    unsigned char *t = p + 6;
    memcpy(p, "Exif\0\0", 6);
#define PUT16(q, v) ((q)[le ? 0 : 1] = (unsigned char)(v), (q)[le ? 1 : 0] = (unsigned char)((v) >> 8))
#define PUT32(q, v) (PUT16((q) + (le ? 0 : 2), (v) & 0xffff), PUT16((q) + (le ? 2 : 0), (v) >> 16))
    memcpy(t, le ? "II" : "MM", 2);
    PUT16(t + 2, 42);
    PUT32(t + 4, 8u);
    PUT16(t + 8, 2); /* two entries */
    unsigned char *e = t + 10;
    PUT16(e, 0x010f); /* Make, ASCII, 4 bytes inline: "gs\0\0" */
    PUT16(e + 2, 2);
    PUT32(e + 4, 4u);
    memcpy(e + 8, "gs\0\0", 4);
    e += 12;
    PUT16(e, 0x0112);
    PUT16(e + 2, type);
    PUT32(e + 4, 1u);
    PUT32(e + 8, 0u);
    PUT16(e + 8, orientation);
    PUT32(e + 12, 0u); /* no next IFD */
#undef PUT16
#undef PUT32
    return 6 + 10 + 24 + 4;
}

/* The upright picture: 64x32, quadrants red, green / blue, white. */
static void upright(int ux, int uy, unsigned char *rgb)
{
    static const unsigned char q[4][3] = {{220, 20, 20}, {20, 200, 20}, {20, 20, 220},
                                          {240, 240, 240}};
    memcpy(rgb, q[(uy >= 16) * 2 + (ux >= 32)], 3);
}

/* The stored image for an orientation, from the EXIF definition (which
 * visual side row 0 and column 0 of the stored image are). */
static unsigned char *stored_for(int o, int *sw, int *sh)
{
    const int W = 64, H = 32, swap = o >= 5;
    *sw = swap ? H : W;
    *sh = swap ? W : H;
    unsigned char *pix = malloc((size_t)W * H * 3);
    for (int sy = 0; sy < *sh; sy++)
        for (int sx = 0; sx < *sw; sx++) {
            int ux, uy;
            switch (o) {
            case 1: ux = sx; uy = sy; break;
            case 2: ux = W - 1 - sx; uy = sy; break;
            case 3: ux = W - 1 - sx; uy = H - 1 - sy; break;
            case 4: ux = sx; uy = H - 1 - sy; break;
            case 5: ux = sy; uy = sx; break;
            case 6: ux = W - 1 - sy; uy = sx; break;
            case 7: ux = W - 1 - sy; uy = H - 1 - sx; break;
            default: ux = sy; uy = H - 1 - sx; break;
            }
            upright(ux, uy, pix + 3 * ((size_t)sy * (size_t)*sw + (size_t)sx));
        }
    return pix;
}

/* Orientations 1..8 in both byte orders, an XMP APP1 after the EXIF one
 * on odd orientations; and (le 2) orientation 6 with the XMP APP1 first,
 * where OpenCV, which read only the first APP1, kept the stored image. */
static void test_exif_orientations(void)
{
    for (int le = 0; le <= 2; le++)
        for (int o = le == 2 ? 6 : 1; o <= (le == 2 ? 6 : 8); o++) {
            int sw, sh;
            unsigned char *pix = stored_for(o, &sw, &sh);
            unsigned char app1[64], xmp[40] = "http://ns.adobe.com/xap/1.0/";
            size_t n = exif_body(app1, le & 1, o, 3);
            CHECK_EQ_INT(gs_exif_orientation(app1, n), o);
            const int xmp_first = le == 2;
            jpeg_spec s = {sw, sh, 3, JCS_RGB, JCS_YCbCr, 100, 0, 0, 0,
                           {xmp_first ? xmp : app1, xmp_first || o % 2 ? (xmp_first ? app1 : xmp) : NULL},
                           {xmp_first ? sizeof xmp : n, xmp_first ? n : o % 2 ? sizeof xmp : 0}};
            bytes b = write_jpeg(&s, pix);
            char name[64];
            snprintf(name, sizeof name, "exif_%d_%s.jpg", o,
                     le == 2 ? "after_xmp" : le ? "II" : "MM");
            dump(name, &b);
            gs_io_image img;
            gs_error err = {0, ""};
            CHECK_MSG(decode(&b, &img, &err) == GS_OK, "%s: %s", name, err.msg);
            if (img.data) {
                CHECK_MSG(img.width == 64 && img.height == 32 && img.stride == 64 * 3,
                          "%s: %dx%d", name, img.width, img.height);
                for (int qy = 0; qy < 2; qy++)
                    for (int qx = 0; qx < 2; qx++) {
                        unsigned char want[3];
                        int x = 16 + 32 * qx, y = 8 + 16 * qy;
                        upright(x, y, want);
                        if (img.width == 64 && img.height == 32)
                            check_rgb(name, &img, x, y, want[0], want[1], want[2], 8);
                    }
            }
            gs_io_image_free(&img);
            free(b.p);
            /* The same as a PNG with an eXIf chunk (the TIFF block alone),
             * before the image data in one byte order, after it in the
             * other. */
            if (le < 2) {
                png_spec ps = {sw, sh, 8, PNG_COLOR_TYPE_RGB, 0, NULL, 0, NULL, 0,
                               app1 + 6, n - 6, le};
                CHECK_EQ_INT(gs_exif_tiff_orientation(app1 + 6, n - 6), o);
                bytes pb = write_png(&ps, pix, (size_t)sw * 3);
                snprintf(name, sizeof name, "exif_%d_%s.png", o, le ? "II_after" : "MM");
                dump(name, &pb);
                CHECK_MSG(decode(&pb, &img, &err) == GS_OK, "%s: %s", name, err.msg);
                if (img.data) {
                    unsigned char *want = stored_for(1, &sw, &sh);
                    CHECK_MSG(img.width == 64 && img.height == 32 &&
                                  memcmp(img.data, want, 64 * 32 * 3) == 0,
                              "%s: %dx%d, not the upright picture", name, img.width, img.height);
                    free(want);
                }
                gs_io_image_free(&img);
                free(pb.p);
            }
            free(pix);
        }
}

/* The parser on bad segments: every prefix of a good one (under ASan each
 * is its own exact-size allocation), wrong magic, byte order, magic 42,
 * type, out-of-range values, an IFD offset or entry count past the end. */
static void test_exif_malformed(void)
{
    unsigned char good[64];
    size_t n = exif_body(good, 1, 6, 3);
    for (size_t k = 0; k < n; k++) {
        unsigned char *cut = malloc(k ? k : 1);
        memcpy(cut, good, k);
        int o = gs_exif_orientation(cut, k);
        /* the orientation entry ends 4 bytes before the next-IFD offset */
        CHECK_MSG(o == (k >= n - 4 ? 6 : 1), "prefix of %zu bytes: orientation %d", k, o);
        free(cut);
    }
    CHECK_EQ_INT(gs_exif_orientation(NULL, 0), 1);
    unsigned char b[64];
    memcpy(b, good, n);
    b[0] = 'e';
    CHECK_EQ_INT(gs_exif_orientation(b, n), 1);
    memcpy(b, good, n);
    b[6] = 'X';
    CHECK_EQ_INT(gs_exif_orientation(b, n), 1);
    memcpy(b, good, n);
    b[8] = 43;
    CHECK_EQ_INT(gs_exif_orientation(b, n), 1);
    CHECK_EQ_INT(gs_exif_orientation(b, exif_body(b, 1, 6, 4)), 1); /* LONG */
    CHECK_EQ_INT(gs_exif_orientation(b, exif_body(b, 0, 0, 3)), 1);
    CHECK_EQ_INT(gs_exif_orientation(b, exif_body(b, 0, 9, 3)), 1);
    CHECK_EQ_INT(gs_exif_orientation(b, exif_body(b, 0, 8, 3)), 8);
    memcpy(b, good, n);
    b[10] = 0xff; /* IFD0 offset 0xff...: past the end */
    b[13] = 0xff;
    CHECK_EQ_INT(gs_exif_orientation(b, n), 1);
    memcpy(b, good, n);
    b[6 + 8] = 0xff; /* 65535 entries claimed, two present */
    b[6 + 9] = 0xff;
    CHECK_EQ_INT(gs_exif_orientation(b, n), 6);
    memcpy(b, good, n);
    b[10] = 4; /* IFD0 inside the TIFF header */
    CHECK_EQ_INT(gs_exif_orientation(b, n), 1);
}

/* ---- PNG colour types and depths ------------------------------------------ */

static void png_case(const char *name, const png_spec *s, const unsigned char *rows,
                     size_t rowlen, const unsigned char *want, int want_w)
{
    bytes b = write_png(s, rows, rowlen);
    dump(name, &b);
    gs_io_image img;
    gs_error err = {0, ""};
    CHECK_MSG(decode(&b, &img, &err) == GS_OK, "%s: %s", name, err.msg);
    if (img.data) {
        CHECK_MSG(img.width == want_w && img.height == s->h, "%s: %dx%d", name, img.width,
                  img.height);
        size_t bad = 0, first = 0;
        for (size_t i = 0; i < (size_t)want_w * (size_t)s->h * 3; i++)
            if (img.data[i] != want[i] && !bad++)
                first = i;
        CHECK_MSG(bad == 0, "%s: %zu values differ, first at %zu: got %d want %d", name, bad,
                  first, img.data[first], want[first]);
    }
    gs_io_image_free(&img);
    free(b.p);
}

static void test_png_types(void)
{
    enum { W = 13, H = 11 }; /* odd: every Adam7 pass is partial */
    unsigned char rgb[H][W * 3], rgb16[H][W * 6], rgba[H][W * 4], la[H][W * 2], g16[H][W * 2];
    unsigned char want[H][W * 3], want16[H][W * 3], wantg[H][W * 3];
    for (int y = 0; y < H; y++)
        for (int x = 0; x < W; x++)
            for (int c = 0; c < 3; c++) {
                unsigned v = (unsigned)(x * 19 + y * 7 + c * 60) & 0xff;
                rgb[y][3 * x + c] = want[y][3 * x + c] = (unsigned char)v;
                rgba[y][4 * x + c] = (unsigned char)v;
                rgba[y][4 * x + 3] = (unsigned char)(x * 20); /* alpha 0 at x = 0 */
                /* 16-bit: high byte v, low byte 0xff or 0x80: the high byte stays */
                rgb16[y][6 * x + 2 * c] = (unsigned char)v;
                rgb16[y][6 * x + 2 * c + 1] = (unsigned char)(c ? 0x80 : 0xff);
                want16[y][3 * x + c] = (unsigned char)v;
                la[y][2 * x] = g16[y][2 * x] = wantg[y][3 * x + c] = (unsigned char)(x * 19 + y);
                la[y][2 * x + 1] = (unsigned char)(255 - x);
                g16[y][2 * x + 1] = 0xff;
            }
    for (int il = 0; il <= 1; il++) {
        char name[64];
        png_spec s = {W, H, 8, PNG_COLOR_TYPE_RGB, il, NULL, 0, NULL, 0, NULL, 0, 0};
        snprintf(name, sizeof name, "rgb8%s.png", il ? "_interlaced" : "");
        png_case(name, &s, &rgb[0][0], W * 3, &want[0][0], W);
        s.ctype = PNG_COLOR_TYPE_RGB_ALPHA;
        snprintf(name, sizeof name, "rgba8%s.png", il ? "_interlaced" : "");
        png_case(name, &s, &rgba[0][0], W * 4, &want[0][0], W);
        s.ctype = PNG_COLOR_TYPE_RGB;
        s.depth = 16;
        snprintf(name, sizeof name, "rgb16%s.png", il ? "_interlaced" : "");
        png_case(name, &s, &rgb16[0][0], W * 6, &want16[0][0], W);
        s.ctype = PNG_COLOR_TYPE_GRAY;
        snprintf(name, sizeof name, "grey16%s.png", il ? "_interlaced" : "");
        png_case(name, &s, &g16[0][0], W * 2, &wantg[0][0], W);
        s.ctype = PNG_COLOR_TYPE_GRAY_ALPHA;
        s.depth = 8;
        snprintf(name, sizeof name, "grey_alpha%s.png", il ? "_interlaced" : "");
        png_case(name, &s, &la[0][0], W * 2, &wantg[0][0], W);
    }
    /* Palette with transparency: the palette's colours, tRNS ignored. */
    static const png_color plte[3] = {{10, 20, 30}, {250, 0, 5}, {0, 128, 255}};
    static const unsigned char trns[3] = {0, 128, 255};
    unsigned char idx[H][W], wantp[H][W * 3];
    for (int y = 0; y < H; y++)
        for (int x = 0; x < W; x++) {
            idx[y][x] = (unsigned char)((x + y) % 3);
            memcpy(&wantp[y][3 * x], &plte[idx[y][x]], 3);
        }
    png_spec p = {W, H, 8, PNG_COLOR_TYPE_PALETTE, 0, plte, 3, trns, 3, NULL, 0, 0};
    png_case("palette_trns.png", &p, &idx[0][0], W, &wantp[0][0], W);
    /* Grey at 1, 2 and 4 bits: scaled to 0..255 by bit replication. */
    for (int depth = 1; depth <= 4; depth *= 2) {
        const int per = 8 / depth, maxv = (1 << depth) - 1;
        unsigned char packed[H][W], wl[H][W * 3];
        memset(packed, 0, sizeof packed);
        for (int y = 0; y < H; y++)
            for (int x = 0; x < W; x++) {
                int v = (x + y) & maxv;
                packed[y][x / per] |= (unsigned char)(v << (8 - depth * (x % per + 1)));
                memset(&wl[y][3 * x], v * 255 / maxv, 3);
            }
        char name[64];
        snprintf(name, sizeof name, "grey%d.png", depth);
        png_spec g = {W, H, depth, PNG_COLOR_TYPE_GRAY, depth == 2, NULL, 0, NULL, 0, NULL, 0, 0};
        png_case(name, &g, &packed[0][0], W, &wl[0][0], W);
    }
}

/* ---- damage --------------------------------------------------------------- */

static size_t find_marker(const bytes *b, unsigned m)
{
    for (size_t i = 2; i + 1 < b->n; i++)
        if (b->p[i] == 0xff && b->p[i + 1] == m)
            return i;
    return 0;
}

static void test_corrupt(void)
{
    gs_io_image img;
    gs_error err = {0, ""};
    unsigned char *pix = blocks_rgb(64, 32);
    jpeg_spec s = {64, 32, 3, JCS_RGB, JCS_YCbCr, 90, 0, 1, 0, {NULL, NULL}, {0, 0}};
    bytes j = write_jpeg(&s, pix);
    /* A frame header with 0 components: libjpeg's own error, caught. */
    size_t sof = find_marker(&j, 0xc0);
    CHECK(sof > 0);
    unsigned char *c = malloc(j.n);
    memcpy(c, j.p, j.n);
    c[sof + 9] = 0;
    bytes bad = {c, j.n};
    dump("bad_components.jpg", &bad);
    CHECK_ERR(decode(&bad, &img, &err), GS_ERR_FORMAT, err, "jpeg: corrupt data");
    /* 12-bit samples: well-formed, but not what this libjpeg decodes. */
    memcpy(c, j.p, j.n);
    c[sof + 4] = 12;
    CHECK_ERR(decode(&bad, &img, &err), GS_ERR_UNSUPPORTED, err,
              "jpeg: not supported: Unsupported JPEG data precision 12");
    /* Lossless (SOF3): a process this libjpeg was built without. */
    memcpy(c, j.p, j.n);
    c[sof + 1] = 0xc3;
    CHECK_ERR(decode(&bad, &img, &err), GS_ERR_UNSUPPORTED, err, "jpeg: not supported");
    /* A Huffman table with impossible code counts. */
    memcpy(c, j.p, j.n);
    size_t dht = find_marker(&j, 0xc4);
    CHECK(dht > 0);
    memset(c + dht + 5, 0xff, 16);
    CHECK_ERR(decode(&bad, &img, &err), GS_ERR_FORMAT, err, "jpeg: corrupt data");
    /* Damaged entropy-coded data decodes (libjpeg warns; nothing is
     * printed), as it did before: a known limit. */
    memcpy(c, j.p, j.n);
    size_t sos = find_marker(&j, 0xda);
    for (size_t i = sos + 20; i < sos + 60 && i + 2 < j.n; i++) {
        unsigned v = c[i] ^ 0x3cu; /* no new 0xFF (a marker), no stuffing broken */
        if (c[i] != 0xff && c[i - 1] != 0xff && v != 0xff)
            c[i] = (unsigned char)v;
    }
    int rc = decode(&bad, &img, &err);
    CHECK_MSG(rc == GS_OK, "damaged scan: %s", err.msg);
    gs_io_image_free(&img);
    /* Scan data cut short, EOI kept: also a libjpeg warning, decodes. */
    bytes cut = {malloc(sos + 40), sos + 40};
    memcpy(cut.p, j.p, sos + 38);
    cut.p[sos + 38] = 0xff;
    cut.p[sos + 39] = 0xd9;
    dump("short_scan.jpg", &cut);
    CHECK_EQ_INT(decode(&cut, &img, &err), GS_OK);
    gs_io_image_free(&img);
    free(cut.p);
    free(c);
    free(j.p);
    free(pix);
    /* PNG: a damaged IDAT (libpng checks its CRC). */
    unsigned char rows[4][12] = {{0}};
    png_spec p = {4, 4, 8, PNG_COLOR_TYPE_RGB, 0, NULL, 0, NULL, 0, NULL, 0, 0};
    bytes png = write_png(&p, &rows[0][0], 12);
    size_t idat = 0;
    for (size_t i = 8; i + 4 < png.n; i++)
        if (memcmp(png.p + i, "IDAT", 4) == 0) {
            idat = i;
            break;
        }
    CHECK(idat > 0);
    png.p[idat + 4] ^= 0x40; /* the zlib header, and so the CRC */
    dump("bad_idat.png", &png);
    CHECK_ERR(decode(&png, &img, &err), GS_ERR_FORMAT, err, "png: corrupt data");
    free(png.p);
}

/* ---- encoder -------------------------------------------------------------- */

/* JPEG quality is libjpeg's scale of the standard tables (what cjpeg
 * -quality and OpenCV's IMWRITE_JPEG_QUALITY mean): the first luminance
 * entry, 16 at 50, is 8 at 75, 2 at 95 and 1 at 100. PNG is 8-bit RGB,
 * not interlaced. */
static void test_encoder(void)
{
    unsigned char *pix = blocks_rgb(64, 32);
    gs_io_image img = {64, 32, 64 * 3, pix};
    static const int q[4] = {50, 75, 95, 100}, first[4] = {16, 8, 2, 1};
    for (int i = 0; i < 4; i++) {
        void *out = NULL;
        size_t n = 0;
        CHECK_EQ_INT(gs_io_image_encode(&img, GS_IO_JPEG, q[i], &out, &n, NULL), GS_OK);
        bytes b = {out, n};
        size_t dqt = out ? find_marker(&b, 0xdb) : 0;
        CHECK(dqt > 0 && dqt + 5 < n);
        if (dqt)
            CHECK_MSG(b.p[dqt + 4] == 0 && b.p[dqt + 5] == first[i],
                      "quality %d: table %d, first entry %d, want %d", q[i], b.p[dqt + 4],
                      b.p[dqt + 5], first[i]);
        free(out);
    }
    void *out = NULL;
    size_t n = 0;
    CHECK_EQ_INT(gs_io_image_encode(&img, GS_IO_PNG, 9, &out, &n, NULL), GS_OK);
    if (out) {
        const unsigned char *ihdr = (const unsigned char *)out + 16;
        CHECK(n > 33 && ihdr[8] == 8 && ihdr[9] == 2 && ihdr[12] == 0);
    }
    free(out);
    free(pix);
}

int main(int argc, char **argv)
{
    dump_dir = argc > 1 ? argv[1] : NULL;
    test_jpeg_grey();
    test_jpeg_cmyk(JCS_CMYK, "cmyk.jpg");
    test_jpeg_cmyk(JCS_YCCK, "ycck.jpg");
    test_jpeg_progressive();
    test_exif_orientations();
    test_exif_malformed();
    test_png_types();
    test_corrupt();
    test_encoder();
    GS_TEST_END();
}
