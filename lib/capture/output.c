/* v4l2loopback output: YUYV frames written with write(). The format is set
 * with S_FMT on the OUTPUT type and read back; consumers (browsers) want
 * YUYV at an even width, so an odd-width frame loses its last column. */
#define _GNU_SOURCE
#include <errno.h>
#include <fcntl.h>
#include <linux/videodev2.h>
#include <stdlib.h>
#include <string.h>

#include "gazesplat/capture.h"

/* After a failed write the device is reopened no sooner than this. */
#define OUT_RETRY_NS 1000000000LL

struct gs_cap_out {
    char *path;
    const gs_cap_ops *ops;
    int fd;
    int width, height, fps;
    uint8_t *yuyv;
    size_t yuyv_cap;
    int64_t retry_ns;
};

static int out_ioctl(gs_cap_out *o, unsigned long req, void *arg)
{
    int r;
    do
        r = o->ops->ioctl(o->ops->ctx, o->fd, req, arg);
    while (r == -EINTR);
    return r;
}

static void out_close(gs_cap_out *o)
{
    if (o->fd >= 0)
        o->ops->close(o->ops->ctx, o->fd);
    o->fd = -1;
}

static int out_open(gs_cap_out *o, gs_error *err)
{
    int fd = o->ops->open(o->ops->ctx, o->path, O_RDWR);
    if (fd < 0)
        return gs_error_set(err, GS_ERR_IO, "%s: open: %s", o->path, strerror(-fd));
    o->fd = fd;
    struct v4l2_format f = {0};
    f.type = V4L2_BUF_TYPE_VIDEO_OUTPUT;
    f.fmt.pix.width = (uint32_t)o->width;
    f.fmt.pix.height = (uint32_t)o->height;
    f.fmt.pix.pixelformat = V4L2_PIX_FMT_YUYV;
    f.fmt.pix.field = V4L2_FIELD_NONE;
    f.fmt.pix.bytesperline = 2 * (uint32_t)o->width;
    f.fmt.pix.sizeimage = 2 * (uint32_t)o->width * (uint32_t)o->height;
    f.fmt.pix.colorspace = V4L2_COLORSPACE_SMPTE170M; /* BT.601 */
    int r = out_ioctl(o, VIDIOC_S_FMT, &f);
    if (r < 0) {
        out_close(o);
        return gs_error_set(err, GS_ERR_IO, "%s: VIDIOC_S_FMT (output): %s", o->path,
                            strerror(-r));
    }
    if (f.fmt.pix.pixelformat != V4L2_PIX_FMT_YUYV || f.fmt.pix.width != (uint32_t)o->width ||
        f.fmt.pix.height != (uint32_t)o->height) {
        out_close(o);
        return gs_error_set(err, GS_ERR_UNSUPPORTED, "%s: output refused YUYV %dx%d",
                            o->path, o->width, o->height);
    }
    if (o->fps > 0) { /* v4l2loopback advertises this rate to readers */
        struct v4l2_streamparm p = {0};
        p.type = V4L2_BUF_TYPE_VIDEO_OUTPUT;
        p.parm.output.timeperframe.numerator = 1;
        p.parm.output.timeperframe.denominator = (uint32_t)o->fps;
        out_ioctl(o, VIDIOC_S_PARM, &p);
    }
    return GS_OK;
}

static int out_size(gs_cap_out *o, int width, int height, gs_error *err)
{
    size_t need = 2 * (size_t)width * (size_t)height;
    if (need > o->yuyv_cap) {
        uint8_t *p = realloc(o->yuyv, need);
        if (!p)
            return gs_error_set(err, GS_ERR_NOMEM, "output: out of memory");
        o->yuyv = p;
        o->yuyv_cap = need;
    }
    o->width = width;
    o->height = height;
    return GS_OK;
}

int gs_cap_out_create(const char *path, int width, int height, int fps, const gs_cap_ops *ops,
                      gs_cap_out **out, gs_error *err)
{
    if (!path || !out)
        return gs_error_set(err, GS_ERR_ARG, "output: NULL argument");
    if (width < 2 || height < 1 || width > GS_CAP_MAX_SIDE || height > GS_CAP_MAX_SIDE ||
        (width & 1))
        return gs_error_set(err, GS_ERR_ARG, "output: size %dx%d (even width 2..%d)", width,
                            height, GS_CAP_MAX_SIDE);
    if (fps < 0 || fps > 1000)
        return gs_error_set(err, GS_ERR_ARG, "output: fps %d outside 0..1000", fps);
    gs_cap_out *o = calloc(1, sizeof *o);
    if (!o || !(o->path = strdup(path))) {
        free(o);
        return gs_error_set(err, GS_ERR_NOMEM, "output: out of memory");
    }
    o->ops = ops ? ops : gs_cap_ops_system();
    o->fd = -1;
    o->fps = fps;
    int r = out_size(o, width, height, err);
    if (r == GS_OK)
        r = out_open(o, err);
    if (r != GS_OK) {
        gs_cap_out_destroy(o);
        return r;
    }
    *out = o;
    return GS_OK;
}

void gs_cap_out_destroy(gs_cap_out *o)
{
    if (!o)
        return;
    out_close(o);
    free(o->yuyv);
    free(o->path);
    free(o);
}

int gs_cap_out_write(gs_cap_out *o, const uint8_t *rgb, size_t stride, int width, int height,
                     gs_error *err)
{
    if (!o || !rgb || width < 2 || height < 1 || stride < 3 * (size_t)width)
        return gs_error_set(err, GS_ERR_ARG, "output: bad frame");
    width &= ~1;
    int r;
    if (width != o->width || height != o->height) {
        out_close(o);
        if ((r = out_size(o, width, height, err)) != GS_OK)
            return r;
        o->retry_ns = 0;
    }
    if (o->fd < 0) {
        if (o->ops->now_ns(o->ops->ctx) < o->retry_ns)
            return gs_error_set(err, GS_ERR_IO, "%s: closed, reopening", o->path);
        if ((r = out_open(o, err)) != GS_OK) {
            o->retry_ns = o->ops->now_ns(o->ops->ctx) + OUT_RETRY_NS;
            return r;
        }
    }
    size_t len = 2 * (size_t)width * (size_t)height;
    gs_cap_rgb_to_yuyv(rgb, stride, width, height, o->yuyv, 2 * (size_t)width);
    ssize_t n;
    do
        n = o->ops->write(o->ops->ctx, o->fd, o->yuyv, len);
    while (n == -EINTR);
    if (n == (ssize_t)len)
        return GS_OK;
    out_close(o);
    o->retry_ns = o->ops->now_ns(o->ops->ctx) + OUT_RETRY_NS;
    if (n < 0)
        return gs_error_set(err, GS_ERR_IO, "%s: write: %s", o->path, strerror((int)-n));
    return gs_error_set(err, GS_ERR_IO, "%s: short write (%zd of %zu)", o->path, n, len);
}
