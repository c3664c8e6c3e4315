/* The real gazesplatd over a real Unix socket: HELLO and version
 * negotiation, limits before and after HELLO, and a malformed-frame suite
 * in which every case gets its ERROR code (and a close when the error is
 * a protocol error) and the server still answers other clients.
 * usage: test_daemon_protocol PATH_TO_GAZESPLATD */
#define _GNU_SOURCE
#include <math.h>

#include "daemon_harness.h"

static const char *bin;
static daemon_proc d;

static size_t pack(uint8_t *buf, uint16_t type, uint32_t id, const uint8_t *key, const ProtobufCMessage *m)
{
    gs_frame_header h;
    memset(&h, 0, sizeof h);
    h.version = 1;
    h.type = type;
    h.request_id = id;
    if (key)
        memcpy(h.key, key, 16);
    uint8_t *out;
    size_t len;
    if (gs_msg_pack(&h, m, 1u << 26, &out, &len) != 0)
        return 0;
    memcpy(buf, out, len);
    free(out);
    return len;
}

/* ---- case builders: each writes the bytes to send into buf ------------ */
typedef size_t (*build_fn)(uint8_t *buf);

static size_t b_magic(uint8_t *b) { h_frame(b, 1, T(HEALTH), 0, 1); b[0] = 'X'; return 32; }
static size_t b_magic_zero(uint8_t *b) { memset(b, 0, 32); return 32; }
static size_t b_http(uint8_t *b)
{
    const char *s = "GET / HTTP/1.1\r\nHost: x\r\n\r\n";
    memcpy(b, s, strlen(s));
    return strlen(s) < 32 ? 32 : strlen(s);
}
static size_t b_ver0(uint8_t *b) { return h_frame(b, 0, T(HELLO), 0, 1); }
static size_t b_ver2(uint8_t *b) { return h_frame(b, 2, T(HELLO), 0, 1); }
static size_t b_verff(uint8_t *b) { return h_frame(b, 0xffff, T(HELLO), 0, 1); }
static size_t b_type0(uint8_t *b) { return h_frame(b, 1, 0, 0, 1); }
static size_t b_type999(uint8_t *b) { return h_frame(b, 1, 999, 0, 1); }
static size_t b_type_reply(uint8_t *b) { return h_frame(b, 1, T(HELLO_OK), 0, 1); }
static size_t b_type_error(uint8_t *b) { return h_frame(b, 1, T(ERROR), 0, 1); }
static size_t b_type_image(uint8_t *b) { return h_frame(b, 1, T(IMAGE), 0, 1); }
static size_t b_pre_big(uint8_t *b) { return h_frame(b, 1, T(HELLO), GS_FRAME_MAX_PAYLOAD_PREHELLO + 1, 1); }
static size_t b_pre_huge(uint8_t *b) { return h_frame(b, 1, T(HELLO), 0xffffffffu, 1); }
static size_t b_pre_health(uint8_t *b) { return h_frame(b, 1, T(HEALTH), 0, 1); }
static size_t b_pre_stats(uint8_t *b) { return h_frame(b, 1, T(STATS), 0, 1); }
static size_t b_pre_fit(uint8_t *b) { return h_frame(b, 1, T(FIT), 0, 1); }
static size_t b_pre_cancel(uint8_t *b) { return h_frame(b, 1, T(CANCEL), 0, 1); }
static size_t b_hello_garbage(uint8_t *b)
{
    h_frame(b, 1, T(HELLO), 5, 1);
    memcpy(b + 32, "\xff\xff\xff\xff\xff", 5);
    return 37;
}
static size_t hello_v(uint8_t *b, uint32_t lo, uint32_t hi)
{
    Gazesplat__Hello m = GAZESPLAT__HELLO__INIT;
    m.min_version = lo;
    m.max_version = hi;
    return pack(b, T(HELLO), 1, NULL, &m.base);
}
static size_t b_hello_empty(uint8_t *b) { return h_frame(b, 1, T(HELLO), 0, 1); }
static size_t b_hello_inverted(uint8_t *b) { return hello_v(b, 3, 1); }
static size_t b_hello_future(uint8_t *b) { return hello_v(b, 2, 5); }
/* After HELLO. */
static size_t b_post_big(uint8_t *b) { return h_frame(b, 1, T(FIT), (1u << 20) + 1, 1); }
static size_t b_post_huge(uint8_t *b) { return h_frame(b, 1, T(REDIRECT), 0xffffffffu, 1); }
static size_t b_second_hello(uint8_t *b) { return hello_v(b, 1, 1); }
static size_t b_post_ver2(uint8_t *b) { return h_frame(b, 2, T(HEALTH), 0, 1); }
static size_t b_post_magic(uint8_t *b) { h_frame(b, 1, T(HEALTH), 0, 1); memcpy(b, "GAZF", 4); return 32; }
static size_t b_post_type(uint8_t *b) { return h_frame(b, 1, 77, 0, 1); }
static size_t b_post_done(uint8_t *b) { return h_frame(b, 1, T(DONE), 0, 1); }
static size_t garbage(uint8_t *b, uint16_t type, const char *bytes, size_t n)
{
    h_frame(b, 1, type, (uint32_t)n, 9);
    memcpy(b + 32, bytes, n);
    return 32 + n;
}
static size_t b_fit_garbage(uint8_t *b) { return garbage(b, T(FIT), "\xff\xff\xff\xff\xff\xff", 6); }
static size_t b_redirect_garbage(uint8_t *b) { return garbage(b, T(REDIRECT), "\x12\x7f\x01", 3); }
/* Field 1 (image, a message) sent as a varint. */
static size_t b_fit_wiretype(uint8_t *b) { return garbage(b, T(FIT), "\x08\x05", 2); }
/* A length-delimited field claiming more bytes than the payload holds. */
static size_t b_fit_truncated(uint8_t *b) { return garbage(b, T(FIT), "\x0a\x40\x08\x01", 4); }
static size_t b_cancel_garbage(uint8_t *b) { return garbage(b, T(CANCEL), "\x08", 1); }
static size_t b_stats_garbage(uint8_t *b) { return garbage(b, T(STATS), "\x0b", 1); }

static uint8_t pixels[64 * 64 * 3];

static size_t fit_with(uint8_t *b, const Gazesplat__Image *img, const Gazesplat__Angles *gaze,
                       const Gazesplat__Angles *head, uint32_t deadline)
{
    Gazesplat__FitRequest m = GAZESPLAT__FIT_REQUEST__INIT;
    m.image = (Gazesplat__Image *)img;
    m.gaze = (Gazesplat__Angles *)gaze;
    m.head = (Gazesplat__Angles *)head;
    m.deadline_ms = deadline;
    return pack(b, T(FIT), 9, NULL, &m.base);
}
static Gazesplat__Image raw_image(uint32_t w, uint32_t h, uint32_t stride, size_t len)
{
    Gazesplat__Image img = GAZESPLAT__IMAGE__INIT;
    img.format = GAZESPLAT__IMAGE_FORMAT__FORMAT_RAW_RGB8;
    img.width = w;
    img.height = h;
    img.stride = stride;
    img.data.data = pixels;
    img.data.len = len;
    return img;
}
static size_t b_fit_noimage(uint8_t *b) { return fit_with(b, NULL, NULL, NULL, 0); }
static size_t b_fit_nan(uint8_t *b)
{
    Gazesplat__Image img = raw_image(8, 8, 24, 192);
    Gazesplat__Angles g = GAZESPLAT__ANGLES__INIT;
    g.pitch_deg = NAN;
    return fit_with(b, &img, &g, NULL, 0);
}
static size_t b_fit_inf_head(uint8_t *b)
{
    Gazesplat__Image img = raw_image(8, 8, 24, 192);
    Gazesplat__Angles h = GAZESPLAT__ANGLES__INIT;
    h.yaw_deg = -INFINITY;
    return fit_with(b, &img, NULL, &h, 0);
}
static size_t b_fit_range(uint8_t *b)
{
    Gazesplat__Image img = raw_image(8, 8, 24, 192);
    Gazesplat__Angles g = GAZESPLAT__ANGLES__INIT;
    g.pitch_deg = 80;
    return fit_with(b, &img, &g, NULL, 0);
}
static size_t b_fit_photo(uint8_t *b)
{
    Gazesplat__Image img = raw_image(8, 8, 24, 192);
    img.kind = GAZESPLAT__IMAGE_KIND__KIND_PHOTO;
    return fit_with(b, &img, NULL, NULL, 0);
}
static size_t b_fit_kind(uint8_t *b)
{
    Gazesplat__Image img = raw_image(8, 8, 24, 192);
    img.kind = (Gazesplat__ImageKind)9;
    return fit_with(b, &img, NULL, NULL, 0);
}
static size_t b_fit_stride(uint8_t *b) { Gazesplat__Image i = raw_image(8, 8, 20, 192); return fit_with(b, &i, NULL, NULL, 0); }
static size_t b_fit_short(uint8_t *b) { Gazesplat__Image i = raw_image(8, 8, 24, 191); return fit_with(b, &i, NULL, NULL, 0); }
static size_t b_fit_zero_w(uint8_t *b) { Gazesplat__Image i = raw_image(0, 8, 24, 192); return fit_with(b, &i, NULL, NULL, 0); }
static size_t b_fit_giant(uint8_t *b) { Gazesplat__Image i = raw_image(100000, 100000, 300000, 192); return fit_with(b, &i, NULL, NULL, 0); }
static size_t b_fit_mpix(uint8_t *b) { Gazesplat__Image i = raw_image(4096, 4096, 12288, 192); return fit_with(b, &i, NULL, NULL, 0); }
static size_t b_fit_format(uint8_t *b)
{
    Gazesplat__Image i = raw_image(8, 8, 24, 192);
    i.format = (Gazesplat__ImageFormat)7;
    return fit_with(b, &i, NULL, NULL, 0);
}
static size_t b_fit_empty(uint8_t *b)
{
    Gazesplat__Image i = GAZESPLAT__IMAGE__INIT;
    i.format = GAZESPLAT__IMAGE_FORMAT__FORMAT_PNG;
    return fit_with(b, &i, NULL, NULL, 0);
}
/* Decompression bombs: files whose headers declare more pixels than the
 * limits (here 8 Mi pixels, 4096 per side); refused from the header. */
static uint8_t bomb[64];
static void put_be(uint8_t *p, uint32_t v, int n)
{
    for (int i = 0; i < n; i++)
        p[i] = (uint8_t)(v >> (8 * (n - 1 - i)));
}
static Gazesplat__Image png_bomb(uint32_t w, uint32_t h)
{
    static const uint8_t head[] = {0x89, 'P', 'N', 'G', '\r', '\n', 0x1a, '\n', 0, 0, 0, 13, 'I', 'H', 'D', 'R'};
    memset(bomb, 0, sizeof bomb);
    memcpy(bomb, head, sizeof head);
    put_be(bomb + 16, w, 4);
    put_be(bomb + 20, h, 4);
    bomb[24] = 8; /* 8-bit RGB */
    bomb[25] = 2;
    Gazesplat__Image img = GAZESPLAT__IMAGE__INIT;
    img.format = GAZESPLAT__IMAGE_FORMAT__FORMAT_PNG;
    img.data.data = bomb;
    img.data.len = 33;
    return img;
}
/* SOI, an APP0 segment to walk over, then SOFn declaring w x h. */
static Gazesplat__Image jpeg_bomb(uint8_t sof, uint32_t w, uint32_t h)
{
    static const uint8_t head[] = {0xff, 0xd8, 0xff, 0xe0, 0, 6, 'J', 'F', 'I', 'F'};
    memset(bomb, 0, sizeof bomb);
    memcpy(bomb, head, sizeof head);
    uint8_t *f = bomb + sizeof head;
    f[0] = 0xff;
    f[1] = sof;
    put_be(f + 2, 17, 2);
    f[4] = 8;
    put_be(f + 5, h, 2);
    put_be(f + 7, w, 2);
    f[9] = 3;
    Gazesplat__Image img = GAZESPLAT__IMAGE__INIT;
    img.format = GAZESPLAT__IMAGE_FORMAT__FORMAT_JPEG;
    img.data.data = bomb;
    img.data.len = sizeof head + 19;
    return img;
}
static size_t b_png_bomb(uint8_t *b) { Gazesplat__Image i = png_bomb(100000, 100000); return fit_with(b, &i, NULL, NULL, 0); }
static size_t b_png_mpix(uint8_t *b) { Gazesplat__Image i = png_bomb(4096, 4096); return fit_with(b, &i, NULL, NULL, 0); }
static size_t b_png_side(uint8_t *b) { Gazesplat__Image i = png_bomb(8000, 16); return fit_with(b, &i, NULL, NULL, 0); }
static size_t b_jpeg_bomb(uint8_t *b) { Gazesplat__Image i = jpeg_bomb(0xc0, 65500, 65500); return fit_with(b, &i, NULL, NULL, 0); }
static size_t b_jpeg_prog(uint8_t *b) { Gazesplat__Image i = jpeg_bomb(0xc2, 4000, 4000); return fit_with(b, &i, NULL, NULL, 0); }
/* A JPEG sent as FORMAT_PNG: the data's own signature is what counts. */
static size_t b_jpeg_as_png(uint8_t *b)
{
    Gazesplat__Image i = jpeg_bomb(0xc1, 30000, 30000);
    i.format = GAZESPLAT__IMAGE_FORMAT__FORMAT_PNG;
    return fit_with(b, &i, NULL, NULL, 0);
}
static size_t b_fit_intrinsics(uint8_t *b)
{
    Gazesplat__Image img = raw_image(8, 8, 24, 192);
    Gazesplat__Intrinsics k = GAZESPLAT__INTRINSICS__INIT;
    k.fx = 0;
    k.fy = 500;
    Gazesplat__FitRequest m = GAZESPLAT__FIT_REQUEST__INIT;
    m.image = &img;
    m.intrinsics = &k;
    return pack(b, T(FIT), 9, NULL, &m.base);
}
static size_t b_fit_iters(uint8_t *b)
{
    Gazesplat__Image img = raw_image(8, 8, 24, 192);
    Gazesplat__FitRequest m = GAZESPLAT__FIT_REQUEST__INIT;
    m.image = &img;
    m.max_iters = 100001;
    return pack(b, T(FIT), 9, NULL, &m.base);
}
static size_t b_fit_deadline(uint8_t *b) { Gazesplat__Image i = raw_image(8, 8, 24, 192); return fit_with(b, &i, NULL, NULL, 4000000); }
static size_t b_fit_nomodel(uint8_t *b) { Gazesplat__Image i = raw_image(8, 8, 24, 192); return fit_with(b, &i, NULL, NULL, 0); }

static const uint8_t subject[16] = {1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15, 16};

static size_t redirect_with(uint8_t *b, int n, double pitch, int no_gaze, const uint8_t *key,
                            void (*tweak)(Gazesplat__RedirectRequest *))
{
    static Gazesplat__Angles g[200];
    static Gazesplat__Target t[200];
    static Gazesplat__Target *tp[200];
    for (int i = 0; i < n; i++) {
        gazesplat__angles__init(&g[i]);
        g[i].pitch_deg = pitch;
        gazesplat__target__init(&t[i]);
        t[i].gaze = no_gaze ? NULL : &g[i];
        tp[i] = &t[i];
    }
    Gazesplat__RedirectRequest m = GAZESPLAT__REDIRECT_REQUEST__INIT;
    m.n_targets = (size_t)n;
    m.targets = tp;
    if (tweak)
        tweak(&m);
    return pack(b, T(REDIRECT), 9, key, &m.base);
}
static void t_paste(Gazesplat__RedirectRequest *m) { m->output_mode = GAZESPLAT__OUTPUT_MODE__OUTPUT_PASTE_BACK; }
static void t_quality(Gazesplat__RedirectRequest *m) { m->jpeg_quality = 101; }
static void t_format(Gazesplat__RedirectRequest *m) { m->output_format = (Gazesplat__ImageFormat)12; }
static void t_deadline(Gazesplat__RedirectRequest *m) { m->deadline_ms = 700000; }
static size_t b_redir_zero(uint8_t *b) { return redirect_with(b, 0, 0, 0, subject, NULL); }
static size_t b_redir_many(uint8_t *b) { return redirect_with(b, 65, 0, 0, subject, NULL); }
static size_t b_redir_nan(uint8_t *b) { return redirect_with(b, 3, NAN, 0, subject, NULL); }
static size_t b_redir_range(uint8_t *b) { return redirect_with(b, 1, -51, 0, subject, NULL); }
static size_t b_redir_nogaze(uint8_t *b) { return redirect_with(b, 1, 0, 1, subject, NULL); }
static size_t b_redir_nokey(uint8_t *b) { return redirect_with(b, 1, 0, 0, NULL, NULL); }
static size_t b_redir_paste(uint8_t *b) { return redirect_with(b, 1, 0, 0, subject, t_paste); }
static size_t b_redir_quality(uint8_t *b) { return redirect_with(b, 1, 0, 0, subject, t_quality); }
static size_t b_redir_format(uint8_t *b) { return redirect_with(b, 1, 0, 0, subject, t_format); }
static size_t b_redir_deadline(uint8_t *b) { return redirect_with(b, 1, 0, 0, subject, t_deadline); }
static void t_bomb(Gazesplat__RedirectRequest *m)
{
    static Gazesplat__Image img;
    img = png_bomb(70000, 3);
    m->image = &img;
}
static void t_mode(Gazesplat__RedirectRequest *m) { m->output_mode = (Gazesplat__OutputMode)5; }
static void t_nan_head(Gazesplat__RedirectRequest *m)
{
    static Gazesplat__Angles head = GAZESPLAT__ANGLES__INIT;
    head.pitch_deg = NAN;
    m->targets[m->n_targets - 1]->head = &head;
}
static size_t b_redir_bomb(uint8_t *b) { return redirect_with(b, 1, 0, 0, NULL, t_bomb); }
static size_t b_redir_mode(uint8_t *b) { return redirect_with(b, 1, 0, 0, subject, t_mode); }
static size_t b_redir_nan_head(uint8_t *b) { return redirect_with(b, 3, 5, 0, subject, t_nan_head); }
static size_t b_redir_nomodel(uint8_t *b) { return redirect_with(b, 2, 10, 0, subject, NULL); }
/* The target table's limits are inclusive: a head of exactly (70, -70)
 * and a gaze of exactly (50, 60) on every target pass validation (the
 * model-less server then answers ERR_NO_MODEL); 70.0000001 on the 6th
 * target is refused up front. */
static void t_heads(Gazesplat__RedirectRequest *m, double last_yaw)
{
    static Gazesplat__Angles head[6];
    for (size_t i = 0; i < m->n_targets && i < 6; i++) {
        gazesplat__angles__init(&head[i]);
        head[i].pitch_deg = i % 2 ? -70 : 70;
        head[i].yaw_deg = i + 1 == m->n_targets ? last_yaw : -70;
        m->targets[i]->gaze->yaw_deg = i % 2 ? -60 : 60;
        m->targets[i]->head = &head[i];
    }
}
static void t_heads_at_limit(Gazesplat__RedirectRequest *m) { t_heads(m, 70); }
static void t_heads_past_limit(Gazesplat__RedirectRequest *m) { t_heads(m, 70.0000001); }
static size_t b_redir_limits(uint8_t *b) { return redirect_with(b, 6, 50, 0, subject, t_heads_at_limit); }
static size_t b_redir_past(uint8_t *b) { return redirect_with(b, 6, -50, 0, subject, t_heads_past_limit); }
static size_t b_sleep_long(uint8_t *b)
{
    Gazesplat__Sleep m = GAZESPLAT__SLEEP__INIT;
    m.ms = 600000;
    return pack(b, T(SLEEP), 9, NULL, &m.base);
}

typedef struct mcase {
    const char *name;
    int prehello;
    build_fn build;
    int code;
    int fatal;
} mcase;

static const mcase cases[] = {
    {"bad magic", 1, b_magic, E(ERR_BAD_MAGIC), 1},
    {"zero header", 1, b_magic_zero, E(ERR_BAD_MAGIC), 1},
    {"HTTP request", 1, b_http, E(ERR_BAD_MAGIC), 1},
    {"version 0", 1, b_ver0, E(ERR_BAD_VERSION), 1},
    {"version 2", 1, b_ver2, E(ERR_BAD_VERSION), 1},
    {"version 0xffff", 1, b_verff, E(ERR_BAD_VERSION), 1},
    {"type 0", 1, b_type0, E(ERR_BAD_TYPE), 1},
    {"type 999", 1, b_type999, E(ERR_BAD_TYPE), 1},
    {"reply type HELLO_OK from client", 1, b_type_reply, E(ERR_BAD_TYPE), 1},
    {"ERROR from client", 1, b_type_error, E(ERR_BAD_TYPE), 1},
    {"IMAGE from client", 1, b_type_image, E(ERR_BAD_TYPE), 1},
    {"payload over pre-HELLO limit", 1, b_pre_big, E(ERR_TOO_LARGE), 1},
    {"payload 4 GiB before HELLO", 1, b_pre_huge, E(ERR_TOO_LARGE), 1},
    {"HEALTH before HELLO", 1, b_pre_health, E(ERR_HELLO_REQUIRED), 1},
    {"STATS before HELLO", 1, b_pre_stats, E(ERR_HELLO_REQUIRED), 1},
    {"FIT before HELLO", 1, b_pre_fit, E(ERR_HELLO_REQUIRED), 1},
    {"CANCEL before HELLO", 1, b_pre_cancel, E(ERR_HELLO_REQUIRED), 1},
    {"garbage HELLO", 1, b_hello_garbage, E(ERR_MALFORMED), 1},
    {"empty HELLO (max_version 0)", 1, b_hello_empty, E(ERR_BAD_VERSION), 1},
    {"HELLO min > max", 1, b_hello_inverted, E(ERR_BAD_VERSION), 1},
    {"HELLO versions 2..5 only", 1, b_hello_future, E(ERR_BAD_VERSION), 1},
    {"payload over max_payload", 0, b_post_big, E(ERR_TOO_LARGE), 1},
    {"payload 4 GiB after HELLO", 0, b_post_huge, E(ERR_TOO_LARGE), 1},
    {"second HELLO", 0, b_second_hello, E(ERR_HELLO_REQUIRED), 1},
    {"version 2 after negotiating 1", 0, b_post_ver2, E(ERR_BAD_VERSION), 1},
    {"bad magic after HELLO", 0, b_post_magic, E(ERR_BAD_MAGIC), 1},
    {"unknown type after HELLO", 0, b_post_type, E(ERR_BAD_TYPE), 1},
    {"DONE from client", 0, b_post_done, E(ERR_BAD_TYPE), 1},
    {"garbage FIT", 0, b_fit_garbage, E(ERR_MALFORMED), 0},
    {"garbage REDIRECT", 0, b_redirect_garbage, E(ERR_MALFORMED), 0},
    {"FIT wrong wire type", 0, b_fit_wiretype, E(ERR_MALFORMED), 0},
    {"FIT truncated field", 0, b_fit_truncated, E(ERR_MALFORMED), 0},
    {"CANCEL truncated varint", 0, b_cancel_garbage, E(ERR_MALFORMED), 0},
    {"STATS bad tag", 0, b_stats_garbage, E(ERR_MALFORMED), 0},
    {"FIT without image", 0, b_fit_noimage, E(ERR_INVALID_ARGUMENT), 0},
    {"FIT NaN gaze", 0, b_fit_nan, E(ERR_INVALID_ARGUMENT), 0},
    {"FIT -inf head", 0, b_fit_inf_head, E(ERR_INVALID_ARGUMENT), 0},
    {"FIT gaze pitch 80", 0, b_fit_range, E(ERR_INVALID_ARGUMENT), 0},
    {"FIT photo (photo_input = no)", 0, b_fit_photo, E(ERR_PHOTO_UNSUPPORTED), 0},
    {"FIT unknown image kind", 0, b_fit_kind, E(ERR_INVALID_ARGUMENT), 0},
    {"FIT raw stride < 3w", 0, b_fit_stride, E(ERR_BAD_IMAGE), 0},
    {"FIT raw data short", 0, b_fit_short, E(ERR_BAD_IMAGE), 0},
    {"FIT raw width 0", 0, b_fit_zero_w, E(ERR_BAD_IMAGE), 0},
    {"FIT raw 100000^2", 0, b_fit_giant, E(ERR_IMAGE_TOO_LARGE), 0},
    {"FIT raw over max_image_mpix", 0, b_fit_mpix, E(ERR_IMAGE_TOO_LARGE), 0},
    {"FIT unknown format", 0, b_fit_format, E(ERR_BAD_IMAGE), 0},
    {"FIT empty PNG", 0, b_fit_empty, E(ERR_BAD_IMAGE), 0},
    {"FIT PNG header 100000^2 (decompression bomb)", 0, b_png_bomb, E(ERR_IMAGE_TOO_LARGE), 0},
    {"FIT PNG header 4096^2 over max_image_mpix", 0, b_png_mpix, E(ERR_IMAGE_TOO_LARGE), 0},
    {"FIT PNG header 8000 wide", 0, b_png_side, E(ERR_IMAGE_TOO_LARGE), 0},
    {"FIT JPEG SOF0 65500^2 (decompression bomb)", 0, b_jpeg_bomb, E(ERR_IMAGE_TOO_LARGE), 0},
    {"FIT progressive JPEG 4000^2", 0, b_jpeg_prog, E(ERR_IMAGE_TOO_LARGE), 0},
    {"FIT JPEG bomb labelled PNG", 0, b_jpeg_as_png, E(ERR_IMAGE_TOO_LARGE), 0},
    {"FIT focal length 0", 0, b_fit_intrinsics, E(ERR_INVALID_ARGUMENT), 0},
    {"FIT max_iters 100001", 0, b_fit_iters, E(ERR_INVALID_ARGUMENT), 0},
    {"FIT deadline over max", 0, b_fit_deadline, E(ERR_INVALID_ARGUMENT), 0},
    {"FIT without a model", 0, b_fit_nomodel, E(ERR_NO_MODEL), 0},
    {"REDIRECT 0 targets", 0, b_redir_zero, E(ERR_INVALID_ARGUMENT), 0},
    {"REDIRECT 65 targets", 0, b_redir_many, E(ERR_INVALID_ARGUMENT), 0},
    {"REDIRECT NaN target", 0, b_redir_nan, E(ERR_INVALID_ARGUMENT), 0},
    {"REDIRECT pitch -51", 0, b_redir_range, E(ERR_INVALID_ARGUMENT), 0},
    {"REDIRECT target without gaze", 0, b_redir_nogaze, E(ERR_INVALID_ARGUMENT), 0},
    {"REDIRECT without key or image", 0, b_redir_nokey, E(ERR_INVALID_ARGUMENT), 0},
    {"REDIRECT paste-back without a photo", 0, b_redir_paste, E(ERR_INVALID_ARGUMENT), 0},
    {"REDIRECT jpeg quality 101", 0, b_redir_quality, E(ERR_INVALID_ARGUMENT), 0},
    {"REDIRECT unknown output format", 0, b_redir_format, E(ERR_INVALID_ARGUMENT), 0},
    {"REDIRECT deadline over max", 0, b_redir_deadline, E(ERR_INVALID_ARGUMENT), 0},
    {"REDIRECT inline PNG bomb 70000 wide", 0, b_redir_bomb, E(ERR_IMAGE_TOO_LARGE), 0},
    {"REDIRECT unknown output mode", 0, b_redir_mode, E(ERR_INVALID_ARGUMENT), 0},
    {"REDIRECT NaN head pose", 0, b_redir_nan_head, E(ERR_INVALID_ARGUMENT), 0},
    {"REDIRECT without a model", 0, b_redir_nomodel, E(ERR_NO_MODEL), 0},
    {"REDIRECT at the inclusive limits (no model)", 0, b_redir_limits, E(ERR_NO_MODEL), 0},
    {"REDIRECT 6th head yaw 70.0000001", 0, b_redir_past, E(ERR_INVALID_ARGUMENT), 0},
    {"SLEEP 600 s", 0, b_sleep_long, E(ERR_INVALID_ARGUMENT), 0},
};

static void run_case(const mcase *mc)
{
    static uint8_t buf[1 << 16];
    size_t n = mc->build(buf);
    gs_client *c = mc->prehello ? h_connect(d.sock) : h_hello(d.sock);
    CHECK_MSG(c != NULL, "%s: connect", mc->name);
    if (!c)
        return;
    gs_error err;
    CHECK(gs_client_send_raw(c, buf, n, &err) == GS_OK);
    int code;
    uint32_t id;
    int type = h_recv(c, 3000, &code, &id, NULL);
    CHECK_MSG(type == T(ERROR) && code == mc->code, "%s: got frame type %d code %s, want ERROR %s",
              mc->name, type, gs_msg_error_name(code), gs_msg_error_name(mc->code));
    if (mc->fatal)
        CHECK_MSG(h_closed(c, 2000), "%s: connection not closed after a protocol error", mc->name);
    else
        CHECK_MSG(h_health_on(c, 555), "%s: same connection stopped answering", mc->name);
    gs_client_close(c);
    CHECK_MSG(h_server_answers(d.sock), "%s: server stopped answering", mc->name);
}

static void test_hello(void)
{
    gs_client *c = h_connect(d.sock);
    Gazesplat__HelloOk *ok = NULL;
    gs_error err;
    /* A client speaking 1..7 gets 1 and the configured limits. */
    Gazesplat__Hello hello = GAZESPLAT__HELLO__INIT;
    hello.min_version = 1;
    hello.max_version = 7;
    gs_client_frame f;
    CHECK(gs_client_call(c, T(HELLO), NULL, 3, &hello.base, 3000, &f, &err) == GS_OK);
    CHECK(f.header.type == T(HELLO_OK) && f.header.request_id == 3);
    ok = (Gazesplat__HelloOk *)f.msg;
    CHECK(ok->version == 1 && ok->limits && ok->limits->max_payload == (1u << 20));
    CHECK(ok->limits && ok->limits->max_targets == 64 && ok->limits->queue_depth == 16);
    CHECK(strncmp(ok->server, "gazesplatd", 10) == 0);
    gs_client_frame_free(&f);
    /* HEALTH: no model configured. */
    Gazesplat__HealthRequest hr = GAZESPLAT__HEALTH_REQUEST__INIT;
    CHECK(gs_client_call(c, T(HEALTH), NULL, 4, &hr.base, 3000, &f, &err) == GS_OK);
    CHECK(f.header.type == T(HEALTH_OK));
    if (f.header.type == T(HEALTH_OK)) {
        Gazesplat__Health *h = (Gazesplat__Health *)f.msg;
        CHECK_MSG(h->state == GAZESPLAT__HEALTH__STATE__FAILED, "state %d", h->state);
        CHECK(strstr(h->detail, "no model") != NULL);
    }
    gs_client_frame_free(&f);
    /* Frames echo the request id and subject key. */
    uint8_t key[16];
    memset(key, 0xab, 16);
    CHECK(gs_client_call(c, T(HEALTH), key, 0xfeedbeef, &hr.base, 3000, &f, &err) == GS_OK);
    CHECK(f.header.request_id == 0xfeedbeef && memcmp(f.header.key, key, 16) == 0);
    gs_client_frame_free(&f);
    gs_client_close(c);
}

/* A HELLO split byte by byte still works (incremental parser). */
static void test_split_hello(void)
{
    uint8_t buf[256];
    size_t n = hello_v(buf, 1, 1);
    gs_client *c = h_connect(d.sock);
    gs_error err;
    for (size_t i = 0; i < n; i++) {
        gs_client_send_raw(c, buf + i, 1, &err);
        h_sleep_ms(1);
    }
    int code;
    CHECK(h_recv(c, 3000, &code, NULL, NULL) == T(HELLO_OK));
    CHECK(h_health_on(c, 1));
    gs_client_close(c);
}

/* Slow senders are cut off: a partial header, a stalled body, no HELLO. */
static void test_slowloris(void)
{
    uint8_t buf[64];
    gs_error err;
    int code;
    gs_client *c = h_connect(d.sock);
    long long t0 = h_now_ms();
    h_frame(buf, 1, T(HELLO), 0, 1);
    gs_client_send_raw(c, buf, 6, &err);
    CHECK(h_recv(c, 5000, &code, NULL, NULL) == T(ERROR) && code == E(ERR_TIMEOUT));
    long long dt = h_now_ms() - t0;
    CHECK_MSG(dt >= 400 && dt < 3000, "partial header cut after %lld ms (header_timeout_ms 500)", dt);
    CHECK(h_closed(c, 2000));
    gs_client_close(c);

    c = h_hello(d.sock);
    h_frame(buf, 1, T(STATS), 1000, 1);
    gs_client_send_raw(c, buf, 40, &err);
    CHECK(h_recv(c, 5000, &code, NULL, NULL) == T(ERROR) && code == E(ERR_TIMEOUT));
    CHECK(h_closed(c, 2000));
    gs_client_close(c);

    c = h_connect(d.sock);
    CHECK(h_recv(c, 5000, &code, NULL, NULL) == T(ERROR) && code == E(ERR_TIMEOUT));
    gs_client_close(c);

    /* Idle after HELLO: idle_timeout_ms 1500. */
    c = h_hello(d.sock);
    t0 = h_now_ms();
    CHECK(h_recv(c, 5000, &code, NULL, NULL) == T(ERROR) && code == E(ERR_TIMEOUT));
    dt = h_now_ms() - t0;
    CHECK_MSG(dt >= 1400, "idle cut after %lld ms (idle_timeout_ms 1500)", dt);
    gs_client_close(c);
    CHECK(h_server_answers(d.sock));
}

/* A peer that never reads: the server stops reading from it once its
 * output is over the cap, keeps serving others, and delivers everything
 * once the peer reads again. */
static void test_output_cap(void)
{
    gs_client *c = h_hello(d.sock);
    enum { N = 1500 };
    static uint8_t buf[N * 32];
    for (int i = 0; i < N; i++)
        h_frame(buf + 32 * i, 1, T(STATS), 0, (uint32_t)i);
    gs_error err;
    CHECK(gs_client_send_raw(c, buf, sizeof buf, &err) == GS_OK);
    h_sleep_ms(300);
    CHECK(h_server_answers(d.sock));
    int got = 0, inorder = 1;
    for (int i = 0; i < N; i++) {
        int code;
        uint32_t id;
        if (h_recv(c, 5000, &code, &id, NULL) != T(STATS_OK))
            break;
        inorder &= id == (uint32_t)i;
        got++;
    }
    CHECK_MSG(got == N && inorder, "%d of %d STATS replies, in order %d", got, N, inorder);
    gs_client_close(c);
}

static void test_stats(void)
{
    gs_client *c = h_hello(d.sock);
    Gazesplat__StatsRequest req = GAZESPLAT__STATS_REQUEST__INIT;
    gs_client_frame f;
    gs_error err;
    CHECK(gs_client_call(c, T(STATS), NULL, 1, &req.base, 3000, &f, &err) == GS_OK);
    CHECK(f.header.type == T(STATS_OK));
    unsigned long long perr = 0, rerr = 0, tmo = 0, acc = 0;
    if (f.header.type == T(STATS_OK)) {
        Gazesplat__Stats *s = (Gazesplat__Stats *)f.msg;
        for (size_t i = 0; i < s->n_counters; i++) {
            const char *n = s->counters[i]->name;
            unsigned long long v = s->counters[i]->value;
            perr = !strcmp(n, "protocol_errors") ? v : perr;
            rerr = !strcmp(n, "request_errors") ? v : rerr;
            tmo = !strcmp(n, "timeouts") ? v : tmo;
            acc = !strcmp(n, "conn_accepted") ? v : acc;
        }
    }
    CHECK_MSG(perr >= 28 && rerr >= 30 && tmo >= 3 && acc > 60,
              "protocol_errors %llu request_errors %llu timeouts %llu accepted %llu", perr, rerr, tmo, acc);
    gs_client_frame_free(&f);
    gs_client_close(c);
}

int main(int argc, char **argv)
{
    if (argc != 2) {
        fprintf(stderr, "usage: %s GAZESPLATD\n", argv[0]);
        return 2;
    }
    bin = argv[1];
    signal(SIGPIPE, SIG_IGN);
    const char *args[] = {"--set", "max_payload=1048576", "--set", "header_timeout_ms=500",
                          "--set", "idle_timeout_ms=1500", "--set", "debug_requests=yes",
                          "--set", "max_output_kb=64", "--set", "max_image_mpix=8",
                          "--set", "photo_input=no",
                          "--log-level", "debug", NULL};
    if (daemon_start_v(&d, bin, args) != 0) {
        fprintf(stderr, "gazesplatd did not start\n");
        daemon_dump_log(&d);
        return 1;
    }
    test_hello();
    test_split_hello();
    size_t ncases = sizeof cases / sizeof cases[0];
    for (size_t i = 0; i < ncases; i++)
        run_case(&cases[i]);
    printf("%zu malformed-frame cases\n", ncases);
    test_slowloris();
    test_output_cap();
    test_stats();
    int st = daemon_stop(&d, SIGTERM, 10000);
    CHECK_MSG(st == 0, "gazesplatd exit status %d after SIGTERM", st);
    if (gs_test_failures)
        daemon_dump_log(&d);
    GS_TEST_END();
}
