#ifndef GSD_HASH_H
#define GSD_HASH_H

#include <stddef.h>
#include <stdint.h>

#include <blake2.h>

/* BLAKE2b-128 (libb2), for model ids and content keys.
 * A subject key names a fit that any client may ask for by content, so
 * it must not collide by accident or by design: a cryptographic hash,
 * cut to the header's 16 bytes. */

typedef struct hash128 {
    blake2b_state st;
} hash128;

static inline void hash_init(hash128 *h)
{
    blake2b_init(&h->st, 16);
}

static inline void hash_bytes(hash128 *h, const void *data, size_t n)
{
    blake2b_update(&h->st, data, n);
}

static inline void hash_out(hash128 *h, uint8_t out[16])
{
    blake2b_final(&h->st, out, 16);
}

#endif
