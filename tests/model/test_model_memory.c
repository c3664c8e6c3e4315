/* A context's memory (model.h, "Contexts and memory"): one that only
 * renders (full, incremental, other subjects, detail transfer, on a pool
 * or inline) never holds the buffers only fitting and training use; a fit
 * makes them, gs_model_ctx_trim frees them, and the renders, the fits and
 * the fine-tunes are the same bytes whatever a context held before; a
 * backward without a training forward is refused; a training forward
 * whose face stream the context has cached from a render, or from before
 * a trim, has the gradients of a fresh context. */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "gazesplat/nn.h"
#include "gs_test.h"
#include "model_test_util.h"

#define NVIEW 4

static size_t train_bytes(const gs_model_ctx *c)
{
    gs_model_ctx_stats st;
    gs_model_ctx_get_stats(c, &st);
    return st.train_bytes;
}

static void view_of(int i, gs_view *v)
{
    memset(v, 0, sizeof *v);
    v->gaze_pitch = 0.1 * (i % 3) - 0.1;
    v->gaze_yaw = 0.15 * i - 0.2;
}

/* The NVIEW views of s through c into out[NVIEW][S*S*3]. */
static void render_views(gs_model_ctx *c, gs_pool *pool, const gs_subject *s, int S, uint8_t *out)
{
    for (int i = 0; i < NVIEW; i++) {
        gs_view v;
        view_of(i, &v);
        gs_error err = {0, ""};
        CHECK_MSG(gs_model_render(c, pool, s, &v, out + (size_t)i * S * S * 3, 3 * (size_t)S, &err) ==
                      GS_OK, "%s", err.msg);
    }
}

static void same_bytes(const uint8_t *a, const uint8_t *b, size_t n, const char *what)
{
    size_t diff = 0, first = n;
    for (size_t i = 0; i < n; i++)
        if (a[i] != b[i]) {
            diff++;
            if (first == n)
                first = i;
        }
    CHECK_MSG(diff == 0, "%s: %zu of %zu bytes differ, the first at %zu (%d against %d)", what, diff,
              n, first, first < n ? a[first] : 0, first < n ? b[first] : 0);
}

static int fit(gs_model_ctx *c, const uint8_t *img, int S, gs_subject *out)
{
    gs_fit_options fo;
    gs_fit_options_default(&fo);
    fo.max_iters = 4;
    gs_error err = {0, ""};
    int rc = gs_model_fit(c, NULL, img, 3 * (size_t)S, &fo, out, NULL, &err);
    CHECK_MSG(rc == GS_OK, "fit: %s", err.msg);
    return rc;
}

static void same_subject(const gs_subject *a, const gs_subject *b, const char *what)
{
    uint8_t ea[GS_SUBJECT_ENCODED_MAX], eb[GS_SUBJECT_ENCODED_MAX];
    size_t na = gs_subject_encode(a, ea, sizeof ea), nb = gs_subject_encode(b, eb, sizeof eb);
    CHECK_MSG(na == nb && !memcmp(ea, eb, na), "%s: the subjects differ", what);
}

static void check_model(gs_model *m, const char *name)
{
    printf("%s\n", name);
    int S = m->cfg.image_size;
    size_t isz = (size_t)S * S * 3;
    gs_subject s = frame_subject(m), s2 = s;
    s2.code[0] += 0.2f;
    gs_pool *pool = gs_pool_create(2);
    uint8_t *ref = malloc(NVIEW * isz), *got = malloc(NVIEW * isz), *img = malloc(isz),
            *xf = malloc(isz);
    gs_model_ctx *a = gs_model_ctx_create(m), *b = gs_model_ctx_create(m);
    CHECK(a && b && pool && ref && got && img && xf);
    /* renders only: none of the training buffers */
    render_views(a, NULL, &s, S, ref);
    render_views(a, NULL, &s2, S, got);
    render_views(a, NULL, &s, S, got);
    same_bytes(ref, got, NVIEW * isz, "back to the first subject");
    render_views(b, pool, &s, S, got);
    same_bytes(ref, got, NVIEW * isz, "a pool of 2 against inline");
    memcpy(img, ref, isz);
    gs_view v;
    view_of(1, &v);
    gs_error err = {0, ""};
    CHECK_MSG(gs_model_render_transfer(a, NULL, &s, img, 3 * (size_t)S, &v, xf, 3 * (size_t)S,
                                       &err) == GS_OK, "%s", err.msg);
    CHECK_MSG(train_bytes(a) == 0 && train_bytes(b) == 0,
              "render-only contexts hold %zu and %zu training bytes", train_bytes(a),
              train_bytes(b));
    gs_model_ctx_stats st;
    gs_model_ctx_get_stats(a, &st);
    printf("  renders: %llu full, %llu incremental; no training buffers\n",
           (unsigned long long)st.renders_full, (unsigned long long)st.renders_incremental);
    /* a backward needs a training forward */
    CHECK_EQ_INT(gs_frame_backward(a, NULL, NULL, NULL, NULL, NULL, NULL, NULL, &err),
                 GS_ERR_STATE);
    /* a fit makes them; trim frees them; everything the same bytes */
    gs_subject f1, f2, f3;
    fit(a, img, S, &f1);
    size_t tb = train_bytes(a);
    CHECK_MSG(tb > 0, "a fit allocated no training buffers");
    printf("  after a fit: %.2f MB of training buffers\n", (double)tb / 1048576.0);
    render_views(a, NULL, &f1, S, got);
    uint8_t *fitted = malloc(NVIEW * isz);
    memcpy(fitted, got, NVIEW * isz);
    CHECK_EQ_INT(gs_model_ctx_trim(a), GS_OK);
    CHECK_EQ_INT(train_bytes(a), 0);
    CHECK_EQ_INT(gs_model_ctx_trim(a), GS_OK); /* again: nothing to do */
    render_views(a, NULL, &f1, S, got);
    same_bytes(fitted, got, NVIEW * isz, "the fitted subject after trim");
    render_views(a, pool, &s, S, got);
    same_bytes(ref, got, NVIEW * isz, "the first subject after a fit and trim");
    CHECK_EQ_INT(gs_frame_backward(a, NULL, NULL, NULL, NULL, NULL, NULL, NULL, &err),
                 GS_ERR_STATE);
    fit(a, img, S, &f2);
    CHECK_EQ_INT(train_bytes(a), tb);
    same_subject(&f1, &f2, "a fit after trim");
    fit(b, img, S, &f3);
    same_subject(&f1, &f3, "a fit through a context that rendered on a pool");
    render_views(b, NULL, &f1, S, got);
    same_bytes(fitted, got, NVIEW * isz, "the fitted subject on another context");
    /* fine-tunes (their own context) are the same bytes either way */
    gs_model *c1 = NULL, *c2 = NULL;
    CHECK(gs_model_clone(m, &c1, &err) == GS_OK && gs_model_clone(m, &c2, &err) == GS_OK);
    gs_finetune_options to;
    gs_finetune_options_default(&to);
    to.iters = 2;
    CHECK_MSG(gs_model_finetune(c1, NULL, &f1, img, 3 * (size_t)S, &to, NULL, &err) == GS_OK, "%s",
              err.msg);
    CHECK_MSG(gs_model_finetune(c2, pool, &f1, img, 3 * (size_t)S, &to, NULL, &err) == GS_OK, "%s",
              err.msg);
    CHECK(c1 && c2 && !memcmp(c1->params, c2->params, c1->nparams * sizeof(float)));
    gs_model_destroy(c1);
    gs_model_destroy(c2);
    gs_model_ctx_destroy(a);
    gs_model_ctx_destroy(b);
    gs_model_ctx_trim(NULL);
    gs_pool_destroy(pool);
    free(ref), free(got), free(img), free(xf), free(fitted);
}

static void check_shared(gs_model *m)
{
    int S = m->cfg.image_size;
    size_t isz = (size_t)S * S * 3;
    gs_error err = {0, ""};
    gs_model *cl = NULL;
    CHECK(gs_model_clone(m, &cl, &err) == GS_OK);
    for (size_t i = 0; cl && i < cl->nparams; i += 7) /* another model */
        cl->params[i] *= 1.01f;
    gs_subject s = frame_subject(m), s2 = s;
    s2.code[1] -= 0.3f;
    gs_pool *pool = gs_pool_create(2);
    uint8_t *ra = malloc(NVIEW * isz), *rb = malloc(NVIEW * isz), *got = malloc(NVIEW * isz);
    /* the references, each through a context of its own */
    gs_model_ctx *a = gs_model_ctx_create(m), *b = gs_model_ctx_create(cl);
    render_views(a, pool, &s, S, ra);
    render_views(b, pool, &s2, S, rb);
    gs_model_ctx_destroy(a);
    gs_model_ctx_destroy(b);
    /* three contexts on one scratch, in turns */
    a = gs_model_ctx_create(m), b = gs_model_ctx_create(cl);
    gs_model_ctx *c = gs_model_ctx_create(m);
    CHECK_EQ_INT(gs_model_ctx_share_scratch(b, a), GS_OK);
    CHECK_EQ_INT(gs_model_ctx_share_scratch(c, b), GS_OK);
    CHECK_EQ_INT(gs_model_ctx_share_scratch(c, a), GS_OK); /* already */
    CHECK_EQ_INT(gs_model_ctx_share_scratch(NULL, a), GS_ERR_ARG);
    for (int round = 0; round < 2; round++) {
        render_views(b, pool, &s2, S, got);
        same_bytes(rb, got, NVIEW * isz, "the clone on a shared scratch");
        render_views(a, round ? pool : NULL, &s, S, got);
        same_bytes(ra, got, NVIEW * isz, "the model on a shared scratch");
        uint8_t *img = malloc(isz);
        memcpy(img, ra, isz);
        gs_subject f;
        fit(c, img, S, &f); /* its own training buffers, the shared scratch */
        free(img);
    }
    gs_model_ctx_destroy(a); /* the scratch's first owner */
    render_views(b, NULL, &s2, S, got);
    same_bytes(rb, got, NVIEW * isz, "the clone after the first owner went");
    gs_model_ctx_trim(c); /* renders through the shared scratch again */
    render_views(c, pool, &s, S, got);
    same_bytes(ra, got, NVIEW * isz, "the model after the first owner went");
    gs_model_ctx_destroy(c);
    gs_model_ctx_destroy(b);
    gs_model_destroy(cl);
    gs_pool_destroy(pool);
    free(ra), free(rb), free(got);
}

/* The frame's code, pose and gaze gradients after a training forward in
 * c, from one fixed image gradient. */
static void frame_grads(gs_model_ctx *c, const gs_frame *fr, const float *drgb, gs_frame_grad *fg)
{
    gs_error err = {0, ""};
    memset(fg, 0, sizeof *fg);
    CHECK_MSG(gs_frame_forward(c, NULL, fr, GS_STREAM_BOTH, 0, &err) == GS_OK, "%s", err.msg);
    CHECK_MSG(gs_frame_backward(c, NULL, drgb, NULL, NULL, NULL, NULL, fg, &err) == GS_OK, "%s",
              err.msg);
}

static void same_grads(const gs_frame_grad *a, const gs_frame_grad *b, const char *what)
{
    CHECK_MSG(!memcmp(a, b, sizeof *a), "%s: the frame's gradients differ (code[0] %.9g against %.9g)",
              what, (double)a->code[0], (double)b->code[0]);
}

/* The face stream is cached by (code, head pose); a training forward's
 * backward reads the face MLPs' activations, which only a forward with the
 * training buffers saves. Hard cases: the same frame after the buffers were
 * trimmed (a fit stopped after its first step, then fitted again: every
 * fit starts at the same frame), and after a render of that frame with no
 * training buffers (a fit that starts at a rendered subject). */
static void check_face_cache(gs_model *m)
{
    int S = m->cfg.image_size;
    gs_frame fr;
    frame_default(m, &fr);
    float *drgb = malloc(sizeof(float) * 3 * (size_t)S * S);
    uint8_t *rgb = malloc(3 * (size_t)S * S);
    CHECK(drgb && rgb);
    for (size_t i = 0; i < 3 * (size_t)S * S; i++)
        drgb[i] = 0.01f * (float)((int)(i % 13) - 6);
    gs_frame_grad ref, got;
    gs_model_ctx *c = gs_model_ctx_create(m);
    frame_grads(c, &fr, drgb, &ref);
    gs_model_ctx_destroy(c);
    c = gs_model_ctx_create(m);
    gs_frame other = fr;
    other.code[0] += 0.3f;
    frame_grads(c, &other, drgb, &got);
    frame_grads(c, &fr, drgb, &got);
    same_grads(&ref, &got, "after another frame");
    gs_model_ctx_trim(c);
    frame_grads(c, &fr, drgb, &got);
    same_grads(&ref, &got, "the same frame after a trim");
    gs_model_ctx_trim(c);
    /* one kept render: nothing is stashed before the training forward */
    CHECK_EQ_INT(gs_model_ctx_set_sweep_cache(c, 1, NULL), GS_OK);
    gs_subject s = frame_subject(m);
    gs_view v;
    memset(&v, 0, sizeof v);
    v.gaze_pitch = fr.gaze[0];
    v.gaze_yaw = fr.gaze[1];
    gs_error err = {0, ""};
    CHECK_MSG(gs_model_render(c, NULL, &s, &v, rgb, 3 * (size_t)S, &err) == GS_OK, "%s", err.msg);
    CHECK_EQ_INT(train_bytes(c), 0);
    frame_grads(c, &fr, drgb, &got);
    same_grads(&ref, &got, "the frame of a render made without training buffers");
    printf("  a cached face stream: the gradients of a fresh context after a trim and a render\n");
    gs_model_ctx_destroy(c);
    free(drgb), free(rgb);
}

int main(void)
{
    gs_nn_blas_set_threads(1);
    gs_model *m = tiny_model(GS_GUIDE_ADDITIVE, 7);
    CHECK(m != NULL);
    if (m)
        check_model(m, "two streams, SOURCE guidance");
    if (m)
        check_shared(m);
    if (m)
        check_face_cache(m);
    gs_model_destroy(m);
    m = with_lids(tiny_model(GS_GUIDE_MULTIPLICATIVE, 8));
    CHECK(m != NULL);
    if (m)
        check_model(m, "with lids, multiplicative guidance");
    if (m)
        check_face_cache(m);
    gs_model_destroy(m);
    GS_TEST_END();
}
