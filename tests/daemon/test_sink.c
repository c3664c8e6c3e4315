/* Jobs emit through their sink (daemon/sink.h): jobs that need no model
 * (SLEEP, a stopped job, a FIT or REDIRECT with no model loaded) run on a
 * worker against a recording sink, with no socket and no loop; then the
 * server's frame sink (out.c) packs the same results as frames, counted in
 * the output budget. */
#define _POSIX_C_SOURCE 200809L
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "daemon.h"
#include "gazesplat/clock.h"
#include "gs_test.h"
#include "out.h"
#include "sink.h"

#define E(x) GAZESPLAT__ERROR_CODE__##x
#define T(x) GAZESPLAT__FRAME_TYPE__FRAME_##x

/* What a recording sink was given. */
typedef struct record {
    int images, dones, errors;
    uint16_t type;  /* done: the final type */
    double seconds; /* done: the Done's seconds (SLEEP_OK, DONE) */
    int code;       /* error */
    char text[600];
} record;

static int rec_image(void *ctx, gsd_job *job, const Gazesplat__ImageResult *m)
{
    (void)job;
    (void)m;
    ((record *)ctx)->images++;
    return 0;
}

static void rec_done(void *ctx, gsd_job *job, uint16_t type, const ProtobufCMessage *m)
{
    (void)job;
    record *r = ctx;
    r->dones++;
    r->type = type;
    if (type == T(SLEEP_OK) || type == T(DONE))
        r->seconds = ((const Gazesplat__Done *)m)->seconds;
}

static void rec_error(void *ctx, gsd_job *job, int code, const char *text)
{
    (void)job;
    record *r = ctx;
    r->errors++;
    r->code = code;
    snprintf(r->text, sizeof r->text, "%s", text);
}

static gsd_server *server_new(void)
{
    gsd_server *s = calloc(1, sizeof *s);
    if (!s)
        abort();
    s->cfg.threads = 1; /* no pool */
    s->cfg.workers = 1;
    s->cfg.sweep_subjects = 1;
    s->cfg.tuned_subjects = 1;
    pthread_mutex_init(&s->model_mu, NULL);
    pthread_mutex_init(&s->post_mu, NULL);
    return s;
}

/* A job of type `type` on request req, as the loop makes one, with the
 * recording sink over r. */
static void job_init(gsd_job *j, gsd_server *s, uint16_t type, ProtobufCMessage *req, record *r)
{
    memset(j, 0, sizeof *j);
    memset(r, 0, sizeof *r);
    j->srv = s;
    j->type = type;
    j->version = 1;
    j->request_id = 42;
    for (int i = 0; i < GS_FRAME_KEY_SIZE; i++)
        j->key[i] = (uint8_t)(0xa0 + i);
    j->enqueued_ms = gs_clock_ms();
    j->deadline_ms = j->enqueued_ms + 60000;
    j->req = req;
    gsd_sink k = {rec_image, rec_done, rec_error, r};
    j->sink = k;
}

static void test_recording(void)
{
    gsd_server *s = server_new();
    gsd_worker *w = gsd_worker_create(s, 0);
    CHECK(w != NULL);
    gsd_job j;
    record r;

    /* A SLEEP ends with SLEEP_OK, its one final result. */
    Gazesplat__Sleep sl = GAZESPLAT__SLEEP__INIT;
    sl.ms = 5;
    job_init(&j, s, T(SLEEP), &sl.base, &r);
    gsd_worker_run(w, &j);
    CHECK(r.dones == 1 && r.errors == 0 && r.images == 0);
    CHECK_EQ_INT(r.type, T(SLEEP_OK));
    CHECK(r.seconds >= 0.004 && r.seconds < 10);
    CHECK_EQ_INT(j.result, 0);
    CHECK(j.started_ms >= j.enqueued_ms);

    /* A job cancelled before it runs: CANCELLED, counted, in its log line. */
    job_init(&j, s, T(SLEEP), &sl.base, &r);
    atomic_store(&j.stop, E(ERR_CANCELLED));
    gsd_worker_run(w, &j);
    CHECK(r.dones == 0 && r.errors == 1);
    CHECK_EQ_INT(r.code, E(ERR_CANCELLED));
    CHECK(strcmp(r.text, "cancelled") == 0);
    CHECK_EQ_INT(j.result, E(ERR_CANCELLED));
    CHECK_EQ_INT((int)atomic_load(&s->ctr.cancelled), 1);

    /* A SLEEP whose deadline passes while it sleeps. */
    sl.ms = 60000;
    job_init(&j, s, T(SLEEP), &sl.base, &r);
    j.deadline_ms = gs_clock_ms() + 20;
    gsd_worker_run(w, &j);
    CHECK(r.dones == 0 && r.errors == 1);
    CHECK_EQ_INT(r.code, E(ERR_DEADLINE));
    CHECK(strcmp(r.text, "deadline passed") == 0);
    CHECK_EQ_INT((int)atomic_load(&s->ctr.deadline_exceeded), 1);

    /* FIT and REDIRECT with no model loaded. */
    Gazesplat__FitRequest fr = GAZESPLAT__FIT_REQUEST__INIT;
    job_init(&j, s, T(FIT), &fr.base, &r);
    gsd_worker_run(w, &j);
    CHECK(r.dones == 0 && r.errors == 1 && r.images == 0);
    CHECK_EQ_INT(r.code, E(ERR_NO_MODEL));
    CHECK(strcmp(r.text, "no model loaded") == 0);
    Gazesplat__RedirectRequest rr = GAZESPLAT__REDIRECT_REQUEST__INIT;
    job_init(&j, s, T(REDIRECT), &rr.base, &r);
    gsd_worker_run(w, &j);
    CHECK(r.errors == 1 && r.images == 0);
    CHECK_EQ_INT(r.code, E(ERR_NO_MODEL));

    /* An error's text is cut at 511 bytes, as the frames always had it. */
    char long_text[700];
    memset(long_text, 'x', sizeof long_text - 1);
    long_text[sizeof long_text - 1] = 0;
    job_init(&j, s, T(SLEEP), &sl.base, &r);
    gsd_emit_error(&j, E(ERR_INTERNAL), "%s", long_text);
    CHECK_EQ_INT((int)strlen(r.text), 511);
    CHECK_EQ_INT(j.result, E(ERR_INTERNAL));

    gsd_worker_destroy(w);
    CHECK_EQ_INT((int)atomic_load(&s->out_total), 0); /* no frame was ever made */
    free(s);
}

/* Takes the one frame posted since the last call. */
static gsd_out *take_post(gsd_server *s)
{
    gsd_out *o = s->post_head;
    CHECK(o != NULL && o->next == NULL);
    s->post_head = s->post_tail = NULL;
    return o;
}

/* The frame's header echoes the job; returns its payload's message of type
 * `type` (unpacked; free it). */
static ProtobufCMessage *frame_check(const gsd_out *o, const gsd_job *j, uint16_t type)
{
    gs_frame_header h;
    CHECK(o->len >= GS_FRAME_HEADER_SIZE);
    CHECK(gs_frame_header_unpack(o->data, &h) == 0);
    CHECK_EQ_INT(h.type, type);
    CHECK_EQ_INT(h.version, j->version);
    CHECK_EQ_INT((int)h.request_id, (int)j->request_id);
    CHECK(memcmp(h.key, j->key, GS_FRAME_KEY_SIZE) == 0);
    CHECK_EQ_INT((int)h.payload_len, (int)(o->len - GS_FRAME_HEADER_SIZE));
    return protobuf_c_message_unpack(gs_msg_descriptor(type), NULL, h.payload_len,
                                     o->data + GS_FRAME_HEADER_SIZE);
}

static void on_wake(ev_loop *loop, void *ctx)
{
    (void)loop;
    (void)ctx;
}

static void test_frame_sink(void)
{
    gsd_server *s = server_new();
    s->loop = ev_create(on_wake, s);
    CHECK(s->loop != NULL);
    gsd_worker *w = gsd_worker_create(s, 0);
    gsd_job j;
    record r;

    /* SLEEP_OK: the final frame, counted in the budget and the job's bytes
     * until it is freed. */
    Gazesplat__Sleep sl = GAZESPLAT__SLEEP__INIT;
    job_init(&j, s, T(SLEEP), &sl.base, &r);
    j.sink = gsd_frame_sink(s);
    gsd_worker_run(w, &j);
    gsd_out *o = take_post(s);
    CHECK(o->final && o->job == &j && !o->request_error);
    CHECK_EQ_INT((int)atomic_load(&s->out_total), (int)o->len);
    CHECK_EQ_INT((int)atomic_load(&j.out_bytes), (int)o->len);
    ProtobufCMessage *m = frame_check(o, &j, T(SLEEP_OK));
    CHECK(m != NULL);
    if (m)
        protobuf_c_message_free_unpacked(m, NULL);
    gsd_out_free(s, o);
    CHECK_EQ_INT((int)atomic_load(&s->out_total), 0);
    CHECK_EQ_INT((int)atomic_load(&j.out_bytes), 0);

    /* A FIT with no model: a final ERROR that counts as a request error. */
    Gazesplat__FitRequest fr = GAZESPLAT__FIT_REQUEST__INIT;
    job_init(&j, s, T(FIT), &fr.base, &r);
    j.sink = gsd_frame_sink(s);
    gsd_worker_run(w, &j);
    o = take_post(s);
    CHECK(o->final && o->request_error);
    Gazesplat__Error *e = (Gazesplat__Error *)frame_check(o, &j, T(ERROR));
    CHECK(e != NULL && e->code == E(ERR_NO_MODEL) && e->request_id == 42);
    CHECK(e && strcmp(e->message, "no model loaded") == 0);
    if (e)
        protobuf_c_message_free_unpacked(&e->base, NULL);
    gsd_out_free(s, o);

    /* A cancelled job's ERROR has its own counter, not request_errors; a
     * job no worker took (work.c's answers) has no run time. */
    job_init(&j, s, T(SLEEP), &sl.base, &r);
    j.sink = gsd_frame_sink(s);
    gsd_emit_error(&j, E(ERR_CANCELLED), "cancelled");
    o = take_post(s);
    CHECK(o->final && !o->request_error && o->job_ms == 0);
    gsd_out_free(s, o);

    /* An image: not final, the job's bytes until freed. */
    job_init(&j, s, T(REDIRECT), NULL, &r);
    j.sink = gsd_frame_sink(s);
    Gazesplat__ImageResult im = GAZESPLAT__IMAGE_RESULT__INIT;
    im.index = 3;
    im.dropped = 1;
    CHECK(gsd_emit_image(&j, &im) == 0);
    o = take_post(s);
    CHECK(!o->final && o->job == &j);
    CHECK_EQ_INT((int)atomic_load(&j.out_bytes), (int)o->len);
    Gazesplat__ImageResult *ir = (Gazesplat__ImageResult *)frame_check(o, &j, T(IMAGE));
    CHECK(ir != NULL && ir->index == 3 && ir->dropped);
    if (ir)
        protobuf_c_message_free_unpacked(&ir->base, NULL);
    gsd_out_free(s, o);
    CHECK_EQ_INT((int)atomic_load(&s->out_total), 0);

    gsd_worker_destroy(w);
    ev_destroy(s->loop);
    free(s);
}

int main(void)
{
    test_recording();
    test_frame_sink();
    GS_TEST_END();
}
