/* safetensors throughput: a model-like file (F32 tensors of varied sizes,
 * plus small U8 and I64 ones) written and read in memory and through a file
 * (page cache warm), MB/s of the median rep. The first row, a plain malloc
 * + memcpy of the same bytes, is the bound that open_mem (one copy plus the
 * checks) can approach; compare ratios when the machine is busy.
 *
 *   bench_safetensors [--mb N] [--reps N] [--dir D]
 *
 * Prints a Markdown table; experiments/bench/README.md records its output. */
#define _POSIX_C_SOURCE 200809L
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "gazesplat/safetensors.h"

static double now(void)
{
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return (double)t.tv_sec + 1e-9 * (double)t.tv_nsec;
}

static int cmp_double(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

/* About mb MiB in 3 tensors per layer: weight, bias, a 3-byte mask. */
static gs_st_writer *make_model(int mb, int *ntensors)
{
    gs_st_writer *w = gs_st_writer_create();
    size_t budget = (size_t)mb << 20, used = 0;
    float *buf = malloc(((size_t)1 << 20) * sizeof *buf);
    uint8_t mask[3] = {1, 2, 3};
    char name[64];
    int layer = 0;
    for (size_t i = 0; i < ((size_t)1 << 20); i++)
        buf[i] = (float)(i % 1000) * 0.001f;
    *ntensors = 0;
    while (used < budget) {
        int64_t rows = 64 + (layer * 37) % 448, cols = 256, bias = rows, m = 3;
        snprintf(name, sizeof name, "layers.%d.weight", layer);
        gs_st_writer_add(w, name, GS_ST_F32, 2, (int64_t[]){rows, cols}, buf);
        snprintf(name, sizeof name, "layers.%d.bias", layer);
        gs_st_writer_add(w, name, GS_ST_F32, 1, &bias, buf);
        snprintf(name, sizeof name, "layers.%d.mask", layer);
        gs_st_writer_add(w, name, GS_ST_U8, 1, &m, mask);
        used += (size_t)(rows * cols + rows) * 4 + 3;
        layer++;
        *ntensors += 3;
    }
    gs_st_writer_meta(w, "format", "bench");
    free(buf);
    return w;
}

int main(int argc, char **argv)
{
    int mb = 64, reps = 5, nt;
    const char *dir = ".";
    for (int i = 1; i + 1 < argc; i += 2) {
        if (!strcmp(argv[i], "--mb"))
            mb = atoi(argv[i + 1]);
        else if (!strcmp(argv[i], "--reps"))
            reps = atoi(argv[i + 1]);
        else if (!strcmp(argv[i], "--dir"))
            dir = argv[i + 1];
    }
    if (mb < 1 || reps < 1 || reps > 64) {
        fprintf(stderr, "usage: %s [--mb N] [--reps 1..64] [--dir D]\n", argv[0]);
        return 2;
    }
    char path[4096];
    snprintf(path, sizeof path, "%s/bench_st.safetensors", dir);
    gs_st_writer *w = make_model(mb, &nt);
    double t[5][64];
    size_t len = 0;
    gs_error err = {0, ""};
    for (int r = 0; r < reps; r++) {
        uint8_t *buf;
        gs_st_file *f;
        double t0 = now();
        if (gs_st_writer_to_mem(w, &buf, &len, &err))
            goto fail;
        double t1 = now();
        if (gs_st_open_mem(buf, len, NULL, &f, &err))
            goto fail;
        double t2 = now();
        gs_st_close(f);
        free(buf);
        double t3 = now();
        if (gs_st_writer_save(w, path, &err))
            goto fail;
        double t4 = now();
        if (gs_st_open(path, NULL, &f, &err))
            goto fail;
        double t5 = now();
        gs_st_close(f);
        double t6 = now();
        void *copy = malloc(len);
        if (!copy || !(buf = malloc(len)))
            return 1;
        memset(buf, 1, len);
        t6 = now();
        memcpy(copy, buf, len);
        double t7 = now();
        free(copy);
        free(buf);
        t[0][r] = t7 - t6;
        t[1][r] = t1 - t0, t[2][r] = t2 - t1, t[3][r] = t4 - t3, t[4][r] = t5 - t4;
    }
    remove(path);
    gs_st_writer_destroy(w);
    const char *what[5] = {"malloc + memcpy (bound)", "writer_to_mem", "open_mem",
                           "writer_save (fsync)", "open (file)"};
    printf("%.1f MiB, %d tensors, median of %d reps\n\n| call | ms | MB/s |\n|---|---|---|\n",
           (double)len / (1 << 20), nt, reps);
    for (int k = 0; k < 5; k++) {
        qsort(t[k], (size_t)reps, sizeof(double), cmp_double);
        double s = t[k][reps / 2];
        printf("| %s | %.1f | %.0f |\n", what[k], 1e3 * s, (double)len / 1e6 / s);
    }
    return 0;
fail:
    fprintf(stderr, "bench_safetensors: %s\n", err.msg);
    return 1;
}
