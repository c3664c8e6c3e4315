/* Synthetic-head renderer benchmark: images per second of the on-the-fly
 * generator (normalized face images, training split, default ranges, one
 * sample per pixel) at 128^2 and 512^2 with 1 and 2 threads.
 *
 *   bench_synth [--quick] [--reps N]
 *
 * Each configuration renders the same sequence of generator indices; a rep
 * is one pass over the sequence, and the table reports the median rep.
 * Configurations run interleaved rep by rep so machine load hits them
 * alike. Prints a Markdown table; experiments/bench/README.md records its output. */
#define _POSIX_C_SOURCE 200809L
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "gazesplat/synth.h"

typedef struct config {
    int size, threads, images;
    double wall[64], cpu[64];
} config;

static double now(clockid_t c)
{
    struct timespec t;
    clock_gettime(c, &t);
    return (double)t.tv_sec + 1e-9 * (double)t.tv_nsec;
}

static int cmp_double(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

static double median(const double *v, int n)
{
    double s[64];
    memcpy(s, v, (size_t)n * sizeof *s);
    qsort(s, (size_t)n, sizeof *s, cmp_double);
    return n % 2 ? s[n / 2] : 0.5 * (s[n / 2 - 1] + s[n / 2]);
}

/* One rep: renders images 0..n-1. Returns 0 or a gs_status. */
static int run(config *c, gs_pool *pool, gs_synth_sample *s, int rep)
{
    gs_synth_gen_config g;
    gs_synth_gen_config_default(&g);
    g.size = c->size;
    double w0 = now(CLOCK_MONOTONIC), c0 = now(CLOCK_PROCESS_CPUTIME_ID);
    for (int i = 0; i < c->images; i++) {
        gs_error err;
        int rc = gs_synth_gen_sample(&g, (uint64_t)i, pool, s, &err);
        if (rc != GS_OK) {
            fprintf(stderr, "bench_synth: %s\n", err.msg);
            return rc;
        }
    }
    c->wall[rep] = now(CLOCK_MONOTONIC) - w0;
    c->cpu[rep] = now(CLOCK_PROCESS_CPUTIME_ID) - c0;
    return 0;
}

int main(int argc, char **argv)
{
    int reps = 5, quick = 0;
    for (int i = 1; i < argc; i++) {
        if (strcmp(argv[i], "--quick") == 0)
            quick = 1;
        else if (strcmp(argv[i], "--reps") == 0 && i + 1 < argc)
            reps = atoi(argv[++i]);
        else {
            fprintf(stderr, "usage: bench_synth [--quick] [--reps N]\n");
            return 2;
        }
    }
    if (reps < 1 || reps > 64)
        reps = 5;
    if (quick)
        reps = 1;
    config cs[4] = {{128, 1, quick ? 20 : 200, {0}, {0}},
                    {128, 2, quick ? 20 : 200, {0}, {0}},
                    {512, 1, quick ? 2 : 16, {0}, {0}},
                    {512, 2, quick ? 2 : 16, {0}, {0}}};
    gs_pool *pools[3] = {NULL, NULL, gs_pool_create(2)};
    gs_synth_sample s128, s512;
    if (!pools[2] || gs_synth_sample_alloc(&s128, 128, 128, NULL) != GS_OK ||
        gs_synth_sample_alloc(&s512, 512, 512, NULL) != GS_OK) {
        fprintf(stderr, "bench_synth: out of memory\n");
        return 1;
    }
    for (int rep = 0; rep < reps; rep++)
        for (int k = 0; k < 4; k++)
            if (run(&cs[k], pools[cs[k].threads], cs[k].size == 128 ? &s128 : &s512, rep))
                return 1;
    printf("| size | threads | images/rep | images/s | ms/image | CPU ms/image |\n"
           "|---|---|---|---|---|---|\n");
    for (int k = 0; k < 4; k++) {
        double w = median(cs[k].wall, reps), c = median(cs[k].cpu, reps);
        printf("| %d² | %d | %d | %.1f | %.2f | %.2f |\n", cs[k].size, cs[k].threads,
               cs[k].images, cs[k].images / w, 1000.0 * w / cs[k].images,
               1000.0 * c / cs[k].images);
    }
    gs_synth_sample_free(&s128);
    gs_synth_sample_free(&s512);
    gs_pool_destroy(pools[2]);
    return 0;
}
