/* gs_msg: frame types <-> protobuf-c descriptors, packing, error names. */
#include "gs_msg.h"

#include <math.h>
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

/* ---- JSON ------------------------------------------------------------------ */

void gs_msg_write_json_string(FILE *f, const char *s)
{
    fputc('"', f);
    for (const unsigned char *p = (const unsigned char *)(s ? s : ""); *p; p++) {
        if (*p == '"' || *p == '\\')
            fprintf(f, "\\%c", *p);
        else if (*p == '\n')
            fputs("\\n", f);
        else if (*p < 0x20 || *p == 0x7f)
            fprintf(f, "\\u%04x", *p);
        else
            fputc(*p, f); /* UTF-8 passes through */
    }
    fputc('"', f);
}

/* The shortest decimal that reads back as v (as a float when is_float). */
static void json_double(FILE *f, double v, int is_float)
{
    if (!isfinite(v)) {
        fputs("null", f);
        return;
    }
    char buf[40];
    for (int prec = is_float ? 6 : 15; prec <= 17; prec++) {
        snprintf(buf, sizeof buf, "%.*g", prec, v);
        double back = strtod(buf, NULL);
        if (is_float ? (float)back == (float)v : back == v)
            break;
    }
    fputs(buf, f);
}

/* One value of field d at p (a scalar, a string pointer, bytes or a
 * message pointer). */
static void json_value(FILE *f, const ProtobufCFieldDescriptor *d, const void *p)
{
    switch (d->type) {
    case PROTOBUF_C_TYPE_INT32:
    case PROTOBUF_C_TYPE_SINT32:
    case PROTOBUF_C_TYPE_SFIXED32:
        fprintf(f, "%d", *(const int32_t *)p);
        break;
    case PROTOBUF_C_TYPE_UINT32:
    case PROTOBUF_C_TYPE_FIXED32:
        fprintf(f, "%u", *(const uint32_t *)p);
        break;
    case PROTOBUF_C_TYPE_INT64:
    case PROTOBUF_C_TYPE_SINT64:
    case PROTOBUF_C_TYPE_SFIXED64:
        fprintf(f, "%lld", (long long)*(const int64_t *)p);
        break;
    case PROTOBUF_C_TYPE_UINT64:
    case PROTOBUF_C_TYPE_FIXED64:
        fprintf(f, "%llu", (unsigned long long)*(const uint64_t *)p);
        break;
    case PROTOBUF_C_TYPE_FLOAT:
        json_double(f, *(const float *)p, 1);
        break;
    case PROTOBUF_C_TYPE_DOUBLE:
        json_double(f, *(const double *)p, 0);
        break;
    case PROTOBUF_C_TYPE_BOOL:
        fputs(*(const protobuf_c_boolean *)p ? "true" : "false", f);
        break;
    case PROTOBUF_C_TYPE_ENUM: {
        const ProtobufCEnumValue *ev =
            protobuf_c_enum_descriptor_get_value((const ProtobufCEnumDescriptor *)d->descriptor,
                                                 *(const int *)p);
        if (ev)
            gs_msg_write_json_string(f, ev->name);
        else
            fprintf(f, "%d", *(const int *)p);
        break;
    }
    case PROTOBUF_C_TYPE_STRING:
        gs_msg_write_json_string(f, *(char *const *)p);
        break;
    case PROTOBUF_C_TYPE_BYTES: {
        const ProtobufCBinaryData *b = p;
        fputc('"', f);
        for (size_t i = 0; i < b->len; i++)
            fprintf(f, "%02x", b->data[i]);
        fputc('"', f);
        break;
    }
    case PROTOBUF_C_TYPE_MESSAGE: {
        const ProtobufCMessage *m = *(const ProtobufCMessage *const *)p;
        if (m)
            gs_msg_write_json(f, m);
        else
            fputs("null", f);
        break;
    }
    }
}

static size_t field_size(const ProtobufCFieldDescriptor *d)
{
    switch (d->type) {
    case PROTOBUF_C_TYPE_INT64:
    case PROTOBUF_C_TYPE_SINT64:
    case PROTOBUF_C_TYPE_SFIXED64:
    case PROTOBUF_C_TYPE_UINT64:
    case PROTOBUF_C_TYPE_FIXED64:
    case PROTOBUF_C_TYPE_DOUBLE:
        return 8;
    case PROTOBUF_C_TYPE_STRING:
    case PROTOBUF_C_TYPE_MESSAGE:
        return sizeof(void *);
    case PROTOBUF_C_TYPE_BYTES:
        return sizeof(ProtobufCBinaryData);
    case PROTOBUF_C_TYPE_BOOL:
        return sizeof(protobuf_c_boolean);
    case PROTOBUF_C_TYPE_ENUM:
        return sizeof(int);
    default:
        return 4;
    }
}

int gs_msg_write_json(FILE *f, const ProtobufCMessage *msg)
{
    const ProtobufCMessageDescriptor *md = msg->descriptor;
    const char *base = (const char *)msg;
    fputc('{', f);
    for (unsigned i = 0; i < md->n_fields; i++) {
        const ProtobufCFieldDescriptor *d = &md->fields[i];
        if (i)
            fputc(',', f);
        gs_msg_write_json_string(f, d->name);
        fputc(':', f);
        if (d->label == PROTOBUF_C_LABEL_REPEATED) {
            size_t n = *(const size_t *)(base + d->quantifier_offset);
            const char *arr = *(char *const *)(base + d->offset);
            fputc('[', f);
            for (size_t k = 0; k < n; k++) {
                if (k)
                    fputc(',', f);
                json_value(f, d, arr + k * field_size(d));
            }
            fputc(']', f);
        } else {
            json_value(f, d, base + d->offset);
        }
    }
    fputc('}', f);
    return ferror(f) ? -1 : 0;
}
