/* What detail transfer costs against the plain render it builds on, on one
 * thread: gs_model_render_transfer against gs_model_render for the same
 * targets of one subject.
 *
 *   bench_transfer [--model FILE] [--reps N]
 *
 * The input is the subject's own view with seeded noise added (any image
 * works: the residual is input minus own view). Each rep, rows
 * interleaved: a gaze change of the same subject (plain: incremental;
 * transfer: incremental plus its maps, the own view kept), and a head
 * change with a fresh head offset (full renders; transfer also renders its
 * depth and coverage maps). Prints a Markdown table of medians with each
 * transfer row's ratio to its plain row. Without --model, a cpu-preset
 * model as initialised (the timing does not depend on training). */
#define _POSIX_C_SOURCE 200809L
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "../bench_util.h"
#include "bench_model.h"
#include "gazesplat/geom.h"
#include "gazesplat/nn.h"

enum { MAX_REPS = 200, ROWS = 4 };

static void die(const char *what, const gs_error *e)
{
    fprintf(stderr, "bench_transfer: %s: %s\n", what, e ? e->msg : "failed");
    exit(1);
}

int main(int argc, char **argv)
{
    const char *path = NULL;
    int reps = 21;
    for (int i = 1; i < argc; i++) {
        if (!strcmp(argv[i], "--model") && i + 1 < argc)
            path = argv[++i];
        else if (!strcmp(argv[i], "--reps") && i + 1 < argc)
            reps = atoi(argv[++i]);
        else {
            fprintf(stderr, "usage: bench_transfer [--model FILE] [--reps N]\n");
            return 2;
        }
    }
    if (reps < 1 || reps > MAX_REPS)
        die("--reps: want 1..200", NULL);
    gs_nn_blas_set_threads(1);
    gs_error err = {0, ""};
    gs_model *m = NULL;
    if (bench_model_open(path, &m, &err))
        die(path ? path : "model", &err);
    gs_model_info info;
    gs_model_get_info(m, &info);
    int S = info.image_size;
    size_t isz = 3 * (size_t)S * S, st = 3 * (size_t)S;
    uint8_t *in = malloc(isz), *out = malloc(isz);
    gs_subject sub;
    bench_subject(&info, 0.05, -0.15, &sub);
    gs_model_ctx *cp = gs_model_ctx_create(m), *cx = gs_model_ctx_create(m);
    if (!cp || !cx || !in || !out)
        die("context", NULL);
    gs_view own = {0};
    if (gs_model_render(cp, NULL, &sub, &own, in, st, &err))
        die("render", &err);
    uint64_t s = 99;
    for (size_t i = 0; i < isz; i++) {
        s = s * 6364136223846793005ULL + 1442695040888963407ULL;
        int v = in[i] + (int)(s >> 60) - 8;
        in[i] = (uint8_t)(v < 0 ? 0 : v > 255 ? 255 : v);
    }
    static double t[ROWS][MAX_REPS];
    const char *names[ROWS] = {"gaze change: plain (incremental)", "gaze change: transfer",
                               "head change: plain (full)", "head change: transfer"};
    for (int r = 0; r < reps; r++) {
        gs_view v = {0};
        v.gaze_pitch = 0.1 * (r % 3) - 0.1;
        v.gaze_yaw = 0.15;
        for (int k = 0; k < 2; k++) {
            double t0 = now_ms();
            int rc = k ? gs_model_render_transfer(cx, NULL, &sub, in, st, &v, out, st, &err)
                       : gs_model_render(cp, NULL, &sub, &v, out, st, &err);
            if (rc)
                die("gaze change", &err);
            t[k][r] = now_ms() - t0;
        }
        gs_view h = v;
        h.use_head = 1;
        gs_geom_rot_from_pitchyaw(0.05, -0.15 + 0.01 * (r + 1), 0.0, h.head_R);
        memcpy(h.head_t, sub.head_t, sizeof h.head_t);
        for (int k = 0; k < 2; k++) {
            double t0 = now_ms();
            int rc = k ? gs_model_render_transfer(cx, NULL, &sub, in, st, &h, out, st, &err)
                       : gs_model_render(cp, NULL, &sub, &h, out, st, &err);
            if (rc)
                die("head change", &err);
            t[2 + k][r] = now_ms() - t0;
        }
    }
    double med[ROWS];
    for (int i = 0; i < ROWS; i++)
        med[i] = median(t[i], reps);
    printf("model: %s (%d px, %d face + %d eye Gaussians); %d reps, 1 thread\n\n",
           path ? path : "cpu preset as initialised", S, info.n_face, info.n_eye, reps);
    printf("| render | median ms | transfer / plain |\n|---|---:|---:|\n");
    for (int i = 0; i < ROWS; i++)
        if (i % 2)
            printf("| %s | %.2f | %.2f× |\n", names[i], med[i], med[i] / med[i - 1]);
        else
            printf("| %s | %.2f | |\n", names[i], med[i]);
    gs_model_ctx_destroy(cp);
    gs_model_ctx_destroy(cx);
    gs_model_destroy(m);
    free(in);
    free(out);
    return 0;
}
