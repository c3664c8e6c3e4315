/* PNG through libpng (png.h).
 *
 * libpng reports errors through our error callback, which records the
 * message and longjmps to png_jmpbuf; as in jpeg_codec.c, what must be
 * freed after the jump lives in a heap context. Warnings (a damaged
 * ancillary chunk, which libpng skips) are not printed.
 *
 * Decoding asks libpng for 8-bit RGB whatever the file holds: palette and
 * grey expanded, 16-bit samples reduced to their high byte
 * (png_set_strip_16), alpha and tRNS dropped without compositing,
 * interlaced files de-interlaced; the transforms OpenCV's imread applied,
 * so pixels are unchanged from the OpenCV days. The EXIF orientation of an
 * eXIf chunk (before or after the image data) is applied, as OpenCV 4.6
 * did. */
#include <setjmp.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <png.h>

#include "image_codec.h"

typedef struct png_ctx {
    png_structp png;
    png_infop info;
    char msg[200];
    int nomem;
    /* decode: the input and the read position */
    const unsigned char *in;
    size_t in_len, in_pos;
    unsigned char *pix;
    png_bytep *rows;
    int orientation;
    /* encode: the output, grown by doubling */
    unsigned char *out;
    size_t out_cap, out_len;
} png_ctx;

static void on_png_error(png_structp png, png_const_charp msg)
{
    png_ctx *c = png_get_error_ptr(png);
    snprintf(c->msg, sizeof c->msg, "%s", msg);
    png_longjmp(png, 1);
}

static void on_png_warning(png_structp png, png_const_charp msg)
{
    (void)png;
    (void)msg;
}

/* ---- decode ------------------------------------------------------------- */

static void read_mem(png_structp png, png_bytep dst, size_t n)
{
    png_ctx *c = png_get_io_ptr(png);
    if (c->in_len - c->in_pos < n)
        png_error(png, "truncated data");
    memcpy(dst, c->in + c->in_pos, n);
    c->in_pos += n;
}

static int png_decode_run(png_ctx *c, size_t max_pixels, int max_side, gs_error *err)
{
    png_structp png = c->png;
    png_infop info = c->info;
    png_set_user_limits(png, (png_uint_32)max_side, (png_uint_32)max_side);
    png_set_read_fn(png, c, read_mem);
    png_read_info(png, info);
    const size_t w = png_get_image_width(png, info), h = png_get_image_height(png, info);
    if (w * h > max_pixels)
        return gs_error_set(err, GS_ERR_LIMIT, "png: %zux%zu over the limits", w, h);
    const int depth = png_get_bit_depth(png, info), ctype = png_get_color_type(png, info);
    if (depth == 16)
        png_set_strip_16(png);
    png_set_strip_alpha(png);
    if (ctype == PNG_COLOR_TYPE_PALETTE)
        png_set_palette_to_rgb(png);
    if (!(ctype & PNG_COLOR_MASK_COLOR)) {
        if (depth < 8)
            png_set_expand_gray_1_2_4_to_8(png);
        png_set_gray_to_rgb(png);
    }
    png_set_interlace_handling(png);
    png_read_update_info(png, info);
    if (png_get_rowbytes(png, info) != w * 3 || png_get_channels(png, info) != 3)
        return gs_error_set(err, GS_ERR_UNSUPPORTED, "png: colour type %d depth %d", ctype,
                            depth);
    c->pix = malloc(w * h * 3);
    c->rows = malloc(h * sizeof *c->rows);
    if (!c->pix || !c->rows)
        return gs_error_set(err, GS_ERR_NOMEM, "png: cannot allocate %zux%zu", w, h);
    for (size_t y = 0; y < h; y++)
        c->rows[y] = c->pix + y * w * 3;
    png_read_image(png, c->rows);
    png_read_end(png, info);
    c->orientation = 1;
#ifdef PNG_eXIf_SUPPORTED
    png_bytep exif = NULL;
    png_uint_32 exif_len = 0;
    if (png_get_eXIf_1(png, info, &exif_len, &exif) && exif)
        c->orientation = gs_exif_tiff_orientation(exif, exif_len);
#endif
    return GS_OK;
}

int gs_png_decode(const unsigned char *buf, size_t len, size_t max_pixels, int max_side,
                  gs_io_image *out, gs_error *err)
{
    png_ctx *c = calloc(1, sizeof *c);
    if (!c)
        return gs_error_set(err, GS_ERR_NOMEM, "png: cannot allocate a decoder");
    int rc;
    c->in = buf;
    c->in_len = len;
    c->png = png_create_read_struct(PNG_LIBPNG_VER_STRING, c, on_png_error, on_png_warning);
    c->info = c->png ? png_create_info_struct(c->png) : NULL;
    if (!c->info) {
        rc = gs_error_set(err, GS_ERR_NOMEM, "png: cannot allocate a decoder");
    } else if (setjmp(png_jmpbuf(c->png))) {
        rc = gs_error_set(err, GS_ERR_FORMAT, "png: corrupt data: %s", c->msg);
    } else {
        rc = png_decode_run(c, max_pixels, max_side, err);
    }
    if (rc == GS_OK) {
        gs_io_image img = {(int)png_get_image_width(c->png, c->info),
                           (int)png_get_image_height(c->png, c->info), 0, c->pix};
        img.stride = (size_t)img.width * 3;
        rc = gs_image_orient(&img, c->orientation, err);
        c->pix = img.data; /* freed below unless handed out */
        if (rc == GS_OK) {
            *out = img;
            c->pix = NULL;
        }
    }
    png_destroy_read_struct(c->png ? &c->png : NULL, c->info ? &c->info : NULL, NULL);
    free(c->pix);
    free(c->rows);
    free(c);
    return rc;
}

/* ---- encode ------------------------------------------------------------- */

static void write_mem(png_structp png, png_bytep src, size_t n)
{
    png_ctx *c = png_get_io_ptr(png);
    if (c->out_cap - c->out_len < n) {
        size_t cap = c->out_cap ? c->out_cap : 65536;
        while (cap - c->out_len < n && cap <= SIZE_MAX / 2)
            cap *= 2;
        unsigned char *nb = cap - c->out_len >= n ? realloc(c->out, cap) : NULL;
        if (!nb) {
            c->nomem = 1;
            png_error(png, "out of memory");
        }
        c->out = nb;
        c->out_cap = cap;
    }
    memcpy(c->out + c->out_len, src, n);
    c->out_len += n;
}

static void flush_mem(png_structp png)
{
    (void)png;
}

/* 8-bit RGB, not interlaced, libpng's adaptive filters, zlib's default
 * strategy at the given level: what OpenCV's imencode wrote for
 * IMWRITE_PNG_COMPRESSION. */
static void png_encode_run(png_ctx *c, const gs_io_image *img, int level)
{
    png_set_write_fn(c->png, c, write_mem, flush_mem);
    png_set_compression_level(c->png, level);
    png_set_IHDR(c->png, c->info, (png_uint_32)img->width, (png_uint_32)img->height, 8,
                 PNG_COLOR_TYPE_RGB, PNG_INTERLACE_NONE, PNG_COMPRESSION_TYPE_DEFAULT,
                 PNG_FILTER_TYPE_DEFAULT);
    png_write_info(c->png, c->info);
    for (int y = 0; y < img->height; y++)
        png_write_row(c->png, img->data + (size_t)y * img->stride);
    png_write_end(c->png, c->info);
}

int gs_png_encode(const gs_io_image *img, int level, unsigned char **out, size_t *out_len,
                  gs_error *err)
{
    png_ctx *c = calloc(1, sizeof *c);
    if (!c)
        return gs_error_set(err, GS_ERR_NOMEM, "png: cannot allocate an encoder");
    int rc = GS_OK;
    c->png = png_create_write_struct(PNG_LIBPNG_VER_STRING, c, on_png_error, on_png_warning);
    c->info = c->png ? png_create_info_struct(c->png) : NULL;
    if (!c->info)
        rc = gs_error_set(err, GS_ERR_NOMEM, "png: cannot allocate an encoder");
    else if (setjmp(png_jmpbuf(c->png)))
        rc = gs_error_set(err, c->nomem ? GS_ERR_NOMEM : GS_ERR_ARG, "png: encoder failed: %s",
                          c->msg);
    else
        png_encode_run(c, img, level);
    png_destroy_write_struct(c->png ? &c->png : NULL, c->info ? &c->info : NULL);
    if (rc == GS_OK) {
        *out = c->out;
        *out_len = c->out_len;
    } else {
        free(c->out);
    }
    free(c);
    return rc;
}
