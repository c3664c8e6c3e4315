/* gazesplat check-labels: scores a dataset's gaze labels against the gaze
 * its images show (a shipped estimator on any dataset; on a gazesplat
 * synth dataset also the exact readout by synthesis) and lists outliers. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "cli.h"
#include "eval_estimator.h"
#include "gs_msg.h"
#include "gazesplat/eval.h"
#include "gazesplat/geom.h"
#include "gazesplat/image_io.h"
#include "gazesplat/synth.h"
#include "gazesplat/xgaze_h5.h"
#include "json_scan.h"

#define DEG 57.29577951308232
#define MAX_LABELS_BYTES ((size_t)4 << 30)

static int run_check(const cli_command *cmd, cli_opt *o);

static const cli_opt check_opts[] = {
    {"--dir", 1, NULL}, {"--labels", 1, NULL}, {"--h5", 1, NULL}, {"--h5-rgb", 0, NULL},
    {"--estimator", 1, NULL}, {"--readout", 1, NULL}, {"--threshold", 1, NULL},
    {"--max-outliers", 1, NULL}, {"--json", 1, NULL}, {"--list", 1, NULL}, {"--limit", 1, NULL},
    {"--threads", 1, NULL}};

const cli_command cli_check_labels_command = {
    "check-labels",
    "score a dataset's gaze labels against its images and list outliers",
    "usage: gazesplat check-labels (--dir DIR | --h5 FILE.h5) [options]\n"
    "\n"
    "  --dir DIR          a dataset folder as gazesplat synth or augment writes\n"
    "                     it: DIR/labels.jsonl with images/*.png (or h5_row\n"
    "                     rows of DIR/augment.h5 where an image is null)\n"
    "  --labels FILE      the labels file (default DIR/labels.jsonl)\n"
    "  --h5 FILE.h5       an ETH-XGaze-style HDF5 file (face_patch, face_gaze);\n"
    "                     patches BGR unless --h5-rgb; subject: the file's stem\n"
    "  --h5-rgb           the HDF5 patches are RGB\n"
    "  --estimator FILE   gaze estimator (default models/gaze-resnet.safetensors,\n"
    "                     here or as installed); 'none': skip it\n"
    "  --readout MODE     synth datasets (DIR/README.md names the generator):\n"
    "                     exact (auto, the default, on such a dataset): the\n"
    "                     generator renders each index again and, when the\n"
    "                     image is that render byte for byte, its gaze is the\n"
    "                     readout, exactly; synthesis: the gaze read from the\n"
    "                     pixels by analysis by synthesis (gs_eval_gaze_readout,\n"
    "                     for images the generator did not write; about 1 s an\n"
    "                     image); off: the estimator alone\n"
    "  --threshold DEG    outlier when the sample's error exceeds DEG (the\n"
    "                     readout's error where there is one, else the\n"
    "                     estimator's; default 20)\n"
    "  --max-outliers F   exit 4 when more than the fraction F of the scored\n"
    "                     samples are outliers (0..1, default 1: never)\n"
    "  --json FILE        summary, per subject, outliers and every sample\n"
    "  --list N           outliers printed in the table (default 20)\n"
    "  --limit N          check only the first N samples\n"
    "  --threads N        worker threads (default 2)\n"
    "\n"
    "The label checked is the gaze in the normalized camera: synth's\n"
    "gaze_norm_*, augment's gaze_cam_* (its camera is the normalized one),\n"
    "the HDF5's face_gaze. Errors are angles between 3D directions, degrees.\n"
    "Exit 0, 1 on bad input (file and line or row named), 4 over --max-outliers.\n",
    .opts = check_opts,
    .nopts = CLI_NOPTS(check_opts),
    .run_opts = run_check,
};

enum {
    O_DIR, O_LABELS, O_H5, O_H5RGB, O_EST, O_READOUT, O_THRESH, O_MAXOUT, O_JSON,
    O_LIST, O_LIMIT, O_THREADS, O_N
};

enum { READ_NONE = 0, READ_EXACT, READ_SYNTHESIS };

typedef struct sample {
    long row;               /* line of the labels (1-based) or HDF5 row (0-based) */
    long long index;        /* the dataset's index */
    char image[256];
    char subject[64];
    double label_p, label_y;   /* normalized camera, radians */
    double est_p, est_y, est_err;
    double read_p, read_y, read_err;
    double score;
    int outlier;
    const char *note;          /* why a reading is missing, or NULL */
} sample;

typedef struct checker {
    const cli_command *cmd;
    gs_pool *pool;
    eval_estimator *est;
    int readout;                /* READ_*: with one, synth is valid */
    gs_synth_gen_config synth;
    gs_synth_sample render;     /* the generator's render (exact) */
    gs_h5_reader *h5;           /* --h5, or DIR/augment.h5 when needed */
    gs_h5_info h5info;
    int h5_bgr;
    char h5_path[4096];
    uint8_t *patch;
} checker;

static void sample_init(sample *s)
{
    memset(s, 0, sizeof *s);
    s->est_p = s->est_y = s->est_err = NAN;
    s->read_p = s->read_y = s->read_err = NAN;
    s->score = NAN;
}

/* ---- reading the labels ---- */

/* Array member of exactly n numbers. 0 or -1. */
static int get_numbers(const js_object *o, const char *key, double *out, int n)
{
    const js_value *v = js_get(o, key);
    if (!v || v->kind != JS_ARRAY)
        return -1;
    const char *p = v->p + 1, *e = v->p + v->len - 1;
    for (int i = 0; i < n; i++) {
        char *q;
        while (p < e && (*p == ' ' || *p == ','))
            p++;
        out[i] = strtod(p, &q);
        if (q == p || !isfinite(out[i]))
            return -1;
        p = q;
    }
    while (p < e && *p == ' ')
        p++;
    return p == e ? 0 : -1;
}

/* The gaze label of a line into s (synth's normalized gaze, else the
 * camera's). */
static int line_label(const checker *c, const char *file, long line, const js_object *o,
                      sample *s)
{
    static const char *const keys[2][2] = {{"gaze_norm_pitch_rad", "gaze_norm_yaw_rad"},
                                           {"gaze_cam_pitch_rad", "gaze_cam_yaw_rad"}};
    int which = js_get(o, keys[0][0]) ? 0 : 1;
    double v[2];
    for (int k = 0; k < 2; k++) {
        int kind;
        if (js_get_number(o, keys[which][k], &v[k], &kind) == 0)
            continue;
        if (kind == JS_NONE)
            return cli_fail(c->cmd, "%s:%ld: no gaze label (gaze_norm_pitch_rad/_yaw_rad "
                            "or gaze_cam_pitch_rad/_yaw_rad)", file, line);
        return cli_fail(c->cmd, "%s:%ld: gaze label %s is %s", file, line, keys[which][k],
                        kind == JS_NULL ? "null (NaN or unknown)"
                                        : kind == JS_NUMBER ? "not finite" : "not a number");
    }
    s->label_p = v[0];
    s->label_y = v[1];
    return CLI_OK;
}

static int parse_line(const checker *c, const char *file, long line, const char *text,
                      size_t len, js_object *o, sample *s)
{
    char msg[160];
    sample_init(s);
    s->row = line;
    if (js_scan_object(text, len, o, msg, sizeof msg))
        return cli_fail(c->cmd, "%s:%ld: bad JSON: %s", file, line, msg);
    int rc = line_label(c, file, line, o, s);
    if (rc)
        return rc;
    double d;
    s->index = js_get_number(o, "index", &d, NULL) == 0 ? (long long)d : line - 1;
    const js_value *im = js_get(o, "image");
    if (im && im->kind == JS_STRING) {
        if (js_get_string(o, "image", s->image, sizeof s->image))
            return cli_fail(c->cmd, "%s:%ld: image name longer than %zu bytes or with a "
                            "non-ASCII escape", file, line, sizeof s->image - 1);
        if (!s->image[0] ||
            s->image[0] == '/' || strstr(s->image, ".."))
            return cli_fail(c->cmd, "%s:%ld: image must be a relative path inside the "
                            "dataset folder", file, line);
    } else if (!(im && im->kind == JS_NULL && js_get_number(o, "h5_row", &d, NULL) == 0)) {
        return cli_fail(c->cmd, "%s:%ld: no image (a file name, or null with h5_row)",
                        file, line);
    }
    if (js_get_number(o, "identity_seed", &d, NULL) == 0)
        snprintf(s->subject, sizeof s->subject, "%.0f", d);
    else if (js_get_string(o, "subject", s->subject, sizeof s->subject) &&
             js_get_string(o, "source", s->subject, sizeof s->subject))
        snprintf(s->subject, sizeof s->subject, "-");
    return CLI_OK;
}

/* ---- the two readings ---- */

static double angle_deg(double p0, double y0, double p1, double y1)
{
    return gs_eval_angle_deg(p0, y0, p1, y1);
}

static int estimate(checker *c, const uint8_t *rgb, int w, int h, size_t stride, sample *s)
{
    if (!c->est)
        return CLI_OK;
    float out[4];
    gs_error err = {0, ""};
    if (eval_estimator_predict(c->est, c->pool, rgb, w, h, stride, out, &err) != GS_OK)
        return cli_fail(c->cmd, "sample %lld: estimator: %s", s->index, err.msg);
    s->est_p = out[0];
    s->est_y = out[1];
    s->est_err = angle_deg(s->label_p, s->label_y, s->est_p, s->est_y);
    return CLI_OK;
}

/* The readouts of a synth sample. Its scene comes from the generator
 * (checked against the line's identity and head pose, which a gaze label
 * error leaves alone). exact: the generator's render of that index must
 * be the image, byte for byte; its gaze is then what the image shows,
 * exactly. synthesis: the gaze read from the pixels by analysis by
 * synthesis (gs_eval_gaze_readout), for images that are not the
 * generator's own. Either is taken to the normalized camera, as the label. */
static void readout(checker *c, const js_object *o, const uint8_t *rgb, size_t stride,
                    sample *s)
{
    gs_synth_scene sc;
    gs_synth_camera cam;
    gs_error err = {0, ""};
    double seed, head_R[9];
    if (s->index < 0 || gs_synth_gen_scene(&c->synth, (uint64_t)s->index, &sc, &cam, &err) ||
        gs_synth_labels_compute(&sc, &cam, &c->render.labels, &err)) {
        s->note = "no scene for this index";
        return;
    }
    const gs_synth_labels *lab = &c->render.labels;
    if (js_get_number(o, "identity_seed", &seed, NULL) || (uint64_t)seed != sc.identity.seed ||
        get_numbers(o, "head_R", head_R, 9)) {
        s->note = "identity or head pose unreadable or not the generator's";
        return;
    }
    for (int k = 0; k < 9; k++)
        if (fabs(head_R[k] - lab->head_R[k]) > 1e-6) {
            s->note = "head pose differs from the generator's";
            return;
        }
    if (c->readout == READ_EXACT) {
        int n = c->synth.size;
        if (gs_synth_gen_sample(&c->synth, (uint64_t)s->index, c->pool, &c->render, &err)) {
            s->note = "the generator failed on this index";
            return;
        }
        for (int y = 0; y < n; y++)
            if (memcmp(rgb + (size_t)y * stride, c->render.rgb + (size_t)y * c->render.stride,
                       3 * (size_t)n)) {
                s->note = "image differs from the generator's render";
                return;
            }
        s->read_p = c->render.labels.gaze_norm_pitch;
        s->read_y = c->render.labels.gaze_norm_yaw;
    } else {
        gs_eval_readout ro;
        if (gs_eval_gaze_readout(&sc, c->synth.size, 0.0, 0.0, rgb, stride, NULL, c->pool,
                                 &ro, &err) != GS_OK) {
            s->note = "readout failed (eyes closed or hidden)";
            return;
        }
        double gh[3], gc[3], gn[3];
        gs_geom_pitchyaw_to_vec(ro.pitch, ro.yaw, gh);
        gs_geom_mat3_vec(lab->head_R, gh, gc);
        gs_geom_norm_vec(&lab->norm, gc, gn);
        gs_geom_vec_to_pitchyaw(gn, &s->read_p, &s->read_y);
    }
    s->read_err = angle_deg(s->label_p, s->label_y, s->read_p, s->read_y);
}

static int read_image(checker *c, const char *dir, const char *file, const js_object *o,
                      sample *s, gs_io_image *img, int *owned)
{
    gs_error err = {0, ""};
    *owned = 0;
    if (s->image[0]) {
        char path[4600];
        snprintf(path, sizeof path, "%s/%s", dir, s->image);
        if (gs_io_image_read(path, NULL, img, &err) != GS_OK)
            return cli_fail(c->cmd, "%s:%ld: image %s: %s", file, s->row, path, err.msg);
        *owned = 1;
        return CLI_OK;
    }
    double d;
    js_get_number(o, "h5_row", &d, NULL);
    if (!c->h5) {
        snprintf(c->h5_path, sizeof c->h5_path, "%s/augment.h5", dir);
        if (gs_h5_open(c->h5_path, &c->h5, &c->h5info, &err) != GS_OK)
            return cli_fail(c->cmd, "%s:%ld: h5_row without an image: %s: %s", file, s->row,
                            c->h5_path, err.msg);
        c->h5_bgr = 1;
        c->patch = malloc((size_t)c->h5info.width * c->h5info.height * 3);
        if (!c->patch)
            return cli_fail(c->cmd, "out of memory");
    }
    if (!(d >= 0 && d < (double)c->h5info.rows))
        return cli_fail(c->cmd, "%s:%ld: h5_row %.0f outside the %zu rows of %s", file, s->row,
                        d, c->h5info.rows, c->h5_path);
    if (gs_h5_read_row(c->h5, (size_t)d, c->patch, NULL, NULL, &err) != GS_OK)
        return cli_fail(c->cmd, "%s: %s", c->h5_path, err.msg);
    img->width = c->h5info.width;
    img->height = c->h5info.height;
    img->stride = 3 * (size_t)img->width;
    img->data = c->patch;
    if (c->h5_bgr)
        for (size_t i = 0; i < (size_t)img->width * img->height; i++) {
            uint8_t t = img->data[3 * i];
            img->data[3 * i] = img->data[3 * i + 2];
            img->data[3 * i + 2] = t;
        }
    return CLI_OK;
}

/* Every line of a labels file, read and scored in order. */
static int check_dir(checker *c, const char *dir, const char *file, long limit,
                     sample **out, long *n_out)
{
    uint8_t *text;
    size_t len;
    if (cli_read_file(file, MAX_LABELS_BYTES, &text, &len))
        return cli_fail(c->cmd, "cannot read %s (missing, empty or unreadable)", file);
    long cap = 1;
    for (size_t i = 0; i < len; i++)
        cap += text[i] == '\n';
    sample *ss = calloc((size_t)cap, sizeof *ss);
    js_object *o = malloc(sizeof *o);
    int rc = ss && o ? CLI_OK : cli_fail(c->cmd, "out of memory");
    long n = 0, line = 0;
    size_t at = 0;
    cli_progress_t prog;
    cli_progress_start(&prog);
    while (rc == CLI_OK && at < len && (limit <= 0 || n < limit)) {
        const char *p = (const char *)text + at;
        const char *nl = memchr(p, '\n', len - at);
        size_t l = nl ? (size_t)(nl - p) : len - at;
        at += l + (nl ? 1 : 0);
        line++;
        if (l == 0 && at >= len)
            break;
        rc = parse_line(c, file, line, p, l, o, &ss[n]);
        gs_io_image img = {0};
        int owned = 0;
        if (rc == CLI_OK)
            rc = read_image(c, dir, file, o, &ss[n], &img, &owned);
        if (rc == CLI_OK)
            rc = estimate(c, img.data, img.width, img.height, img.stride, &ss[n]);
        if (rc == CLI_OK && c->readout) {
            if (img.width != c->synth.size || img.height != c->synth.size)
                rc = cli_fail(c->cmd, "%s:%ld: image is %dx%d, the dataset's README says %d",
                              file, line, img.width, img.height, c->synth.size);
            else
                readout(c, o, img.data, img.stride, &ss[n]);
        }
        if (owned)
            gs_io_image_free(&img);
        n++;
        if (rc == CLI_OK)
            cli_progress(&prog, 0, "gazesplat check-labels: %ld samples, %.0f s", n,
                         cli_now_s() - prog.start);
    }
    cli_progress_done(&prog);
    free(o);
    free(text);
    if (rc == CLI_OK && n == 0)
        rc = cli_fail(c->cmd, "%s: no labels", file);
    if (rc != CLI_OK) {
        free(ss);
        return rc;
    }
    *out = ss;
    *n_out = n;
    return CLI_OK;
}

static int check_h5(checker *c, const char *path, long limit, sample **out, long *n_out)
{
    gs_error err = {0, ""};
    if (gs_h5_open(path, &c->h5, &c->h5info, &err) != GS_OK)
        return cli_fail(c->cmd, "%s: %s", path, err.msg);
    snprintf(c->h5_path, sizeof c->h5_path, "%s", path);
    if (!c->h5info.has_gaze)
        return cli_fail(c->cmd, "%s has no face_gaze: no labels to check", path);
    long n = (long)c->h5info.rows;
    if (limit > 0 && n > limit)
        n = limit;
    sample *ss = calloc((size_t)n + 1, sizeof *ss);
    size_t plane = (size_t)c->h5info.width * c->h5info.height;
    c->patch = malloc(3 * plane);
    if (!ss || !c->patch) {
        free(ss);
        return cli_fail(c->cmd, "out of memory");
    }
    const char *base = strrchr(path, '/');
    base = base ? base + 1 : path;
    int rc = CLI_OK;
    for (long r = 0; r < n && rc == CLI_OK; r++) {
        float g[2];
        sample_init(&ss[r]);
        ss[r].row = r;
        ss[r].index = r;
        snprintf(ss[r].subject, sizeof ss[r].subject, "%.*s", (int)strcspn(base, "."), base);
        if (gs_h5_read_row(c->h5, (size_t)r, c->patch, g, NULL, &err) != GS_OK) {
            rc = cli_fail(c->cmd, "%s: %s", path, err.msg);
            break;
        }
        ss[r].label_p = g[0];
        ss[r].label_y = g[1];
        if (c->h5_bgr)
            for (size_t i = 0; i < plane; i++) {
                uint8_t t = c->patch[3 * i];
                c->patch[3 * i] = c->patch[3 * i + 2];
                c->patch[3 * i + 2] = t;
            }
        rc = estimate(c, c->patch, c->h5info.width, c->h5info.height,
                      3 * (size_t)c->h5info.width, &ss[r]);
    }
    if (rc != CLI_OK) {
        free(ss);
        return rc;
    }
    *out = ss;
    *n_out = n;
    return CLI_OK;
}

/* ---- the report ---- */

static int cmp_double(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return x < y ? -1 : x > y;
}

/* Quantile q of the finite values (linear between order statistics). */
typedef struct stats {
    long n;
    double mean, median, p90, max;
} stats;

static stats stats_of(const sample *s, long n, int field, const char *subject)
{
    stats st = {0, NAN, NAN, NAN, NAN};
    double *v = malloc(((size_t)n + 1) * sizeof *v);
    if (!v)
        return st;
    double sum = 0;
    for (long i = 0; i < n; i++) {
        double x = field == 0 ? s[i].est_err : field == 1 ? s[i].read_err : s[i].score;
        if (isfinite(x) && (!subject || !strcmp(subject, s[i].subject))) {
            v[st.n++] = x;
            sum += x;
        }
    }
    if (st.n) {
        qsort(v, (size_t)st.n, sizeof *v, cmp_double);
        st.mean = sum / (double)st.n;
        double q[2] = {0.5, 0.9}, r[2];
        for (int k = 0; k < 2; k++) {
            double at = q[k] * (double)(st.n - 1);
            long lo = (long)at;
            double f = at - (double)lo;
            r[k] = lo + 1 < st.n ? v[lo] * (1 - f) + v[lo + 1] * f : v[lo];
        }
        st.median = r[0];
        st.p90 = r[1];
        st.max = v[st.n - 1];
    }
    free(v);
    return st;
}

static const sample *g_sort_base;
static int cmp_outlier(const void *a, const void *b)
{
    const sample *x = &g_sort_base[*(const long *)a], *y = &g_sort_base[*(const long *)b];
    if (x->score != y->score)
        return x->score > y->score ? -1 : 1;
    return x->index < y->index ? -1 : x->index > y->index;
}

static void json_num(FILE *f, double v)
{
    if (isfinite(v))
        fprintf(f, "%.6g", v);
    else
        fputs("null", f);
}

static void json_stats(FILE *f, const char *key, stats st)
{
    fprintf(f, "\"%s\":{\"n\":%ld,\"mean\":", key, st.n);
    json_num(f, st.mean);
    fputs(",\"median\":", f);
    json_num(f, st.median);
    fputs(",\"p90\":", f);
    json_num(f, st.p90);
    fputs(",\"max\":", f);
    json_num(f, st.max);
    fputs("}", f);
}

static void json_sample(FILE *f, const sample *s)
{
    fprintf(f, "{\"index\":%lld,\"row\":%ld,\"image\":", s->index, s->row);
    if (s->image[0])
        gs_msg_write_json_string(f, s->image);
    else
        fputs("null", f);
    fputs(",\"subject\":", f);
    gs_msg_write_json_string(f, s->subject);
    const double v[9] = {s->label_p * DEG, s->label_y * DEG, s->est_p * DEG, s->est_y * DEG,
                         s->est_err,       s->read_p * DEG,  s->read_y * DEG, s->read_err,
                         s->score};
    static const char *const k[9] = {"label_pitch_deg",  "label_yaw_deg",   "estimator_pitch_deg",
                                     "estimator_yaw_deg", "estimator_error_deg",
                                     "readout_pitch_deg", "readout_yaw_deg", "readout_error_deg",
                                     "error_deg"};
    for (int i = 0; i < 9; i++) {
        fprintf(f, ",\"%s\":", k[i]);
        json_num(f, v[i]);
    }
    fprintf(f, ",\"outlier\":%s,\"note\":", s->outlier ? "true" : "false");
    if (s->note)
        gs_msg_write_json_string(f, s->note);
    else
        fputs("null", f);
    fputs("}", f);
}

/* Distinct subjects in first-seen order (indices of their first sample). */
static long subjects_of(const sample *s, long n, long *first)
{
    long m = 0;
    for (long i = 0; i < n; i++) {
        long j = 0;
        while (j < m && strcmp(s[first[j]].subject, s[i].subject))
            j++;
        if (j == m)
            first[m++] = i;
    }
    return m;
}

typedef struct report {
    const char *dataset, *estimator;
    int readout;
    double threshold;
    long n, scored, outliers;
    const long *order;  /* outliers, worst first */
} report;

static int write_json(const char *path, const report *r, const sample *s, const long *subj,
                      long nsubj)
{
    FILE *f = fopen(path, "w");
    if (!f)
        return -1;
    fputs("{\"dataset\":", f);
    gs_msg_write_json_string(f, r->dataset);
    fputs(",\"estimator\":", f);
    if (r->estimator)
        gs_msg_write_json_string(f, r->estimator);
    else
        fputs("null", f);
    static const char *const modes[3] = {"null", "\"exact\"", "\"synthesis\""};
    fprintf(f, ",\"readout\":%s,\"threshold_deg\":%.6g,\"samples\":%ld,\"scored\":%ld,"
               "\"outliers\":%ld,\"outlier_fraction\":",
            modes[r->readout], r->threshold, r->n, r->scored, r->outliers);
    json_num(f, r->scored ? (double)r->outliers / (double)r->scored : NAN);
    fputc(',', f);
    json_stats(f, "estimator_error_deg", stats_of(s, r->n, 0, NULL));
    fputc(',', f);
    json_stats(f, "readout_error_deg", stats_of(s, r->n, 1, NULL));
    fputs(",\"subjects\":[", f);
    for (long j = 0; j < nsubj; j++) {
        const char *name = s[subj[j]].subject;
        long out = 0, cnt = 0;
        for (long i = 0; i < r->n; i++)
            if (!strcmp(s[i].subject, name)) {
                cnt++;
                out += s[i].outlier;
            }
        fputs(j ? ",{\"subject\":" : "{\"subject\":", f);
        gs_msg_write_json_string(f, name);
        fprintf(f, ",\"samples\":%ld,\"outliers\":%ld,", cnt, out);
        json_stats(f, "error_deg", stats_of(s, r->n, 2, name));
        fputs("}", f);
    }
    fputs("],\"outlier_list\":[", f);
    for (long i = 0; i < r->outliers; i++) {
        if (i)
            fputc(',', f);
        json_sample(f, &s[r->order[i]]);
    }
    fputs("],\"per_sample\":[", f);
    for (long i = 0; i < r->n; i++) {
        if (i)
            fputc(',', f);
        json_sample(f, &s[i]);
    }
    fputs("]}\n", f);
    int bad = ferror(f);
    bad |= fclose(f) != 0;
    return bad ? -1 : 0;
}

static void print_stats(const char *what, stats st)
{
    if (st.n)
        printf("  %-22s %6ld  %7.2f  %7.2f  %7.2f  %7.2f\n", what, st.n, st.mean, st.median,
               st.p90, st.max);
    else
        printf("  %-22s %6s\n", what, "-");
}

/* "pitch,yaw" in degrees, or "-" when there is no reading. */
static void pair(char buf[32], double p, double y)
{
    if (isfinite(p) && isfinite(y))
        snprintf(buf, 32, "%.1f,%.1f", p * DEG, y * DEG);
    else
        snprintf(buf, 32, "-");
}

static void print_table(const report *r, const sample *s, const long *subj, long nsubj,
                        long list)
{
    printf("gazesplat check-labels: %s: %ld samples, %ld scored (%s), threshold %.3g deg\n",
           r->dataset, r->n, r->scored,
           r->readout == READ_EXACT       ? "exact readout, estimator alongside"
           : r->readout == READ_SYNTHESIS ? "readout by synthesis, estimator alongside"
                                          : "estimator",
           r->threshold);
    printf("  %-22s %6s  %7s  %7s  %7s  %7s\n", "error vs label (deg)", "n", "mean", "median",
           "p90", "max");
    print_stats("estimator", stats_of(s, r->n, 0, NULL));
    print_stats("readout", stats_of(s, r->n, 1, NULL));
    printf("  outliers: %ld of %ld scored (%.1f %%)\n", r->outliers, r->scored,
           r->scored ? 100.0 * (double)r->outliers / (double)r->scored : 0.0);
    if (nsubj > 1) {
        printf("  %-22s %6s  %7s  %7s  %8s\n", "subject", "n", "median", "p90", "outliers");
        for (long j = 0; j < nsubj; j++) {
            const char *name = s[subj[j]].subject;
            stats st = stats_of(s, r->n, 2, name);
            long out = 0, cnt = 0;
            for (long i = 0; i < r->n; i++)
                if (!strcmp(s[i].subject, name)) {
                    cnt++;
                    out += s[i].outlier;
                }
            printf("  %-22.22s %6ld  %7.2f  %7.2f  %8ld\n", name, cnt, st.median, st.p90, out);
        }
    }
    if (r->outliers) {
        printf("  %-10s %-22s %-12s %15s %15s %15s %7s\n", "index", "image", "subject",
               "label p,y", "estimator p,y", "readout p,y", "error");
        for (long i = 0; i < r->outliers && i < list; i++) {
            const sample *x = &s[r->order[i]];
            char lab[32], est[32], rd[32];
            pair(lab, x->label_p, x->label_y);
            pair(est, x->est_p, x->est_y);
            pair(rd, x->read_p, x->read_y);
            printf("  %-10lld %-22.22s %-12.12s %15s %15s %15s %7.2f\n", x->index,
                   x->image[0] ? x->image : "-", x->subject, lab, est, rd, x->score);
        }
        if (r->outliers > list)
            printf("  ... %ld more (--list, --json)\n", r->outliers - list);
    }
}

/* ---- the command ---- */

static int setup(checker *c, const cli_opt *o, double *thresh, double *maxout, long *list,
                 long *limit, const char **est_path)
{
    const cli_command *cmd = c->cmd;
    long threads = 2;
    if (!o[O_DIR].value == !o[O_H5].value)
        return cli_usage_error(cmd, "give one of --dir and --h5");
    if (o[O_H5].value && (o[O_LABELS].value || o[O_READOUT].value))
        return cli_usage_error(cmd, "--labels and --readout go with --dir");
    if (o[O_H5RGB].value && !o[O_H5].value)
        return cli_usage_error(cmd, "--h5-rgb goes with --h5");
    if (cli_parse_range(cmd, "--threshold", o[O_THRESH].value, 0.01, 180.0,
                        "degrees in [0.01, 180]", thresh) ||
        cli_parse_range(cmd, "--max-outliers", o[O_MAXOUT].value, 0.0, 1.0, "a fraction in [0, 1]",
                        maxout))
        return CLI_USAGE;
    if (o[O_LIST].value && cli_parse_long(o[O_LIST].value, 0, 1000000000L, list))
        return cli_usage_error(cmd, "--list: want 0..1000000000; got '%s'", o[O_LIST].value);
    if (o[O_LIMIT].value && cli_parse_long(o[O_LIMIT].value, 1, 1000000000L, limit))
        return cli_usage_error(cmd, "--limit: want 1..1000000000; got '%s'", o[O_LIMIT].value);
    if (o[O_THREADS].value && cli_parse_long(o[O_THREADS].value, 1, 256, &threads))
        return cli_usage_error(cmd, "--threads: want 1..256; got '%s'", o[O_THREADS].value);
    const char *ro = o[O_READOUT].value ? o[O_READOUT].value : "auto";
    int mode = !strcmp(ro, "auto") || !strcmp(ro, "exact") ? READ_EXACT
               : !strcmp(ro, "synthesis")                  ? READ_SYNTHESIS
                                                           : READ_NONE;
    if (mode == READ_NONE && strcmp(ro, "off"))
        return cli_usage_error(cmd, "--readout: want auto, exact, synthesis or off; got '%s'",
                               ro);
    *est_path = o[O_EST].value ? o[O_EST].value : cli_shipped_model("gaze-resnet.safetensors");
    if (!strcmp(*est_path, "none"))
        *est_path = NULL;
    if (!*est_path && (o[O_H5].value || mode == READ_NONE))
        return cli_usage_error(cmd, "nothing reads the images: --estimator none needs the "
                               "readout of a synth dataset");
    c->h5_bgr = !o[O_H5RGB].value;
    gs_error err = {0, ""};
    if (o[O_DIR].value && mode != READ_NONE) {
        int synth = gs_synth_dataset_config_read(o[O_DIR].value, &c->synth, NULL, NULL,
                                                 &err) == GS_OK;
        if (!synth && strcmp(ro, "auto"))
            return cli_fail(cmd, "--readout %s needs a gazesplat synth dataset: %s", ro,
                            err.msg);
        if (synth && c->synth.rig != GS_SYNTH_RIG_NORMALIZED)
            return cli_fail(cmd, "%s: a synth dataset of rig %s; check-labels reads "
                            "normalized face images (rig normalized)", o[O_DIR].value,
                            c->synth.rig == GS_SYNTH_RIG_ETHX ? "ethx" : "single");
        if (synth && gs_synth_sample_alloc(&c->render, c->synth.size, c->synth.size, &err))
            return cli_fail(cmd, "%s", err.msg);
        c->readout = synth ? mode : READ_NONE;
    }
    if (!c->readout && !*est_path)
        return cli_fail(cmd, "%s is not a gazesplat synth dataset (no README.md naming the "
                        "generator): --estimator none leaves nothing to read the images",
                        o[O_DIR].value);
    c->pool = gs_pool_create((int)threads);
    if (!c->pool)
        return cli_fail(cmd, "cannot start threads");
    if (*est_path && eval_estimator_load(*est_path, &c->est, &err) != GS_OK)
        return cli_fail(cmd, "estimator %s: %s", *est_path, err.msg);
    return CLI_PARSED;
}

_Static_assert(CLI_NOPTS(check_opts) == O_N, "check_opts: one entry per option index");

static int run_check(const cli_command *cmd, cli_opt *o)
{
    checker c;
    memset(&c, 0, sizeof c);
    c.cmd = cmd;
    int rc = CLI_OK;
    double thresh = 20.0, maxout = 1.0;
    long list = 20, limit = 0;
    const char *est_path = NULL;
    rc = setup(&c, o, &thresh, &maxout, &list, &limit, &est_path);
    sample *s = NULL;
    long n = 0;
    char lpath[4200];
    if (rc == CLI_PARSED && o[O_DIR].value) {
        if (o[O_LABELS].value)
            snprintf(lpath, sizeof lpath, "%s", o[O_LABELS].value);
        else
            snprintf(lpath, sizeof lpath, "%s/labels.jsonl", o[O_DIR].value);
        rc = check_dir(&c, o[O_DIR].value, lpath, limit, &s, &n);
    } else if (rc == CLI_PARSED) {
        rc = check_h5(&c, o[O_H5].value, limit, &s, &n);
    }
    if (rc == CLI_PARSED)
        rc = CLI_OK;
    long *order = NULL, *subj = NULL;
    if (rc == CLI_OK) {
        order = malloc(((size_t)n + 1) * sizeof *order);
        subj = malloc(((size_t)n + 1) * sizeof *subj);
        if (!order || !subj)
            rc = cli_fail(c.cmd, "out of memory");
    }
    if (rc == CLI_OK) {
        report r = {o[O_DIR].value ? o[O_DIR].value : o[O_H5].value, est_path, c.readout,
                    thresh, n, 0, 0, order};
        for (long i = 0; i < n; i++) {
            s[i].score = isfinite(s[i].read_err) ? s[i].read_err : s[i].est_err;
            if (!isfinite(s[i].score))
                continue;
            r.scored++;
            s[i].outlier = s[i].score > thresh;
            if (s[i].outlier)
                order[r.outliers++] = i;
        }
        g_sort_base = s;
        qsort(order, (size_t)r.outliers, sizeof *order, cmp_outlier);
        long nsubj = subjects_of(s, n, subj);
        print_table(&r, s, subj, nsubj, list);
        if (o[O_JSON].value && write_json(o[O_JSON].value, &r, s, subj, nsubj))
            rc = cli_fail(c.cmd, "cannot write %s", o[O_JSON].value);
        double frac = r.scored ? (double)r.outliers / (double)r.scored : 0.0;
        if (rc == CLI_OK && frac > maxout) {
            fprintf(stderr, "gazesplat check-labels: %.1f %% outliers, more than "
                            "--max-outliers %.3g\n", 100.0 * frac, maxout);
            rc = CLI_OUTLIERS;
        }
    }
    free(order);
    free(subj);
    free(s);
    free(c.patch);
    if (c.h5)
        gs_h5_close(c.h5);
    gs_synth_sample_free(&c.render);
    eval_estimator_free(c.est);
    if (c.pool)
        gs_pool_destroy(c.pool);
    return rc;
}
