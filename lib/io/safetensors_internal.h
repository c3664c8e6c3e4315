/* Shared by the safetensors reader and writer: byte order, UTF-8 and
 * finiteness checks. */
#ifndef GS_SAFETENSORS_INTERNAL_H
#define GS_SAFETENSORS_INTERNAL_H

#include <stddef.h>
#include <stdint.h>
#include <string.h>

#include "gazesplat/safetensors.h"

#define ST_ERR "safetensors: "

#if defined(__BYTE_ORDER__) && __BYTE_ORDER__ == __ORDER_BIG_ENDIAN__
#define ST_BIG_ENDIAN 1
#else
#define ST_BIG_ENDIAN 0
#endif

/* Swaps every esize-byte element of p in place: file bytes are
 * little-endian, so this is the conversion both ways on a big-endian host
 * and a no-op otherwise. */
static inline void st_swap_to_le(void *p, size_t nbytes, size_t esize)
{
    unsigned char *b = p;
    if (!ST_BIG_ENDIAN || esize < 2)
        return;
    for (size_t i = 0; i + esize <= nbytes; i += esize)
        for (size_t j = 0; j < esize / 2; j++) {
            unsigned char t = b[i + j];
            b[i + j] = b[i + esize - 1 - j];
            b[i + esize - 1 - j] = t;
        }
}

/* Length of the well-formed UTF-8 sequence at s (n > 0 bytes available):
 * 1..4, or 0 for a bad lead or continuation byte, an overlong form, a
 * surrogate or a code point past U+10FFFF. */
static inline size_t st_utf8_len(const unsigned char *s, size_t n)
{
    unsigned c = s[0];
    size_t len;
    uint32_t cp, min;
    if (c < 0x80)
        return 1;
    if ((c & 0xE0) == 0xC0) {
        len = 2, cp = c & 0x1F, min = 0x80;
    } else if ((c & 0xF0) == 0xE0) {
        len = 3, cp = c & 0x0F, min = 0x800;
    } else if ((c & 0xF8) == 0xF0) {
        len = 4, cp = c & 0x07, min = 0x10000;
    } else {
        return 0;
    }
    if (n < len)
        return 0;
    for (size_t i = 1; i < len; i++) {
        if ((s[i] & 0xC0) != 0x80)
            return 0;
        cp = cp << 6 | (s[i] & 0x3F);
    }
    if (cp < min || cp > 0x10FFFF || (cp >= 0xD800 && cp <= 0xDFFF))
        return 0;
    return len;
}

/* Index of the first NaN/Inf element of an F32 or F16 tensor (host byte
 * order), or SIZE_MAX if all are finite or the dtype has no such values.
 * Tests the exponent bits, so it holds under any floating-point flags.
 * Blocks of a fixed count with an OR-reduction, so the compiler vectorizes
 * them (gcc's -O2 cost model wants a known trip count); only a block that
 * holds a bad value is searched element by element. */
#define ST_BLOCK 256

static inline size_t st_first_nonfinite(gs_st_dtype dt, const void *data, size_t nbytes)
{
    const unsigned char *b = data;
    size_t esize = dt == GS_ST_F32 ? 4 : dt == GS_ST_F16 ? 2 : 0;
    if (!esize)
        return SIZE_MAX;
    size_t n = nbytes / esize, i0 = 0;
    uint32_t mask = esize == 4 ? 0x7F800000u : 0x7C00u;
    for (; i0 < n; i0 += ST_BLOCK) {
        uint32_t any = 0;
        if (n - i0 >= ST_BLOCK && esize == 4) {
            for (size_t i = 0; i < ST_BLOCK; i++) {
                uint32_t u;
                memcpy(&u, b + 4 * (i0 + i), 4);
                any |= (u & mask) == mask;
            }
        } else if (n - i0 >= ST_BLOCK) {
            for (size_t i = 0; i < ST_BLOCK; i++) {
                uint16_t h;
                memcpy(&h, b + 2 * (i0 + i), 2);
                any |= (h & mask) == mask;
            }
        } else {
            any = 1; /* the tail: search it */
        }
        if (!any)
            continue;
        for (size_t i = i0; i < n && i < i0 + ST_BLOCK; i++) {
            uint32_t u;
            uint16_t h;
            if (esize == 4) {
                memcpy(&u, b + 4 * i, 4);
            } else {
                memcpy(&h, b + 2 * i, 2);
                u = h;
            }
            if ((u & mask) == mask)
                return i;
        }
    }
    return SIZE_MAX;
}

#endif
