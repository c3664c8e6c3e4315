/* What detail transfer costs against the plain render it builds on:
 * gs_model_render_transfer against gs_model_render for the same targets of
 * one subject.
 *
 *   bench_transfer [--model FILE] [--reps N] [--threads N]
 *
 * The input is the subject's own view with seeded noise added (any image
 * works: the residual is input minus own view). Each rep, rows interleaved,
 * each row on its own context:
 *   gaze change, plain: the incremental render;
 *   gaze change, transfer, incremental: the last target had the same head
 *     pose, so its maps and warp are redone over the eyes' reach only;
 *   gaze change, transfer, full: the same target with the kept one dropped
 *     first (the path before incremental transfers);
 *   head change (a fresh head offset each rep): full renders, and transfer
 *     with its maps of every Gaussian;
 *   gaze change, transfer, incremental, with the eyeball warp off
 *     (transfer_eye_warp_deg 0): what the warp costs a sweep's image;
 *   a subject's first gaze change (the context reset first), with the
 *     warp and without: the own view, and with the warp its eye opening's
 *     probe renders, once per subject.
 * Prints a Markdown table of medians with each row's ratio to the plain
 * render of its kind, the full gaze change's to the incremental one and
 * the share of the image the incremental one redid.
 * --threads N (default 1) gives every call a gs_pool of N threads. Without
 * --model, a cpu-preset model as initialised (the timing does not depend
 * on training). */
#define _POSIX_C_SOURCE 200809L
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "../bench_util.h"
#include "bench_model.h"
#include "frame.h"
#include "gazesplat/geom.h"
#include "gazesplat/nn.h"
#include "gazesplat/pool.h"

enum { MAX_REPS = 200, ROWS = 8 };

static void die(const char *what, const gs_error *e)
{
    fprintf(stderr, "bench_transfer: %s: %s\n", what, e ? e->msg : "failed");
    exit(1);
}

int main(int argc, char **argv)
{
    const char *path = NULL;
    int reps = 21, nthreads = 1;
    for (int i = 1; i < argc; i++) {
        if (!strcmp(argv[i], "--model") && i + 1 < argc)
            path = argv[++i];
        else if (!strcmp(argv[i], "--reps") && i + 1 < argc)
            reps = atoi(argv[++i]);
        else if (!strcmp(argv[i], "--threads") && i + 1 < argc)
            nthreads = atoi(argv[++i]);
        else {
            fprintf(stderr, "usage: bench_transfer [--model FILE] [--reps N] "
                            "[--threads N]\n");
            return 2;
        }
    }
    if (reps < 1 || reps > MAX_REPS)
        die("--reps: want 1..200", NULL);
    if (nthreads < 1 || nthreads > 64)
        die("--threads: want 1..64", NULL);
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
    gs_pool *pool = nthreads > 1 ? gs_pool_create(nthreads) : NULL;
    gs_model_ctx *ctx[ROWS];
    int fail = !in || !out || (nthreads > 1 && !pool);
    for (int k = 0; k < ROWS; k++)
        fail |= !(ctx[k] = gs_model_ctx_create(m));
    if (fail)
        die("context", NULL);
    gs_model_render_options nowarp;
    gs_model_render_options_default(&nowarp);
    nowarp.transfer_eye_warp_deg = 0.0;
    if (gs_model_ctx_set_render_options(ctx[5], &nowarp, &err) ||
        gs_model_ctx_set_render_options(ctx[7], &nowarp, &err))
        die("render options", &err);
    gs_view own = {0};
    if (gs_model_render(ctx[0], pool, &sub, &own, in, st, &err))
        die("render", &err);
    uint64_t s = 99;
    for (size_t i = 0; i < isz; i++) {
        s = s * 6364136223846793005ULL + 1442695040888963407ULL;
        int v = in[i] + (int)(s >> 60) - 8;
        in[i] = (uint8_t)(v < 0 ? 0 : v > 255 ? 255 : v);
    }
    static double t[ROWS][MAX_REPS];
    const char *names[ROWS] = {"gaze change: plain (incremental)",
                               "gaze change: transfer, incremental",
                               "gaze change: transfer, full maps",
                               "head change: plain (full)", "head change: transfer",
                               "gaze change: transfer, incremental, warp off",
                               "first gaze change of a subject: transfer",
                               "first gaze change of a subject: transfer, warp off"};
    const int plain[ROWS] = {1, 0, 0, 1, 0, 0, 0, 0};
    const int base[ROWS] = {0, 0, 0, 3, 3, 0, 7, 7};
    const int head[ROWS] = {0, 0, 0, 1, 1, 0, 0, 0};
    for (int r = -1; r < reps; r++) { /* rep -1 warms up, untimed */
        gs_view v = {0};
        v.gaze_pitch = 0.1 * ((r + 3) % 3) - 0.1;
        v.gaze_yaw = 0.15;
        gs_view h = v;
        h.use_head = 1;
        gs_geom_rot_from_pitchyaw(0.05, -0.15 + 0.01 * (r + 2), 0.0, h.head_R);
        memcpy(h.head_t, sub.head_t, sizeof h.head_t);
        gs_xfer_forget_target(ctx[2]->xfer);
        gs_model_ctx_reset(ctx[6]);
        gs_model_ctx_reset(ctx[7]);
        for (int k = 0; k < ROWS; k++) {
            const gs_view *vk = head[k] ? &h : &v;
            double t0 = now_ms();
            int rc = plain[k] ? gs_model_render(ctx[k], pool, &sub, vk, out, st, &err)
                              : gs_model_render_transfer(ctx[k], pool, &sub, in, st, vk,
                                                         out, st, &err);
            if (rc)
                die(names[k], &err);
            if (r >= 0)
                t[k][r] = now_ms() - t0;
        }
    }
    gs_model_ctx_stats cs;
    gs_model_ctx_get_stats(ctx[1], &cs);
    if (cs.transfers_incremental != (uint64_t)reps)
        die("the incremental row did not take the incremental path", NULL);
    double med[ROWS];
    for (int i = 0; i < ROWS; i++)
        med[i] = median(t[i], reps);
    printf("model: %s (%d px, %d face + %d eye Gaussians); %d reps, %d thread%s\n\n",
           path ? path : "cpu preset as initialised", S, info.n_face, info.n_eye, reps,
           nthreads, nthreads > 1 ? "s" : "");
    printf("| render | median ms | images/s | / plain |\n|---|---:|---:|---:|\n");
    for (int i = 0; i < ROWS; i++) {
        printf("| %s | %.2f | %.1f |", names[i], med[i], 1000.0 / med[i]);
        if (plain[i] || base[i] == i) /* a row the others are measured by */
            printf(" |\n");
        else
            printf(" %.2f× |\n", med[i] / med[base[i]]);
    }
    printf("\nthe eyeball warp: %.2f× a sweep's incremental transfer without it; its eye "
           "opening %.1f ms once per subject\n",
           med[1] / med[5], med[6] - med[7]);
    printf("\ngaze change, transfer: full / incremental %.2f×; the eyes' box %.1f %% of "
           "the image\n",
           med[2] / med[1], 100.0 * ctx[1]->xfer_px / ((double)S * S * (double)reps));
    for (int k = 0; k < ROWS; k++)
        gs_model_ctx_destroy(ctx[k]);
    gs_pool_destroy(pool);
    gs_model_destroy(m);
    free(in);
    free(out);
    return 0;
}
