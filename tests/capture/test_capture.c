/* V4L2 capture and loopback output against the fake device and clock:
 * negotiation with a driver that adjusts, newest-frame semantics, bad and
 * missing frames, errors mid-stream with reopen, back-off and re-applied
 * format and rate, an unbound driver (EINVAL), kicks, MJPEG. */
#define _GNU_SOURCE
#include <errno.h>
#include <linux/videodev2.h>
#include <stdlib.h>
#include <string.h>

#include "fake_v4l2.h"
#include "gazesplat/image_io.h"
#include "gs_test.h"

static gs_cap *make(fake_v4l2 *f, int w, int h, int fps, gs_cap_pixfmt pf)
{
    gs_cap_config c = gs_cap_config_default("/dev/video7");
    c.width = w;
    c.height = h;
    c.fps = fps;
    c.pixfmt = pf;
    c.ops = &f->ops;
    gs_cap *cap = NULL;
    gs_error e = {0};
    int r = gs_cap_create(&c, &cap, &e);
    CHECK_MSG(r == GS_OK, "create: %s", e.msg);
    return cap;
}

static int grab(gs_cap *cap, gs_cap_frame *fr)
{
    gs_error e = {0};
    return gs_cap_grab(cap, fr, &e);
}

/* The driver clamps 1920x1080@60 to 1280x720@30: both read back. */
static void test_negotiation(void)
{
    fake_v4l2 f;
    fake_init(&f);
    f.auto_produce = 1;
    gs_cap *cap = make(&f, 1920, 1080, 60, GS_CAP_PIX_AUTO);
    gs_cap_frame fr;
    CHECK_EQ_INT(grab(cap, &fr), GS_OK);
    gs_cap_format fmt;
    CHECK_EQ_INT(gs_cap_get_format(cap, &fmt), GS_OK);
    CHECK_EQ_INT(f.req_w, 1920);
    CHECK_EQ_INT(f.req_fps, 60);
    CHECK_EQ_INT(fmt.width, 1280);
    CHECK_EQ_INT(fmt.height, 720);
    CHECK_EQ_INT(fmt.fps_num, 30);
    CHECK_EQ_INT(fmt.fps_den, 1);
    CHECK_EQ_INT(fmt.pixfmt, GS_CAP_PIX_YUYV);
    CHECK_EQ_INT(fmt.bytesperline, 2560);
    CHECK_EQ_INT(fmt.nbuffers, 4);
    CHECK_EQ_INT(fr.width, 1280);
    CHECK_EQ_INT(fr.stride, 3840);
    gs_cap_destroy(cap);
    fake_free(&f);

    /* No YUYV: AUTO settles on MJPEG; no S_PARM: rate unknown. */
    fake_init(&f);
    f.yuyv = 0;
    f.max_fps = 0;
    cap = make(&f, 640, 480, 30, GS_CAP_PIX_AUTO);
    f.auto_produce = 1;
    static const uint8_t jpeg_stub[256] = {0xFF, 0xD8};
    f.mjpeg_data = jpeg_stub;
    f.mjpeg_len = sizeof jpeg_stub;
    grab(cap, &fr); /* the stub has no EOI: dropped, times out */
    CHECK_EQ_INT(gs_cap_get_format(cap, &fmt), GS_OK);
    CHECK_EQ_INT(fmt.pixfmt, GS_CAP_PIX_MJPEG);
    CHECK_EQ_INT(fmt.fps_num, 0);
    gs_cap_destroy(cap);
    fake_free(&f);

    /* YUYV demanded of an MJPEG-only camera: refused, not mistaken. */
    fake_init(&f);
    f.yuyv = 0;
    cap = make(&f, 640, 480, 30, GS_CAP_PIX_YUYV);
    gs_error e = {0};
    CHECK_EQ_INT(gs_cap_grab(cap, &fr, &e), GS_ERR_UNSUPPORTED);
    CHECK(strstr(e.msg, "YUYV") != NULL);
    CHECK_EQ_INT(f.fd_open, 0);
    gs_cap_destroy(cap);
    fake_free(&f);
}

/* Three frames waiting: the newest is delivered, two counted stale, every
 * buffer is back with the driver. */
static void test_newest(void)
{
    fake_v4l2 f;
    fake_init(&f);
    f.auto_produce = 1;
    gs_cap *cap = make(&f, 64, 48, 30, GS_CAP_PIX_YUYV);
    gs_cap_frame fr;
    CHECK_EQ_INT(grab(cap, &fr), GS_OK);
    CHECK_EQ_INT(fr.sequence, 0);
    f.auto_produce = 0;
    CHECK_EQ_INT(fake_produce(&f, 3), 3);
    CHECK_EQ_INT(grab(cap, &fr), GS_OK);
    CHECK_EQ_INT(fr.sequence, 3);
    CHECK_EQ_INT(fr.skipped, 2);
    CHECK_EQ_INT(f.nqueued, f.nbufs);
    /* YUYV Y=v, U=V=128 is grey 1.164 (v - 16). */
    int want = (int)(1.164383 * (fake_luma_of(3) - 16) + 0.5);
    CHECK_MSG(abs(fr.rgb[0] - want) <= 1 && fr.rgb[0] == fr.rgb[1] && fr.rgb[1] == fr.rgb[2],
              "pixel %d,%d,%d want grey %d", fr.rgb[0], fr.rgb[1], fr.rgb[2], want);
    gs_cap_stats s;
    gs_cap_get_stats(cap, &s);
    CHECK_EQ_INT(s.stale, 2);
    CHECK_EQ_INT(s.frames, 2);

    /* A bad newest frame: the good older one wins. A sequence jump counts. */
    f.seq_skip = 5;
    fake_produce(&f, 1);
    f.next_bad = 1;
    fake_produce(&f, 1);
    CHECK_EQ_INT(grab(cap, &fr), GS_OK);
    CHECK_EQ_INT(fr.sequence, 9);
    CHECK_EQ_INT(fr.skipped, 6);
    gs_cap_get_stats(cap, &s);
    CHECK_EQ_INT(s.bad, 1);
    CHECK_EQ_INT(s.gaps, 5);
    CHECK_EQ_INT(f.nqueued, f.nbufs);
    /* Capture time is the driver's timestamp. */
    CHECK(fr.t_capture_ns <= fr.t_dequeue_ns);
    gs_cap_destroy(cap);
    fake_free(&f);
}

/* DQBUF fails mid-stream: closed, reopened after the back-off with format
 * and rate applied again; a device reset to 5 fps comes back at 30. */
static void test_reopen(void)
{
    fake_v4l2 f;
    fake_init(&f);
    f.auto_produce = 1;
    gs_cap *cap = make(&f, 640, 480, 30, GS_CAP_PIX_YUYV);
    gs_cap_frame fr;
    CHECK_EQ_INT(grab(cap, &fr), GS_OK);
    fake_fail(&f, VIDIOC_DQBUF, EIO, 0);
    gs_error e = {0};
    CHECK_EQ_INT(gs_cap_grab(cap, &fr, &e), GS_ERR_IO);
    CHECK(strstr(e.msg, "DQBUF") != NULL);
    CHECK_EQ_INT(f.fd_open, 0);
    CHECK(!gs_cap_is_open(cap));
    f.fps = 5; /* what a rebound driver starts with */
    int64_t t_lost = f.t_ns;
    CHECK_EQ_INT(grab(cap, &fr), GS_OK);
    CHECK_EQ_INT(f.opens, 2);
    CHECK_EQ_INT(f.s_fmt_calls, 2);
    CHECK_EQ_INT(f.s_parm_calls, 2);
    CHECK_EQ_INT(f.fps, 30);
    CHECK_EQ_INT(f.req_w, 640);
    CHECK_EQ_INT(f.streamons, 2);
    int64_t waited = f.open_t[1] - t_lost;
    CHECK_MSG(waited >= 100000000 && waited < 120000000, "reopened after %lld ns",
              (long long)waited);
    /* The driver's share of the recovery: from the open to the first frame,
     * which the fake delivers at its next 1/30 s tick. */
    gs_cap_stats st;
    gs_cap_get_stats(cap, &st);
    CHECK_EQ_INT((long long)st.first_frame_ns, (long long)(f.t_ns - f.open_t[1]));
    CHECK(st.first_frame_ns > 0 && st.first_frame_ns <= 1000000000 / 30 + 1);

    /* Unbound driver: EINVAL on every ioctl, not ENODEV. */
    f.unbound = 1;
    CHECK_EQ_INT(gs_cap_grab(cap, &fr, &e), GS_ERR_IO);
    CHECK_EQ_INT(f.fd_open, 0);
    CHECK_EQ_INT(grab(cap, &fr), GS_OK);
    CHECK_EQ_INT(f.opens, 3);

    /* A stalled stream times out after timeout_ms and is reopened. */
    f.stall = 1;
    int64_t t0 = f.t_ns;
    CHECK_EQ_INT(gs_cap_grab(cap, &fr, &e), GS_ERR_IO);
    CHECK(strstr(e.msg, "no frame") != NULL);
    CHECK_MSG(f.t_ns - t0 >= 1000000000, "gave up after %lld ns", (long long)(f.t_ns - t0));
    f.stall = 0;
    CHECK_EQ_INT(grab(cap, &fr), GS_OK);
    CHECK_EQ_INT(f.opens, 4);

    /* A vanished node: open attempts back off 100, 200, 400, 800, 1000 ms. */
    f.present = 0;
    f.unbound = 1;
    CHECK_EQ_INT(gs_cap_grab(cap, &fr, &e), GS_ERR_IO);
    int first = f.open_attempts;
    int64_t prev = f.t_ns;
    for (int i = 0; i < 12; i++)
        gs_cap_grab(cap, &fr, &e);
    static const int want_ms[] = {100, 200, 400, 800, 1000, 1000};
    for (int i = 0; i < 6 && first + i < f.open_attempts; i++) {
        int64_t d = f.open_t[first + i] - prev;
        prev = f.open_t[first + i];
        CHECK_MSG(d >= (int64_t)want_ms[i] * 1000000 && d < (int64_t)want_ms[i] * 1000000 + 20000000,
                  "attempt %d after %lld ms, want %d", i, (long long)(d / 1000000), want_ms[i]);
    }
    CHECK(f.open_attempts >= first + 6);

    /* Re-plugged: a kick skips the back-off. */
    f.present = 1;
    gs_cap_kick(cap);
    int64_t tk = f.t_ns;
    CHECK_EQ_INT(grab(cap, &fr), GS_OK);
    int64_t d = f.open_t[f.open_attempts - 1] - tk;
    CHECK_MSG(d < 20000000, "kick opened after %lld ns", (long long)d);
    gs_cap_stats s;
    gs_cap_get_stats(cap, &s);
    CHECK_EQ_INT(s.opens, 5);
    gs_cap_destroy(cap);
    fake_free(&f);
}

/* A real JPEG decodes; the same without its EOI marker is dropped. */
static void test_mjpeg(void)
{
    enum { W = 64, H = 48 };
    gs_io_image img = {W, H, 3 * W, malloc(3 * W * H)};
    for (int i = 0; i < 3 * W * H; i++)
        img.data[i] = (uint8_t)(i % 3 == 0 ? 200 : i % 3 == 1 ? 60 : 30);
    void *jpg = NULL;
    size_t len = 0;
    CHECK_EQ_INT(gs_io_image_encode(&img, GS_IO_JPEG, 95, &jpg, &len, NULL), GS_OK);
    fake_v4l2 f;
    fake_init(&f);
    f.yuyv = 0;
    f.auto_produce = 1;
    f.mjpeg_data = jpg;
    f.mjpeg_len = len;
    gs_cap *cap = make(&f, W, H, 30, GS_CAP_PIX_MJPEG);
    gs_cap_frame fr;
    CHECK_EQ_INT(grab(cap, &fr), GS_OK);
    int worst = 0;
    for (int i = 0; i < 3 * W * H; i++)
        worst = abs(fr.rgb[i] - img.data[i]) > worst ? abs(fr.rgb[i] - img.data[i]) : worst;
    CHECK_MSG(worst <= 6, "decoded MJPEG differs by %d", worst);
    f.mjpeg_len = len - 2; /* cut FFD9 */
    gs_error e = {0};
    CHECK_EQ_INT(gs_cap_grab(cap, &fr, &e), GS_ERR_IO);
    gs_cap_stats s;
    gs_cap_get_stats(cap, &s);
    CHECK_MSG(s.bad >= 20, "%llu frames without EOI dropped", (unsigned long long)s.bad);
    CHECK_EQ_INT(s.frames, 1);
    gs_cap_destroy(cap);
    fake_free(&f);
    free(jpg);
    free(img.data);
}

static void test_config(void)
{
    gs_cap_config c = gs_cap_config_default("/dev/video0");
    gs_cap *cap = NULL;
    c.width = 0;
    CHECK_EQ_INT(gs_cap_create(&c, &cap, NULL), GS_ERR_ARG);
    c = gs_cap_config_default("/dev/video0");
    c.nbuffers = 1;
    CHECK_EQ_INT(gs_cap_create(&c, &cap, NULL), GS_ERR_ARG);
    c = gs_cap_config_default(NULL);
    CHECK_EQ_INT(gs_cap_create(&c, &cap, NULL), GS_ERR_ARG);
    CHECK(cap == NULL);
}

/* Loopback output: even widths only, S_FMT on the OUTPUT type, YUYV bytes
 * written, a failed write reopens after a second. */
static void test_output(void)
{
    fake_v4l2 f;
    fake_init(&f);
    gs_cap_out *o = NULL;
    CHECK_EQ_INT(gs_cap_out_create("/dev/video9", 63, 48, 30, &f.ops, &o, NULL), GS_ERR_ARG);
    CHECK_EQ_INT(gs_cap_out_create("/dev/video9", 64, 48, 30, &f.ops, &o, NULL), GS_OK);
    CHECK_EQ_INT(f.out_type_set, 1);
    uint8_t rgb[64 * 48 * 3], want[64 * 48 * 2];
    for (size_t i = 0; i < sizeof rgb; i++)
        rgb[i] = (uint8_t)(i * 7);
    gs_cap_rgb_to_yuyv(rgb, 192, 64, 48, want, 128);
    CHECK_EQ_INT(gs_cap_out_write(o, rgb, 192, 64, 48, NULL), GS_OK);
    CHECK_EQ_INT(f.last_write_len, sizeof want);
    CHECK(f.last_write && memcmp(f.last_write, want, sizeof want) == 0);
    fake_fail(&f, 0, EIO, 0);
    gs_error e = {0};
    CHECK_EQ_INT(gs_cap_out_write(o, rgb, 192, 64, 48, &e), GS_ERR_IO);
    CHECK_EQ_INT(f.fd_open, 0);
    CHECK_EQ_INT(gs_cap_out_write(o, rgb, 192, 64, 48, &e), GS_ERR_IO);
    f.t_ns += 1000000000;
    CHECK_EQ_INT(gs_cap_out_write(o, rgb, 192, 64, 48, &e), GS_OK);
    CHECK_EQ_INT(f.opens, 2);
    /* Frames of another size keep the format: letterboxed, never renegotiated. */
    int sfmt = f.s_fmt_calls;
    CHECK_EQ_INT(gs_cap_out_write(o, rgb, 192, 63, 48, &e), GS_OK);
    CHECK_EQ_INT(gs_cap_out_write(o, rgb, 96, 32, 16, &e), GS_OK);
    CHECK_EQ_INT(f.s_fmt_calls, sfmt);
    CHECK_EQ_INT(f.w, 64);
    CHECK_EQ_INT(f.last_write_len, 64 * 48 * 2);
    /* 32x16 into 64x48: scale 2, rows 8..39 carry the picture, bars are black
     * (Y 16 in limited range). */
    CHECK_EQ_INT(f.last_write[0], 16);
    CHECK_EQ_INT(f.last_write[(size_t)47 * 128], 16);
    CHECK(f.last_write[(size_t)20 * 128 + 2 * 4] != 16 || f.last_write[(size_t)20 * 128 + 2 * 5] != 16);
    /* The placeholder: the same format, text brighter than the background. */
    CHECK_EQ_INT(gs_cap_out_write_placeholder(o, &e), GS_OK);
    CHECK_EQ_INT(f.last_write_len, 64 * 48 * 2);
    int lo = 255, hi = 0;
    for (size_t i = 0; i < 64 * 48 * 2; i += 2) {
        lo = f.last_write[i] < lo ? f.last_write[i] : lo;
        hi = f.last_write[i] > hi ? f.last_write[i] : hi;
    }
    CHECK_MSG(lo < 60 && hi > 150, "placeholder luma %d..%d", lo, hi);
    CHECK_EQ_INT(f.s_fmt_calls, sfmt);
    gs_cap_out_destroy(o);
    fake_free(&f);
}

int main(void)
{
    test_config();
    test_negotiation();
    test_newest();
    test_reopen();
    test_mjpeg();
    test_output();
    GS_TEST_END();
}
