/* gs_msg: frames carrying protobuf-c messages (proto/gazesplat.proto).
 *
 * Ties each frame type to its message descriptor, packs header + message
 * into one buffer, and names the protocol's error codes. */
#ifndef GS_MSG_H
#define GS_MSG_H

#include <stddef.h>
#include <stdio.h>
#include <stdint.h>

#include "gazesplat.pb-c.h"
#include "gs_frame.h"

#ifdef __cplusplus
extern "C" {
#endif

/* The message descriptor of a frame type, or NULL for an unknown type. */
const ProtobufCMessageDescriptor *gs_msg_descriptor(uint16_t type);

/* Printable name of a frame type ("HELLO"), "?" when unknown. */
const char *gs_msg_type_name(uint16_t type);

/* Non-zero for the types a client may send / a server may send. */
int gs_msg_is_request(uint16_t type);
int gs_msg_is_reply(uint16_t type);

/* Name of an ErrorCode ("ERR_BAD_MAGIC"), "ERR_?" when unknown. */
const char *gs_msg_error_name(int code);

/* Packs the header (payload_len is set from msg; msg may be NULL for an
 * empty payload) and msg into a malloc'd buffer. Returns 0, or -1 when out
 * of memory or the message is over max_payload. */
int gs_msg_pack(const gs_frame_header *h, const ProtobufCMessage *msg, size_t max_payload,
                uint8_t **out, size_t *out_len);

/* Unpacks the payload of a frame as the message its type names. NULL when
 * the bytes are not a valid message (free with protobuf_c_message_free_unpacked). */
ProtobufCMessage *gs_msg_unpack(uint16_t type, const uint8_t *payload, size_t len);

/* Writes msg as one JSON object (no newline): the proto3 JSON mapping
 * with the proto's field names, except that bytes are lowercase hex (keys
 * are hex everywhere in gazesplat) and every field is written, defaults
 * included, so scripts find each key. Enums by name, 64-bit integers as
 * numbers, non-finite floats as null. Returns 0, or -1 on a write error. */
int gs_msg_write_json(FILE *f, const ProtobufCMessage *msg);
/* s (NULL: "") as a JSON string, quotes and escapes included. */
void gs_msg_write_json_string(FILE *f, const char *s);

#ifdef __cplusplus
}
#endif
#endif
