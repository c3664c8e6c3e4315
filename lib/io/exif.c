/* EXIF Orientation: the one tag we read (IFD0, 0x0112), and the flip or
 * rotation it asks for. The parser reads only inside the segment it is
 * given and gives up (orientation 1) on anything it does not expect. */
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "image_codec.h"

static unsigned rd16(const unsigned char *p, int le)
{
    return le ? (unsigned)p[0] | (unsigned)p[1] << 8 : (unsigned)p[0] << 8 | p[1];
}

static uint32_t rd32(const unsigned char *p, int le)
{
    return le ? (uint32_t)p[0] | (uint32_t)p[1] << 8 | (uint32_t)p[2] << 16 |
                    (uint32_t)p[3] << 24
              : (uint32_t)p[0] << 24 | (uint32_t)p[1] << 16 | (uint32_t)p[2] << 8 | p[3];
}

int gs_exif_orientation(const unsigned char *app1, size_t len)
{
    static const unsigned char magic[6] = {'E', 'x', 'i', 'f', 0, 0};
    if (!app1 || len < 6 || memcmp(app1, magic, 6) != 0)
        return 1;
    return gs_exif_tiff_orientation(app1 + 6, len - 6);
}

int gs_exif_tiff_orientation(const unsigned char *t, size_t n)
{
    int le;
    if (!t || n < 8)
        return 1;
    if (t[0] == 'I' && t[1] == 'I')
        le = 1;
    else if (t[0] == 'M' && t[1] == 'M')
        le = 0;
    else
        return 1;
    if (rd16(t + 2, le) != 42)
        return 1;
    uint32_t ifd = rd32(t + 4, le);
    if (ifd < 8 || ifd > n - 2)
        return 1;
    size_t count = rd16(t + ifd, le);
    size_t room = (n - ifd - 2) / 12;
    if (count > room)
        count = room; /* a cut-off directory: read the entries that are there */
    for (size_t i = 0; i < count; i++) {
        const unsigned char *e = t + ifd + 2 + 12 * i;
        if (rd16(e, le) != 0x0112)
            continue;
        /* SHORT, count 1: the value sits in the first two bytes of the
         * entry's value field */
        if (rd16(e + 2, le) != 3 || rd32(e + 4, le) < 1)
            return 1;
        unsigned v = rd16(e + 8, le);
        return v >= 1 && v <= 8 ? (int)v : 1;
    }
    return 1;
}

int gs_image_orient(gs_io_image *img, int orientation, gs_error *err)
{
    if (orientation <= 1 || orientation > 8)
        return GS_OK;
    const ptrdiff_t w = img->width, h = img->height;
    /* Destination pixel (x, y) is source pixel base + x*dx + y*dy (in
     * pixels, row-major source of width w). */
    ptrdiff_t base, dx, dy;
    switch (orientation) {
    case 2: base = w - 1; dx = -1; dy = w; break;                /* mirror */
    case 3: base = (h - 1) * w + w - 1; dx = -1; dy = -w; break; /* 180 */
    case 4: base = (h - 1) * w; dx = 1; dy = -w; break;          /* flip */
    case 5: base = 0; dx = w; dy = 1; break;                     /* transpose */
    case 6: base = (h - 1) * w; dx = -w; dy = 1; break;          /* 90 clockwise */
    case 7: base = (h - 1) * w + w - 1; dx = -w; dy = -1; break; /* transverse */
    default: base = w - 1; dx = w; dy = -1; break;               /* 8: 90 anticlockwise */
    }
    const int swap = orientation >= 5;
    const ptrdiff_t dw = swap ? h : w, dh = swap ? w : h;
    unsigned char *dst = malloc((size_t)(w * h * 3));
    if (!dst)
        return gs_error_set(err, GS_ERR_NOMEM, "image: cannot allocate %tdx%td", w, h);
    const unsigned char *src = img->data;
    for (ptrdiff_t y = 0; y < dh; y++) {
        unsigned char *d = dst + y * dw * 3;
        ptrdiff_t s = base + y * dy;
        for (ptrdiff_t x = 0; x < dw; x++, s += dx) {
            d[3 * x + 0] = src[3 * s + 0];
            d[3 * x + 1] = src[3 * s + 1];
            d[3 * x + 2] = src[3 * s + 2];
        }
    }
    free(img->data);
    img->data = dst;
    img->width = (int)dw;
    img->height = (int)dh;
    img->stride = (size_t)dw * 3;
    return GS_OK;
}
