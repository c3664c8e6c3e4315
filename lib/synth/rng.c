/* Deterministic random numbers and value noise for lib/synth. */
#include "synth_internal.h"

uint64_t gs_synth_splitmix64(uint64_t *state)
{
    uint64_t z = (*state += 0x9e3779b97f4a7c15ULL);
    z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ULL;
    z = (z ^ (z >> 27)) * 0x94d049bb133111ebULL;
    return z ^ (z >> 31);
}

uint64_t gs_synth_hash2(uint64_t a, uint64_t b)
{
    uint64_t s = a ^ ((b << 29) | (b >> 35)) ^ (b * 0xd1b54a32d192ed03ULL);
    return gs_synth_splitmix64(&s);
}

void gs_rng_seed(gs_rng *r, uint64_t seed)
{
    uint64_t s = seed;
    for (int i = 0; i < 4; i++)
        r->s[i] = gs_synth_splitmix64(&s);
}

static inline uint64_t rotl(uint64_t x, int k)
{
    return (x << k) | (x >> (64 - k));
}

uint64_t gs_rng_next(gs_rng *r)
{
    uint64_t *s = r->s;
    uint64_t result = rotl(s[1] * 5, 7) * 9;
    uint64_t t = s[1] << 17;
    s[2] ^= s[0];
    s[3] ^= s[1];
    s[1] ^= s[2];
    s[0] ^= s[3];
    s[2] ^= t;
    s[3] = rotl(s[3], 45);
    return result;
}

double gs_rng_uniform(gs_rng *r, double lo, double hi)
{
    double u = (double)(gs_rng_next(r) >> 11) * 0x1.0p-53;
    return lo + (hi - lo) * u;
}

/* Lattice hash of an integer cell to [-1, 1]. */
static inline float lattice(int32_t x, int32_t y, int32_t z, uint32_t seed)
{
    uint32_t h = seed ^ 0x9e3779b9u;
    h ^= (uint32_t)x * 0x85ebca6bu;
    h = (h << 13) | (h >> 19);
    h ^= (uint32_t)y * 0xc2b2ae35u;
    h = (h << 13) | (h >> 19);
    h ^= (uint32_t)z * 0x27d4eb2fu;
    h ^= h >> 16;
    h *= 0x7feb352du;
    h ^= h >> 15;
    h *= 0x846ca68bu;
    h ^= h >> 16;
    return (float)(h >> 8) * (2.0f / 16777216.0f) - 1.0f;
}

float gs_synth_noise3(v3 p, uint32_t seed)
{
    float fx = floorf(p.x), fy = floorf(p.y), fz = floorf(p.z);
    int32_t ix = (int32_t)fx, iy = (int32_t)fy, iz = (int32_t)fz;
    float tx = p.x - fx, ty = p.y - fy, tz = p.z - fz;
    /* Quintic fade keeps the noise C2 so shading shows no creases. */
    float ux = tx * tx * tx * (tx * (tx * 6 - 15) + 10);
    float uy = ty * ty * ty * (ty * (ty * 6 - 15) + 10);
    float uz = tz * tz * tz * (tz * (tz * 6 - 15) + 10);
    float c000 = lattice(ix, iy, iz, seed), c100 = lattice(ix + 1, iy, iz, seed);
    float c010 = lattice(ix, iy + 1, iz, seed), c110 = lattice(ix + 1, iy + 1, iz, seed);
    float c001 = lattice(ix, iy, iz + 1, seed), c101 = lattice(ix + 1, iy, iz + 1, seed);
    float c011 = lattice(ix, iy + 1, iz + 1, seed), c111 = lattice(ix + 1, iy + 1, iz + 1, seed);
    float x00 = mixf(c000, c100, ux), x10 = mixf(c010, c110, ux);
    float x01 = mixf(c001, c101, ux), x11 = mixf(c011, c111, ux);
    return mixf(mixf(x00, x10, uy), mixf(x01, x11, uy), uz);
}
