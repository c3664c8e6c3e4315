/* gazesplat augment --addr (augment_remote.h). */
#define _POSIX_C_SOURCE 200809L
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "augment_remote.h"
#include "gs_client.h"
#include "gazesplat/image_io.h"

#define T(x) GAZESPLAT__FRAME_TYPE__FRAME_##x
#define TIMEOUT_MS (30 * 60 * 1000) /* one fit or one group of renders */

static unsigned max_targets = 64;
static uint32_t next_id = 1;

static void nap_ms(unsigned ms)
{
    struct timespec ts = {ms / 1000, (long)(ms % 1000) * 1000000L};
    nanosleep(&ts, NULL);
}

/* Transport failures other than a timeout (the daemon went away, or the
 * proxy found no daemon) may be retried on a new connection. */
static int io_status(const gs_error *err)
{
    return strcmp(err->msg, "timeout") == 0 ? AUG_REMOTE_FATAL : AUG_REMOTE_RETRY;
}

int aug_remote_connect(const char *addr, const char *token, const uint8_t *route_key,
                       gs_client **out, int *image_size, char *server, size_t server_cap,
                       char *msg, size_t cap)
{
    /* A server still loading its model says image_size 0: ask again for
     * up to a minute. */
    for (int attempt = 0;; attempt++) {
        gs_error err;
        gs_error_clear(&err);
        *out = NULL;
        if (gs_client_connect(addr, 10000, out, &err) != GS_OK) {
            snprintf(msg, cap, "%s: %s", addr, err.msg);
            return AUG_REMOTE_RETRY;
        }
        if (route_key)
            gs_client_set_route_key(*out, route_key);
        Gazesplat__HelloOk *ok = NULL;
        int hr = gs_client_hello(*out, "gazesplat-augment", token, 10000, &ok, &err);
        if (hr != GS_OK) {
            snprintf(msg, cap, "%s: HELLO: %s", addr, err.msg);
            gs_client_close(*out);
            *out = NULL;
            /* A server's ERROR (a wrong token: fatal; too many connections,
             * draining: retried) or the connection lost. */
            if (hr == GS_ERR_STATE)
                return strstr(err.msg, "ERR_TOO_MANY_CONNECTIONS") ||
                               strstr(err.msg, "ERR_SHUTTING_DOWN") ||
                               strstr(err.msg, "ERR_LOADING")
                           ? AUG_REMOTE_RETRY
                           : AUG_REMOTE_FATAL;
            return hr == GS_ERR_IO ? io_status(&err) : AUG_REMOTE_FATAL;
        }
        *image_size = (int)ok->image_size;
        snprintf(server, server_cap, "%s", ok->server ? ok->server : "");
        if (ok->limits && ok->limits->max_targets)
            max_targets = ok->limits->max_targets;
        protobuf_c_message_free_unpacked(&ok->base, NULL);
        if (*image_size >= 16)
            return 0;
        gs_client_close(*out);
        *out = NULL;
        if (attempt == 240) {
            snprintf(msg, cap, "%s: the server has no model loaded (a minute)", addr);
            return AUG_REMOTE_FATAL;
        }
        nap_ms(250);
    }
}

void aug_remote_close(gs_client *c)
{
    if (c)
        gs_client_close(c);
}

/* ERROR or an unexpected frame into msg. AUG_REMOTE_RETRY for the errors a
 * new connection may not meet (the daemon idle-closed, full, loading or
 * draining; the subject gone from the daemon that answered, which a new
 * FIT puts back), AUG_REMOTE_FATAL for the rest. */
static int frame_problem(const gs_client_frame *f, const char *what, char *msg, size_t cap)
{
    if (f->header.type == T(ERROR)) {
        const Gazesplat__Error *e = (const Gazesplat__Error *)f->msg;
        snprintf(msg, cap, "%s: server: %s: %s", what, gs_msg_error_name(e->code), e->message);
        switch (e->code) {
        case GAZESPLAT__ERROR_CODE__ERR_TIMEOUT:
        case GAZESPLAT__ERROR_CODE__ERR_TOO_MANY_CONNECTIONS:
        case GAZESPLAT__ERROR_CODE__ERR_LOADING:
        case GAZESPLAT__ERROR_CODE__ERR_SHUTTING_DOWN:
        case GAZESPLAT__ERROR_CODE__ERR_UNKNOWN_SUBJECT:
            return AUG_REMOTE_RETRY;
        default:
            return AUG_REMOTE_FATAL;
        }
    }
    snprintf(msg, cap, "%s: unexpected frame type %u", what, (unsigned)f->header.type);
    return AUG_REMOTE_FATAL;
}

int aug_remote_fit_one(gs_client *c, const aug_remote_fit *in, aug_remote_subject *out, char *msg,
                       size_t cap)
{
    Gazesplat__FitRequest req = GAZESPLAT__FIT_REQUEST__INIT;
    Gazesplat__Image img = GAZESPLAT__IMAGE__INIT;
    Gazesplat__Angles gaze = GAZESPLAT__ANGLES__INIT, head = GAZESPLAT__ANGLES__INIT;
    int fmt = gs_io_format_sniff(in->image, in->len);
    img.format = fmt == GS_IO_JPEG ? GAZESPLAT__IMAGE_FORMAT__FORMAT_JPEG
                                   : GAZESPLAT__IMAGE_FORMAT__FORMAT_PNG;
    img.data.data = (uint8_t *)in->image;
    img.data.len = in->len;
    img.kind = in->photo ? GAZESPLAT__IMAGE_KIND__KIND_PHOTO
                         : GAZESPLAT__IMAGE_KIND__KIND_NORMALIZED_FACE;
    req.image = &img;
    if (in->known_gaze) {
        gaze.pitch_deg = in->gaze_deg[0];
        gaze.yaw_deg = in->gaze_deg[1];
        req.gaze = &gaze;
    }
    if (in->known_head) {
        head.pitch_deg = in->head_deg[0];
        head.yaw_deg = in->head_deg[1];
        req.head = &head;
    }
    req.max_iters = (uint32_t)in->iters;
    req.finetune_steps = (uint32_t)in->ft_steps;
    req.finetune_lr = in->ft_steps ? in->ft_lr : 0;
    req.keep_image = in->keep_image;
    uint8_t key[16] = {0};
    for (;;) {
        gs_client_frame f;
        gs_error err;
        gs_error_clear(&err);
        if (gs_client_call(c, T(FIT), key, next_id++, &req.base, TIMEOUT_MS, &f, &err) != GS_OK) {
            snprintf(msg, cap, "FIT: %s", err.msg);
            return io_status(&err);
        }
        if (f.header.type == T(BUSY)) {
            unsigned ms = ((const Gazesplat__Busy *)f.msg)->retry_after_ms;
            gs_client_frame_free(&f);
            nap_ms(ms ? ms : 100);
            continue;
        }
        int rc = 0;
        if (f.header.type == T(FIT_OK)) {
            const Gazesplat__FitResult *m = (const Gazesplat__FitResult *)f.msg;
            memcpy(out->key, f.header.key, 16);
            out->gaze_deg[0] = m->gaze ? m->gaze->pitch_deg : NAN;
            out->gaze_deg[1] = m->gaze ? m->gaze->yaw_deg : NAN;
            out->head_deg[0] = m->head ? m->head->pitch_deg : 0;
            out->head_deg[1] = m->head ? m->head->yaw_deg : 0;
            out->psnr = m->psnr;
            out->ssim = m->ssim;
            out->ft_psnr = m->finetune_steps ? m->finetune_psnr : NAN;
            out->cached = m->cached;
        } else
            rc = frame_problem(&f, "FIT", msg, cap);
        gs_client_frame_free(&f);
        return rc;
    }
}

/* One REDIRECT of targets [t0, t0 + n). */
/* The server's Quality as the library's record. */
static void quality_of(const Gazesplat__Quality *m, gs_face_quality *q)
{
    const double deg = 3.14159265358979323846 / 180.0;
    memset(q, 0, sizeof *q);
    q->score = m->score;
    q->eyes = (int)m->eyes;
    if (m->asked) {
        q->commanded[0] = m->asked->pitch_deg * deg;
        q->commanded[1] = m->asked->yaw_deg * deg;
    }
    q->measured[0] = m->seen ? m->seen->pitch_deg * deg : NAN;
    q->measured[1] = m->seen ? m->seen->yaw_deg * deg : NAN;
    q->gaze_error_deg = m->eyes ? m->gaze_error_deg : NAN;
    q->delta_e = m->eyes ? m->iris_delta_e : NAN;
    q->artifact = m->eye_speckle;
    snprintf(q->reason, sizeof q->reason, "%s", m->reason ? m->reason : "");
}

static int render_group(gs_client *c, const aug_remote_subject *s, const aug_remote_target *t,
                        size_t t0, size_t n, int transfer, int size, uint8_t *out, size_t rec,
                        gs_face_quality *q, char *msg, size_t cap)
{
    Gazesplat__Target *tg = calloc(n, sizeof *tg);
    Gazesplat__Target **tp = calloc(n, sizeof *tp);
    Gazesplat__Angles *an = calloc(2 * n, sizeof *an);
    unsigned char *got = calloc(n, 1);
    int rc = 0;
    if (!tg || !tp || !an || !got) {
        snprintf(msg, cap, "out of memory");
        rc = -1;
        goto done;
    }
    for (size_t i = 0; i < n; i++) {
        const aug_remote_target *x = &t[t0 + i];
        gazesplat__target__init(&tg[i]);
        gazesplat__angles__init(&an[2 * i]);
        gazesplat__angles__init(&an[2 * i + 1]);
        an[2 * i].pitch_deg = x->gaze_deg[0];
        an[2 * i].yaw_deg = x->gaze_deg[1];
        tg[i].gaze = &an[2 * i];
        if (x->use_head) {
            an[2 * i + 1].pitch_deg = x->head_deg[0];
            an[2 * i + 1].yaw_deg = x->head_deg[1];
            tg[i].head = &an[2 * i + 1];
        }
        tp[i] = &tg[i];
    }
    Gazesplat__RedirectRequest req = GAZESPLAT__REDIRECT_REQUEST__INIT;
    req.n_targets = n;
    req.targets = tp;
    req.output_format = GAZESPLAT__IMAGE_FORMAT__FORMAT_RAW_RGB8;
    req.transfer = transfer;
    req.quality = q != NULL;
    for (;;) {
        gs_error err;
        gs_error_clear(&err);
        uint32_t id = next_id++;
        if (gs_client_send(c, T(REDIRECT), s->key, id, &req.base, &err) != GS_OK) {
            snprintf(msg, cap, "REDIRECT: %s", err.msg);
            rc = io_status(&err);
            goto done;
        }
        int busy = 0;
        for (;;) {
            gs_client_frame f;
            if (gs_client_recv(c, TIMEOUT_MS, &f, &err) != GS_OK) {
                snprintf(msg, cap, "REDIRECT: %s", err.msg);
                rc = io_status(&err);
                goto done;
            }
            uint16_t type = f.header.type;
            if (type == T(BUSY)) {
                unsigned ms = ((const Gazesplat__Busy *)f.msg)->retry_after_ms;
                gs_client_frame_free(&f);
                nap_ms(ms ? ms : 100);
                busy = 1;
                break;
            }
            if (type == T(IMAGE)) {
                const Gazesplat__ImageResult *m = (const Gazesplat__ImageResult *)f.msg;
                const Gazesplat__Image *im = m->image;
                size_t row = (size_t)size * 3;
                if (m->index >= n || !im || im->format != GAZESPLAT__IMAGE_FORMAT__FORMAT_RAW_RGB8 ||
                    im->width != (uint32_t)size || im->height != (uint32_t)size ||
                    im->stride < row || im->data.len < (size_t)im->stride * (size - 1) + row) {
                    snprintf(msg, cap, "REDIRECT: a malformed IMAGE frame");
                    rc = -1;
                } else {
                    uint8_t *dst = out + (t0 + m->index) * rec;
                    for (int y = 0; y < size; y++)
                        memcpy(dst + (size_t)y * row, im->data.data + (size_t)y * im->stride, row);
                    got[m->index] = 1;
                    if (q && m->quality)
                        quality_of(m->quality, &q[t0 + m->index]);
                }
                gs_client_frame_free(&f);
                if (rc)
                    goto done;
                continue;
            }
            if (type != T(DONE))
                rc = frame_problem(&f, "REDIRECT", msg, cap);
            gs_client_frame_free(&f);
            if (rc)
                goto done;
            break;
        }
        if (!busy)
            break;
    }
    for (size_t i = 0; i < n && !rc; i++)
        if (!got[i]) {
            snprintf(msg, cap, "REDIRECT: no image for target %zu", t0 + i);
            rc = -1;
        }
done:
    free(tg);
    free(tp);
    free(an);
    free(got);
    return rc;
}

int aug_remote_render(gs_client *c, const aug_remote_subject *s, const aug_remote_target *t,
                      size_t n, int transfer, int size, uint8_t *out, size_t rec,
                      gs_face_quality *q, char *msg, size_t cap)
{
    for (size_t i = 0; q && i < n; i++) {
        memset(&q[i], 0, sizeof q[i]);
        q[i].score = NAN;
    }
    for (size_t t0 = 0; t0 < n; t0 += max_targets) {
        size_t k = n - t0 < max_targets ? n - t0 : max_targets;
        int rc = render_group(c, s, t, t0, k, transfer, size, out, rec, q, msg, cap);
        if (rc)
            return rc;
    }
    return 0;
}
