/* A subject from several images (gs_model_fit_images,
 * gs_model_finetune_images, gs_model_fit_images_key) on a tiny model
 * trained for a few steps: one image gives gs_model_fit's bytes, several
 * share their identity bit for bit, 1 and 2 threads agree, the key covers
 * every image and label in order, bad input is refused naming the image.
 * With a model file argument (the shipped model; slow): on synthetic views
 * of held-out identities, each with one expression and light, the held-out
 * view's render and the identity improve from 1 to 4 labelled images. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "gazesplat/nn.h"
#include "gazesplat/pool.h"
#include "gazesplat/synth.h"
#include "gazesplat/train.h"
#include "gs_test.h"
#include "model_test_util.h"

static int subject_bytes_equal(const gs_subject *a, const gs_subject *b)
{
    uint8_t ea[GS_SUBJECT_ENCODED_MAX], eb[GS_SUBJECT_ENCODED_MAX];
    size_t na = gs_subject_encode(a, ea, sizeof ea), nb = gs_subject_encode(b, eb, sizeof eb);
    return na == nb && na > 0 && !memcmp(ea, eb, na);
}

/* Images of one held-out identity: sample `index` of the test split and
 * the same person at other head poses and gazes (same expression, lights
 * and background), normalized; labels and face masks with them. */
typedef struct views {
    int n;
    gs_synth_sample smp[8];
} views;

static int make_views(int S, uint64_t identity, int n, views *v, gs_error *err)
{
    memset(v, 0, sizeof *v);
    gs_synth_ranges rg;
    gs_synth_ranges_default(&rg);
    rg.head_yaw = 30 * 3.14159265358979 / 180;
    rg.head_pitch = 20 * 3.14159265358979 / 180;
    rg.head_roll = 0;
    rg.gaze_yaw = rg.gaze_pitch = 25 * 3.14159265358979 / 180;
    rg.blink_prob = 0;
    const uint64_t id_seed = gs_synth_split_seed(GS_SYNTH_TEST, identity);
    gs_synth_scene base;
    gs_synth_scene_random(id_seed, 7000 + identity, &rg, &base);
    for (int i = 0; i < n; i++) {
        gs_synth_scene sc;
        gs_synth_scene_random(id_seed, 7100 + identity * 64 + (uint64_t)i, &rg, &sc);
        gs_synth_scene s = base; /* the person, expression and lights of base */
        memcpy(s.head_R, sc.head_R, sizeof s.head_R);
        memcpy(s.head_t, sc.head_t, sizeof s.head_t);
        s.gaze_pitch = sc.gaze_pitch;
        s.gaze_yaw = sc.gaze_yaw;
        gs_synth_camera cam, nc;
        gs_synth_camera_single(S, 600, 250, &cam);
        int rc = gs_synth_camera_normalized(&s, &cam, S, 0, 1600.0 * S / 512, &nc, err);
        if (!rc)
            rc = gs_synth_sample_alloc(&v->smp[i], S, S, err);
        if (!rc)
            rc = gs_synth_render(&s, &nc, NULL, NULL, &v->smp[i], err);
        if (rc)
            return rc;
        v->n = i + 1;
    }
    return GS_OK;
}

static void views_free(views *v)
{
    for (int i = 0; i < v->n; i++)
        gs_synth_sample_free(&v->smp[i]);
}

/* Image i of v with its true head pose (and gaze when `gaze`). */
static void view_image(const views *v, int i, int gaze, int mask, gs_fit_image *im)
{
    const gs_synth_sample *s = &v->smp[i];
    gs_fit_image_from_options(im, s->rgb, s->stride, NULL);
    im->mask = mask ? gs_synth_sample_mask(s, GS_SYNTH_MASK_HEAD) : NULL;
    im->known_head = 1;
    memcpy(im->head_R, s->labels.head_R, sizeof im->head_R);
    memcpy(im->head_t, s->labels.head_t, sizeof im->head_t);
    im->known_gaze = gaze;
    im->gaze_pitch = s->labels.gaze_head_pitch;
    im->gaze_yaw = s->labels.gaze_head_yaw;
}

static void tiny_checks(void)
{
    gs_nn_blas_set_threads(1);
    char path[128];
    tiny_path(path, "test_model_multi");
    gs_error err = {0, ""};
    gs_train_report rep;
    gs_model *m = trained_tiny(path, 6, &rep, &err);
    CHECK_MSG(m != NULL, "%s", err.msg);
    gs_model_info info;
    gs_model_get_info(m, &info);
    const int S = info.image_size, id_dim = m->cfg.id_dim;
    gs_model_ctx *c = gs_model_ctx_create(m);
    gs_pool *pool2 = gs_pool_create(2);
    CHECK(c != NULL && pool2 != NULL);
    views v;
    CHECK_MSG(make_views(S, 1, 3, &v, &err) == GS_OK, "%s", err.msg);
    gs_fit_image im[4];
    for (int i = 0; i < 3; i++)
        view_image(&v, i, i != 1, 1, &im[i]);

    /* One image: the bytes of gs_model_fit with the same labels and mask,
     * plain, mirrored and with the priors; the same key. */
    for (int variant = 0; variant < 3; variant++) {
        gs_fit_options fo, fi;
        gs_fit_options_default(&fo);
        fo.max_iters = 6;
        fo.mirror = variant == 1;
        fo.id_prior = variant == 2 ? 0.5 : 0;
        fo.code_prior = variant == 2 ? 0.3 : GS_FIT_CODE_PRIOR_MODEL;
        fi = fo;
        fo.mask = im[0].mask;
        fo.known_head = 1;
        memcpy(fo.head_R, im[0].head_R, sizeof fo.head_R);
        memcpy(fo.head_t, im[0].head_t, sizeof fo.head_t);
        fo.known_gaze = 1;
        fo.gaze_pitch = im[0].gaze_pitch;
        fo.gaze_yaw = im[0].gaze_yaw;
        gs_subject a, b;
        gs_fit_report ra, rb;
        CHECK_MSG(gs_model_fit(c, NULL, im[0].rgb, im[0].stride, &fo, &a, &ra, &err) == GS_OK,
                  "%s", err.msg);
        CHECK_MSG(gs_model_fit_images(c, NULL, im, 1, &fi, &b, &rb, &err) == GS_OK, "%s",
                  err.msg);
        CHECK_MSG(subject_bytes_equal(&a, &b), "variant %d: one image differs from gs_model_fit "
                  "(psnr %.6f vs %.6f)", variant, a.fit_psnr, b.fit_psnr);
        CHECK(ra.iters == rb.iters && ra.loss_last == rb.loss_last);
        CHECK(gs_model_fit_key(m, &fo, im[0].rgb, im[0].stride) ==
              gs_model_fit_images_key(m, &fi, im, 1));
    }

    /* Three images: one identity, bit for bit; their own gaze, head and
     * expression; the same bytes on 1 and 2 threads; known labels kept. */
    gs_fit_options fo;
    gs_fit_options_default(&fo);
    fo.max_iters = 8;
    gs_subject s1[3], s2[3];
    gs_fit_report r3;
    CHECK_MSG(gs_model_fit_images(c, NULL, im, 3, &fo, s1, &r3, &err) == GS_OK, "%s", err.msg);
    CHECK_MSG(gs_model_fit_images(c, pool2, im, 3, &fo, s2, NULL, &err) == GS_OK, "%s", err.msg);
    CHECK(r3.iters >= 1 && r3.loss_last <= r3.loss_first);
    for (int i = 0; i < 3; i++) {
        CHECK_MSG(subject_bytes_equal(&s1[i], &s2[i]), "image %d: 1 and 2 threads differ", i);
        CHECK_MSG(!memcmp(s1[i].code, s1[0].code, (size_t)id_dim * sizeof(float)),
                  "image %d: identity differs from image 0's (slot 0: %.9g vs %.9g)", i,
                  s1[i].code[0], s1[0].code[0]);
        CHECK(isfinite(s1[i].fit_psnr) && s1[i].fit_psnr > 5);
        CHECK(!memcmp(s1[i].head_R, im[i].head_R, sizeof im[i].head_R));
    }
    CHECK(s1[0].gaze_pitch == im[0].gaze_pitch && s1[2].gaze_yaw == im[2].gaze_yaw);
    CHECK(s1[1].gaze_pitch != im[1].gaze_pitch); /* image 1's gaze is fitted */
    int expr_differs = 0;
    for (int k = id_dim; k < s1[0].code_dim; k++)
        expr_differs |= s1[0].code[k] != s1[1].code[k];
    CHECK_MSG(expr_differs, "images 0 and 1 have the same expression and lights");
    printf("3 images: %d iterations, loss %.4f -> %.4f, PSNR %.2f %.2f %.2f dB\n", r3.iters,
           r3.loss_first, r3.loss_last, s1[0].fit_psnr, s1[1].fit_psnr, s1[2].fit_psnr);
    /* The first image alone fits another identity. */
    gs_subject one;
    CHECK(gs_model_fit_images(c, NULL, im, 1, &fo, &one, NULL, &err) == GS_OK);
    CHECK(memcmp(one.code, s1[0].code, (size_t)id_dim * sizeof(float)) != 0);

    /* The key: every image, label and mask, in order. */
    const uint64_t k3 = gs_model_fit_images_key(m, &fo, im, 3);
    CHECK(k3 != 0 && k3 == gs_model_fit_images_key(m, &fo, im, 3));
    CHECK(k3 != gs_model_fit_images_key(m, &fo, im, 2));
    gs_fit_image sw[3] = {im[1], im[0], im[2]};
    CHECK(k3 != gs_model_fit_images_key(m, &fo, sw, 3));
    sw[0] = im[0], sw[1] = im[1];
    sw[2].gaze_yaw += 1e-3;
    CHECK(k3 != gs_model_fit_images_key(m, &fo, sw, 3));
    sw[2] = im[2];
    sw[1].mask = NULL;
    CHECK(k3 != gs_model_fit_images_key(m, &fo, sw, 3));
    CHECK(gs_model_fit_images_key(m, &fo, im, 0) == 0 &&
          gs_model_fit_images_key(m, &fo, im, GS_FIT_IMAGES_MAX + 1) == 0);

    /* Bad input: the count, labels in the options, a bad label names its
     * image; the subjects are left alone. */
    gs_subject keep[3];
    memcpy(keep, s1, sizeof keep);
    CHECK(gs_model_fit_images(c, NULL, im, 0, &fo, s1, NULL, &err) == GS_ERR_ARG);
    CHECK(gs_model_fit_images(c, NULL, im, GS_FIT_IMAGES_MAX + 1, &fo, s1, NULL, &err) ==
          GS_ERR_ARG);
    CHECK(strstr(err.msg, "1..16") != NULL);
    gs_fit_options fl = fo;
    fl.known_gaze = 1;
    CHECK(gs_model_fit_images(c, NULL, im, 3, &fl, s1, NULL, &err) == GS_ERR_ARG);
    sw[1] = im[1];
    sw[2].known_gaze = 1;
    sw[2].gaze_pitch = NAN;
    CHECK(gs_model_fit_images(c, NULL, sw, 3, &fo, s1, NULL, &err) != GS_OK);
    CHECK_MSG(strstr(err.msg, "image 2") != NULL, "%s", err.msg);
    sw[2] = im[2];
    sw[1].stride = 3;
    CHECK(gs_model_fit_images(c, NULL, sw, 3, &fo, s1, NULL, &err) == GS_ERR_ARG);
    CHECK_MSG(strstr(err.msg, "image 1") != NULL, "%s", err.msg);
    CHECK(!memcmp(keep, s1, sizeof keep));

    /* Fine-tuning over the pairs: one image gives gs_model_finetune's
     * parameters; three tune one set that renders the three better. */
    gs_finetune_options ft;
    gs_finetune_options_default(&ft);
    ft.iters = 4;
    gs_model *ta = NULL, *tb = NULL, *tc = NULL;
    CHECK(gs_model_clone(m, &ta, &err) == GS_OK && gs_model_clone(m, &tb, &err) == GS_OK &&
          gs_model_clone(m, &tc, &err) == GS_OK);
    gs_finetune_options fm = ft;
    fm.mask = im[0].mask;
    gs_finetune_report fa, fb, fc;
    CHECK_MSG(gs_model_finetune(ta, NULL, &s1[0], im[0].rgb, im[0].stride, &fm, &fa, &err) ==
                  GS_OK, "%s", err.msg);
    CHECK_MSG(gs_model_finetune_images(tb, NULL, s1, im, 1, &ft, &fb, &err) == GS_OK, "%s",
              err.msg);
    CHECK_MSG(gs_model_param_id(ta) == gs_model_param_id(tb) && fa.loss_best == fb.loss_best,
              "one pair differs from gs_model_finetune (loss %.9g vs %.9g)", fa.loss_best,
              fb.loss_best);
    CHECK_MSG(gs_model_finetune_images(tc, pool2, s1, im, 3, &ft, &fc, &err) == GS_OK, "%s",
              err.msg);
    CHECK(fc.iters >= 1 && fc.loss_best <= fc.loss_first && isfinite(fc.psnr_best));
    CHECK(gs_model_param_id(tc) != gs_model_param_id(m));
    printf("finetune over 3 pairs: loss %.4f -> %.4f, mean PSNR %.2f -> %.2f dB\n",
           fc.loss_first, fc.loss_best, fc.psnr_first, fc.psnr_best);
    CHECK(gs_model_finetune_images(tc, NULL, s1, im, 0, &ft, &fc, &err) == GS_ERR_ARG);
    CHECK(gs_model_finetune_images(tc, NULL, s1, im, 3, &fm, &fc, &err) == GS_ERR_ARG);
    gs_model_destroy(ta);
    gs_model_destroy(tb);
    gs_model_destroy(tc);

    views_free(&v);
    gs_pool_destroy(pool2);
    gs_model_ctx_destroy(c);
    gs_model_destroy(m);
    tiny_remove(path);
}

/* The shipped model (param_id 2d2a9728e3a27b21) gains 0.22 dB on the mean
 * over the 4 identities (+0.53, +0.20, +0.25, -0.10: docs/subjects.md);
 * the run is deterministic, so this asks for about half of that. */
#define GAIN_MIN_DB 0.1

/* PSNR over the mask's pixels (255) of two S x S RGB images. */
static double masked_psnr(const uint8_t *a, const uint8_t *b, size_t stride, const uint8_t *mask,
                          int S)
{
    double se = 0;
    size_t n = 0;
    for (int y = 0; y < S; y++)
        for (int x = 0; x < S; x++) {
            if (mask[(size_t)y * S + x] < 128)
                continue;
            for (int k = 0; k < 3; k++) {
                double d = (a[(size_t)y * stride + 3 * x + k] - b[(size_t)y * S * 3 + 3 * x + k]) /
                           255.0;
                se += d * d;
            }
            n += 3;
        }
    return -10.0 * log10(se / (double)(n ? n : 1) + 1e-12);
}

/* The shipped model: per held-out identity, fit images 0..k-1 (true head
 * pose and gaze, the head mask), render view 5 (never fitted) from image
 * 0's subject at that view's gaze and head pose, and compare. */
static void shipped_checks(const char *model_path, int ids)
{
    gs_error err = {0, ""};
    gs_model *m = NULL;
    CHECK_MSG(gs_model_load(model_path, &m, &err) == GS_OK, "%s", err.msg);
    gs_model_info info;
    gs_model_get_info(m, &info);
    const int S = info.image_size;
    gs_model_ctx *c = gs_model_ctx_create(m);
    gs_pool *pool = gs_pool_create(2);
    uint8_t *out = malloc(3 * (size_t)S * S);
    CHECK(c && pool && out);
    const int ks[2] = {1, 4}, held = 5;
    double sum[2] = {0, 0};
    int better = 0;
    for (int id = 0; id < ids; id++) {
        views v;
        CHECK_MSG(make_views(S, 20 + (uint64_t)id, held + 1, &v, &err) == GS_OK, "%s", err.msg);
        double p[2];
        for (int t = 0; t < 2; t++) {
            gs_fit_image im[GS_FIT_IMAGES_MAX];
            for (int i = 0; i < ks[t]; i++)
                view_image(&v, i, 1, 1, &im[i]);
            gs_fit_options fo;
            gs_fit_options_default(&fo);
            gs_subject sub[GS_FIT_IMAGES_MAX];
            gs_fit_report r;
            CHECK_MSG(gs_model_fit_images(c, pool, im, ks[t], &fo, sub, &r, &err) == GS_OK, "%s",
                      err.msg);
            const gs_synth_sample *h = &v.smp[held];
            gs_view view = {.gaze_pitch = h->labels.gaze_head_pitch,
                            .gaze_yaw = h->labels.gaze_head_yaw, .use_head = 1};
            memcpy(view.head_R, h->labels.head_R, sizeof view.head_R);
            memcpy(view.head_t, h->labels.head_t, sizeof view.head_t);
            CHECK_MSG(gs_model_render(c, pool, &sub[0], &view, out, 3 * (size_t)S, &err) == GS_OK,
                      "%s", err.msg);
            p[t] = masked_psnr(h->rgb, out, h->stride, gs_synth_sample_mask(h, GS_SYNTH_MASK_FACE),
                               S);
            sum[t] += p[t];
            printf("identity %d, k = %d: %d iterations in %.1f s, held-out view face PSNR "
                   "%.2f dB\n", id, ks[t], r.iters, r.seconds, p[t]);
        }
        better += p[1] > p[0];
        views_free(&v);
    }
    const double gain = (sum[1] - sum[0]) / ids;
    printf("held-out view face PSNR over %d identities: k = 1 %.2f dB, k = 4 %.2f dB "
           "(%+.2f dB; better for %d of %d)\n", ids, sum[0] / ids, sum[1] / ids, gain, better, ids);
    CHECK_MSG(gain > GAIN_MIN_DB, "k = 4 gains %.2f dB over k = 1, want > %.2f", gain, GAIN_MIN_DB);
    free(out);
    gs_pool_destroy(pool);
    gs_model_ctx_destroy(c);
    gs_model_destroy(m);
}

int main(int argc, char **argv)
{
    setvbuf(stdout, NULL, _IOLBF, 0); /* the slow run's progress, line by line */
    if (argc > 1) {
        shipped_checks(argv[1], argc > 2 ? atoi(argv[2]) : 4);
        GS_TEST_END();
    }
    tiny_checks();
    GS_TEST_END();
}
