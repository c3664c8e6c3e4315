/* Subject cache: LRU by memory budget, atomic persistence, corrupt files. */
#define _POSIX_C_SOURCE 200809L
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include "cache.h"
#include "gs_test.h"

static void key_of(int i, uint8_t k[16])
{
    memset(k, 0, 16);
    k[0] = (uint8_t)i;
    k[1] = (uint8_t)(i >> 8);
    k[15] = 0x5a;
}

static void test_lru(void)
{
    /* Room for a handful of 1000-byte blobs. */
    gsd_cache *c = gsd_cache_create(5 * 1100);
    uint8_t blob[1000], out[2000], k[16];
    for (int i = 0; i < 10; i++) {
        memset(blob, i, sizeof blob);
        key_of(i, k);
        CHECK(gsd_cache_put(c, k, blob, sizeof blob) == 0);
        if (i == 2) { /* touch 0 so it survives the next evictions */
            key_of(0, k);
            CHECK(gsd_cache_get(c, k, out, sizeof out) == 1000);
        }
    }
    gsd_cache_stats st;
    gsd_cache_stats_get(c, &st);
    CHECK_MSG(st.bytes <= st.budget, "bytes %llu budget %llu", (unsigned long long)st.bytes,
              (unsigned long long)st.budget);
    CHECK(st.evictions > 0 && st.entries + st.evictions == 10);
    key_of(9, k);
    CHECK(gsd_cache_get(c, k, out, sizeof out) == 1000 && out[999] == 9);
    key_of(1, k);
    CHECK(gsd_cache_get(c, k, out, sizeof out) == -1);
    /* Too-small output buffer or oversized blob. */
    key_of(9, k);
    CHECK(gsd_cache_get(c, k, out, 10) == -1);
    static uint8_t huge[GSD_CACHE_MAX_BLOB + 1];
    CHECK(gsd_cache_put(c, k, huge, sizeof huge) == -1);
    /* Replacing keeps one entry. */
    gsd_cache_stats_get(c, &st);
    uint64_t n = st.entries;
    CHECK(gsd_cache_put(c, k, blob, 10) == 0);
    gsd_cache_stats_get(c, &st);
    CHECK(st.entries == n);
    CHECK(gsd_cache_get(c, k, out, sizeof out) == 10);
    gsd_cache_destroy(c);
}

/* A sized cache (fine-tuned blocks): blobs over 64 KiB, copies made by
 * get_alloc, contains leaving the LRU order alone. */
static void test_sized(void)
{
    size_t big = 3u << 20;
    gsd_cache *c = gsd_cache_create_sized(8u << 20, 4u << 20);
    uint8_t *blob = malloc(big), *copy = NULL, k[16];
    for (size_t i = 0; i < big; i++)
        blob[i] = (uint8_t)(i * 7);
    key_of(1, k);
    CHECK(gsd_cache_put(c, k, blob, big) == 0);
    CHECK(gsd_cache_contains(c, k) == 1);
    CHECK(gsd_cache_get_alloc(c, k, &copy) == (long)big && copy && !memcmp(copy, blob, big));
    free(copy);
    key_of(2, k);
    CHECK(gsd_cache_contains(c, k) == 0);
    CHECK(gsd_cache_get_alloc(c, k, &copy) == -1 && copy == NULL);
    CHECK(gsd_cache_put(c, k, blob, big) == 0);
    /* contains() on key 1 must not make it recent: a third blob evicts it. */
    key_of(1, k);
    CHECK(gsd_cache_contains(c, k) == 1);
    key_of(3, k);
    CHECK(gsd_cache_put(c, k, blob, big) == 0);
    key_of(1, k);
    CHECK(gsd_cache_contains(c, k) == 0);
    key_of(2, k);
    CHECK(gsd_cache_contains(c, k) == 1);
    /* Over the sized limit: refused. */
    uint8_t *huge = calloc(1, (4u << 20) + 1);
    CHECK(gsd_cache_put(c, k, huge, (4u << 20) + 1) == -1);
    free(huge);
    free(blob);
    gsd_cache_destroy(c);
}

static void test_many(void)
{
    gsd_cache *c = gsd_cache_create(64u << 20);
    uint8_t k[16], out[8];
    for (int i = 0; i < 5000; i++) {
        key_of(i, k);
        k[2] = (uint8_t)(i * 7);
        CHECK(gsd_cache_put(c, k, &i, sizeof i) == 0);
    }
    int bad = 0;
    for (int i = 0; i < 5000; i++) {
        key_of(i, k);
        k[2] = (uint8_t)(i * 7);
        int v = -1;
        bad += gsd_cache_get(c, k, out, sizeof out) != 4 || (memcpy(&v, out, 4), v != i);
    }
    CHECK_MSG(bad == 0, "%d of 5000 lookups wrong", bad);
    gsd_cache_destroy(c);
}

static void test_persist(void)
{
    char dir[] = "/tmp/gs_cache_XXXXXX";
    CHECK(mkdtemp(dir) != NULL);
    char msg[300], path[512];
    gsd_cache *c = gsd_cache_create(1 << 20);
    uint8_t k[16], blob[300], out[400];
    for (int i = 0; i < 20; i++) {
        key_of(i, k);
        memset(blob, i + 1, sizeof blob);
        gsd_cache_put(c, k, blob, (size_t)(100 + i));
    }
    CHECK_MSG(gsd_cache_save(c, dir, "model-a", msg, sizeof msg) == 0, "%s", msg);
    gsd_cache_destroy(c);

    c = gsd_cache_create(1 << 20);
    CHECK_MSG(gsd_cache_load(c, dir, "model-a", msg, sizeof msg) == 0, "%s", msg);
    gsd_cache_stats st;
    gsd_cache_stats_get(c, &st);
    CHECK(st.entries == 20);
    key_of(7, k);
    CHECK(gsd_cache_get(c, k, out, sizeof out) == 107 && out[106] == 8);
    gsd_cache_destroy(c);

    /* Another model's file is ignored. */
    c = gsd_cache_create(1 << 20);
    CHECK(gsd_cache_load(c, dir, "model-b", msg, sizeof msg) == 1);
    gsd_cache_stats_get(c, &st);
    CHECK(st.entries == 0);
    gsd_cache_destroy(c);

    /* Every truncation and a flipped byte are refused whole. */
    snprintf(path, sizeof path, "%s/%s", dir, GSD_CACHE_FILE);
    FILE *f = fopen(path, "rb");
    static uint8_t file[65536];
    size_t n = fread(file, 1, sizeof file, f);
    fclose(f);
    for (size_t cut = 0; cut < n; cut += 97) {
        f = fopen(path, "wb");
        fwrite(file, 1, cut, f);
        fclose(f);
        c = gsd_cache_create(1 << 20);
        CHECK_MSG(gsd_cache_load(c, dir, "model-a", msg, sizeof msg) == 1, "cut %zu", cut);
        gsd_cache_stats_get(c, &st);
        CHECK_MSG(st.entries == 0, "cut %zu: %llu entries", cut, (unsigned long long)st.entries);
        gsd_cache_destroy(c);
    }
    file[n / 2] ^= 0x40;
    f = fopen(path, "wb");
    fwrite(file, 1, n, f);
    fclose(f);
    c = gsd_cache_create(1 << 20);
    CHECK(gsd_cache_load(c, dir, "model-a", msg, sizeof msg) == 1 && strstr(msg, "checksum"));
    gsd_cache_destroy(c);

    /* A missing file is an empty cache; no temporary file is left behind. */
    unlink(path);
    c = gsd_cache_create(1 << 20);
    CHECK(gsd_cache_load(c, dir, "model-a", msg, sizeof msg) == 0);
    CHECK(gsd_cache_save(c, dir, "model-a", msg, sizeof msg) == 0);
    snprintf(path, sizeof path, "%s/%s.tmp", dir, GSD_CACHE_FILE);
    struct stat sb;
    CHECK(stat(path, &sb) != 0);
    gsd_cache_destroy(c);
    snprintf(path, sizeof path, "%s/%s", dir, GSD_CACHE_FILE);
    unlink(path);
    rmdir(dir);
}

/* The held keys and their digest (HEALTH): most recent first, the
 * digest independent of the order, back to zero when all are gone. */
static void test_keys(void)
{
    gsd_cache *a = gsd_cache_create(1 << 20), *b = gsd_cache_create(2 * 1100);
    uint8_t k[16], blob[1000] = {0}, keys[4 * 16], da[16], db[16], zero[16] = {0};
    CHECK(gsd_cache_keys(a, NULL, 0, da) == 0 && !memcmp(da, zero, 16));
    for (int i = 0; i < 3; i++) {
        key_of(i, k);
        CHECK(gsd_cache_put(a, k, blob, 10) == 0);
        key_of(2 - i, k);
        CHECK(gsd_cache_put(b, k, blob, 10) == 0);
    }
    CHECK(gsd_cache_keys(a, keys, 4, da) == 3);
    key_of(2, k);
    CHECK(!memcmp(keys, k, 16)); /* the last put first */
    key_of(0, k);
    CHECK(!memcmp(keys + 32, k, 16));
    CHECK(gsd_cache_keys(a, keys, 1, NULL) == 3); /* the count covers all */
    CHECK(gsd_cache_keys(b, NULL, 0, db) == 3 && !memcmp(da, db, 16) && memcmp(da, zero, 16));
    key_of(1, k); /* replacing a key keeps the set, and the digest */
    CHECK(gsd_cache_put(a, k, blob, 20) == 0);
    CHECK(gsd_cache_keys(a, NULL, 0, db) == 3 && !memcmp(da, db, 16));
    /* b has room for about two 1000-byte blobs: evictions change the set. */
    CHECK(gsd_cache_put(b, k, blob, sizeof blob) == 0);
    key_of(7, k);
    CHECK(gsd_cache_put(b, k, blob, sizeof blob) == 0);
    gsd_cache_stats st;
    gsd_cache_stats_get(b, &st);
    CHECK(st.evictions >= 1 && gsd_cache_keys(b, keys, 4, db) == st.entries && memcmp(da, db, 16));
    gsd_cache_clear(a);
    CHECK(gsd_cache_keys(a, NULL, 0, da) == 0 && !memcmp(da, zero, 16));
    gsd_cache_destroy(a);
    gsd_cache_destroy(b);
}

int main(void)
{
    test_keys();
    test_lru();
    test_sized();
    test_many();
    test_persist();
    GS_TEST_END();
}
