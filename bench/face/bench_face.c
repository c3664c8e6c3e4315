/* bench_face: model parse time, landmark prediction per face, detection
 * and the whole analysis on a photo.
 * usage: bench_face PHOTO [REPEATS] */
#define _POSIX_C_SOURCE 200809L
#include <stdio.h>
#include <stdlib.h>
#include <time.h>

#include "gazesplat/face.h"

static double clock_s(clockid_t id)
{
    struct timespec t;
    clock_gettime(id, &t);
    return (double)t.tv_sec + 1e-9 * (double)t.tv_nsec;
}

static double now(void)
{
    return clock_s(CLOCK_MONOTONIC);
}

int main(int argc, char **argv)
{
    if (argc < 2) {
        fprintf(stderr, "usage: bench_face PHOTO [REPEATS]\n");
        return 2;
    }
    int reps = argc > 2 ? atoi(argv[2]) : 1000;
    gs_error err;
    gs_io_image img;
    if (gs_io_image_read(argv[1], NULL, &img, &err)) {
        fprintf(stderr, "%s\n", err.msg);
        return 1;
    }
    gs_face_shape_model *sp;
    gs_face_detector *det;
    double t0 = now();
    if (gs_face_shape_model_load(NULL, &sp, &err)) {
        fprintf(stderr, "%s\n", err.msg);
        return 1;
    }
    double t_parse = now() - t0;
    if (gs_face_detector_load(NULL, &det, &err)) {
        fprintf(stderr, "%s\n", err.msg);
        return 1;
    }
    gs_face_detection d[16];
    int n = 0;
    t0 = now();
    for (int i = 0; i < 5; i++)
        gs_face_detect(det, &img, NULL, d, 16, &n, &err);
    double t_detect = (now() - t0) / 5;
    if (n < 1) {
        fprintf(stderr, "no face in %s\n", argv[1]);
        return 1;
    }
    int pts[136];
    t0 = now();
    double c0 = clock_s(CLOCK_THREAD_CPUTIME_ID);
    for (int i = 0; i < reps; i++)
        gs_face_shape_predict(sp, &img, d[i % (n < 16 ? n : 16)].box, pts, NULL, &err);
    double t_pred = (now() - t0) / reps;
    double c_pred = (clock_s(CLOCK_THREAD_CPUTIME_ID) - c0) / reps;
    gs_face_result r;
    t0 = now();
    for (int i = 0; i < 5; i++)
        gs_face_analyze(det, sp, &img, NULL, &r, &err);
    double t_all = (now() - t0) / 5;
    gs_io_image norm;
    t0 = now();
    for (int i = 0; i < 20; i++) {
        gs_face_normalize_image(&img, &r.norm, &norm, &err);
        gs_io_image_free(&norm);
    }
    double t_norm = (now() - t0) / 20;
    printf("photo %dx%d, %d faces\n", img.width, img.height, n);
    printf("model parse        %8.1f ms\n", 1e3 * t_parse);
    printf("detect             %8.2f ms\n", 1e3 * t_detect);
    printf("landmarks per face %8.3f ms wall, %.3f ms CPU (%d runs)\n", 1e3 * t_pred,
           1e3 * c_pred, reps);
    printf("analyze            %8.2f ms (detect + landmarks + pose + normalization)\n",
           1e3 * t_all);
    printf("normalize 512^2    %8.2f ms\n", 1e3 * t_norm);
    gs_face_detector_destroy(det);
    gs_face_shape_model_destroy(sp);
    gs_io_image_free(&img);
    return 0;
}
