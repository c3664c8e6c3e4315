/* Fuzz target: the EXIF Orientation parser on arbitrary APP1 bodies (and
 * as bare TIFF blocks, as in PNG eXIf chunks), and
 * the flip or rotation it selects. Invariants (abort on violation): the
 * orientation is 1..8; orienting a small image keeps its pixels, swaps
 * width and height exactly for 5..8, and the inverse orientation (6 and 8
 * swap, the others undo themselves) gives the original back. */
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "image_codec.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    int o = gs_exif_orientation(data, size);
    int t = gs_exif_tiff_orientation(data, size); /* as a PNG eXIf chunk */
    if (o < 1 || o > 8 || t < 1 || t > 8)
        abort();
    /* a 5x3 image whose every pixel is different */
    enum { W = 5, H = 3 };
    unsigned char orig[W * H * 3];
    for (int i = 0; i < W * H * 3; i++)
        orig[i] = (unsigned char)(i * 7 + (size ? data[i % size] : 0));
    for (int i = 0; i < W * H; i++)
        orig[3 * i] = (unsigned char)i;
    gs_io_image img = {W, H, W * 3, malloc(sizeof orig)};
    if (!img.data)
        return 0;
    memcpy(img.data, orig, sizeof orig);
    if (gs_image_orient(&img, o, NULL) != GS_OK)
        abort();
    const int swap = o >= 5;
    if (img.width != (swap ? H : W) || img.height != (swap ? W : H) ||
        img.stride != 3 * (size_t)img.width)
        abort();
    const int inverse = o == 6 ? 8 : o == 8 ? 6 : o;
    if (gs_image_orient(&img, inverse, NULL) != GS_OK || img.width != W || img.height != H ||
        memcmp(img.data, orig, sizeof orig) != 0)
        abort();
    free(img.data);
    return 0;
}
