/* The 64-bit content hash of model files and tuned blocks (not
 * cryptographic): four multiply-rotate lanes over 32-byte blocks, a final
 * mix. Shared by the parameter id (layout.c) and the tuned blocks' keys
 * and checksums (tuned.c); changing it changes every id and checksum. */
#ifndef GS_MODEL_HASH64_H
#define GS_MODEL_HASH64_H

#include <stddef.h>
#include <stdint.h>
#include <string.h>

static inline uint64_t rotl(uint64_t x, int r)
{
    return x << r | x >> (64 - r);
}

/* Four independent lanes over 32-byte blocks (a single dependent chain
 * would run at about a byte per cycle over a 30 MB model), folded at the
 * end. Not cryptographic: it tells models and corrupt blocks apart. */
typedef struct {
    uint64_t v[4];
    uint64_t n;
} hash64;

static inline void hash_init(hash64 *h, uint64_t seed)
{
    for (int k = 0; k < 4; k++)
        h->v[k] = seed + 0x9e3779b97f4a7c15ULL * (uint64_t)(k + 1);
    h->n = 0;
}

static inline uint64_t lane(uint64_t v, uint64_t w)
{
    return rotl(v ^ (w * 0xbf58476d1ce4e5b9ULL), 29) * 0x94d049bb133111ebULL;
}

/* Whole blocks of 32 bytes only, except for the last call's tail. */
static inline void hash_bytes(hash64 *h, const void *p, size_t n)
{
    const uint8_t *b = p;
    h->n += n;
    for (; n >= 32; n -= 32, b += 32)
        for (int k = 0; k < 4; k++) {
            uint64_t w;
            memcpy(&w, b + 8 * k, 8);
            h->v[k] = lane(h->v[k], w);
        }
    for (int k = 0; n > 0; k++) {
        uint64_t w = 0;
        size_t c = n < 8 ? n : 8;
        memcpy(&w, b, c);
        h->v[k] = lane(h->v[k], w ^ 0xa5);
        b += c, n -= c;
    }
}

static inline uint64_t hash_final(const hash64 *h)
{
    uint64_t x = h->n;
    for (int k = 0; k < 4; k++)
        x = lane(x, h->v[k]);
    x ^= x >> 31;
    x *= 0xd6e8feb86659fd93ULL;
    return x ^ (x >> 32);
}

#endif
