/* v4l2loopback output: YUYV frames written with write(). The format is set
 * once with S_FMT on the OUTPUT type and read back, and kept for the
 * writer's life (re-applied on every reopen): consumers (browsers) want
 * YUYV at an even width and a format that never changes under them. */
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
    uint8_t *scaled;       /* a frame of another size, letterboxed */
    size_t scaled_cap;
    uint8_t *placeholder;  /* the "no video" frame, drawn once */
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
    free(o->scaled);
    free(o->placeholder);
    free(o->path);
    free(o);
}

/* Nearest-neighbour letterbox of src into dst (w x h): the aspect ratio
 * kept, black bars. Camera frames of another size (a camera that came back
 * at another resolution) keep the loopback's format: readers that opened it
 * would otherwise see the stream break (v4l2loopback refuses S_FMT while
 * it is in use). */
static void letterbox(const uint8_t *src, size_t stride, int sw, int sh, uint8_t *dst, int w,
                      int h)
{
    double s = (double)w / sw < (double)h / sh ? (double)w / sw : (double)h / sh;
    int ow = (int)(sw * s), oh = (int)(sh * s);
    int x0 = (w - ow) / 2, y0 = (h - oh) / 2;
    memset(dst, 0, 3 * (size_t)w * (size_t)h);
    for (int y = 0; y < oh; y++) {
        int sy = (int)((y + 0.5) / s);
        sy = sy < sh ? sy : sh - 1;
        uint8_t *d = dst + ((size_t)(y0 + y) * (size_t)w + (size_t)x0) * 3;
        for (int x = 0; x < ow; x++) {
            int sx = (int)((x + 0.5) / s);
            sx = sx < sw ? sx : sw - 1;
            memcpy(d + 3 * (size_t)x, src + (size_t)sy * stride + 3 * (size_t)sx, 3);
        }
    }
}

int gs_cap_out_write(gs_cap_out *o, const uint8_t *rgb, size_t stride, int width, int height,
                     gs_error *err)
{
    if (!o || !rgb || width < 2 || height < 1 || stride < 3 * (size_t)width)
        return gs_error_set(err, GS_ERR_ARG, "output: bad frame");
    int r;
    if ((width & ~1) != o->width || height != o->height) {
        size_t need = 3 * (size_t)o->width * (size_t)o->height;
        if (need > o->scaled_cap) {
            uint8_t *p = realloc(o->scaled, need);
            if (!p)
                return gs_error_set(err, GS_ERR_NOMEM, "output: out of memory");
            o->scaled = p;
            o->scaled_cap = need;
        }
        letterbox(rgb, stride, width, height, o->scaled, o->width, o->height);
        rgb = o->scaled;
        stride = 3 * (size_t)o->width;
    }
    width = o->width;
    height = o->height;
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

void gs_cap_out_size(const gs_cap_out *o, int *width, int *height)
{
    *width = o->width;
    *height = o->height;
}

/* 5x7 glyphs, one byte per row (bit 4 = leftmost column). */
static const struct {
    char c;
    uint8_t rows[7];
} glyphs[] = {{'N', {0x11, 0x19, 0x15, 0x13, 0x11, 0x11, 0x11}},
              {'O', {0x0E, 0x11, 0x11, 0x11, 0x11, 0x11, 0x0E}},
              {'V', {0x11, 0x11, 0x11, 0x11, 0x11, 0x0A, 0x04}},
              {'I', {0x0E, 0x04, 0x04, 0x04, 0x04, 0x04, 0x0E}},
              {'D', {0x1E, 0x11, 0x11, 0x11, 0x11, 0x11, 0x1E}},
              {'E', {0x1F, 0x10, 0x10, 0x1E, 0x10, 0x10, 0x1F}},
              {' ', {0, 0, 0, 0, 0, 0, 0}}};

static const uint8_t *glyph(char c)
{
    for (size_t i = 0; i < sizeof glyphs / sizeof glyphs[0]; i++)
        if (glyphs[i].c == c)
            return glyphs[i].rows;
    return glyphs[sizeof glyphs / sizeof glyphs[0] - 1].rows;
}

void gs_cap_placeholder_rgb(uint8_t *rgb, size_t stride, int width, int height)
{
    static const char text[] = "NO VIDEO";
    int n = (int)sizeof text - 1;
    for (int y = 0; y < height; y++)
        memset(rgb + (size_t)y * stride, 32, 3 * (size_t)width);
    int cell = width / (6 * n + 4); /* glyph pixel size: the text spans most of the width */
    cell = cell < 1 ? 1 : cell;
    if (cell * 7 > height)
        return;
    int x0 = (width - cell * (6 * n - 1)) / 2, y0 = (height - 7 * cell) / 2;
    for (int i = 0; i < n; i++) {
        const uint8_t *g = glyph(text[i]);
        for (int r = 0; r < 7 * cell; r++)
            for (int c = 0; c < 5 * cell; c++) {
                if (!(g[r / cell] & (0x10 >> (c / cell))))
                    continue;
                int x = x0 + (6 * i) * cell + c, y = y0 + r;
                if (x >= 0 && x < width && y >= 0 && y < height)
                    memset(rgb + (size_t)y * stride + 3 * (size_t)x, 200, 3);
            }
    }
}

int gs_cap_out_write_placeholder(gs_cap_out *o, gs_error *err)
{
    if (!o)
        return gs_error_set(err, GS_ERR_ARG, "output: NULL argument");
    size_t need = 3 * (size_t)o->width * (size_t)o->height;
    if (!o->placeholder) {
        if (!(o->placeholder = malloc(need)))
            return gs_error_set(err, GS_ERR_NOMEM, "output: out of memory");
        gs_cap_placeholder_rgb(o->placeholder, 3 * (size_t)o->width, o->width, o->height);
    }
    return gs_cap_out_write(o, o->placeholder, 3 * (size_t)o->width, o->width, o->height, err);
}
