/* The eye-contact policy: thresholds, strength and off, smoothing, blink
 * hold, settings changed from another thread. */
#include <math.h>
#include <pthread.h>
#include <string.h>

#include "gazesplat/capture.h"
#include "gs_test.h"

#define DEG (3.14159265358979323846f / 180.0f)

static gs_cap_policy_input look(float gp, float gy, float hp, float hy)
{
    gs_cap_policy_input in = {1, gp * DEG, gy * DEG, hp * DEG, hy * DEG, 1.0f, 1.0f / 30};
    return in;
}

static float weight_of(gs_cap_policy *p, gs_cap_policy_input in)
{
    gs_cap_policy_output o;
    gs_cap_policy_update(p, &in, &o);
    return o.weight;
}

static gs_cap_policy *make(float smooth)
{
    gs_cap_policy_config c = gs_cap_policy_config_default();
    c.smooth_s = smooth;
    gs_cap_policy *p = NULL;
    CHECK_EQ_INT(gs_cap_policy_create(&c, &p, NULL), GS_OK);
    return p;
}

static void test_thresholds(void)
{
    gs_cap_policy *p = make(0.0f);
    CHECK_CLOSE(weight_of(p, look(0, 0, 0, 0)), 1.0, 1e-6, 0);
    CHECK_CLOSE(weight_of(p, look(20, 0, 0, 0)), 1.0, 1e-5, 0);
    CHECK_CLOSE(weight_of(p, look(25, 0, 0, 0)), 0.5, 1e-5, 0);
    CHECK_CLOSE(weight_of(p, look(0, -27.5f, 0, 0)), 0.25, 1e-5, 0);
    CHECK_CLOSE(weight_of(p, look(0, 31, 0, 0)), 0.0, 1e-6, 0);
    CHECK_CLOSE(weight_of(p, look(0, 0, 20, 0)), 0.5, 1e-5, 0);
    CHECK_CLOSE(weight_of(p, look(0, 0, -26, 0)), 0.0, 1e-6, 0);
    CHECK_CLOSE(weight_of(p, look(0, 0, 0, 27.5f)), 0.5, 1e-5, 0);
    CHECK_CLOSE(weight_of(p, look(0, 0, 0, 24)), 1.0, 1e-5, 0);
    /* The smallest factor wins. */
    CHECK_CLOSE(weight_of(p, look(25, 0, 22.5f, 0)), 0.25, 1e-5, 0);
    gs_cap_policy_input nan_in = look(NAN, 0, 0, 0);
    CHECK_CLOSE(weight_of(p, nan_in), 0.0, 1e-6, 0);
    gs_cap_policy_input noface = look(0, 0, 0, 0);
    noface.face = 0;
    CHECK_CLOSE(weight_of(p, noface), 0.0, 1e-6, 0);
    gs_cap_policy_config c = gs_cap_policy_config_default();
    c.smooth_s = 0;
    c.strength = 0.4f;
    CHECK_EQ_INT(gs_cap_policy_set(p, &c, NULL), GS_OK);
    CHECK_CLOSE(weight_of(p, look(25, 0, 0, 0)), 0.2, 1e-5, 0);
    c.enabled = 0;
    CHECK_EQ_INT(gs_cap_policy_set(p, &c, NULL), GS_OK);
    CHECK_CLOSE(weight_of(p, look(0, 0, 0, 0)), 0.0, 1e-6, 0);
    gs_cap_policy_destroy(p);
}

static void test_config_check(void)
{
    gs_cap_policy_config c = gs_cap_policy_config_default();
    CHECK_EQ_INT(gs_cap_policy_config_check(&c, NULL), GS_OK);
    c.gaze_low_deg = 30;
    CHECK_EQ_INT(gs_cap_policy_config_check(&c, NULL), GS_ERR_ARG);
    c = gs_cap_policy_config_default();
    c.strength = 1.5f;
    CHECK_EQ_INT(gs_cap_policy_config_check(&c, NULL), GS_ERR_ARG);
    c = gs_cap_policy_config_default();
    c.smooth_s = NAN;
    CHECK_EQ_INT(gs_cap_policy_config_check(&c, NULL), GS_ERR_ARG);
    c = gs_cap_policy_config_default();
    c.head_yaw_high_deg = 95;
    CHECK_EQ_INT(gs_cap_policy_config_check(&c, NULL), GS_ERR_ARG);
    gs_cap_policy *p = make(0.1f);
    c.head_yaw_high_deg = 95;
    CHECK_EQ_INT(gs_cap_policy_set(p, &c, NULL), GS_ERR_ARG);
    gs_cap_policy_config got;
    gs_cap_policy_get(p, &got);
    CHECK_CLOSE(got.head_yaw_high_deg, 30.0, 0, 0);
    gs_cap_policy_destroy(p);
}

/* First frame snaps; afterwards an exponential with time constant 0.1 s. */
static void test_smoothing(void)
{
    gs_cap_policy *p = make(0.1f);
    CHECK_CLOSE(weight_of(p, look(0, 0, 0, 0)), 1.0, 1e-6, 0);
    float w = 0;
    for (int i = 0; i < 3; i++)
        w = weight_of(p, look(40, 0, 0, 0));
    CHECK_CLOSE(w, exp(-1.0), 1e-4, 0);
    gs_cap_policy_output o;
    gs_cap_policy_input in = look(10, 0, 0, 0);
    gs_cap_policy_update(p, &in, &o);
    /* Gaze follows with the same filter: from 40 deg toward 10. */
    CHECK(o.gaze_pitch > 10 * DEG && o.gaze_pitch < 40 * DEG);
    gs_cap_policy_destroy(p);
}

/* A blink holds weight and gaze; eyes closed past the limit fade out. */
static void test_blink(void)
{
    gs_cap_policy *p = make(0.0f);
    gs_cap_policy_output o;
    gs_cap_policy_input in = look(24, 3, 0, 0);
    gs_cap_policy_update(p, &in, &o);
    CHECK_CLOSE(o.weight, 0.6, 1e-5, 0);
    in = look(45, -20, 0, 0);
    in.openness = 0.05f;
    for (int i = 0; i < 12; i++) { /* 0.4 s */
        gs_cap_policy_update(p, &in, &o);
        CHECK(o.held == 1);
        CHECK_CLOSE(o.weight, 0.6, 1e-6, 0);
        CHECK_CLOSE(o.gaze_pitch, 24 * DEG, 1e-6, 0);
    }
    for (int i = 0; i < 6; i++)
        gs_cap_policy_update(p, &in, &o);
    CHECK(o.held == 0);
    CHECK_CLOSE(o.weight, 0.0, 1e-6, 0);
    in = look(0, 0, 0, 0);
    gs_cap_policy_update(p, &in, &o);
    CHECK_CLOSE(o.weight, 1.0, 1e-6, 0);
    gs_cap_policy_destroy(p);
}

static void *setter(void *arg)
{
    gs_cap_policy *p = arg;
    gs_cap_policy_config c = gs_cap_policy_config_default();
    for (int i = 0; i < 2000; i++) {
        c.strength = (float)(i % 2);
        gs_cap_policy_set(p, &c, NULL);
    }
    return NULL;
}

static void test_threads(void)
{
    gs_cap_policy *p = make(0.0f);
    pthread_t t;
    CHECK(pthread_create(&t, NULL, setter, p) == 0);
    for (int i = 0; i < 2000; i++) {
        float w = weight_of(p, look(0, 0, 0, 0));
        CHECK(w == 0.0f || w == 1.0f);
    }
    pthread_join(t, NULL);
    gs_cap_policy_destroy(p);
}

/* Settings by name: all or nothing, ranges checked on the result. */
static void test_parse(void)
{
    gs_cap_policy_config c = gs_cap_policy_config_default();
    gs_error e = {0};
    CHECK_EQ_INT(gs_cap_policy_config_parse(&c, "strength=0.5,enabled=off,smooth_s=0.25", &e),
                 GS_OK);
    CHECK(c.strength == 0.5f && c.enabled == 0 && c.smooth_s == 0.25f);
    /* low above the old high, then high: fine in this order */
    CHECK_EQ_INT(gs_cap_policy_config_parse(&c, "gaze_low_deg=35,gaze_high_deg=45", &e), GS_OK);
    CHECK(c.gaze_low_deg == 35.0f && c.gaze_high_deg == 45.0f);
    static const char *bad[] = {"strength=2",  "gaze_low_deg=50", "nope=1",        "strength=nan",
                                "enabled=maybe", "strength",      "smooth_s=1e30", "strength=0.1x",
                                "strength=0.7,bogus=1", "blink_openness="};
    for (size_t i = 0; i < sizeof bad / sizeof bad[0]; i++) {
        gs_cap_policy_config before = c;
        int r = gs_cap_policy_config_parse(&c, bad[i], &e);
        CHECK_MSG(r == GS_ERR_ARG, "'%s' accepted", bad[i]);
        CHECK_MSG(memcmp(&before, &c, sizeof c) == 0, "'%s' changed the config", bad[i]);
    }
    CHECK_EQ_INT(gs_cap_policy_config_set(&c, "enabled", "YES", &e), GS_OK);
    CHECK_EQ_INT(c.enabled, 1);
}

int main(void)
{
    test_parse();
    test_thresholds();
    test_config_check();
    test_smoothing();
    test_blink();
    test_threads();
    GS_TEST_END();
}
