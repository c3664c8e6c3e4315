/* JPEG through libjpeg(-turbo)'s own API (jpeglib.h).
 *
 * libjpeg reports a fatal error through error_exit, which must not return:
 * ours formats the message and longjmps back to the call that started the
 * work. Everything that call must free after the jump lives in a heap
 * context whose address does not change after setjmp, so no local variable
 * is read after a longjmp. Warnings (corrupt entropy data, which libjpeg
 * decodes as grey blocks) are neither fatal nor printed. */
#include <limits.h>
#include <setjmp.h>
#include <stdint.h>
#include <stdio.h> /* jpeglib.h needs FILE; snprintf */
#include <stdlib.h>
#include <string.h>

#include <jpeglib.h>
#include <jerror.h>

#include "image_codec.h"

typedef struct jpeg_err {
    struct jpeg_error_mgr pub;
    jmp_buf jump;
    char msg[JMSG_LENGTH_MAX];
    int code; /* libjpeg's message code (J_MESSAGE_CODE) */
} jpeg_err;

static void on_error_exit(j_common_ptr c)
{
    jpeg_err *e = (jpeg_err *)c->err;
    (*c->err->format_message)(c, e->msg);
    e->code = c->err->msg_code;
    longjmp(e->jump, 1);
}

static void on_output_message(j_common_ptr c)
{
    (void)c; /* the library prints nothing */
}

/* A well-formed file this libjpeg does not decode (12-bit samples, an
 * odd component layout) rather than a damaged one. */
static int jpeg_err_unsupported(const jpeg_err *e)
{
    return e->code == JERR_BAD_PRECISION || e->code == JERR_CONVERSION_NOTIMPL ||
           e->code == JERR_NOT_COMPILED || e->code == JERR_BAD_J_COLORSPACE ||
           e->code == JERR_SOF_UNSUPPORTED;
}

static void jpeg_err_init(jpeg_err *e)
{
    jpeg_std_error(&e->pub);
    e->pub.error_exit = on_error_exit;
    e->pub.output_message = on_output_message;
    e->msg[0] = '\0';
}

/* ---- decode ------------------------------------------------------------- */

typedef struct jpeg_dec {
    struct jpeg_decompress_struct cinfo;
    jpeg_err jerr;
    unsigned char *pix; /* the RGB result */
    unsigned char *row; /* one CMYK scanline */
    int orientation;
} jpeg_dec;

/* Adobe-inverted CMYK (what libjpeg returns for CMYK and YCCK files that
 * photo tools write) to RGB: each colour channel times K, the rounding
 * OpenCV used (c = k - ((255 - c) * k >> 8)). */
static void cmyk_to_rgb(const unsigned char *s, unsigned char *d, size_t w)
{
    for (size_t x = 0; x < w; x++, s += 4, d += 3) {
        int k = s[3];
        d[0] = (unsigned char)(k - ((255 - s[0]) * k >> 8));
        d[1] = (unsigned char)(k - ((255 - s[1]) * k >> 8));
        d[2] = (unsigned char)(k - ((255 - s[2]) * k >> 8));
    }
}

/* The orientation from the first APP1 segment that holds EXIF. */
static int jpeg_orientation(const struct jpeg_decompress_struct *cinfo)
{
    for (jpeg_saved_marker_ptr m = cinfo->marker_list; m; m = m->next)
        if (m->marker == JPEG_APP0 + 1 && m->data_length >= 6 && memcmp(m->data, "Exif", 4) == 0)
            return gs_exif_orientation(m->data, m->data_length);
    return 1;
}

/* The part that may longjmp: header, checks, scanlines. Returns GS_OK or a
 * status for a refusal found between library calls. */
static int jpeg_decode_run(jpeg_dec *d, const unsigned char *buf, size_t len, size_t max_pixels,
                           int max_side, gs_error *err)
{
    struct jpeg_decompress_struct *ci = &d->cinfo;
    jpeg_mem_src(ci, buf, (unsigned long)len);
    jpeg_save_markers(ci, JPEG_APP0 + 1, 0xffff);
    jpeg_read_header(ci, TRUE);
    /* the saved markers live until jpeg_finish_decompress */
    d->orientation = jpeg_orientation(ci);
    const int cmyk = ci->num_components == 4;
    ci->out_color_space = cmyk ? JCS_CMYK : JCS_RGB;
    jpeg_calc_output_dimensions(ci);
    const size_t w = ci->output_width, h = ci->output_height;
    if (w > (size_t)max_side || h > (size_t)max_side || w * h > max_pixels)
        return gs_error_set(err, GS_ERR_LIMIT, "jpeg: %zux%zu over the limits", w, h);
    if (ci->output_components != (cmyk ? 4 : 3))
        return gs_error_set(err, GS_ERR_UNSUPPORTED, "jpeg: %d components",
                            ci->output_components);
    d->pix = malloc(w * h * 3);
    d->row = cmyk ? malloc(w * 4) : NULL;
    if (!d->pix || (cmyk && !d->row))
        return gs_error_set(err, GS_ERR_NOMEM, "jpeg: cannot allocate %zux%zu", w, h);
    jpeg_start_decompress(ci);
    while (ci->output_scanline < ci->output_height) {
        unsigned char *dst = d->pix + (size_t)ci->output_scanline * w * 3;
        JSAMPROW r = cmyk ? d->row : dst;
        if (jpeg_read_scanlines(ci, &r, 1) != 1)
            return gs_error_set(err, GS_ERR_FORMAT, "jpeg: no data at row %u",
                                ci->output_scanline);
        if (cmyk)
            cmyk_to_rgb(d->row, dst, w);
    }
    jpeg_finish_decompress(ci);
    return GS_OK;
}

int gs_jpeg_decode(const unsigned char *buf, size_t len, size_t max_pixels, int max_side,
                   gs_io_image *out, gs_error *err)
{
    if (len > ULONG_MAX)
        return gs_error_set(err, GS_ERR_LIMIT, "jpeg: %zu bytes too large", len);
    jpeg_dec *d = calloc(1, sizeof *d);
    if (!d)
        return gs_error_set(err, GS_ERR_NOMEM, "jpeg: cannot allocate a decoder");
    int rc;
    jpeg_err_init(&d->jerr);
    d->cinfo.err = &d->jerr.pub;
    if (setjmp(d->jerr.jump)) {
        rc = jpeg_err_unsupported(&d->jerr)
                 ? gs_error_set(err, GS_ERR_UNSUPPORTED, "jpeg: not supported: %s", d->jerr.msg)
                 : gs_error_set(err, GS_ERR_FORMAT, "jpeg: corrupt data: %s", d->jerr.msg);
    } else {
        jpeg_create_decompress(&d->cinfo);
        rc = jpeg_decode_run(d, buf, len, max_pixels, max_side, err);
    }
    jpeg_destroy_decompress(&d->cinfo);
    if (rc == GS_OK) {
        gs_io_image img = {(int)d->cinfo.output_width, (int)d->cinfo.output_height,
                           (size_t)d->cinfo.output_width * 3, d->pix};
        d->pix = NULL;
        rc = gs_image_orient(&img, d->orientation, err);
        if (rc == GS_OK)
            *out = img;
        else
            free(img.data);
    }
    free(d->pix);
    free(d->row);
    free(d);
    return rc;
}

/* ---- encode ------------------------------------------------------------- */

typedef struct jpeg_enc {
    struct jpeg_compress_struct cinfo; /* first: the callbacks cast back */
    struct jpeg_destination_mgr dest;
    jpeg_err jerr;
    unsigned char *buf; /* the output, grown by doubling */
    size_t cap, len;
    unsigned char *row;
} jpeg_enc;

#define GS_JPEG_OUT_START 65536

static void dest_init(j_compress_ptr c)
{
    jpeg_enc *e = (jpeg_enc *)c;
    e->buf = malloc(GS_JPEG_OUT_START);
    if (!e->buf) {
        snprintf(e->jerr.msg, sizeof e->jerr.msg, "out of memory");
        longjmp(e->jerr.jump, 1);
    }
    e->cap = GS_JPEG_OUT_START;
    e->dest.next_output_byte = e->buf;
    e->dest.free_in_buffer = e->cap;
}

static boolean dest_grow(j_compress_ptr c)
{
    jpeg_enc *e = (jpeg_enc *)c;
    unsigned char *nb = e->cap <= SIZE_MAX / 2 ? realloc(e->buf, e->cap * 2) : NULL;
    if (!nb) {
        snprintf(e->jerr.msg, sizeof e->jerr.msg, "out of memory at %zu bytes", e->cap);
        longjmp(e->jerr.jump, 1);
    }
    e->buf = nb;
    e->dest.next_output_byte = nb + e->cap; /* the whole old buffer is full */
    e->dest.free_in_buffer = e->cap;
    e->cap *= 2;
    return TRUE;
}

static void dest_term(j_compress_ptr c)
{
    jpeg_enc *e = (jpeg_enc *)c;
    e->len = e->cap - e->dest.free_in_buffer;
}

/* libjpeg's defaults with the quality scaling of its cjpeg (-quality q):
 * baseline Huffman tables, 4:2:0, no optimisation, as OpenCV wrote them. */
static void jpeg_encode_run(jpeg_enc *e, const gs_io_image *img, int quality)
{
    struct jpeg_compress_struct *ci = &e->cinfo;
    e->dest.init_destination = dest_init;
    e->dest.empty_output_buffer = dest_grow;
    e->dest.term_destination = dest_term;
    ci->dest = &e->dest;
    ci->image_width = (JDIMENSION)img->width;
    ci->image_height = (JDIMENSION)img->height;
    ci->input_components = 3;
    ci->in_color_space = JCS_RGB;
    jpeg_set_defaults(ci);
    jpeg_set_quality(ci, quality, TRUE);
    jpeg_start_compress(ci, TRUE);
    const size_t rowlen = (size_t)img->width * 3;
    while (ci->next_scanline < ci->image_height) {
        /* jpeg_write_scanlines takes non-const rows: hand it a copy */
        memcpy(e->row, img->data + (size_t)ci->next_scanline * img->stride, rowlen);
        JSAMPROW r = e->row;
        jpeg_write_scanlines(ci, &r, 1);
    }
    jpeg_finish_compress(ci);
}

int gs_jpeg_encode(const gs_io_image *img, int quality, unsigned char **out, size_t *out_len,
                   gs_error *err)
{
    jpeg_enc *e = calloc(1, sizeof *e);
    if (e)
        e->row = malloc((size_t)img->width * 3);
    if (!e || !e->row) {
        free(e);
        return gs_error_set(err, GS_ERR_NOMEM, "jpeg: cannot allocate an encoder");
    }
    int rc = GS_OK;
    jpeg_err_init(&e->jerr);
    e->cinfo.err = &e->jerr.pub;
    if (setjmp(e->jerr.jump)) {
        rc = gs_error_set(err, GS_ERR_ARG, "jpeg: encoder failed: %s", e->jerr.msg);
    } else {
        jpeg_create_compress(&e->cinfo);
        jpeg_encode_run(e, img, quality);
    }
    jpeg_destroy_compress(&e->cinfo);
    if (rc == GS_OK) {
        *out = e->buf;
        *out_len = e->len;
    } else {
        free(e->buf);
    }
    free(e->row);
    free(e);
    return rc;
}
