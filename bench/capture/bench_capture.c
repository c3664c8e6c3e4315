/* bench_capture: the live pipeline (capture -> pass-through -> loopback
 * writer) fed by a synthetic 30 fps YUYV camera: the fake V4L2 device of
 * the tests on the real clock, which fills each frame like a driver would
 * (a full-frame write) and hands it over by mmap and DQBUF; the loopback is
 * the fake's write(), one copy of the YUYV frame. Reports sustained output
 * fps, added latency (frame timestamp -> written) p50/p99 and CPU use.
 *
 * usage: bench_capture [--seconds S] [--size WxH] [--fps N] */
#define _GNU_SOURCE
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/resource.h>
#include <time.h>

#include "fake_v4l2.h"

static double now_s(void)
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

int main(int argc, char **argv)
{
    int seconds = 10, w = 640, h = 480, fps = 30;
    for (int i = 1; i + 1 < argc; i += 2) {
        if (strcmp(argv[i], "--seconds") == 0)
            seconds = atoi(argv[i + 1]);
        else if (strcmp(argv[i], "--size") == 0 && sscanf(argv[i + 1], "%dx%d", &w, &h) == 2)
            ;
        else if (strcmp(argv[i], "--fps") == 0)
            fps = atoi(argv[i + 1]);
        else {
            fprintf(stderr, "usage: bench_capture [--seconds S] [--size WxH] [--fps N]\n");
            return 2;
        }
    }
    fake_v4l2 cam, out;
    fake_init(&cam);
    fake_init(&out);
    cam.real_clock = out.real_clock = 1;
    cam.auto_produce = 1;
    cam.max_w = cam.max_h = 4096;
    cam.max_fps = 240;
    gs_cap_config c = gs_cap_config_default("synthetic");
    c.width = w;
    c.height = h;
    c.fps = fps;
    c.ops = &cam.ops;
    gs_cap *cap = NULL;
    gs_cap_out *o = NULL;
    gs_cap_pipe *p = NULL;
    gs_error e = {0};
    if (gs_cap_create(&c, &cap, &e) || gs_cap_out_create("loopback", w, h, fps, &out.ops, &o, &e)) {
        fprintf(stderr, "bench_capture: %s\n", e.msg);
        return 1;
    }
    gs_cap_pipe_config pc = {cap, gs_cap_stage_passthrough(), o, 2, NULL, NULL, NULL, -1};
    double t0 = now_s(), c0 = cpu_s();
    if (gs_cap_pipe_start(&pc, &p, &e)) {
        fprintf(stderr, "bench_capture: %s\n", e.msg);
        return 1;
    }
    struct timespec ts = {seconds, 0};
    nanosleep(&ts, NULL);
    gs_cap_pipe_stats s;
    gs_cap_pipe_get_stats(p, &s);
    double t1 = now_s(), c1 = cpu_s();
    gs_cap_pipe_stop(p);
    printf("synthetic %dx%d YUYV at %d fps, pass-through, %d s\n", w, h, fps, seconds);
    printf("fps out %.1f (in %.1f), frames in %llu out %llu, dropped stale %llu ring %llu\n",
           (double)s.out / (t1 - t0), (double)s.in / (t1 - t0), (unsigned long long)s.in,
           (unsigned long long)s.out, (unsigned long long)s.cap.stale,
           (unsigned long long)s.ring_drops);
    printf("added latency ms (frame timestamp -> written): p50 %.2f p99 %.2f max %.2f\n",
           s.total.p50_ms, s.total.p99_ms, s.total.max_ms);
    printf("  capture (DQBUF + YUYV->RGB) p50 %.2f p99 %.2f | process p50 %.2f p99 %.2f | "
           "output (RGB->YUYV + write) p50 %.2f p99 %.2f\n",
           s.capture.p50_ms, s.capture.p99_ms, s.process.p50_ms, s.process.p99_ms,
           s.output.p50_ms, s.output.p99_ms);
    printf("cpu %.1f%% of one core (%.2f s over %.2f s, includes the fake driver's frame fill)\n",
           100.0 * (c1 - c0) / (t1 - t0), c1 - c0, t1 - t0);
    gs_cap_out_destroy(o);
    gs_cap_destroy(cap);
    fake_free(&cam);
    fake_free(&out);
    return 0;
}
