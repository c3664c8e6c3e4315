/* lib/redirect (redirect.h), the pieces every redirect path shares:
 * - inputs: a normalized face of the wrong size, a flat face with and
 *   without the gate, a photo with no face, an index past the faces and
 *   a real photo (astronaut.png), each with the error and refusal callers
 *   map to their exit codes and protocol errors; a failed input holds
 *   nothing and has taken the image;
 * - the fit's options: the landmarks' pose in the normalized camera at
 *   d_n, the mask, the served iteration cap; a known head at d_n;
 * - fine-tuning: a clone made on first use; a clone given is reset to the
 *   shared parameters first, so a second subject's block equals the one a
 *   fresh clone gets; the shared model is untouched;
 * - rendering: plain is gs_model_render, with the input gs_model_render_transfer;
 * - paste-back: refused for a normalized input; the photo's own face pasted
 *   back leaves every pixel outside the mask as it was and changes the
 *   eyes by little; the masks are made once. */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "gazesplat/redirect.h"
#include "gs_test.h"
#include "../model/model_test_util.h"

static gs_io_image grey(int w, int h, uint8_t v)
{
    gs_io_image im = {w, h, (size_t)w * 3, malloc((size_t)w * h * 3)};
    memset(im.data, v, (size_t)w * h * 3);
    return im;
}

static void inputs(const gs_model_info *info)
{
    gs_error err = {0, ""};
    gs_redirect_input in;
    int S = info->image_size;

    gs_io_image f = grey(S + 1, S, 128);
    CHECK(gs_redirect_input_face(info, &f, 0, &in, &err) == GS_ERR_ARG);
    CHECK(f.data == NULL && in.norm.data == NULL); /* taken, then freed */
    CHECK_MSG(strstr(err.msg, "normalized face is") && strstr(err.msg, "the model wants"), "%s",
              err.msg);
    CHECK(in.gate.refusal == GS_FACE_USABLE);

    f = grey(S, S, 128);
    CHECK(gs_redirect_input_face(info, &f, 0, &in, &err) == GS_OK);
    CHECK(in.norm.data && !in.is_photo && !in.mask);
    gs_redirect_input_free(&in);
    CHECK(in.norm.data == NULL);

    f = grey(S, S, 128);
    CHECK(gs_redirect_input_face(info, &f, 1, &in, &err) == GS_ERR_ARG);
    CHECK_MSG(in.gate.refusal == GS_FACE_REFUSED_FLAT, "refusal %d", (int)in.gate.refusal);
    CHECK_MSG(strstr(err.msg, "face refused (flat)") == err.msg, "%s", err.msg);
    CHECK(in.norm.data == NULL);
}

static void photo_inputs(const gs_model_info *info, gs_face_detector *det, const gs_face_shape_model *sp,
                         const gs_io_image *astro)
{
    gs_error err = {0, ""};
    gs_redirect_input in;
    gs_redirect_photo_opts po;
    gs_redirect_photo_opts_default(&po);
    CHECK(po.gate == 1 && po.index == 0 && po.use_k == 0);

    gs_io_image black = grey(320, 240, 0);
    CHECK(gs_redirect_input_photo(det, sp, info, &black, &po, &in, &err) == GS_ERR_ARG);
    CHECK(in.gate.refusal == GS_FACE_REFUSED_NO_FACE);
    CHECK_MSG(strncmp(err.msg, "photo: ", 7) == 0, "%s", err.msg);
    CHECK(black.data == NULL && in.photo.data == NULL && in.norm.data == NULL && !in.mask);

    gs_io_image copy = *astro;
    copy.data = malloc(astro->stride * (size_t)astro->height);
    memcpy(copy.data, astro->data, astro->stride * (size_t)astro->height);
    po.index = 5; /* one face in the astronaut */
    CHECK(gs_redirect_input_photo(det, sp, info, &copy, &po, &in, &err) == GS_ERR_ARG);
    CHECK(in.gate.refusal == GS_FACE_REFUSED_NO_FACE);
}

/* 1 when the two models' parameters hold the same bytes. */
static int params_same(const gs_model *a, const gs_model *b)
{
    return a->nparams == b->nparams && !memcmp(a->params, b->params, a->nparams * sizeof(float));
}

static void fit_render_paste(gs_model *m, gs_face_detector *det, const gs_face_shape_model *sp,
                             const gs_io_image *astro)
{
    gs_error err = {0, ""};
    gs_model_info info;
    gs_model_get_info(m, &info);
    int S = info.image_size;
    gs_redirect_input in;
    gs_redirect_photo_opts po;
    gs_redirect_photo_opts_default(&po);
    po.gate = 0; /* the tiny model's image size is under the gate's eye width */
    gs_io_image copy = *astro;
    copy.data = malloc(astro->stride * (size_t)astro->height);
    memcpy(copy.data, astro->data, astro->stride * (size_t)astro->height);
    CHECK_MSG(gs_redirect_input_photo(det, sp, &info, &copy, &po, &in, &err) == GS_OK, "%s", err.msg);
    if (!in.norm.data)
        return;
    CHECK(in.is_photo && in.mask && in.photo.data && copy.data == NULL);
    CHECK(in.norm.width == S && in.norm.height == S);

    /* The fit's options: the landmarks' pose, rotated into the normalized
     * camera, at d_n; the mask; 200 iterations. */
    gs_fit_options o;
    gs_redirect_fit_options(&in, &o);
    double R_n[9];
    gs_geom_norm_rot(&in.face.norm, in.face.pose.R, R_n);
    CHECK(o.known_head && !o.known_gaze && o.mask == in.mask);
    CHECK(o.max_iters == GS_REDIRECT_FIT_ITERS);
    CHECK(!memcmp(o.head_R, R_n, sizeof R_n));
    CHECK(o.head_t[0] == 0.0 && o.head_t[1] == 0.0 && o.head_t[2] == info.distance_mm);
    CHECK(in.face.norm.d_n_mm == info.distance_mm);
    gs_fit_options oh;
    gs_fit_options_default(&oh);
    gs_redirect_fit_head(R_n, 600.0, &oh);
    CHECK(oh.known_head && oh.head_t[2] == 600.0 && !memcmp(oh.head_R, R_n, sizeof R_n));

    o.max_iters = 4;
    gs_model_ctx *c = gs_model_ctx_create(m);
    gs_subject sub;
    gs_fit_report fr;
    CHECK_MSG(gs_model_fit(c, NULL, in.norm.data, in.norm.stride, &o, &sub, &fr, &err) == GS_OK, "%s",
              err.msg);

    /* Fine-tuning: made, then reused and reset. */
    gs_model *shared_copy = NULL;
    CHECK(gs_model_clone(m, &shared_copy, &err) == GS_OK);
    gs_finetune_options ft;
    gs_redirect_finetune_options(3, &ft);
    CHECK(ft.iters == 3 && ft.lr == GS_FINETUNE_LR_SERVED);
    gs_fit_image im;
    gs_fit_image_from_options(&im, in.norm.data, in.norm.stride, NULL);
    im.mask = in.mask;
    gs_model *tuned = NULL, *fresh = NULL;
    gs_finetune_report rep;
    CHECK_MSG(gs_redirect_finetune(&tuned, m, NULL, &sub, &im, 1, &ft, &rep, &err) == GS_OK, "%s", err.msg);
    CHECK(tuned != NULL && rep.iters == 3);
    CHECK(!params_same(tuned, m));
    CHECK(params_same(m, shared_copy)); /* the shared model is untouched */
    /* a second run in the same clone (another subject's turn in a daemon
     * slot) starts from the shared parameters: a fresh clone's bytes */
    gs_subject sub2 = sub;
    sub2.gaze_yaw += 0.1;
    CHECK(gs_redirect_finetune(&tuned, m, NULL, &sub2, &im, 1, &ft, &rep, &err) == GS_OK);
    CHECK(gs_redirect_finetune(&fresh, m, NULL, &sub2, &im, 1, &ft, &rep, &err) == GS_OK);
    CHECK(fresh && params_same(tuned, fresh));
    /* a bad request leaves no clone behind */
    gs_model *none = NULL;
    CHECK(gs_redirect_finetune(&none, m, NULL, &sub, &im, 0, &ft, &rep, &err) != GS_OK);
    CHECK(none == NULL);

    /* Rendering: the library's two modes are the model's. */
    size_t n = (size_t)S * S * 3;
    uint8_t *a = malloc(n), *b = malloc(n);
    gs_view v = {0};
    v.gaze_pitch = sub.gaze_pitch + 0.1;
    v.gaze_yaw = sub.gaze_yaw - 0.15;
    gs_model_ctx *c1 = gs_model_ctx_create(m), *c2 = gs_model_ctx_create(m);
    CHECK(gs_redirect_render(c1, NULL, &sub, NULL, 0, NULL, &v, a, (size_t)S * 3, &err) == GS_OK);
    CHECK(gs_model_render(c2, NULL, &sub, &v, b, (size_t)S * 3, &err) == GS_OK);
    CHECK(!memcmp(a, b, n));
    gs_model_ctx_reset(c1);
    gs_model_ctx_reset(c2);
    gs_xfer_eyes xe = gs_redirect_eyes(&in);
    CHECK(xe.opening == in.opening && xe.n_iris == in.n_iris && !memcmp(xe.iris, in.iris, sizeof xe.iris));
    CHECK(gs_redirect_render(c1, NULL, &sub, in.norm.data, in.norm.stride, &xe, &v, a, (size_t)S * 3, &err) ==
          GS_OK);
    CHECK(gs_model_render_transfer_eyes(c2, NULL, &sub, in.norm.data, in.norm.stride, &xe, &v, b,
                                        (size_t)S * 3, &err) == GS_OK);
    CHECK(!memcmp(a, b, n));
    /* a photo's irises are the localizer's on its normalized face, both
     * found here (status OK) */
    CHECK_MSG(in.n_iris == 2, "%d irises", in.n_iris);
    for (int e = 0; e < 2; e++) {
        gs_face_iris_opts io;
        gs_face_iris_opts_default(&io);
        gs_face_iris_opts_scale(&io, info.focal / info.distance_mm);
        gs_face_iris ir;
        CHECK(gs_face_iris_locate(&in.norm, (const double(*)[2])in.face.uv_n[36 + 6 * e], &io, &ir, &err) ==
              GS_OK);
        CHECK_MSG(ir.status == GS_FACE_IRIS_OK && in.iris[e][0] == ir.centre[0] &&
                      in.iris[e][1] == ir.centre[1] && in.iris[e][2] == ir.radius,
                  "iris %d: (%g, %g, %g) against the localizer's (%g, %g, %g)", e, in.iris[e][0],
                  in.iris[e][1], in.iris[e][2], ir.centre[0], ir.centre[1], ir.radius);
    }
    /* a photo's opening is its landmarks' eye contours */
    {
        uint8_t *op = malloc((size_t)S * S);
        CHECK(in.opening && op &&
              gs_redirect_eye_opening((const double(*)[2])in.face.uv_n, S, op, &err) == GS_OK &&
              !memcmp(op, in.opening, (size_t)S * S));
        size_t open = 0;
        for (size_t i = 0; in.opening && i < (size_t)S * S; i++)
            open += in.opening[i] > 0;
        CHECK_MSG(open > 0 && open < (size_t)S * S / 20, "opening of %zu px", open);
        /* not grown like the eye masks: inside them and smaller */
        size_t eyes = 0, outside = 0;
        CHECK(op && gs_face_mask((const double(*)[2])in.face.uv_n, GS_FACE_MASK_EYES, 1.0, 2.0, S, S,
                                 op, &err) == GS_OK);
        for (size_t i = 0; op && in.opening && i < (size_t)S * S; i++) {
            eyes += op[i] > 0;
            outside += in.opening[i] > op[i];
        }
        CHECK_MSG(outside == 0 && open < eyes, "opening %zu px, eye masks %zu, %zu above them", open,
                  eyes, outside);
        free(op);
    }

    /* Paste-back: the input's own normalized face back into the photo. */
    gs_redirect_paste_state ps;
    memset(&ps, 0, sizeof ps);
    gs_redirect_input plain;
    gs_io_image g = grey(S, S, 100);
    CHECK(gs_redirect_input_face(&info, &g, 0, &plain, &err) == GS_OK);
    CHECK(plain.opening == NULL); /* a face as given has no landmarks */
    {
        gs_xfer_eyes pe = gs_redirect_eyes(&plain);
        CHECK(pe.opening == NULL && pe.n_iris == 0);
    }
    CHECK(gs_redirect_paste(&plain, &ps, 0, &plain.norm, &err) == GS_ERR_ARG);
    gs_redirect_input_free(&plain);
    CHECK_MSG(gs_redirect_paste(&in, &ps, 0, &in.norm, &err) == GS_OK, "%s", err.msg);
    CHECK(ps.mask[0] && !ps.mask[1]);
    const uint8_t *mask0 = ps.mask[0];
    const gs_io_image *ph = &in.photo;
    size_t outside_changed = 0, inside = 0;
    double inside_diff = 0;
    for (int y = 0; y < ph->height; y++)
        for (int x = 0; x < ph->width; x++) {
            size_t o3 = (size_t)y * ph->stride + 3 * (size_t)x;
            int mk = ps.mask[0][(size_t)y * ph->width + x];
            for (int ch = 0; ch < 3; ch++) {
                int d = abs((int)ps.out.data[o3 + ch] - (int)ph->data[o3 + ch]);
                if (!mk)
                    outside_changed += d != 0;
                else {
                    inside_diff += d;
                    inside++;
                }
            }
        }
    CHECK_MSG(outside_changed == 0, "%zu values changed outside the eye mask", outside_changed);
    CHECK(inside > 0);
    CHECK_MSG(inside_diff / (double)(inside ? inside : 1) < 12.0, "mean change %.2f inside the mask",
              inside_diff / (double)(inside ? inside : 1));
    /* the rendered face pasted in changes the eyes; the mask is kept */
    gs_io_image rendered = {S, S, (size_t)S * 3, a};
    CHECK(gs_redirect_paste(&in, &ps, 0, &rendered, &err) == GS_OK);
    CHECK(ps.mask[0] == mask0);
    CHECK(gs_redirect_paste(&in, &ps, 1, &rendered, &err) == GS_OK);
    CHECK(ps.mask[1] != NULL);
    size_t whole = 0, eyes = 0;
    for (size_t i = 0; i < (size_t)ph->width * ph->height; i++) {
        whole += ps.mask[1][i] != 0;
        eyes += ps.mask[0][i] != 0;
    }
    CHECK_MSG(whole > 4 * eyes, "whole-face mask %zu px against the eyes' %zu", whole, eyes);
    gs_redirect_paste_free(&ps);
    CHECK(ps.out.data == NULL && ps.mask[0] == NULL);

    free(a);
    free(b);
    gs_model_ctx_destroy(c);
    gs_model_ctx_destroy(c1);
    gs_model_ctx_destroy(c2);
    gs_model_destroy(tuned);
    gs_model_destroy(fresh);
    gs_model_destroy(shared_copy);
    gs_redirect_input_free(&in);
}

int main(void)
{
    gs_model *m = tiny_model(GS_GUIDE_ADDITIVE, 7);
    CHECK(m != NULL);
    if (!m)
        GS_TEST_END();
    gs_model_info info;
    gs_model_get_info(m, &info);
    inputs(&info);

    gs_error err = {0, ""};
    gs_io_image astro = {0};
    if (gs_io_image_read(GS_SKIMAGE_DATA "/astronaut.png", NULL, &astro, &err) != GS_OK) {
        fprintf(stderr, "skip: %s\n", err.msg);
        gs_model_destroy(m);
        return 77;
    }
    gs_face_detector *det = NULL;
    gs_face_shape_model *sp = NULL;
    CHECK_MSG(gs_face_detector_load(NULL, &det, &err) == GS_OK, "%s", err.msg);
    CHECK_MSG(gs_face_shape_model_load(NULL, &sp, &err) == GS_OK, "%s", err.msg);
    if (det && sp) {
        photo_inputs(&info, det, sp, &astro);
        fit_render_paste(m, det, sp, &astro);
    }
    gs_face_detector_destroy(det);
    gs_face_shape_model_destroy(sp);
    gs_io_image_free(&astro);
    gs_model_destroy(m);
    GS_TEST_END();
}
