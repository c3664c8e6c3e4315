/* gs_client: a small blocking client for gazesplatd (PROTOCOL.md).
 *
 * One connection, one thread. Every call takes a timeout and returns
 * GS_OK or a negative gs_status with a message in the optional gs_error;
 * a server ERROR frame is returned to the caller as a frame, not as a
 * failure, so tests can check codes. */
#ifndef GS_CLIENT_H
#define GS_CLIENT_H

#include <stddef.h>
#include <stdint.h>

#include "gazesplat/error.h"
#include "gs_msg.h"

#ifdef __cplusplus
extern "C" {
#endif

typedef struct gs_client gs_client;

/* addr: "unix:PATH", "tcp:HOST:PORT", or a plain PATH (a Unix socket). */
int gs_client_connect(const char *addr, int timeout_ms, gs_client **out, gs_error *err);
void gs_client_close(gs_client *c);
int gs_client_fd(const gs_client *c);

/* Version the frames are sent with (1 until HELLO negotiates). */
void gs_client_set_version(gs_client *c, uint16_t version);

/* The subject key HELLO's header carries (16 zero bytes until set): a
 * proxy routing on the first frame's key (deploy/haproxy,
 * docs/scale-out.md) takes the connection to that key's daemon. Set it
 * before gs_client_hello. */
void gs_client_set_route_key(gs_client *c, const uint8_t key[GS_FRAME_KEY_SIZE]);

/* A route key for the subject fitted from `image` (the bytes as sent)
 * with `settings` (any bytes naming the fit's settings; may be NULL):
 * BLAKE2b-128 of a fixed tag, the image's length and bytes and the
 * settings, so that every connection about one subject, from any process,
 * opens with the same key. */
void gs_client_route_key(const void *image, size_t len, const void *settings,
                         size_t settings_len, uint8_t out[GS_FRAME_KEY_SIZE]);

/* Sends HELLO (versions min..max, token may be NULL) and waits for
 * HELLO_OK; *ok (may be NULL) receives the reply, freed by the caller with
 * protobuf_c_message_free_unpacked. A server ERROR gives GS_ERR_STATE and
 * its code and message in err. */
int gs_client_hello(gs_client *c, const char *client_name, const char *token,
                    int timeout_ms, Gazesplat__HelloOk **ok, gs_error *err);

/* Sends one frame (msg may be NULL: empty payload). */
int gs_client_send(gs_client *c, uint16_t type, const uint8_t key[GS_FRAME_KEY_SIZE],
                   uint32_t request_id, const ProtobufCMessage *msg, gs_error *err);

/* Sends raw bytes (tests of malformed input). */
int gs_client_send_raw(gs_client *c, const void *buf, size_t len, gs_error *err);

/* A received frame: header and its unpacked message (never NULL after
 * GS_OK; an empty payload is the default message). Free with
 * gs_client_frame_free. */
typedef struct gs_client_frame {
    gs_frame_header header;
    ProtobufCMessage *msg;
} gs_client_frame;
void gs_client_frame_free(gs_client_frame *f);

/* Waits up to timeout_ms for a whole frame. GS_ERR_IO on timeout (message
 * "timeout") or when the server closed (message "closed"). */
int gs_client_recv(gs_client *c, int timeout_ms, gs_client_frame *f, gs_error *err);

/* Sends a request and waits for its first reply frame. */
int gs_client_call(gs_client *c, uint16_t type, const uint8_t key[GS_FRAME_KEY_SIZE],
                   uint32_t request_id, const ProtobufCMessage *msg, int timeout_ms,
                   gs_client_frame *reply, gs_error *err);

#ifdef __cplusplus
}
#endif
#endif
