/* gs_frame: header codec and incremental frame parser. */
#include "gs_frame.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

enum { ST_HEADER, ST_PAYLOAD, ST_READY, ST_ERROR };

/* Payload buffers above this are freed after each frame. */
#define KEEP_PAYLOAD_CAP 65536u

static void put16(uint8_t *p, uint16_t v)
{
    p[0] = (uint8_t)v;
    p[1] = (uint8_t)(v >> 8);
}

static void put32(uint8_t *p, uint32_t v)
{
    for (int i = 0; i < 4; i++)
        p[i] = (uint8_t)(v >> (8 * i));
}

static uint16_t get16(const uint8_t *p)
{
    return (uint16_t)(p[0] | (p[1] << 8));
}

static uint32_t get32(const uint8_t *p)
{
    return (uint32_t)p[0] | (uint32_t)p[1] << 8 | (uint32_t)p[2] << 16 | (uint32_t)p[3] << 24;
}

void gs_frame_header_pack(const gs_frame_header *h, uint8_t out[GS_FRAME_HEADER_SIZE])
{
    memcpy(out, "GAZE", 4);
    put16(out + 4, h->version);
    put16(out + 6, h->type);
    put32(out + 8, h->payload_len);
    memcpy(out + 12, h->key, GS_FRAME_KEY_SIZE);
    put32(out + 28, h->request_id);
}

int gs_frame_header_unpack(const uint8_t in[GS_FRAME_HEADER_SIZE], gs_frame_header *h)
{
    h->version = get16(in + 4);
    h->type = get16(in + 6);
    h->payload_len = get32(in + 8);
    memcpy(h->key, in + 12, GS_FRAME_KEY_SIZE);
    h->request_id = get32(in + 28);
    return memcmp(in, "GAZE", 4) == 0 ? 0 : -1;
}

void gs_frame_parser_init(gs_frame_parser *p, const gs_frame_limits *lim)
{
    memset(p, 0, sizeof *p);
    p->limits = *lim;
    p->state = ST_HEADER;
}

void gs_frame_parser_free(gs_frame_parser *p)
{
    free(p->payload);
    p->payload = NULL;
    p->payload_cap = 0;
}

void gs_frame_parser_want(gs_frame_parser *p, uint8_t **dst, size_t *n)
{
    if (p->state == ST_HEADER) {
        *dst = p->hbuf + p->have;
        *n = GS_FRAME_HEADER_SIZE - p->have;
    } else if (p->state == ST_PAYLOAD) {
        *dst = p->payload + p->have;
        *n = p->header.payload_len - p->have;
    } else {
        *dst = NULL;
        *n = 0;
    }
}

static int fail(gs_frame_parser *p, int code)
{
    p->state = ST_ERROR;
    p->error = code;
    return code;
}

/* Every check on a complete header, before anything is allocated. */
static int header_done(gs_frame_parser *p)
{
    gs_frame_header *h = &p->header;
    if (gs_frame_header_unpack(p->hbuf, h) != 0)
        return fail(p, GS_FRAME_ERR_MAGIC);
    if (h->version < p->limits.version_min || h->version > p->limits.version_max)
        return fail(p, GS_FRAME_ERR_VERSION);
    if (p->limits.type_ok && !p->limits.type_ok(h->type))
        return fail(p, GS_FRAME_ERR_TYPE);
    if (h->payload_len > p->limits.max_payload || h->payload_len > GS_FRAME_HARD_MAX_PAYLOAD)
        return fail(p, GS_FRAME_ERR_TOO_LARGE);
    size_t need = h->payload_len ? h->payload_len : 1;
    if (need > p->payload_cap) {
        free(p->payload);
        p->payload = malloc(need);
        p->payload_cap = p->payload ? need : 0;
        if (!p->payload)
            return fail(p, GS_FRAME_ERR_NOMEM);
    }
    p->have = 0;
    p->state = h->payload_len ? ST_PAYLOAD : ST_READY;
    return p->state == ST_READY ? GS_FRAME_READY : GS_FRAME_NEED_MORE;
}

int gs_frame_parser_advance(gs_frame_parser *p, size_t n)
{
    if (p->state == ST_ERROR)
        return p->error;
    if (p->state == ST_READY)
        return GS_FRAME_READY;
    p->have += n;
    if (p->state == ST_HEADER)
        return p->have == GS_FRAME_HEADER_SIZE ? header_done(p) : GS_FRAME_NEED_MORE;
    if (p->have == p->header.payload_len) {
        p->state = ST_READY;
        return GS_FRAME_READY;
    }
    return GS_FRAME_NEED_MORE;
}

int gs_frame_parser_feed(gs_frame_parser *p, const uint8_t *buf, size_t len, size_t *used)
{
    size_t off = 0;
    int r = p->state == ST_ERROR ? p->error : p->state == ST_READY ? GS_FRAME_READY : GS_FRAME_NEED_MORE;
    while (r == GS_FRAME_NEED_MORE && off < len) {
        uint8_t *dst;
        size_t want;
        gs_frame_parser_want(p, &dst, &want);
        size_t n = len - off < want ? len - off : want;
        memcpy(dst, buf + off, n);
        off += n;
        r = gs_frame_parser_advance(p, n);
    }
    *used = off;
    return r;
}

int gs_frame_parser_partial(const gs_frame_parser *p)
{
    return p->state == ST_PAYLOAD || (p->state == ST_HEADER && p->have > 0);
}

const gs_frame_header *gs_frame_parser_header(const gs_frame_parser *p)
{
    return p->state == ST_READY ? &p->header : NULL;
}

const uint8_t *gs_frame_parser_payload(const gs_frame_parser *p)
{
    return p->state == ST_READY ? p->payload : NULL;
}

void gs_frame_parser_next(gs_frame_parser *p)
{
    if (p->state != ST_READY)
        return;
    if (p->payload_cap > KEEP_PAYLOAD_CAP)
        gs_frame_parser_free(p);
    p->state = ST_HEADER;
    p->have = 0;
}

const char *gs_frame_strerror(int code)
{
    switch (code) {
    case GS_FRAME_NEED_MORE: return "need more bytes";
    case GS_FRAME_READY: return "frame ready";
    case GS_FRAME_ERR_MAGIC: return "bad magic (want \"GAZE\")";
    case GS_FRAME_ERR_VERSION: return "unsupported protocol version";
    case GS_FRAME_ERR_TYPE: return "unexpected frame type";
    case GS_FRAME_ERR_TOO_LARGE: return "payload over the limit";
    case GS_FRAME_ERR_NOMEM: return "out of memory";
    default: return "unknown frame error";
    }
}

void gs_frame_key_hex(const uint8_t key[GS_FRAME_KEY_SIZE], char out[33])
{
    static const char digits[] = "0123456789abcdef";
    for (int i = 0; i < GS_FRAME_KEY_SIZE; i++) {
        out[2 * i] = digits[key[i] >> 4];
        out[2 * i + 1] = digits[key[i] & 15];
    }
    out[32] = '\0';
}

static int hexval(char c)
{
    if (c >= '0' && c <= '9')
        return c - '0';
    if (c >= 'a' && c <= 'f')
        return c - 'a' + 10;
    if (c >= 'A' && c <= 'F')
        return c - 'A' + 10;
    return -1;
}

int gs_frame_key_parse(const char *hex, uint8_t key[GS_FRAME_KEY_SIZE])
{
    if (strlen(hex) != 2 * GS_FRAME_KEY_SIZE)
        return -1;
    for (int i = 0; i < GS_FRAME_KEY_SIZE; i++) {
        int hi = hexval(hex[2 * i]), lo = hexval(hex[2 * i + 1]);
        if (hi < 0 || lo < 0)
            return -1;
        key[i] = (uint8_t)(hi << 4 | lo);
    }
    return 0;
}
