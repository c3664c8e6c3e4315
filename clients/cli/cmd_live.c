/* gazesplat live: camera -> eye contact (with --model; else pass-through)
 * -> v4l2loopback, with periodic statistics. The policy is fixed at start
 * here (--policy); gazesplatd with live.device changes it at run time. */
#define _GNU_SOURCE
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/resource.h>
#include <time.h>

#include "gazesplat/clock.h"
#include "cli.h"
#include "gazesplat/capture.h"
#include "gazesplat/live.h"

static const char usage[] =
    "usage: gazesplat live --in /dev/videoN|usb:VID:PID[:SERIAL] [--out /dev/videoM]\n"
    "                      [--size WxH] [--fps N] [--format auto|yuyv|mjpeg]\n"
    "                      [--seconds S] [--stats S] [--no-hotplug] [--hotplug-any]\n"
    "                      [--sysfs DIR] [--model M [--policy k=v,...]]\n"
    "\n"
    "Streams a camera to a v4l2loopback device (YUYV; load the module with\n"
    "exclusive_caps=1 for browsers). Without --out frames are discarded (to\n"
    "measure the capture alone). The camera is reopened whenever it fails,\n"
    "with a back-off up to 1 s; a usb: camera is also reopened at once when\n"
    "libusb reports a USB video device arriving (--hotplug-any: any device).\n"
    "\n"
    "  --in       camera: a device path or USB vendor:product[:serial] (hex)\n"
    "  --out      loopback device to write (even width)\n"
    "  --size     requested capture size (default 640x480; the driver may adjust)\n"
    "  --fps      requested frame rate (default 30)\n"
    "  --format   pixel format asked of the camera (default auto: YUYV, else MJPEG)\n"
    "  --seconds  stop after S seconds (default: run until SIGINT/SIGTERM)\n"
    "  --stats    print statistics every S seconds (default 5; 0 only at the end)\n"
    "  --sysfs    sysfs root for resolving usb: cameras (default /sys)\n"
    "  --model    a model file: turns on eye contact (the subject is fitted in the\n"
    "             background on the first frontal frames; pass-through until then)\n"
    "  --policy   eye-contact policy, e.g. strength=0.8,smooth_s=0.2,enabled=yes\n"
    "             (keys in docs/live.md); at run time use gazesplatd's live.device\n"
    "\n"
    "Events and statistics go to stderr, one line each, prefixed with the\n"
    "monotonic time in seconds.\n";

static int run_live(const cli_command *cmd, cli_opt *o);
static const cli_opt live_opts[] = {
    {"--in", 1, NULL}, {"--out", 1, NULL}, {"--size", 1, NULL}, {"--fps", 1, NULL},
    {"--format", 1, NULL}, {"--seconds", 1, NULL}, {"--stats", 1, NULL}, {"--no-hotplug", 0, NULL},
    {"--hotplug-any", 0, NULL}, {"--sysfs", 1, NULL}, {"--model", 1, NULL}, {"--policy", 1, NULL}};

const cli_command cli_live_command = {"live", "stream a camera to a v4l2loopback device",
                                      usage, .opts = live_opts, .nopts = CLI_NOPTS(live_opts),
                                      .run_opts = run_live};

static volatile sig_atomic_t stop_flag;

static void on_signal(int sig)
{
    (void)sig;
    stop_flag = 1;
}

static double cpu_s(void)
{
    struct rusage ru;
    getrusage(RUSAGE_SELF, &ru);
    return (double)ru.ru_utime.tv_sec + (double)ru.ru_utime.tv_usec / 1e6 +
           (double)ru.ru_stime.tv_sec + (double)ru.ru_stime.tv_usec / 1e6;
}

static void on_event(void *user, gs_cap_pipe_event ev, const char *msg)
{
    (void)user;
    static const char *names[] = {"", "capture", "capture lost", "output error", "stage error"};
    fprintf(stderr, "[%.3f] %s: %s\n", gs_clock_s(), names[ev], msg);
}

static void on_hotplug(void *user, gs_cap_hotplug_event ev, uint16_t vid, uint16_t pid)
{
    fprintf(stderr, "[%.3f] hotplug: %04x:%04x %s\n", gs_clock_s(), vid, pid,
            ev == GS_CAP_HOTPLUG_ARRIVED ? "arrived" : "left");
    if (ev == GS_CAP_HOTPLUG_ARRIVED)
        gs_cap_kick(user);
}

typedef struct tick {
    double t, cpu;
    uint64_t in, out;
} tick;

static void print_live(gs_live_stage *st)
{
    if (!st)
        return;
    gs_live_status s;
    gs_live_stage_get_status(st, &s);
    fprintf(stderr,
            "[%.3f] eyes: face %d subject %s | fits %llu refits %llu renders %llu | weight "
            "%.2f | head %.0f/%.0f deg | last fit %.1f s\n",
            gs_clock_s(), s.face, s.subject_ready ? "ready" : s.fitting ? "fitting" : "none",
            (unsigned long long)s.fits, (unsigned long long)s.refits,
            (unsigned long long)s.renders, (double)s.weight, s.head_pitch * 57.29578,
            s.head_yaw * 57.29578, s.last_fit_s);
}

static void print_stats(gs_cap_pipe *p, tick *last, int final)
{
    gs_cap_pipe_stats s;
    gs_cap_pipe_get_stats(p, &s);
    tick now = {gs_clock_s(), cpu_s(), s.in, s.out};
    double dt = now.t - last->t > 1e-6 ? now.t - last->t : 1e-6;
    fprintf(stderr,
            "[%.3f] %s: fps in %.1f out %.1f | frames in %llu out %llu | dropped stale %llu "
            "bad %llu gaps %llu ring %llu | reopens %llu | latency ms p50/p99 capture "
            "%.1f/%.1f process %.1f/%.1f output %.1f/%.1f total %.1f/%.1f | cpu %.0f%%\n",
            now.t, final ? "total" : "stats", (double)(now.in - last->in) / dt,
            (double)(now.out - last->out) / dt, (unsigned long long)s.in,
            (unsigned long long)s.out, (unsigned long long)s.cap.stale,
            (unsigned long long)s.cap.bad, (unsigned long long)s.cap.gaps,
            (unsigned long long)s.ring_drops,
            (unsigned long long)(s.cap.opens ? s.cap.opens - 1 : 0), s.capture.p50_ms,
            s.capture.p99_ms, s.process.p50_ms, s.process.p99_ms, s.output.p50_ms,
            s.output.p99_ms, s.total.p50_ms, s.total.p99_ms,
            100.0 * (now.cpu - last->cpu) / dt);
    *last = now;
}

enum { O_IN, O_OUT, O_SIZE, O_FPS, O_FORMAT, O_SECONDS, O_STATS, O_NOHOTPLUG, O_HPANY,
       O_SYSFS, O_MODEL, O_POLICY, O_COUNT };

/* What eye contact needs; all NULL without --model. */
typedef struct eyes {
    gs_model *model;
    gs_face_shape_model *sp;
    gs_face_detector *det;
    gs_live_face_models fm;
    gs_live_engine engine;
    gs_cap_policy *policy;
    gs_live_stage *stage;
} eyes;

static void eyes_free(eyes *y)
{
    gs_live_stage_destroy(y->stage);
    gs_live_engine_model_free(&y->engine);
    gs_cap_policy_destroy(y->policy);
    gs_face_detector_destroy(y->det);
    gs_face_shape_model_destroy(y->sp);
    gs_model_destroy(y->model);
}

static int eyes_start(const char *model, const char *policy, eyes *y, gs_error *e)
{
    gs_cap_policy_config pc = gs_cap_policy_config_default();
    int r = policy ? gs_cap_policy_config_parse(&pc, policy, e) : GS_OK;
    if (r == GS_OK)
        r = gs_model_load(model, &y->model, e);
    if (r == GS_OK)
        r = gs_face_shape_model_load(NULL, &y->sp, e);
    if (r == GS_OK)
        r = gs_face_detector_load(NULL, &y->det, e);
    if (r == GS_OK)
        r = gs_cap_policy_create(&pc, &y->policy, e);
    if (r == GS_OK)
        r = gs_live_engine_model(y->model, NULL, 0, &y->engine, e);
    y->fm.det = y->det;
    y->fm.sp = y->sp;
    gs_live_track_ops ops = gs_live_track_ops_face(&y->fm);
    if (r == GS_OK)
        r = gs_live_stage_create(NULL, &ops, &y->engine, y->policy, &y->stage, e);
    return r;
}

static int parse_format(const char *s, gs_cap_pixfmt *pf)
{
    if (!s || strcmp(s, "auto") == 0)
        *pf = GS_CAP_PIX_AUTO;
    else if (strcmp(s, "yuyv") == 0)
        *pf = GS_CAP_PIX_YUYV;
    else if (strcmp(s, "mjpeg") == 0)
        *pf = GS_CAP_PIX_MJPEG;
    else
        return -1;
    return 0;
}

/* Runs until a signal or the time limit, printing statistics. */
static void loop(gs_cap_pipe *p, gs_live_stage *st, long seconds, long stats_every)
{
    tick last = {gs_clock_s(), cpu_s(), 0, 0}, first = last;
    double t_end = seconds > 0 ? last.t + (double)seconds : 0, t_stats = last.t + (double)stats_every;
    while (!stop_flag && (t_end == 0 || gs_clock_s() < t_end)) {
        struct timespec ts = {0, 50000000};
        nanosleep(&ts, NULL);
        if (stats_every > 0 && gs_clock_s() >= t_stats) {
            print_stats(p, &last, 0);
            print_live(st);
            t_stats += (double)stats_every;
        }
    }
    print_stats(p, &first, 1);
    print_live(st);
}

_Static_assert(CLI_NOPTS(live_opts) == O_COUNT, "live_opts: one entry per option index");

static int run_live(const cli_command *cmd, cli_opt *o)
{
    int r = CLI_OK;
    if (!o[O_IN].value)
        return cli_usage_error(cmd, "--in is required");
    gs_cap_config c = gs_cap_config_default(NULL);
    long fps = 30, seconds = 0, stats_every = 5;
    if (o[O_SIZE].value && cli_parse_size(o[O_SIZE].value, GS_CAP_MAX_SIDE, &c.width, &c.height))
        return cli_usage_error(cmd, "--size: expected WxH");
    if (o[O_FPS].value && cli_parse_long(o[O_FPS].value, 1, 1000, &fps))
        return cli_usage_error(cmd, "--fps: expected 1..1000");
    if (o[O_SECONDS].value && cli_parse_long(o[O_SECONDS].value, 1, 100000000, &seconds))
        return cli_usage_error(cmd, "--seconds: expected a positive integer");
    if (o[O_STATS].value && cli_parse_long(o[O_STATS].value, 0, 3600, &stats_every))
        return cli_usage_error(cmd, "--stats: expected 0..3600");
    if (parse_format(o[O_FORMAT].value, &c.pixfmt))
        return cli_usage_error(cmd, "--format: auto, yuyv or mjpeg");
    c.fps = (int)fps;

    gs_error e = {0};
    char path[512];
    gs_cap_resolve_opts ro = {o[O_SYSFS].value, NULL, 1};
    if (gs_cap_resolve(o[O_IN].value, &ro, path, sizeof path, &e) != GS_OK)
        return cli_fail(cmd, "%s", e.msg);
    c.path = path;
    if (o[O_POLICY].value && !o[O_MODEL].value)
        return cli_usage_error(cmd, "--policy needs --model");
    eyes y;
    memset(&y, 0, sizeof y);
    if (o[O_MODEL].value && eyes_start(o[O_MODEL].value, o[O_POLICY].value, &y, &e) != GS_OK) {
        eyes_free(&y);
        return cli_fail(cmd, "%s", e.msg);
    }
    gs_cap *cap = NULL;
    gs_cap_out *out = NULL;
    if (gs_cap_create(&c, &cap, &e) != GS_OK) {
        eyes_free(&y);
        return cli_fail(cmd, "%s", e.msg);
    }
    if (o[O_OUT].value && gs_cap_out_create(o[O_OUT].value, c.width & ~1, c.height, c.fps, NULL,
                                            &out, &e) != GS_OK) {
        gs_cap_destroy(cap);
        eyes_free(&y);
        return cli_fail(cmd, "%s", e.msg);
    }
    /* Hotplug: for usb: cameras (and on request for any device); a missing
     * libusb hotplug only costs the immediate reopen. */
    gs_cap_hotplug *hp = NULL;
    int want_hp = !o[O_NOHOTPLUG].value &&
                  (strncmp(o[O_IN].value, "usb:", 4) == 0 || o[O_HPANY].value);
    if (want_hp) {
        gs_cap_usb_id id;
        int filtered = gs_cap_usb_id_parse(o[O_IN].value, &id, NULL) == GS_OK;
        if (gs_cap_hotplug_start(filtered ? &id : NULL, o[O_HPANY].value != NULL, on_hotplug,
                                 cap, &hp, &e) != GS_OK)
            fprintf(stderr, "[%.3f] hotplug: off (%s)\n", gs_clock_s(), e.msg);
        else
            fprintf(stderr, "[%.3f] hotplug: watching\n", gs_clock_s());
    }
    signal(SIGINT, on_signal);
    signal(SIGTERM, on_signal);
    gs_cap_stage stage = y.stage ? gs_live_stage_as_cap(y.stage) : gs_cap_stage_passthrough();
    gs_cap_pipe_config pc = {cap, stage, out, 2, NULL, on_event, NULL, 0};
    gs_cap_pipe *p = NULL;
    r = gs_cap_pipe_start(&pc, &p, &e);
    if (r == GS_OK) {
        fprintf(stderr, "[%.3f] live: %s -> %s\n", gs_clock_s(), path,
                o[O_OUT].value ? o[O_OUT].value : "(discard)");
        loop(p, y.stage, seconds, stats_every);
        gs_cap_pipe_stop(p);
    }
    eyes_free(&y);
    gs_cap_hotplug_stop(hp);
    gs_cap_out_destroy(out);
    gs_cap_destroy(cap);
    return r == GS_OK ? CLI_OK : cli_fail(cmd, "%s", e.msg);
}
