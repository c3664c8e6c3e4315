/* PNG and JPEG: the checks in front of the codecs (png_codec.c,
 * jpeg_codec.c), and file I/O.
 *
 * Before any pixel is decoded the encoded stream is walked chunk by chunk
 * (PNG) or segment by segment (JPEG): truncation and structural damage are
 * refused here with a message, and the dimensions from the header are held
 * against the limits, so a small file cannot make the decoder allocate a
 * huge image. */
#define _POSIX_C_SOURCE 200809L /* fileno, fstat, strcasecmp */

#include "gazesplat/image_io.h"

#include <errno.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>
#include <sys/stat.h>

#include "image_codec.h"

#define GS_IO_ENCODE_MAX_SIDE 65535 /* the JPEG format's limit; PNG alike */
/* Progressive JPEGs need about ten scans; thousands of tiny scans are a
 * known way to make libjpeg spend minutes on a small file. */
#define GS_IO_JPEG_MAX_SCANS 256

static const unsigned char png_sig[8] = {0x89, 'P', 'N', 'G', '\r', '\n', 0x1a, '\n'};

gs_io_image_limits gs_io_image_limits_default(void)
{
    gs_io_image_limits lim = {GS_IO_IMAGE_DEFAULT_MAX_BYTES, GS_IO_IMAGE_DEFAULT_MAX_PIXELS,
                              GS_IO_IMAGE_DEFAULT_MAX_SIDE};
    return lim;
}

void gs_io_image_free(gs_io_image *img)
{
    if (img) {
        free(img->data);
        memset(img, 0, sizeof *img);
    }
}

int gs_io_format_from_path(const char *path)
{
    const char *dot = path ? strrchr(path, '.') : NULL;
    if (!dot)
        return 0;
    if (strcasecmp(dot, ".png") == 0)
        return GS_IO_PNG;
    if (strcasecmp(dot, ".jpg") == 0 || strcasecmp(dot, ".jpeg") == 0)
        return GS_IO_JPEG;
    return 0;
}

int gs_io_format_sniff(const void *buf, size_t len)
{
    const unsigned char *b = buf;
    if (len >= 8 && memcmp(b, png_sig, 8) == 0)
        return GS_IO_PNG;
    if (len >= 3 && b[0] == 0xff && b[1] == 0xd8 && b[2] == 0xff)
        return GS_IO_JPEG;
    return 0;
}

static uint32_t be32(const unsigned char *p)
{
    return (uint32_t)p[0] << 24 | (uint32_t)p[1] << 16 | (uint32_t)p[2] << 8 | p[3];
}

static unsigned be16(const unsigned char *p)
{
    return (unsigned)p[0] << 8 | p[1];
}

/* The formats we do not decode, named in the refusal. */
static const char *other_format(const unsigned char *b, size_t len)
{
    if (len >= 12 && memcmp(b, "RIFF", 4) == 0 && memcmp(b + 8, "WEBP", 4) == 0)
        return "WebP";
    if (len >= 4 && (memcmp(b, "II*\0", 4) == 0 || memcmp(b, "MM\0*", 4) == 0))
        return "TIFF";
    if (len >= 6 && (memcmp(b, "GIF87a", 6) == 0 || memcmp(b, "GIF89a", 6) == 0))
        return "GIF";
    if (len >= 2 && b[0] == 'B' && b[1] == 'M')
        return "BMP";
    if (len >= 12 && memcmp(b, "\0\0\0\x0cjP  ", 8) == 0)
        return "JPEG 2000";
    if (len >= 4 && memcmp(b, "\x76\x2f\x31\x01", 4) == 0)
        return "OpenEXR";
    if (len >= 12 && memcmp(b + 4, "ftyp", 4) == 0)
        return "HEIF/AVIF";
    if (len >= 3 && b[0] == 'P' && b[1] >= '1' && b[1] <= '7' &&
        (b[2] == '\n' || b[2] == ' ' || b[2] == '\r' || b[2] == '\t'))
        return "PNM (PBM/PGM/PPM/PAM)";
    if (len >= 10 && memcmp(b, "#?RADIANCE", 10) == 0)
        return "Radiance HDR";
    return NULL;
}

static int refuse_format(const unsigned char *b, size_t len, gs_error *err)
{
    const char *name = other_format(b, len);
    if (name)
        return gs_error_set(err, GS_ERR_UNSUPPORTED,
                            "image: %s is not supported (PNG or JPEG only)", name);
    return gs_error_set(err, GS_ERR_UNSUPPORTED, "image: not a PNG or JPEG file");
}

/* ---- PNG structure ------------------------------------------------------ */

/* Walks the chunks: IHDR first, at least one IDAT, IEND before the end of
 * the buffer (bytes after IEND are ignored, as by libpng). */
static int png_check(const unsigned char *b, size_t len, uint32_t *w, uint32_t *h,
                     gs_error *err)
{
    size_t pos = 8;
    int idat = 0;
    for (int first = 1;; first = 0) {
        if (len - pos < 12)
            return gs_error_set(err, GS_ERR_FORMAT, "png: truncated at offset %zu (no IEND)", pos);
        uint32_t clen = be32(b + pos);
        const unsigned char *type = b + pos + 4;
        if (clen > 0x7fffffffu)
            return gs_error_set(err, GS_ERR_FORMAT, "png: chunk length %u at offset %zu",
                                (unsigned)clen, pos);
        if (len - pos - 12 < clen)
            return gs_error_set(err, GS_ERR_FORMAT,
                                "png: truncated: chunk '%.4s' at offset %zu needs %u bytes, %zu left",
                                (const char *)type, pos, (unsigned)clen, len - pos - 12);
        if (first) {
            if (memcmp(type, "IHDR", 4) != 0 || clen != 13)
                return gs_error_set(err, GS_ERR_FORMAT, "png: first chunk is not IHDR");
            *w = be32(b + pos + 8);
            *h = be32(b + pos + 12);
            if (*w == 0 || *h == 0 || *w > 0x7fffffffu || *h > 0x7fffffffu)
                return gs_error_set(err, GS_ERR_FORMAT, "png: bad size %ux%u", (unsigned)*w,
                                    (unsigned)*h);
        }
        idat |= memcmp(type, "IDAT", 4) == 0;
        if (memcmp(type, "IEND", 4) == 0)
            break;
        pos += 12 + (size_t)clen;
    }
    if (!idat)
        return gs_error_set(err, GS_ERR_FORMAT, "png: no IDAT chunk");
    return GS_OK;
}

/* ---- JPEG structure ----------------------------------------------------- */

static int is_sof(unsigned m)
{
    return m >= 0xc0 && m <= 0xcf && m != 0xc4 && m != 0xc8 && m != 0xcc;
}

/* Skips entropy-coded data from pos; returns the offset of the next real
 * marker's 0xFF (stuffed 0xFF00, restart markers and fill bytes are data)
 * or len when the data runs out. */
static size_t jpeg_skip_scan(const unsigned char *b, size_t len, size_t pos)
{
    while (pos + 1 < len) {
        if (b[pos] != 0xff) {
            pos++;
            continue;
        }
        unsigned n = b[pos + 1];
        if (n == 0x00 || (n >= 0xd0 && n <= 0xd7))
            pos += 2;
        else if (n == 0xff)
            pos++;
        else
            return pos;
    }
    return len;
}

/* Reads one SOF segment body (after the length) of seglen bytes. */
static int jpeg_sof(const unsigned char *s, size_t seglen, uint32_t *w, uint32_t *h,
                    gs_error *err)
{
    if (seglen < 6)
        return gs_error_set(err, GS_ERR_FORMAT, "jpeg: short frame header");
    *h = be16(s + 1);
    *w = be16(s + 3);
    if (*h == 0)
        return gs_error_set(err, GS_ERR_UNSUPPORTED, "jpeg: height defined by DNL");
    if (*w == 0)
        return gs_error_set(err, GS_ERR_FORMAT, "jpeg: zero width");
    return GS_OK;
}

/* Walks the markers from SOI to EOI: one frame header before the first
 * scan, every segment length within the buffer, at most
 * GS_IO_JPEG_MAX_SCANS scans, EOI present. */
static int jpeg_check(const unsigned char *b, size_t len, uint32_t *w, uint32_t *h,
                      gs_error *err)
{
    size_t pos = 2;
    int sof = 0, sos = 0;
    for (;;) {
        if (pos >= len)
            return gs_error_set(err, GS_ERR_FORMAT, "jpeg: truncated (no EOI marker)");
        if (b[pos] != 0xff)
            return gs_error_set(err, GS_ERR_FORMAT, "jpeg: no marker at offset %zu", pos);
        while (pos < len && b[pos] == 0xff)
            pos++;
        if (pos >= len)
            return gs_error_set(err, GS_ERR_FORMAT, "jpeg: truncated (no EOI marker)");
        unsigned m = b[pos++];
        if (m == 0xd9) {
            if (!sos)
                return gs_error_set(err, GS_ERR_FORMAT, "jpeg: EOI before any scan");
            return GS_OK;
        }
        if ((m >= 0xd0 && m <= 0xd7) || m == 0x01)
            continue;
        if (m == 0x00 || m == 0xd8)
            return gs_error_set(err, GS_ERR_FORMAT, "jpeg: bad marker 0x%02x", m);
        if (len - pos < 2 || be16(b + pos) < 2 || be16(b + pos) > len - pos)
            return gs_error_set(err, GS_ERR_FORMAT, "jpeg: truncated segment 0x%02x at offset %zu",
                                m, pos - 2);
        size_t seglen = be16(b + pos);
        if (is_sof(m)) {
            if (sof++)
                return gs_error_set(err, GS_ERR_FORMAT, "jpeg: two frame headers");
            int rc = jpeg_sof(b + pos + 2, seglen - 2, w, h, err);
            if (rc)
                return rc;
        }
        pos += seglen;
        if (m == 0xda) {
            if (!sof)
                return gs_error_set(err, GS_ERR_FORMAT, "jpeg: scan before frame header");
            if (++sos > GS_IO_JPEG_MAX_SCANS)
                return gs_error_set(err, GS_ERR_LIMIT, "jpeg: more than %d scans",
                                    GS_IO_JPEG_MAX_SCANS);
            pos = jpeg_skip_scan(b, len, pos);
        }
    }
}

/* ---- decode ------------------------------------------------------------- */

static int check_dims(uint32_t w, uint32_t h, const gs_io_image_limits *lim, gs_error *err)
{
    if (w > (uint32_t)lim->max_side || h > (uint32_t)lim->max_side)
        return gs_error_set(err, GS_ERR_LIMIT, "image: %ux%u: a side over the limit %d",
                            (unsigned)w, (unsigned)h, lim->max_side);
    if ((uint64_t)w * h > (uint64_t)lim->max_pixels)
        return gs_error_set(err, GS_ERR_LIMIT, "image: %ux%u: over the limit of %zu pixels",
                            (unsigned)w, (unsigned)h, lim->max_pixels);
    return GS_OK;
}

int gs_io_image_decode(const void *buf, size_t len, const gs_io_image_limits *lim,
                       gs_io_image *out, gs_error *err)
{
    gs_io_image_limits dl = gs_io_image_limits_default();
    uint32_t w = 0, h = 0;
    if (!out || (!buf && len))
        return gs_error_set(err, GS_ERR_ARG, "image: NULL argument");
    if (!lim)
        lim = &dl;
    if (len > lim->max_bytes)
        return gs_error_set(err, GS_ERR_LIMIT, "image: %zu bytes over the limit %zu", len,
                            lim->max_bytes);
    int fmt = gs_io_format_sniff(buf, len);
    int rc = fmt == GS_IO_PNG    ? png_check(buf, len, &w, &h, err)
             : fmt == GS_IO_JPEG ? jpeg_check(buf, len, &w, &h, err)
                                 : refuse_format(buf, len, err);
    if (!rc)
        rc = check_dims(w, h, lim, err);
    if (!rc && fmt == GS_IO_PNG)
        rc = gs_png_decode(buf, len, lim->max_pixels, lim->max_side, out, err);
    else if (!rc)
        rc = gs_jpeg_decode(buf, len, lim->max_pixels, lim->max_side, out, err);
    return rc;
}

int gs_io_image_read(const char *path, const gs_io_image_limits *lim, gs_io_image *out,
                     gs_error *err)
{
    gs_io_image_limits dl = gs_io_image_limits_default();
    struct stat st;
    if (!path || !out)
        return gs_error_set(err, GS_ERR_ARG, "image: NULL argument");
    if (!lim)
        lim = &dl;
    FILE *f = fopen(path, "rb");
    if (!f)
        return gs_error_set(err, GS_ERR_IO, "image: cannot open %s: %s", path, strerror(errno));
    if (fstat(fileno(f), &st) != 0 || !S_ISREG(st.st_mode)) {
        fclose(f);
        return gs_error_set(err, GS_ERR_IO, "image: %s is not a regular file", path);
    }
    size_t size = (size_t)st.st_size;
    if (size > lim->max_bytes) {
        fclose(f);
        return gs_error_set(err, GS_ERR_LIMIT, "image: %s: %zu bytes over the limit %zu", path,
                            size, lim->max_bytes);
    }
    unsigned char *buf = malloc(size ? size : 1);
    int rc = !buf ? gs_error_set(err, GS_ERR_NOMEM, "image: cannot allocate %zu bytes", size)
             : fread(buf, 1, size, f) != size
                 ? gs_error_set(err, GS_ERR_IO, "image: cannot read %s", path)
                 : gs_io_image_decode(buf, size, lim, out, err);
    free(buf);
    fclose(f);
    return rc;
}

/* ---- encode ------------------------------------------------------------- */

static int resolve_quality(gs_io_format format, int quality, int *q, gs_error *err)
{
    if (format == GS_IO_JPEG) {
        *q = quality ? quality : 95;
        if (*q < 1 || *q > 100)
            return gs_error_set(err, GS_ERR_ARG, "jpeg: quality %d outside 1..100", quality);
    } else if (format == GS_IO_PNG) {
        *q = quality ? quality : 3;
        if (*q < 1 || *q > 9)
            return gs_error_set(err, GS_ERR_ARG, "png: level %d outside 1..9", quality);
    } else {
        return gs_error_set(err, GS_ERR_ARG, "image: unknown format %d", (int)format);
    }
    return GS_OK;
}

int gs_io_image_encode(const gs_io_image *img, gs_io_format format, int quality, void **out,
                       size_t *out_len, gs_error *err)
{
    int q = 0;
    if (!img || !img->data || !out || !out_len)
        return gs_error_set(err, GS_ERR_ARG, "image: NULL argument");
    if (img->width < 1 || img->height < 1 || img->width > GS_IO_ENCODE_MAX_SIDE ||
        img->height > GS_IO_ENCODE_MAX_SIDE)
        return gs_error_set(err, GS_ERR_ARG, "image: size %dx%d outside 1..%d", img->width,
                            img->height, GS_IO_ENCODE_MAX_SIDE);
    if (img->stride < (size_t)img->width * 3)
        return gs_error_set(err, GS_ERR_ARG, "image: stride %zu < 3 * width %d", img->stride,
                            img->width);
    int rc = resolve_quality(format, quality, &q, err);
    if (rc)
        return rc;
    unsigned char *buf = NULL;
    rc = format == GS_IO_JPEG ? gs_jpeg_encode(img, q, &buf, out_len, err)
                              : gs_png_encode(img, q, &buf, out_len, err);
    if (!rc)
        *out = buf;
    return rc;
}

int gs_io_image_write(const char *path, const gs_io_image *img, gs_io_format format,
                      int quality, gs_error *err)
{
    void *buf = NULL;
    size_t len = 0;
    if (!path)
        return gs_error_set(err, GS_ERR_ARG, "image: NULL path");
    int rc = gs_io_image_encode(img, format, quality, &buf, &len, err);
    if (rc)
        return rc;
    FILE *f = fopen(path, "wb");
    if (!f) {
        free(buf);
        return gs_error_set(err, GS_ERR_IO, "image: cannot create %s: %s", path, strerror(errno));
    }
    int ok = fwrite(buf, 1, len, f) == len;
    ok = (fclose(f) == 0) && ok;
    free(buf);
    if (!ok)
        return gs_error_set(err, GS_ERR_IO, "image: cannot write %s: %s", path, strerror(errno));
    return GS_OK;
}
