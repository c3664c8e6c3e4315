/* gazesplat client: talk to a running gazesplatd (proto/PROTOCOL.md). */
#define _POSIX_C_SOURCE 200809L
#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

#include "cli.h"
#include "gazesplat/image_io.h"
#include "gs_client.h"

static int run_client(int argc, char **argv);

const cli_command cli_client_command = {
    "client",
    "talk to a running gazesplatd: hello, health, stats, fit, redirect, live-policy, live-status",
    "usage: gazesplat client ACTION [options]\n"
    "\n"
    "Actions:\n"
    "  hello      negotiate the protocol version, print the server's limits\n"
    "  health     print the server state (LOADING, READY, FAILED, DRAINING)\n"
    "  stats      print every STATS counter\n"
    "  fit        fit a subject to --image; prints its key and estimated labels\n"
    "             (--image A,B,...: up to 16 images of one person, one subject\n"
    "             rendering from the first; --gaze/--head then take one P,Y per\n"
    "             image separated by ';', '-' where unknown; docs/subjects.md)\n"
    "  redirect   render --subject KEY (or --image) at each --gaze-deg target\n"
    "  live-policy  print the live eye-contact policy; --set k=v (repeatable, or\n"
    "             k=v,k=v) changes it at once, all settings or none; --refit\n"
    "             drops the fitted subject\n"
    "  live-status  print the live pipeline's state (camera, face, subject, weight)\n"
    "\n"
    "Options:\n"
    "  --addr ADDR          unix:PATH, tcp:HOST:PORT or PATH (default\n"
    "                       $GAZESPLAT_ADDR, else /run/gazesplat/gazesplatd.sock, the\n"
    "                       socket of the shipped units)\n"
    "  --token TOKEN        shared secret for TCP (default $GAZESPLAT_TOKEN)\n"
    "  --timeout-ms N       wait this long for each reply (default 120000)\n"
    "  --image FILE         a normalized face image (PNG or JPEG)\n"
    "  --photo              the image is a photo: the server finds and normalizes\n"
    "                       the face\n"
    "  --gaze P,Y           fit: known gaze of the image, degrees (pitch in [-50, 50],\n"
    "                       yaw in [-60, 60], inclusive)\n"
    "  --head P,Y           fit: known head pose, degrees (each in [-70, 70])\n"
    "  --key HEX            fit: the subject key to use (32 hex digits)\n"
    "  --max-iters N        fit (and redirect of an --image): iteration limit\n"
    "  --finetune N         fit (and redirect of an --image): then fine-tune a copy\n"
    "                       of the model on the image for N steps; the subject\n"
    "                       renders with it (the server's max_finetune_steps)\n"
    "  --finetune-parts L   with --finetune: face, eye, renderer, mlp, geometry,\n"
    "                       face-geometry, comma-separated (default face,geometry)\n"
    "  --finetune-outline PX  with --finetune, 0..8: the colours learn nothing within\n"
    "                       PX feature pixels of the model's outline (2 with\n"
    "                       --finetune-mirror 0: fewer background-coloured patches)\n"
    "  --finetune-mirror B  with --finetune: 1 (default) also fits the image mirrored\n"
    "                       left to right from the mirrored pose; 0: the image alone\n"
    "  --finetune-lr X      with --finetune, (0, 1]: Adam's base rate (default: the\n"
    "                       server's finetune_lr, 0.004 unless configured)\n"
    "  --keep-image         fit: the server keeps the input with the subject, for\n"
    "                       redirect --transfer by key\n"
    "  --json               print each reply as one JSON object per line (the\n"
    "                       protocol's field names; keys as hex); redirect prints\n"
    "                       one line per image ({\"index\", \"path\", \"target\"}) and a\n"
    "                       last {\"done\": {...}}; errors stay text on stderr\n"
    "  --transfer           redirect: detail transfer (keep the input's own detail;\n"
    "                       by --subject it needs a fit with --keep-image)\n"
    "  --subject HEX        redirect: a fitted subject key\n"
    "  --gaze-deg LIST      redirect: targets 'P,Y;P,Y;...', degrees (ranges as --gaze)\n"
    "  --head-deg LIST      redirect: head poses, one per target (as --head)\n"
    "  --format F           redirect: png (default), jpeg or raw\n"
    "  --paste-back         redirect: paste the result back into the --photo\n"
    "  --out DIR            redirect: writes DIR/target_NNN.png (or .jpg, .rgb)\n"
    "  --deadline-ms N      per-request deadline\n"
    "\n"
    "Exit status: 0 success, 1 failure (a server ERROR included), 2 bad usage.\n",
    .run = run_client, /* a verb comes first: it reads its own argv */
};

enum {
    O_ADDR, O_TOKEN, O_TIMEOUT, O_IMAGE, O_PHOTO, O_GAZE, O_HEAD, O_KEY, O_ITERS, O_SUBJECT,
    O_GAZES, O_HEADS, O_FORMAT, O_OUT, O_DEADLINE, O_PASTE, O_REFIT, O_FT, O_FT_PARTS, O_KEEP,
    O_TRANSFER, O_FT_OUTLINE, O_FT_MIRROR, O_FT_LR, O_JSON, O_N
};

/* --json: each reply printed as one JSON object (gs_msg_write_json);
 * program state, set once by run_client. */
static int json_out;

static void print_json(const ProtobufCMessage *m)
{
    gs_msg_write_json(stdout, m);
    putchar('\n');
}

/* --finetune N [--finetune-parts L] [--finetune-outline PX]
 * [--finetune-mirror B] [--finetune-lr X]: 0 or CLI_USAGE (reported). */
static int finetune_opts(const cli_command *cmd, const cli_opt *o, uint32_t *steps, char **parts,
                         uint32_t *outline, protobuf_c_boolean *no_mirror, double *lr)
{
    long n = 0, px = 0, mir = 1;
    if (o[O_FT].value && cli_parse_long(o[O_FT].value, 1, 100000, &n) != 0)
        return cli_usage_error(cmd, "--finetune wants 1..100000 steps");
    if ((o[O_FT_PARTS].value || o[O_FT_OUTLINE].value || o[O_FT_MIRROR].value || o[O_FT_LR].value) &&
        !o[O_FT].value)
        return cli_usage_error(cmd, "--finetune-parts, --finetune-outline, --finetune-mirror and "
                                    "--finetune-lr go with --finetune N");
    *lr = 0; /* the server's */
    if (o[O_FT_LR].value && cli_parse_rate(o[O_FT_LR].value, 1.0, lr) != 0)
        return cli_usage_error(cmd, "--finetune-lr wants a rate in (0, 1]");
    if (o[O_FT_MIRROR].value && cli_parse_long(o[O_FT_MIRROR].value, 0, 1, &mir) != 0)
        return cli_usage_error(cmd, "--finetune-mirror wants 0 or 1");
    *no_mirror = !mir;
    if (o[O_FT_OUTLINE].value && cli_parse_long(o[O_FT_OUTLINE].value, 0, 8, &px) != 0)
        return cli_usage_error(cmd, "--finetune-outline wants 0..8 feature pixels");
    *outline = (uint32_t)px;
    *steps = (uint32_t)n;
    *parts = o[O_FT_PARTS].value ? (char *)o[O_FT_PARTS].value : (char *)"";
    return CLI_OK;
}

#define MAX_SETS 32

#define T(x) GAZESPLAT__FRAME_TYPE__FRAME_##x

static int print_error(const gs_client_frame *f)
{
    const Gazesplat__Error *e = (const Gazesplat__Error *)f->msg;
    fprintf(stderr, "gazesplat client: server: %s: %s\n", gs_msg_error_name(e->code), e->message);
    return CLI_FAIL;
}

static int print_busy(const gs_client_frame *f)
{
    const Gazesplat__Busy *b = (const Gazesplat__Busy *)f->msg;
    fprintf(stderr, "gazesplat client: server busy (queue %u), retry after %u ms\n", b->queue_length,
            b->retry_after_ms);
    return CLI_FAIL;
}

/* --gaze, --head (one pair) or --gaze-deg, --head-deg (lists) into a
 * malloc'd array of *n angles, each checked against the target table
 * (cli_parse_angles). Returns CLI_OK, CLI_USAGE (reported) or CLI_FAIL. */
static int parse_angles(const char *flag, const char *s, int list, int head, Gazesplat__Angles **out,
                        int *n)
{
    const cli_command *cmd = &cli_client_command;
    enum { MAXT = 4096 }; /* the server refuses more than its max_targets */
    double(*v)[2] = malloc(MAXT * sizeof *v);
    *out = NULL;
    if (!v)
        return cli_fail(cmd, "out of memory");
    int rc = cli_parse_angles(cmd, flag, s, list, head, v, list ? MAXT : 1, n);
    Gazesplat__Angles *a = rc == CLI_OK ? calloc((size_t)*n, sizeof *a) : NULL;
    if (rc == CLI_OK && !a)
        rc = cli_fail(cmd, "out of memory");
    for (int k = 0; rc == CLI_OK && k < *n; k++) {
        gazesplat__angles__init(&a[k]);
        a[k].pitch_deg = v[k][0];
        a[k].yaw_deg = v[k][1];
    }
    free(v);
    *out = a;
    return rc;
}

#define FIT_IMAGES_MAX 16 /* the protocol's limit on the images of one FIT */

/* Every angle option given, checked before connecting: a bad target is a
 * usage error whether or not a server is there. */
static int check_angle_opts(const cli_opt *o)
{
    static const struct {
        int opt, list, head;
        const char *flag;
    } k[] = {{O_GAZE, 0, 0, "--gaze"},
             {O_HEAD, 0, 1, "--head"},
             {O_GAZES, 1, 0, "--gaze-deg"},
             {O_HEADS, 1, 1, "--head-deg"}};
    /* fit --image A,B,...: --gaze and --head hold one item per image */
    int images = 1;
    for (const char *p = o[O_IMAGE].value; p && *p; p++)
        images += *p == ',';
    for (size_t i = 0; i < sizeof k / sizeof k[0]; i++) {
        if (images > 1 && !k[i].list) {
            double v[FIT_IMAGES_MAX][2];
            int known[FIT_IMAGES_MAX];
            int rc = o[k[i].opt].value && images <= FIT_IMAGES_MAX
                         ? cli_parse_image_labels(&cli_client_command, k[i].flag, o[k[i].opt].value,
                                                  k[i].head, images, v, known)
                         : CLI_OK;
            if (rc != CLI_OK)
                return rc;
            continue;
        }
        Gazesplat__Angles *a = NULL;
        int n, rc = o[k[i].opt].value
                        ? parse_angles(k[i].flag, o[k[i].opt].value, k[i].list, k[i].head, &a, &n)
                        : CLI_OK;
        free(a);
        if (rc != CLI_OK)
            return rc;
    }
    return CLI_OK;
}

static int do_health(gs_client *c, int timeout)
{
    static const char *const states[] = {"LOADING", "READY", "FAILED", "DRAINING"};
    gs_client_frame f;
    gs_error err;
    Gazesplat__HealthRequest req = GAZESPLAT__HEALTH_REQUEST__INIT;
    if (gs_client_call(c, T(HEALTH), NULL, 1, &req.base, timeout, &f, &err) != GS_OK) {
        fprintf(stderr, "gazesplat client: %s\n", err.msg);
        return CLI_FAIL;
    }
    int rc = CLI_OK;
    if (f.header.type == T(HEALTH_OK)) {
        const Gazesplat__Health *h = (const Gazesplat__Health *)f.msg;
        if (json_out)
            print_json(f.msg);
        else
            printf("state %s\ndetail %s\nqueue %u/%u\nworkers %u\nimage_size %u\nmodel_id %s\n",
               h->state < 4 ? states[h->state] : "?", h->detail, h->queue_length, h->queue_depth,
               h->workers, h->image_size, h->model_id);
        rc = h->state == GAZESPLAT__HEALTH__STATE__READY ? CLI_OK : CLI_FAIL;
    } else {
        rc = f.header.type == T(ERROR) ? print_error(&f) : CLI_FAIL;
    }
    gs_client_frame_free(&f);
    return rc;
}

static int do_stats(gs_client *c, int timeout)
{
    gs_client_frame f;
    gs_error err;
    Gazesplat__StatsRequest req = GAZESPLAT__STATS_REQUEST__INIT;
    if (gs_client_call(c, T(STATS), NULL, 1, &req.base, timeout, &f, &err) != GS_OK) {
        fprintf(stderr, "gazesplat client: %s\n", err.msg);
        return CLI_FAIL;
    }
    int rc = CLI_OK;
    if (f.header.type == T(STATS_OK)) {
        const Gazesplat__Stats *s = (const Gazesplat__Stats *)f.msg;
        if (json_out) /* one flat object: {"fits": 3, ...} */
            putchar('{');
        for (size_t i = 0; i < s->n_counters; i++) {
            unsigned long long v = s->counters[i]->value;
            if (!json_out) {
                printf("%s %llu\n", s->counters[i]->name, v);
                continue;
            }
            if (i)
                putchar(',');
            gs_msg_write_json_string(stdout, s->counters[i]->name);
            printf(":%llu", v);
        }
        if (json_out)
            puts("}");
    } else {
        rc = f.header.type == T(ERROR) ? print_error(&f) : CLI_FAIL;
    }
    gs_client_frame_free(&f);
    return rc;
}

static void print_policy(const Gazesplat__LivePolicy *p, const char *prefix)
{
    if (!p)
        return;
    printf("%senabled %s\n%sstrength %g\n%sgaze_low_deg %g\n%sgaze_high_deg %g\n"
           "%shead_pitch_low_deg %g\n%shead_pitch_high_deg %g\n%shead_yaw_low_deg %g\n"
           "%shead_yaw_high_deg %g\n%ssmooth_s %g\n%sblink_openness %g\n%sblink_hold_max_s %g\n",
           prefix, p->enabled ? "yes" : "no", prefix, p->strength, prefix, p->gaze_low_deg, prefix,
           p->gaze_high_deg, prefix, p->head_pitch_low_deg, prefix, p->head_pitch_high_deg, prefix,
           p->head_yaw_low_deg, prefix, p->head_yaw_high_deg, prefix, p->smooth_s, prefix,
           p->blink_openness, prefix, p->blink_hold_max_s);
}

/* Splits each "k=v[,k=v...]" into LiveSetting messages (in buf). */
static int parse_sets(const char **sets, int nsets, char *buf, size_t cap,
                      Gazesplat__LiveSetting *items, Gazesplat__LiveSetting **ptrs, size_t *n)
{
    size_t used = 0;
    *n = 0;
    for (int i = 0; i < nsets; i++) {
        size_t len = strlen(sets[i]);
        if (used + len + 1 > cap)
            return -1;
        char *s = memcpy(buf + used, sets[i], len + 1), *save = NULL;
        used += len + 1;
        for (char *kv = strtok_r(s, ",", &save); kv; kv = strtok_r(NULL, ",", &save)) {
            char *eq = strchr(kv, '=');
            if (!eq || eq == kv || *n >= MAX_SETS)
                return -1;
            *eq = '\0';
            gazesplat__live_setting__init(&items[*n]);
            items[*n].key = kv;
            items[*n].value = eq + 1;
            ptrs[*n] = &items[*n];
            (*n)++;
        }
    }
    return 0;
}

static int do_live_policy(gs_client *c, const char **sets, int nsets, int refit, int timeout)
{
    const cli_command *cmd = &cli_client_command;
    char buf[4096];
    Gazesplat__LiveSetting items[MAX_SETS], *ptrs[MAX_SETS];
    Gazesplat__LivePolicyRequest req = GAZESPLAT__LIVE_POLICY_REQUEST__INIT;
    if (parse_sets(sets, nsets, buf, sizeof buf, items, ptrs, &req.n_set) != 0)
        return cli_usage_error(cmd, "--set wants key=value[,key=value...] (at most %d)", MAX_SETS);
    req.set = ptrs;
    req.refit = refit;
    gs_client_frame f;
    gs_error err;
    if (gs_client_call(c, T(LIVE_POLICY), NULL, 1, &req.base, timeout, &f, &err) != GS_OK)
        return cli_fail(cmd, "%s", err.msg);
    int rc = CLI_OK;
    if (f.header.type == T(LIVE_POLICY_OK) && json_out)
        print_json(f.msg);
    else if (f.header.type == T(LIVE_POLICY_OK))
        print_policy((const Gazesplat__LivePolicy *)f.msg, "");
    else
        rc = f.header.type == T(ERROR) ? print_error(&f) : CLI_FAIL;
    gs_client_frame_free(&f);
    return rc;
}

static int do_live_status(gs_client *c, int timeout)
{
    const cli_command *cmd = &cli_client_command;
    Gazesplat__LiveStatusRequest req = GAZESPLAT__LIVE_STATUS_REQUEST__INIT;
    gs_client_frame f;
    gs_error err;
    if (gs_client_call(c, T(LIVE_STATUS), NULL, 1, &req.base, timeout, &f, &err) != GS_OK)
        return cli_fail(cmd, "%s", err.msg);
    if (f.header.type != T(LIVE_STATUS_OK)) {
        int rc = f.header.type == T(ERROR) ? print_error(&f) : CLI_FAIL;
        gs_client_frame_free(&f);
        return rc;
    }
    const Gazesplat__LiveStatus *m = (const Gazesplat__LiveStatus *)f.msg;
    if (json_out) {
        print_json(f.msg);
        gs_client_frame_free(&f);
        return CLI_OK;
    }
    printf("running %s\ndevice %s\noutput %s\nstreaming %s\nframes_in %llu\nframes_out %llu\n"
           "placeholders %llu\nreopens %llu\nlatency_ms %.1f/%.1f\nface %s\nsubject_ready %s\n"
           "fitting %s\nfits %llu\nrefits %llu\nrenders %llu\nweight %.3f\n",
           m->running ? "yes" : "no", m->device, m->output, m->streaming ? "yes" : "no",
           (unsigned long long)m->frames_in, (unsigned long long)m->frames_out,
           (unsigned long long)m->placeholders, (unsigned long long)m->reopens,
           m->latency_p50_ms, m->latency_p99_ms, m->face ? "yes" : "no",
           m->subject_ready ? "yes" : "no", m->fitting ? "yes" : "no",
           (unsigned long long)m->fits, (unsigned long long)m->refits,
           (unsigned long long)m->renders, m->weight);
    if (m->head)
        printf("head_deg %.1f,%.1f\n", m->head->pitch_deg, m->head->yaw_deg);
    if (m->correction)
        printf("correction_deg %.1f,%.1f\n", m->correction->pitch_deg, m->correction->yaw_deg);
    print_policy(m->policy, "policy.");
    printf("detail %s\n", m->detail);
    gs_client_frame_free(&f);
    return CLI_OK;
}

static int load_image_path(const cli_command *cmd, const cli_opt *o, const char *path,
                           Gazesplat__Image *img, uint8_t **data)
{
    size_t len;
    if (cli_read_file(path, (size_t)256 << 20, data, &len) != 0)
        return cli_fail(cmd, "cannot read %s", path);
    int fmt = gs_io_format_sniff(*data, len);
    if (!fmt) {
        free(*data);
        *data = NULL;
        return cli_fail(cmd, "%s is neither PNG nor JPEG", path);
    }
    img->format = fmt == GS_IO_PNG ? GAZESPLAT__IMAGE_FORMAT__FORMAT_PNG : GAZESPLAT__IMAGE_FORMAT__FORMAT_JPEG;
    img->data.data = *data;
    img->data.len = len;
    img->kind = o[O_PHOTO].value ? GAZESPLAT__IMAGE_KIND__KIND_PHOTO : GAZESPLAT__IMAGE_KIND__KIND_NORMALIZED_FACE;
    return CLI_OK;
}

static int load_image(const cli_command *cmd, const cli_opt *o, Gazesplat__Image *img, uint8_t **data)
{
    return load_image_path(cmd, o, o[O_IMAGE].value, img, data);
}

/* fit --image A,B,...: images 1..n-1 as FitRequest.more_images, with
 * their --gaze / --head items (';'-separated, '-' unknown); image 0's
 * labels go to *gaze and *head (their presence to *has). */
typedef struct more_images {
    int n;
    char *buf;
    const char *path[FIT_IMAGES_MAX];
    uint8_t *data[FIT_IMAGES_MAX];
    Gazesplat__FitImage fi[FIT_IMAGES_MAX], *fip[FIT_IMAGES_MAX];
    Gazesplat__Image img[FIT_IMAGES_MAX];
    Gazesplat__Angles gaze[FIT_IMAGES_MAX], head[FIT_IMAGES_MAX];
} more_images;

static void more_images_free(more_images *mi)
{
    for (int i = 0; i < mi->n; i++)
        free(mi->data[i]);
    free(mi->buf);
}

static int more_images_load(const cli_command *cmd, const cli_opt *o, more_images *mi,
                            Gazesplat__FitRequest *req)
{
    double g[FIT_IMAGES_MAX][2] = {{0}}, h[FIT_IMAGES_MAX][2] = {{0}};
    int kg[FIT_IMAGES_MAX] = {0}, kh[FIT_IMAGES_MAX] = {0};
    int rc = cli_split_paths(cmd, "--image", o[O_IMAGE].value, FIT_IMAGES_MAX, &mi->buf, mi->path,
                             &mi->n);
    int n = mi->n;
    mi->n = 0; /* images loaded */
    if (!rc && o[O_GAZE].value)
        rc = cli_parse_image_labels(cmd, "--gaze", o[O_GAZE].value, 0, n, g, kg);
    if (!rc && o[O_HEAD].value)
        rc = cli_parse_image_labels(cmd, "--head", o[O_HEAD].value, 1, n, h, kh);
    for (int i = 0; !rc && i < n; i++) {
        gazesplat__image__init(&mi->img[i]);
        rc = load_image_path(cmd, o, mi->path[i], &mi->img[i], &mi->data[i]);
        if (rc)
            break;
        mi->n = i + 1;
        gazesplat__angles__init(&mi->gaze[i]);
        gazesplat__angles__init(&mi->head[i]);
        mi->gaze[i].pitch_deg = g[i][0];
        mi->gaze[i].yaw_deg = g[i][1];
        mi->head[i].pitch_deg = h[i][0];
        mi->head[i].yaw_deg = h[i][1];
        gazesplat__fit_image__init(&mi->fi[i]);
        mi->fi[i].image = &mi->img[i];
        mi->fi[i].gaze = kg[i] ? &mi->gaze[i] : NULL;
        mi->fi[i].head = kh[i] ? &mi->head[i] : NULL;
        mi->fip[i] = &mi->fi[i];
    }
    if (rc)
        return rc;
    req->image = &mi->img[0];
    req->gaze = mi->fi[0].gaze;
    req->head = mi->fi[0].head;
    req->n_more_images = (size_t)(n - 1);
    req->more_images = mi->fip + 1;
    return CLI_OK;
}

static int do_fit(gs_client *c, const cli_opt *o, int timeout)
{
    const cli_command *cmd = &cli_client_command;
    if (!o[O_IMAGE].value)
        return cli_usage_error(cmd, "fit needs --image");
    Gazesplat__FitRequest req = GAZESPLAT__FIT_REQUEST__INIT;
    Gazesplat__Image img = GAZESPLAT__IMAGE__INIT;
    Gazesplat__Angles gaze = GAZESPLAT__ANGLES__INIT, head = GAZESPLAT__ANGLES__INIT, *a = NULL;
    uint8_t key[GS_FRAME_KEY_SIZE] = {0}, *data = NULL;
    int n, rc;
    more_images mi;
    memset(&mi, 0, sizeof mi);
    const int several = strchr(o[O_IMAGE].value, ',') != NULL;
    for (int k = 0; !several && k < 2; k++) { /* the labels, checked before anything is sent */
        const char *v = o[k ? O_HEAD : O_GAZE].value;
        if (v && (rc = parse_angles(k ? "--head" : "--gaze", v, 0, k, &a, &n)) != CLI_OK)
            return rc;
        if (v)
            *(k ? &head : &gaze) = a[0];
        free(a);
        a = NULL;
    }
    if (o[O_KEY].value && gs_frame_key_parse(o[O_KEY].value, key) != 0)
        return cli_usage_error(cmd, "--key wants 32 hex digits");
    long iters = 0, deadline = 0;
    if (o[O_ITERS].value && cli_parse_long(o[O_ITERS].value, 1, 100000, &iters) != 0)
        return cli_usage_error(cmd, "--max-iters wants 1..100000");
    if (o[O_DEADLINE].value && cli_parse_long(o[O_DEADLINE].value, 1, 3600000, &deadline) != 0)
        return cli_usage_error(cmd, "--deadline-ms wants 1..3600000");
    rc = finetune_opts(cmd, o, &req.finetune_steps, &req.finetune_parts,
                       &req.finetune_outline_px, &req.finetune_no_mirror, &req.finetune_lr);
    if (rc != CLI_OK)
        return rc;
    if (several) { /* several images of one person: one subject */
        rc = more_images_load(cmd, o, &mi, &req);
        if (rc != CLI_OK) {
            more_images_free(&mi);
            return rc;
        }
    } else {
        rc = load_image(cmd, o, &img, &data);
        if (rc != CLI_OK)
            return rc;
        req.image = &img;
        req.gaze = o[O_GAZE].value ? &gaze : NULL;
        req.head = o[O_HEAD].value ? &head : NULL;
    }
    req.max_iters = (uint32_t)iters;
    req.deadline_ms = (uint32_t)deadline;
    req.keep_image = o[O_KEEP].value != NULL;
    gs_client_frame f;
    gs_error err;
    int r = gs_client_call(c, T(FIT), key, 1, &req.base, timeout, &f, &err);
    free(data);
    more_images_free(&mi);
    if (r != GS_OK)
        return cli_fail(cmd, "%s", err.msg);
    if (f.header.type == T(FIT_OK)) {
        const Gazesplat__FitResult *m = (const Gazesplat__FitResult *)f.msg;
        char hex[33];
        gs_frame_key_hex(f.header.key, hex);
        if (json_out) {
            print_json(f.msg);
            gs_client_frame_free(&f);
            return CLI_OK;
        }
        printf("subject %s\ngaze_deg %.3f,%.3f\nhead_deg %.3f,%.3f\npsnr %.2f\nssim %.4f\niters %u\n"
               "seconds %.3f\ncached %s\nfinetuned %s\nimage_kept %s\n", hex,
               m->gaze ? m->gaze->pitch_deg : 0.0, m->gaze ? m->gaze->yaw_deg : 0.0,
               m->head ? m->head->pitch_deg : 0.0, m->head ? m->head->yaw_deg : 0.0, m->psnr, m->ssim,
               m->iters, m->seconds, m->cached ? "yes" : "no", m->finetuned ? "yes" : "no",
               m->image_kept ? "yes" : "no");
        if (m->finetune_steps)
            printf("finetune_steps %u\nfinetune_psnr %.2f\nfinetune_lr %.6g\n", m->finetune_steps,
                   m->finetune_psnr, m->finetune_lr);
        for (size_t i = 0; i < m->n_image_results; i++) {
            const Gazesplat__FitImageResult *ir = m->image_results[i];
            printf("image %zu gaze_deg %.3f,%.3f head_deg %.3f,%.3f psnr %.2f ssim %.4f\n", i,
                   ir->gaze ? ir->gaze->pitch_deg : 0.0, ir->gaze ? ir->gaze->yaw_deg : 0.0,
                   ir->head ? ir->head->pitch_deg : 0.0, ir->head ? ir->head->yaw_deg : 0.0,
                   ir->psnr, ir->ssim);
        }
        rc = CLI_OK;
    } else {
        rc = f.header.type == T(BUSY) ? print_busy(&f) : f.header.type == T(ERROR) ? print_error(&f) : CLI_FAIL;
    }
    gs_client_frame_free(&f);
    return rc;
}

static int write_result(const char *dir, const Gazesplat__ImageResult *m)
{
    const Gazesplat__Image *img = m->image;
    const char *ext = img->format == GAZESPLAT__IMAGE_FORMAT__FORMAT_JPEG ? "jpg"
                      : img->format == GAZESPLAT__IMAGE_FORMAT__FORMAT_RAW_RGB8 ? "rgb" : "png";
    char path[4096];
    snprintf(path, sizeof path, "%s/target_%03u.%s", dir, m->index, ext);
    FILE *f = fopen(path, "wb");
    int ok = f && fwrite(img->data.data, 1, img->data.len, f) == img->data.len;
    if (f && fclose(f) != 0)
        ok = 0;
    if (ok && json_out) {
        printf("{\"index\":%u,\"path\":", m->index);
        gs_msg_write_json_string(stdout, path);
        fputs(",\"target\":", stdout);
        if (m->target)
            gs_msg_write_json(stdout, &m->target->base);
        else
            fputs("null", stdout);
        puts("}");
    } else if (ok) {
        printf("%s\n", path);
    }
    return ok ? 0 : -1;
}

/* Receives K IMAGE frames and DONE (or an ERROR) for request 1. */
static int receive_images(gs_client *c, const char *out, int timeout)
{
    for (;;) {
        gs_client_frame f;
        gs_error err;
        if (gs_client_recv(c, timeout, &f, &err) != GS_OK) {
            fprintf(stderr, "gazesplat client: %s\n", err.msg);
            return CLI_FAIL;
        }
        uint16_t type = f.header.type;
        int rc = -1;
        if (type == T(IMAGE))
            rc = write_result(out, (const Gazesplat__ImageResult *)f.msg) == 0 ? -1 : CLI_FAIL;
        else if (type == T(DONE)) {
            rc = CLI_OK;
            if (json_out) {
                fputs("{\"done\":", stdout);
                gs_msg_write_json(stdout, f.msg);
                fputs("}\n", stdout);
            }
        }
        else
            rc = type == T(BUSY) ? print_busy(&f) : type == T(ERROR) ? print_error(&f) : CLI_FAIL;
        gs_client_frame_free(&f);
        if (rc >= 0)
            return rc;
    }
}

static int do_redirect(gs_client *c, const cli_opt *o, int timeout)
{
    const cli_command *cmd = &cli_client_command;
    if (!o[O_GAZES].value || !o[O_OUT].value || (!o[O_SUBJECT].value == !o[O_IMAGE].value))
        return cli_usage_error(cmd, "redirect needs --gaze-deg, --out and one of --subject, --image");
    uint8_t key[GS_FRAME_KEY_SIZE] = {0}, *data = NULL;
    if (o[O_SUBJECT].value && gs_frame_key_parse(o[O_SUBJECT].value, key) != 0)
        return cli_usage_error(cmd, "--subject wants 32 hex digits");
    Gazesplat__Angles *gazes = NULL, *heads = NULL;
    int n = 0, nh = 0;
    int rc = parse_angles("--gaze-deg", o[O_GAZES].value, 1, 0, &gazes, &n);
    if (rc == CLI_OK && o[O_HEADS].value)
        rc = parse_angles("--head-deg", o[O_HEADS].value, 1, 1, &heads, &nh);
    if (rc != CLI_OK) {
        free(gazes);
        return rc;
    }
    int fmt = GAZESPLAT__IMAGE_FORMAT__FORMAT_PNG;
    const char *fs = o[O_FORMAT].value;
    if (fs && !strcmp(fs, "jpeg"))
        fmt = GAZESPLAT__IMAGE_FORMAT__FORMAT_JPEG;
    else if (fs && !strcmp(fs, "raw"))
        fmt = GAZESPLAT__IMAGE_FORMAT__FORMAT_RAW_RGB8;
    if (o[O_HEADS].value && nh != n)
        rc = cli_usage_error(cmd, "--head-deg needs one pose per target (%d)", n);
    else if (fs && strcmp(fs, "png") && strcmp(fs, "jpeg") && strcmp(fs, "raw"))
        rc = cli_usage_error(cmd, "--format wants png, jpeg or raw");
    else if (mkdir(o[O_OUT].value, 0777) != 0 && errno != EEXIST)
        rc = cli_fail(cmd, "cannot create %s", o[O_OUT].value);
    Gazesplat__Image img = GAZESPLAT__IMAGE__INIT;
    if (rc == CLI_OK && o[O_IMAGE].value)
        rc = load_image(cmd, o, &img, &data);
    Gazesplat__Target *targets = calloc((size_t)n, sizeof *targets);
    Gazesplat__Target **tp = calloc((size_t)n, sizeof *tp);
    if (rc == CLI_OK && (!targets || !tp))
        rc = cli_fail(cmd, "out of memory");
    if (rc == CLI_OK) {
        for (int i = 0; i < n; i++) {
            gazesplat__target__init(&targets[i]);
            targets[i].gaze = &gazes[i];
            targets[i].head = heads ? &heads[i] : NULL;
            tp[i] = &targets[i];
        }
        Gazesplat__RedirectRequest req = GAZESPLAT__REDIRECT_REQUEST__INIT;
        req.image = o[O_IMAGE].value ? &img : NULL;
        req.n_targets = (size_t)n;
        req.targets = tp;
        req.output_format = (Gazesplat__ImageFormat)fmt;
        if (o[O_PASTE].value)
            req.output_mode = GAZESPLAT__OUTPUT_MODE__OUTPUT_PASTE_BACK;
        req.transfer = o[O_TRANSFER].value != NULL;
        long iters = 0;
        if (o[O_ITERS].value && cli_parse_long(o[O_ITERS].value, 1, 100000, &iters) == 0)
            req.max_iters = (uint32_t)iters;
        gs_error err;
        if ((rc = finetune_opts(cmd, o, &req.finetune_steps, &req.finetune_parts,
                                &req.finetune_outline_px, &req.finetune_no_mirror,
                                &req.finetune_lr)) != CLI_OK)
            ; /* reported */
        else if (gs_client_send(c, T(REDIRECT), key, 1, &req.base, &err) != GS_OK)
            rc = cli_fail(cmd, "%s", err.msg);
        else
            rc = receive_images(c, o[O_OUT].value, timeout);
    }
    free(targets);
    free(tp);
    free(gazes);
    free(heads);
    free(data);
    return rc;
}

static int run_client(int argc, char **argv)
{
    const cli_command *cmd = &cli_client_command;
    if (argc < 2 || !strcmp(argv[1], "--help") || !strcmp(argv[1], "-h")) {
        fputs(cmd->usage, argc < 2 ? stderr : stdout);
        return argc < 2 ? CLI_USAGE : CLI_OK;
    }
    const char *action = argv[1];
    cli_opt o[O_N] = {
        {"--addr", 1, NULL}, {"--token", 1, NULL}, {"--timeout-ms", 1, NULL}, {"--image", 1, NULL},
        {"--photo", 0, NULL}, {"--gaze", 1, NULL}, {"--head", 1, NULL}, {"--key", 1, NULL},
        {"--max-iters", 1, NULL}, {"--subject", 1, NULL}, {"--gaze-deg", 1, NULL},
        {"--head-deg", 1, NULL}, {"--format", 1, NULL}, {"--out", 1, NULL}, {"--deadline-ms", 1, NULL},
        {"--paste-back", 0, NULL}, {"--refit", 0, NULL}, {"--finetune", 1, NULL},
        {"--finetune-parts", 1, NULL}, {"--keep-image", 0, NULL}, {"--transfer", 0, NULL},
        {"--finetune-outline", 1, NULL}, {"--finetune-mirror", 1, NULL},
        {"--finetune-lr", 1, NULL}, {"--json", 0, NULL},
    };
    /* --set may repeat: take every one out before the common parser. */
    const char *sets[MAX_SETS];
    int nsets = 0, kept = 1;
    for (int i = 1; i < argc; i++) {
        if (!strcmp(argv[i], "--set") && i + 1 < argc && nsets < MAX_SETS) {
            sets[nsets++] = argv[++i];
            continue;
        }
        if (!strcmp(argv[i], "--set"))
            return cli_usage_error(cmd, "--set wants key=value (at most %d)", MAX_SETS);
        argv[kept++] = argv[i];
    }
    argc = kept;
    int r = cli_parse(cmd, argc - 1, argv + 1, o, O_N);
    json_out = o[O_JSON].value != NULL;
    if (r == CLI_HELP) {
        fputs(cmd->usage, stdout);
        return CLI_OK;
    }
    if (r != CLI_PARSED)
        return r;
    int known = !strcmp(action, "hello") || !strcmp(action, "health") || !strcmp(action, "stats") ||
                !strcmp(action, "fit") || !strcmp(action, "redirect") ||
                !strcmp(action, "live-policy") || !strcmp(action, "live-status");
    if (nsets && strcmp(action, "live-policy"))
        return cli_usage_error(cmd, "--set is for live-policy");
    if (!known)
        return cli_usage_error(cmd, "unknown action '%s'", action);
    long timeout = 120000;
    if (o[O_TIMEOUT].value && cli_parse_long(o[O_TIMEOUT].value, 1, 86400000, &timeout) != 0)
        return cli_usage_error(cmd, "--timeout-ms wants 1..86400000");
    const char *addr = o[O_ADDR].value ? o[O_ADDR].value : getenv("GAZESPLAT_ADDR");
    if (!addr)
        addr = "/run/gazesplat/gazesplatd.sock"; /* systemd/gazesplatd.socket */
    const char *token = o[O_TOKEN].value ? o[O_TOKEN].value : getenv("GAZESPLAT_TOKEN");
    if ((r = check_angle_opts(o)) != CLI_OK)
        return r;
    gs_client *c;
    gs_error err;
    if (gs_client_connect(addr, (int)timeout, &c, &err) != GS_OK)
        return cli_fail(cmd, "%s", err.msg);
    Gazesplat__HelloOk *ok = NULL;
    if (gs_client_hello(c, "gazesplat-cli", token, (int)timeout, &ok, &err) != GS_OK) {
        gs_client_close(c);
        return cli_fail(cmd, "HELLO: %s", err.msg);
    }
    if (!strcmp(action, "hello") && json_out) {
        print_json(&ok->base);
    } else if (!strcmp(action, "hello")) {
        const Gazesplat__Limits *l = ok->limits;
        printf("version %u\nserver %s\nimage_size %u\n", ok->version, ok->server, ok->image_size);
        if (l)
            printf("max_payload %u\nmax_targets %u\nmax_inflight %u\nmax_image_side %u\n"
                   "max_image_pixels %llu\nqueue_depth %u\nidle_timeout_ms %u\nmax_deadline_ms %u\n",
                   l->max_payload, l->max_targets, l->max_inflight, l->max_image_side,
                   (unsigned long long)l->max_image_pixels, l->queue_depth, l->idle_timeout_ms,
                   l->max_deadline_ms);
    }
    protobuf_c_message_free_unpacked(&ok->base, NULL);
    int timeout_i = (int)timeout;
    if (!strcmp(action, "hello"))
        r = CLI_OK; /* printed above */
    else if (!strcmp(action, "health"))
        r = do_health(c, timeout_i);
    else if (!strcmp(action, "stats"))
        r = do_stats(c, timeout_i);
    else if (!strcmp(action, "fit"))
        r = do_fit(c, o, timeout_i);
    else if (!strcmp(action, "live-policy"))
        r = do_live_policy(c, sets, nsets, o[O_REFIT].value != NULL, timeout_i);
    else if (!strcmp(action, "live-status"))
        r = do_live_status(c, timeout_i);
    else
        r = do_redirect(c, o, timeout_i);
    gs_client_close(c);
    return r;
}
