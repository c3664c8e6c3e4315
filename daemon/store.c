/* What a daemon keeps of its subjects besides the subject cache (store.h):
 * fine-tuned blocks and kept inputs in their caches and, with a state
 * directory, on disk. */
#define _GNU_SOURCE
#include "store.h"

#include <ctype.h>
#include <dirent.h>
#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <time.h>
#include <unistd.h>

#include "log.h"

#define E(x) GAZESPLAT__ERROR_CODE__##x

/* ---- kept blobs: fine-tuned blocks and inputs ----------------------------------
 * Besides its gs_subject (the subject cache), a subject may have:
 *   a tuned block (STORE_TUNED), its fine-tuned tensors
 *     (gs_model_tuned_encode); the subject's cache blob then has "GSTR"
 *     and the block's checksum (its last 8 bytes) after the gs_subject;
 *   a kept input (STORE_INPUT), the normalized face a FIT kept
 *     (keep_image) for REDIRECT transfer: "GSFI", u32 side, side x side RGB.
 * Each kind lives in an LRU cache of its own (tuned_cache_mb,
 * input_cache_mb) and, with a state directory, one file per subject
 * (PREFIX<key hex>SUFFIX, written atomically), kept while the blob is in
 * its cache: the files only bring the blobs back at start (gsd_store_restore). */

#define TUNED_REF_MAGIC 0x52545347u /* "GSTR" */
#define INPUT_MAGIC 0x49465347u     /* "GSFI" */
/* A kept input's irises, after its opening: magic, count, 2 x 3 doubles. */
#define INPUT_IRIS_MAGIC 0x52495347u /* "GSIR" */
#define INPUT_IRIS_LEN (8 + 6 * sizeof(double))

static const struct store_kind {
    const char *prefix, *suffix, *what, *budget;
} store_kinds[STORE_KINDS] = {
    {"tuned-", ".gsft", "fine-tuned parameters", "tuned_cache_mb"},
    {"input-", ".gsfi", "kept input", "input_cache_mb"},
};

static gsd_cache *store_cache(const gsd_server *s, int kind)
{
    return kind == STORE_TUNED ? s->tuned : s->inputs;
}

static int store_budget_mb(const gsd_server *s, int kind)
{
    return kind == STORE_TUNED ? s->cfg.tuned_cache_mb : s->cfg.input_cache_mb;
}

/* The subject's cache blob; sum non-NULL: a fine-tuned subject. */
size_t gsd_subject_blob(const gs_subject *subj, const uint64_t *sum, uint8_t *blob, size_t cap)
{
    size_t n = gs_subject_encode(subj, blob, cap);
    if (!sum || n == 0 || n + 12 > cap)
        return sum ? 0 : n;
    uint32_t magic = TUNED_REF_MAGIC;
    memcpy(blob + n, &magic, 4);
    memcpy(blob + n + 4, sum, 8);
    return n + 12;
}

int gsd_subject_lookup(gsd_server *s, const uint8_t key[16], gs_subject *subj, int *tuned, uint64_t *sum)
{
    uint8_t blob[GS_SUBJECT_ENCODED_MAX + 12];
    long n = gsd_cache_get(s->cache, key, blob, sizeof blob);
    *tuned = 0;
    if (n < 12)
        return -1;
    uint32_t magic;
    size_t slen = gs_subject_encoded_len(blob, (size_t)n);
    if (slen && (size_t)n == slen + 12) {
        memcpy(&magic, blob + slen, 4);
        if (magic != TUNED_REF_MAGIC)
            return -1;
        memcpy(sum, blob + slen + 4, 8);
        *tuned = 1;
    } else if ((size_t)n != slen) {
        return -1;
    }
    return gs_subject_decode(blob, slen, subj, NULL) == GS_OK ? 0 : -1;
}

/* A blob file's name in the state directory, and its path. */
static void store_name(int kind, const uint8_t key[16], char out[64])
{
    char hex[33];
    gs_frame_key_hex(key, hex);
    snprintf(out, 64, "%s%s%s", store_kinds[kind].prefix, hex, store_kinds[kind].suffix);
}

static void store_path(const gsd_server *s, int kind, const uint8_t key[16], char *out, size_t cap)
{
    char name[64];
    store_name(kind, key, name);
    snprintf(out, cap, "%s/%s", s->state_dir, name);
}

/* The key of a blob file's name of this kind, or -1 for other names. */
static int store_file_key(int kind, const char *name, uint8_t key[16])
{
    const char *pre = store_kinds[kind].prefix, *suf = store_kinds[kind].suffix;
    size_t pl = strlen(pre);
    if (strncmp(name, pre, pl) || strlen(name) != pl + 32 + strlen(suf) || strcmp(name + pl + 32, suf))
        return -1;
    for (int i = 0; i < 16; i++) {
        unsigned v;
        char b[3] = {name[pl + 2 * i], name[pl + 2 * i + 1], 0};
        if (!isxdigit((unsigned char)b[0]) || !isxdigit((unsigned char)b[1]) || sscanf(b, "%x", &v) != 1)
            return -1;
        key[i] = (uint8_t)v;
    }
    return 0;
}

/* Removes the kind's files whose blob is no longer in its cache (evicted,
 * or the model changed). Under persist_mu. */
static void store_sweep_locked(gsd_server *s, int kind)
{
    DIR *d = opendir(s->state_dir);
    if (!d)
        return;
    struct dirent *e;
    while ((e = readdir(d)) != NULL) {
        uint8_t key[16];
        if (store_file_key(kind, e->d_name, key) == 0 && !gsd_cache_contains(store_cache(s, kind), key)) {
            char path[GSD_STR_MAX + 64];
            store_path(s, kind, key, path, sizeof path);
            if (unlink(path) != 0 && errno != ENOENT)
                LOG_W("%s %s: unlink: %s", store_kinds[kind].what, path, strerror(errno));
        }
    }
    closedir(d);
}

void gsd_store_sweep_all_locked(gsd_server *s)
{
    for (int k = 0; k < STORE_KINDS; k++)
        store_sweep_locked(s, k);
}

/* Keeps a subject's blob: in its cache, and on disk with a state
 * directory (a failure there is logged and counted: the blob still
 * serves until evicted or a restart). */
int gsd_store_put(gsd_server *s, int kind, const uint8_t key[16], const uint8_t *blob, size_t len,
                     char *msg, size_t cap)
{
    if (gsd_cache_put(store_cache(s, kind), key, blob, len) != 0) {
        snprintf(msg, cap, "%s (%zu bytes) over %s (%d MiB)", store_kinds[kind].what, len,
                 store_kinds[kind].budget, store_budget_mb(s, kind));
        return E(ERR_INTERNAL);
    }
    if (!s->state_dir[0])
        return 0;
    char name[64], err[400];
    store_name(kind, key, name);
    pthread_mutex_lock(&s->persist_mu);
    int r = gsd_file_write_atomic(s->state_dir, name, blob, len, err, sizeof err);
    store_sweep_locked(s, kind);
    pthread_mutex_unlock(&s->persist_mu);
    if (kind == STORE_TUNED)
        atomic_fetch_add(r == 0 ? &s->ctr.tuned_saves : &s->ctr.tuned_save_failures, 1);
    else
        atomic_fetch_add(r == 0 ? &s->ctr.input_saves : &s->ctr.input_save_failures, 1);
    if (r != 0)
        LOG_E("%s: %s", store_kinds[kind].what, err);
    return 0;
}

typedef struct store_file {
    uint8_t key[16];
    struct timespec mtime;
} store_file;

static int by_mtime(const void *a, const void *b)
{
    const struct timespec *x = &((const store_file *)a)->mtime, *y = &((const store_file *)b)->mtime;
    return x->tv_sec != y->tv_sec ? (x->tv_sec < y->tv_sec ? -1 : 1)
                                  : (x->tv_nsec < y->tv_nsec ? -1 : x->tv_nsec > y->tv_nsec);
}

/* The kind's files of cached subjects, oldest first (so that the budget
 * keeps the newest); *n their count. NULL when none (or out of memory). */
static store_file *store_list(gsd_server *s, int kind, size_t *n)
{
    DIR *d = opendir(s->state_dir);
    *n = 0;
    if (!d)
        return NULL;
    store_file *f = NULL;
    size_t cap = 0;
    struct dirent *e;
    while ((e = readdir(d)) != NULL) {
        uint8_t key[16];
        struct stat st;
        char path[GSD_STR_MAX + 64];
        if (store_file_key(kind, e->d_name, key) != 0 || !gsd_cache_contains(s->cache, key))
            continue;
        store_path(s, kind, key, path, sizeof path);
        if (stat(path, &st) != 0)
            continue;
        if (*n == cap) {
            store_file *g = realloc(f, (cap = cap ? 2 * cap : 64) * sizeof *f);
            if (!g)
                break;
            f = g;
        }
        memcpy(f[*n].key, key, 16);
        f[(*n)++].mtime = st.st_mtim;
    }
    closedir(d);
    if (*n)
        qsort(f, *n, sizeof *f, by_mtime);
    return f;
}

/* At start: the blobs of cached subjects back into their caches; every
 * other file of the kind goes. */
void gsd_store_restore(gsd_server *s, int kind)
{
    size_t n = 0;
    store_file *f = store_list(s, kind, &n);
    gsd_cache *c = store_cache(s, kind);
    for (size_t i = 0; i < n; i++) {
        char path[GSD_STR_MAX + 64];
        size_t len = 0;
        int missing;
        store_path(s, kind, f[i].key, path, sizeof path);
        uint8_t *b = gsd_file_read(path, (size_t)store_budget_mb(s, kind) << 20, &len, &missing);
        if (b) /* a blob over the budget is refused here and its file swept below */
            gsd_cache_put(c, f[i].key, b, len);
        free(b);
    }
    free(f);
    pthread_mutex_lock(&s->persist_mu);
    store_sweep_locked(s, kind);
    pthread_mutex_unlock(&s->persist_mu);
    gsd_cache_stats st;
    gsd_cache_stats_get(c, &st);
    LOG_I("%s: %llu restored (%llu MiB)", store_kinds[kind].what, (unsigned long long)st.entries,
          (unsigned long long)(st.bytes >> 20));
}

/* ---- kept inputs -------------------------------------------------------------- */

/* Keeps face (the model's size) as key's input. */
int gsd_input_keep(gsd_server *s, const uint8_t key[16], const gs_io_image *face,
                   const gs_xfer_eyes *eyes, char *msg, size_t cap)
{
    const uint8_t *opening = eyes ? eyes->opening : NULL;
    size_t row = (size_t)face->width * 3, img = row * (size_t)face->height;
    size_t px = (size_t)face->width * face->height;
    size_t len = 8 + img + (opening ? px + INPUT_IRIS_LEN : 0);
    uint8_t *b = malloc(len);
    if (!b) {
        snprintf(msg, cap, "out of memory");
        return E(ERR_INTERNAL);
    }
    uint32_t hdr[2] = {INPUT_MAGIC, (uint32_t)face->width};
    memcpy(b, hdr, 8);
    for (int y = 0; y < face->height; y++)
        memcpy(b + 8 + (size_t)y * row, face->data + (size_t)y * face->stride, row);
    if (opening) { /* after the image: a blob without them is still an input */
        memcpy(b + 8 + img, opening, px);
        uint32_t ih[2] = {INPUT_IRIS_MAGIC, (uint32_t)eyes->n_iris};
        memcpy(b + 8 + img + px, ih, 8);
        memcpy(b + 8 + img + px + 8, eyes->iris, sizeof eyes->iris);
    }
    int e = gsd_store_put(s, STORE_INPUT, key, b, len, msg, cap);
    free(b);
    return e;
}

/* key's kept input as a size x size image (out->data malloc'd); -1 when
 * none is kept, or it does not fit the model. */
int gsd_input_get(gsd_server *s, const uint8_t key[16], int size, gs_io_image *out,
                  uint8_t **opening, gs_xfer_eyes *eyes)
{
    uint8_t *b = NULL;
    long n = gsd_cache_get_alloc(s->inputs, key, &b);
    uint32_t hdr[2] = {0, 0};
    size_t px = (size_t)size * size, img = 3 * px;
    if (n >= 8)
        memcpy(hdr, b, 8);
    *opening = NULL;
    memset(eyes, 0, sizeof *eyes);
    size_t with_iris = 8 + img + px + INPUT_IRIS_LEN;
    uint32_t ih[2] = {0, 0};
    if ((size_t)n == with_iris)
        memcpy(ih, b + 8 + img + px, 8);
    if (n < 8 || hdr[0] != INPUT_MAGIC || hdr[1] != (uint32_t)size ||
        ((size_t)n != 8 + img && (size_t)n != 8 + img + px && (size_t)n != with_iris) ||
        ((size_t)n == with_iris && (ih[0] != INPUT_IRIS_MAGIC || ih[1] > 2))) {
        free(b);
        return -1;
    }
    if ((size_t)n >= 8 + img + px) {
        if (!(*opening = malloc(px))) {
            free(b);
            return -1;
        }
        memcpy(*opening, b + 8 + img, px);
        eyes->opening = *opening;
    }
    if ((size_t)n == with_iris) {
        eyes->n_iris = (int)ih[1];
        memcpy(eyes->iris, b + 8 + img + px + 8, sizeof eyes->iris);
    }
    memmove(b, b + 8, img);
    *out = (gs_io_image){size, size, 3 * (size_t)size, b};
    return 0;
}

