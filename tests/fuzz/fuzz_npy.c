/* Fuzz target: the .npy parser on arbitrary bytes.
 * Invariants (abort on violation): a failure carries its code and a
 * message; a success re-encodes and parses back to the same dtype, shape
 * and data. */
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "gazesplat/image_io.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    gs_io_array a, b;
    gs_error err = {0, ""};
    void *enc = NULL;
    size_t len = 0;
    int rc = gs_io_npy_parse(data, size, (size_t)1 << 24, &a, &err);
    if (rc != GS_OK) {
        if (rc > 0 || err.code != rc || err.msg[0] == '\0')
            abort();
        return 0;
    }
    if (gs_io_npy_encode(a.dtype, a.rank, a.shape, a.data, &enc, &len, NULL) != GS_OK)
        abort();
    if (gs_io_npy_parse(enc, len, 0, &b, NULL) != GS_OK)
        abort();
    size_t nbytes = gs_io_array_count(&a) * gs_io_dtype_size(a.dtype);
    if (a.dtype != b.dtype || a.rank != b.rank ||
        memcmp(a.shape, b.shape, sizeof a.shape) != 0 || memcmp(a.data, b.data, nbytes) != 0)
        abort();
    free(enc);
    gs_io_array_free(&a);
    gs_io_array_free(&b);
    return 0;
}
