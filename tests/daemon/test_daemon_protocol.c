/* The real gazesplatd over a real Unix socket: HELLO and version
 * negotiation, limits before and after HELLO, and a malformed-frame suite
 * in which every case gets its ERROR code (and a close when the error is
 * a protocol error) and the server still answers other clients; then the
 * start-up checks (state directory, open-files limit, max_connections)
 * and, with a model, PROTOCOL.md's HELLO_OK and ERROR examples against the
 * frames the daemon really sends.
 * usage: test_daemon_protocol PATH_TO_GAZESPLATD [PROTOCOL.md MODEL] */
#define _GNU_SOURCE
#include <math.h>

#include "daemon_harness.h"

static const char *bin, *protocol_md, *model_path;
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
static size_t b_hello_min2_nomax(uint8_t *b) { return hello_v(b, 2, 0); }
static size_t hello_named(uint8_t *b, const char *name)
{
    Gazesplat__Hello m = GAZESPLAT__HELLO__INIT;
    m.min_version = 1;
    m.max_version = 1;
    m.client_name = (char *)name;
    return pack(b, T(HELLO), 1, NULL, &m.base);
}
static size_t b_name_long(uint8_t *b)
{
    char name[66];
    memset(name, 'n', 65);
    name[65] = 0;
    return hello_named(b, name);
}
/* 33 two-byte characters: 66 bytes, though 33 characters. */
static size_t b_name_long_utf8(uint8_t *b)
{
    char name[67] = "";
    for (int i = 0; i < 33; i++)
        strcat(name, "\xc3\xa9");
    return hello_named(b, name);
}
static size_t b_name_overlong(uint8_t *b) { return hello_named(b, "a\xc0\xaf" "b"); } /* '/' in 2 bytes */
static size_t b_name_overlong3(uint8_t *b) { return hello_named(b, "\xe0\x80\xaf"); }  /* and in 3 */
static size_t b_name_surrogate(uint8_t *b) { return hello_named(b, "x\xed\xa0\x80"); } /* U+D800 */
static size_t b_name_too_high(uint8_t *b) { return hello_named(b, "\xf4\x90\x80\x80"); } /* U+110000 */
static size_t b_name_f5(uint8_t *b) { return hello_named(b, "\xf5\x80\x80\x80"); }
static size_t b_name_truncated(uint8_t *b) { return hello_named(b, "py\xe2\x82"); }
static size_t b_name_lone_cont(uint8_t *b) { return hello_named(b, "\x80py"); }
static size_t b_name_latin1(uint8_t *b) { return hello_named(b, "caf\xe9"); }
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
static size_t b_fit_format_none(uint8_t *b)
{
    Gazesplat__Image i = raw_image(8, 8, 24, 192);
    i.format = GAZESPLAT__IMAGE_FORMAT__FORMAT_NONE;
    return fit_with(b, &i, NULL, NULL, 0);
}
/* A small PNG (signature and IHDR of 8x8) labelled JPEG, and the reverse. */
static uint8_t small_png[33] = {0x89, 'P', 'N', 'G', '\r', '\n', 0x1a, '\n', 0, 0, 0, 13,
                                'I', 'H', 'D', 'R', 0, 0, 0, 8, 0, 0, 0, 8, 8, 2};
static uint8_t small_jpeg[] = {0xff, 0xd8, 0xff, 0xe0, 0, 6, 'J', 'F', 'I', 'F', 0xff, 0xd9};
static size_t b_png_as_jpeg(uint8_t *b)
{
    Gazesplat__Image i = GAZESPLAT__IMAGE__INIT;
    i.format = GAZESPLAT__IMAGE_FORMAT__FORMAT_JPEG;
    i.data.data = small_png;
    i.data.len = sizeof small_png;
    return fit_with(b, &i, NULL, NULL, 0);
}
static size_t b_jpeg_as_png_small(uint8_t *b)
{
    Gazesplat__Image i = GAZESPLAT__IMAGE__INIT;
    i.format = GAZESPLAT__IMAGE_FORMAT__FORMAT_PNG;
    i.data.data = small_jpeg;
    i.data.len = sizeof small_jpeg;
    return fit_with(b, &i, NULL, NULL, 0);
}
static size_t b_text_as_png(uint8_t *b)
{
    static uint8_t text[] = "not an image at all";
    Gazesplat__Image i = GAZESPLAT__IMAGE__INIT;
    i.format = GAZESPLAT__IMAGE_FORMAT__FORMAT_PNG;
    i.data.data = text;
    i.data.len = sizeof text - 1;
    return fit_with(b, &i, NULL, NULL, 0);
}
/* LIVE_POLICY to a server without a live pipeline. */
static size_t live_set(uint8_t *b, const char *key, const char *value)
{
    Gazesplat__LiveSetting st = GAZESPLAT__LIVE_SETTING__INIT, *sets[1] = {&st};
    st.key = (char *)key;
    st.value = (char *)value;
    Gazesplat__LivePolicyRequest m = GAZESPLAT__LIVE_POLICY_REQUEST__INIT;
    m.n_set = 1;
    m.set = sets;
    return pack(b, T(LIVE_POLICY), 9, NULL, &m.base);
}
static size_t b_live_unknown(uint8_t *b) { return live_set(b, "brightness", "1"); }
static size_t b_live_unparsable(uint8_t *b) { return live_set(b, "strength", "lots"); }
static size_t b_live_nan(uint8_t *b) { return live_set(b, "smooth_s", "nan"); }
static size_t b_live_good(uint8_t *b) { return live_set(b, "strength", "0.5"); }
static size_t b_live_range(uint8_t *b) { return live_set(b, "strength", "7"); }
static size_t b_live_read(uint8_t *b)
{
    Gazesplat__LivePolicyRequest m = GAZESPLAT__LIVE_POLICY_REQUEST__INIT;
    return pack(b, T(LIVE_POLICY), 9, NULL, &m.base);
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
    {"HELLO min > max", 1, b_hello_inverted, E(ERR_BAD_VERSION), 1},
    {"HELLO min 2, no max", 1, b_hello_min2_nomax, E(ERR_BAD_VERSION), 1},
    {"HELLO client_name 65 bytes", 1, b_name_long, E(ERR_INVALID_ARGUMENT), 1},
    {"HELLO client_name 33 characters in 66 bytes", 1, b_name_long_utf8, E(ERR_INVALID_ARGUMENT), 1},
    {"HELLO client_name overlong 2-byte", 1, b_name_overlong, E(ERR_MALFORMED), 1},
    {"HELLO client_name overlong 3-byte", 1, b_name_overlong3, E(ERR_MALFORMED), 1},
    {"HELLO client_name surrogate", 1, b_name_surrogate, E(ERR_MALFORMED), 1},
    {"HELLO client_name over U+10FFFF", 1, b_name_too_high, E(ERR_MALFORMED), 1},
    {"HELLO client_name lead byte F5", 1, b_name_f5, E(ERR_MALFORMED), 1},
    {"HELLO client_name truncated sequence", 1, b_name_truncated, E(ERR_MALFORMED), 1},
    {"HELLO client_name lone continuation byte", 1, b_name_lone_cont, E(ERR_MALFORMED), 1},
    {"HELLO client_name Latin-1", 1, b_name_latin1, E(ERR_MALFORMED), 1},
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
    {"FIT unknown format", 0, b_fit_format, E(ERR_INVALID_ARGUMENT), 0},
    {"FIT format NONE", 0, b_fit_format_none, E(ERR_INVALID_ARGUMENT), 0},
    {"FIT PNG bytes labelled JPEG", 0, b_png_as_jpeg, E(ERR_BAD_IMAGE), 0},
    {"FIT JPEG bytes labelled PNG", 0, b_jpeg_as_png_small, E(ERR_BAD_IMAGE), 0},
    {"FIT text labelled PNG", 0, b_text_as_png, E(ERR_BAD_IMAGE), 0},
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
    {"LIVE_POLICY unknown key, no live pipeline", 0, b_live_unknown, E(ERR_INVALID_ARGUMENT), 0},
    {"LIVE_POLICY unparsable value, no live pipeline", 0, b_live_unparsable, E(ERR_INVALID_ARGUMENT), 0},
    {"LIVE_POLICY NaN value, no live pipeline", 0, b_live_nan, E(ERR_INVALID_ARGUMENT), 0},
    {"LIVE_POLICY good setting, no live pipeline", 0, b_live_good, E(ERR_LIVE_OFF), 0},
    {"LIVE_POLICY out of range, no live pipeline", 0, b_live_range, E(ERR_LIVE_OFF), 0},
    {"LIVE_POLICY read, no live pipeline", 0, b_live_read, E(ERR_LIVE_OFF), 0},
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

/* HELLO without bounds: an empty HELLO (every field 0) is valid and gets
 * the server's highest version; names up to 64 bytes of UTF-8 pass. */
static void test_hello_defaults(void)
{
    static const char *const names[] = {
        "",
        "nnnnnnnnnnnnnnnnnnnnnnnnnnnnnnnnnnnnnnnnnnnnnnnnnnnnnnnnnnnnnnnn", /* 64 bytes */
        "caf\xc3\xa9 \xe2\x9c\x93 \xf0\x9f\x98\x80 \xf4\x8f\xbf\xbf \xef\xbf\xbf", /* up to U+10FFFF */
    };
    uint8_t buf[256];
    int code;
    Gazesplat__HelloOk *ok = NULL;
    gs_client *c = h_connect(d.sock);
    CHECK(c && gs_client_send_raw(c, buf, b_hello_empty(buf), NULL) == GS_OK);
    int type = h_recv(c, 3000, &code, NULL, (ProtobufCMessage **)&ok);
    CHECK_MSG(type == T(HELLO_OK) && ok->version == 1, "empty HELLO: frame type %d code %s", type,
              gs_msg_error_name(code));
    if (type >= 0)
        protobuf_c_message_free_unpacked(&ok->base, NULL);
    CHECK(h_health_on(c, 2));
    gs_client_close(c);
    for (size_t i = 0; i < sizeof names / sizeof names[0]; i++) {
        c = h_connect(d.sock);
        CHECK(c && gs_client_send_raw(c, buf, hello_named(buf, names[i]), NULL) == GS_OK);
        type = h_recv(c, 3000, &code, NULL, NULL);
        CHECK_MSG(type == T(HELLO_OK), "client_name %zu (%zu bytes): frame type %d code %s", i,
                  strlen(names[i]), type, gs_msg_error_name(code));
        gs_client_close(c);
    }
}

/* CANCEL is never answered, not even a malformed one: the next frame on
 * the connection is the reply to the request after it. */
static void test_cancel_silent(void)
{
    uint8_t buf[128];
    gs_client *c = h_hello(d.sock);
    size_t n = garbage(buf, T(CANCEL), "\x08", 1); /* truncated varint, frame id 9 */
    n += h_frame(buf + n, 1, T(HEALTH), 0, 10);
    CHECK(c && gs_client_send_raw(c, buf, n, NULL) == GS_OK);
    int code;
    uint32_t id = 0;
    int type = h_recv(c, 3000, &code, &id, NULL);
    CHECK_MSG(type == T(HEALTH_OK) && id == 10, "after a malformed CANCEL: frame type %d id %u code %s",
              type, id, gs_msg_error_name(code));
    gs_client_close(c);
}

static unsigned long long stat_of(gs_client *c, const char *name)
{
    Gazesplat__StatsRequest req = GAZESPLAT__STATS_REQUEST__INIT;
    gs_client_frame f;
    gs_error err;
    unsigned long long v = ~0ull;
    if (gs_client_call(c, T(STATS), NULL, 77, &req.base, 3000, &f, &err) != GS_OK)
        return v;
    if (f.header.type == T(STATS_OK)) {
        Gazesplat__Stats *s = (Gazesplat__Stats *)f.msg;
        for (size_t i = 0; i < s->n_counters; i++)
            if (!strcmp(s->counters[i]->name, name))
                v = s->counters[i]->value;
    }
    gs_client_frame_free(&f);
    return v;
}

static int log_has(const daemon_proc *p, const char *text)
{
    FILE *f = fopen(p->log, "r");
    char line[2048];
    int found = 0;
    while (f && !found && fgets(line, sizeof line, f))
        found = strstr(line, text) != NULL;
    if (f)
        fclose(f);
    return found;
}

/* An open-files limit of 72 leaves room for 72 - 64 = 8 connections: the
 * default max_connections 1024 is lowered to that with a warning, and the
 * ninth connection gets ERROR ERR_TOO_MANY_CONNECTIONS before the close. */
static void test_connection_limit(void)
{
    daemon_proc e;
    memset(&e, 0, sizeof e);
    e.nofile = 72;
    const char *args[] = {"--set", "photo_input=no", "--log-level", "debug", NULL};
    if (daemon_start_v(&e, bin, args) != 0) {
        CHECK_MSG(0, "gazesplatd with RLIMIT_NOFILE 72 did not start");
        daemon_dump_log(&e);
        return;
    }
    enum { CAP = 8 };
    gs_client *cs[CAP] = {0};
    for (int i = 0; i < CAP; i++)
        cs[i] = h_hello(e.sock);
    CHECK_MSG(cs[CAP - 1] != NULL, "connection %d of %d refused", CAP, CAP);
    unsigned long long maxc = cs[0] ? stat_of(cs[0], "max_connections") : 0;
    CHECK_MSG(maxc == CAP, "STATS max_connections %llu, want %d", maxc, CAP);
    CHECK_MSG(log_has(&e, "max_connections 8 in force"), "no warning about the lowered max_connections");
    gs_client *extra = h_connect(e.sock);
    int code = 0;
    uint32_t id = 1;
    int type = extra ? h_recv(extra, 3000, &code, &id, NULL) : -1;
    CHECK_MSG(type == T(ERROR) && code == E(ERR_TOO_MANY_CONNECTIONS) && id == 0,
              "connection over max_connections: frame type %d code %s id %u", type,
              gs_msg_error_name(code), id);
    CHECK(extra && h_closed(extra, 2000));
    gs_client_close(extra);
    gs_client_close(cs[CAP - 1]);
    cs[CAP - 1] = NULL;
    h_sleep_ms(100); /* the server sees the close */
    CHECK_MSG(h_server_answers(e.sock), "no connection after one closed");
    unsigned long long rej = cs[0] ? stat_of(cs[0], "conn_rejected") : 0;
    CHECK_MSG(rej == 1, "conn_rejected %llu, want 1", rej);
    for (int i = 0; i < CAP; i++)
        gs_client_close(cs[i]);
    int st = daemon_stop(&e, SIGTERM, 10000);
    CHECK_MSG(st == 0, "exit status %d", st);
    if (gs_test_failures)
        daemon_dump_log(&e);
}

/* Runs the daemon with args and waits up to 5 s for it to exit: its exit
 * status, or -1 when it is still running (it is then stopped). */
static int run_to_exit(const char *dir, const char *const *args, char *log, size_t cap)
{
    char sock[128], logpath[128];
    snprintf(sock, sizeof sock, "%s/x.sock", dir);
    snprintf(logpath, sizeof logpath, "%s/xlog", dir);
    unlink(logpath);
    const char *argv[16];
    int n = 0;
    argv[n++] = bin;
    argv[n++] = "--socket";
    argv[n++] = sock;
    for (int i = 0; args[i] && n < 15; i++)
        argv[n++] = args[i];
    argv[n] = NULL;
    pid_t pid = fork();
    if (pid == 0) {
        int fd = open(logpath, O_WRONLY | O_CREAT | O_TRUNC, 0600);
        dup2(fd, 2);
        execv(bin, (char *const *)argv);
        _exit(127);
    }
    int st, r = -1;
    for (int i = 0; i < 500; i++) {
        if (waitpid(pid, &st, WNOHANG) == pid) {
            r = WIFEXITED(st) ? WEXITSTATUS(st) : 128 + WTERMSIG(st);
            break;
        }
        h_sleep_ms(10);
    }
    if (r < 0) {
        kill(pid, SIGTERM);
        waitpid(pid, &st, 0);
    }
    log[0] = 0;
    FILE *f = fopen(logpath, "r");
    if (f) {
        size_t got = fread(log, 1, cap - 1, f);
        log[got] = 0;
        fclose(f);
    }
    return r;
}

/* An unusable state directory stops the start with status 1 and says why;
 * a missing one whose parent exists is created. */
static void test_state_dir(void)
{
    char dir[64] = "/tmp/gsd_state_XXXXXX", path[128], log[4096];
    CHECK(mkdtemp(dir) != NULL);
    static const struct {
        const char *sub, *says;
    } bad[] = {
        {"no/such/parent", "cannot be created"},
        {"file", "not a directory"},
        {"ro", "not writable"},
    };
    snprintf(path, sizeof path, "%s/file", dir);
    FILE *f = fopen(path, "w");
    if (f)
        fclose(f);
    snprintf(path, sizeof path, "%s/ro", dir);
    mkdir(path, 0500);
    for (size_t i = 0; i < sizeof bad / sizeof bad[0]; i++) {
        if (!strcmp(bad[i].sub, "ro") && geteuid() == 0) {
            printf("state_dir not writable: skipped (root writes anywhere)\n");
            continue;
        }
        snprintf(path, sizeof path, "%s/%s", dir, bad[i].sub);
        const char *args[] = {"--state-dir", path, "--set", "photo_input=no", NULL};
        int st = run_to_exit(dir, args, log, sizeof log);
        CHECK_MSG(st == 1 && strstr(log, bad[i].says) && strstr(log, path),
                  "state_dir %s: exit status %d, log: %s", bad[i].sub, st, log);
    }
    /* A missing directory in an existing one is created and the daemon runs. */
    daemon_proc e;
    memset(&e, 0, sizeof e);
    snprintf(e.dir, sizeof e.dir, "%s", dir);
    snprintf(path, sizeof path, "%s/new", dir);
    const char *args[] = {"--state-dir", path, "--set", "photo_input=no", NULL};
    CHECK_MSG(daemon_start_v(&e, bin, args) == 0, "did not start with a state_dir to create");
    struct stat sb;
    CHECK_MSG(stat(path, &sb) == 0 && S_ISDIR(sb.st_mode), "state_dir %s not created", path);
    CHECK(daemon_stop(&e, SIGTERM, 10000) == 0);
    static const char *const files[] = {"file", "xlog", "log"}, *const dirs[] = {"new", "ro", ""};
    for (size_t i = 0; i < sizeof files / sizeof files[0]; i++) {
        snprintf(path, sizeof path, "%s/%s", dir, files[i]);
        unlink(path);
    }
    for (size_t i = 0; i < sizeof dirs / sizeof dirs[0]; i++) {
        snprintf(path, sizeof path, "%s/%s", dir, dirs[i]);
        rmdir(path);
    }
}

/* The hex block after the line starting with `caption` in PROTOCOL.md. */
static size_t doc_example(const char *caption, uint8_t *out, size_t cap)
{
    FILE *f = fopen(protocol_md, "r");
    char line[512];
    int state = 0; /* 0 looking for the caption, 1 for the block, 2 in it */
    size_t n = 0;
    while (f && fgets(line, sizeof line, f)) {
        if (state == 0 && !strncmp(line, caption, strlen(caption)))
            state = 1;
        else if (state == 1 && !strncmp(line, "```hex", 6))
            state = 2;
        else if (state == 2 && !strncmp(line, "```", 3))
            break;
        else if (state == 2)
            for (char *p = line + 4, *end; n < cap; p = end) {
                unsigned long v = strtoul(p, &end, 16);
                if (end == p)
                    break;
                out[n++] = (uint8_t)v;
            }
    }
    if (f)
        fclose(f);
    return state == 2 ? n : 0;
}

/* The frame as the daemon packed it (protobuf-c packs canonically). */
static size_t frame_bytes(const gs_client_frame *f, uint8_t *out, size_t cap)
{
    uint8_t *buf;
    size_t len;
    if (gs_msg_pack(&f->header, f->msg, 1u << 20, &buf, &len) != 0 || len > cap)
        return 0;
    memcpy(out, buf, len);
    free(buf);
    return len;
}

/* With a model: PROTOCOL.md's HELLO sent as printed gets its HELLO_OK
 * byte for byte (default limits, 256 px, photo input), its REDIRECT of an
 * unknown subject gets its ERROR byte for byte, that worker-side ERROR
 * counts in request_errors, and a cached FIT says iters 0. */
static void test_doc_examples(void)
{
    if (!protocol_md || !model_path || access(model_path, R_OK) != 0) {
        printf("PROTOCOL.md examples against the daemon: skipped (no model)\n");
        return;
    }
    daemon_proc e;
    memset(&e, 0, sizeof e);
    const char *args[] = {"--model", model_path, NULL};
    if (daemon_start_v(&e, bin, args) != 0) {
        CHECK_MSG(0, "gazesplatd with %s did not start", model_path);
        daemon_dump_log(&e);
        return;
    }
    /* Wait for the model and the face models (HELLO_OK says photo_input). */
    gs_client *c = h_hello(e.sock);
    int ready = 0;
    for (int i = 0; c && i < 1200 && !ready; i++) {
        Gazesplat__HealthRequest hr = GAZESPLAT__HEALTH_REQUEST__INIT;
        gs_client_frame f;
        gs_error err;
        if (gs_client_call(c, T(HEALTH), NULL, 1, &hr.base, 3000, &f, &err) != GS_OK)
            break;
        Gazesplat__Health *h = (Gazesplat__Health *)f.msg;
        ready = f.header.type == T(HEALTH_OK) && h->state != GAZESPLAT__HEALTH__STATE__LOADING &&
                (h->photo_input || h->photo_detail[0] != 'f'); /* "face models not loaded yet" */
        gs_client_frame_free(&f);
        if (!ready)
            h_sleep_ms(50);
    }
    gs_client_close(c);
    CHECK_MSG(ready, "model not loaded within 60 s");
    static uint8_t want[4096], got[4096], req[4096];
    gs_client_frame f;
    gs_error err;
    size_t nreq = doc_example("HELLO, versions 1..1", req, sizeof req);
    size_t nwant = doc_example("HELLO_OK", want, sizeof want);
    CHECK_MSG(nreq > 32 && nwant > 32, "PROTOCOL.md: HELLO or HELLO_OK example not found");
    c = h_connect(e.sock);
    size_t ngot = 0;
    if (c && gs_client_send_raw(c, req, nreq, &err) == GS_OK && gs_client_recv(c, 3000, &f, &err) == GS_OK) {
        ngot = frame_bytes(&f, got, sizeof got);
        gs_client_frame_free(&f);
    }
    CHECK_MSG(ngot == nwant && memcmp(got, want, ngot) == 0,
              "HELLO_OK: the daemon sent %zu bytes, PROTOCOL.md shows %zu (or they differ)", ngot, nwant);
    nreq = doc_example("REDIRECT of subject 3f1c9a07", req, sizeof req);
    nwant = doc_example("ERROR ERR_UNKNOWN_SUBJECT (18) for request 7", want, sizeof want);
    CHECK_MSG(nreq > 32 && nwant > 32, "PROTOCOL.md: REDIRECT or ERROR example not found");
    ngot = 0;
    if (c && gs_client_send_raw(c, req, nreq, &err) == GS_OK && gs_client_recv(c, 10000, &f, &err) == GS_OK) {
        ngot = frame_bytes(&f, got, sizeof got);
        if (f.header.type == T(ERROR))
            printf("daemon: %s\n", ((Gazesplat__Error *)f.msg)->message);
        gs_client_frame_free(&f);
    }
    CHECK_MSG(ngot == nwant && memcmp(got, want, ngot) == 0,
              "ERROR: the daemon sent %zu bytes, PROTOCOL.md shows %zu (or they differ)", ngot, nwant);
    unsigned long long rerr = c ? stat_of(c, "request_errors") : 0;
    CHECK_MSG(rerr == 1, "request_errors %llu after one worker-side ERROR, want 1", rerr);
    /* A FIT of a known key is cached: the subject's fit quality, iters 0
     * (this request ran no fit). */
    static uint8_t face[256 * 256 * 3];
    /* A smooth gradient: the face gate refuses a flat frame (docs/face.md). */
    for (size_t i = 0; i < sizeof face; i++)
        face[i] = (uint8_t)(((i / 3) % 256 + (i / 768)) / 2);
    Gazesplat__Image img = GAZESPLAT__IMAGE__INIT;
    img.format = GAZESPLAT__IMAGE_FORMAT__FORMAT_RAW_RGB8;
    img.width = img.height = 256;
    img.stride = 768;
    img.data.data = face;
    img.data.len = sizeof face;
    Gazesplat__FitRequest fr = GAZESPLAT__FIT_REQUEST__INIT;
    fr.image = &img;
    fr.max_iters = 2;
    Gazesplat__FitResult res[2];
    int got_fit = 0;
    for (int i = 0; c && i < 2; i++) {
        if (gs_client_call(c, T(FIT), NULL, 20 + (uint32_t)i, &fr.base, 60000, &f, &err) != GS_OK)
            break;
        if (f.header.type == T(FIT_OK)) {
            res[i] = *(Gazesplat__FitResult *)f.msg;
            got_fit++;
        }
        gs_client_frame_free(&f);
    }
    CHECK_MSG(got_fit == 2, "%d of 2 FITs answered FIT_OK", got_fit);
    if (got_fit == 2)
        CHECK_MSG(!res[0].cached && res[0].iters > 0 && res[1].cached && res[1].iters == 0 &&
                      res[1].psnr == res[0].psnr,
                  "FIT then cached FIT: cached %d/%d iters %u/%u psnr %g/%g", res[0].cached,
                  res[1].cached, res[0].iters, res[1].iters, res[0].psnr, res[1].psnr);
    gs_client_close(c);
    CHECK(daemon_stop(&e, SIGTERM, 10000) == 0);
    if (gs_test_failures)
        daemon_dump_log(&e);
}

int main(int argc, char **argv)
{
    if (argc != 2 && argc != 4) {
        fprintf(stderr, "usage: %s GAZESPLATD [PROTOCOL.md MODEL]\n", argv[0]);
        return 2;
    }
    bin = argv[1];
    protocol_md = argc == 4 ? argv[2] : NULL;
    model_path = argc == 4 ? argv[3] : NULL;
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
    test_hello_defaults();
    test_split_hello();
    test_cancel_silent();
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
    test_connection_limit();
    test_state_dir();
    test_doc_examples();
    GS_TEST_END();
}
