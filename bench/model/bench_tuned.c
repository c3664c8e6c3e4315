/* What serving fine-tuned subjects costs: switching a clone of the model
 * between two subjects' tuned blocks (gs_model_tuned_apply plus
 * gs_model_ctx_reset) against the renders around it, on one thread.
 *
 *   bench_tuned [--model FILE] [--reps N] [--steps N] [--parts LIST]
 *
 * Two subjects (head poses apart) are rendered by the shared model, then
 * each gets a real block: a clone fine-tuned for --steps (default 2) on
 * that render (gs_model_finetune, default parts "face"). Each rep, rows
 * interleaved: a switch to the other subject's block; the first render
 * after it (full: the switch drops the context's kept renders); a gaze
 * change of the same subject (incremental); a full render of a plain
 * subject by the shared model with a fresh head offset (what a request
 * costs with nothing tuned). Prints a Markdown table of medians over reps with
 * each row's share of the plain full render, the block size and the time
 * to encode a block and to compute a parameter id (gs_model_param_id, paid
 * once per model load). Without --model, a cpu-preset model as
 * initialised (the timing does not depend on training). */
#define _POSIX_C_SOURCE 200809L
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "../../lib/model/model_internal.h" /* gs_model_param_id */
#include "../bench_util.h"
#include "bench_model.h"
#include "gazesplat/geom.h"
#include "gazesplat/model.h"
#include "gazesplat/nn.h"
#include "gazesplat/train.h"

#define PI 3.14159265358979323846
enum { MAX_REPS = 200, ROWS = 4 };

static void die(const char *what, const gs_error *e)
{
    fprintf(stderr, "bench_tuned: %s: %s\n", what, e ? e->msg : "failed");
    exit(1);
}

int main(int argc, char **argv)
{
    const char *path = NULL, *parts_s = "face";
    int reps = 21, steps = 2;
    for (int i = 1; i < argc; i++) {
        if (!strcmp(argv[i], "--model") && i + 1 < argc)
            path = argv[++i];
        else if (!strcmp(argv[i], "--reps") && i + 1 < argc)
            reps = atoi(argv[++i]);
        else if (!strcmp(argv[i], "--steps") && i + 1 < argc)
            steps = atoi(argv[++i]);
        else if (!strcmp(argv[i], "--parts") && i + 1 < argc)
            parts_s = argv[++i];
        else {
            fprintf(stderr, "usage: bench_tuned [--model FILE] [--reps N] [--steps N] "
                            "[--parts LIST]\n");
            return 2;
        }
    }
    reps = reps < 1 ? 1 : reps > MAX_REPS ? MAX_REPS : reps;
    steps = steps < 1 ? 1 : steps;
    gs_nn_blas_select_kernels(argv);
    gs_nn_blas_set_threads(1);
    gs_error err = {0, ""};
    unsigned parts = 0;
    if (gs_finetune_parts_parse(parts_s, &parts, &err))
        die("--parts", &err);
    gs_model *m = NULL;
    double t0 = now_ms();
    if (bench_model_open(path, &m, &err))
        die(path ? path : "model", &err);
    double load_ms = now_ms() - t0;
    gs_model_info info;
    gs_model_get_info(m, &info);
    int S = info.image_size;
    size_t isz = 3 * (size_t)S * S;
    uint8_t *img = malloc(isz);
    gs_subject sub[2];
    bench_subject(&info, 0.05, -0.15, &sub[0]);
    bench_subject(&info, 0.05, 0.2, &sub[1]);

    /* Real blocks: each subject's clone fine-tuned on its own render. */
    uint8_t *blk[2];
    size_t len[2];
    double encode_ms = 0;
    gs_model_ctx *base_ctx = gs_model_ctx_create(m);
    for (int k = 0; k < 2; k++) {
        gs_view v = {0};
        if (gs_model_render(base_ctx, NULL, &sub[k], &v, img, 3 * (size_t)S, &err))
            die("render", &err);
        gs_model *t = NULL;
        if (gs_model_clone(m, &t, &err))
            die("clone", &err);
        gs_finetune_options fo;
        gs_finetune_options_default(&fo);
        fo.iters = steps;
        fo.parts = parts;
        fo.lr = 5e-3; /* a visible change in a few steps */
        if (gs_model_finetune(t, NULL, &sub[k], img, 3 * (size_t)S, &fo, NULL, &err))
            die("finetune", &err);
        t0 = now_ms();
        if (gs_model_tuned_encode(t, &blk[k], &len[k], &err))
            die("encode", &err);
        encode_ms += (now_ms() - t0) / 2;
        gs_model_destroy(t);
    }
    t0 = now_ms();
    volatile uint64_t id = gs_model_param_id(m);
    double id_ms = now_ms() - t0;
    (void)id;

    gs_model *srv = NULL;
    if (gs_model_clone(m, &srv, &err))
        die("clone", &err);
    gs_model_ctx *sc = gs_model_ctx_create(srv);
    if (!sc || !base_ctx)
        die("context", NULL);
    gs_model_ctx_set_sweep_cache(sc, 1, NULL);
    static double t[ROWS][MAX_REPS];
    const char *names[ROWS] = {"switch to the other subject's block (apply + reset)",
                               "first render after the switch (full)",
                               "gaze change, same subject (incremental)",
                               "plain subject, full render (shared model)"};
    int cur = -1;
    for (int r = 0; r < reps; r++) {
        int k = (cur + 1) % 2;
        t0 = now_ms();
        if (gs_model_tuned_apply(srv, m, blk[k], len[k], &err))
            die("apply", &err);
        gs_model_ctx_reset(sc);
        t[0][r] = now_ms() - t0;
        cur = k;
        gs_view v = {0};
        v.gaze_yaw = 0.1 * (r % 3);
        t0 = now_ms();
        if (gs_model_render(sc, NULL, &sub[k], &v, img, 3 * (size_t)S, &err))
            die("render", &err);
        t[1][r] = now_ms() - t0;
        v.gaze_pitch = 0.15;
        t0 = now_ms();
        if (gs_model_render(sc, NULL, &sub[k], &v, img, 3 * (size_t)S, &err))
            die("render", &err);
        t[2][r] = now_ms() - t0;
        gs_subject p = sub[k];
        p.head_t[0] = 0.01 * (r + 1); /* a new head offset: nothing reused */
        t0 = now_ms();
        if (gs_model_render(base_ctx, NULL, &p, &v, img, 3 * (size_t)S, &err))
            die("render", &err);
        t[3][r] = now_ms() - t0;
    }
    double med[ROWS];
    for (int i = 0; i < ROWS; i++)
        med[i] = median(t[i], reps);
    char pn[64];
    printf("model: %s (%d px, %d face + %d eye Gaussians, %.1f MB of parameters, loaded in %.0f ms)\n",
           path ? path : "cpu preset as initialised", S, info.n_face, info.n_eye,
           (double)info.param_bytes / 1e6, load_ms);
    printf("block: parts %s, %zu bytes; encode %.2f ms; parameter id %.2f ms; %d reps, 1 thread\n\n",
           gs_finetune_parts_name(parts, pn, sizeof pn), len[0], encode_ms, id_ms, reps);
    printf("| step | median ms | of a plain full render |\n|---|---:|---:|\n");
    for (int i = 0; i < ROWS; i++)
        printf("| %s | %.3f | %.1f %% |\n", names[i], med[i], 100.0 * med[i] / med[3]);
    gs_model_ctx_destroy(sc);
    gs_model_ctx_destroy(base_ctx);
    gs_model_destroy(srv);
    gs_model_destroy(m);
    free(blk[0]);
    free(blk[1]);
    free(img);
    return 0;
}
