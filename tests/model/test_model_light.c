/* Lights at another head pose. The light part of a subject's code is in
 * its head frame; a view at another head pose keeps the lights where they
 * are in the camera (gs_view.light_on_head = 0), or on the head (1).
 *
 *   test_model_light              the algebra and the render paths on a
 *                                 tiny model (unit)
 *   test_model_light MODEL.st     also the physics on a trained model:
 *                                 held-out faces fitted at one pose and
 *                                 rendered at turned ones are closer to
 *                                 the synthetic ground truth (same lights)
 *                                 with the lights kept in the camera */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "../../lib/model/model_internal.h"
#include "gazesplat/eval.h"
#include "gazesplat/geom.h"
#include "gazesplat/nn.h"
#include "gazesplat/synth.h"
#include "gs_test.h"
#include "model_test_util.h"

/* The labels' light code (gs_model_light_code) of a scene at two head
 * poses, against the first turned to the second. */
static void check_against_labels(void)
{
    gs_synth_ranges rg;
    gs_synth_ranges_default(&rg);
    double worst = 0, worst_back = 0;
    for (uint64_t k = 0; k < 40; k++) {
        gs_synth_scene a, b;
        gs_synth_scene_random(1000 + k, 77 * k + 5, &rg, &a);
        gs_synth_scene_random(1000 + k, 91 * k + 3, &rg, &b);
        b.n_lights = a.n_lights; /* b: a's lights, another head pose */
        memcpy(b.light, a.light, sizeof b.light);
        memcpy(b.ambient, a.ambient, sizeof b.ambient);
        float code[GS_MODEL_MAX_CODE] = {0};
        int dim = 8 + GS_MODEL_EXPR_DIM + GS_MODEL_LIGHT_DIM;
        float *la = code + dim - GS_MODEL_LIGHT_DIM, lb[GS_MODEL_LIGHT_DIM];
        gs_model_light_code(&a, la);
        gs_model_light_code(&b, lb);
        for (int i = 0; i < dim - GS_MODEL_LIGHT_DIM; i++)
            code[i] = (float)i; /* identity and expression: untouched */
        float orig[GS_MODEL_LIGHT_DIM];
        memcpy(orig, la, sizeof orig);
        gs_model_light_to_view(code, dim, a.head_R, b.head_R);
        for (int i = 0; i < GS_MODEL_LIGHT_DIM; i++) {
            double d = fabs(la[i] - lb[i]);
            worst = d > worst ? d : worst;
        }
        for (int i = 0; i < dim - GS_MODEL_LIGHT_DIM; i++)
            CHECK(code[i] == (float)i);
        gs_model_light_to_view(code, dim, b.head_R, a.head_R);
        for (int i = 0; i < GS_MODEL_LIGHT_DIM; i++) {
            double d = fabs(la[i] - orig[i]);
            worst_back = d > worst_back ? d : worst_back;
        }
        CHECK(memcmp(la + 9, orig + 9, 3 * sizeof(float)) == 0); /* ambient */
    }
    printf("labels: turned light vs the other pose's label, max |d| %.2e; "
           "there and back %.2e\n", worst, worst_back);
    CHECK_MSG(worst < 2e-6, "turned light differs from the label by %.3g", worst);
    CHECK_MSG(worst_back < 2e-6, "there and back differs by %.3g", worst_back);
}

static gs_view turned(const gs_subject *s, double yaw, double pitch)
{
    gs_view v;
    memset(&v, 0, sizeof v);
    v.gaze_pitch = 0.05;
    v.gaze_yaw = -0.1;
    v.use_head = 1;
    double Rt[9];
    gs_geom_rot_from_pitchyaw(pitch, yaw, 0.0, Rt);
    gs_geom_mat3_mul(Rt, s->head_R, v.head_R);
    memcpy(v.head_t, s->head_t, sizeof v.head_t);
    return v;
}

/* The render paths on a tiny model: lights kept in the camera are the
 * subject's light turned by hand and kept on the head; the subject's own
 * head pose given explicitly changes nothing. */
static void check_renders(void)
{
    char path[128];
    tiny_path(path, "test_model_light");
    gs_error err = {0, ""};
    gs_train_report rep;
    gs_model *m = trained_tiny(path, 4, &rep, &err);
    CHECK_MSG(m != NULL, "%s", err.msg);
    if (!m)
        return;
    gs_model_info info;
    gs_model_get_info(m, &info);
    int S = info.image_size;
    gs_model_ctx *c = gs_model_ctx_create(m), *c2 = gs_model_ctx_create(m);
    gs_synth_sample smp;
    gs_subject sub;
    CHECK_MSG(fit_held_out(c, S, 4, 4, &smp, &sub, &err) == GS_OK, "%s", err.msg);
    /* A strong side light, so that where it falls shows. */
    float *l = sub.code + sub.code_dim - GS_MODEL_LIGHT_DIM;
    for (int k = 0; k < 3; k++) {
        l[3 * k] = -0.9f;
        l[3 * k + 1] = -0.3f;
        l[3 * k + 2] = -0.4f;
    }
    size_t st = 3 * (size_t)S, n = st * S;
    uint8_t *a = malloc(n), *b = malloc(n), *own = malloc(n);

    gs_view v_own;
    memset(&v_own, 0, sizeof v_own);
    v_own.gaze_pitch = 0.05;
    v_own.gaze_yaw = -0.1;
    CHECK(gs_model_render(c, NULL, &sub, &v_own, own, st, &err) == GS_OK);
    gs_view v_same = v_own;
    v_same.use_head = 1;
    memcpy(v_same.head_R, sub.head_R, sizeof v_same.head_R);
    memcpy(v_same.head_t, sub.head_t, sizeof v_same.head_t);
    CHECK(gs_model_render(c2, NULL, &sub, &v_same, a, st, &err) == GS_OK);
    CHECK_MSG(memcmp(a, own, n) == 0, "own head pose given explicitly differs");

    for (int t = 0; t < 3; t++) {
        gs_view v = turned(&sub, 0.35 * (t - 1) + 0.1, 0.12 * t - 0.1);
        CHECK(gs_model_render(c, NULL, &sub, &v, a, st, &err) == GS_OK);
        gs_subject by_hand = sub;
        gs_model_light_to_view(by_hand.code, by_hand.code_dim, sub.head_R, v.head_R);
        gs_view v_head = v;
        v_head.light_on_head = 1;
        CHECK(gs_model_render(c2, NULL, &by_hand, &v_head, b, st, &err) == GS_OK);
        CHECK_MSG(memcmp(a, b, n) == 0, "turn %d: lights in the camera != the "
                  "light turned by hand on the head", t);
        CHECK(gs_model_render(c2, NULL, &sub, &v_head, b, st, &err) == GS_OK);
        CHECK_MSG(memcmp(a, b, n) != 0, "turn %d: the light made no difference", t);
    }
    free(a);
    free(b);
    free(own);
    gs_synth_sample_free(&smp);
    gs_model_ctx_destroy(c);
    gs_model_ctx_destroy(c2);
    gs_model_destroy(m);
    tiny_remove(path);
}

/* A trained model on the validation pairing's head-change pairs: each
 * input fitted (its true pose and gaze given, 25 iterations, as the
 * evaluation does), its targets rendered both ways and compared with the
 * synthetic ground truth, which keeps the input's lights in the camera. */
static void check_physics(const char *model_path, int n_inputs)
{
    gs_error err = {0, ""};
    gs_model *m = NULL;
    CHECK_MSG(gs_model_load(model_path, &m, &err) == GS_OK, "%s", err.msg);
    if (!m)
        return;
    gs_model_info info;
    gs_model_get_info(m, &info);
    int S = info.image_size;
    size_t st = 3 * (size_t)S;
    gs_pool *pool = gs_pool_create(2);
    gs_model_ctx *c = gs_model_ctx_create(m);
    gs_eval_pairs_spec spec;
    gs_eval_pairs_spec_default(&spec);
    spec.split = GS_SYNTH_VAL;
    gs_eval_pairs ps = {0, NULL};
    CHECK_MSG(gs_eval_pairs_make(&spec, &ps, &err) == GS_OK, "%s", err.msg);
    uint8_t *a = malloc(st * S), *b = malloc(st * S);
    double sum_cam = 0, sum_head = 0;
    int n = 0, wins = 0, last_input = -1;
    gs_subject sub;
    gs_synth_sample in = {0};
    for (int i = 0; i < ps.n && ps.p[i].input < n_inputs; i++) {
        const gs_eval_pair *p = &ps.p[i];
        if (!p->head_change || p->head_change_deg < 15)
            continue;
        gs_synth_scene is, ts;
        gs_eval_pair_scenes(p, &is, &ts);
        if (p->input != last_input) {
            gs_synth_sample_free(&in);
            CHECK(gs_eval_render_scene(&is, S, info.distance_mm, info.focal, pool, &in,
                                       &err) == GS_OK);
            CHECK_MSG(gs_eval_fit_sample(c, pool, &in, 25, 0, 0, &sub, NULL, &err) == GS_OK,
                      "%s", err.msg);
            last_input = p->input;
        }
        gs_synth_sample gt = {0};
        CHECK(gs_eval_render_scene(&ts, S, info.distance_mm, info.focal, pool, &gt,
                                   &err) == GS_OK);
        gs_view v;
        memset(&v, 0, sizeof v);
        v.gaze_pitch = ts.gaze_pitch;
        v.gaze_yaw = ts.gaze_yaw;
        v.use_head = 1;
        memcpy(v.head_R, gt.labels.head_R, sizeof v.head_R);
        memcpy(v.head_t, gt.labels.head_t, sizeof v.head_t);
        CHECK(gs_model_render(c, pool, &sub, &v, a, st, &err) == GS_OK);
        v.light_on_head = 1;
        CHECK(gs_model_render(c, pool, &sub, &v, b, st, &err) == GS_OK);
        double pc = gs_eval_psnr(a, st, gt.rgb, gt.stride, S, S, NULL);
        double ph = gs_eval_psnr(b, st, gt.rgb, gt.stride, S, S, NULL);
        printf("pair %3d: head change %5.1f deg, PSNR lights in the camera %.2f, "
               "on the head %.2f dB\n", i, p->head_change_deg, pc, ph);
        sum_cam += pc;
        sum_head += ph;
        wins += pc > ph;
        n++;
        gs_synth_sample_free(&gt);
    }
    CHECK(n >= 4);
    if (n) {
        printf("%d head-change pairs: mean PSNR %.2f (lights in the camera) vs %.2f "
               "(on the head); camera better on %d\n", n, sum_cam / n, sum_head / n, wins);
        CHECK_MSG(sum_cam / n > sum_head / n + 0.3,
                  "lights kept in the camera should be closer to the truth");
        CHECK_MSG(2 * wins > n, "camera lights better on only %d of %d", wins, n);
    }
    free(a);
    free(b);
    gs_synth_sample_free(&in);
    gs_eval_pairs_free(&ps);
    gs_model_ctx_destroy(c);
    gs_pool_destroy(pool);
    gs_model_destroy(m);
}

int main(int argc, char **argv)
{
    gs_nn_blas_set_threads(1);
    if (argc > 1) {
        check_physics(argv[1], argc > 2 ? atoi(argv[2]) : 6);
        GS_TEST_END();
    }
    check_against_labels();
    check_renders();
    GS_TEST_END();
}
