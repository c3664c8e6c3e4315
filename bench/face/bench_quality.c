/* What the redirect quality costs (face.h): one gs_face_quality_measure
 * of a 256 px image against its prepared reference, the one-shot
 * gs_face_redirect_quality (which also measures the input), and, beside
 * them in the same run, a gaze-sweep render of the model (gs_model_render
 * at new gazes, one thread), the work it is added to.
 * usage: bench_quality MODEL [N] */ 
#define _POSIX_C_SOURCE 200809L
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "gazesplat/face.h"
#include "gazesplat/model.h"
#include "gazesplat/synth.h"

static double now_s(void)
{
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return (double)t.tv_sec + 1e-9 * (double)t.tv_nsec;
}

int main(int argc, char **argv)
{
    if (argc < 2) {
        fprintf(stderr, "usage: bench_quality MODEL [N]\n");
        return 2;
    }
    int n = argc > 2 ? atoi(argv[2]) : 100;
    if (n < 1)
        n = 1;
    gs_error err = {0, ""};
    gs_model *m = NULL;
    if (gs_model_load(argv[1], &m, &err)) {
        fprintf(stderr, "%s: %s\n", argv[1], err.msg);
        return 1;
    }
    gs_model_info info;
    gs_model_get_info(m, &info);
    int S = info.image_size;
    gs_synth_scene sc;
    gs_synth_scene_default(&sc, 650);
    gs_synth_camera base, cam;
    gs_synth_camera_single(S, 650, 300, &base);
    gs_synth_sample a = {0}, b = {0};
    if (gs_synth_camera_normalized(&sc, &base, S, 0, 0, &cam, &err) ||
        gs_synth_sample_alloc(&a, S, S, &err) || gs_synth_sample_alloc(&b, S, S, &err) ||
        gs_synth_render(&sc, &cam, NULL, NULL, &a, &err)) {
        fprintf(stderr, "%s\n", err.msg);
        return 1;
    }
    sc.gaze_yaw = 0.3;
    if (gs_synth_render(&sc, &cam, NULL, NULL, &b, &err)) {
        fprintf(stderr, "%s\n", err.msg);
        return 1;
    }
    gs_io_image in = {S, S, a.stride, a.rgb}, out = {S, S, b.stride, b.rgb};
    const double(*uv)[2] = (const double(*)[2])a.labels.lm2d;
    gs_face_quality_opts qo;
    gs_face_quality_opts_default(&qo);
    qo.px_per_mm = info.focal / info.distance_mm;
    gs_face_quality_ref *r = NULL;
    gs_face_quality q;
    if (gs_face_quality_ref_create(&in, uv, &qo, &r, &err)) {
        fprintf(stderr, "%s\n", err.msg);
        return 1;
    }
    double t0 = now_s();
    for (int i = 0; i < n; i++)
        gs_face_quality_measure(r, &out, a.labels.head_R, 0, 0.3, &q, NULL);
    double t1 = now_s();
    for (int i = 0; i < n; i++)
        gs_face_redirect_quality(&in, &out, uv, a.labels.head_R, 0, 0.3, &qo, &q, NULL);
    double t2 = now_s();
    /* With the landmark model (what every photo path passes): the
     * output's contours moved with its lids. */
    gs_face_shape_model *sp = NULL;
    gs_face_quality_ref *rs = NULL;
    double ms = NAN;
    if (gs_face_shape_model_load(NULL, &sp, NULL) == GS_OK) {
        gs_face_quality_opts qs = qo;
        qs.shape = sp;
        if (gs_face_quality_ref_create(&in, uv, &qs, &rs, &err) == GS_OK) {
            double t = now_s();
            for (int i = 0; i < n; i++)
                gs_face_quality_measure(rs, &out, a.labels.head_R, 0, 0.3, &q, NULL);
            ms = (now_s() - t) / n * 1e3;
        }
    }
    /* A fitted-looking subject: the model's mean code, frontal. */
    gs_subject s;
    memset(&s, 0, sizeof s);
    s.code_dim = info.code_dim;
    s.head_R[0] = s.head_R[4] = s.head_R[8] = 1;
    s.head_t[2] = info.distance_mm;
    for (int k = 0; k < 3; k++)
        s.colour_gain[k] = 1;
    gs_model_ctx *c = gs_model_ctx_create(m);
    uint8_t *px = malloc((size_t)S * S * 3);
    gs_view v;
    memset(&v, 0, sizeof v);
    gs_model_render(c, NULL, &s, &v, px, (size_t)S * 3, NULL); /* the sweep's first, full render */
    double t3 = now_s();
    for (int i = 0; i < n; i++) {
        v.gaze_yaw = 0.005 * (i % 60);
        gs_model_render(c, NULL, &s, &v, px, (size_t)S * 3, NULL);
    }
    double t4 = now_s();
    double mq = (t1 - t0) / n * 1e3, oq = (t2 - t1) / n * 1e3, rr = (t4 - t3) / n * 1e3;
    printf("%d px, %d runs: quality %.2f ms an image (one-shot, input measured too: %.2f ms; "
           "with the landmark model: %.2f ms); gaze-sweep render %.2f ms; quality / render %.2f\n",
           S, n, mq, oq, ms, rr, mq / rr);
    gs_face_quality_ref_destroy(rs);
    gs_face_shape_model_destroy(sp);
    free(px);
    gs_model_ctx_destroy(c);
    gs_face_quality_ref_destroy(r);
    gs_synth_sample_free(&a);
    gs_synth_sample_free(&b);
    gs_model_destroy(m);
    return 0;
}
