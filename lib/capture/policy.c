/* The eye-contact policy: how much correction to apply, from the tracked
 * gaze and head pose (thresholds after NVIDIA Maxine's eye contact: gaze
 * 20->30 deg, head pitch 15->25 deg, head yaw 25->30 deg). Pure arithmetic
 * plus a mutex so another thread can change the settings at run time. */
#define _GNU_SOURCE
#include <math.h>
#include <pthread.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>

#include "gazesplat/capture.h"

#define DEG (3.14159265358979323846f / 180.0f)

struct gs_cap_policy {
    pthread_mutex_t lock;
    gs_cap_policy_config pending; /* guarded by lock */
    int dirty;                    /* guarded by lock */
    gs_cap_policy_config cfg;     /* the updating thread's copy */
    int started, have_gaze;
    float weight, gaze_pitch, gaze_yaw;
    float closed_s;               /* how long the eyes have been closed */
};

gs_cap_policy_config gs_cap_policy_config_default(void)
{
    gs_cap_policy_config c;
    c.enabled = 1;
    c.strength = 1.0f;
    c.gaze_low_deg = 20.0f;
    c.gaze_high_deg = 30.0f;
    c.head_pitch_low_deg = 15.0f;
    c.head_pitch_high_deg = 25.0f;
    c.head_yaw_low_deg = 25.0f;
    c.head_yaw_high_deg = 30.0f;
    c.smooth_s = 0.1f;
    c.blink_openness = 0.2f;
    c.blink_hold_max_s = 0.5f;
    return c;
}

static int pair_ok(float lo, float hi)
{
    return isfinite(lo) && isfinite(hi) && lo >= 0.0f && lo < hi && hi <= 90.0f;
}

int gs_cap_policy_config_check(const gs_cap_policy_config *c, gs_error *err)
{
    if (!c)
        return gs_error_set(err, GS_ERR_ARG, "policy: NULL config");
    if (!(c->strength >= 0.0f && c->strength <= 1.0f))
        return gs_error_set(err, GS_ERR_ARG, "policy: strength %g outside 0..1",
                            (double)c->strength);
    if (!pair_ok(c->gaze_low_deg, c->gaze_high_deg) ||
        !pair_ok(c->head_pitch_low_deg, c->head_pitch_high_deg) ||
        !pair_ok(c->head_yaw_low_deg, c->head_yaw_high_deg))
        return gs_error_set(err, GS_ERR_ARG, "policy: thresholds need 0 <= low < high <= 90");
    if (!(c->smooth_s >= 0.0f && c->smooth_s <= 10.0f))
        return gs_error_set(err, GS_ERR_ARG, "policy: smooth_s %g outside 0..10",
                            (double)c->smooth_s);
    if (!(c->blink_openness >= 0.0f && c->blink_openness <= 1.0f) ||
        !(c->blink_hold_max_s >= 0.0f && c->blink_hold_max_s <= 10.0f))
        return gs_error_set(err, GS_ERR_ARG, "policy: blink settings out of range");
    return GS_OK;
}

int gs_cap_policy_create(const gs_cap_policy_config *cfg, gs_cap_policy **out, gs_error *err)
{
    gs_cap_policy_config c = cfg ? *cfg : gs_cap_policy_config_default();
    int r = gs_cap_policy_config_check(&c, err);
    if (r != GS_OK)
        return r;
    if (!out)
        return gs_error_set(err, GS_ERR_ARG, "policy: NULL argument");
    gs_cap_policy *p = calloc(1, sizeof *p);
    if (!p)
        return gs_error_set(err, GS_ERR_NOMEM, "policy: out of memory");
    if (pthread_mutex_init(&p->lock, NULL) != 0) {
        free(p);
        return gs_error_set(err, GS_ERR_NOMEM, "policy: mutex");
    }
    p->cfg = p->pending = c;
    *out = p;
    return GS_OK;
}

void gs_cap_policy_destroy(gs_cap_policy *p)
{
    if (!p)
        return;
    pthread_mutex_destroy(&p->lock);
    free(p);
}

int gs_cap_policy_set(gs_cap_policy *p, const gs_cap_policy_config *cfg, gs_error *err)
{
    int r = gs_cap_policy_config_check(cfg, err);
    if (r != GS_OK || !p)
        return p ? r : gs_error_set(err, GS_ERR_ARG, "policy: NULL policy");
    pthread_mutex_lock(&p->lock);
    p->pending = *cfg;
    p->dirty = 1;
    pthread_mutex_unlock(&p->lock);
    return GS_OK;
}

void gs_cap_policy_get(gs_cap_policy *p, gs_cap_policy_config *cfg)
{
    pthread_mutex_lock(&p->lock);
    *cfg = p->pending;
    pthread_mutex_unlock(&p->lock);
}

/* 1 up to lo, 0 from hi, linear between (angles in radians, limits in
 * degrees). */
static float fade(float angle, float lo_deg, float hi_deg)
{
    float a = fabsf(angle) / DEG;
    if (!(a > lo_deg))
        return isnan(a) ? 0.0f : 1.0f;
    if (a >= hi_deg)
        return 0.0f;
    return (hi_deg - a) / (hi_deg - lo_deg);
}

static float target_weight(const gs_cap_policy_config *c, const gs_cap_policy_input *in)
{
    if (!c->enabled || !in->face)
        return 0.0f;
    float f = fade(in->gaze_pitch, c->gaze_low_deg, c->gaze_high_deg);
    f = fminf(f, fade(in->gaze_yaw, c->gaze_low_deg, c->gaze_high_deg));
    f = fminf(f, fade(in->head_pitch, c->head_pitch_low_deg, c->head_pitch_high_deg));
    f = fminf(f, fade(in->head_yaw, c->head_yaw_low_deg, c->head_yaw_high_deg));
    return c->strength * f;
}

void gs_cap_policy_update(gs_cap_policy *p, const gs_cap_policy_input *in,
                          gs_cap_policy_output *out)
{
    pthread_mutex_lock(&p->lock);
    if (p->dirty)
        p->cfg = p->pending;
    p->dirty = 0;
    pthread_mutex_unlock(&p->lock);
    const gs_cap_policy_config *c = &p->cfg;
    float dt = isfinite(in->dt_s) && in->dt_s > 0.0f ? in->dt_s : 0.0f;
    int closed = in->face && in->openness < c->blink_openness;
    p->closed_s = closed ? p->closed_s + dt : 0.0f;
    /* A blink holds everything: the gaze measured through closed lids is
     * noise, and the correction must not flicker on every blink. */
    int held = closed && p->started && c->enabled && p->closed_s <= c->blink_hold_max_s;
    if (!held) {
        float target = closed ? 0.0f : target_weight(c, in);
        float a = c->smooth_s > 0.0f && p->started ? 1.0f - expf(-dt / c->smooth_s) : 1.0f;
        p->weight += a * (target - p->weight);
        if (in->face && !closed && isfinite(in->gaze_pitch) && isfinite(in->gaze_yaw)) {
            float ag = p->have_gaze ? a : 1.0f;
            p->gaze_pitch += ag * (in->gaze_pitch - p->gaze_pitch);
            p->gaze_yaw += ag * (in->gaze_yaw - p->gaze_yaw);
            p->have_gaze = 1;
        }
        p->started = 1;
    }
    out->weight = p->weight;
    out->gaze_pitch = p->gaze_pitch;
    out->gaze_yaw = p->gaze_yaw;
    out->held = held;
}

/* ---- settings by name (the daemon's LIVE_POLICY, the CLI) ---- */

/* The float field called `name`, or NULL. */
static float *field(gs_cap_policy_config *c, const char *name)
{
    struct {
        const char *name;
        float *f;
    } t[] = {{"strength", &c->strength},
             {"gaze_low_deg", &c->gaze_low_deg},
             {"gaze_high_deg", &c->gaze_high_deg},
             {"head_pitch_low_deg", &c->head_pitch_low_deg},
             {"head_pitch_high_deg", &c->head_pitch_high_deg},
             {"head_yaw_low_deg", &c->head_yaw_low_deg},
             {"head_yaw_high_deg", &c->head_yaw_high_deg},
             {"smooth_s", &c->smooth_s},
             {"blink_openness", &c->blink_openness},
             {"blink_hold_max_s", &c->blink_hold_max_s}};
    for (size_t i = 0; i < sizeof t / sizeof t[0]; i++)
        if (!strcmp(name, t[i].name))
            return t[i].f;
    return NULL;
}

static int parse_bool(const char *v, int *out)
{
    static const char *yes[] = {"yes", "true", "on", "1"}, *no[] = {"no", "false", "off", "0"};
    for (int i = 0; i < 4; i++) {
        if (!strcasecmp(v, yes[i]))
            return *out = 1, 0;
        if (!strcasecmp(v, no[i]))
            return *out = 0, 0;
    }
    return -1;
}

int gs_cap_policy_config_set(gs_cap_policy_config *c, const char *key, const char *value,
                             gs_error *err)
{
    if (!c || !key || !value)
        return gs_error_set(err, GS_ERR_ARG, "policy: setting without key or value");
    if (!strcmp(key, "enabled")) {
        if (parse_bool(value, &c->enabled) == 0)
            return GS_OK;
        return gs_error_set(err, GS_ERR_ARG, "policy: enabled: want yes or no, got '%.40s'", value);
    }
    float *f = field(c, key);
    if (f) {
        char *end;
        double d = strtod(value, &end);
        if (end == value || *end || !isfinite(d) || fabs(d) > 1e6)
            return gs_error_set(err, GS_ERR_ARG, "policy: %s: want a number, got '%.40s'", key,
                                value);
        *f = (float)d;
        return GS_OK;
    }
    return gs_error_set(err, GS_ERR_ARG, "policy: unknown key '%.60s'", key);
}

int gs_cap_policy_config_parse(gs_cap_policy_config *c, const char *list, gs_error *err)
{
    gs_cap_policy_config t = *c;
    char buf[1024];
    if (!list || strlen(list) >= sizeof buf)
        return gs_error_set(err, GS_ERR_ARG, "policy: settings list missing or too long");
    strcpy(buf, list);
    char *save = NULL;
    for (char *kv = strtok_r(buf, ",", &save); kv; kv = strtok_r(NULL, ",", &save)) {
        char *eq = strchr(kv, '=');
        if (!eq)
            return gs_error_set(err, GS_ERR_ARG, "policy: want key=value, got '%.40s'", kv);
        *eq = '\0';
        int r = gs_cap_policy_config_set(&t, kv, eq + 1, err);
        if (r != GS_OK)
            return r;
    }
    int r = gs_cap_policy_config_check(&t, err);
    if (r == GS_OK)
        *c = t;
    return r;
}
