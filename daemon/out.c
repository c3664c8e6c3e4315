/* What a job sends back (out.h): the frame sink (sink.h), frames packed
 * for the job's connection, and the post queue that hands them to the
 * loop thread. Jobs and workers reach it only through their sink; the
 * loop (server.c) drains the queue into connections. */
#include "out.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "gazesplat/clock.h"
#include "gazesplat/error.h"
#include "log.h"

#define E(x) GAZESPLAT__ERROR_CODE__##x
#define T(x) GAZESPLAT__FRAME_TYPE__FRAME_##x

/* Every output frame is counted in s->out_total from here to gsd_out_free,
 * and in its job's out_bytes while o->job is set. */
gsd_out *gsd_out_pack(gsd_server *s, const gs_frame_header *h, const ProtobufCMessage *msg)
{
    uint8_t *buf;
    size_t len;
    if (gs_msg_pack(h, msg, GS_FRAME_HARD_MAX_PAYLOAD, &buf, &len) != 0)
        return NULL;
    gsd_out *o = malloc(sizeof *o + len);
    if (o) {
        memset(o, 0, sizeof *o);
        o->len = len;
        memcpy(o->data, buf, len);
        atomic_fetch_add(&s->out_total, len);
    }
    free(buf);
    return o;
}

static void out_attach(gsd_out *o, const gsd_job *job)
{
    o->job = (gsd_job *)job;
    atomic_fetch_add(&o->job->out_bytes, o->len);
}

void gsd_out_free(gsd_server *s, gsd_out *o)
{
    atomic_fetch_sub(&s->out_total, o->len);
    if (o->job)
        atomic_fetch_sub(&o->job->out_bytes, o->len);
    free(o);
}

static gsd_out *frame_new(const gsd_job *job, uint16_t type, const ProtobufCMessage *msg)
{
    gs_frame_header h;
    memset(&h, 0, sizeof h);
    h.version = job->version;
    h.type = type;
    h.request_id = job->request_id;
    memcpy(h.key, job->key, GS_FRAME_KEY_SIZE);
    gsd_out *o = gsd_out_pack(job->srv, &h, msg);
    if (o)
        out_attach(o, job);
    return o;
}

gsd_out *gsd_out_error(gsd_server *s, const gs_frame_header *h, int code, const char *text)
{
    Gazesplat__Error e = GAZESPLAT__ERROR__INIT;
    e.code = (Gazesplat__ErrorCode)code;
    e.message = (char *)text;
    e.request_id = h->request_id;
    gs_frame_header eh = *h;
    eh.type = T(ERROR);
    return gsd_out_pack(s, &eh, &e.base);
}

static gsd_out *error_frame(const gsd_job *job, int code, const char *text)
{
    gs_frame_header h;
    memset(&h, 0, sizeof h);
    h.version = job->version;
    h.request_id = job->request_id;
    memcpy(h.key, job->key, GS_FRAME_KEY_SIZE);
    Gazesplat__Error e = GAZESPLAT__ERROR__INIT;
    e.code = (Gazesplat__ErrorCode)code;
    e.message = (char *)text;
    e.request_id = h.request_id;
    if (code == E(ERR_FACE_REFUSED))
        e.refusal = (Gazesplat__FaceRefusal)job->refusal;
    h.type = T(ERROR);
    gsd_out *o = gsd_out_pack(job->srv, &h, &e.base);
    if (o) {
        out_attach(o, job);
        /* Cancellations and deadlines have counters of their own. */
        o->request_error = code != E(ERR_CANCELLED) && code != E(ERR_DEADLINE);
    }
    return o;
}

static void post(gsd_server *s, gsd_out *o)
{
    if (!o) {
        LOG_E("out of memory building a reply; a request stays unanswered");
        return;
    }
    pthread_mutex_lock(&s->post_mu);
    o->next = NULL;
    if (s->post_tail)
        s->post_tail->next = o;
    else
        s->post_head = o;
    s->post_tail = o;
    pthread_mutex_unlock(&s->post_mu);
    ev_wake(s->loop);
}

/* The job's last frame: the loop frees the job once it has it; job_ms is
 * its run time from when a worker took it (0 when none did). */
static void post_final(gsd_server *s, const gsd_job *job, gsd_out *o)
{
    if (o) {
        o->final = 1;
        o->job_ms = job->started_ms ? (uint64_t)(gs_clock_ms() - job->started_ms) : 0;
    }
    post(s, o);
}

static int sink_image(void *ctx, gsd_job *job, const Gazesplat__ImageResult *m)
{
    gsd_out *o = frame_new(job, T(IMAGE), &m->base);
    if (!o)
        return -1;
    post(ctx, o);
    return 0;
}

static void sink_done(void *ctx, gsd_job *job, uint16_t type, const ProtobufCMessage *m)
{
    post_final(ctx, job, frame_new(job, type, m));
}

static void sink_error(void *ctx, gsd_job *job, int code, const char *text)
{
    post_final(ctx, job, error_frame(job, code, text));
}

gsd_sink gsd_frame_sink(gsd_server *s)
{
    gsd_sink k = {sink_image, sink_done, sink_error, s};
    return k;
}

/* A library status (gs_status) as the ErrorCode a computing job answers
 * with: the one table for every step (fit, fine-tune, render). Inputs have
 * their own answers (an image that does not decode is BAD_IMAGE, a face
 * the gate refuses FACE_REFUSED: compute.c). */
int gsd_status_error(int status)
{
    static const struct {
        int status, code;
    } table[] = {
        {GS_ERR_ARG, E(ERR_INVALID_ARGUMENT)}, /* a request the model cannot take */
        {GS_ERR_CANCELLED, E(ERR_CANCELLED)},
    };
    for (size_t i = 0; i < sizeof table / sizeof table[0]; i++)
        if (table[i].status == status)
            return table[i].code;
    return E(ERR_INTERNAL); /* out of memory, non-finite, I/O: the server's failure */
}
