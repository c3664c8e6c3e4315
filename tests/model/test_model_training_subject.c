/* gs_model_training_subject: the subject a training step sees (the oracle
 * of `gazesplat eval --method oracle`). Checked on a tiny model with two
 * training identities and samples of the training generator: the code is
 * the identity's learned code, then the sample's expression, then its
 * lights in the head frame; head pose and gaze are the labels'; colour
 * gain 1, bias 0. The code reaches the render (the two identities in one
 * scene render differently; one of them twice, the same bytes). Refused:
 * another identity's labels, k out of range, NULL arguments, a model
 * without training codes.
 * gs_model_scene_code: the model's mean code with a scene's expression,
 * lights and/or learned identity code written in (the same slots as the
 * training subject's), flagged fixed; a fit from it keeps those to the
 * bit and moves the rest; bad parts, the identity code of a face the
 * model did not train on, NULLs and a non-finite start are refused.
 * gs_model_add_identities: a copy with more identities keeps every other
 * tensor and the learned codes to the bit, the new codes at their mean;
 * fewer or as many identities, or too many, are refused. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "gazesplat/synth.h"
#include "gazesplat/train.h"
#include "gs_test.h"
#include "model_test_util.h"

int main(void)
{
    gs_error err = {0, ""};
    gs_model_spec spec;
    gs_model_spec_default(&spec);
    spec.preset = "tiny";
    spec.train_identities = 2;
    gs_model *m = NULL;
    CHECK_MSG(gs_model_new(&spec, 5, &m, &err) == GS_OK, "%s", err.msg);
    if (!m)
        GS_TEST_END();
    gs_model_info mi;
    gs_model_get_info(m, &mi);
    CHECK_EQ_INT(mi.n_train_ids, 2);
    const int id = m->cfg.id_dim, D = mi.code_dim, S = mi.image_size;

    /* The training generator's samples until both identities showed. */
    gs_synth_gen_config g;
    gs_synth_gen_config_default(&g);
    g.split = GS_SYNTH_TRAIN;
    g.identities = 2;
    g.size = S;
    g.rig = GS_SYNTH_RIG_NORMALIZED;
    gs_synth_scene sc[2];
    gs_synth_sample smp[2];
    int have[2] = {0, 0};
    for (int k = 0; k < 2; k++)
        CHECK(gs_synth_sample_alloc(&smp[k], S, S, &err) == GS_OK);
    for (uint64_t i = 0; i < 64 && !(have[0] && have[1]); i++) {
        gs_synth_scene s;
        gs_synth_camera cam;
        CHECK(gs_synth_gen_scene(&g, i, &s, &cam, &err) == GS_OK);
        int k = s.identity.seed == gs_synth_split_seed(GS_SYNTH_TRAIN, 1);
        if (have[k])
            continue;
        sc[k] = s;
        CHECK_MSG(gs_synth_gen_sample(&g, i, NULL, &smp[k], &err) == GS_OK, "%s", err.msg);
        have[k] = 1;
    }
    CHECK(have[0] && have[1]);

    for (int k = 0; k < 2; k++) {
        gs_subject s;
        const gs_synth_labels *l = &smp[k].labels;
        CHECK_MSG(gs_model_training_subject(m, k, &sc[k], l, &s, &err) == GS_OK, "%s",
                  err.msg);
        CHECK_EQ_INT(s.code_dim, D);
        CHECK(!memcmp(s.code, m->p.codes + (size_t)k * id, id * sizeof(float)));
        float ex[GS_MODEL_EXPR_DIM], li[GS_MODEL_LIGHT_DIM];
        gs_synth_expression_to_array(&l->expr, ex);
        gs_model_light_code(&sc[k], li);
        CHECK(!memcmp(s.code + id, ex, sizeof ex));
        CHECK(!memcmp(s.code + id + GS_MODEL_EXPR_DIM, li, sizeof li));
        float lsum = 0;
        for (int j = 0; j < GS_MODEL_LIGHT_DIM; j++)
            lsum += fabsf(li[j]);
        CHECK(lsum > 0); /* a lit scene: the light part is not left at 0 */
        CHECK(!memcmp(s.head_R, l->head_R, sizeof s.head_R));
        CHECK(!memcmp(s.head_t, l->head_t, sizeof s.head_t));
        CHECK(s.gaze_pitch == l->gaze_head_pitch && s.gaze_yaw == l->gaze_head_yaw);
        for (int c = 0; c < 3; c++)
            CHECK(s.colour_gain[c] == 1.0f && s.colour_bias[c] == 0.0f);
        /* another identity's labels, k out of range, NULLs */
        gs_subject t;
        CHECK(gs_model_training_subject(m, 1 - k, &sc[k], l, &t, &err) == GS_ERR_ARG);
        CHECK(strstr(err.msg, "identity") != NULL);
        CHECK(gs_model_training_subject(m, 2, &sc[k], l, &t, &err) == GS_ERR_ARG);
        CHECK(gs_model_training_subject(m, -1, &sc[k], l, &t, &err) == GS_ERR_ARG);
        CHECK(gs_model_training_subject(NULL, k, &sc[k], l, &t, &err) == GS_ERR_ARG);
        CHECK(gs_model_training_subject(m, k, NULL, l, &t, &err) == GS_ERR_ARG);
        CHECK(gs_model_training_subject(m, k, &sc[k], NULL, &t, &err) == GS_ERR_ARG);
        CHECK(gs_model_training_subject(m, k, &sc[k], l, NULL, &err) == GS_ERR_ARG);
    }

    /* gs_model_scene_code: the mean code with the scene's expression,
     * lights and/or learned identity code written in as a training step
     * writes them, flagged fixed; every combination, both identities. */
    for (int k = 0; k < 2; k++) {
        const gs_synth_scene *scn = &sc[k];
        gs_subject ts;
        CHECK(gs_model_training_subject(m, k, scn, &smp[k].labels, &ts, &err) == GS_OK);
        for (unsigned parts = 1; parts <= 7; parts++) {
            float code[GS_MODEL_MAX_CODE];
            uint8_t fixed[GS_MODEL_MAX_CODE];
            CHECK_MSG(gs_model_scene_code(m, scn, parts, code, fixed, &err) == GS_OK,
                      "%s", err.msg);
            for (int j = 0; j < D; j++) {
                int idp = j < id;
                int ex = j >= id && j < id + GS_MODEL_EXPR_DIM;
                int li = j >= id + GS_MODEL_EXPR_DIM;
                int want = (ex && (parts & GS_SCENE_CODE_EXPR)) ||
                           (li && (parts & GS_SCENE_CODE_LIGHT)) ||
                           (idp && (parts & GS_SCENE_CODE_ID));
                CHECK_MSG(fixed[j] == want, "parts %u slot %d fixed %d", parts, j,
                          fixed[j]);
                float v = want ? ts.code[j] : m->p.code_mean[j];
                CHECK_MSG(code[j] == v, "parts %u slot %d: %g, want %g", parts, j,
                          code[j], v);
            }
        }
    }
    {
        const gs_synth_scene *scn = &sc[0];
        float code[GS_MODEL_MAX_CODE];
        uint8_t fixed[GS_MODEL_MAX_CODE];
        CHECK(gs_model_scene_code(m, scn, 0, code, fixed, &err) == GS_ERR_ARG);
        CHECK(gs_model_scene_code(m, scn, 8, code, fixed, &err) == GS_ERR_ARG);
        CHECK(strstr(err.msg, "parts") != NULL);
        /* the identity code only for the model's own training identities:
         * not a held-out face, nor a training identity past its codes */
        gs_synth_scene other = *scn;
        other.identity.seed = gs_synth_split_seed(GS_SYNTH_TEST, 0);
        CHECK(gs_model_scene_code(m, &other, GS_SCENE_CODE_ID, code, fixed, &err) ==
              GS_ERR_ARG);
        CHECK(strstr(err.msg, "training identities") != NULL);
        other.identity.seed = gs_synth_split_seed(GS_SYNTH_TRAIN, 2);
        CHECK(gs_model_scene_code(m, &other, GS_SCENE_CODE_ID | GS_SCENE_CODE_EXPR,
                                  code, fixed, &err) == GS_ERR_ARG);
        CHECK(gs_model_scene_code(m, &other, GS_SCENE_CODE_EXPR, code, fixed, &err) ==
              GS_OK);
        CHECK(gs_model_scene_code(NULL, scn, 1, code, fixed, &err) == GS_ERR_ARG);
        CHECK(gs_model_scene_code(m, NULL, 1, code, fixed, &err) == GS_ERR_ARG);
        CHECK(gs_model_scene_code(m, scn, 1, NULL, fixed, &err) == GS_ERR_ARG);
        CHECK(gs_model_scene_code(m, scn, 1, code, NULL, &err) == GS_ERR_ARG);

        /* A fit from that code keeps the fixed slots to the bit and moves
         * the others; a fit without keeps nothing at the truth. */
        CHECK(gs_model_scene_code(m, scn, GS_SCENE_CODE_EXPR | GS_SCENE_CODE_LIGHT,
                                  code, fixed, &err) == GS_OK);
        gs_model_ctx *fc = gs_model_ctx_create(m);
        CHECK(fc != NULL);
        gs_fit_options fo;
        gs_fit_options_default(&fo);
        fo.max_iters = 6;
        fo.known_head = 1;
        memcpy(fo.head_R, smp[0].labels.head_R, sizeof fo.head_R);
        memcpy(fo.head_t, smp[0].labels.head_t, sizeof fo.head_t);
        fo.known_gaze = 1;
        fo.gaze_pitch = smp[0].labels.gaze_head_pitch;
        fo.gaze_yaw = smp[0].labels.gaze_head_yaw;
        gs_subject plain, known;
        CHECK_MSG(gs_model_fit(fc, NULL, smp[0].rgb, smp[0].stride, &fo, &plain, NULL,
                               &err) == GS_OK, "%s", err.msg);
        fo.code_start = code;
        fo.code_fixed = fixed;
        CHECK_MSG(gs_model_fit(fc, NULL, smp[0].rgb, smp[0].stride, &fo, &known, NULL,
                               &err) == GS_OK, "%s", err.msg);
        int kept = 1, moved = 0, plain_at_truth = 1;
        for (int j = 0; j < D; j++) {
            if (fixed[j]) {
                kept &= known.code[j] == code[j];
                plain_at_truth &= plain.code[j] == code[j];
            } else {
                moved |= known.code[j] != code[j];
            }
        }
        CHECK_MSG(kept, "a fixed slot moved");
        CHECK_MSG(moved, "no free slot moved");
        CHECK_MSG(!plain_at_truth, "the plain fit landed on the truth");
        float nan_code[GS_MODEL_MAX_CODE];
        memcpy(nan_code, code, sizeof nan_code);
        nan_code[id] = NAN;
        fo.code_start = nan_code;
        CHECK(gs_model_fit(fc, NULL, smp[0].rgb, smp[0].stride, &fo, &known, NULL,
                           &err) == GS_ERR_ARG);
        CHECK(strstr(err.msg, "code_start") != NULL);
        gs_model_ctx_destroy(fc);
    }

    /* The code reaches the render: identity 1's code in identity 0's scene
     * draws another image; identity 0's, twice, the same bytes. */
    gs_subject a, b;
    CHECK(gs_model_training_subject(m, 0, &sc[0], &smp[0].labels, &a, &err) == GS_OK);
    b = a;
    memcpy(b.code, m->p.codes + id, id * sizeof(float));
    gs_view own = {.gaze_pitch = a.gaze_pitch, .gaze_yaw = a.gaze_yaw};
    size_t isz = 3 * (size_t)S * S;
    uint8_t *ia = malloc(isz), *ib = malloc(isz), *ic = malloc(isz);
    gs_model_ctx *c = gs_model_ctx_create(m);
    CHECK(c && ia && ib && ic);
    CHECK(gs_model_render(c, NULL, &a, &own, ia, 3 * (size_t)S, &err) == GS_OK);
    CHECK(gs_model_render(c, NULL, &b, &own, ib, 3 * (size_t)S, &err) == GS_OK);
    gs_model_ctx_reset(c);
    CHECK(gs_model_render(c, NULL, &a, &own, ic, 3 * (size_t)S, &err) == GS_OK);
    CHECK(memcmp(ia, ib, isz) != 0);
    CHECK(!memcmp(ia, ic, isz));
    gs_model_ctx_destroy(c);

    /* More identities: 2 -> 5. */
    gs_model *gm = NULL;
    CHECK_MSG(gs_model_add_identities(m, 5, &gm, &err) == GS_OK, "%s", err.msg);
    if (gm) {
        gs_model_info gi;
        gs_model_get_info(gm, &gi);
        CHECK_EQ_INT(gi.n_train_ids, 5);
        CHECK_EQ_INT(gm->ntensors, m->ntensors);
        for (int i = 0; i < gm->ntensors && i < m->ntensors; i++) {
            const gs_ptensor *d = &gm->t[i], *s = &m->t[i];
            CHECK(!strcmp(d->name, s->name));
            if (strcmp(d->name, "codes.train") != 0)
                CHECK_MSG(d->count == s->count &&
                              !memcmp(gm->params + d->offset, m->params + s->offset,
                                      s->count * sizeof(float)),
                          "%s changed", d->name);
        }
        CHECK(!memcmp(gm->p.codes, m->p.codes, 2 * (size_t)id * sizeof(float)));
        int mean_ok = 1;
        for (int j = 0; j < id; j++) {
            float want = (float)(((double)m->p.codes[j] + m->p.codes[id + j]) / 2);
            for (int k = 2; k < 5; k++)
                mean_ok &= fabsf(gm->p.codes[(size_t)k * id + j] - want) <= 1e-6f * (1 + fabsf(want));
        }
        CHECK_MSG(mean_ok, "the new codes are not the mean of the learned ones");
        gs_subject ga;
        CHECK(gs_model_training_subject(gm, 0, &sc[0], &smp[0].labels, &ga, &err) == GS_OK);
        CHECK(!memcmp(ga.code, a.code, sizeof(float) * (size_t)D));
        CHECK(gs_model_training_subject(gm, 4, &sc[0], &smp[0].labels, &ga, &err) == GS_ERR_ARG);
        CHECK(gm->id != m->id);
        gs_model_destroy(gm);
    }
    const int bad_n[] = {2, 1, 0, 100001};
    for (size_t i = 0; i < sizeof bad_n / sizeof bad_n[0]; i++) {
        gm = NULL;
        CHECK_MSG(gs_model_add_identities(m, bad_n[i], &gm, &err) == GS_ERR_ARG && !gm,
                  "%d identities accepted", bad_n[i]);
    }
    CHECK(gs_model_add_identities(NULL, 5, &gm, &err) == GS_ERR_ARG);
    CHECK(gs_model_add_identities(m, 5, NULL, &err) == GS_ERR_ARG);

    /* A model without training codes (as one written without them loads):
     * refused, and its info says 0. */
    m->cfg.n_train_ids = 0;
    gs_model_get_info(m, &mi);
    CHECK_EQ_INT(mi.n_train_ids, 0);
    CHECK(gs_model_training_subject(m, 0, &sc[0], &smp[0].labels, &a, &err) == GS_ERR_ARG);
    CHECK(strstr(err.msg, "no training codes") != NULL);
    gm = NULL;
    CHECK(gs_model_add_identities(m, 5, &gm, &err) == GS_ERR_ARG && !gm);
    m->cfg.n_train_ids = 2;

    free(ia);
    free(ib);
    free(ic);
    for (int k = 0; k < 2; k++)
        gs_synth_sample_free(&smp[k]);
    gs_model_destroy(m);
    GS_TEST_END();
}
