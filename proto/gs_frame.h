/* gs_frame: the 32-byte frame header of the gazesplat protocol and an
 * incremental parser for a stream of frames (PROTOCOL.md).
 *
 * Header, little-endian:
 *   0  u8[4]  magic "GAZE"       12 u8[16] subject key
 *   4  u16    version            28 u32    request id
 *   6  u16    type
 *   8  u32    payload_len
 * then payload_len bytes of protobuf (the message of `type`).
 *
 * The parser keeps per-connection state across partial reads. It hands out
 * the place the next bytes must go (the header buffer, then the payload
 * buffer), so a reader can read() straight into it; a payload is allocated
 * only after its header passed every check (magic, version, type, length
 * against the current limit). Errors are sticky, like libspng's. */
#ifndef GS_FRAME_H
#define GS_FRAME_H

#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

#define GS_FRAME_HEADER_SIZE 32
#define GS_FRAME_KEY_SIZE 16
#define GS_PROTO_VERSION_MIN 1
#define GS_PROTO_VERSION_MAX 1

/* Default limits (PROTOCOL.md "Limits"). */
#define GS_FRAME_MAX_PAYLOAD_PREHELLO 4096u        /* before HELLO */
#define GS_FRAME_DEFAULT_MAX_PAYLOAD (16u << 20)   /* after HELLO */
#define GS_FRAME_HARD_MAX_PAYLOAD (256u << 20)     /* never more */

typedef struct gs_frame_header {
    uint16_t version;
    uint16_t type;
    uint32_t payload_len;
    uint8_t key[GS_FRAME_KEY_SIZE];
    uint32_t request_id;
} gs_frame_header;

/* Writes h as 32 bytes (magic included). */
void gs_frame_header_pack(const gs_frame_header *h, uint8_t out[GS_FRAME_HEADER_SIZE]);

/* Reads 32 bytes; returns 0, or -1 when the magic is wrong (h is filled
 * anyway). No other check: see gs_frame_parser. */
int gs_frame_header_unpack(const uint8_t in[GS_FRAME_HEADER_SIZE], gs_frame_header *h);

/* Parser results. The error values equal the protocol's ErrorCode. */
enum {
    GS_FRAME_NEED_MORE = 0,   /* keep feeding */
    GS_FRAME_READY = 1,       /* a whole frame: gs_frame_parser_frame */
    GS_FRAME_ERR_MAGIC = -1,
    GS_FRAME_ERR_VERSION = -2,
    GS_FRAME_ERR_TYPE = -3,
    GS_FRAME_ERR_TOO_LARGE = -4,
    GS_FRAME_ERR_NOMEM = -29
};

/* What the parser accepts. Change it between frames (e.g. after HELLO). */
typedef struct gs_frame_limits {
    uint32_t max_payload;
    uint16_t version_min, version_max;
    /* Returns non-zero for a type the reader accepts; NULL: any type. */
    int (*type_ok)(uint16_t type);
} gs_frame_limits;

typedef struct gs_frame_parser {
    gs_frame_limits limits;
    int state;         /* internal: header, payload, ready, error */
    int error;         /* sticky GS_FRAME_ERR_*, 0 when none */
    size_t have;       /* bytes of the current part received */
    uint8_t hbuf[GS_FRAME_HEADER_SIZE];
    gs_frame_header header;
    uint8_t *payload;  /* owned; reused between frames */
    size_t payload_cap;
} gs_frame_parser;

void gs_frame_parser_init(gs_frame_parser *p, const gs_frame_limits *lim);
void gs_frame_parser_free(gs_frame_parser *p);

/* Where the next bytes go and how many are wanted (never 0 unless a frame
 * is READY or the parser is in error). */
void gs_frame_parser_want(gs_frame_parser *p, uint8_t **dst, size_t *n);

/* Tells the parser n bytes were written at the place `want` gave.
 * Returns NEED_MORE, READY or an error (sticky). */
int gs_frame_parser_advance(gs_frame_parser *p, size_t n);

/* Copies from buf through want/advance until a frame is ready, an error
 * occurs or buf is used up; *used gets the bytes consumed. */
int gs_frame_parser_feed(gs_frame_parser *p, const uint8_t *buf, size_t len, size_t *used);

/* true while the parser holds part of a frame (header or payload). */
int gs_frame_parser_partial(const gs_frame_parser *p);

/* The ready frame: header and payload (valid until gs_frame_parser_next).
 * The payload pointer is non-NULL even when payload_len is 0. */
const gs_frame_header *gs_frame_parser_header(const gs_frame_parser *p);
const uint8_t *gs_frame_parser_payload(const gs_frame_parser *p);

/* Done with the ready frame; start on the next header. Large payload
 * buffers are released here so an idle connection holds little memory. */
void gs_frame_parser_next(gs_frame_parser *p);

/* A short human text for a GS_FRAME_ERR_* value. */
const char *gs_frame_strerror(int code);

/* Hex of a key into out (33 bytes). */
void gs_frame_key_hex(const uint8_t key[GS_FRAME_KEY_SIZE], char out[33]);
/* Parses 32 hex digits; returns 0 or -1. */
int gs_frame_key_parse(const char *hex, uint8_t key[GS_FRAME_KEY_SIZE]);

#ifdef __cplusplus
}
#endif
#endif
