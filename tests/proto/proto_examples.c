/* Prints real frames of the protocol as hex dumps for proto/PROTOCOL.md.
 * Each example: a line "example NAME: TEXT", then a ```hex block
 * (offset, 16 bytes per line). check_examples.py checks that the document
 * carries every block verbatim and that Python decodes each frame. */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "gs_msg.h"

#define T(x) GAZESPLAT__FRAME_TYPE__FRAME_##x

static void dump(const char *name, const char *text, uint16_t type, uint32_t id, const uint8_t *key,
                 const ProtobufCMessage *msg)
{
    gs_frame_header h;
    memset(&h, 0, sizeof h);
    h.version = 1;
    h.type = type;
    h.request_id = id;
    if (key)
        memcpy(h.key, key, 16);
    uint8_t *buf;
    size_t len;
    if (gs_msg_pack(&h, msg, 1u << 20, &buf, &len) != 0)
        exit(1);
    printf("example %s: %s\n```hex\n", name, text);
    for (size_t i = 0; i < len; i += 16) {
        printf("%04zx ", i);
        for (size_t k = i; k < i + 16 && k < len; k++)
            printf(" %02x", buf[k]);
        printf("\n");
    }
    printf("```\n\n");
    free(buf);
}

int main(void)
{
    static const uint8_t key[16] = {0x3f, 0x1c, 0x9a, 0x07, 0x5e, 0x22, 0x81, 0xd4,
                                    0x6b, 0x10, 0xee, 0x45, 0x93, 0x0a, 0x7c, 0x28};
    Gazesplat__Hello hello = GAZESPLAT__HELLO__INIT;
    hello.min_version = 1;
    hello.max_version = 1;
    hello.client_name = "py";
    dump("hello", "HELLO, versions 1..1, client_name \"py\", no token", T(HELLO), 0, NULL, &hello.base);

    Gazesplat__Limits lim = GAZESPLAT__LIMITS__INIT;
    lim.max_payload = 16777216;
    lim.max_targets = 64;
    lim.max_inflight = 8;
    lim.max_image_side = 4096;
    lim.max_image_pixels = 16777216;
    lim.queue_depth = 16;
    lim.idle_timeout_ms = 300000;
    lim.max_deadline_ms = 600000;
    Gazesplat__HelloOk ok = GAZESPLAT__HELLO_OK__INIT;
    ok.version = 1;
    ok.server = "gazesplatd 0.1.0";
    ok.limits = &lim;
    ok.image_size = 256;
    ok.photo_input = 1; /* the default photo_input = yes, face models loaded */
    dump("hello_ok", "HELLO_OK: version 1, default limits, 256 px model, photo input available",
         T(HELLO_OK), 0, NULL, &ok.base);

    dump("health", "HEALTH, request id 1, empty payload", T(HEALTH), 1, NULL, NULL);

    Gazesplat__Angles g1 = GAZESPLAT__ANGLES__INIT, g2 = GAZESPLAT__ANGLES__INIT;
    g1.pitch_deg = 10;
    g1.yaw_deg = -20;
    g2.pitch_deg = 0;
    g2.yaw_deg = 15;
    Gazesplat__Target t1 = GAZESPLAT__TARGET__INIT, t2 = GAZESPLAT__TARGET__INIT;
    t1.gaze = &g1;
    t2.gaze = &g2;
    Gazesplat__Target *tp[2] = {&t1, &t2};
    Gazesplat__RedirectRequest rr = GAZESPLAT__REDIRECT_REQUEST__INIT;
    rr.n_targets = 2;
    rr.targets = tp;
    dump("redirect", "REDIRECT of subject 3f1c9a07..., request id 7, targets (10, -20) and (0, 15) deg, PNG out",
         T(REDIRECT), 7, key, &rr.base);

    static const uint8_t pixels[12] = {255, 0, 0, 0, 255, 0, 0, 0, 255, 255, 255, 255};
    Gazesplat__Image img = GAZESPLAT__IMAGE__INIT;
    img.format = GAZESPLAT__IMAGE_FORMAT__FORMAT_RAW_RGB8;
    img.data.data = (uint8_t *)pixels;
    img.data.len = sizeof pixels;
    img.width = 2;
    img.height = 2;
    img.stride = 6;
    Gazesplat__Angles gaze = GAZESPLAT__ANGLES__INIT;
    gaze.pitch_deg = 5;
    gaze.yaw_deg = 0;
    Gazesplat__FitRequest fr = GAZESPLAT__FIT_REQUEST__INIT;
    fr.image = &img;
    fr.gaze = &gaze;
    dump("fit", "FIT, request id 2, a 2x2 raw RGB8 image (stride 6) with known gaze (5, 0) deg; "
         "zero key: the server derives one", T(FIT), 2, NULL, &fr.base);

    Gazesplat__Cancel cancel = GAZESPLAT__CANCEL__INIT;
    cancel.request_id = 7;
    dump("cancel", "CANCEL of request 7 (the frame's own id is 8)", T(CANCEL), 8, NULL, &cancel.base);

    Gazesplat__Error err = GAZESPLAT__ERROR__INIT;
    err.code = GAZESPLAT__ERROR_CODE__ERR_UNKNOWN_SUBJECT;
    err.message = "no subject 3f1c9a075e2281d46b10ee45930a7c28 (never fitted or evicted)"; /* compute.c */
    err.request_id = 7;
    dump("error", "ERROR ERR_UNKNOWN_SUBJECT (18) for request 7", T(ERROR), 7, key, &err.base);

    Gazesplat__Busy busy = GAZESPLAT__BUSY__INIT;
    busy.retry_after_ms = 250;
    busy.queue_length = 16;
    dump("busy", "BUSY for request 9: retry after 250 ms, 16 queued", T(BUSY), 9, NULL, &busy.base);

    Gazesplat__Done done = GAZESPLAT__DONE__INIT;
    done.count = 2;
    done.seconds = 0.5;
    dump("done", "DONE for request 7: 2 images in 0.5 s", T(DONE), 7, key, &done.base);

    Gazesplat__LiveSetting st = GAZESPLAT__LIVE_SETTING__INIT, *sets[1] = {&st};
    st.key = "strength";
    st.value = "0.5";
    Gazesplat__LivePolicyRequest lp = GAZESPLAT__LIVE_POLICY_REQUEST__INIT;
    lp.n_set = 1;
    lp.set = sets;
    dump("live_policy", "LIVE_POLICY, request 3: set strength to 0.5", T(LIVE_POLICY), 3, NULL,
         &lp.base);
    return 0;
}
