/* gazesplat live: camera -> processing (pass-through until the eye-contact
 * stage exists) -> v4l2loopback, with periodic statistics. */
#define _GNU_SOURCE
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/resource.h>
#include <time.h>

#include "cli.h"
#include "gazesplat/capture.h"

static const char usage[] =
    "usage: gazesplat live --in /dev/videoN|usb:VID:PID[:SERIAL] [--out /dev/videoM]\n"
    "                      [--size WxH] [--fps N] [--format auto|yuyv|mjpeg]\n"
    "                      [--seconds S] [--stats S] [--no-hotplug] [--hotplug-any]\n"
    "                      [--sysfs DIR]\n"
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
    "\n"
    "Events and statistics go to stderr, one line each, prefixed with the\n"
    "monotonic time in seconds.\n";

static int run_live(int argc, char **argv);
const cli_command cli_live_command = {"live", "stream a camera to a v4l2loopback device",
                                      usage, run_live};

static volatile sig_atomic_t stop_flag;

static void on_signal(int sig)
{
    (void)sig;
    stop_flag = 1;
}

static double mono_s(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + (double)ts.tv_nsec / 1e9;
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
    fprintf(stderr, "[%.3f] %s: %s\n", mono_s(), names[ev], msg);
}

static void on_hotplug(void *user, gs_cap_hotplug_event ev, uint16_t vid, uint16_t pid)
{
    fprintf(stderr, "[%.3f] hotplug: %04x:%04x %s\n", mono_s(), vid, pid,
            ev == GS_CAP_HOTPLUG_ARRIVED ? "arrived" : "left");
    if (ev == GS_CAP_HOTPLUG_ARRIVED)
        gs_cap_kick(user);
}

typedef struct tick {
    double t, cpu;
    uint64_t in, out;
} tick;

static void print_stats(gs_cap_pipe *p, tick *last, int final)
{
    gs_cap_pipe_stats s;
    gs_cap_pipe_get_stats(p, &s);
    tick now = {mono_s(), cpu_s(), s.in, s.out};
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
       O_SYSFS, O_COUNT };

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
static void loop(gs_cap_pipe *p, long seconds, long stats_every)
{
    tick last = {mono_s(), cpu_s(), 0, 0}, first = last;
    double t_end = seconds > 0 ? last.t + (double)seconds : 0, t_stats = last.t + (double)stats_every;
    while (!stop_flag && (t_end == 0 || mono_s() < t_end)) {
        struct timespec ts = {0, 50000000};
        nanosleep(&ts, NULL);
        if (stats_every > 0 && mono_s() >= t_stats) {
            print_stats(p, &last, 0);
            t_stats += (double)stats_every;
        }
    }
    print_stats(p, &first, 1);
}

static int run_live(int argc, char **argv)
{
    const cli_command *cmd = &cli_live_command;
    cli_opt o[O_COUNT] = {{"--in", 1, NULL},      {"--out", 1, NULL},     {"--size", 1, NULL},
                          {"--fps", 1, NULL},     {"--format", 1, NULL},  {"--seconds", 1, NULL},
                          {"--stats", 1, NULL},   {"--no-hotplug", 0, NULL},
                          {"--hotplug-any", 0, NULL}, {"--sysfs", 1, NULL}};
    int r = cli_parse(cmd, argc, argv, o, O_COUNT);
    if (r == CLI_HELP) {
        fputs(usage, stdout);
        return CLI_OK;
    }
    if (r != CLI_PARSED)
        return r;
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
    gs_cap *cap = NULL;
    gs_cap_out *out = NULL;
    if (gs_cap_create(&c, &cap, &e) != GS_OK)
        return cli_fail(cmd, "%s", e.msg);
    if (o[O_OUT].value && gs_cap_out_create(o[O_OUT].value, c.width & ~1, c.height, c.fps, NULL,
                                            &out, &e) != GS_OK) {
        gs_cap_destroy(cap);
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
            fprintf(stderr, "[%.3f] hotplug: off (%s)\n", mono_s(), e.msg);
        else
            fprintf(stderr, "[%.3f] hotplug: watching\n", mono_s());
    }
    signal(SIGINT, on_signal);
    signal(SIGTERM, on_signal);
    gs_cap_pipe_config pc = {cap, gs_cap_stage_passthrough(), out, 2, NULL, on_event, NULL};
    gs_cap_pipe *p = NULL;
    r = gs_cap_pipe_start(&pc, &p, &e);
    if (r == GS_OK) {
        fprintf(stderr, "[%.3f] live: %s -> %s\n", mono_s(), path,
                o[O_OUT].value ? o[O_OUT].value : "(discard)");
        loop(p, seconds, stats_every);
        gs_cap_pipe_stop(p);
    }
    gs_cap_hotplug_stop(hp);
    gs_cap_out_destroy(out);
    gs_cap_destroy(cap);
    return r == GS_OK ? CLI_OK : cli_fail(cmd, "%s", e.msg);
}
