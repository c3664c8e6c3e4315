/* gazesplatd's live pipeline: camera -> eye contact -> v4l2loopback,
 * hosted by the daemon when live.device is set, so the one process that
 * holds the model serves both the socket API and the virtual camera, and
 * the policy is changed over the daemon's own socket (LIVE_POLICY,
 * LIVE_STATUS).
 *
 * The pipeline starts with the server (pass-through, the "no video" frame
 * while the camera is missing); the eye-contact stage is attached once the
 * first model and the landmark model are loaded. It keeps that model for
 * its life: a SIGHUP reload serves the socket API with the new model but
 * the live stage needs a restart to change. */
#define _GNU_SOURCE
#include <math.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "gazesplat/capture.h"
#include "gazesplat/live.h"
#include "log.h"
#include "daemon.h"

#define E(x) GAZESPLAT__ERROR_CODE__##x
#define RAD2DEG (180.0 / M_PI)

struct gsd_live {
    gs_cap *cap;
    gs_cap_out *out;
    gs_cap_pipe *pipe;
    gs_cap_policy *policy;
    gs_cap_hotplug *hotplug;
    _Atomic(gs_live_stage *) stage; /* NULL: pass-through */
    gs_live_engine engine;
    gs_face_detector *det;
    gs_live_face_models fm;
    gsd_model *model;               /* the reference the stage renders with */
    char device[GSD_STR_MAX], output[GSD_STR_MAX];
    char detail[320];               /* (loop) */
    atomic_int streaming;
};

static int live_process(void *ctx, uint8_t *rgb, size_t stride, int w, int h, int64_t t,
                        gs_error *err)
{
    gsd_live *l = ctx;
    gs_live_stage *st = atomic_load(&l->stage);
    return st ? gs_live_stage_process(st, rgb, stride, w, h, t, err) : GS_OK;
}

static void live_event(void *user, gs_cap_pipe_event ev, const char *msg)
{
    gsd_live *l = user;
    if (ev == GS_CAP_EV_STREAMING)
        atomic_store(&l->streaming, 1);
    if (ev == GS_CAP_EV_LOST)
        atomic_store(&l->streaming, 0);
    if (ev == GS_CAP_EV_STAGE_ERROR)
        LOG_D("live: %s", msg);
    else
        LOG_I("live: %s", msg);
}

static void live_hotplug(void *user, gs_cap_hotplug_event ev, uint16_t vid, uint16_t pid)
{
    gsd_live *l = user;
    LOG_I("live: USB %04x:%04x %s", vid, pid, ev == GS_CAP_HOTPLUG_ARRIVED ? "arrived" : "left");
    if (ev == GS_CAP_HOTPLUG_ARRIVED)
        gs_cap_kick(l->cap);
}

int gsd_live_start(gsd_server *s, char *msg, size_t cap)
{
    const gsd_config *c = &s->cfg;
    if (!c->live_device[0])
        return 0;
    gsd_live *l = calloc(1, sizeof *l);
    if (!l) {
        snprintf(msg, cap, "live: out of memory");
        return -1;
    }
    s->live = l;
    gs_error e = {0};
    gs_cap_resolve_opts ro = {NULL, NULL, 1};
    char found[sizeof l->device];
    /* A usb: camera is looked up again at every open (a camera plugged in
     * after the start, or back as another videoN): the capture gets the
     * spec itself. */
    snprintf(l->device, sizeof l->device, "%s", c->live_device);
    if (gs_cap_resolve(c->live_device, &ro, found, sizeof found, &e) != GS_OK)
        LOG_W("live: %s; waiting for it", e.msg);
    else if (strcmp(found, c->live_device))
        LOG_I("live: %s is %s now", c->live_device, found);
    snprintf(l->output, sizeof l->output, "%s", c->live_output);
    gs_cap_config cc = gs_cap_config_default(l->device);
    cc.width = c->live_width;
    cc.height = c->live_height;
    cc.fps = c->live_fps;
    int r = gs_cap_create(&cc, &l->cap, &e);
    if (r == GS_OK)
        r = gs_cap_policy_create(NULL, &l->policy, &e);
    if (r == GS_OK && l->output[0])
        r = gs_cap_out_create(l->output, c->live_width & ~1, c->live_height, c->live_fps, NULL,
                              &l->out, &e);
    if (r == GS_OK) {
        gs_cap_stage stage = {l, live_process};
        gs_cap_pipe_config pc = {l->cap, stage, l->out, 2, NULL, live_event, l, 0};
        r = gs_cap_pipe_start(&pc, &l->pipe, &e);
    }
    if (r != GS_OK) {
        snprintf(msg, cap, "live: %s", e.msg);
        return -1;
    }
    if (strncmp(c->live_device, "usb:", 4) == 0) {
        gs_cap_usb_id id;
        if (gs_cap_usb_id_parse(c->live_device, &id, NULL) == GS_OK &&
            gs_cap_hotplug_start(&id, 0, live_hotplug, l, &l->hotplug, &e) != GS_OK)
            LOG_W("live: hotplug off: %s", e.msg);
    }
    snprintf(l->detail, sizeof l->detail, "waiting for the model");
    LOG_I("live: %s -> %s (pass-through until the model is loaded)", l->device,
          l->output[0] ? l->output : "(no output)");
    return 0;
}

void gsd_live_model_ready(gsd_server *s)
{
    gsd_live *l = s->live;
    if (!l || atomic_load(&l->stage))
        return;
    if (!s->face_sp) {
        snprintf(l->detail, sizeof l->detail, "no landmark model (photo_input and face_landmarks)");
        LOG_W("live: %s: pass-through", l->detail);
        return;
    }
    gs_error e = {0};
    const struct gs_model *m = gsd_model_get(s, &l->model);
    int r = m ? GS_OK : gs_error_set(&e, GS_ERR_STATE, "no model");
    if (r == GS_OK)
        r = gs_face_detector_load(s->face_cascade, &l->det, &e);
    if (r == GS_OK)
        r = gs_live_engine_model(m, NULL, s->cfg.live_fit_budget_s, &l->engine, &e);
    l->fm.det = l->det;
    l->fm.sp = s->face_sp;
    gs_live_track_ops ops = gs_live_track_ops_face(&l->fm);
    gs_live_stage *st = NULL;
    if (r == GS_OK)
        r = gs_live_stage_create(NULL, &ops, &l->engine, l->policy, &st, &e);
    if (r != GS_OK) {
        snprintf(l->detail, sizeof l->detail, "eye contact unavailable: %s", e.msg);
        LOG_W("live: %s", l->detail);
        return;
    }
    atomic_store(&l->stage, st);
    l->detail[0] = '\0';
    LOG_I("live: eye contact ready (fits the subject in the background)");
}

void gsd_live_stop(gsd_server *s)
{
    gsd_live *l = s->live;
    if (!l)
        return;
    gs_cap_hotplug_stop(l->hotplug);
    gs_cap_pipe_stop(l->pipe); /* no stage call after this */
    gs_live_stage_destroy(atomic_load(&l->stage));
    gs_live_engine_model_free(&l->engine);
    gs_face_detector_destroy(l->det);
    gsd_model_put(l->model);
    gs_cap_out_destroy(l->out);
    gs_cap_destroy(l->cap);
    gs_cap_policy_destroy(l->policy);
    free(l);
    s->live = NULL;
}

/* ---- LIVE_POLICY ---- */

static void fill_policy(const gs_cap_policy_config *c, Gazesplat__LivePolicy *p)
{
    p->enabled = c->enabled != 0;
    p->strength = c->strength;
    p->gaze_low_deg = c->gaze_low_deg;
    p->gaze_high_deg = c->gaze_high_deg;
    p->head_pitch_low_deg = c->head_pitch_low_deg;
    p->head_pitch_high_deg = c->head_pitch_high_deg;
    p->head_yaw_low_deg = c->head_yaw_low_deg;
    p->head_yaw_high_deg = c->head_yaw_high_deg;
    p->smooth_s = c->smooth_s;
    p->blink_openness = c->blink_openness;
    p->blink_hold_max_s = c->blink_hold_max_s;
}

int gsd_live_policy(gsd_server *s, const Gazesplat__LivePolicyRequest *r, Gazesplat__LivePolicy *out,
                    char *msg, size_t cap)
{
    /* Field validation before server state (PROTOCOL.md's check order):
     * every setting must name a key and parse, live pipeline or not. The
     * result's range depends on the policy in force, so it is checked
     * after ERR_LIVE_OFF. */
    gsd_live *l = s->live;
    gs_cap_policy_config c = gs_cap_policy_config_default();
    if (l)
        gs_cap_policy_get(l->policy, &c);
    gs_error e = {0};
    for (size_t i = 0; i < r->n_set; i++)
        if (gs_cap_policy_config_set(&c, r->set[i]->key, r->set[i]->value, &e) != GS_OK) {
            snprintf(msg, cap, "%s", e.msg);
            return E(ERR_INVALID_ARGUMENT);
        }
    if (!l) {
        snprintf(msg, cap, "this server hosts no live pipeline (live.device is not set)");
        return E(ERR_LIVE_OFF);
    }
    if (r->n_set && gs_cap_policy_set(l->policy, &c, &e) != GS_OK) {
        snprintf(msg, cap, "%s", e.msg);
        return E(ERR_INVALID_ARGUMENT);
    }
    if (r->n_set)
        LOG_I("live: policy changed (%zu settings)", r->n_set);
    gs_live_stage *st = atomic_load(&l->stage);
    if (r->refit && st) {
        gs_live_stage_refit(st);
        LOG_I("live: refit requested");
    }
    fill_policy(&c, out);
    return 0;
}

void gsd_live_status(gsd_server *s, Gazesplat__LiveStatus *m, Gazesplat__LivePolicy *pol,
                     Gazesplat__Angles *head, Gazesplat__Angles *corr)
{
    gsd_live *l = s->live;
    if (!l) {
        m->running = 0;
        m->detail = "live.device is not set";
        return;
    }
    m->running = 1;
    m->device = l->device;
    m->output = l->output;
    m->streaming = atomic_load(&l->streaming) != 0;
    gs_cap_pipe_stats ps;
    gs_cap_pipe_get_stats(l->pipe, &ps);
    m->frames_in = ps.in;
    m->frames_out = ps.out;
    m->placeholders = ps.placeholders;
    m->reopens = ps.cap.opens ? ps.cap.opens - 1 : 0;
    m->latency_p50_ms = (float)ps.total.p50_ms;
    m->latency_p99_ms = (float)ps.total.p99_ms;
    gs_cap_policy_config c;
    gs_cap_policy_get(l->policy, &c);
    fill_policy(&c, pol);
    m->policy = pol;
    m->detail = l->detail;
    gs_live_stage *st = atomic_load(&l->stage);
    if (!st)
        return;
    gs_live_status ls;
    gs_live_stage_get_status(st, &ls);
    m->face = ls.face != 0;
    m->subject_ready = ls.subject_ready != 0;
    m->fitting = ls.fitting != 0;
    m->fits = ls.fits;
    m->refits = ls.refits;
    m->renders = ls.renders;
    m->weight = ls.weight;
    head->pitch_deg = ls.head_pitch * RAD2DEG;
    head->yaw_deg = ls.head_yaw * RAD2DEG;
    corr->pitch_deg = ls.target_pitch * RAD2DEG;
    corr->yaw_deg = ls.target_yaw * RAD2DEG;
    m->head = head;
    m->correction = corr;
    if (!m->subject_ready)
        m->detail = m->fitting ? "fitting the subject (pass-through)"
                               : "waiting for a frontal face to fit (pass-through)";
}
