/* gazesplat augment: a gaze dataset made larger offline. Each source face
 * (a photo, a normalized face, or a row of an ETH-XGaze-style HDF5 file) is
 * fitted as gazesplat redirect fits it (gazesplat/redirect.h, the same library
 * calls and defaults), optionally fine-tuned, and rendered at targets from
 * a grid, a list, a seeded distribution or a file. Outputs: PNGs and
 * labels.jsonl, and/or an ETH-XGaze-style HDF5 file.
 *
 * Crash safety (docs/augment.md): each source's outputs are written to
 * temporary names, fsync'd and renamed, then the source is appended to the
 * manifest and fsync'd. The final labels file and HDF5 are assembled only
 * when every source of the shard is done, from the per-source parts, in
 * source order, so a run killed at any moment and run again ends with the
 * bytes an uninterrupted run writes. With --min-quality the manifest line
 * of a source also records each sample's decision (kept, dropped, kept
 * unscored), so a resume neither re-adds a dropped sample nor counts one
 * twice. */
#define _POSIX_C_SOURCE 200809L
#include <dirent.h>
#include <errno.h>
#include <fcntl.h>
#include <math.h>
#include <stdarg.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>
#include <sys/stat.h>
#include <time.h>
#include <unistd.h>

#include "augment_merge.h"
#include "augment_remote.h"
#include "augment_table.h"
#include "gs_client.h"
#include "cli.h"
#include "gazesplat/redirect.h"
#include "gazesplat/face.h"
#include "gazesplat/geom.h"
#include "gazesplat/image_io.h"
#include "gazesplat/model.h"
#include "gazesplat/nn.h"
#include "gazesplat/xgaze_h5.h"

static int run_augment(const cli_command *cmd, cli_opt *o);

static const cli_opt augment_opts[] = {
    {"--model", 1, NULL}, {"--input", 1, NULL}, {"--out", 1, NULL}, {"--grid", 1, NULL},
    {"--gaze-deg", 1, NULL}, {"--uniform", 1, NULL}, {"--per-image", 1, NULL},
    {"--targets", 1, NULL}, {"--head-deg", 1, NULL}, {"--head-uniform", 1, NULL},
    {"--labels", 1, NULL}, {"--format", 1, NULL}, {"--shard", 1, NULL}, {"--seed", 1, NULL},
    {"--iters", 1, NULL}, {"--finetune", 1, NULL}, {"--finetune-lr", 1, NULL},
    {"--no-transfer", 0, NULL}, {"--fit-labels", 0, NULL}, {"--h5-rgb", 0, NULL},
    {"--threads", 1, NULL}, {"--size", 1, NULL}, {"--addr", 1, NULL}, {"--token", 1, NULL},
    {"--merge", 1, NULL}, {"--no-gate", 0, NULL}, {"--quality", 0, NULL}, {"--retries", 1, NULL},
    {"--min-quality", 1, NULL}};

const cli_command cli_augment_command = {
    "augment",
    "augment a gaze dataset offline: fit each face, render it at new gazes (PNG/JSONL, HDF5)",
    "usage: gazesplat augment (--model M | --addr ADDR [--token T])\n"
    "                         --input DIR|FILE.h5 --out DIR\n"
    "                         (--grid P0:P1:STEP,Y0:Y1:STEP | --gaze-deg \"P,Y;P,Y\"\n"
    "                          | --uniform P0,P1,Y0,Y1 --per-image N | --targets FILE)\n"
    "                         [--head-deg \"P,Y;P,Y\" | --head-uniform P0,P1,Y0,Y1]\n"
    "                         [--labels FILE] [--format png|h5|both] [--shard I/N]\n"
    "                         [--seed N] [--iters N] [--finetune N] [--finetune-lr X]\n"
    "                         [--no-transfer] [--fit-labels] [--h5-rgb] [--size S]\n"
    "                         [--threads N] [--no-gate] [--quality] [--min-quality X]\n"
    "                         [--retries N]\n"
    "       gazesplat augment --merge N --out DIR\n"
    "\n"
    "  --model M        fit and render in this process with model file M\n"
    "  --addr ADDR      or through gazesplatd at ADDR (unix:PATH, tcp:HOST:PORT or\n"
    "                   a socket path; --token T or $GAZESPLAT_TOKEN): FIT, then\n"
    "                   REDIRECT by the subject's key, the same options sent.\n"
    "                   Each source on a connection of its own that opens with\n"
    "                   the source's route key, so a proxy hashing it (HAProxy:\n"
    "                   deploy/haproxy) spreads the sources over its daemons;\n"
    "                   a source whose daemon went away is fitted again where\n"
    "                   the proxy sends it next (--retries N tries in all, 4)\n"
    "\n"
    "Inputs (--input):\n"
    "  DIR              its .png/.jpg/.jpeg files in byte order of name: a file\n"
    "                   of the model's size is a normalized face, any other a\n"
    "                   photo (its largest face is detected and normalized as\n"
    "                   gazesplat redirect does)\n"
    "  FILE.h5          ETH-XGaze layout: face_patch N x H x W x 3 uint8 (BGR,\n"
    "                   as ETH-XGaze stores it; --h5-rgb: RGB), optional\n"
    "                   face_gaze and face_head_pose N x 2 (radians); patches\n"
    "                   of another size are resized to the model's\n"
    "  --labels FILE    (DIR) CSV with a header row, or JSON Lines: file (the\n"
    "                   image's name in DIR), and any of gaze_pitch_deg,\n"
    "                   gaze_yaw_deg, head_pitch_deg, head_yaw_deg (normalized\n"
    "                   camera frame, as ETH-XGaze's labels), subject\n"
    "  --fit-labels     normalized faces: fit with the labelled gaze and head\n"
    "                   pose as known (default: estimated; labels are copied)\n"
    "\n"
    "Targets (gaze in the head frame, degrees; pitch > 0 up, yaw > 0 toward\n"
    "image-left; the model's range: |pitch| <= 50, |yaw| <= 60):\n"
    "  --grid P0:P1:STEP,Y0:Y1:STEP  every pitch x yaw of the grid, ends included\n"
    "  --gaze-deg LIST  the same list for every image, ';'-separated\n"
    "  --uniform P0,P1,Y0,Y1 --per-image N  N draws per image, uniform in the\n"
    "                   box; image k's draws come from (--seed, k) alone, so\n"
    "                   they do not depend on --shard\n"
    "  --targets FILE   CSV or JSON Lines: file (DIR) or row (HDF5),\n"
    "                   gaze_pitch_deg, gaze_yaw_deg[, head_pitch_deg,\n"
    "                   head_yaw_deg]; one line per target\n"
    "  --head-deg LIST  also change the head pose (normalized camera, |angle|\n"
    "                   <= 70): every gaze target at each of these poses\n"
    "  --head-uniform P0,P1,Y0,Y1  a head pose drawn per target\n"
    "                   (default: the fitted head pose)\n"
    "\n"
    "Outputs (--out DIR, created if needed):\n"
    "  --format F       png: DIR/images/NNNNNNNN.png; h5: DIR/augment.h5\n"
    "                   (ETH-XGaze layout, face_patch BGR); both (default).\n"
    "                   DIR/labels.jsonl always: one line per image (fields:\n"
    "                   docs/augment.md), in the HDF5's row order\n"
    "  --size S         output patches of S x S px (16..1024), resized\n"
    "                   (bilinear) from the model's renders (default: the\n"
    "                   model's size; e.g. 224 for ETH-XGaze's patch size)\n"
    "  --shard I/N      only sources k with k mod N = I (0 <= I < N); files\n"
    "                   named labels-I-of-N.jsonl and augment-I-of-N.h5;\n"
    "                   image names and targets as in the unsharded run\n"
    "  Resumable: DIR/.augment (.augment-I-of-N with --shard) holds the\n"
    "  manifest and the per-source parts; run the same command again after\n"
    "  a crash, a kill or a full disk and it continues where it stopped,\n"
    "  ending with the bytes an uninterrupted run writes.\n"
    "  --merge N        after the N shards of one run finished in DIR (a shared\n"
    "                   folder; a Slurm job array: deploy/slurm): write DIR's\n"
    "                   labels.jsonl and augment.h5, the unsharded run's bytes;\n"
    "                   checks that every shard finished and every image is\n"
    "                   there once\n"
    "\n"
    "Fit and render: the daemon's served setting by default, through the\n"
    "library calls gazesplat redirect makes: the fit to its plateau, at most\n"
    "--iters N (200); --finetune N steps (15; 0: none) at --finetune-lr X\n"
    "(0.004) with the mirrored view; detail transfer with the eyeball warp\n"
    "(--no-transfer: the model's render alone). --seed N (0): --uniform's\n"
    "and --head-uniform's draws. --threads N (2): the same bytes for any N.\n"
    "\n"
    "Every source goes through the face gate first (docs/face.md): a flat or\n"
    "noise image, and in a photo no face, eyes under 16 px or closed, a head\n"
    "beyond the trained range or a face cut by the border, stop the run with\n"
    "exit status 3 naming the source and the reason; --no-gate: augment\n"
    "every source whatever it holds.\n"
    "--quality: each gaze-only sample's label gets its redirect quality\n"
    "(docs/face.md; 28 ms a sample at 256 px), else null.\n"
    "--min-quality X (0..1; implies --quality): a gaze-only sample scoring\n"
    "under X is not written: no image, no HDF5 row, no label. Each one is\n"
    "listed in DIR/dropped.jsonl (dropped-I-of-N.jsonl with --shard: index,\n"
    "source, subject, target, score, reason). A sample without a score (a\n"
    "head change; a face whose landmarks were not found) is kept and counted\n"
    "as unscored. The HDF5 holds the kept samples only, in order; images\n"
    "and index keep the global numbering. The last line counts kept,\n"
    "dropped and unscored; a run whose every sample was dropped exits 0\n"
    "and says so on stderr (docs/augment.md).\n"
    "\n"
    "Exit status: 0 done, 1 a failure (named with its file and line or row;\n"
    "the sources done are kept), 2 bad usage, 3 a source the gate refused.\n",
    .opts = augment_opts,
    .nopts = CLI_NOPTS(augment_opts),
    .run_opts = run_augment,
};

#define DEG (3.14159265358979323846 / 180.0)
#define MAX_SOURCES 10000000
#define MAX_TARGETS_PER_SOURCE 4096

enum {
    O_MODEL, O_INPUT, O_OUT, O_GRID, O_GAZE, O_UNIFORM, O_PER, O_TARGETS, O_HEAD, O_HEADU,
    O_LABELS, O_FORMAT, O_SHARD, O_SEED, O_ITERS, O_FT, O_FTLR, O_TRANSFER, O_FITLAB, O_RGB,
    O_THREADS, O_SIZE, O_ADDR, O_TOKEN, O_MERGE, O_NOGATE, O_QUALITY, O_RETRIES, O_MINQ, O_N
};

typedef struct target {
    double gp, gy;   /* gaze, head frame, radians */
    int use_head;
    double hp, hy;   /* head angles, normalized camera, radians */
} target;

typedef struct source {
    char *name;       /* file name in DIR; NULL for HDF5 rows */
    size_t row;       /* HDF5 row */
    char *subject;    /* NULL: none */
    int has_gaze, has_head;
    double gaze[2], head[2]; /* labels, radians, normalized camera */
    size_t t0, nt;    /* targets[t0 .. t0 + nt) */
    size_t first;     /* global index of its first sample */
} source;

typedef struct job {
    const cli_command *cmd;
    const char *input, *out;
    int is_h5, h5_rgb, fit_labels, transfer, want_png, want_h5;
    int gate;    /* the face gate (off: --no-gate) */
    int quality; /* --quality: each gaze-only sample's redirect quality */
    int min_q;          /* --min-quality given: samples scoring under it are dropped */
    double min_quality; /* its X, 0..1 */
    char *decide;       /* with min_q, per target of j->tg: 'k' kept, 'd' dropped,
                           'u' kept unscored, 0 not made yet */
    int refused; /* load_face: the gate refused the source */
    long iters, shard_i, shard_n;
    gs_finetune_options ft;
    source *src;
    size_t nsrc;
    target *tg;
    size_t ntg;
    char h5_name[512]; /* basename of the HDF5 input */
    char state[4000], manifest[4100], labels_path[4100], h5_path[4100], dropped_path[4100];
    gs_model *model;
    gs_model_info info;
    gs_pool *pool;
    gs_h5_reader *h5;
    gs_h5_info h5i;
    gs_face_detector *det;
    gs_face_shape_model *sp;
    uint64_t fingerprint;
    long write_budget; /* test hook: writes left before ENOSPC (-1: off) */
    int out_size;      /* output patches, px (--size; default the model's) */
    const char *addr, *token; /* --addr (fits and renders through gazesplatd), --token */
    char server[256];  /* the first HELLO_OK's server name */
    long retries;      /* --retries: tries of one source in all */
} job;

/* ---- small helpers ---- */

static uint64_t fnv(uint64_t h, const void *p, size_t n)
{
    const unsigned char *b = p;
    for (size_t i = 0; i < n; i++) {
        h ^= b[i];
        h *= 1099511628211ull;
    }
    return h;
}

static uint64_t fnv_str(uint64_t h, const char *s)
{
    return fnv(h, s ? s : "\x01", s ? strlen(s) + 1 : 1);
}

static uint64_t splitmix(uint64_t *x)
{
    uint64_t z = (*x += 0x9E3779B97F4A7C15ull);
    z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
    z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
    return z ^ (z >> 31);
}

static double uniform(uint64_t *x, double lo, double hi)
{
    double u = (double)(splitmix(x) >> 11) * (1.0 / 9007199254740992.0);
    return lo + (hi - lo) * u;
}

/* A finite decimal number, the whole string. */
static int parse_num(const char *s, double *out)
{
    char *e;
    if (!s || !*s)
        return -1;
    errno = 0;
    double v = strtod(s, &e);
    if (errno == ERANGE || *e != '\0' || !isfinite(v))
        return -1;
    *out = v;
    return 0;
}

static int gaze_in_range(double p, double y)
{
    return fabs(p) <= GS_MODEL_MAX_GAZE_PITCH + 1e-9 && fabs(y) <= GS_MODEL_MAX_GAZE_YAW + 1e-9;
}

static int head_in_range(double p, double y)
{
    return fabs(p) <= GS_MODEL_MAX_HEAD_ANGLE + 1e-9 && fabs(y) <= GS_MODEL_MAX_HEAD_ANGLE + 1e-9;
}

/* "P,Y;P,Y" in degrees into a malloc'd list (radians). */
static int parse_pairs(const char *s, double (**out)[2], size_t *n)
{
    *out = NULL;
    *n = 0;
    size_t cap = 0;
    while (*s) {
        char item[64];
        size_t len = strcspn(s, ";");
        float v[2];
        if (len == 0 || len >= sizeof item || *n == MAX_TARGETS_PER_SOURCE)
            goto bad;
        memcpy(item, s, len);
        item[len] = 0;
        if (cli_parse_floats(item, v, 2))
            goto bad;
        if (*n == cap) {
            cap = cap ? 2 * cap : 16;
            double(*g)[2] = realloc(*out, cap * sizeof *g);
            if (!g)
                goto bad;
            *out = g;
        }
        (*out)[*n][0] = v[0] * DEG;
        (*out)[*n][1] = v[1] * DEG;
        (*n)++;
        s += len;
        if (*s == ';')
            s++;
    }
    if (*n)
        return 0;
bad:
    free(*out);
    *out = NULL;
    return -1;
}

/* "A:B:STEP" (degrees): its values A, A + STEP, ... <= B. */
static int parse_range(const char *s, double *lo, double *hi, double *step)
{
    char buf[128];
    if (strlen(s) >= sizeof buf)
        return -1;
    strcpy(buf, s);
    char *a = buf, *b = strchr(a, ':');
    if (!b)
        return -1;
    *b++ = 0;
    char *c = strchr(b, ':');
    if (!c)
        return -1;
    *c++ = 0;
    if (parse_num(a, lo) || parse_num(b, hi) || parse_num(c, step) || !(*step > 0) || *hi < *lo)
        return -1;
    return (*hi - *lo) / *step > MAX_TARGETS_PER_SOURCE ? -1 : 0;
}

static int grid_values(double lo, double hi, double step, double *v)
{
    int n = 0;
    for (int i = 0;; i++) {
        double x = lo + i * step;
        if (x > hi + 1e-9 * (1 + fabs(hi)))
            break;
        v[n++] = x * DEG;
    }
    return n;
}

/* ---- files: every write goes through here ---- */

/* Writes data to path via path.tmp: write, fsync, rename. The test hook
 * GAZESPLAT_AUGMENT_ENOSPC_AFTER=K makes the write after the first K fail
 * as a full disk does. errno says why on failure. */
static int commit_file(job *j, const char *path, const void *data, size_t len)
{
    char tmp[4200];
    snprintf(tmp, sizeof tmp, "%s.tmp", path);
    if (j->write_budget == 0) {
        errno = ENOSPC;
        return -1;
    }
    if (j->write_budget > 0)
        j->write_budget--;
    int fd = open(tmp, O_WRONLY | O_CREAT | O_TRUNC, 0666);
    if (fd < 0)
        return -1;
    if (cli_write_all(fd, data, len)) {
        int e = errno;
        close(fd);
        unlink(tmp);
        errno = e;
        return -1;
    }
    if (fsync(fd) || close(fd)) {
        int e = errno;
        unlink(tmp);
        errno = e;
        return -1;
    }
    if (rename(tmp, path)) {
        int e = errno;
        unlink(tmp);
        errno = e;
        return -1;
    }
    return 0;
}

static int make_dir(const char *path)
{
    struct stat st;
    return mkdir(path, 0777) == 0 || (stat(path, &st) == 0 && S_ISDIR(st.st_mode)) ? 0 : -1;
}

static int file_size_is(const char *path, long long want)
{
    struct stat st;
    return stat(path, &st) == 0 && S_ISREG(st.st_mode) && (want < 0 || st.st_size == want);
}

/* ---- JSON output ---- */

typedef struct jbuf {
    char *p;
    size_t len, cap;
    int oom;
} jbuf;

static void jput(jbuf *b, const char *fmt, ...) __attribute__((format(printf, 2, 3)));
static void jput(jbuf *b, const char *fmt, ...)
{
    for (;;) {
        va_list ap;
        va_start(ap, fmt);
        size_t room = b->cap - b->len;
        int n = vsnprintf(b->p ? b->p + b->len : NULL, b->p ? room : 0, fmt, ap);
        va_end(ap);
        if (n < 0)
            return;
        if (b->p && (size_t)n < room) {
            b->len += (size_t)n;
            return;
        }
        size_t cap = (b->cap + (size_t)n + 1) * 2;
        char *q = realloc(b->p, cap);
        if (!q) {
            b->oom = 1;
            return;
        }
        b->p = q;
        b->cap = cap;
    }
}

static void jnum(jbuf *b, const char *key, double v)
{
    if (isfinite(v))
        jput(b, ",\"%s\":%.10g", key, v);
    else
        jput(b, ",\"%s\":null", key);
}

static void jstr(jbuf *b, const char *key, const char *s)
{
    if (!s) {
        jput(b, ",\"%s\":null", key);
        return;
    }
    jput(b, ",\"%s\":\"", key);
    for (; *s; s++) {
        unsigned char c = (unsigned char)*s;
        if (c == '"' || c == '\\')
            jput(b, "\\%c", c);
        else if (c < 0x20)
            jput(b, "\\u%04x", c);
        else
            jput(b, "%c", c);
    }
    jput(b, "\"");
}

static void jarr(jbuf *b, const char *key, const double *v, int n)
{
    jput(b, ",\"%s\":[", key);
    for (int i = 0; i < n; i++)
        jput(b, isfinite(v[i]) ? "%s%.10g" : "%snull", i ? "," : "", v[i]);
    jput(b, "]");
}

/* ---- sources and targets ---- */

static int has_image_ext(const char *n)
{
    const char *d = strrchr(n, '.');
    return d && (!strcasecmp(d, ".png") || !strcasecmp(d, ".jpg") || !strcasecmp(d, ".jpeg"));
}

static int cmp_name(const void *a, const void *b)
{
    return strcmp(((const source *)a)->name, ((const source *)b)->name);
}

static int list_dir(job *j)
{
    DIR *d = opendir(j->input);
    if (!d)
        return cli_fail(j->cmd, "%s: cannot open (%s)", j->input, strerror(errno));
    size_t cap = 0;
    struct dirent *e;
    int rc = CLI_OK;
    while ((e = readdir(d)) && !rc) {
        if (e->d_name[0] == '.' || !has_image_ext(e->d_name))
            continue;
        if (j->nsrc == MAX_SOURCES) {
            rc = cli_fail(j->cmd, "%s: over %d images", j->input, MAX_SOURCES);
            break;
        }
        if (j->nsrc == cap) {
            cap = cap ? 2 * cap : 64;
            source *s = realloc(j->src, cap * sizeof *s);
            if (!s) {
                rc = cli_fail(j->cmd, "out of memory");
                break;
            }
            j->src = s;
        }
        memset(&j->src[j->nsrc], 0, sizeof *j->src);
        if (!(j->src[j->nsrc].name = strdup(e->d_name)))
            rc = cli_fail(j->cmd, "out of memory");
        else
            j->nsrc++;
    }
    closedir(d);
    if (!rc && j->nsrc == 0)
        rc = cli_fail(j->cmd, "%s: no .png, .jpg or .jpeg files", j->input);
    if (!rc)
        qsort(j->src, j->nsrc, sizeof *j->src, cmp_name);
    return rc;
}

static source *find_source(job *j, const char *name)
{
    source key;
    memset(&key, 0, sizeof key);
    key.name = (char *)name;
    return bsearch(&key, j->src, j->nsrc, sizeof *j->src, cmp_name);
}

/* A pair of angle columns of row r: both empty (0), both finite numbers
 * (1), or an error (-1, reported). */
static int angle_pair(job *j, const char *path, const aug_table *t, size_t r, int ca, int cb,
                      double lim_a, double lim_b, double out[2])
{
    const char *a = ca >= 0 ? t->cells[r][ca] : NULL, *b = cb >= 0 ? t->cells[r][cb] : NULL;
    if (!a && !b)
        return 0;
    const char *na = ca >= 0 ? t->cols[ca] : "?", *nb = cb >= 0 ? t->cols[cb] : "?";
    if (!a || !b) {
        cli_fail(j->cmd, "%s line %zu: %s without %s", path, t->line[r], a ? na : nb,
                 a ? nb : na);
        return -1;
    }
    if (parse_num(a, &out[0]) || parse_num(b, &out[1])) {
        cli_fail(j->cmd, "%s line %zu: %s '%s', %s '%s': want finite numbers (degrees)", path,
                 t->line[r], na, a, nb, b);
        return -1;
    }
    if (fabs(out[0]) > lim_a / DEG + 1e-9 || fabs(out[1]) > lim_b / DEG + 1e-9) {
        cli_fail(j->cmd, "%s line %zu: %s, %s = %g, %g outside the model's range (|%g|, |%g| deg)",
                 path, t->line[r], na, nb, out[0], out[1], lim_a / DEG, lim_b / DEG);
        return -1;
    }
    out[0] *= DEG;
    out[1] *= DEG;
    return 1;
}

/* Only the named columns; a missing key column is an error. */
static int check_columns(job *j, const char *path, const aug_table *t, const char *const *ok,
                         const char *key)
{
    for (int c = 0; c < t->ncols; c++) {
        int k = 0;
        while (ok[k] && strcmp(ok[k], t->cols[c]))
            k++;
        if (!ok[k]) {
            char list[512] = "";
            for (k = 0; ok[k]; k++)
                snprintf(list + strlen(list), sizeof list - strlen(list), "%s%s", k ? ", " : "",
                         ok[k]);
            return cli_fail(j->cmd, "%s: unknown column '%s' (the columns: %s)", path, t->cols[c],
                            list);
        }
    }
    if (aug_table_col(t, key) < 0)
        return cli_fail(j->cmd, "%s: no column '%s'", path, key);
    return CLI_OK;
}

/* The source a table row names: column file (DIR) or row (HDF5). */
static source *row_source(job *j, const char *path, const aug_table *t, size_t r, int ckey)
{
    const char *v = t->cells[r][ckey];
    if (!v) {
        cli_fail(j->cmd, "%s line %zu: empty %s", path, t->line[r], t->cols[ckey]);
        return NULL;
    }
    if (j->is_h5) {
        long row;
        if (cli_parse_long(v, 0, (long)j->nsrc - 1, &row)) {
            cli_fail(j->cmd, "%s line %zu: row '%s': want 0..%zu (%s's rows)", path, t->line[r], v,
                     j->nsrc - 1, j->input);
            return NULL;
        }
        return &j->src[row];
    }
    source *s = find_source(j, v);
    if (!s)
        cli_fail(j->cmd, "%s line %zu: no image '%s' in %s", path, t->line[r], v, j->input);
    return s;
}

static int read_labels(job *j, const char *path, uint64_t *fp)
{
    static const char *const ok[] = {"file", "gaze_pitch_deg", "gaze_yaw_deg", "head_pitch_deg",
                                     "head_yaw_deg", "subject", NULL};
    aug_table t;
    char msg[300];
    if (aug_table_read(path, &t, msg, sizeof msg))
        return cli_fail(j->cmd, "%s: %s", path, msg);
    int rc = check_columns(j, path, &t, ok, "file");
    int cf = aug_table_col(&t, "file"), cgp = aug_table_col(&t, "gaze_pitch_deg"),
        cgy = aug_table_col(&t, "gaze_yaw_deg"), chp = aug_table_col(&t, "head_pitch_deg"),
        chy = aug_table_col(&t, "head_yaw_deg"), cs = aug_table_col(&t, "subject");
    if (!rc && ((cgp >= 0) != (cgy >= 0) || (chp >= 0) != (chy >= 0)))
        rc = cli_fail(j->cmd, "%s: pitch and yaw columns come in pairs (gaze_pitch_deg with "
                      "gaze_yaw_deg, head_pitch_deg with head_yaw_deg)", path);
    unsigned char *seen = rc ? NULL : calloc(j->nsrc, 1);
    if (!rc && !seen)
        rc = cli_fail(j->cmd, "out of memory");
    for (size_t r = 0; !rc && r < t.nrows; r++) {
        source *s = row_source(j, path, &t, r, cf);
        if (!s) {
            rc = CLI_FAIL;
            break;
        }
        if (seen[s - j->src]++) {
            rc = cli_fail(j->cmd, "%s line %zu: a second row for '%s'", path, t.line[r], s->name);
            break;
        }
        int g = angle_pair(j, path, &t, r, cgp, cgy, 1e9, 1e9, s->gaze);
        int h = g < 0 ? -1 : angle_pair(j, path, &t, r, chp, chy, 1e9, 1e9, s->head);
        if (g < 0 || h < 0) {
            rc = CLI_FAIL;
            break;
        }
        s->has_gaze = g;
        s->has_head = h;
        if (cs >= 0 && t.cells[r][cs] && !(s->subject = strdup(t.cells[r][cs])))
            rc = cli_fail(j->cmd, "out of memory");
    }
    for (size_t i = 0; !rc && i < j->nsrc; i++) {
        source *s = &j->src[i];
        *fp = fnv_str(*fp, s->subject);
        *fp = fnv(*fp, &s->has_gaze, sizeof s->has_gaze);
        *fp = fnv(*fp, &s->has_head, sizeof s->has_head);
        *fp = fnv(*fp, s->gaze, sizeof s->gaze);
        *fp = fnv(*fp, s->head, sizeof s->head);
    }
    free(seen);
    aug_table_free(&t);
    return rc;
}

/* The HDF5 file's rows as sources, their labels checked here, up front. */
static int open_h5(job *j)
{
    gs_error err = {0, ""};
    if (gs_h5_open(j->input, &j->h5, &j->h5i, &err))
        return cli_fail(j->cmd, "%s", err.msg);
    if (j->h5i.rows == 0)
        return cli_fail(j->cmd, "%s: face_patch has no rows", j->input);
    if (j->h5i.height != j->h5i.width)
        return cli_fail(j->cmd, "%s: face_patch is %d x %d; want square patches", j->input,
                        j->h5i.height, j->h5i.width);
    if (j->h5i.rows > MAX_SOURCES)
        return cli_fail(j->cmd, "%s: over %d rows", j->input, MAX_SOURCES);
    j->nsrc = j->h5i.rows;
    if (!(j->src = calloc(j->nsrc, sizeof *j->src)))
        return cli_fail(j->cmd, "out of memory");
    const char *base = strrchr(j->input, '/');
    snprintf(j->h5_name, sizeof j->h5_name, "%s", base ? base + 1 : j->input);
    char stem[512];
    snprintf(stem, sizeof stem, "%s", j->h5_name);
    char *dot = strrchr(stem, '.');
    if (dot && dot != stem)
        *dot = 0;
    for (size_t i = 0; i < j->nsrc; i++) {
        source *s = &j->src[i];
        float g[2], h[2];
        s->row = i;
        if (gs_h5_read_row(j->h5, i, NULL, g, h, &err))
            return cli_fail(j->cmd, "%s: %s", j->input, err.msg);
        if ((s->has_gaze = j->h5i.has_gaze)) {
            s->gaze[0] = g[0];
            s->gaze[1] = g[1];
        }
        if ((s->has_head = j->h5i.has_head)) {
            s->head[0] = h[0];
            s->head[1] = h[1];
        }
        if (!(s->subject = strdup(stem)))
            return cli_fail(j->cmd, "out of memory");
    }
    return CLI_OK;
}

static int push_target(job *j, size_t *cap, const target *t)
{
    if (j->ntg == *cap) {
        *cap = *cap ? 2 * *cap : 256;
        target *g = realloc(j->tg, *cap * sizeof *g);
        if (!g)
            return -1;
        j->tg = g;
    }
    j->tg[j->ntg++] = *t;
    return 0;
}

static int read_targets(job *j, const char *path, size_t *cap)
{
    static const char *const ok_dir[] = {"file", "gaze_pitch_deg", "gaze_yaw_deg",
                                         "head_pitch_deg", "head_yaw_deg", NULL};
    static const char *const ok_h5[] = {"row", "gaze_pitch_deg", "gaze_yaw_deg", "head_pitch_deg",
                                        "head_yaw_deg", NULL};
    aug_table t;
    char msg[300];
    if (aug_table_read(path, &t, msg, sizeof msg))
        return cli_fail(j->cmd, "%s: %s", path, msg);
    const char *key = j->is_h5 ? "row" : "file";
    int rc = check_columns(j, path, &t, j->is_h5 ? ok_h5 : ok_dir, key);
    int ck = aug_table_col(&t, key), cgp = aug_table_col(&t, "gaze_pitch_deg"),
        cgy = aug_table_col(&t, "gaze_yaw_deg"), chp = aug_table_col(&t, "head_pitch_deg"),
        chy = aug_table_col(&t, "head_yaw_deg");
    if (!rc && (cgp < 0 || cgy < 0))
        rc = cli_fail(j->cmd, "%s: no column gaze_pitch_deg / gaze_yaw_deg", path);
    /* Rows grouped by source, in file order within each. */
    size_t *cnt = rc ? NULL : calloc(j->nsrc + 1, sizeof *cnt);
    target *rows = rc ? NULL : calloc(t.nrows + 1, sizeof *rows);
    size_t *owner = rc ? NULL : calloc(t.nrows + 1, sizeof *owner);
    if (!rc && (!cnt || !rows || !owner))
        rc = cli_fail(j->cmd, "out of memory");
    for (size_t r = 0; !rc && r < t.nrows; r++) {
        source *s = row_source(j, path, &t, r, ck);
        if (!s) {
            rc = CLI_FAIL;
            break;
        }
        double g[2], h[2];
        int hg = angle_pair(j, path, &t, r, cgp, cgy, GS_MODEL_MAX_GAZE_PITCH,
                            GS_MODEL_MAX_GAZE_YAW, g);
        int hh = hg < 0 ? -1
                        : angle_pair(j, path, &t, r, chp, chy, GS_MODEL_MAX_HEAD_ANGLE,
                                     GS_MODEL_MAX_HEAD_ANGLE, h);
        if (hg == 0)
            rc = cli_fail(j->cmd, "%s line %zu: no gaze_pitch_deg / gaze_yaw_deg", path,
                          t.line[r]);
        else if (hg < 0 || hh < 0)
            rc = CLI_FAIL;
        else if (++cnt[s - j->src] > MAX_TARGETS_PER_SOURCE)
            rc = cli_fail(j->cmd, "%s line %zu: over %d targets for one source", path, t.line[r],
                          MAX_TARGETS_PER_SOURCE);
        if (rc)
            break;
        target tg = {g[0], g[1], hh == 1, hh == 1 ? h[0] : 0, hh == 1 ? h[1] : 0};
        rows[r] = tg;
        owner[r] = (size_t)(s - j->src);
    }
    for (size_t k = 0; !rc && k < j->nsrc; k++) {
        j->src[k].t0 = j->ntg;
        for (size_t r = 0; r < t.nrows && !rc; r++)
            if (owner[r] == k && push_target(j, cap, &rows[r]))
                rc = cli_fail(j->cmd, "out of memory");
        j->src[k].nt = j->ntg - j->src[k].t0;
    }
    free(cnt);
    free(rows);
    free(owner);
    aug_table_free(&t);
    return rc;
}

/* Targets of every source (all shards: the global sample numbers). */
static int make_targets(job *j, const cli_opt *o, uint64_t seed)
{
    const cli_command *cmd = j->cmd;
    size_t cap = 0;
    int nspec = !!o[O_GRID].value + !!o[O_GAZE].value + !!o[O_UNIFORM].value + !!o[O_TARGETS].value;
    if (nspec != 1)
        return cli_usage_error(cmd, "one of --grid, --gaze-deg, --uniform and --targets");
    if (!!o[O_UNIFORM].value != !!o[O_PER].value)
        return cli_usage_error(cmd, "--uniform and --per-image go together");
    if (o[O_HEAD].value && o[O_HEADU].value)
        return cli_usage_error(cmd, "--head-deg or --head-uniform, not both");
    /* Head poses */
    double(*heads)[2] = NULL;
    size_t nh = 0;
    if (o[O_HEAD].value) {
        if (parse_pairs(o[O_HEAD].value, &heads, &nh))
            return cli_usage_error(cmd, "--head-deg: want \"P,Y;P,Y\" (degrees, <= %d)",
                                   MAX_TARGETS_PER_SOURCE);
        for (size_t i = 0; i < nh; i++)
            if (!head_in_range(heads[i][0], heads[i][1])) {
                int rc = cli_usage_error(cmd, "--head-deg: %g,%g outside the model's range "
                                         "(|70| deg)", heads[i][0] / DEG, heads[i][1] / DEG);
                free(heads);
                return rc;
            }
    }
    float hu[4] = {0, 0, 0, 0};
    if (o[O_HEADU].value &&
        (cli_parse_floats(o[O_HEADU].value, hu, 4) || hu[1] < hu[0] || hu[3] < hu[2] ||
         !head_in_range(hu[0] * DEG, hu[2] * DEG) || !head_in_range(hu[1] * DEG, hu[3] * DEG)))
        return cli_usage_error(cmd, "--head-uniform: want P0,P1,Y0,Y1 (degrees, P0 <= P1, Y0 <= "
                               "Y1, within +-70)");
    int rc = CLI_OK;
    double(*gz)[2] = NULL;
    size_t ng = 0;
    long per = 0;
    float un[4] = {0, 0, 0, 0};
    if (o[O_GRID].value) {
        const char *s = o[O_GRID].value, *comma = strchr(s, ',');
        char a[128];
        double p0, p1, ps, y0, y1, ys;
        if (!comma || (size_t)(comma - s) >= sizeof a) {
            rc = cli_usage_error(cmd, "--grid: want P0:P1:STEP,Y0:Y1:STEP (degrees)");
            goto done;
        }
        memcpy(a, s, (size_t)(comma - s));
        a[comma - s] = 0;
        if (parse_range(a, &p0, &p1, &ps) || parse_range(comma + 1, &y0, &y1, &ys)) {
            rc = cli_usage_error(cmd, "--grid: want P0:P1:STEP,Y0:Y1:STEP (degrees, lo <= hi, "
                                 "STEP > 0, <= %d values each)", MAX_TARGETS_PER_SOURCE);
            goto done;
        }
        static double pv[MAX_TARGETS_PER_SOURCE + 2], yv[MAX_TARGETS_PER_SOURCE + 2];
        int np = grid_values(p0, p1, ps, pv), ny = grid_values(y0, y1, ys, yv);
        if ((size_t)np * (size_t)ny > MAX_TARGETS_PER_SOURCE) {
            rc = cli_usage_error(cmd, "--grid: %d x %d targets; at most %d", np, ny,
                                 MAX_TARGETS_PER_SOURCE);
            goto done;
        }
        if (!(gz = malloc((size_t)np * ny * sizeof *gz))) {
            rc = cli_fail(cmd, "out of memory");
            goto done;
        }
        for (int a1 = 0; a1 < np; a1++)
            for (int b1 = 0; b1 < ny; b1++) {
                gz[ng][0] = pv[a1];
                gz[ng][1] = yv[b1];
                ng++;
            }
    } else if (o[O_GAZE].value) {
        if (parse_pairs(o[O_GAZE].value, &gz, &ng)) {
            rc = cli_usage_error(cmd, "--gaze-deg: want \"P,Y;P,Y\" (degrees, <= %d)",
                                 MAX_TARGETS_PER_SOURCE);
            goto done;
        }
    } else if (o[O_UNIFORM].value) {
        if (cli_parse_floats(o[O_UNIFORM].value, un, 4) || un[1] < un[0] || un[3] < un[2]) {
            rc = cli_usage_error(cmd, "--uniform: want P0,P1,Y0,Y1 (degrees, P0 <= P1, Y0 <= Y1)");
            goto done;
        }
        if (cli_parse_long(o[O_PER].value, 1, MAX_TARGETS_PER_SOURCE, &per)) {
            rc = cli_usage_error(cmd, "--per-image: want 1..%d", MAX_TARGETS_PER_SOURCE);
            goto done;
        }
        if (!gaze_in_range(un[0] * DEG, un[2] * DEG) || !gaze_in_range(un[1] * DEG, un[3] * DEG)) {
            rc = cli_usage_error(cmd, "--uniform: %s outside the model's range (|pitch| <= 50, "
                                 "|yaw| <= 60 deg)", o[O_UNIFORM].value);
            goto done;
        }
    }
    for (size_t i = 0; i < ng; i++)
        if (!gaze_in_range(gz[i][0], gz[i][1])) {
            rc = cli_usage_error(cmd, "%s: target %g,%g outside the model's range (|pitch| <= 50, "
                                 "|yaw| <= 60 deg)", o[O_GRID].value ? "--grid" : "--gaze-deg",
                                 gz[i][0] / DEG, gz[i][1] / DEG);
            goto done;
        }
    if (ng * (nh ? nh : 1) > MAX_TARGETS_PER_SOURCE || (size_t)per * (nh ? nh : 1) > MAX_TARGETS_PER_SOURCE) {
        rc = cli_usage_error(cmd, "over %d targets per image", MAX_TARGETS_PER_SOURCE);
        goto done;
    }
    if (o[O_TARGETS].value) {
        if (nh) {
            rc = cli_usage_error(cmd, "--targets: give head poses in the file "
                                 "(head_pitch_deg, head_yaw_deg), not --head-deg");
            goto done;
        }
        if ((rc = read_targets(j, o[O_TARGETS].value, &cap)))
            goto done;
    }
    for (size_t k = 0; !o[O_TARGETS].value && k < j->nsrc; k++) {
        source *s = &j->src[k];
        s->t0 = j->ntg;
        uint64_t st = seed * 0x100000001B3ull ^ (uint64_t)k;
        splitmix(&st);
        size_t n = per ? (size_t)per : ng;
        for (size_t h = 0; h < (nh ? nh : 1) && !rc; h++)
            for (size_t i = 0; i < n; i++) {
                target t = {0};
                if (per) {
                    t.gp = uniform(&st, un[0] * DEG, un[1] * DEG);
                    t.gy = uniform(&st, un[2] * DEG, un[3] * DEG);
                } else {
                    t.gp = gz[i][0];
                    t.gy = gz[i][1];
                }
                if (nh) {
                    t.use_head = 1;
                    t.hp = heads[h][0];
                    t.hy = heads[h][1];
                }
                if (push_target(j, &cap, &t)) {
                    rc = cli_fail(cmd, "out of memory");
                    break;
                }
            }
        s->nt = j->ntg - s->t0;
    }
    /* Head draws come after the gaze draws, from their own stream. */
    for (size_t k = 0; !rc && o[O_HEADU].value && k < j->nsrc; k++) {
        uint64_t st = (seed * 0x100000001B3ull ^ (uint64_t)k) + 0x5bd1e995ull;
        splitmix(&st);
        for (size_t i = 0; i < j->src[k].nt; i++) {
            target *t = &j->tg[j->src[k].t0 + i];
            t->use_head = 1;
            t->hp = uniform(&st, hu[0] * DEG, hu[1] * DEG);
            t->hy = uniform(&st, hu[2] * DEG, hu[3] * DEG);
        }
    }
    size_t first = 0;
    for (size_t k = 0; !rc && k < j->nsrc; k++) {
        j->src[k].first = first;
        first += j->src[k].nt;
    }
done:
    free(gz);
    free(heads);
    return rc;
}

/* ---- the manifest ---- */

/* A source's line: "done K\n", or with --min-quality "done K q=LETTERS\n",
 * one letter per target of source K (k kept, d dropped, u kept unscored).
 * Marks K done and takes its decisions; -1 for a line of another form. */
static int parse_done(job *j, const char *line, unsigned char *done)
{
    unsigned long long k;
    int at = 0;
    if (strncmp(line, "done ", 5) || line[5] < '0' || line[5] > '9' ||
        sscanf(line, "done %llu%n", &k, &at) != 1 || k >= j->nsrc)
        return -1;
    const char *p = line + at;
    if (j->min_q) {
        const source *s = &j->src[k];
        if (strncmp(p, " q=", 3) || strspn(p + 3, "kdu") != s->nt || strcmp(p + 3 + s->nt, "\n"))
            return -1;
        memcpy(j->decide + s->t0, p + 3, s->nt);
    } else if (strcmp(p, "\n")) {
        return -1;
    }
    done[k] = 1;
    return 0;
}

/* Source k's line for the manifest (malloc'd; NULL: out of memory). */
static char *done_line(const job *j, size_t k)
{
    const source *s = &j->src[k];
    size_t cap = 48 + s->nt;
    char *line = malloc(cap);
    if (!line)
        return NULL;
    int n = snprintf(line, cap, "done %zu", k);
    if (j->min_q) {
        memcpy(line + n, " q=", 3);
        memcpy(line + n + 3, j->decide + s->t0, s->nt);
        n += 3 + (int)s->nt;
    }
    memcpy(line + n, "\n", 2);
    return line;
}

/* Source k's samples by decision: kept (returned; all without
 * --min-quality), and of them unscored; dropped. */
static size_t kept_of(const job *j, size_t k, size_t *dropped, size_t *unscored)
{
    const source *s = &j->src[k];
    size_t kept = s->nt, d = 0, u = 0;
    for (size_t t = 0; j->decide && t < s->nt; t++) {
        d += j->decide[s->t0 + t] == 'd';
        u += j->decide[s->t0 + t] == 'u';
    }
    if (dropped)
        *dropped = d;
    if (unscored)
        *unscored = u;
    return kept - d;
}

/* Reads the manifest: marks done sources in done[] and *finished. A torn
 * last line (no newline: killed mid-append) is cut off. Creates it (with
 * the header) when absent. */
static int open_manifest(job *j, unsigned char *done, int *finished)
{
    char header[200];
    snprintf(header, sizeof header, "gazesplat-augment-manifest 1 %016llx %zu %zu\n",
             (unsigned long long)j->fingerprint, j->nsrc, j->ntg);
    *finished = 0;
    FILE *f = fopen(j->manifest, "rb");
    if (!f) {
        if (errno != ENOENT)
            return cli_fail(j->cmd, "%s: %s", j->manifest, strerror(errno));
        if (commit_file(j, j->manifest, header, strlen(header)) || cli_fsync_path(j->state))
            return cli_fail(j->cmd, "%s: cannot write (%s)", j->manifest, strerror(errno));
        return CLI_OK;
    }
    char *line = NULL;
    size_t lcap = 0;
    ssize_t got;
    long good = 0;
    int rc = CLI_OK, first = 1;
    while ((got = getline(&line, &lcap, f)) > 0) {
        size_t n = (size_t)got;
        if (line[n - 1] != '\n' || strlen(line) != n)
            break; /* torn */
        if (first) {
            if (strcmp(line, header) != 0) {
                rc = cli_fail(j->cmd, "%s was written by another augment run (other options, "
                              "model, inputs or shard); use a new --out, or remove %s to "
                              "start over", j->out, j->state);
                break;
            }
            first = 0;
        } else if (strcmp(line, "finished\n") == 0)
            *finished = 1;
        else if (parse_done(j, line, done)) {
            rc = cli_fail(j->cmd, "%s: bad line '%.*s'", j->manifest, n > 200 ? 200 : (int)(n - 1),
                          line);
            break;
        }
        good = ftell(f);
    }
    free(line);
    fseek(f, 0, SEEK_END);
    long size = ftell(f);
    fclose(f);
    if (!rc && first)
        rc = cli_fail(j->cmd, "%s: no header; remove %s to start over", j->manifest, j->state);
    if (!rc && size != good && truncate(j->manifest, good))
        rc = cli_fail(j->cmd, "%s: cannot cut its torn last line (%s)", j->manifest,
                      strerror(errno));
    return rc;
}

static int manifest_append(job *j, const char *line)
{
    if (j->write_budget == 0) {
        errno = ENOSPC;
        return -1;
    }
    if (j->write_budget > 0)
        j->write_budget--;
    int fd = open(j->manifest, O_WRONLY | O_APPEND);
    if (fd < 0)
        return -1;
    size_t n = strlen(line);
    ssize_t w = write(fd, line, n);
    int e = errno;
    int bad = w != (ssize_t)n || fsync(fd);
    if (bad && w >= 0 && w != (ssize_t)n)
        e = ENOSPC;
    close(fd);
    errno = e;
    return bad ? -1 : 0;
}

/* ---- one source ---- */

static void part_path(const job *j, size_t k, const char *ext, char *out, size_t cap)
{
    snprintf(out, cap, "%s/%08zu.%s", j->state, k, ext);
}

static void image_path(const job *j, size_t index, char *out, size_t cap, int rel)
{
    if (rel)
        snprintf(out, cap, "images/%08zu.png", index);
    else
        snprintf(out, cap, "%s/images/%08zu.png", j->out, index);
}

/* Whether source k's parts are all there (manifest says done): its
 * labels, its dropped samples (--min-quality), the HDF5 records and the
 * PNGs of the samples kept. */
static int parts_present(const job *j, size_t k)
{
    const source *s = &j->src[k];
    size_t S = (size_t)j->out_size, kept = kept_of(j, k, NULL, NULL);
    char p[4300];
    part_path(j, k, "jsonl", p, sizeof p);
    if (!file_size_is(p, -1))
        return 0;
    part_path(j, k, "dropped", p, sizeof p);
    if (j->min_q && !file_size_is(p, -1))
        return 0;
    if (j->want_h5) {
        part_path(j, k, "bin", p, sizeof p);
        if (!file_size_is(p, (long long)(kept * (S * S * 3 + 16))))
            return 0;
    }
    for (size_t t = 0; j->want_png && t < s->nt; t++) {
        if (j->decide && j->decide[s->t0 + t] == 'd')
            continue;
        image_path(j, s->first + t, p, sizeof p, 0);
        if (!file_size_is(p, -1))
            return 0;
    }
    return 1;
}

/* Bilinear resize of a square RGB patch (n x n) to S x S, pixel centres
 * aligned (geom.h pixels). */
static void resize_rgb(const uint8_t *in, int n, uint8_t *out, int S)
{
    double sc = (double)n / S;
    for (int y = 0; y < S; y++) {
        double fy = (y + 0.5) * sc - 0.5;
        int y0 = (int)floor(fy);
        double wy = fy - y0;
        int ya = y0 < 0 ? 0 : y0 >= n ? n - 1 : y0, yb = y0 + 1 < 0 ? 0 : y0 + 1 >= n ? n - 1 : y0 + 1;
        for (int x = 0; x < S; x++) {
            double fx = (x + 0.5) * sc - 0.5;
            int x0 = (int)floor(fx);
            double wx = fx - x0;
            int xa = x0 < 0 ? 0 : x0 >= n ? n - 1 : x0,
                xb = x0 + 1 < 0 ? 0 : x0 + 1 >= n ? n - 1 : x0 + 1;
            for (int c = 0; c < 3; c++) {
                double v = (1 - wy) * ((1 - wx) * in[((size_t)ya * n + xa) * 3 + c] +
                                       wx * in[((size_t)ya * n + xb) * 3 + c]) +
                           wy * ((1 - wx) * in[((size_t)yb * n + xa) * 3 + c] +
                                 wx * in[((size_t)yb * n + xb) * 3 + c]);
                out[((size_t)y * S + x) * 3 + c] = (uint8_t)(v + 0.5);
            }
        }
    }
}

typedef struct fitted {
    gs_subject sub;
    int photo;             /* the source was a photo */
    double fit_seconds;
    int fit_iters;
    double ft_psnr;        /* NaN: no fine-tuning */
} fitted;

/* The face gate on a normalized face (a file or an HDF5 row): a refusal
 * frees the face, sets j->refused and says why in err. */
/* Source k as a redirect input: its normalized face (an HDF5 row, resized
 * to the model's size; an image of that size; or a photo's face,
 * normalized, with its mask and landmarks), through the face gate unless
 * --no-gate; j->refused says whether the gate refused it. */
static int load_face(job *j, size_t k, gs_redirect_input *in, gs_error *err)
{
    int S = j->info.image_size;
    source *s = &j->src[k];
    memset(in, 0, sizeof *in);
    j->refused = 0;
    gs_io_image img = {0};
    int rc;
    if (j->is_h5) {
        int n = j->h5i.width;
        uint8_t *patch = malloc((size_t)n * n * 3);
        img.data = malloc((size_t)S * S * 3);
        if (!patch || !img.data) {
            free(patch);
            gs_io_image_free(&img);
            return gs_error_set(err, GS_ERR_NOMEM, "out of memory");
        }
        img.width = img.height = S;
        img.stride = (size_t)S * 3;
        rc = gs_h5_read_row(j->h5, s->row, patch, NULL, NULL, err);
        if (rc == GS_OK && !j->h5_rgb)
            for (size_t i = 0; i < (size_t)n * n; i++) {
                uint8_t b = patch[3 * i];
                patch[3 * i] = patch[3 * i + 2];
                patch[3 * i + 2] = b;
            }
        if (rc == GS_OK) {
            if (n == S)
                memcpy(img.data, patch, (size_t)S * S * 3);
            else
                resize_rgb(patch, n, img.data, S);
        }
        free(patch);
        if (rc != GS_OK) {
            gs_io_image_free(&img);
            return rc;
        }
    } else {
        char path[4300];
        snprintf(path, sizeof path, "%s/%s", j->input, s->name);
        if ((rc = gs_io_image_read(path, NULL, &img, err)) != GS_OK)
            return rc;
    }
    if (img.width == S && img.height == S)
        rc = gs_redirect_input_face(&j->info, &img, j->gate, in, err);
    else {
        /* A photo: the face detector and landmark model, loaded once. */
        if ((!j->det && (rc = gs_face_detector_load(NULL, &j->det, err)) != GS_OK) ||
            (!j->sp && (rc = gs_face_shape_model_load(NULL, &j->sp, err)) != GS_OK)) {
            gs_io_image_free(&img);
            return rc;
        }
        gs_redirect_photo_opts po;
        gs_redirect_photo_opts_default(&po);
        po.gate = j->gate;
        rc = gs_redirect_input_photo(j->det, j->sp, &j->info, &img, &po, in, err);
    }
    j->refused = rc != GS_OK && in->gate.refusal != GS_FACE_USABLE;
    return rc;
}

static const char *src_label(const job *j, size_t k, char *buf, size_t cap)
{
    if (j->is_h5)
        snprintf(buf, cap, "%s row %zu", j->input, j->src[k].row);
    else
        snprintf(buf, cap, "%s/%s", j->input, j->src[k].name);
    return buf;
}

/* ,"quality":{...} of one sample (docs/face.md), or null. */
static void quality_json(jbuf *b, const gs_face_quality *q)
{
    if (!q) {
        jput(b, ",\"quality\":null");
        return;
    }
    /* Redirect quality (docs/face.md): the score and what it is made of. */
    jput(b, ",\"quality\":{\"score\":%.4f,\"eyes\":%d", q->score, q->eyes);
    jnum(b, "asked_pitch_rad", q->commanded[0]);
    jnum(b, "asked_yaw_rad", q->commanded[1]);
    jnum(b, "seen_pitch_rad", q->measured[0]);
    jnum(b, "seen_yaw_rad", q->measured[1]);
    jnum(b, "gaze_error_deg", q->gaze_error_deg);
    jnum(b, "iris_delta_e", q->delta_e);
    jnum(b, "eye_speckle", q->artifact);
    jstr(b, "reason", q->reason);
    jput(b, "}");
}

/* The dropped.jsonl line of a sample --min-quality dropped: what it would
 * have been (index, source, target) and why (its unrounded score, the
 * quality's reason, the whole quality as the labels carry it). */
static void dropped_json(const job *j, size_t k, size_t t, const target *tg,
                         const gs_face_quality *q, jbuf *b)
{
    const source *s = &j->src[k];
    jput(b, "{\"index\":%zu", s->first + t);
    jstr(b, "source", j->is_h5 ? j->h5_name : s->name);
    jput(b, ",\"source_index\":%zu", k);
    if (j->is_h5)
        jput(b, ",\"source_row\":%zu", s->row);
    else
        jput(b, ",\"source_row\":null");
    jput(b, ",\"target_index\":%zu", t);
    jstr(b, "subject", s->subject);
    jnum(b, "gaze_head_pitch_rad", tg->gp);
    jnum(b, "gaze_head_yaw_rad", tg->gy);
    jput(b, ",\"score\":%.10g", q->score);
    jstr(b, "reason", q->reason);
    quality_json(b, q);
    jput(b, "}\n");
}

/* The JSON line of one sample. */
static void sample_json(const job *j, size_t k, size_t t, const fitted *fi, const double R[9],
                        const double ht[3], const target *tg, const gs_face_quality *q,
                        double gcam_out[2], double hd[2], jbuf *b)
{
    const source *s = &j->src[k];
    size_t index = s->first + t;
    double gh[3], gc[3], gcp = NAN, gcy = NAN, hp, hy;
    gs_geom_pitchyaw_to_vec(tg->gp, tg->gy, gh);
    gs_geom_mat3_vec(R, gh, gc);
    gs_geom_vec_to_pitchyaw(gc, &gcp, &gcy);
    gs_geom_head_pitchyaw(R, &hp, &hy);
    gcam_out[0] = gcp;
    gcam_out[1] = gcy;
    hd[0] = hp;
    hd[1] = hy;
    char img[64];
    image_path(j, index, img, sizeof img, 1);
    jput(b, "{\"image\":");
    if (j->want_png)
        jput(b, "\"%s\"", img);
    else
        jput(b, "null");
    jput(b, ",\"index\":%zu", index);
    if (j->want_h5)
        jput(b, ",\"h5_row\":%zu", (size_t)0); /* patched at assembly */
    char src[600];
    if (j->is_h5)
        snprintf(src, sizeof src, "%s", j->h5_name);
    jstr(b, "source", j->is_h5 ? src : s->name);
    jput(b, ",\"source_index\":%zu", k);
    if (j->is_h5)
        jput(b, ",\"source_row\":%zu", s->row);
    else
        jput(b, ",\"source_row\":null");
    jput(b, ",\"source_kind\":\"%s\"", j->is_h5 ? "hdf5" : fi->photo ? "photo" : "normalized");
    jput(b, ",\"target_index\":%zu", t);
    jstr(b, "subject", s->subject);
    jput(b, ",\"width\":%d,\"height\":%d", j->out_size, j->out_size);
    jarr(b, "gaze_head", gh, 3);
    jnum(b, "gaze_head_pitch_rad", tg->gp);
    jnum(b, "gaze_head_yaw_rad", tg->gy);
    jarr(b, "gaze_cam", gc, 3);
    jnum(b, "gaze_cam_pitch_rad", gcp);
    jnum(b, "gaze_cam_yaw_rad", gcy);
    jarr(b, "head_R", R, 9);
    jarr(b, "head_t_mm", ht, 3);
    jnum(b, "head_pitch_rad", hp);
    jnum(b, "head_yaw_rad", hy);
    jnum(b, "head_roll_rad", gs_geom_head_roll(R));
    jput(b, ",\"head_changed\":%s", tg->use_head ? "true" : "false");
    jnum(b, "source_gaze_cam_pitch_rad", s->has_gaze ? s->gaze[0] : NAN);
    jnum(b, "source_gaze_cam_yaw_rad", s->has_gaze ? s->gaze[1] : NAN);
    jnum(b, "source_head_pitch_rad", s->has_head ? s->head[0] : NAN);
    jnum(b, "source_head_yaw_rad", s->has_head ? s->head[1] : NAN);
    jnum(b, "fit_gaze_head_pitch_rad", fi->sub.gaze_pitch);
    jnum(b, "fit_gaze_head_yaw_rad", fi->sub.gaze_yaw);
    jnum(b, "fit_psnr", fi->sub.fit_psnr);
    jnum(b, "fit_ssim", fi->sub.fit_ssim);
    jnum(b, "finetune_psnr", fi->ft_psnr);
    quality_json(b, q);
    jput(b, "}\n");
}

static void put_f32le(uint8_t *p, float v)
{
    uint32_t u;
    memcpy(&u, &v, 4);
    p[0] = (uint8_t)u;
    p[1] = (uint8_t)(u >> 8);
    p[2] = (uint8_t)(u >> 16);
    p[3] = (uint8_t)(u >> 24);
}

static float get_f32le(const uint8_t *p)
{
    uint32_t u = (uint32_t)p[0] | (uint32_t)p[1] << 8 | (uint32_t)p[2] << 16 |
                 (uint32_t)p[3] << 24;
    float v;
    memcpy(&v, &u, 4);
    return v;
}

static void nap_s(double s)
{
    struct timespec ts = {(time_t)s, (long)((s - (double)(time_t)s) * 1e9)};
    nanosleep(&ts, NULL);
}

/* The fit's settings as route_key hashes them (with the image). */
static size_t route_settings(const aug_remote_fit *in, char *buf, size_t cap)
{
    int n = snprintf(buf, cap, "photo=%d iters=%d ft=%d lr=%.17g keep=%d gaze=%d:%.17g,%.17g "
                     "head=%d:%.17g,%.17g", in->photo, in->iters, in->ft_steps, in->ft_lr,
                     in->keep_image, in->known_gaze, in->known_gaze ? in->gaze_deg[0] : 0,
                     in->known_gaze ? in->gaze_deg[1] : 0, in->known_head,
                     in->known_head ? in->head_deg[0] : 0, in->known_head ? in->head_deg[1] : 0);
    return n < 0 ? 0 : (size_t)n < cap ? (size_t)n : cap - 1;
}

/* One source's FIT and REDIRECTs on a connection of its own, opened with
 * the source's route key (docs/scale-out.md): behind a proxy that hashes
 * it, every source has one daemon and a source's requests meet its fit.
 * A try that fails in a way a new connection may mend (the daemon died,
 * drained or dropped the subject: AUG_REMOTE_RETRY) starts again with a
 * new FIT, after 0.5 s doubling up to 5 s, jittered; the renders are the
 * same bytes on any daemon of the same model, so nothing a retry asks
 * again lands twice. 0, or -1 with msg. */
static int remote_fit_render(job *j, const aug_remote_fit *in, aug_remote_subject *rs,
                             const aug_remote_target *tg, size_t nt, uint8_t *renders,
                             gs_face_quality *quals, char *msg, size_t cap)
{
    char settings[512];
    uint8_t key[16];
    gs_client_route_key(in->image, in->len, settings, route_settings(in, settings, sizeof settings),
                        key);
    unsigned seed = (unsigned)key[0] | (unsigned)key[1] << 8 | (unsigned)getpid() << 16;
    double wait_s = 0.5;
    for (long attempt = 1;; attempt++) {
        gs_client *c = NULL;
        int size = 0, rc;
        char server[256];
        rc = aug_remote_connect(j->addr, j->token, key, &c, &size, server, sizeof server, msg, cap);
        if (!rc && (size != j->info.image_size || strcmp(server, j->server))) {
            snprintf(msg, cap, "%s: the daemons behind it differ (%s at %d px, then %s at %d px)",
                     j->addr, j->server, j->info.image_size, server, size);
            rc = AUG_REMOTE_FATAL;
        }
        if (!rc)
            rc = aug_remote_fit_one(c, in, rs, msg, cap);
        if (!rc)
            rc = aug_remote_render(c, rs, tg, nt, j->transfer, j->info.image_size, renders,
                                   (size_t)j->info.image_size * j->info.image_size * 3, quals,
                                   msg, cap);
        aug_remote_close(c);
        if (rc != AUG_REMOTE_RETRY)
            return rc ? -1 : 0;
        if (attempt >= j->retries) {
            size_t n = strlen(msg);
            snprintf(msg + n, cap - n, " (after %ld tries)", attempt);
            return -1;
        }
        fprintf(stderr, "gazesplat augment: %s; trying again\n", msg);
        double f = 0.75 + 0.5 * (double)rand_r(&seed) / RAND_MAX;
        nap_s(wait_s * f);
        wait_s = wait_s * 2 > 5 ? 5 : wait_s * 2;
    }
}

/* --addr: source k's FIT and REDIRECT through the daemon. Photos go as
 * they are (the server detects and normalizes them as redirect does);
 * normalized faces and HDF5 rows as PNGs of the normalized face. The
 * renders land in *renders (nt x S x S x 3 RGB). */
static int remote_source(job *j, size_t k, fitted *fi, uint8_t **renders, gs_face_quality **quals,
                         const char *what)
{
    const cli_command *cmd = j->cmd;
    source *s = &j->src[k];
    int S = j->info.image_size;
    gs_error err = {0, ""};
    uint8_t *bytes = NULL;
    void *enc = NULL;
    size_t len = 0;
    int rc = CLI_OK;
    aug_remote_fit in;
    memset(&in, 0, sizeof in);
    if (j->is_h5) {
        gs_redirect_input ri;
        if (load_face(j, k, &ri, &err) ||
            gs_io_image_encode(&ri.norm, GS_IO_PNG, 0, &enc, &len, &err))
            rc = j->refused ? (cli_fail(cmd, "%s: %s (--no-gate to augment it anyway)", what,
                                        err.msg),
                               CLI_REFUSED)
                            : cli_fail(cmd, "%s: %s", what, err.msg);
        gs_redirect_input_free(&ri);
        in.image = enc;
    } else {
        char path[4300];
        gs_io_image img = {0};
        snprintf(path, sizeof path, "%s/%s", j->input, s->name);
        if (gs_io_image_read(path, NULL, &img, &err))
            rc = cli_fail(cmd, "%s: %s", what, err.msg);
        else if (cli_read_file(path, (size_t)256 << 20, &bytes, &len))
            rc = cli_fail(cmd, "%s: cannot read", what);
        fi->photo = !rc && !(img.width == S && img.height == S);
        gs_io_image_free(&img);
        in.image = bytes;
    }
    in.len = len;
    in.photo = fi->photo;
    in.iters = (int)j->iters;
    in.ft_steps = j->ft.iters;
    in.ft_lr = j->ft.lr;
    /* The server measures the quality against the input it keeps. */
    in.keep_image = j->transfer || j->quality;
    if (!fi->photo && j->fit_labels && s->has_head) {
        in.known_head = 1;
        in.head_deg[0] = s->head[0] / DEG;
        in.head_deg[1] = s->head[1] / DEG;
    }
    if (!fi->photo && j->fit_labels && s->has_gaze) {
        double R[9], g[3], gh[3], p, y;
        if (s->has_head)
            gs_geom_rot_from_pitchyaw(s->head[0], s->head[1], 0, R);
        else
            gs_geom_mat3_identity(R);
        gs_geom_pitchyaw_to_vec(s->gaze[0], s->gaze[1], g);
        gs_geom_mat3_tvec(R, g, gh);
        gs_geom_vec_to_pitchyaw(gh, &p, &y);
        in.known_gaze = 1;
        in.gaze_deg[0] = p / DEG;
        in.gaze_deg[1] = y / DEG;
    }
    aug_remote_subject rs;
    char msg[600];
    aug_remote_target *tg = rc ? NULL : calloc(s->nt + 1, sizeof *tg);
    *renders = rc ? NULL : malloc((size_t)S * S * 3 * (s->nt + 1));
    if (!rc && (!tg || !*renders))
        rc = cli_fail(cmd, "out of memory");
    for (size_t t = 0; !rc && t < s->nt; t++) {
        const target *x = &j->tg[s->t0 + t];
        tg[t].gaze_deg[0] = x->gp / DEG;
        tg[t].gaze_deg[1] = x->gy / DEG;
        tg[t].use_head = x->use_head;
        tg[t].head_deg[0] = x->hp / DEG;
        tg[t].head_deg[1] = x->hy / DEG;
    }
    if (!rc && j->quality && !(*quals = calloc(s->nt + 1, sizeof **quals)))
        rc = cli_fail(cmd, "out of memory");
    if (!rc && remote_fit_render(j, &in, &rs, tg, s->nt, *renders, *quals, msg, sizeof msg))
        rc = cli_fail(cmd, "%s: %s", what, msg);
    if (!rc) {
        /* The subject as FIT_OK tells it: head angles (roll 0), gaze. */
        gs_geom_rot_from_pitchyaw(rs.head_deg[0] * DEG, rs.head_deg[1] * DEG, 0, fi->sub.head_R);
        fi->sub.head_t[0] = fi->sub.head_t[1] = fi->sub.head_t[2] = NAN;
        fi->sub.gaze_pitch = rs.gaze_deg[0] * DEG;
        fi->sub.gaze_yaw = rs.gaze_deg[1] * DEG;
        fi->sub.fit_psnr = (float)rs.psnr;
        fi->sub.fit_ssim = (float)rs.ssim;
        /* A FIT answered from the server's cache cannot tell what the
         * fine-tuning reached, and whether a rerun after a kill finds the
         * subject cached depends on when the kill came: left out over a
         * daemon, so that a resumed run gives the bytes of an
         * uninterrupted one. */
        fi->ft_psnr = NAN;
    }
    free(tg);
    free(bytes);
    free(enc);
    return rc;
}

/* What one source's renders leave for its parts. */
typedef struct source_out {
    uint8_t *blob; /* per kept sample: the patch as BGR (face_patch's order),
                      then face_gaze and face_head_pose as float32 LE */
    size_t kept;   /* records in blob, lines in labels */
    jbuf labels, dropped;
} source_out;

/* With --min-quality, a sample's decision: unscored (no quality: a head
 * change, or no landmarks to measure against), dropped under X, kept. */
static char decision(const job *j, const gs_face_quality *q)
{
    if (!q || !isfinite(q->score))
        return 'u';
    return q->score < j->min_quality ? 'd' : 'k';
}

/* A kept sample (its patch, So x So RGB, at px): its label, its PNG, and
 * its HDF5 record in place (BGR, then the labels). */
static int emit_sample(job *j, size_t k, size_t t, const fitted *fi, const double R[9],
                       const double ht[3], const target *tg, const gs_face_quality *qp,
                       uint8_t *px, source_out *so)
{
    int So = j->out_size;
    size_t img_bytes = (size_t)So * So * 3;
    double gc[2], hd[2];
    sample_json(j, k, t, fi, R, ht, tg, qp, gc, hd, &so->labels);
    if (j->want_png) {
        gs_io_image out = {So, So, (size_t)So * 3, px};
        gs_error err = {0, ""};
        void *png = NULL;
        size_t plen = 0;
        char path[4300];
        image_path(j, j->src[k].first + t, path, sizeof path, 0);
        if (gs_io_image_encode(&out, GS_IO_PNG, 0, &png, &plen, &err))
            return cli_fail(j->cmd, "%s: %s", path, err.msg);
        int bad = commit_file(j, path, png, plen);
        free(png);
        if (bad)
            return cli_fail(j->cmd, "%s: cannot write (%s)", path, strerror(errno));
    }
    for (size_t i = 0; i < (size_t)So * So; i++) { /* RGB -> BGR in place */
        uint8_t b = px[3 * i];
        px[3 * i] = px[3 * i + 2];
        px[3 * i + 2] = b;
    }
    put_f32le(px + img_bytes, (float)gc[0]);
    put_f32le(px + img_bytes + 4, (float)gc[1]);
    put_f32le(px + img_bytes + 8, (float)hd[0]);
    put_f32le(px + img_bytes + 12, (float)hd[1]);
    so->kept++;
    return CLI_OK;
}

/* Renders source k at each of its targets (in process through c, or the
 * daemon's renders in remote), measures the quality where asked and keeps
 * or drops each sample (--min-quality) into *so. */
static int render_source(job *j, size_t k, const fitted *fi, gs_model_ctx *c,
                         const gs_io_image *face, const gs_xfer_eyes *eyes, const uint8_t *remote,
                         const gs_face_quality *rquals, const gs_face_quality_ref *qref,
                         source_out *so, const char *what)
{
    const source *s = &j->src[k];
    int S = j->info.image_size, So = j->out_size;
    size_t rec = (size_t)So * So * 3 + 16;
    gs_error err = {0, ""};
    so->blob = malloc(s->nt * rec + 1);
    uint8_t *render = So != S ? malloc((size_t)S * S * 3) : NULL;
    int rc = CLI_OK;
    if (!so->blob || (So != S && !render))
        rc = cli_fail(j->cmd, "out of memory");
    for (size_t t = 0; t < s->nt && !rc; t++) {
        const target *tg = &j->tg[s->t0 + t];
        gs_view v;
        memset(&v, 0, sizeof v);
        v.gaze_pitch = tg->gp;
        v.gaze_yaw = tg->gy;
        double R[9], ht[3];
        memcpy(R, fi->sub.head_R, sizeof R);
        memcpy(ht, fi->sub.head_t, sizeof ht);
        if (tg->use_head) {
            v.use_head = 1;
            gs_geom_rot_from_pitchyaw(tg->hp, tg->hy, 0, v.head_R);
            memcpy(v.head_t, fi->sub.head_t, sizeof v.head_t);
            memcpy(R, v.head_R, sizeof R);
        }
        /* A dropped sample's slot is the next one's. */
        uint8_t *px = so->blob + so->kept * rec, *dst = render ? render : px;
        int r = 0;
        if (remote)
            memcpy(dst, remote + t * (size_t)S * S * 3, (size_t)S * S * 3);
        else
            r = gs_redirect_render(c, j->pool, &fi->sub, j->transfer ? face->data : NULL,
                                   face->stride, eyes, &v, dst, (size_t)S * 3, &err);
        if (r) {
            rc = cli_fail(j->cmd, "%s: target %zu: %s", what, t, err.msg);
            break;
        }
        gs_face_quality q;
        const gs_face_quality *qp = NULL;
        if (qref && !tg->use_head) {
            gs_io_image ri = {S, S, (size_t)S * 3, dst};
            if (gs_face_quality_measure(qref, &ri, fi->sub.head_R, tg->gp - fi->sub.gaze_pitch,
                                        tg->gy - fi->sub.gaze_yaw, &q, &err)) {
                rc = cli_fail(j->cmd, "%s: target %zu: quality: %s", what, t, err.msg);
                break;
            }
            qp = &q;
        } else if (rquals && !isnan(rquals[t].score)) {
            qp = &rquals[t];
        }
        char d = j->min_q ? decision(j, qp) : 'k';
        if (j->min_q)
            j->decide[s->t0 + t] = d;
        if (d == 'd') {
            dropped_json(j, k, t, tg, qp, &so->dropped);
            continue;
        }
        if (render)
            resize_rgb(render, S, px, So);
        rc = emit_sample(j, k, t, fi, R, ht, tg, qp, px, so);
    }
    free(render);
    if (!rc && (so->labels.oom || so->dropped.oom))
        rc = cli_fail(j->cmd, "out of memory");
    return rc;
}

/* Source k's parts (HDF5 records, labels, dropped samples), then its line
 * in the manifest: after this it is done. */
static int commit_source(job *j, size_t k, source_out *so)
{
    const cli_command *cmd = j->cmd;
    size_t rec = (size_t)j->out_size * j->out_size * 3 + 16;
    char path[4300];
    if (j->want_h5) {
        part_path(j, k, "bin", path, sizeof path);
        if (commit_file(j, path, so->blob, so->kept * rec))
            return cli_fail(cmd, "%s: cannot write (%s)", path, strerror(errno));
    }
    part_path(j, k, "jsonl", path, sizeof path);
    if (commit_file(j, path, so->labels.p ? so->labels.p : "", so->labels.len))
        return cli_fail(cmd, "%s: cannot write (%s)", path, strerror(errno));
    part_path(j, k, "dropped", path, sizeof path);
    if (j->min_q && commit_file(j, path, so->dropped.p ? so->dropped.p : "", so->dropped.len))
        return cli_fail(cmd, "%s: cannot write (%s)", path, strerror(errno));
    char images[4200];
    snprintf(images, sizeof images, "%s/images", j->out);
    char *line = done_line(j, k);
    if (!line)
        return cli_fail(cmd, "out of memory");
    int bad = (j->want_png && cli_fsync_path(images)) || cli_fsync_path(j->state) ||
              manifest_append(j, line);
    free(line);
    if (bad)
        return cli_fail(cmd, "%s: cannot write (%s)", j->manifest, strerror(errno));
    return CLI_OK;
}

/* Fit, fine-tune, render and commit source k. */
static int do_source(job *j, size_t k, double *psnr_out)
{
    const cli_command *cmd = j->cmd;
    source *s = &j->src[k];
    char what[4400];
    src_label(j, k, what, sizeof what);
    gs_error err = {0, ""};
    gs_redirect_input in;
    memset(&in, 0, sizeof in);
    const gs_io_image *face = &in.norm;
    fitted fi;
    memset(&fi, 0, sizeof fi);
    fi.ft_psnr = NAN;
    int rc = CLI_OK;
    gs_model_ctx *c = NULL;
    gs_model *tuned = NULL;
    uint8_t *remote = NULL;
    source_out so;
    memset(&so, 0, sizeof so);
    gs_face_quality_ref *qref = NULL; /* in process: the quality of each gaze-only render */
    gs_face_quality *rquals = NULL; /* through the daemon: its Quality of each */
    if (j->addr) {
        if ((rc = remote_source(j, k, &fi, &remote, &rquals, what)))
            goto done;
        goto render;
    }
    if (load_face(j, k, &in, &err)) {
        rc = cli_fail(cmd, "%s: %s%s", what, err.msg,
                      j->refused ? " (--no-gate to augment it anyway)" : "");
        if (j->refused)
            rc = CLI_REFUSED;
        goto done;
    }
    fi.photo = in.is_photo;
    gs_fit_options o;
    gs_redirect_fit_options(&in, &o);
    o.max_iters = (int)j->iters;
    if (!fi.photo) {
        if (j->fit_labels && s->has_head) {
            double R[9];
            gs_geom_rot_from_pitchyaw(s->head[0], s->head[1], 0, R);
            gs_redirect_fit_head(R, j->info.distance_mm, &o);
        }
        if (j->fit_labels && s->has_gaze) {
            /* The label is in the normalized camera; the fit wants it in
             * the head frame: the labelled head pose's, or the frontal. */
            double R[9], g[3], gh[3];
            if (s->has_head)
                gs_geom_rot_from_pitchyaw(s->head[0], s->head[1], 0, R);
            else
                gs_geom_mat3_identity(R);
            gs_geom_pitchyaw_to_vec(s->gaze[0], s->gaze[1], g);
            gs_geom_mat3_tvec(R, g, gh);
            o.known_gaze = 1;
            gs_geom_vec_to_pitchyaw(gh, &o.gaze_pitch, &o.gaze_yaw);
        }
    }
    /* A fresh context per source: its renders never depend on the sources
     * before it, so a resumed run writes the same bytes. */
    if (!(c = gs_model_ctx_create(j->model))) {
        rc = cli_fail(cmd, "out of memory");
        goto done;
    }
    gs_fit_report fr;
    if (gs_model_fit(c, j->pool, face->data, face->stride, &o, &fi.sub, &fr, &err)) {
        rc = cli_fail(cmd, "%s: fit: %s", what, err.msg);
        goto done;
    }
    if (j->ft.iters > 0) {
        gs_fit_image im;
        gs_fit_image_from_options(&im, face->data, face->stride, NULL);
        im.mask = in.mask;
        gs_finetune_report r;
        if (gs_redirect_finetune(&tuned, j->model, j->pool, &fi.sub, &im, 1, &j->ft, &r, &err)) {
            rc = cli_fail(cmd, "%s: finetune: %s", what, err.msg);
            goto done;
        }
        fi.ft_psnr = r.psnr_best;
        gs_model_ctx_destroy(c);
        if (!(c = gs_model_ctx_create(tuned))) {
            rc = cli_fail(cmd, "out of memory");
            goto done;
        }
    }
/* --quality: what the renders are measured against, the input face and
     * its landmarks (a photo's; found in a normalized face). */
    double quv[GS_FACE_LANDMARKS][2];
    int have_uv = 0;
    if (j->quality && fi.photo) {
        memcpy(quv, in.face.uv_n, sizeof quv);
        have_uv = 1;
    } else if (j->quality && (j->sp || gs_face_shape_model_load(NULL, &j->sp, NULL) == GS_OK) &&
               gs_face_normalized_landmarks(j->sp, face, quv, NULL) == GS_OK) {
        have_uv = 1;
    }
    if (have_uv) {
        gs_face_quality_opts qo;
        gs_face_quality_opts_default(&qo);
        qo.px_per_mm = j->info.focal / j->info.distance_mm;
        qo.shape = j->sp;
        if (gs_face_quality_ref_create(face, (const double(*)[2])quv, &qo, &qref, &err)) {
            rc = cli_fail(cmd, "%s: quality: %s", what, err.msg);
            goto done;
        }
    }
render:
    *psnr_out = fi.sub.fit_psnr;
    gs_xfer_eyes eyes = gs_redirect_eyes(&in);
    if (!(rc = render_source(j, k, &fi, c, face, &eyes, remote, rquals, qref, &so, what)))
        rc = commit_source(j, k, &so);
done:
    free(so.labels.p);
    free(so.dropped.p);
    free(so.blob);
    free(remote);
    free(rquals);
    gs_face_quality_ref_destroy(qref);
    gs_model_ctx_destroy(c);
    gs_model_destroy(tuned);
    gs_redirect_input_free(&in);
    return rc;
}

/* ---- assembly ---- */

/* Appends source k's part ext ("jsonl": labels, h5_row given from *row
 * on; "dropped": as they are) to *all; it must hold want lines. */
static int append_part(job *j, size_t k, const char *ext, size_t want, size_t *row, jbuf *all)
{
    char path[4300];
    uint8_t *buf = NULL;
    size_t len = 0, n = 0;
    part_path(j, k, ext, path, sizeof path);
    if (want && cli_read_file(path, (size_t)1 << 30, &buf, &len))
        return cli_fail(j->cmd, "%s: cannot read; remove %s to start over", path, j->state);
    /* Each label gets its HDF5 row in place of the placeholder. */
    const char *p = (const char *)buf, *end = p + len;
    int renumber = row && j->want_h5;
    while (p < end) {
        const char *nl = memchr(p, '\n', (size_t)(end - p));
        const char *stop = nl ? nl + 1 : end;
        const char *ph = renumber ? strstr(p, ",\"h5_row\":0,") : NULL;
        if (ph && ph < stop) {
            jput(all, "%.*s,\"h5_row\":%zu,", (int)(ph - p), p, *row + n);
            const char *rest = ph + strlen(",\"h5_row\":0,");
            jput(all, "%.*s", (int)(stop - rest), rest);
        } else
            jput(all, "%.*s", (int)(stop - p), p);
        n++;
        p = stop;
    }
    free(buf);
    if (n != want)
        return cli_fail(j->cmd, "%s: %zu lines, want %zu; remove %s to start over", path, n, want,
                        j->state);
    if (row)
        *row += n;
    return CLI_OK;
}

/* Source k's n HDF5 records into rows [row, row + n) of w. */
static int write_h5_part(job *j, size_t k, size_t n, size_t row, gs_h5_writer *w)
{
    const cli_command *cmd = j->cmd;
    size_t S = (size_t)j->out_size, img_bytes = S * S * 3, rec = img_bytes + 16;
    char path[4300];
    uint8_t *blob = NULL;
    size_t len = 0;
    gs_error err = {0, ""};
    part_path(j, k, "bin", path, sizeof path);
    if (cli_read_file(path, (size_t)1 << 40, &blob, &len) || len != n * rec) {
        free(blob);
        return cli_fail(cmd, "%s: cannot read; remove %s to start over", path, j->state);
    }
    uint8_t *pt = malloc(n * img_bytes);
    float *gz = malloc(n * 2 * sizeof *gz), *hd = malloc(n * 2 * sizeof *hd);
    int rc = pt && gz && hd ? CLI_OK : cli_fail(cmd, "out of memory");
    for (size_t t = 0; !rc && t < n; t++) {
        const uint8_t *q = blob + t * rec;
        memcpy(pt + t * img_bytes, q, img_bytes);
        gz[2 * t] = get_f32le(q + img_bytes);
        gz[2 * t + 1] = get_f32le(q + img_bytes + 4);
        hd[2 * t] = get_f32le(q + img_bytes + 8);
        hd[2 * t + 1] = get_f32le(q + img_bytes + 12);
    }
    if (!rc && gs_h5_write_rows(w, row, n, pt, gz, hd, &err))
        rc = cli_fail(cmd, "%s: %s", j->h5_path, err.msg);
    free(pt);
    free(gz);
    free(hd);
    free(blob);
    return rc;
}

/* The shard's final files from the parts, in source order: the HDF5 (the
 * kept samples' rows), the dropped samples' list (--min-quality), the
 * labels. *rows_out: the samples kept. */
static int assemble(job *j, size_t *rows_out)
{
    const cli_command *cmd = j->cmd;
    size_t rows = 0;
    for (size_t k = (size_t)j->shard_i; k < j->nsrc; k += (size_t)j->shard_n)
        rows += kept_of(j, k, NULL, NULL);
    *rows_out = rows;
    jbuf all = {0}, dropped = {0};
    int rc = CLI_OK;
    size_t row = 0;
    gs_h5_writer *w = NULL;
    gs_error err = {0, ""};
    char tmp[4200];
    snprintf(tmp, sizeof tmp, "%s.tmp", j->h5_path);
    if (j->want_h5) {
        if (j->write_budget == 0) {
            errno = ENOSPC;
            return cli_fail(cmd, "%s: cannot write (%s)", j->h5_path, strerror(errno));
        }
        if (gs_h5_create(tmp, rows, j->out_size, &w, &err))
            return cli_fail(cmd, "%s: %s", j->h5_path, err.msg);
    }
    for (size_t k = (size_t)j->shard_i; k < j->nsrc && !rc; k += (size_t)j->shard_n) {
        size_t nd = 0, kept = kept_of(j, k, &nd, NULL), row0 = row;
        rc = append_part(j, k, "jsonl", kept, &row, &all);
        if (!rc && j->min_q)
            rc = append_part(j, k, "dropped", nd, NULL, &dropped);
        if (!rc && w && kept)
            rc = write_h5_part(j, k, kept, row0, w);
    }
    if (w) {
        if (rc)
            gs_h5_abort(w);
        else if (gs_h5_finish(w, &err))
            rc = cli_fail(cmd, "%s: %s", j->h5_path, err.msg);
        if (!rc && (cli_fsync_path(tmp) || rename(tmp, j->h5_path)))
            rc = cli_fail(cmd, "%s: cannot write (%s)", j->h5_path, strerror(errno));
        if (rc)
            unlink(tmp);
    }
    if (!rc && (all.oom || dropped.oom))
        rc = cli_fail(cmd, "out of memory");
    if (!rc && j->min_q &&
        commit_file(j, j->dropped_path, dropped.p ? dropped.p : "", dropped.len))
        rc = cli_fail(cmd, "%s: cannot write (%s)", j->dropped_path, strerror(errno));
    if (!rc && commit_file(j, j->labels_path, all.p ? all.p : "", all.len))
        rc = cli_fail(cmd, "%s: cannot write (%s)", j->labels_path, strerror(errno));
    if (!rc && cli_fsync_path(j->out))
        rc = cli_fail(cmd, "%s: cannot sync (%s)", j->out, strerror(errno));
    free(all.p);
    free(dropped.p);
    return rc;
}

/* After the final files: the parts are no longer needed. */
static void remove_parts(job *j)
{
    char path[4300];
    for (size_t k = (size_t)j->shard_i; k < j->nsrc; k += (size_t)j->shard_n) {
        part_path(j, k, "bin", path, sizeof path);
        unlink(path);
        part_path(j, k, "jsonl", path, sizeof path);
        unlink(path);
        part_path(j, k, "dropped", path, sizeof path);
        unlink(path);
    }
}

/* ---- progress ---- */

static void fmt_eta(double s, char *buf, size_t cap)
{
    if (!(s >= 0) || s > 1e8)
        snprintf(buf, cap, "?");
    else if (s >= 3600)
        snprintf(buf, cap, "%dh%02dm", (int)(s / 3600), (int)fmod(s / 60, 60));
    else if (s >= 60)
        snprintf(buf, cap, "%dm%02ds", (int)(s / 60), (int)fmod(s, 60));
    else
        snprintf(buf, cap, "%ds", (int)(s + 0.5));
}

/* ---- the command ---- */

/* --min-quality's counts over the shard for the last line, into buf (""
 * without the option); on stderr when every sample was dropped, and when
 * gaze-only samples could not be scored (kept all the same). Returns the
 * samples dropped. */
static size_t gate_report(const job *j, char *buf, size_t cap)
{
    size_t kept = 0, dropped = 0, unscored = 0, blind = 0;
    buf[0] = 0;
    if (!j->min_q)
        return 0;
    for (size_t k = (size_t)j->shard_i; k < j->nsrc; k += (size_t)j->shard_n) {
        const source *s = &j->src[k];
        size_t d, u;
        kept += kept_of(j, k, &d, &u);
        dropped += d;
        unscored += u;
        for (size_t t = 0; t < s->nt; t++)
            blind += j->decide[s->t0 + t] == 'u' && !j->tg[s->t0 + t].use_head;
    }
    if (blind)
        fprintf(stderr, "gazesplat augment: warning: %zu gaze-only samples carry no score and "
                "were kept unscored (%s)\n", blind,
                j->addr ? "the daemon measured none: it needs its landmark model (photo_input) "
                          "and a face's landmarks"
                        : "no landmarks found in their faces to measure against");
    const char *list = j->dropped_path + strlen(j->out) + 1;
    snprintf(buf, cap, "; --min-quality %.10g: %zu kept (%zu of them unscored), %zu dropped "
             "(listed in %s)", j->min_quality, kept, unscored, dropped, list);
    if (kept == 0 && dropped > 0)
        fprintf(stderr, "gazesplat augment: every sample%s was dropped: all %zu scored under "
                "--min-quality %.10g; %s is empty%s and %s lists them\n",
                j->shard_n > 1 ? " of this shard" : "", dropped, j->min_quality,
                j->labels_path + strlen(j->out) + 1,
                j->want_h5 ? ", the HDF5 has no rows," : "", list);
    return dropped;
}

static uint64_t hash_file(uint64_t h, const char *path)
{
    FILE *f = fopen(path, "rb");
    if (!f)
        return fnv_str(h, "(unreadable)");
    unsigned char buf[65536];
    size_t n;
    while ((n = fread(buf, 1, sizeof buf, f)) > 0)
        h = fnv(h, buf, n);
    fclose(f);
    return h;
}

static void job_free(job *j)
{
    for (size_t i = 0; i < j->nsrc; i++) {
        free(j->src[i].name);
        free(j->src[i].subject);
    }
    free(j->src);
    free(j->tg);
    free(j->decide);
    gs_h5_close(j->h5);
    gs_face_detector_destroy(j->det);
    gs_face_shape_model_destroy(j->sp);
    gs_pool_destroy(j->pool);
    gs_model_destroy(j->model);
}

_Static_assert(CLI_NOPTS(augment_opts) == O_N, "augment_opts: one entry per option index");

static int run_augment(const cli_command *cmd, cli_opt *o)
{
    int rc = CLI_OK;
    if (o[O_MERGE].value) {
        long n;
        for (int i = 0; i < O_N; i++)
            if (i != O_MERGE && i != O_OUT && o[i].value)
                return cli_usage_error(cmd, "--merge takes --out alone, not %s", o[i].name);
        if (!o[O_OUT].value)
            return cli_usage_error(cmd, "--merge N needs --out DIR (where the shards are)");
        if (cli_parse_long(o[O_MERGE].value, 2, 1000000, &n))
            return cli_usage_error(cmd, "--merge: want the number of shards, 2 or more; got '%s'",
                                   o[O_MERGE].value);
        return aug_merge(cmd, o[O_OUT].value, n);
    }
    job j;
    memset(&j, 0, sizeof j);
    j.cmd = cmd;
    j.write_budget = -1;
    if ((!o[O_MODEL].value == !o[O_ADDR].value) || !o[O_INPUT].value || !o[O_OUT].value)
        return cli_usage_error(cmd, "--input, --out and one of --model (in process) and --addr "
                               "(through gazesplatd) are needed");
    if (o[O_TOKEN].value && !o[O_ADDR].value)
        return cli_usage_error(cmd, "--token goes with --addr");
    if (o[O_ADDR].value && o[O_THREADS].value)
        return cli_usage_error(cmd, "--threads is the server's with --addr");
    if (o[O_RETRIES].value && !o[O_ADDR].value)
        return cli_usage_error(cmd, "--retries goes with --addr");
    j.retries = 4;
    if (o[O_RETRIES].value && cli_parse_long(o[O_RETRIES].value, 1, 100, &j.retries))
        return cli_usage_error(cmd, "--retries: want the tries of one source in all, 1..100; "
                               "got '%s'", o[O_RETRIES].value);
    j.input = o[O_INPUT].value;
    j.out = o[O_OUT].value;
    j.gate = !o[O_NOGATE].value;
    j.quality = o[O_QUALITY].value != NULL;
    if (o[O_MINQ].value) {
        if (parse_num(o[O_MINQ].value, &j.min_quality) || j.min_quality < 0 || j.min_quality > 1)
            return cli_usage_error(cmd, "--min-quality: want a score in [0, 1] (the redirect "
                                   "quality, docs/face.md); got '%s'", o[O_MINQ].value);
        j.min_q = j.quality = 1;
    }
    j.want_png = j.want_h5 = 1;
    if (o[O_FORMAT].value) {
        const char *f = o[O_FORMAT].value;
        if (!strcmp(f, "png"))
            j.want_h5 = 0;
        else if (!strcmp(f, "h5"))
            j.want_png = 0;
        else if (strcmp(f, "both"))
            return cli_usage_error(cmd, "--format: want png, h5 or both; got '%s'", f);
    }
    j.shard_i = 0;
    j.shard_n = 1;
    if (o[O_SHARD].value) {
        char a[32];
        const char *sl = strchr(o[O_SHARD].value, '/');
        size_t n = sl ? (size_t)(sl - o[O_SHARD].value) : 0;
        if (!sl || n == 0 || n >= sizeof a)
            return cli_usage_error(cmd, "--shard: want I/N with 0 <= I < N; got '%s'",
                                   o[O_SHARD].value);
        memcpy(a, o[O_SHARD].value, n);
        a[n] = 0;
        if (cli_parse_long(sl + 1, 1, 1000000, &j.shard_n) ||
            cli_parse_long(a, 0, 1000000, &j.shard_i))
            return cli_usage_error(cmd, "--shard: want I/N with 0 <= I < N; got '%s'",
                                   o[O_SHARD].value);
        if (j.shard_i >= j.shard_n)
            return cli_usage_error(cmd, "--shard %s: index %ld out of range (0..%ld)",
                                   o[O_SHARD].value, j.shard_i, j.shard_n - 1);
    }
    long seed = 0, threads = 2, size = 0;
    j.iters = GS_REDIRECT_FIT_ITERS;
    if (o[O_SEED].value && cli_parse_long(o[O_SEED].value, 0, 4294967295L, &seed))
        return cli_usage_error(cmd, "--seed: want 0..4294967295; got '%s'", o[O_SEED].value);
    if (o[O_ITERS].value && cli_parse_long(o[O_ITERS].value, 1, 100000, &j.iters))
        return cli_usage_error(cmd, "--iters: want 1..100000; got '%s'", o[O_ITERS].value);
    if (o[O_SIZE].value && cli_parse_long(o[O_SIZE].value, 16, 1024, &size))
        return cli_usage_error(cmd, "--size: want 16..1024 px; got '%s'", o[O_SIZE].value);
    if (o[O_THREADS].value && cli_parse_long(o[O_THREADS].value, 1, 256, &threads))
        return cli_usage_error(cmd, "--threads: want 1..256; got '%s'", o[O_THREADS].value);
    /* The served setting (daemon/README.md, experiments/eval/README.md): the fit
     * to its plateau (at most 200 iterations), 15 fine-tuning steps at
     * 0.004 with the mirrored view, detail transfer with the eyeball warp. */
    const char *ftn = o[O_FT].value ? o[O_FT].value : CLI_STR(GS_REDIRECT_FINETUNE_STEPS);
    if (strcmp(ftn, "0") == 0) {
        if (o[O_FTLR].value)
            return cli_usage_error(cmd, "--finetune-lr goes with --finetune N > 0");
        gs_finetune_options_default(&j.ft);
        j.ft.iters = 0;
    } else if ((rc = cli_parse_finetune(cmd, ftn, NULL,
                                        o[O_FTLR].value, NULL, NULL,
                                        NULL, &j.ft)))
        return rc;
    j.transfer = o[O_TRANSFER].value == NULL;
    j.fit_labels = o[O_FITLAB].value != NULL;
    j.h5_rgb = o[O_RGB].value != NULL;
    const char *hook = getenv("GAZESPLAT_AUGMENT_ENOSPC_AFTER");
    if (hook && *hook && cli_parse_long(hook, 0, 1L << 40, &j.write_budget))
        return cli_usage_error(cmd, "GAZESPLAT_AUGMENT_ENOSPC_AFTER: want a count");

    /* Inputs. */
    struct stat st;
    if (stat(j.input, &st) != 0) {
        rc = cli_fail(cmd, "%s: %s", j.input, strerror(errno));
        goto out;
    }
    j.is_h5 = !S_ISDIR(st.st_mode);
    if (j.is_h5 && o[O_LABELS].value) {
        rc = cli_usage_error(cmd, "--labels goes with a folder (an HDF5 file has its labels)");
        goto out;
    }
    if (!j.is_h5 && j.h5_rgb) {
        rc = cli_usage_error(cmd, "--h5-rgb goes with an HDF5 input");
        goto out;
    }
    uint64_t fp = 1469598103934665603ull;
    if ((rc = j.is_h5 ? open_h5(&j) : list_dir(&j)))
        goto out;
    if (!j.is_h5 && o[O_LABELS].value && (rc = read_labels(&j, o[O_LABELS].value, &fp)))
        goto out;
    if ((rc = make_targets(&j, o, (uint64_t)seed)))
        goto out;
    if (j.min_q && !(j.decide = calloc(j.ntg + 1, 1))) {
        rc = cli_fail(cmd, "out of memory");
        goto out;
    }
    /* Everything that shapes the outputs goes into the fingerprint. */
    for (int i = 0; i < O_N; i++)
        if (i != O_THREADS && i != O_OUT && (i != O_MINQ || o[i].value)) {
            /* (--min-quality only when given: a run without it keeps the
             * fingerprint it had before the option existed.) */
            fp = fnv_str(fp, o[i].name);
            fp = fnv_str(fp, o[i].value);
        }
    if (o[O_MODEL].value)
        fp = hash_file(fp, o[O_MODEL].value);
    if (j.is_h5)
        fp = fnv(fp, &st.st_size, sizeof st.st_size);
    for (size_t i = 0; i < j.nsrc; i++)
        fp = fnv_str(fp, j.src[i].name);
    fp = fnv(fp, j.tg, j.ntg * sizeof *j.tg);
    j.fingerprint = fp;

    gs_error err = {0, ""};
    if (o[O_ADDR].value) {
        char server[256], msg[600];
        int srv_size = 0;
        const char *token = o[O_TOKEN].value ? o[O_TOKEN].value : getenv("GAZESPLAT_TOKEN");
        j.addr = o[O_ADDR].value;
        j.token = token;
        gs_client *first = NULL;
        if (aug_remote_connect(o[O_ADDR].value, token, NULL, &first, &srv_size, server,
                               sizeof server, msg, sizeof msg)) {
            rc = cli_fail(cmd, "%s", msg);
            goto out;
        }
        /* The server's model is in the fingerprint as far as HELLO tells it. */
        j.fingerprint = fnv_str(fnv(j.fingerprint, &srv_size, sizeof srv_size), server);
        snprintf(j.server, sizeof j.server, "%s", server);
        /* Each source opens its own connection (remote_fit_render). */
        aug_remote_close(first);
        memset(&j.info, 0, sizeof j.info);
        j.info.image_size = srv_size;
        j.info.distance_mm = NAN;
    } else if (gs_model_load(o[O_MODEL].value, &j.model, &err)) {
        rc = cli_fail(cmd, "%s: %s", o[O_MODEL].value, err.msg);
        goto out;
    } else
        gs_model_get_info(j.model, &j.info);
    j.out_size = size ? (int)size : j.info.image_size;
    j.pool = gs_pool_create((int)threads);
    if (!j.pool) {
        rc = cli_fail(cmd, "out of memory");
        goto out;
    }

    /* Outputs. */
    char suffix[64] = "";
    if (j.shard_n > 1)
        snprintf(suffix, sizeof suffix, "-%ld-of-%ld", j.shard_i, j.shard_n);
    snprintf(j.state, sizeof j.state, "%s/.augment%s", j.out, j.shard_n > 1 ? suffix : "");
    snprintf(j.manifest, sizeof j.manifest, "%s/manifest", j.state);
    snprintf(j.labels_path, sizeof j.labels_path, "%s/labels%s.jsonl", j.out, suffix);
    snprintf(j.h5_path, sizeof j.h5_path, "%s/augment%s.h5", j.out, suffix);
    snprintf(j.dropped_path, sizeof j.dropped_path, "%s/dropped%s.jsonl", j.out, suffix);
    char images[4200];
    snprintf(images, sizeof images, "%s/images", j.out);
    if (strlen(j.out) > 3800 || make_dir(j.out) || make_dir(j.state) ||
        (j.want_png && make_dir(images))) {
        rc = cli_fail(cmd, "cannot create %s (%s)", j.out, strerror(errno));
        goto out;
    }
    unsigned char *done = calloc(j.nsrc, 1);
    int finished = 0;
    if (!done) {
        rc = cli_fail(cmd, "out of memory");
        goto out;
    }
    if ((rc = open_manifest(&j, done, &finished))) {
        free(done);
        goto out;
    }
    size_t todo = 0, total = 0, shard_samples = 0;
    for (size_t k = (size_t)j.shard_i; k < j.nsrc; k += (size_t)j.shard_n) {
        total++;
        shard_samples += j.src[k].nt;
    }
    if (finished) {
        char gate[600];
        if (!file_size_is(j.labels_path, -1) || (j.want_h5 && !file_size_is(j.h5_path, -1)) ||
            (j.min_q && !file_size_is(j.dropped_path, -1)))
            rc = cli_fail(cmd, "%s: finished, but its files are gone; remove %s to make them "
                          "again", j.out, j.state);
        else
            printf("gazesplat augment: already complete: %zu images -> %s%s\n",
                   shard_samples - gate_report(&j, gate, sizeof gate), j.out, gate);
        free(done);
        goto out;
    }
    for (size_t k = (size_t)j.shard_i; k < j.nsrc; k += (size_t)j.shard_n) {
        if (done[k] && !parts_present(&j, k))
            done[k] = 0; /* listed but its parts are gone: made again */
        todo += !done[k];
    }
    int tty = isatty(2);
    double t0 = cli_now_s();
    size_t ndone = 0, images_done = 0, images_todo = 0;
    for (size_t k = (size_t)j.shard_i; k < j.nsrc; k += (size_t)j.shard_n)
        images_todo += done[k] ? 0 : j.src[k].nt;
    if (total > todo)
        fprintf(stderr, "gazesplat augment: resuming: %zu of %zu sources done\n", total - todo,
                total);
    for (size_t k = (size_t)j.shard_i; k < j.nsrc && !rc; k += (size_t)j.shard_n) {
        if (done[k])
            continue;
        double psnr = NAN;
        rc = do_source(&j, k, &psnr);
        if (rc)
            break;
        ndone++;
        images_done += j.src[k].nt;
        double el = cli_now_s() - t0, rate = el > 0 ? images_done / el : 0;
        char eta[32], what[4400];
        fmt_eta(rate > 0 ? (images_todo - images_done) / rate : -1, eta, sizeof eta);
        if (tty)
            fprintf(stderr, "\rgazesplat augment: %zu/%zu sources, %zu images, %.2f images/s, "
                    "ETA %s   ", total - todo + ndone, total, images_done, rate, eta);
        else
            fprintf(stderr, "gazesplat augment: %zu/%zu %s: PSNR %.2f dB, %zu images "
                    "(%.2f images/s, ETA %s)\n", total - todo + ndone, total,
                    src_label(&j, k, what, sizeof what), psnr, j.src[k].nt, rate, eta);
    }
    if (tty && ndone)
        fputc('\n', stderr);
    free(done);
    if (rc) {
        fprintf(stderr, "gazesplat augment: stopped; the sources done are kept in %s: run the "
                "same command again to continue\n", j.manifest);
        goto out;
    }
    size_t rows = 0;
    if ((rc = assemble(&j, &rows)))
        goto out;
    if (manifest_append(&j, "finished\n")) {
        rc = cli_fail(cmd, "%s: cannot write (%s)", j.manifest, strerror(errno));
        goto out;
    }
    remove_parts(&j);
    double el = cli_now_s() - t0;
    char gate[600];
    gate_report(&j, gate, sizeof gate);
    printf("gazesplat augment: %zu images from %zu sources -> %s (%s%s%s) in %.1f s%s\n", rows,
           total, j.out, j.labels_path + strlen(j.out) + 1, j.want_h5 ? ", " : "",
           j.want_h5 ? j.h5_path + strlen(j.out) + 1 : "", el, gate);
out:
    job_free(&j);
    return rc;
}
