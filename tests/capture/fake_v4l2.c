/* The fake V4L2 device (see fake_v4l2.h). */
#define _GNU_SOURCE
#include "fake_v4l2.h"

#include <errno.h>
#include <linux/videodev2.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#define FAKE_FD 42

int fake_luma_of(uint32_t seq)
{
    return 16 + (int)(seq % 200);
}

static int take_failure(fake_v4l2 *f, unsigned long req)
{
    for (int i = 0; i < f->nfail; i++) {
        if (f->fail_req[i] != req)
            continue;
        if (f->fail_after[i]-- > 0)
            return 0;
        int e = f->fail_errno[i];
        f->fail_req[i] = f->fail_req[--f->nfail];
        f->fail_errno[i] = f->fail_errno[f->nfail];
        f->fail_after[i] = f->fail_after[f->nfail];
        return -e;
    }
    return 0;
}

void fake_fail(fake_v4l2 *f, unsigned long request, int e, int after)
{
    if (f->nfail < FAKE_NREQ) {
        f->fail_req[f->nfail] = request;
        f->fail_errno[f->nfail] = e;
        f->fail_after[f->nfail] = after;
        f->nfail++;
    }
}

static void fill_frame(fake_v4l2 *f, int i)
{
    uint8_t *m = f->mem[i];
    if (f->fourcc == V4L2_PIX_FMT_MJPEG) {
        size_t n = f->mjpeg_len < f->buflen ? f->mjpeg_len : f->buflen;
        if (f->mjpeg_data)
            memcpy(m, f->mjpeg_data, n);
        f->bytesused[i] = (uint32_t)n;
        return;
    }
    /* Touch only the first row fully and a marker elsewhere: filling the
     * whole frame every time would dominate a benchmark of the capture. */
    uint8_t y = (uint8_t)fake_luma_of(f->seq);
    size_t bpl = 2 * (size_t)f->w;
    for (size_t k = 0; k < bpl; k += 2) {
        m[k] = y;
        m[k + 1] = 128;
    }
    for (int r = 1; r < f->h; r++)
        memcpy(m + (size_t)r * bpl, m, bpl);
    f->bytesused[i] = (uint32_t)(bpl * (size_t)f->h);
}

int fake_produce(fake_v4l2 *f, int n)
{
    int made = 0;
    while (made < n && f->nqueued > 0 && f->streaming) {
        int i = f->order[0];
        memmove(f->order, f->order + 1, (size_t)(f->nqueued - 1) * sizeof f->order[0]);
        f->nqueued--;
        f->seq += f->seq_skip;
        f->seq_skip = 0;
        fill_frame(f, i);
        f->seq_of[i] = f->seq++;
        f->ts_of[i] = f->ops.now_ns(f);
        f->flags_of[i] = 0;
        if (f->next_bad > 0) {
            f->flags_of[i] = V4L2_BUF_FLAG_ERROR;
            f->next_bad--;
        }
        f->state[i] = 2;
        f->done[f->ndone++] = i;
        made++;
    }
    return made;
}

static int64_t f_now(void *ctx)
{
    fake_v4l2 *f = ctx;
    if (f->real_clock) {
        struct timespec ts;
        clock_gettime(CLOCK_MONOTONIC, &ts);
        return (int64_t)ts.tv_sec * 1000000000 + ts.tv_nsec;
    }
    return f->t_ns;
}

static void f_sleep(void *ctx, int64_t ns)
{
    fake_v4l2 *f = ctx;
    if (f->real_clock) {
        struct timespec ts = {(time_t)(ns / 1000000000), (long)(ns % 1000000000)};
        nanosleep(&ts, NULL);
    } else if (ns > 0) {
        f->t_ns += ns;
    }
}

static int f_open(void *ctx, const char *path, int flags)
{
    (void)path, (void)flags;
    fake_v4l2 *f = ctx;
    if (f->open_attempts < 64)
        f->open_t[f->open_attempts] = f->ops.now_ns(f);
    f->open_attempts++;
    if (!f->present)
        return -ENOENT;
    if (f->fd_open)
        return -EBUSY;
    f->fd_open = 1;
    f->unbound = 0;
    f->opens++;
    return FAKE_FD;
}

static void free_bufs(fake_v4l2 *f)
{
    for (int i = 0; i < f->nbufs; i++) {
        free(f->mem[i]);
        f->mem[i] = NULL;
    }
    f->nbufs = f->nqueued = f->ndone = 0;
    f->streaming = 0;
}

static int f_close(void *ctx, int fd)
{
    fake_v4l2 *f = ctx;
    if (fd != FAKE_FD || !f->fd_open)
        return -EBADF;
    f->fd_open = 0;
    f->closes++;
    free_bufs(f);
    return 0;
}

static int do_s_fmt(fake_v4l2 *f, struct v4l2_format *fmt)
{
    f->s_fmt_calls++;
    struct v4l2_pix_format *p = &fmt->fmt.pix;
    if (fmt->type == V4L2_BUF_TYPE_VIDEO_OUTPUT) {
        f->out_type_set = 1;
        f->w = (int)p->width;
        f->h = (int)p->height;
        return 0;
    }
    if (fmt->type != V4L2_BUF_TYPE_VIDEO_CAPTURE)
        return -EINVAL;
    if (f->nbufs)
        return -EBUSY;
    f->req_w = (int)p->width;
    f->req_h = (int)p->height;
    f->req_fourcc = p->pixelformat;
    /* Like a driver: unknown formats become the first offered one, sizes
     * are clamped and rounded to even widths. */
    if (!(p->pixelformat == V4L2_PIX_FMT_YUYV && f->yuyv) &&
        !(p->pixelformat == V4L2_PIX_FMT_MJPEG && f->mjpeg))
        p->pixelformat = f->yuyv ? V4L2_PIX_FMT_YUYV : V4L2_PIX_FMT_MJPEG;
    if ((int)p->width > f->max_w)
        p->width = (uint32_t)f->max_w;
    if ((int)p->height > f->max_h)
        p->height = (uint32_t)f->max_h;
    p->width &= ~1u;
    p->field = V4L2_FIELD_NONE;
    p->bytesperline = p->pixelformat == V4L2_PIX_FMT_YUYV ? 2 * p->width : 0;
    p->sizeimage = 2 * p->width * p->height;
    f->w = (int)p->width;
    f->h = (int)p->height;
    f->fourcc = p->pixelformat;
    return 0;
}

static int do_parm(fake_v4l2 *f, struct v4l2_streamparm *p, int set)
{
    if (!f->max_fps)
        return -ENOTTY;
    struct v4l2_fract *t = &p->parm.capture.timeperframe;
    if (set) {
        f->s_parm_calls++;
        f->req_fps = t->numerator ? (int)(t->denominator / t->numerator) : 0;
        f->fps = f->req_fps < 1 ? 1 : f->req_fps > f->max_fps ? f->max_fps : f->req_fps;
    }
    p->parm.capture.capability = V4L2_CAP_TIMEPERFRAME;
    t->numerator = 1;
    t->denominator = (uint32_t)f->fps;
    return 0;
}

static int do_reqbufs(fake_v4l2 *f, struct v4l2_requestbuffers *rb)
{
    if (rb->count == 0) {
        free_bufs(f);
        return 0;
    }
    if (f->nbufs)
        return -EBUSY;
    int n = rb->count > FAKE_MAX_BUFS ? FAKE_MAX_BUFS : (int)rb->count;
    f->buflen = 2 * (size_t)f->w * (size_t)f->h;
    for (int i = 0; i < n; i++) {
        f->mem[i] = calloc(1, f->buflen);
        f->state[i] = 0;
    }
    f->nbufs = n;
    rb->count = (uint32_t)n;
    return 0;
}

static int do_qbuf(fake_v4l2 *f, struct v4l2_buffer *b)
{
    if (b->index >= (uint32_t)f->nbufs || f->state[b->index] == 1 || f->state[b->index] == 2)
        return -EINVAL;
    f->state[b->index] = 1;
    f->order[f->nqueued++] = (int)b->index;
    return 0;
}

static int do_dqbuf(fake_v4l2 *f, struct v4l2_buffer *b)
{
    if (!f->streaming)
        return -EINVAL;
    if (!f->ndone)
        return -EAGAIN;
    int i = f->done[0];
    memmove(f->done, f->done + 1, (size_t)(f->ndone - 1) * sizeof f->done[0]);
    f->ndone--;
    f->state[i] = 3;
    b->index = (uint32_t)i;
    b->bytesused = f->bytesused[i];
    b->sequence = f->seq_of[i];
    b->flags = f->flags_of[i] | V4L2_BUF_FLAG_TIMESTAMP_MONOTONIC;
    b->timestamp.tv_sec = f->ts_of[i] / 1000000000;
    b->timestamp.tv_usec = (f->ts_of[i] % 1000000000) / 1000;
    return 0;
}

static int f_ioctl(void *ctx, int fd, unsigned long req, void *arg)
{
    fake_v4l2 *f = ctx;
    if (fd != FAKE_FD || !f->fd_open)
        return -EBADF;
    if (f->unbound)
        return -EINVAL; /* what vivid answers once unbound */
    int r = take_failure(f, req);
    if (r)
        return r;
    switch (req) {
    case VIDIOC_QUERYCAP: {
        struct v4l2_capability *c = arg;
        memset(c, 0, sizeof *c);
        c->capabilities = V4L2_CAP_VIDEO_CAPTURE | V4L2_CAP_STREAMING | V4L2_CAP_DEVICE_CAPS;
        c->device_caps = V4L2_CAP_VIDEO_CAPTURE | V4L2_CAP_STREAMING;
        return 0;
    }
    case VIDIOC_S_FMT:
        return do_s_fmt(f, arg);
    case VIDIOC_S_PARM:
        return do_parm(f, arg, 1);
    case VIDIOC_G_PARM:
        return do_parm(f, arg, 0);
    case VIDIOC_REQBUFS:
        return do_reqbufs(f, arg);
    case VIDIOC_QUERYBUF: {
        struct v4l2_buffer *b = arg;
        if (b->index >= (uint32_t)f->nbufs)
            return -EINVAL;
        b->length = (uint32_t)f->buflen;
        b->m.offset = b->index * 4096u;
        return 0;
    }
    case VIDIOC_QBUF:
        return do_qbuf(f, arg);
    case VIDIOC_DQBUF:
        return do_dqbuf(f, arg);
    case VIDIOC_STREAMON:
        f->streaming = 1;
        f->streamons++;
        return 0;
    case VIDIOC_STREAMOFF:
        f->streaming = 0;
        return 0;
    default:
        return -ENOTTY;
    }
}

static void *f_mmap(void *ctx, int fd, size_t len, off_t off, int *e)
{
    fake_v4l2 *f = ctx;
    int i = (int)(off / 4096);
    if (fd != FAKE_FD || i < 0 || i >= f->nbufs || len != f->buflen) {
        *e = EINVAL;
        return NULL;
    }
    return f->mem[i];
}

static int f_munmap(void *ctx, void *addr, size_t len)
{
    (void)ctx, (void)addr, (void)len;
    return 0;
}

static int f_poll(void *ctx, struct pollfd *fds, nfds_t n, int timeout_ms)
{
    fake_v4l2 *f = ctx;
    (void)n;
    fds[0].revents = 0;
    if (f->unbound) {
        fds[0].revents = POLLERR;
        return 1;
    }
    if (!f->ndone && f->auto_produce && !f->stall && f->streaming) {
        int64_t interval = 1000000000LL / (f->fps > 0 ? f->fps : 30);
        int64_t wait = interval - (f->ops.now_ns(f) % interval);
        if (wait > (int64_t)timeout_ms * 1000000) {
            f_sleep(f, (int64_t)timeout_ms * 1000000);
            return 0;
        }
        f_sleep(f, wait);
        fake_produce(f, 1);
    }
    if (!f->ndone) {
        f_sleep(f, (int64_t)timeout_ms * 1000000);
        return 0;
    }
    fds[0].revents = POLLIN;
    return 1;
}

static ssize_t f_write(void *ctx, int fd, const void *buf, size_t len)
{
    fake_v4l2 *f = ctx;
    if (fd != FAKE_FD || !f->fd_open)
        return -EBADF;
    int r = take_failure(f, 0);
    if (r)
        return r;
    f->writes++;
    f->written_bytes += len;
    uint8_t *p = realloc(f->last_write, len);
    if (p) {
        memcpy(p, buf, len);
        f->last_write = p;
        f->last_write_len = len;
    }
    return (ssize_t)len;
}

void fake_init(fake_v4l2 *f)
{
    memset(f, 0, sizeof *f);
    f->ops = (gs_cap_ops){f, f_open, f_close, f_ioctl, f_mmap, f_munmap,
                          f_poll, f_write, f_now, f_sleep};
    f->t_ns = 1000000000;
    f->present = 1;
    f->yuyv = f->mjpeg = 1;
    f->max_w = 1280;
    f->max_h = 720;
    f->max_fps = 30;
    f->fps = 30;
}

void fake_free(fake_v4l2 *f)
{
    free_bufs(f);
    free(f->last_write);
    f->last_write = NULL;
}
