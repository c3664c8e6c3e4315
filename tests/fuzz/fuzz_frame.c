/* Fuzz target: the frame parser and the message decoder, as the daemon
 * drives them. The first input byte picks the limits (before or after
 * HELLO) and the chunk size the stream is fed in; every complete frame's
 * payload is unpacked as the message its type names, and the image of a
 * FIT or REDIRECT goes through the daemon's header probe (the PNG/JPEG
 * size check that refuses decompression bombs on the loop thread); the
 * input and each HELLO's client_name go through the UTF-8 check. */
#include <stddef.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "gs_frame.h"
#include "gs_msg.h"
#include "server.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

static int request_type(uint16_t t)
{
    return gs_msg_is_request(t);
}

static void probe(const Gazesplat__Image *img)
{
    uint32_t w, h;
    if (img) /* the probe's reads are what is fuzzed; the result does not matter */
        (void)gsd_image_probe(img->data.data, img->data.len, &w, &h);
}

static void probe_request(uint16_t type, const ProtobufCMessage *m)
{
    if (type == GAZESPLAT__FRAME_TYPE__FRAME_FIT)
        probe(((const Gazesplat__FitRequest *)m)->image);
    else if (type == GAZESPLAT__FRAME_TYPE__FRAME_REDIRECT)
        probe(((const Gazesplat__RedirectRequest *)m)->image);
    else if (type == GAZESPLAT__FRAME_TYPE__FRAME_HELLO) {
        const char *name = ((const Gazesplat__Hello *)m)->client_name;
        (void)gsd_utf8_valid(name, strlen(name));
    }
}

static int any_type(uint16_t t)
{
    return gs_msg_is_request(t) || gs_msg_is_reply(t);
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    if (size < 1)
        return 0;
    uint8_t mode = data[0];
    data++;
    size--;
    (void)gsd_utf8_valid((const char *)data, size); /* the HELLO name check, on any bytes */
    gs_frame_limits lim = {mode & 1 ? GS_FRAME_MAX_PAYLOAD_PREHELLO : 1u << 20, 1, 1,
                           mode & 2 ? any_type : request_type};
    size_t chunk = (size_t)(mode >> 2) + 1;
    gs_frame_parser p;
    gs_frame_parser_init(&p, &lim);
    size_t off = 0;
    while (off < size) {
        size_t n = size - off < chunk ? size - off : chunk, used;
        int r = gs_frame_parser_feed(&p, data + off, n, &used);
        off += used;
        if (r < 0)
            break;
        if (r == GS_FRAME_READY) {
            const gs_frame_header *h = gs_frame_parser_header(&p);
            ProtobufCMessage *m = gs_msg_unpack(h->type, gs_frame_parser_payload(&p), h->payload_len);
            if (m) {
                probe_request(h->type, m);
                /* Re-pack what was decoded: sizes must agree. */
                uint8_t *buf;
                size_t len;
                if (gs_msg_pack(h, m, 1u << 24, &buf, &len) == 0) {
                    gs_frame_header back;
                    if (gs_frame_header_unpack(buf, &back) != 0 || back.payload_len != len - 32)
                        __builtin_trap();
                    free(buf);
                }
                protobuf_c_message_free_unpacked(m, NULL);
            }
            gs_frame_parser_next(&p);
        }
    }
    gs_frame_parser_free(&p);
    return 0;
}
