/* A fake V4L2 device and clock behind gs_cap_ops, for the capture tests and
 * the synthetic benchmark: mmap buffers in memory, a driver-side queue,
 * frames produced on demand or in step with a fake clock, format and rate
 * adjustment like a real driver, and injected failures (an ioctl's errno,
 * an unbound driver answering EINVAL, a vanished node). */
#ifndef GS_FAKE_V4L2_H
#define GS_FAKE_V4L2_H

#include <stdint.h>

#include "gazesplat/capture.h"

#define FAKE_MAX_BUFS 16
#define FAKE_NREQ 24

typedef struct fake_v4l2 {
    gs_cap_ops ops;            /* points back at this fake */
    int64_t t_ns;              /* the fake clock */
    int real_clock;            /* 1: CLOCK_MONOTONIC and real sleeps (benchmark) */
    /* the device */
    int present;               /* 0: open fails with ENOENT */
    int unbound;               /* 1: every ioctl on an open fd fails with EINVAL */
    int yuyv, mjpeg;           /* formats offered */
    int max_w, max_h;          /* the driver clamps sizes to these */
    int max_fps;               /* and the rate to this; 0: no S_PARM at all */
    int fps;                   /* current rate */
    int w, h;
    uint32_t fourcc;
    int nbufs;
    size_t buflen;
    uint8_t *mem[FAKE_MAX_BUFS];
    int state[FAKE_MAX_BUFS];  /* 0 idle, 1 queued, 2 done, 3 with the user */
    int order[FAKE_MAX_BUFS];  /* queue order (driver side, FIFO) */
    int nqueued;
    int done[FAKE_MAX_BUFS];   /* done order */
    int ndone;
    uint32_t bytesused[FAKE_MAX_BUFS], seq_of[FAKE_MAX_BUFS], flags_of[FAKE_MAX_BUFS];
    int64_t ts_of[FAKE_MAX_BUFS];
    uint32_t seq;
    int streaming;
    int fd_open;
    /* producing */
    int auto_produce;          /* poll makes one frame per frame interval */
    int stall;                 /* poll times out */
    const uint8_t *mjpeg_data; /* MJPEG payload to deliver */
    size_t mjpeg_len;
    int next_bad;              /* the next produced frames carry the error flag */
    uint32_t seq_skip;         /* the next frame's sequence jumps by this */
    /* failures: request -> errno, fired once after `after` successful calls */
    unsigned long fail_req[FAKE_NREQ];
    int fail_errno[FAKE_NREQ], fail_after[FAKE_NREQ];
    int nfail;
    /* counters */
    int64_t open_t[64];        /* times of open attempts */
    int open_attempts;
    int opens, s_fmt_calls, s_parm_calls, streamons, closes;
    int req_w, req_h, req_fps;
    uint32_t req_fourcc;
    /* output side */
    uint64_t written_bytes, writes;
    uint8_t *last_write;
    size_t last_write_len;
    int out_type_set;
} fake_v4l2;

/* A present YUYV+MJPEG device clamped at 1280x720, 30 fps max. */
void fake_init(fake_v4l2 *f);
void fake_free(fake_v4l2 *f);

/* Makes up to n queued buffers done (oldest queued first). Returns how many. */
int fake_produce(fake_v4l2 *f, int n);

/* Fails the next call of request with errno e (after `after` good calls). */
void fake_fail(fake_v4l2 *f, unsigned long request, int e, int after);

/* The Y value frame `seq` carries (YUYV fill), so tests can tell frames apart. */
int fake_luma_of(uint32_t seq);

#endif
