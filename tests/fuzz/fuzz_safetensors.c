/* Fuzz target: the safetensors reader on arbitrary bytes, with small limits.
 * Invariants (abort on violation): a failure carries its code and a message
 * and leaves no file; a success has names that find themselves, shapes that
 * match the byte sizes, aligned data (every byte is read) tiling the buffer,
 * metadata that looks itself up; and it re-encodes through the writer to a
 * file that opens and re-encodes to the same bytes. */
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "gazesplat/safetensors.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

static void check_tensors(const gs_st_file *f)
{
    size_t at = 0;
    volatile uint8_t sink = 0;
    for (int i = 0; i < gs_st_count(f); i++) {
        const gs_st_tensor *t = gs_st_at(f, i);
        size_t len = strlen(t->name), count = 1;
        if (!len || len > GS_ST_MAX_NAME || gs_st_find(f, t->name) != t || t->ndim < 0 ||
            t->ndim > GS_ST_MAX_DIMS || t->offset != at || ((uintptr_t)t->data & 7))
            abort();
        for (int d = 0; d < t->ndim; d++)
            count *= (size_t)t->shape[d];
        if (count * gs_st_dtype_size(t->dtype) != t->nbytes)
            abort();
        for (size_t b = 0; b < t->nbytes; b++)
            sink ^= ((const uint8_t *)t->data)[b];
        at += t->nbytes;
    }
    (void)sink;
    for (int i = 0; i < gs_st_meta_count(f); i++) {
        const char *k, *v;
        gs_st_meta_at(f, i, &k, &v);
        if (!k || !v || gs_st_meta(f, k) != v)
            abort();
    }
}

/* f through the writer; NULL buffer on failure. */
static uint8_t *encode(const gs_st_file *f, size_t *len)
{
    gs_st_writer *w = gs_st_writer_create();
    uint8_t *buf = NULL;
    if (!w)
        abort();
    for (int i = 0; i < gs_st_count(f); i++) {
        const gs_st_tensor *t = gs_st_at(f, i);
        if (gs_st_writer_add(w, t->name, t->dtype, t->ndim, t->shape, t->data) != GS_OK)
            abort();
    }
    for (int i = 0; i < gs_st_meta_count(f); i++) {
        const char *k, *v;
        gs_st_meta_at(f, i, &k, &v);
        if (gs_st_writer_meta(w, k, v) != GS_OK)
            abort();
    }
    if (gs_st_writer_to_mem(w, &buf, len, NULL) != GS_OK)
        abort();
    gs_st_writer_destroy(w);
    return buf;
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    gs_st_limits lim = {(size_t)1 << 20, (size_t)1 << 16, 64};
    gs_st_file *f = NULL, *g = NULL;
    gs_error err = {0, ""};
    int rc = gs_st_open_mem(data, size, &lim, &f, &err);
    if (rc != GS_OK) {
        if (rc > 0 || err.code != rc || err.msg[0] == '\0' || f)
            abort();
        return 0;
    }
    check_tensors(f);
    size_t len1, len2;
    uint8_t *enc1 = encode(f, &len1);
    if (gs_st_open_mem(enc1, len1, NULL, &g, NULL) != GS_OK || gs_st_count(g) != gs_st_count(f))
        abort();
    check_tensors(g);
    uint8_t *enc2 = encode(g, &len2);
    if (len1 != len2 || memcmp(enc1, enc2, len1) != 0)
        abort();
    free(enc1);
    free(enc2);
    gs_st_close(f);
    gs_st_close(g);
    return 0;
}
