/* Subject cache: chained hash table + doubly linked LRU list. */
#define _GNU_SOURCE
#include "cache.h"

#include <errno.h>
#include <fcntl.h>
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include <blake2.h>

typedef struct entry {
    uint8_t key[GSD_CACHE_KEY];
    struct entry *hnext;       /* hash chain */
    struct entry *prev, *next; /* LRU: head = most recent */
    size_t len;
    uint8_t blob[];
} entry;

struct gsd_cache {
    pthread_mutex_t mu;
    entry **buckets;
    size_t nbuckets; /* power of two */
    entry *head, *tail;
    size_t budget, max_blob;
    gsd_cache_stats st;
    uint8_t digest[GSD_CACHE_KEY]; /* XOR of BLAKE2b-128(key) over the entries */
};

/* What an entry costs against the budget. */
static size_t cost(size_t len)
{
    return sizeof(entry) + len + sizeof(entry *);
}

static size_t bucket_of(const gsd_cache *c, const uint8_t *key)
{
    uint64_t h = 1469598103934665603ull; /* FNV-1a */
    for (int i = 0; i < GSD_CACHE_KEY; i++)
        h = (h ^ key[i]) * 1099511628211ull;
    return (size_t)(h & (c->nbuckets - 1));
}

gsd_cache *gsd_cache_create(size_t budget_bytes)
{
    return gsd_cache_create_sized(budget_bytes, GSD_CACHE_MAX_BLOB);
}

gsd_cache *gsd_cache_create_sized(size_t budget_bytes, size_t max_blob)
{
    gsd_cache *c = calloc(1, sizeof *c);
    if (!c)
        return NULL;
    c->nbuckets = 1024;
    c->buckets = calloc(c->nbuckets, sizeof *c->buckets);
    if (!c->buckets) {
        free(c);
        return NULL;
    }
    pthread_mutex_init(&c->mu, NULL);
    c->budget = budget_bytes;
    c->max_blob = max_blob;
    c->st.budget = budget_bytes;
    return c;
}

/* Adds or removes key's share of the set digest (XOR is its own inverse,
 * and the order of the entries does not matter). */
static void digest_toggle(gsd_cache *c, const uint8_t *key)
{
    uint8_t h[GSD_CACHE_KEY];
    blake2b(h, key, NULL, sizeof h, GSD_CACHE_KEY, 0);
    for (int i = 0; i < GSD_CACHE_KEY; i++)
        c->digest[i] ^= h[i];
}

static void free_all(gsd_cache *c)
{
    for (entry *e = c->head, *n; e; e = n) {
        n = e->next;
        free(e);
    }
    memset(c->buckets, 0, c->nbuckets * sizeof *c->buckets);
    c->head = c->tail = NULL;
    c->st.entries = c->st.bytes = 0;
    memset(c->digest, 0, sizeof c->digest);
}

void gsd_cache_destroy(gsd_cache *c)
{
    if (!c)
        return;
    free_all(c);
    free(c->buckets);
    pthread_mutex_destroy(&c->mu);
    free(c);
}

static entry *lookup(gsd_cache *c, const uint8_t *key, entry ***link)
{
    entry **pp = &c->buckets[bucket_of(c, key)];
    while (*pp && memcmp((*pp)->key, key, GSD_CACHE_KEY) != 0)
        pp = &(*pp)->hnext;
    if (link)
        *link = pp;
    return *pp;
}

static void lru_unlink(gsd_cache *c, entry *e)
{
    if (e->prev)
        e->prev->next = e->next;
    else
        c->head = e->next;
    if (e->next)
        e->next->prev = e->prev;
    else
        c->tail = e->prev;
    e->prev = e->next = NULL;
}

static void lru_push_front(gsd_cache *c, entry *e)
{
    e->prev = NULL;
    e->next = c->head;
    if (c->head)
        c->head->prev = e;
    c->head = e;
    if (!c->tail)
        c->tail = e;
}

static void remove_entry(gsd_cache *c, entry *e)
{
    entry **pp;
    lookup(c, e->key, &pp);
    *pp = e->hnext;
    lru_unlink(c, e);
    digest_toggle(c, e->key);
    c->st.entries--;
    c->st.bytes -= cost(e->len);
    free(e);
}

/* Grows the table when chains get long; failure just keeps it. */
static void maybe_grow(gsd_cache *c)
{
    if (c->st.entries < c->nbuckets)
        return;
    size_t n = c->nbuckets * 2;
    entry **b = calloc(n, sizeof *b);
    if (!b)
        return;
    free(c->buckets);
    c->buckets = b;
    c->nbuckets = n;
    for (entry *e = c->head; e; e = e->next) {
        size_t i = bucket_of(c, e->key);
        e->hnext = b[i];
        b[i] = e;
    }
}

static void evict(gsd_cache *c)
{
    while (c->st.bytes > c->budget && c->tail) {
        remove_entry(c, c->tail);
        c->st.evictions++;
    }
}

static int put_locked(gsd_cache *c, const uint8_t *key, const void *blob, size_t len)
{
    if (len > c->max_blob)
        return -1;
    entry *old = lookup(c, key, NULL);
    if (old)
        remove_entry(c, old);
    entry *e = malloc(sizeof *e + len);
    if (!e)
        return -1;
    memcpy(e->key, key, GSD_CACHE_KEY);
    memcpy(e->blob, blob, len);
    e->len = len;
    maybe_grow(c);
    size_t i = bucket_of(c, key);
    e->hnext = c->buckets[i];
    c->buckets[i] = e;
    lru_push_front(c, e);
    digest_toggle(c, key);
    c->st.entries++;
    c->st.bytes += cost(len);
    c->st.inserts++;
    evict(c);
    return 0;
}

int gsd_cache_put(gsd_cache *c, const uint8_t key[GSD_CACHE_KEY], const void *blob, size_t len)
{
    pthread_mutex_lock(&c->mu);
    int r = put_locked(c, key, blob, len);
    pthread_mutex_unlock(&c->mu);
    return r;
}

/* Copies e's blob to dst and marks it recently used (a hit). */
static long take_locked(gsd_cache *c, entry *e, void *dst)
{
    memcpy(dst, e->blob, e->len);
    lru_unlink(c, e);
    lru_push_front(c, e);
    c->st.hits++;
    return (long)e->len;
}

long gsd_cache_get(gsd_cache *c, const uint8_t key[GSD_CACHE_KEY], void *out, size_t cap)
{
    pthread_mutex_lock(&c->mu);
    entry *e = lookup(c, key, NULL);
    long r = -1;
    if (e && out && e->len <= cap)
        r = take_locked(c, e, out);
    else
        c->st.misses++;
    pthread_mutex_unlock(&c->mu);
    return r;
}

long gsd_cache_get_alloc(gsd_cache *c, const uint8_t key[GSD_CACHE_KEY], uint8_t **out)
{
    *out = NULL;
    pthread_mutex_lock(&c->mu);
    entry *e = lookup(c, key, NULL);
    long r = -1;
    if (e && (*out = malloc(e->len ? e->len : 1)) != NULL)
        r = take_locked(c, e, *out);
    else
        c->st.misses++;
    pthread_mutex_unlock(&c->mu);
    return r;
}

int gsd_cache_contains(gsd_cache *c, const uint8_t key[GSD_CACHE_KEY])
{
    pthread_mutex_lock(&c->mu);
    int r = lookup(c, key, NULL) != NULL;
    pthread_mutex_unlock(&c->mu);
    return r;
}

void gsd_cache_clear(gsd_cache *c)
{
    pthread_mutex_lock(&c->mu);
    free_all(c);
    pthread_mutex_unlock(&c->mu);
}

void gsd_cache_set_budget(gsd_cache *c, size_t budget_bytes)
{
    pthread_mutex_lock(&c->mu);
    c->budget = budget_bytes;
    c->st.budget = budget_bytes;
    evict(c);
    pthread_mutex_unlock(&c->mu);
}

size_t gsd_cache_keys(gsd_cache *c, uint8_t *keys, size_t max, uint8_t digest[GSD_CACHE_KEY])
{
    pthread_mutex_lock(&c->mu);
    size_t n = 0;
    for (entry *e = c->head; e && n < max; e = e->next, n++)
        memcpy(keys + n * GSD_CACHE_KEY, e->key, GSD_CACHE_KEY);
    size_t total = c->st.entries;
    if (digest)
        memcpy(digest, c->digest, GSD_CACHE_KEY);
    pthread_mutex_unlock(&c->mu);
    return total;
}

void gsd_cache_stats_get(gsd_cache *c, gsd_cache_stats *s)
{
    pthread_mutex_lock(&c->mu);
    *s = c->st;
    pthread_mutex_unlock(&c->mu);
}

/* ---- persistence ---------------------------------------------------------
 * File: "GZSC" u32 version=1, u32 tag_len, tag, u32 count, then count x
 * (key[16], u32 len, blob[len]) from least to most recently used, then a
 * CRC-32 (IEEE) of everything before it. Little-endian. */

#define FILE_VERSION 1u
#define MAX_TAG 256u

static uint32_t crc32_update(uint32_t crc, const uint8_t *p, size_t n)
{
    crc = ~crc;
    for (size_t i = 0; i < n; i++) {
        crc ^= p[i];
        for (int k = 0; k < 8; k++)
            crc = (crc >> 1) ^ (0xEDB88320u & (0u - (crc & 1u)));
    }
    return ~crc;
}

static void put32(uint8_t *p, uint32_t v)
{
    for (int i = 0; i < 4; i++)
        p[i] = (uint8_t)(v >> (8 * i));
}

static uint32_t get32(const uint8_t *p)
{
    return (uint32_t)p[0] | (uint32_t)p[1] << 8 | (uint32_t)p[2] << 16 | (uint32_t)p[3] << 24;
}

/* Serializes under the lock into one buffer. */
static uint8_t *serialize(gsd_cache *c, const char *tag, size_t *out_len)
{
    size_t tl = strlen(tag) < MAX_TAG ? strlen(tag) : MAX_TAG;
    pthread_mutex_lock(&c->mu);
    size_t n = 16 + tl + 4;
    for (entry *e = c->tail; e; e = e->prev)
        n += GSD_CACHE_KEY + 4 + e->len;
    uint8_t *buf = malloc(n);
    if (buf) {
        memcpy(buf, "GZSC", 4);
        put32(buf + 4, FILE_VERSION);
        put32(buf + 8, (uint32_t)tl);
        memcpy(buf + 12, tag, tl);
        put32(buf + 12 + tl, (uint32_t)c->st.entries);
        size_t o = 16 + tl;
        for (entry *e = c->tail; e; e = e->prev) {
            memcpy(buf + o, e->key, GSD_CACHE_KEY);
            put32(buf + o + GSD_CACHE_KEY, (uint32_t)e->len);
            memcpy(buf + o + GSD_CACHE_KEY + 4, e->blob, e->len);
            o += GSD_CACHE_KEY + 4 + e->len;
        }
        put32(buf + o, crc32_update(0, buf, o));
    }
    pthread_mutex_unlock(&c->mu);
    *out_len = n;
    return buf;
}

static int write_all(int fd, const uint8_t *p, size_t n)
{
    while (n > 0) {
        ssize_t w = write(fd, p, n);
        if (w < 0 && errno == EINTR)
            continue;
        if (w <= 0)
            return -1;
        p += w;
        n -= (size_t)w;
    }
    return 0;
}

int gsd_file_write_atomic(const char *dir, const char *name, const uint8_t *data, size_t n,
                          char *msg, size_t cap)
{
    char path[4096], tmp[4200];
    snprintf(path, sizeof path, "%s/%s", dir, name);
    snprintf(tmp, sizeof tmp, "%s.tmp", path);
    int fd = open(tmp, O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0600);
    int rc = fd < 0 || write_all(fd, data, n) != 0 || fsync(fd) != 0 ? -1 : 0;
    int e = errno;
    if (fd >= 0 && close(fd) != 0 && rc == 0) {
        rc = -1;
        e = errno;
    }
    if (rc == 0 && rename(tmp, path) != 0) {
        rc = -1;
        e = errno;
    }
    if (rc != 0) {
        snprintf(msg, cap, "writing %s: %s", tmp, strerror(e));
        unlink(tmp);
        return -1;
    }
    /* The rename is durable once the directory is synced. */
    int dfd = open(dir, O_RDONLY | O_DIRECTORY | O_CLOEXEC);
    if (dfd >= 0) {
        fsync(dfd);
        close(dfd);
    }
    return 0;
}

int gsd_cache_save(gsd_cache *c, const char *dir, const char *tag, char *msg, size_t cap)
{
    size_t n;
    uint8_t *buf = serialize(c, tag, &n);
    if (!buf) {
        snprintf(msg, cap, "out of memory serializing %zu bytes", n);
        return -1;
    }
    int rc = gsd_file_write_atomic(dir, GSD_CACHE_FILE, buf, n, msg, cap);
    free(buf);
    return rc;
}

uint8_t *gsd_file_read(const char *path, size_t max, size_t *len, int *missing)
{
    *missing = 0;
    int fd = open(path, O_RDONLY | O_CLOEXEC);
    if (fd < 0) {
        *missing = errno == ENOENT;
        return NULL;
    }
    struct stat st;
    uint8_t *buf = NULL;
    if (fstat(fd, &st) == 0 && st.st_size >= 0 && (size_t)st.st_size <= max) {
        size_t n = (size_t)st.st_size, got = 0;
        buf = malloc(n ? n : 1);
        while (buf && got < n) {
            ssize_t r = read(fd, buf + got, n - got);
            if (r <= 0) {
                free(buf);
                buf = NULL;
                break;
            }
            got += (size_t)r;
        }
        *len = n;
    }
    close(fd);
    return buf;
}

/* Checks the whole file before inserting anything. */
static int parse_file(gsd_cache *c, const uint8_t *b, size_t n, const char *tag, char *msg, size_t cap)
{
    if (n < 20 || memcmp(b, "GZSC", 4) != 0 || get32(b + 4) != FILE_VERSION) {
        snprintf(msg, cap, "not a version %u cache file", FILE_VERSION);
        return 1;
    }
    if (crc32_update(0, b, n - 4) != get32(b + n - 4)) {
        snprintf(msg, cap, "checksum mismatch");
        return 1;
    }
    size_t tl = get32(b + 8);
    if (tl > MAX_TAG || 16 + tl + 4 > n) {
        snprintf(msg, cap, "bad tag length");
        return 1;
    }
    if (tl != strlen(tag) || memcmp(b + 12, tag, tl) != 0) {
        snprintf(msg, cap, "written for another model (%.*s); starting empty", (int)tl, (const char *)b + 12);
        return 1;
    }
    uint32_t count = get32(b + 12 + tl);
    size_t o = 16 + tl, end = n - 4;
    for (uint32_t i = 0; i < count; i++) {
        if (end - o < GSD_CACHE_KEY + 4 || get32(b + o + GSD_CACHE_KEY) > end - o - GSD_CACHE_KEY - 4) {
            snprintf(msg, cap, "entry %u truncated", i);
            gsd_cache_clear(c);
            return 1;
        }
        size_t len = get32(b + o + GSD_CACHE_KEY);
        if (gsd_cache_put(c, b + o, b + o + GSD_CACHE_KEY + 4, len) != 0) {
            snprintf(msg, cap, "entry %u: %zu bytes", i, len);
            gsd_cache_clear(c);
            return len > c->max_blob ? 1 : -1;
        }
        o += GSD_CACHE_KEY + 4 + len;
    }
    if (o != end) {
        snprintf(msg, cap, "%zu trailing bytes", end - o);
        gsd_cache_clear(c);
        return 1;
    }
    snprintf(msg, cap, "%u subjects", count);
    return 0;
}

int gsd_cache_load(gsd_cache *c, const char *dir, const char *tag, char *msg, size_t cap)
{
    char path[4096];
    snprintf(path, sizeof path, "%s/%s", dir, GSD_CACHE_FILE);
    size_t n = 0;
    int missing;
    /* A file can hold at most what the budget allows, plus slack. */
    uint8_t *b = gsd_file_read(path, c->budget * 2 + 4096, &n, &missing);
    if (!b) {
        snprintf(msg, cap, missing ? "no cache file" : "cannot read %s (or over the budget)", path);
        return missing ? 0 : 1;
    }
    int r = parse_file(c, b, n, tag, msg, cap);
    free(b);
    return r;
}
