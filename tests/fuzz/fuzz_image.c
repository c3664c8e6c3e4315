/* Fuzz target: the PNG/JPEG checks and decoder on arbitrary bytes.
 * Invariants (abort on violation): a failure carries its code and a
 * message; a success respects the limits and its pixels survive a PNG
 * round trip exactly. The limits are small to keep each run fast. */
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "gazesplat/image_io.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

static void check_png_round_trip(const gs_io_image *img)
{
    void *enc = NULL;
    size_t len = 0;
    gs_io_image back;
    if (gs_io_image_encode(img, GS_IO_PNG, 1, &enc, &len, NULL) != GS_OK)
        abort();
    if (gs_io_image_decode(enc, len, NULL, &back, NULL) != GS_OK)
        abort();
    if (back.width != img->width || back.height != img->height ||
        memcmp(back.data, img->data, img->stride * (size_t)img->height) != 0)
        abort();
    gs_io_image_free(&back);
    free(enc);
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    const gs_io_image_limits lim = {1 << 20, 1 << 16, 1024};
    gs_io_image img;
    gs_error err = {0, ""};
    int rc = gs_io_image_decode(data, size, &lim, &img, &err);
    if (rc != GS_OK) {
        if (rc > 0 || err.code != rc || err.msg[0] == '\0')
            abort();
        return 0;
    }
    if (img.width < 1 || img.height < 1 || img.width > lim.max_side ||
        img.height > lim.max_side || (size_t)img.width * (size_t)img.height > lim.max_pixels ||
        img.stride != 3 * (size_t)img.width)
        abort();
    check_png_round_trip(&img);
    gs_io_image_free(&img);
    return 0;
}
