/* gazesplat augment --merge N --out DIR: the N finished shards of one run
 * (labels-I-of-N.jsonl, augment-I-of-N.h5, .augment-I-of-N/manifest, all in
 * DIR) made into the unsharded run's labels.jsonl and augment.h5, byte for
 * byte: lines in global index order with h5_row renumbered, HDF5 rows in
 * the same order. The PNGs already carry global names and stay where they
 * are. Checked first: every shard finished, all of one run (the same
 * sources and targets), every sample exactly once. A run with
 * --min-quality has dropped-I-of-N.jsonl in every shard: each sample is
 * then in exactly one shard's labels or dropped list, the HDF5 and the
 * labels hold the kept ones and dropped.jsonl the others, in index order. */
#define _POSIX_C_SOURCE 200809L
#include "augment_merge.h"

#include <errno.h>
#include <fcntl.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include "gazesplat/xgaze_h5.h"

typedef struct line {
    const char *p;  /* the line, its newline included */
    size_t len;
    int shard;
    size_t row;     /* its row in the shard's files */
} line;

typedef struct merge {
    const cli_command *cmd;
    const char *out;
    long n;
    uint8_t **bufs;  /* each shard's labels file */
    uint8_t **dbufs; /* each shard's dropped list (--min-quality) */
    line *lines;     /* kept samples' labels by global index */
    line *dlines;    /* dropped samples' lines by global index (NULL: no gate) */
    size_t total;    /* samples of the run (the manifests' target count) */
    gs_h5_reader **h5;
} merge;

/* Reads shard i's manifest: finished, and the run's source and target
 * counts (the same in every shard of one run). */
static int read_manifest(merge *m, long i, size_t *nsrc, size_t *ntg)
{
    char path[4300];
    snprintf(path, sizeof path, "%s/.augment-%ld-of-%ld/manifest", m->out, i, m->n);
    uint8_t *b = NULL;
    size_t len = 0;
    if (cli_read_file(path, (size_t)1 << 30, &b, &len))
        return cli_fail(m->cmd, "%s: cannot read (%s): is shard %ld/%ld in %s?", path,
                        strerror(errno), i, m->n, m->out);
    char head[256];
    size_t hl = len < sizeof head - 1 ? len : sizeof head - 1;
    memcpy(head, b, hl);
    head[hl] = 0;
    unsigned long long fp;
    int ok = sscanf(head, "gazesplat-augment-manifest 1 %llx %zu %zu\n", &fp, nsrc, ntg) == 3;
    int done = len >= 9 && !memcmp(b + len - 9, "finished\n", 9);
    free(b);
    if (!ok)
        return cli_fail(m->cmd, "%s: not an augment manifest", path);
    if (!done)
        return cli_fail(m->cmd, "%s: shard %ld/%ld is not finished; run it to the end first",
                        path, i, m->n);
    return CLI_OK;
}

/* The number after "key": in a line (the first occurrence), or -1. */
static long long field(const char *p, size_t len, const char *key, const char **at, size_t *digits)
{
    size_t kl = strlen(key);
    for (size_t o = 0; o + kl < len; o++) {
        if (memcmp(p + o, key, kl))
            continue;
        size_t d = o + kl, e = d;
        long long v = 0;
        while (e < len && p[e] >= '0' && p[e] <= '9' && e - d < 18)
            v = v * 10 + (p[e++] - '0');
        if (e == d)
            return -1;
        if (at)
            *at = p + d;
        if (digits)
            *digits = e - d;
        return v;
    }
    return -1;
}

/* Where global index idx already is (a kept or a dropped sample), or NULL. */
static const line *taken(const merge *m, long long idx, const char **as)
{
    if (m->lines[idx].p) {
        *as = "labels";
        return &m->lines[idx];
    }
    *as = "dropped list";
    return m->dlines && m->dlines[idx].p ? &m->dlines[idx] : NULL;
}

/* Shard i's labels (dropped 0) or dropped list (1): each line into its
 * global index's slot. */
static int take_lines(merge *m, long i, int dropped, int *has_row)
{
    char path[4300];
    snprintf(path, sizeof path, "%s/%s-%ld-of-%ld.jsonl", m->out, dropped ? "dropped" : "labels",
             i, m->n);
    size_t len = 0;
    struct stat st;
    uint8_t **buf = dropped ? &m->dbufs[i] : &m->bufs[i];
    if (stat(path, &st) != 0)
        return cli_fail(m->cmd, "%s: cannot read (%s)", path, strerror(errno));
    if (st.st_size > 0 && cli_read_file(path, (size_t)1 << 34, buf, &len))
        return cli_fail(m->cmd, "%s: cannot read (%s)", path, strerror(errno));
    const char *p = (const char *)*buf, *end = p + len;
    size_t row = 0;
    while (p < end) {
        const char *nl = memchr(p, '\n', (size_t)(end - p));
        if (!nl)
            return cli_fail(m->cmd, "%s:%zu: no newline at the end (a torn file?)", path, row + 1);
        size_t n = (size_t)(nl + 1 - p);
        long long idx = field(p, n, "\"index\":", NULL, NULL);
        if (idx < 0)
            return cli_fail(m->cmd, "%s:%zu: no \"index\"", path, row + 1);
        if ((size_t)idx >= m->total)
            return cli_fail(m->cmd, "%s:%zu: index %lld, but the run has %zu samples", path,
                            row + 1, idx, m->total);
        const char *as;
        const line *o = taken(m, idx, &as);
        if (o)
            return cli_fail(m->cmd, "%s:%zu: index %lld also in shard %d's %s (line %zu)", path,
                            row + 1, idx, o->shard, as, o->row + 1);
        int hr = field(p, n, ",\"h5_row\":", NULL, NULL) >= 0;
        if (!dropped && *has_row < 0)
            *has_row = hr;
        else if (!dropped && *has_row != hr)
            return cli_fail(m->cmd, "%s:%zu: h5_row %s, unlike the lines before", path, row + 1,
                            hr ? "present" : "absent");
        (dropped ? m->dlines : m->lines)[idx] = (line){p, n, (int)i, row};
        row++;
        p = nl + 1;
    }
    return CLI_OK;
}

/* Writes path atomically: path.tmp, fsync, rename. */
static int commit(merge *m, const char *path, const line *lines, size_t count, int renumber)
{
    char tmp[4400];
    snprintf(tmp, sizeof tmp, "%s.tmp", path);
    int fd = open(tmp, O_WRONLY | O_CREAT | O_TRUNC, 0666);
    int rc = fd < 0 ? -1 : 0;
    for (size_t r = 0; !rc && r < count; r++) {
        const line *l = &lines[r];
        const char *at;
        size_t digits;
        if (renumber && field(l->p, l->len, ",\"h5_row\":", &at, &digits) >= 0) {
            char num[32];
            int k = snprintf(num, sizeof num, "%zu", r);
            rc = cli_write_all(fd, l->p, (size_t)(at - l->p)) || cli_write_all(fd, num, (size_t)k) ||
                 cli_write_all(fd, at + digits, l->len - (size_t)(at + digits - l->p));
        } else
            rc = cli_write_all(fd, l->p, l->len);
    }
    if (!rc && fsync(fd))
        rc = -1;
    int e = errno;
    if (fd >= 0 && close(fd) && !rc) {
        rc = -1;
        e = errno;
    }
    if (!rc && rename(tmp, path)) {
        rc = -1;
        e = errno;
    }
    if (rc) {
        unlink(tmp);
        return cli_fail(m->cmd, "%s: cannot write (%s)", path, strerror(e));
    }
    return CLI_OK;
}

/* augment.h5 from the shards' files: the rows of the count samples in
 * kept (global index order). */
static int merge_h5(merge *m, const line *kept, size_t count)
{
    char path[4300], tmp[4400];
    gs_error err = {0, ""};
    int side = 0;
    for (long i = 0; i < m->n; i++) {
        snprintf(path, sizeof path, "%s/augment-%ld-of-%ld.h5", m->out, i, m->n);
        gs_h5_info info;
        if (gs_h5_open(path, &m->h5[i], &info, &err))
            return cli_fail(m->cmd, "%s: %s", path, err.msg);
        if (info.height != info.width || (side && info.height != side))
            return cli_fail(m->cmd, "%s: %d x %d patches, unlike the other shards' %d x %d", path,
                            info.height, info.width, side, side);
        side = info.height;
    }
    snprintf(path, sizeof path, "%s/augment.h5", m->out);
    snprintf(tmp, sizeof tmp, "%s.tmp", path);
    gs_h5_writer *w = NULL;
    if (gs_h5_create(tmp, count, side, &w, &err))
        return cli_fail(m->cmd, "%s: %s", path, err.msg);
    size_t bytes = (size_t)side * (size_t)side * 3;
    uint8_t *patch = malloc(bytes);
    int rc = patch ? CLI_OK : cli_fail(m->cmd, "out of memory");
    for (size_t r = 0; !rc && r < count; r++) {
        const line *l = &kept[r];
        float gaze[2], head[2];
        if (gs_h5_read_row(m->h5[l->shard], l->row, patch, gaze, head, &err) ||
            gs_h5_write_rows(w, r, 1, patch, gaze, head, &err))
            rc = cli_fail(m->cmd, "%s (row %zu of shard %d): %s", path, l->row, l->shard, err.msg);
    }
    free(patch);
    if (rc) {
        gs_h5_abort(w);
    } else if (gs_h5_finish(w, &err)) {
        rc = cli_fail(m->cmd, "%s: %s", path, err.msg);
    } else if (cli_fsync_path(tmp) || rename(tmp, path)) {
        rc = cli_fail(m->cmd, "%s: cannot write (%s)", path, strerror(errno));
    }
    if (rc)
        unlink(tmp);
    return rc;
}

/* Whether shard i wrote the file NAME-i-of-n.EXT. */
static int shard_has(const merge *m, long i, const char *name, const char *ext)
{
    char path[4300];
    struct stat st;
    snprintf(path, sizeof path, "%s/%s-%ld-of-%ld.%s", m->out, name, i, m->n, ext);
    return stat(path, &st) == 0;
}

/* Every sample once: in a shard's labels, or (--min-quality) in a shard's
 * dropped list; the kept ones packed into kept (index order), the dropped
 * into dropped, their counts in *nk, *nd, the kept without a score in *nu. */
static int sort_samples(const merge *m, line *kept, line *dropped, size_t *nk, size_t *nd,
                        size_t *nu)
{
    static const char unscored[] = ",\"quality\":null}\n";
    size_t ul = sizeof unscored - 1;
    *nk = *nd = *nu = 0;
    for (size_t r = 0; r < m->total; r++) {
        const line *l = &m->lines[r];
        if (l->p) {
            kept[(*nk)++] = *l;
            *nu += l->len >= ul && !memcmp(l->p + l->len - ul, unscored, ul);
        } else if (m->dlines && m->dlines[r].p) {
            dropped[(*nd)++] = m->dlines[r];
        } else {
            return cli_fail(m->cmd, "sample %zu is in no shard's labels%s (of %zu)", r,
                            m->dlines ? " or dropped list" : "", m->total);
        }
    }
    return CLI_OK;
}

/* The merge's last line; on stderr when every sample was dropped. */
static void merge_report(const merge *m, int h5, size_t nk, size_t nd, size_t nu)
{
    char gate[300] = "";
    if (m->dlines)
        snprintf(gate, sizeof gate, "; --min-quality: %zu kept (%zu of them unscored), %zu dropped "
                 "(listed in dropped.jsonl)", nk, nu, nd);
    printf("gazesplat augment: merged %ld shards: %zu images -> %s (labels.jsonl%s%s)%s\n", m->n,
           nk, m->out, h5 ? ", augment.h5" : "", m->dlines ? ", dropped.jsonl" : "", gate);
    if (m->dlines && nk == 0 && nd > 0)
        fprintf(stderr, "gazesplat augment: every sample of the run was dropped: all %zu scored "
                "under --min-quality; labels.jsonl is empty%s and dropped.jsonl lists them\n", nd,
                h5 ? ", augment.h5 has no rows," : "");
}

int aug_merge(const cli_command *cmd, const char *out, long n)
{
    if (n < 2 || n > 1000000)
        return cli_fail(cmd, "--merge: %ld shards (2..1000000)", n);
    merge m = {cmd, out, n, NULL, NULL, NULL, NULL, 0, NULL};
    size_t nsrc0 = 0, nsrc, ntg;
    int rc = CLI_OK;
    for (long i = 0; i < n && !rc; i++) {
        if ((rc = read_manifest(&m, i, &nsrc, &ntg)))
            break;
        if (i == 0) {
            nsrc0 = nsrc;
            m.total = ntg;
        } else if (nsrc != nsrc0 || ntg != m.total) {
            rc = cli_fail(cmd, "shard %ld/%ld: %zu sources and %zu samples, shard 0/%ld: %zu and "
                          "%zu: not shards of one run", i, n, nsrc, ntg, n, nsrc0, m.total);
        }
    }
    if (rc)
        return rc;
    int h5 = 0, gate = 0;
    for (long i = 0; i < n; i++) {
        h5 += shard_has(&m, i, "augment", "h5");
        gate += shard_has(&m, i, "dropped", "jsonl");
    }
    if (gate && gate != n)
        return cli_fail(cmd, "%d of %ld shards have a dropped list (dropped-I-of-%ld.jsonl, "
                        "--min-quality): all or none", gate, n, n);
    size_t cells = m.total ? m.total : 1;
    m.bufs = calloc((size_t)n, sizeof *m.bufs);
    m.dbufs = calloc((size_t)n, sizeof *m.dbufs);
    m.h5 = calloc((size_t)n, sizeof *m.h5);
    m.lines = calloc(cells, sizeof *m.lines);
    m.dlines = gate ? calloc(cells, sizeof *m.dlines) : NULL;
    line *kept = calloc(cells, sizeof *kept), *dropped = calloc(cells, sizeof *dropped);
    if (!m.bufs || !m.dbufs || !m.h5 || !m.lines || (gate && !m.dlines) || !kept || !dropped)
        rc = cli_fail(cmd, "out of memory");
    int has_row = -1;
    for (long i = 0; i < n && !rc; i++)
        if (!(rc = take_lines(&m, i, 0, &has_row)) && gate)
            rc = take_lines(&m, i, 1, NULL);
    size_t nk = 0, nd = 0, nu = 0;
    if (!rc)
        rc = sort_samples(&m, kept, dropped, &nk, &nd, &nu);
    if (!rc && h5 && h5 != n)
        rc = cli_fail(cmd, "%d of %ld shards have an HDF5 file (augment-I-of-%ld.h5): all or none",
                      h5, n, n);
    if (!rc && h5 && has_row != 1 && nk)
        rc = cli_fail(cmd, "the shards have HDF5 files but their labels no h5_row");
    char labels[4300], dlist[4300];
    snprintf(labels, sizeof labels, "%s/labels.jsonl", out);
    snprintf(dlist, sizeof dlist, "%s/dropped.jsonl", out);
    if (!rc && h5)
        rc = merge_h5(&m, kept, nk);
    if (!rc && gate)
        rc = commit(&m, dlist, dropped, nd, 0);
    if (!rc)
        rc = commit(&m, labels, kept, nk, h5 > 0);
    if (!rc && cli_fsync_path(out))
        rc = cli_fail(cmd, "%s: cannot sync (%s)", out, strerror(errno));
    if (!rc)
        merge_report(&m, h5, nk, nd, nu);
    for (long i = 0; m.bufs && i < n; i++)
        free(m.bufs[i]);
    for (long i = 0; m.dbufs && i < n; i++)
        free(m.dbufs[i]);
    for (long i = 0; m.h5 && i < n; i++)
        gs_h5_close(m.h5[i]);
    free(m.bufs);
    free(m.dbufs);
    free(m.h5);
    free(m.lines);
    free(m.dlines);
    free(kept);
    free(dropped);
    return rc;
}
