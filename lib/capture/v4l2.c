/* V4L2 capture: mmap buffers, format and fps negotiation read back from the
 * driver, newest-frame semantics, reopen with back-off on any error.
 *
 * No buffer is held between grabs: the newest frame is converted to RGB
 * and re-queued at once, so the driver always has every buffer but one to
 * fill and a slow consumer only ever sees the latest picture. */
#define _GNU_SOURCE
#include <errno.h>
#include <fcntl.h>
#include <linux/videodev2.h>
#include <stdatomic.h>
#include <stdlib.h>
#include <string.h>

#include "gazesplat/capture.h"
#include "gazesplat/image_io.h"

/* A frame shorter than this is a driver glitch, never a picture. */
#define MIN_FRAME_BYTES 128
/* Sleeping for a reopen is cut in slices so a kick is noticed quickly. */
#define KICK_POLL_NS 10000000

typedef struct cap_buf {
    void *start;
    size_t len;
} cap_buf;

struct gs_cap {
    gs_cap_config cfg;
    char *path;     /* the device opened (a usb: spec's node, found at each open) */
    char *spec;     /* cfg.path as given */
    gs_cap_resolve_opts resolve; /* where a usb: spec is looked up */
    const gs_cap_ops *ops;
    int fd;
    int streaming;
    cap_buf bufs[GS_CAP_MAX_BUFFERS];
    int nbufs;
    gs_cap_format fmt;
    int have_fmt;
    uint8_t *rgb;
    size_t rgb_cap;
    int64_t next_open_ns;
    int backoff_ms;
    atomic_int kick;
    uint32_t last_seq;
    int have_seq;
    uint64_t skipped_base; /* stale + bad + gaps at the last delivered frame */
    int64_t open_start_ns; /* when the current open began */
    int awaiting_first;    /* opened, no frame delivered yet */
    gs_cap_stats stats;
};

gs_cap_config gs_cap_config_default(const char *path)
{
    gs_cap_config c = {0};
    c.path = path;
    c.width = 640;
    c.height = 480;
    c.fps = 30;
    c.pixfmt = GS_CAP_PIX_AUTO;
    return c;
}

static int xioctl(gs_cap *cap, unsigned long req, void *arg)
{
    int r;
    do
        r = cap->ops->ioctl(cap->ops->ctx, cap->fd, req, arg);
    while (r == -EINTR);
    return r;
}

static int64_t now_ns(const gs_cap *cap)
{
    return cap->ops->now_ns(cap->ops->ctx);
}

int gs_cap_create(const gs_cap_config *cfg, gs_cap **out, gs_error *err)
{
    if (!cfg || !out || !cfg->path || !cfg->path[0])
        return gs_error_set(err, GS_ERR_ARG, "capture: no device path");
    if (cfg->width < 2 || cfg->height < 1 || cfg->width > GS_CAP_MAX_SIDE ||
        cfg->height > GS_CAP_MAX_SIDE)
        return gs_error_set(err, GS_ERR_ARG, "capture: size %dx%d outside 2..%d",
                            cfg->width, cfg->height, GS_CAP_MAX_SIDE);
    if (cfg->fps < 0 || cfg->fps > 1000)
        return gs_error_set(err, GS_ERR_ARG, "capture: fps %d outside 0..1000", cfg->fps);
    if (cfg->pixfmt < GS_CAP_PIX_AUTO || cfg->pixfmt > GS_CAP_PIX_MJPEG)
        return gs_error_set(err, GS_ERR_ARG, "capture: unknown pixel format %d", cfg->pixfmt);
    if (cfg->nbuffers != 0 && (cfg->nbuffers < 2 || cfg->nbuffers > GS_CAP_MAX_BUFFERS))
        return gs_error_set(err, GS_ERR_ARG, "capture: %d buffers outside 2..%d",
                            cfg->nbuffers, GS_CAP_MAX_BUFFERS);
    if (cfg->timeout_ms < 0 || cfg->backoff_min_ms < 0 || cfg->backoff_max_ms < 0 ||
        cfg->timeout_ms > 60000 || cfg->backoff_max_ms > 3600000)
        return gs_error_set(err, GS_ERR_ARG, "capture: timeout or back-off out of range");
    gs_cap *cap = calloc(1, sizeof *cap);
    char *path = strdup(cfg->path), *spec = strdup(cfg->path);
    if (!cap || !path || !spec) {
        free(cap);
        free(path);
        free(spec);
        return gs_error_set(err, GS_ERR_NOMEM, "capture: out of memory");
    }
    cap->cfg = *cfg;
    cap->path = path;
    cap->spec = spec;
    cap->cfg.path = spec;
    if (cfg->resolve)
        cap->resolve = *cfg->resolve;
    else
        cap->resolve = (gs_cap_resolve_opts){NULL, NULL, 1};
    cap->cfg.resolve = NULL;
    if (!cap->cfg.nbuffers)
        cap->cfg.nbuffers = 4;
    if (!cap->cfg.timeout_ms)
        cap->cfg.timeout_ms = 1000;
    if (!cap->cfg.backoff_min_ms)
        cap->cfg.backoff_min_ms = 100;
    if (!cap->cfg.backoff_max_ms)
        cap->cfg.backoff_max_ms = 1000;
    if (cap->cfg.backoff_max_ms < cap->cfg.backoff_min_ms)
        cap->cfg.backoff_max_ms = cap->cfg.backoff_min_ms;
    cap->ops = cfg->ops ? cfg->ops : gs_cap_ops_system();
    cap->fd = -1;
    cap->backoff_ms = cap->cfg.backoff_min_ms;
    atomic_init(&cap->kick, 0);
    *out = cap;
    return GS_OK;
}

void gs_cap_close(gs_cap *cap)
{
    if (!cap || cap->fd < 0)
        return;
    if (cap->streaming) {
        int type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
        xioctl(cap, VIDIOC_STREAMOFF, &type); /* a vanished device fails here: fine */
    }
    for (int i = 0; i < cap->nbufs; i++)
        if (cap->bufs[i].start)
            cap->ops->munmap(cap->ops->ctx, cap->bufs[i].start, cap->bufs[i].len);
    if (cap->nbufs) {
        struct v4l2_requestbuffers rb = {0};
        rb.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
        rb.memory = V4L2_MEMORY_MMAP;
        xioctl(cap, VIDIOC_REQBUFS, &rb);
    }
    cap->ops->close(cap->ops->ctx, cap->fd);
    memset(cap->bufs, 0, sizeof cap->bufs);
    cap->nbufs = 0;
    cap->streaming = 0;
    cap->have_seq = 0;
    cap->fd = -1;
}

void gs_cap_destroy(gs_cap *cap)
{
    if (!cap)
        return;
    gs_cap_close(cap);
    free(cap->rgb);
    free(cap->path);
    free(cap->spec);
    free(cap);
}

static uint32_t fourcc_of(gs_cap_pixfmt f)
{
    return f == GS_CAP_PIX_MJPEG ? V4L2_PIX_FMT_MJPEG : V4L2_PIX_FMT_YUYV;
}

/* S_FMT with one pixel format; keeps what the driver answered when it is
 * that format at a usable size. 1 accepted, 0 driver chose another format,
 * < 0 error. */
static int try_format(gs_cap *cap, gs_cap_pixfmt pf, gs_error *err)
{
    struct v4l2_format f = {0};
    f.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
    f.fmt.pix.width = (uint32_t)cap->cfg.width;
    f.fmt.pix.height = (uint32_t)cap->cfg.height;
    f.fmt.pix.pixelformat = fourcc_of(pf);
    f.fmt.pix.field = V4L2_FIELD_NONE;
    int r = xioctl(cap, VIDIOC_S_FMT, &f);
    if (r < 0)
        return gs_error_set(err, GS_ERR_IO, "%s: VIDIOC_S_FMT: %s", cap->path, strerror(-r));
    if (f.fmt.pix.pixelformat != fourcc_of(pf))
        return 0;
    uint32_t w = f.fmt.pix.width, h = f.fmt.pix.height;
    if (w < 2 || h < 1 || w > GS_CAP_MAX_SIDE || h > GS_CAP_MAX_SIDE || (w & 1))
        return gs_error_set(err, GS_ERR_UNSUPPORTED, "%s: driver chose size %ux%u",
                            cap->path, w, h);
    size_t bpl = f.fmt.pix.bytesperline;
    if (pf == GS_CAP_PIX_YUYV) {
        if (bpl < 2 * (size_t)w)
            bpl = 2 * (size_t)w;
        if (f.fmt.pix.sizeimage && f.fmt.pix.sizeimage < bpl * h)
            return gs_error_set(err, GS_ERR_UNSUPPORTED, "%s: image size %u < %zu",
                                cap->path, f.fmt.pix.sizeimage, bpl * h);
    }
    cap->fmt.width = (int)w;
    cap->fmt.height = (int)h;
    cap->fmt.pixfmt = pf;
    cap->fmt.bytesperline = bpl;
    cap->fmt.sizeimage = f.fmt.pix.sizeimage;
    return 1;
}

static int set_format(gs_cap *cap, gs_error *err)
{
    static const gs_cap_pixfmt autolist[] = {GS_CAP_PIX_YUYV, GS_CAP_PIX_MJPEG};
    int n = cap->cfg.pixfmt == GS_CAP_PIX_AUTO ? 2 : 1;
    for (int i = 0; i < n; i++) {
        gs_cap_pixfmt pf = cap->cfg.pixfmt == GS_CAP_PIX_AUTO ? autolist[i] : cap->cfg.pixfmt;
        int r = try_format(cap, pf, err);
        if (r != 0)
            return r < 0 ? r : GS_OK;
    }
    return gs_error_set(err, GS_ERR_UNSUPPORTED, "%s: neither YUYV nor MJPEG offered",
                        cap->path);
}

/* S_PARM, then the rate read back. A driver without S_PARM keeps its own
 * rate (fps unknown); that is not a lost device. */
static int set_fps(gs_cap *cap, gs_error *err)
{
    struct v4l2_streamparm p = {0};
    p.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
    int r = -ENOTTY;
    if (cap->cfg.fps > 0) {
        p.parm.capture.timeperframe.numerator = 1;
        p.parm.capture.timeperframe.denominator = (uint32_t)cap->cfg.fps;
        r = xioctl(cap, VIDIOC_S_PARM, &p);
    }
    if (r == -ENOTTY || r == -EINVAL) {
        memset(&p, 0, sizeof p);
        p.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
        r = xioctl(cap, VIDIOC_G_PARM, &p);
        if (r == -ENOTTY || r == -EINVAL) {
            cap->fmt.fps_num = cap->fmt.fps_den = 0;
            return GS_OK;
        }
    }
    if (r < 0)
        return gs_error_set(err, GS_ERR_IO, "%s: VIDIOC_S_PARM: %s", cap->path, strerror(-r));
    const struct v4l2_fract *t = &p.parm.capture.timeperframe;
    int known = (p.parm.capture.capability & V4L2_CAP_TIMEPERFRAME) && t->numerator &&
                t->denominator && t->denominator <= INT32_MAX && t->numerator <= INT32_MAX;
    cap->fmt.fps_num = known ? (int)t->denominator : 0;
    cap->fmt.fps_den = known ? (int)t->numerator : 0;
    return GS_OK;
}

static int map_buffers(gs_cap *cap, gs_error *err)
{
    struct v4l2_requestbuffers rb = {0};
    rb.count = (uint32_t)cap->cfg.nbuffers;
    rb.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
    rb.memory = V4L2_MEMORY_MMAP;
    int r = xioctl(cap, VIDIOC_REQBUFS, &rb);
    if (r < 0)
        return gs_error_set(err, GS_ERR_IO, "%s: VIDIOC_REQBUFS: %s", cap->path, strerror(-r));
    if (rb.count < 2)
        return gs_error_set(err, GS_ERR_IO, "%s: driver gave %u buffers", cap->path, rb.count);
    cap->nbufs = rb.count > GS_CAP_MAX_BUFFERS ? GS_CAP_MAX_BUFFERS : (int)rb.count;
    for (int i = 0; i < cap->nbufs; i++) {
        struct v4l2_buffer b = {0};
        b.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
        b.memory = V4L2_MEMORY_MMAP;
        b.index = (uint32_t)i;
        if ((r = xioctl(cap, VIDIOC_QUERYBUF, &b)) < 0)
            return gs_error_set(err, GS_ERR_IO, "%s: VIDIOC_QUERYBUF: %s", cap->path,
                                strerror(-r));
        int e = 0;
        void *p = cap->ops->mmap(cap->ops->ctx, cap->fd, b.length, (off_t)b.m.offset, &e);
        if (!p)
            return gs_error_set(err, GS_ERR_IO, "%s: mmap: %s", cap->path, strerror(e));
        cap->bufs[i].start = p;
        cap->bufs[i].len = b.length;
        if ((r = xioctl(cap, VIDIOC_QBUF, &b)) < 0)
            return gs_error_set(err, GS_ERR_IO, "%s: VIDIOC_QBUF: %s", cap->path, strerror(-r));
    }
    return GS_OK;
}

static int ensure_rgb(gs_cap *cap, gs_error *err)
{
    size_t need = (size_t)cap->fmt.width * (size_t)cap->fmt.height * 3;
    if (need <= cap->rgb_cap)
        return GS_OK;
    uint8_t *p = realloc(cap->rgb, need);
    if (!p)
        return gs_error_set(err, GS_ERR_NOMEM, "capture: out of memory");
    cap->rgb = p;
    cap->rgb_cap = need;
    return GS_OK;
}

/* Open, check, negotiate, map, stream on. Leaves the device closed on
 * failure. */
static int open_device(gs_cap *cap, gs_error *err)
{
    cap->open_start_ns = now_ns(cap);
    if (strncmp(cap->spec, "usb:", 4) == 0) {
        /* A camera named by USB identity is looked up at every open: it
         * may arrive after the start, or come back as another videoN. */
        char dev[256];
        int r = gs_cap_resolve(cap->spec, &cap->resolve, dev, sizeof dev, err);
        if (r != GS_OK)
            return r;
        char *p = strdup(dev);
        if (!p)
            return gs_error_set(err, GS_ERR_NOMEM, "capture: out of memory");
        free(cap->path);
        cap->path = p;
    }
    int fd = cap->ops->open(cap->ops->ctx, cap->path, O_RDWR | O_NONBLOCK);
    if (fd < 0)
        return gs_error_set(err, GS_ERR_IO, "%s: open: %s", cap->path, strerror(-fd));
    cap->fd = fd;
    struct v4l2_capability qc = {0};
    int r = xioctl(cap, VIDIOC_QUERYCAP, &qc);
    uint32_t caps = (qc.capabilities & V4L2_CAP_DEVICE_CAPS) ? qc.device_caps : qc.capabilities;
    if (r < 0)
        r = gs_error_set(err, GS_ERR_IO, "%s: VIDIOC_QUERYCAP: %s", cap->path, strerror(-r));
    else if (!(caps & V4L2_CAP_VIDEO_CAPTURE) || !(caps & V4L2_CAP_STREAMING))
        r = gs_error_set(err, GS_ERR_UNSUPPORTED, "%s: not a streaming capture device",
                         cap->path);
    if (r == GS_OK)
        r = set_format(cap, err);
    if (r == GS_OK)
        r = set_fps(cap, err);
    if (r == GS_OK)
        r = ensure_rgb(cap, err);
    if (r == GS_OK)
        r = map_buffers(cap, err);
    if (r == GS_OK) {
        int type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
        int s = xioctl(cap, VIDIOC_STREAMON, &type);
        if (s < 0)
            r = gs_error_set(err, GS_ERR_IO, "%s: VIDIOC_STREAMON: %s", cap->path, strerror(-s));
        else
            cap->streaming = 1;
    }
    if (r != GS_OK) {
        gs_cap_close(cap);
        return r;
    }
    cap->fmt.nbuffers = cap->nbufs;
    cap->have_fmt = 1;
    cap->awaiting_first = 1;
    cap->stats.opens++;
    return GS_OK;
}

/* Closes the device and schedules the next open after the back-off, which
 * then doubles. Returns the code already set in err (GS_ERR_IO if none). */
static int lose(gs_cap *cap, int code)
{
    gs_cap_close(cap);
    cap->stats.failures++;
    cap->next_open_ns = now_ns(cap) + (int64_t)cap->backoff_ms * 1000000;
    cap->backoff_ms = cap->backoff_ms * 2 > cap->cfg.backoff_max_ms ? cap->cfg.backoff_max_ms
                                                                    : cap->backoff_ms * 2;
    return code ? code : GS_ERR_IO;
}

/* Waits for the reopen time or a kick, at most until deadline. 1 when it
 * is time to open. */
static int wait_reopen(gs_cap *cap, int64_t deadline)
{
    for (;;) {
        if (atomic_exchange(&cap->kick, 0))
            cap->next_open_ns = 0;
        int64_t t = now_ns(cap);
        if (t >= cap->next_open_ns)
            return 1;
        if (t >= deadline)
            return 0;
        int64_t until = cap->next_open_ns < deadline ? cap->next_open_ns : deadline;
        int64_t step = until - t < KICK_POLL_NS ? until - t : KICK_POLL_NS;
        cap->ops->sleep_ns(cap->ops->ctx, step);
    }
}

static int queue(gs_cap *cap, struct v4l2_buffer *b, gs_error *err)
{
    int r = xioctl(cap, VIDIOC_QBUF, b);
    if (r < 0)
        return gs_error_set(err, GS_ERR_IO, "%s: VIDIOC_QBUF: %s", cap->path, strerror(-r));
    return GS_OK;
}

/* 1 when buffer b holds a frame worth decoding. */
static int frame_valid(const gs_cap *cap, const struct v4l2_buffer *b)
{
    if (b->flags & V4L2_BUF_FLAG_ERROR || b->bytesused < MIN_FRAME_BYTES ||
        b->index >= (uint32_t)cap->nbufs || b->bytesused > cap->bufs[b->index].len)
        return 0;
    if (cap->fmt.pixfmt == GS_CAP_PIX_YUYV)
        return b->bytesused >= cap->fmt.bytesperline * (size_t)cap->fmt.height;
    return gs_cap_mjpeg_complete(cap->bufs[b->index].start, b->bytesused);
}

static void count_gap(gs_cap *cap, uint32_t seq)
{
    if (cap->have_seq && seq > cap->last_seq + 1)
        cap->stats.gaps += seq - cap->last_seq - 1;
    cap->last_seq = seq;
    cap->have_seq = 1;
}

/* Dequeues until EAGAIN; *newest gets the newest valid buffer (still
 * dequeued), every other buffer goes back to the driver. 1 when a frame was
 * kept, 0 none, < 0 error. */
static int drain(gs_cap *cap, struct v4l2_buffer *newest, gs_error *err)
{
    int have = 0;
    for (;;) {
        struct v4l2_buffer b = {0};
        b.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
        b.memory = V4L2_MEMORY_MMAP;
        int r = xioctl(cap, VIDIOC_DQBUF, &b);
        if (r == -EAGAIN)
            return have;
        if (r < 0)
            return gs_error_set(err, GS_ERR_IO, "%s: VIDIOC_DQBUF: %s", cap->path,
                                strerror(-r));
        if (b.index >= (uint32_t)cap->nbufs)
            return gs_error_set(err, GS_ERR_IO, "%s: driver returned buffer %u of %d",
                                cap->path, b.index, cap->nbufs);
        count_gap(cap, b.sequence);
        if (!frame_valid(cap, &b)) {
            cap->stats.bad++;
            if ((r = queue(cap, &b, err)) < 0)
                return r;
            continue;
        }
        if (have) {
            cap->stats.stale++;
            if ((r = queue(cap, newest, err)) < 0)
                return r;
        }
        *newest = b;
        have = 1;
    }
}

static int decode(gs_cap *cap, const struct v4l2_buffer *b)
{
    const uint8_t *src = cap->bufs[b->index].start;
    int w = cap->fmt.width, h = cap->fmt.height;
    if (cap->fmt.pixfmt == GS_CAP_PIX_YUYV) {
        gs_cap_yuyv_to_rgb(src, cap->fmt.bytesperline, w, h, cap->rgb, 3 * (size_t)w);
        return GS_OK;
    }
    gs_io_image img = {0};
    int r = gs_io_image_decode(src, b->bytesused, NULL, &img, NULL);
    if (r == GS_OK && (img.width != w || img.height != h))
        r = GS_ERR_FORMAT;
    if (r == GS_OK)
        memcpy(cap->rgb, img.data, (size_t)w * (size_t)h * 3);
    gs_io_image_free(&img);
    return r;
}

static int64_t buf_time_ns(const struct v4l2_buffer *b, int64_t fallback)
{
    if ((b->flags & V4L2_BUF_FLAG_TIMESTAMP_MASK) != V4L2_BUF_FLAG_TIMESTAMP_MONOTONIC ||
        (b->timestamp.tv_sec == 0 && b->timestamp.tv_usec == 0))
        return fallback;
    return (int64_t)b->timestamp.tv_sec * 1000000000 + (int64_t)b->timestamp.tv_usec * 1000;
}

static void deliver(gs_cap *cap, const struct v4l2_buffer *b, int64_t t, gs_cap_frame *f)
{
    uint64_t skipped = cap->stats.stale + cap->stats.bad + cap->stats.gaps;
    f->width = cap->fmt.width;
    f->height = cap->fmt.height;
    f->stride = 3 * (size_t)cap->fmt.width;
    f->rgb = cap->rgb;
    f->sequence = b->sequence;
    f->t_dequeue_ns = t;
    /* Some drivers (vivid) stamp the ideal frame time, which can lie a
     * little in the future: never report a negative capture latency. */
    int64_t tc = buf_time_ns(b, t);
    f->t_capture_ns = tc < t ? tc : t;
    f->skipped = (int)(skipped - cap->skipped_base);
    cap->skipped_base = skipped;
    cap->stats.frames++;
    if (cap->awaiting_first) {
        cap->stats.first_frame_ns = (uint64_t)(t > cap->open_start_ns ? t - cap->open_start_ns : 0);
        cap->awaiting_first = 0;
    }
    cap->backoff_ms = cap->cfg.backoff_min_ms;
}

/* Polls and drains until a good frame or the deadline. */
static int grab_open(gs_cap *cap, int64_t deadline, gs_cap_frame *frame, gs_error *err)
{
    for (;;) {
        int64_t t = now_ns(cap);
        if (t >= deadline)
            return lose(cap, gs_error_set(err, GS_ERR_IO, "%s: no frame in %d ms", cap->path,
                                          cap->cfg.timeout_ms));
        struct pollfd pfd = {cap->fd, POLLIN, 0};
        int wait_ms = (int)((deadline - t + 999999) / 1000000);
        int n = cap->ops->poll(cap->ops->ctx, &pfd, 1, wait_ms);
        if (n == -EINTR || n == 0)
            continue;
        if (n < 0)
            return lose(cap, gs_error_set(err, GS_ERR_IO, "%s: poll: %s", cap->path,
                                          strerror(-n)));
        struct v4l2_buffer b;
        int r = drain(cap, &b, err);
        if (r < 0)
            return lose(cap, r);
        if (r == 0) {
            if (pfd.revents & (POLLERR | POLLHUP | POLLNVAL))
                return lose(cap, gs_error_set(err, GS_ERR_IO, "%s: device error (poll)",
                                              cap->path));
            continue;
        }
        int64_t tq = now_ns(cap);
        int ok = decode(cap, &b) == GS_OK;
        if (ok)
            deliver(cap, &b, tq, frame);
        else
            cap->stats.bad++;
        if ((r = queue(cap, &b, err)) < 0)
            return lose(cap, r);
        if (ok)
            return GS_OK;
    }
}

int gs_cap_grab(gs_cap *cap, gs_cap_frame *frame, gs_error *err)
{
    if (!cap || !frame)
        return gs_error_set(err, GS_ERR_ARG, "capture: NULL argument");
    memset(frame, 0, sizeof *frame);
    int64_t deadline = now_ns(cap) + (int64_t)cap->cfg.timeout_ms * 1000000;
    if (cap->fd < 0) {
        if (!wait_reopen(cap, deadline))
            return gs_error_set(err, GS_ERR_IO, "%s: closed, reopening", cap->path);
        int r = open_device(cap, err);
        if (r != GS_OK)
            return lose(cap, r);
        deadline = now_ns(cap) + (int64_t)cap->cfg.timeout_ms * 1000000;
    }
    return grab_open(cap, deadline, frame, err);
}

void gs_cap_kick(gs_cap *cap)
{
    if (cap)
        atomic_store(&cap->kick, 1);
}

int gs_cap_is_open(const gs_cap *cap)
{
    return cap && cap->fd >= 0 && cap->streaming;
}

int gs_cap_get_format(const gs_cap *cap, gs_cap_format *fmt)
{
    if (!cap || !fmt || !cap->have_fmt)
        return GS_ERR_STATE;
    *fmt = cap->fmt;
    return GS_OK;
}

void gs_cap_get_stats(const gs_cap *cap, gs_cap_stats *stats)
{
    if (cap && stats)
        *stats = cap->stats;
}
