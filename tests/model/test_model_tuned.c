/* Serving fine-tuned subjects: gs_model_tuned_encode / gs_model_tuned_apply
 * move what gs_model_finetune changed into another clone of the shared
 * model, which then renders the same bytes; switching between subjects'
 * blocks and back to none restores exactly; every bad block is refused
 * with dst untouched. Also the parameter id and gs_model_ctx_reset. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "gazesplat/nn.h"
#include "gazesplat/synth.h"
#include "gs_test.h"
#include "model_test_util.h"

static int same_params(const gs_model *a, const gs_model *b)
{
    return a->nparams == b->nparams &&
           !memcmp(a->params, b->params, a->nparams * sizeof(float));
}

/* Renders s at its own gaze with a fresh context on m. */
static void render_fresh(gs_model *m, const gs_subject *s, const gs_view *v, uint8_t *out)
{
    gs_error err = {0, ""};
    gs_model_ctx *c = gs_model_ctx_create(m);
    CHECK_MSG(gs_model_render(c, NULL, s, v, out, 3 * (size_t)m->cfg.image_size, &err) == GS_OK,
              "%s", err.msg);
    gs_model_ctx_destroy(c);
}

/* A block with one byte changed must be refused with dst unchanged. */
static void refuse(gs_model *dst, const gs_model *base, const uint8_t *blk, size_t len,
                   int want, const char *what)
{
    float *snap = malloc(dst->nparams * sizeof(float));
    memcpy(snap, dst->params, dst->nparams * sizeof(float));
    unsigned tuned = dst->tuned;
    gs_error err = {0, ""};
    int rc = gs_model_tuned_apply(dst, base, blk, len, &err);
    CHECK_MSG(rc == want, "%s: rc %d, want %d (%s)", what, rc, want, err.msg);
    CHECK_MSG(strstr(err.msg, "tuned block") != NULL, "%s: message '%s'", what, err.msg);
    CHECK_MSG(!memcmp(snap, dst->params, dst->nparams * sizeof(float)) && dst->tuned == tuned,
              "%s: dst changed", what);
    printf("refused (%s): %s\n", what, err.msg);
    free(snap);
}

int main(void)
{
    gs_nn_blas_set_threads(1);
    char path[128];
    tiny_path(path, "test_model_tuned");
    gs_error err = {0, ""};
    gs_model *m = trained_tiny(path, 4, NULL, &err);
    CHECK_MSG(m != NULL, "%s", err.msg);
    if (!m)
        return 1;
    int S = m->cfg.image_size;
    size_t isz = 3 * (size_t)S * S;

    /* The parameter id: a clone keeps it, loading the file again gives it
     * again, other parameters give another. */
    gs_model_info info;
    gs_model_get_info(m, &info);
    CHECK(info.param_id == m->id && info.param_id != 0 && info.tuned_parts == 0);
    CHECK(m->id == gs_model_param_id(m));
    gs_model *again = NULL;
    CHECK_MSG(gs_model_load(path, &again, &err) == GS_OK, "%s", err.msg);
    CHECK(again->id == m->id);
    again->params[again->nparams / 2] += 1.0f;
    CHECK(gs_model_param_id(again) != m->id);
    gs_model_destroy(again);

    /* Two held-out faces, fitted with their true head poses. */
    gs_synth_sample smp[2];
    gs_subject sub[2];
    gs_view view[2];
    gs_model_ctx *c = gs_model_ctx_create(m);
    for (int k = 0; k < 2; k++) {
        CHECK_MSG(fit_held_out(c, S, 7 + 4 * (uint64_t)k, 5, &smp[k], &sub[k], &err) == GS_OK, "%s",
                  err.msg);
        memset(&view[k], 0, sizeof view[k]);
        view[k].gaze_pitch = sub[k].gaze_pitch + 0.1;
        view[k].gaze_yaw = sub[k].gaze_yaw - 0.2;
    }

    /* A subject file is the subject, then maybe a block: its length comes
     * from its header whatever follows. */
    uint8_t enc[GS_SUBJECT_ENCODED_MAX + 16];
    size_t elen = gs_subject_encode(&sub[0], enc, sizeof enc);
    memset(enc + elen, 0xab, 16);
    CHECK(elen > 12 && gs_subject_encoded_len(enc, elen) == elen);
    CHECK(gs_subject_encoded_len(enc, elen + 16) == elen);
    CHECK(gs_subject_encoded_len(enc, 11) == 0 && gs_subject_encoded_len(NULL, 100) == 0);
    uint32_t bad_dim = GS_MODEL_MAX_CODE + 1;
    memcpy(enc + 8, &bad_dim, 4);
    CHECK(gs_subject_encoded_len(enc, elen) == 0);

    /* Subject 0: the face; subject 1: the face with its geometry (not the
     * eyeballs') and the eyes' colours. */
    gs_model *ft[2] = {NULL, NULL};
    uint8_t *blk[2] = {NULL, NULL};
    size_t len[2] = {0, 0};
    unsigned parts[2] = {GS_FT_FACE, GS_FT_FACE | GS_FT_FACE_GEOMETRY | GS_FT_EYE};
    for (int k = 0; k < 2; k++) {
        CHECK(gs_model_clone(m, &ft[k], &err) == GS_OK);
        CHECK(ft[k]->id == m->id);
        CHECK(gs_model_tuned_encode(ft[k], &blk[k], &len[k], &err) == GS_ERR_ARG);
        gs_finetune_options o;
        gs_finetune_options_default(&o);
        o.iters = 4;
        o.lr = 5e-3;
        o.parts = parts[k];
        CHECK_MSG(gs_model_finetune(ft[k], NULL, &sub[k], smp[k].rgb, smp[k].stride, &o, NULL,
                                    &err) == GS_OK, "%s", err.msg);
        gs_model_get_info(ft[k], &info);
        CHECK(info.tuned_parts == parts[k] && info.param_id == m->id);
        CHECK_MSG(gs_model_tuned_encode(ft[k], &blk[k], &len[k], &err) == GS_OK, "%s", err.msg);
        size_t want = 32;
        int eye_geom = 0;
        for (int i = 0; i < m->ntensors; i++)
            if (gs_model_tensor_part(&m->t[i]) & parts[k]) {
                want += 8 + m->t[i].count * sizeof(float);
                eye_geom += !strcmp(m->t[i].name, "eye.xyz");
            }
        CHECK(!eye_geom);
        CHECK_EQ_INT(len[k], want);
        printf("subject %d: block of %zu bytes\n", k, len[k]);
    }

    /* A third clone serves both: a context used before each switch, reset,
     * renders what a fresh context on the tuned model renders. */
    gs_model *srv = NULL;
    CHECK(gs_model_clone(m, &srv, &err) == GS_OK);
    gs_model_ctx *sc = gs_model_ctx_create(srv);
    uint8_t *want = malloc(isz), *got = malloc(isz), *plain = malloc(isz);
    CHECK(gs_model_render(sc, NULL, &sub[0], &view[0], plain, 3 * (size_t)S, &err) == GS_OK);
    int order[] = {0, 1, 0, -1, 1, -1};
    for (size_t j = 0; j < sizeof order / sizeof order[0]; j++) {
        int k = order[j];
        CHECK_MSG(gs_model_tuned_apply(srv, m, k < 0 ? NULL : blk[k], k < 0 ? 0 : len[k], &err) ==
                      GS_OK, "%s", err.msg);
        gs_model_ctx_reset(sc);
        CHECK_MSG(same_params(srv, k < 0 ? m : ft[k]), "switch %zu: parameters differ", j);
        CHECK(srv->tuned == (k < 0 ? 0u : parts[k]));
        int s = k < 0 ? 0 : k;
        render_fresh(k < 0 ? m : ft[k], &sub[s], &view[s], want);
        CHECK(gs_model_render(sc, NULL, &sub[s], &view[s], got, 3 * (size_t)S, &err) == GS_OK);
        CHECK_MSG(!memcmp(want, got, isz), "switch %zu: render differs", j);
    }
    /* The tuned render is not the plain one (the block did something). */
    render_fresh(ft[0], &sub[0], &view[0], got);
    CHECK(memcmp(got, plain, isz) != 0);

    /* A clone copied from elsewhere starts from base. */
    gs_model *other = NULL;
    CHECK(gs_model_clone(m, &other, &err) == GS_OK);
    for (size_t i = 0; i < other->nparams; i += 97)
        other->params[i] *= 1.5f;
    other->id ^= 1;
    CHECK(gs_model_tuned_apply(other, m, blk[0], len[0], &err) == GS_OK);
    CHECK(same_params(other, ft[0]) && other->id == m->id);
    gs_model_destroy(other);

    /* Bad blocks, each refused with srv unchanged. */
    CHECK(gs_model_tuned_apply(srv, m, blk[1], len[1], &err) == GS_OK);
    uint8_t *bad = malloc(len[1] + 8);
    refuse(srv, m, blk[1], len[1] - 1, GS_ERR_FORMAT, "one byte short");
    refuse(srv, m, blk[1], 20, GS_ERR_FORMAT, "20 bytes");
    memcpy(bad, blk[1], len[1]);
    memset(bad + len[1], 0, 8);
    refuse(srv, m, bad, len[1] + 8, GS_ERR_FORMAT, "8 bytes too many");
    memcpy(bad, blk[1], len[1]);
    bad[len[1] / 2] ^= 0x10;
    refuse(srv, m, bad, len[1], GS_ERR_FORMAT, "a flipped bit");
    memcpy(bad, blk[1], len[1]);
    bad[0] = 'X';
    refuse(srv, m, bad, len[1], GS_ERR_FORMAT, "bad magic");
    memcpy(bad, blk[1], len[1]);
    bad[4] = 9;
    refuse(srv, m, bad, len[1], GS_ERR_UNSUPPORTED, "version 9");
    /* Well-formed but wrong: tuned from another model, non-finite values. */
    gs_model *pruned = NULL, *pft = NULL;
    CHECK(gs_model_prune(m, NULL, m->cfg.n_face - 3, &pruned, &err) == GS_OK);
    CHECK(pruned->id != m->id);
    CHECK(gs_model_clone(pruned, &pft, &err) == GS_OK);
    gs_finetune_options o;
    gs_finetune_options_default(&o);
    o.iters = 1;
    CHECK(gs_model_finetune(pft, NULL, &sub[0], smp[0].rgb, smp[0].stride, &o, NULL, &err) ==
          GS_OK);
    uint8_t *pb = NULL;
    size_t pl = 0;
    CHECK(gs_model_tuned_encode(pft, &pb, &pl, &err) == GS_OK);
    refuse(srv, m, pb, pl, GS_ERR_ARG, "another model's block");
    free(pb);
    float keep = ft[0]->params[ft[0]->p.f_feat - ft[0]->params + 5];
    ft[0]->p.f_feat[5] = NAN;
    CHECK(gs_model_tuned_encode(ft[0], &pb, &pl, &err) == GS_OK);
    refuse(srv, m, pb, pl, GS_ERR_FORMAT, "a NaN inside");
    ft[0]->p.f_feat[5] = keep;
    free(pb);
    /* Wrong models: dst of another layout, the shared model itself, a
     * tuned base. */
    CHECK(gs_model_tuned_apply(pruned, m, blk[0], len[0], &err) == GS_ERR_ARG);
    CHECK(gs_model_tuned_apply(m, m, blk[0], len[0], &err) == GS_ERR_ARG);
    CHECK(gs_model_tuned_apply(srv, ft[1], blk[0], len[0], &err) == GS_ERR_ARG);
    CHECK(gs_model_tuned_apply(srv, m, NULL, 5, &err) == GS_ERR_ARG);
    CHECK(gs_model_tuned_apply(NULL, m, blk[0], len[0], &err) == GS_ERR_ARG);
    CHECK(same_params(srv, ft[1]));
    /* A failed fine-tune marks nothing tuned. */
    gs_model *fresh = NULL;
    CHECK(gs_model_clone(m, &fresh, &err) == GS_OK);
    gs_subject bs = sub[0];
    bs.code[0] = NAN;
    CHECK(gs_model_finetune(fresh, NULL, &bs, smp[0].rgb, smp[0].stride, &o, NULL, &err) ==
          GS_ERR_NONFINITE);
    CHECK(fresh->tuned == 0);
    gs_model_destroy(fresh);
    /* A time budget ends it early, keeping the best iterate (here the
     * start: no step fits in a nanosecond). */
    CHECK(gs_model_clone(m, &fresh, &err) == GS_OK);
    gs_finetune_report fr;
    o.iters = 50;
    o.time_budget_s = 1e-9;
    CHECK(gs_model_finetune(fresh, NULL, &sub[0], smp[0].rgb, smp[0].stride, &o, &fr, &err) ==
          GS_OK);
    CHECK(fr.stopped_on_time == 1 && fr.iters == 0);
    CHECK(same_params(fresh, m));
    /* A plateau rule that no 20 steps can pass (a 100 % gain) stops at 20. */
    o.time_budget_s = 0;
    o.iters = 30;
    o.plateau_rel = 1.0;
    CHECK(gs_model_finetune(fresh, NULL, &sub[0], smp[0].rgb, smp[0].stride, &o, &fr, &err) ==
          GS_OK);
    CHECK_MSG(fr.stopped_on_plateau == 1 && fr.iters == 20 && !fr.stopped_on_time,
              "plateau: %d steps, flag %d", fr.iters, fr.stopped_on_plateau);
    o.plateau_rel = NAN;
    CHECK(gs_model_finetune(fresh, NULL, &sub[0], smp[0].rgb, smp[0].stride, &o, &fr, &err) ==
          GS_ERR_ARG);
    o.plateau_rel = 0;
    gs_model_destroy(fresh);

    /* Part names. */
    unsigned bits = 0;
    char names[64];
    CHECK(gs_finetune_parts_parse("face,eye", &bits, &err) == GS_OK && bits == 3u);
    CHECK(gs_finetune_parts_parse("geometry,renderer,mlp", &bits, &err) == GS_OK && bits == 28u);
    CHECK(!strcmp(gs_finetune_parts_name(0x1f, names, sizeof names),
                  "face,eye,renderer,mlp,geometry"));
    CHECK(gs_finetune_parts_parse("face,face-geometry", &bits, &err) == GS_OK && bits == 33u);
    CHECK(!strcmp(gs_finetune_parts_name(GS_FT_ALL_PARTS, names, sizeof names),
                  "face,eye,renderer,mlp,geometry,face-geometry"));
    CHECK(!strcmp(gs_finetune_parts_name(0, names, sizeof names), ""));
    const char *badp[] = {"", "face,", ",face", "nose", "face,,eye", "Face"};
    for (size_t i = 0; i < sizeof badp / sizeof badp[0]; i++) {
        bits = 99;
        CHECK_MSG(gs_finetune_parts_parse(badp[i], &bits, &err) == GS_ERR_ARG && bits == 99,
                  "'%s' accepted", badp[i]);
    }

    free(bad);
    free(want);
    free(got);
    free(plain);
    gs_model_ctx_destroy(sc);
    gs_model_destroy(srv);
    gs_model_destroy(pft);
    gs_model_destroy(pruned);
    for (int k = 0; k < 2; k++) {
        free(blk[k]);
        gs_model_destroy(ft[k]);
        gs_synth_sample_free(&smp[k]);
    }
    gs_model_ctx_destroy(c);
    gs_model_destroy(m);
    tiny_remove(path);
    GS_TEST_END();
}
