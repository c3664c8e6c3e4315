#define _GNU_SOURCE /* fmemopen */
/* Frame header codec, incremental parser and message packing. */
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "gs_frame.h"
#include "gs_msg.h"
#include "gs_test.h"

static int any_type(uint16_t t)
{
    return gs_msg_is_request(t) || gs_msg_is_reply(t);
}

static gs_frame_limits lim(uint32_t max)
{
    gs_frame_limits l = {max, 1, 1, any_type};
    return l;
}

/* The byte layout of DESIGN.md, field by field. */
static void test_header_layout(void)
{
    gs_frame_header h = {0};
    h.version = 0x0102;
    h.type = 0x0304;
    h.payload_len = 0x05060708;
    for (int i = 0; i < 16; i++)
        h.key[i] = (uint8_t)(0xa0 + i);
    h.request_id = 0x090a0b0c;
    uint8_t b[32];
    gs_frame_header_pack(&h, b);
    static const uint8_t want[32] = {
        'G', 'A', 'Z', 'E', 0x02, 0x01, 0x04, 0x03, 0x08, 0x07, 0x06, 0x05,
        0xa0, 0xa1, 0xa2, 0xa3, 0xa4, 0xa5, 0xa6, 0xa7, 0xa8, 0xa9, 0xaa, 0xab,
        0xac, 0xad, 0xae, 0xaf, 0x0c, 0x0b, 0x0a, 0x09};
    for (int i = 0; i < 32; i++)
        CHECK_MSG(b[i] == want[i], "byte %d: got %02x want %02x", i, b[i], want[i]);
    gs_frame_header u;
    CHECK(gs_frame_header_unpack(b, &u) == 0);
    CHECK(memcmp(&u, &h, sizeof h) == 0);
    b[0] = 'X';
    CHECK(gs_frame_header_unpack(b, &u) == -1);
}

static size_t make_frame(uint8_t *buf, uint16_t version, uint16_t type, uint32_t len,
                         uint32_t id, uint8_t fill)
{
    gs_frame_header h = {0};
    h.version = version;
    h.type = type;
    h.payload_len = len;
    h.request_id = id;
    gs_frame_header_pack(&h, buf);
    memset(buf + 32, fill, len);
    return 32 + len;
}

static void test_parser_chunks(void)
{
    uint8_t buf[1024];
    size_t n = make_frame(buf, 1, 3, 10, 77, 0x55);
    n += make_frame(buf + n, 1, 5, 0, 78, 0);
    /* Any chunking gives the same two frames. */
    for (size_t chunk = 1; chunk <= n; chunk++) {
        gs_frame_limits l = lim(100);
        gs_frame_parser p;
        gs_frame_parser_init(&p, &l);
        int frames = 0;
        for (size_t off = 0; off < n;) {
            size_t len = n - off < chunk ? n - off : chunk, used;
            int r = gs_frame_parser_feed(&p, buf + off, len, &used);
            off += used;
            CHECK_MSG(r >= 0, "chunk %zu: error %d", chunk, r);
            if (r == GS_FRAME_READY) {
                const gs_frame_header *h = gs_frame_parser_header(&p);
                CHECK(h->request_id == (frames ? 78u : 77u));
                CHECK(h->payload_len == (frames ? 0u : 10u));
                CHECK(gs_frame_parser_payload(&p) != NULL);
                if (!frames)
                    CHECK(gs_frame_parser_payload(&p)[9] == 0x55);
                frames++;
                gs_frame_parser_next(&p);
            }
            if (r < 0)
                break;
        }
        CHECK_MSG(frames == 2, "chunk %zu: %d frames", chunk, frames);
        CHECK(!gs_frame_parser_partial(&p));
        gs_frame_parser_free(&p);
    }
}

static int parse_one(const uint8_t *buf, size_t n, uint32_t max, void **payload_before)
{
    gs_frame_limits l = lim(max);
    gs_frame_parser p;
    gs_frame_parser_init(&p, &l);
    size_t used;
    int r = gs_frame_parser_feed(&p, buf, n, &used);
    if (payload_before)
        *payload_before = p.payload;
    /* Errors are sticky. */
    if (r < 0)
        CHECK(gs_frame_parser_feed(&p, buf, n, &used) == r && used == 0);
    gs_frame_parser_free(&p);
    return r;
}

static void test_parser_errors(void)
{
    uint8_t buf[64];
    void *payload;
    make_frame(buf, 1, 3, 0, 1, 0);
    buf[3] = 'X';
    CHECK(parse_one(buf, 32, 100, NULL) == GS_FRAME_ERR_MAGIC);
    make_frame(buf, 2, 3, 0, 1, 0);
    CHECK(parse_one(buf, 32, 100, NULL) == GS_FRAME_ERR_VERSION);
    make_frame(buf, 0, 3, 0, 1, 0);
    CHECK(parse_one(buf, 32, 100, NULL) == GS_FRAME_ERR_VERSION);
    make_frame(buf, 1, 999, 0, 1, 0);
    CHECK(parse_one(buf, 32, 100, NULL) == GS_FRAME_ERR_TYPE);
    make_frame(buf, 1, 0, 0, 1, 0);
    CHECK(parse_one(buf, 32, 100, NULL) == GS_FRAME_ERR_TYPE);
    /* Over the limit: refused from the header alone, nothing allocated. */
    make_frame(buf, 1, 3, 0, 1, 0);
    buf[8] = 101;
    CHECK(parse_one(buf, 32, 100, &payload) == GS_FRAME_ERR_TOO_LARGE);
    CHECK(payload == NULL);
    memset(buf + 8, 0xff, 4);
    CHECK(parse_one(buf, 32, 0xffffffffu, &payload) == GS_FRAME_ERR_TOO_LARGE);
    CHECK(payload == NULL);
    /* Exactly at the limit is fine; a truncated body just needs more. */
    make_frame(buf, 1, 3, 20, 1, 7);
    CHECK(parse_one(buf, 52, 20, NULL) == GS_FRAME_READY);
    CHECK(parse_one(buf, 40, 20, NULL) == GS_FRAME_NEED_MORE);
    CHECK(parse_one(buf, 31, 20, NULL) == GS_FRAME_NEED_MORE);
    /* The error names are stable. */
    CHECK(strstr(gs_frame_strerror(GS_FRAME_ERR_MAGIC), "magic") != NULL);
    CHECK(strcmp(gs_msg_error_name(GAZESPLAT__ERROR_CODE__ERR_TOO_LARGE), "ERR_TOO_LARGE") == 0);
    CHECK(strcmp(gs_msg_error_name(9999), "ERR_?") == 0);
}

/* Big payload buffers are dropped between frames; small ones reused. */
static void test_parser_buffers(void)
{
    static uint8_t buf[32 + 100000];
    gs_frame_limits l = lim(200000);
    gs_frame_parser p;
    gs_frame_parser_init(&p, &l);
    size_t n = make_frame(buf, 1, 3, 100000, 1, 1), used;
    CHECK(gs_frame_parser_feed(&p, buf, n, &used) == GS_FRAME_READY && used == n);
    gs_frame_parser_next(&p);
    CHECK(p.payload == NULL && p.payload_cap == 0);
    n = make_frame(buf, 1, 3, 100, 2, 1);
    CHECK(gs_frame_parser_feed(&p, buf, n, &used) == GS_FRAME_READY);
    void *keep = p.payload;
    gs_frame_parser_next(&p);
    CHECK(p.payload == keep);
    gs_frame_parser_free(&p);
}

static void test_messages(void)
{
    Gazesplat__Hello hello = GAZESPLAT__HELLO__INIT;
    hello.min_version = 1;
    hello.max_version = 3;
    hello.client_name = "test";
    hello.token.data = (uint8_t *)"secret";
    hello.token.len = 6;
    gs_frame_header h = {0};
    h.version = 1;
    h.type = GAZESPLAT__FRAME_TYPE__FRAME_HELLO;
    h.request_id = 5;
    uint8_t *buf;
    size_t len;
    CHECK(gs_msg_pack(&h, &hello.base, 3, &buf, &len) == -1); /* over max_payload */
    CHECK(gs_msg_pack(&h, &hello.base, 4096, &buf, &len) == 0);
    gs_frame_header u;
    CHECK(gs_frame_header_unpack(buf, &u) == 0 && u.payload_len == len - 32);
    Gazesplat__Hello *m = (Gazesplat__Hello *)gs_msg_unpack(u.type, buf + 32, u.payload_len);
    CHECK(m && m->max_version == 3 && strcmp(m->client_name, "test") == 0 && m->token.len == 6);
    if (m)
        protobuf_c_message_free_unpacked(&m->base, NULL);
    /* Every strict prefix either fails cleanly or parses (ASan watches). */
    for (size_t k = 0; k < u.payload_len; k++) {
        uint8_t *copy = malloc(k ? k : 1);
        memcpy(copy, buf + 32, k);
        ProtobufCMessage *pm = gs_msg_unpack(u.type, copy, k);
        if (pm)
            protobuf_c_message_free_unpacked(pm, NULL);
        free(copy);
    }
    free(buf);
    CHECK(gs_msg_unpack(999, (const uint8_t *)"", 0) == NULL);
    CHECK(gs_msg_is_request(GAZESPLAT__FRAME_TYPE__FRAME_FIT));
    CHECK(!gs_msg_is_request(GAZESPLAT__FRAME_TYPE__FRAME_IMAGE));
    CHECK(gs_msg_is_reply(GAZESPLAT__FRAME_TYPE__FRAME_BUSY));
    CHECK(strcmp(gs_msg_type_name(GAZESPLAT__FRAME_TYPE__FRAME_REDIRECT), "REDIRECT") == 0);
}

static void test_keys(void)
{
    uint8_t k[16], k2[16];
    for (int i = 0; i < 16; i++)
        k[i] = (uint8_t)(i * 17);
    char hex[33];
    gs_frame_key_hex(k, hex);
    CHECK(strcmp(hex, "00112233445566778899aabbccddeeff") == 0);
    CHECK(gs_frame_key_parse(hex, k2) == 0 && memcmp(k, k2, 16) == 0);
    CHECK(gs_frame_key_parse("0011", k2) == -1);
    CHECK(gs_frame_key_parse("zz112233445566778899aabbccddeeff", k2) == -1);
}

/* gs_msg_write_json: every field, escapes, enums by name, bytes as hex,
 * non-finite floats as null, shortest round-trip numbers. */
static void test_json(void)
{
    char buf[1024];
    FILE *f = fmemopen(buf, sizeof buf, "w");
    Gazesplat__Health h = GAZESPLAT__HEALTH__INIT;
    h.state = GAZESPLAT__HEALTH__STATE__READY;
    h.detail = "a \"q\"\\ \n\x01 \xc3\xa9";
    h.queue_length = 3;
    h.model_id = "";
    gs_msg_write_json(f, &h.base);
    fputc('\n', f);
    Gazesplat__FitResult r = GAZESPLAT__FIT_RESULT__INIT;
    uint8_t key[2] = {0xab, 0x01};
    r.subject_key.data = key;
    r.subject_key.len = 2;
    r.psnr = 0.1f;
    r.seconds = 0.331;
    r.ssim = INFINITY;
    gs_msg_write_json(f, &r.base);
    fclose(f);
    CHECK_MSG(!strncmp(buf, "{\"state\":\"READY\",\"detail\":\"a \\\"q\\\"\\\\ \\n\\u0001 \xc3\xa9\",", 45),
              "%s", buf);
    CHECK_MSG(strstr(buf, "\"queue_length\":3,") && strstr(buf, "\"model_id\":\"\""), "%s", buf);
    CHECK_MSG(strstr(buf, "\"subject_key\":\"ab01\"") && strstr(buf, "\"gaze\":null") &&
                  strstr(buf, "\"psnr\":0.1,") && strstr(buf, "\"seconds\":0.331,") &&
                  strstr(buf, "\"ssim\":null") && strstr(buf, "\"cached\":false"),
              "%s", buf);
}

int main(void)
{
    test_json();
    test_header_layout();
    test_parser_chunks();
    test_parser_errors();
    test_parser_buffers();
    test_messages();
    test_keys();
    GS_TEST_END();
}
