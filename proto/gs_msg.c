/* gs_msg: frame types <-> protobuf-c descriptors, packing, error names. */
#include "gs_msg.h"

#include <stdlib.h>
#include <string.h>

typedef struct type_entry {
    uint16_t type;
    const char *name;
    const ProtobufCMessageDescriptor *desc;
    int request; /* sent by clients */
} type_entry;

static const type_entry types[] = {
    {GAZESPLAT__FRAME_TYPE__FRAME_HELLO, "HELLO", &gazesplat__hello__descriptor, 1},
    {GAZESPLAT__FRAME_TYPE__FRAME_HELLO_OK, "HELLO_OK", &gazesplat__hello_ok__descriptor, 0},
    {GAZESPLAT__FRAME_TYPE__FRAME_HEALTH, "HEALTH", &gazesplat__health_request__descriptor, 1},
    {GAZESPLAT__FRAME_TYPE__FRAME_HEALTH_OK, "HEALTH_OK", &gazesplat__health__descriptor, 0},
    {GAZESPLAT__FRAME_TYPE__FRAME_STATS, "STATS", &gazesplat__stats_request__descriptor, 1},
    {GAZESPLAT__FRAME_TYPE__FRAME_STATS_OK, "STATS_OK", &gazesplat__stats__descriptor, 0},
    {GAZESPLAT__FRAME_TYPE__FRAME_FIT, "FIT", &gazesplat__fit_request__descriptor, 1},
    {GAZESPLAT__FRAME_TYPE__FRAME_FIT_OK, "FIT_OK", &gazesplat__fit_result__descriptor, 0},
    {GAZESPLAT__FRAME_TYPE__FRAME_REDIRECT, "REDIRECT", &gazesplat__redirect_request__descriptor, 1},
    {GAZESPLAT__FRAME_TYPE__FRAME_IMAGE, "IMAGE", &gazesplat__image_result__descriptor, 0},
    {GAZESPLAT__FRAME_TYPE__FRAME_DONE, "DONE", &gazesplat__done__descriptor, 0},
    {GAZESPLAT__FRAME_TYPE__FRAME_CANCEL, "CANCEL", &gazesplat__cancel__descriptor, 1},
    {GAZESPLAT__FRAME_TYPE__FRAME_ERROR, "ERROR", &gazesplat__error__descriptor, 0},
    {GAZESPLAT__FRAME_TYPE__FRAME_BUSY, "BUSY", &gazesplat__busy__descriptor, 0},
    {GAZESPLAT__FRAME_TYPE__FRAME_LIVE_POLICY, "LIVE_POLICY", &gazesplat__live_policy_request__descriptor, 1},
    {GAZESPLAT__FRAME_TYPE__FRAME_LIVE_POLICY_OK, "LIVE_POLICY_OK", &gazesplat__live_policy__descriptor, 0},
    {GAZESPLAT__FRAME_TYPE__FRAME_LIVE_STATUS, "LIVE_STATUS", &gazesplat__live_status_request__descriptor, 1},
    {GAZESPLAT__FRAME_TYPE__FRAME_LIVE_STATUS_OK, "LIVE_STATUS_OK", &gazesplat__live_status__descriptor, 0},
    {GAZESPLAT__FRAME_TYPE__FRAME_SLEEP, "SLEEP", &gazesplat__sleep__descriptor, 1},
    {GAZESPLAT__FRAME_TYPE__FRAME_SLEEP_OK, "SLEEP_OK", &gazesplat__done__descriptor, 0},
};
#define NTYPES (sizeof types / sizeof types[0])

static const type_entry *find(uint16_t type)
{
    for (size_t i = 0; i < NTYPES; i++)
        if (types[i].type == type)
            return &types[i];
    return NULL;
}

const ProtobufCMessageDescriptor *gs_msg_descriptor(uint16_t type)
{
    const type_entry *e = find(type);
    return e ? e->desc : NULL;
}

const char *gs_msg_type_name(uint16_t type)
{
    const type_entry *e = find(type);
    return e ? e->name : "?";
}

int gs_msg_is_request(uint16_t type)
{
    const type_entry *e = find(type);
    return e && e->request;
}

int gs_msg_is_reply(uint16_t type)
{
    const type_entry *e = find(type);
    return e && !e->request;
}

const char *gs_msg_error_name(int code)
{
    const ProtobufCEnumValue *v =
        protobuf_c_enum_descriptor_get_value(&gazesplat__error_code__descriptor, code);
    return v ? v->name : "ERR_?";
}

int gs_msg_pack(const gs_frame_header *h, const ProtobufCMessage *msg, size_t max_payload,
                uint8_t **out, size_t *out_len)
{
    size_t n = msg ? protobuf_c_message_get_packed_size(msg) : 0;
    if (n > max_payload || n > GS_FRAME_HARD_MAX_PAYLOAD)
        return -1;
    uint8_t *buf = malloc(GS_FRAME_HEADER_SIZE + n);
    if (!buf)
        return -1;
    gs_frame_header hh = *h;
    hh.payload_len = (uint32_t)n;
    gs_frame_header_pack(&hh, buf);
    if (msg)
        protobuf_c_message_pack(msg, buf + GS_FRAME_HEADER_SIZE);
    *out = buf;
    *out_len = GS_FRAME_HEADER_SIZE + n;
    return 0;
}

ProtobufCMessage *gs_msg_unpack(uint16_t type, const uint8_t *payload, size_t len)
{
    const ProtobufCMessageDescriptor *d = gs_msg_descriptor(type);
    if (!d)
        return NULL;
    return protobuf_c_message_unpack(d, NULL, len, payload);
}
