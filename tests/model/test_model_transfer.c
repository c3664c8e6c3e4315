/* Detail transfer (gs_model_render_transfer): the subject's own view gives
 * the input back whatever the input is; a zero residual gives the plain
 * render for any view; a constant residual arrives whole away from the
 * eyes and never more than whole anywhere; the kept own view follows the
 * subject and the context's resets; 1 and 2 threads give the same bytes;
 * bad arguments are refused with the output untouched. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "gazesplat/nn.h"
#include "gazesplat/pool.h"
#include "gazesplat/synth.h"
#include "gs_test.h"
#include "model_test_util.h"

static int max_diff(const uint8_t *a, const uint8_t *b, size_t n)
{
    int m = 0;
    for (size_t i = 0; i < n; i++) {
        int d = abs((int)a[i] - (int)b[i]);
        m = d > m ? d : m;
    }
    return m;
}

static void render(gs_model_ctx *c, gs_pool *pool, const gs_subject *s, const gs_view *v,
                   uint8_t *out, int S)
{
    gs_error err = {0, ""};
    CHECK_MSG(gs_model_render(c, pool, s, v, out, 3 * (size_t)S, &err) == GS_OK, "%s", err.msg);
}

static void transfer(gs_model_ctx *c, gs_pool *pool, const gs_subject *s, const uint8_t *in,
                     const gs_view *v, uint8_t *out, int S)
{
    gs_error err = {0, ""};
    CHECK_MSG(gs_model_render_transfer(c, pool, s, in, 3 * (size_t)S, v, out, 3 * (size_t)S,
                                       &err) == GS_OK,
              "%s", err.msg);
}

static gs_view own_view(const gs_subject *s)
{
    gs_view v;
    memset(&v, 0, sizeof v);
    v.gaze_pitch = s->gaze_pitch;
    v.gaze_yaw = s->gaze_yaw;
    return v;
}

/* The subject's view with the head turned by yaw (rad) about the camera's
 * vertical axis through the face centre, and the gaze (pitch, yaw). */
static gs_view turned(const gs_subject *s, double yaw, double gp, double gy)
{
    gs_view v = own_view(s);
    v.gaze_pitch = gp;
    v.gaze_yaw = gy;
    v.use_head = 1;
    double Ry[9];
    gs_geom_rot_from_pitchyaw(0.0, yaw, 0.0, Ry);
    gs_geom_mat3_mul(Ry, s->head_R, v.head_R);
    memcpy(v.head_t, s->head_t, sizeof v.head_t);
    return v;
}

/* A bad call must fail with `want` and leave out as it was. */
static void refuse(gs_model_ctx *c, const gs_subject *s, const uint8_t *in, size_t in_stride,
                   const gs_view *v, uint8_t *out, size_t stride, int want, const char *what,
                   size_t n)
{
    uint8_t *snap = malloc(n);
    memcpy(snap, out, n);
    gs_error err = {0, ""};
    int rc = gs_model_render_transfer(c, NULL, s, in, in_stride, v, out, stride, &err);
    CHECK_MSG(rc == want, "%s: rc %d, want %d (%s)", what, rc, want, err.msg);
    CHECK_MSG(err.msg[0] != '\0', "%s: no message", what);
    CHECK_MSG(!memcmp(snap, out, n), "%s: output changed", what);
    printf("refused (%s): %s\n", what, err.msg);
    free(snap);
}

int main(void)
{
    gs_nn_blas_set_threads(1);
    char path[128];
    tiny_path(path, "test_model_transfer");
    gs_error err = {0, ""};
    gs_model *m = trained_tiny(path, 4, NULL, &err);
    CHECK_MSG(m != NULL, "%s", err.msg);
    if (!m)
        return 1;
    int S = m->cfg.image_size;
    size_t isz = 3 * (size_t)S * S;
    uint8_t *in = malloc(isz), *out = malloc(isz), *ref = malloc(isz), *own = malloc(isz),
            *a = malloc(isz), *b = malloc(isz);

    gs_model_ctx *c = gs_model_ctx_create(m);
    gs_synth_sample smp[2];
    gs_subject sub[2];
    for (int k = 0; k < 2; k++)
        CHECK_MSG(fit_held_out(c, S, 3 + 5 * (uint64_t)k, 5, &smp[k], &sub[k], &err) == GS_OK,
                  "%s", err.msg);
    for (int y = 0; y < S; y++)
        memcpy(in + (size_t)y * 3 * S, smp[0].rgb + (size_t)y * smp[0].stride, 3 * (size_t)S);
    gs_view v_own = own_view(&sub[0]);
    gs_view v_gaze = v_own;
    v_gaze.gaze_pitch += 0.2;
    v_gaze.gaze_yaw -= 0.3;
    gs_view v_head = turned(&sub[0], 0.15, sub[0].gaze_pitch, sub[0].gaze_yaw);
    gs_view v_both = turned(&sub[0], -0.2, sub[0].gaze_pitch - 0.15, sub[0].gaze_yaw + 0.25);
    const gs_view *views[3] = {&v_gaze, &v_head, &v_both};
    const char *names[3] = {"gaze", "head", "gaze and head"};

    /* The own view gives the input back, for the face and for noise. */
    transfer(c, NULL, &sub[0], in, &v_own, out, S);
    int d = max_diff(out, in, isz);
    CHECK_MSG(d <= 1, "own view: input back within 1, got %d", d);
    uint8_t *noise = malloc(isz);
    uint64_t st = 12345;
    for (size_t i = 0; i < isz; i++) {
        st = st * 6364136223846793005ULL + 1442695040888963407ULL;
        noise[i] = (uint8_t)(st >> 56);
    }
    transfer(c, NULL, &sub[0], noise, &v_own, out, S);
    d = max_diff(out, noise, isz);
    CHECK_MSG(d <= 1, "own view of noise: input back within 1, got %d", d);
    printf("own view: the input back (face and noise, max diff %d)\n", d);

    /* A zero residual: the plain render, for every view. */
    gs_model_ctx *c2 = gs_model_ctx_create(m);
    render(c2, NULL, &sub[0], &v_own, own, S);
    for (int k = 0; k < 3; k++) {
        render(c2, NULL, &sub[0], views[k], ref, S);
        transfer(c, NULL, &sub[0], own, views[k], out, S);
        d = max_diff(out, ref, isz);
        CHECK_MSG(d <= 1, "%s: zero residual gives the plain render within 1, got %d", names[k],
                  d);
        CHECK_MSG(max_diff(ref, own, isz) > (k ? 10 : 0), "%s: the view changes the image",
                  names[k]);
    }

    /* A constant residual of +20 (own view + 20): every output pixel is the
     * plain render plus at most 20, and most of the face gets all of it. */
    for (size_t i = 0; i < isz; i++)
        a[i] = (uint8_t)(own[i] > 235 ? 255 : own[i] + 20);
    for (int k = 0; k < 3; k++) {
        render(c2, NULL, &sub[0], views[k], ref, S);
        transfer(c, NULL, &sub[0], a, views[k], out, S);
        size_t whole = 0, counted = 0;
        int bad = 0;
        for (size_t i = 0; i < isz; i++) {
            int dd = (int)out[i] - (int)ref[i];
            if (ref[i] <= 235 && own[i] <= 235) {
                counted++;
                whole += dd == 20;
                bad |= dd < 0 || dd > 20;
            }
        }
        double share = (double)whole / (double)counted;
        printf("%s: constant residual arrives whole on %.1f %% of the samples\n", names[k],
               100.0 * share);
        CHECK_MSG(!bad, "%s: residual outside [0, 20]", names[k]);
        CHECK_MSG(share > (k == 0 ? 0.95 : 0.6), "%s: whole on %.3f only", names[k], share);
    }

    /* The kept own view follows the subject, the context's resets and
     * other renders in between; a fresh context agrees; 2 threads too. */
    transfer(c, NULL, &sub[0], in, &v_both, a, S);
    gs_view v1 = own_view(&sub[1]);
    v1.gaze_yaw += 0.2;
    transfer(c, NULL, &sub[1], in, &v1, b, S);
    render(c, NULL, &sub[1], &v1, out, S);
    transfer(c, NULL, &sub[0], in, &v_both, out, S);
    CHECK_MSG(!memcmp(out, a, isz), "subject switch changed the bytes");
    gs_model_ctx_reset(c);
    transfer(c, NULL, &sub[0], in, &v_both, out, S);
    CHECK_MSG(!memcmp(out, a, isz), "reset changed the bytes");
    gs_model_ctx *c3 = gs_model_ctx_create(m);
    gs_pool *pool = gs_pool_create(2);
    transfer(c3, pool, &sub[0], in, &v_both, out, S);
    CHECK_MSG(max_diff(out, a, isz) <= 1, "fresh context with 2 threads: differs by %d",
              max_diff(out, a, isz));
    gs_model_ctx_destroy(c3);
    c3 = gs_model_ctx_create(m);
    transfer(c3, NULL, &sub[0], in, &v_gaze, a, S);
    gs_model_ctx_destroy(c3);
    c3 = gs_model_ctx_create(m);
    transfer(c3, pool, &sub[0], in, &v_gaze, out, S);
    CHECK_MSG(!memcmp(out, a, isz), "1 and 2 threads differ");
    gs_model_ctx_destroy(c3);
    printf("kept own view, resets and thread counts: same bytes\n");

    /* Bad arguments. */
    memset(out, 0x5a, isz);
    refuse(c, &sub[0], NULL, 3 * (size_t)S, &v_gaze, out, 3 * (size_t)S, GS_ERR_ARG, "no input",
           isz);
    refuse(c, &sub[0], in, 3 * (size_t)S - 1, &v_gaze, out, 3 * (size_t)S, GS_ERR_ARG,
           "input stride", isz);
    refuse(c, &sub[0], in, 3 * (size_t)S, &v_gaze, out, 3 * (size_t)S - 3, GS_ERR_ARG,
           "output stride", isz);
    refuse(c, &sub[0], in, 3 * (size_t)S, NULL, out, 3 * (size_t)S, GS_ERR_ARG, "no view", isz);
    gs_view v_bad = v_gaze;
    v_bad.gaze_yaw = NAN;
    refuse(c, &sub[0], in, 3 * (size_t)S, &v_bad, out, 3 * (size_t)S, GS_ERR_NONFINITE, "NaN gaze",
           isz);
    v_bad = v_head;
    v_bad.head_R[0] = 5.0;
    refuse(c, &sub[0], in, 3 * (size_t)S, &v_bad, out, 3 * (size_t)S, GS_ERR_ARG,
           "not a rotation", isz);
    gs_subject s_bad = sub[0];
    s_bad.code[0] = INFINITY;
    refuse(c, &s_bad, in, 3 * (size_t)S, &v_gaze, out, 3 * (size_t)S, GS_ERR_NONFINITE,
           "non-finite code", isz);
    gs_model_config cfg;
    tiny_config(&cfg);
    cfg.two_stream = 0;
    gs_model *one = NULL;
    CHECK_MSG(gs_model_create(&cfg, 3, &one, &err) == GS_OK, "%s", err.msg);
    gs_model_ctx *c1 = gs_model_ctx_create(one);
    refuse(c1, &sub[0], in, 3 * (size_t)S, &v_gaze, out, 3 * (size_t)S, GS_ERR_ARG,
           "single stream", isz);
    gs_model_ctx_destroy(c1);
    gs_model_destroy(one);
    /* The context still works after the refusals. */
    transfer(c, NULL, &sub[0], in, &v_own, out, S);
    CHECK(max_diff(out, in, isz) <= 1);

    gs_pool_destroy(pool);
    gs_model_ctx_destroy(c);
    gs_model_ctx_destroy(c2);
    for (int k = 0; k < 2; k++)
        gs_synth_sample_free(&smp[k]);
    free(in), free(out), free(ref), free(own), free(a), free(b), free(noise);
    gs_model_destroy(m);
    tiny_remove(path);
    GS_TEST_END();
}
