/* Subject cache: 16-byte key -> opaque blob (an encoded gs_subject), least
 * recently used entries evicted when the memory budget is exceeded.
 * Persisted as one file under the state directory, replaced atomically
 * (write a temporary file, fsync, rename, fsync the directory), so a crash
 * at any moment leaves either the old or the new file.
 *
 * Thread-safe: one mutex; workers get and put, the loop thread reads the
 * counters. Blobs are copied in and out. */
#ifndef GSD_CACHE_H
#define GSD_CACHE_H

#include <stddef.h>
#include <stdint.h>

#define GSD_CACHE_KEY 16
#define GSD_CACHE_MAX_BLOB 65536
#define GSD_CACHE_FILE "subjects.gsc"

typedef struct gsd_cache gsd_cache;

typedef struct gsd_cache_stats {
    uint64_t entries, bytes, budget;
    uint64_t hits, misses, inserts, evictions;
} gsd_cache_stats;

gsd_cache *gsd_cache_create(size_t budget_bytes);
/* The same with blobs up to max_blob bytes (fine-tuned parameter blocks). */
gsd_cache *gsd_cache_create_sized(size_t budget_bytes, size_t max_blob);
void gsd_cache_destroy(gsd_cache *c);

/* Inserts or replaces; may evict others. -1 when len is over the cache's
 * largest blob (GSD_CACHE_MAX_BLOB unless created sized) or out of memory. */
int gsd_cache_put(gsd_cache *c, const uint8_t key[GSD_CACHE_KEY], const void *blob, size_t len);

/* Copies the blob out (cap bytes available) and marks it recently used.
 * Returns its length, or -1 when missing (or cap too small). */
long gsd_cache_get(gsd_cache *c, const uint8_t key[GSD_CACHE_KEY], void *out, size_t cap);
/* The same into a malloc'd copy (*out; free it). -1 when missing or out
 * of memory (*out NULL). */
long gsd_cache_get_alloc(gsd_cache *c, const uint8_t key[GSD_CACHE_KEY], uint8_t **out);
/* 1 when key is present (its recency unchanged), else 0. */
int gsd_cache_contains(gsd_cache *c, const uint8_t key[GSD_CACHE_KEY]);

/* Drops every entry (e.g. a different model was loaded). */
void gsd_cache_clear(gsd_cache *c);

void gsd_cache_stats_get(gsd_cache *c, gsd_cache_stats *s);

/* The held keys for routers (HEALTH): copies up to max keys, most recently
 * used first, into keys (max * GSD_CACHE_KEY bytes; NULL when max is 0) and
 * the set's digest (XOR over the keys of BLAKE2b-128(key), all zero when
 * empty; digest may be NULL); returns the number of entries. */
size_t gsd_cache_keys(gsd_cache *c, uint8_t *keys, size_t max, uint8_t digest[GSD_CACHE_KEY]);

/* Writes dir/GSD_CACHE_FILE atomically; tag names what the blobs belong to
 * (the model id). 0, or -1 with a message. */
int gsd_cache_save(gsd_cache *c, const char *dir, const char *tag, char *msg, size_t cap);

/* Loads dir/GSD_CACHE_FILE into the cache. A missing file is not an error
 * (returns 0); a corrupt one, or one with another tag, is ignored with a
 * message (returns 1). Returns -1 only when out of memory. */
int gsd_cache_load(gsd_cache *c, const char *dir, const char *tag, char *msg, size_t cap);

/* State-directory files. Writes dir/name atomically: a temporary file,
 * fsync, rename, fsync of the directory; 0, or -1 with a message. */
int gsd_file_write_atomic(const char *dir, const char *name, const uint8_t *data, size_t n,
                          char *msg, size_t cap);
/* Reads a file whole (malloc'd; *len its size) when it is at most max
 * bytes; NULL otherwise, *missing telling a file that does not exist. */
uint8_t *gsd_file_read(const char *path, size_t max, size_t *len, int *missing);

/* Changes the budget (evicting if needed). */
void gsd_cache_set_budget(gsd_cache *c, size_t budget_bytes);

#endif
