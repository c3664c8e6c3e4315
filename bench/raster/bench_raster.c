/* Rasterizer benchmark: forward and backward milliseconds of the fast path
 * (1 and 2 threads) against the plain scalar single-thread path, in one run,
 * on a seeded head-like scene: Gaussians on the surface of an ellipsoid head
 * with two eyeballs, 32 feature channels, camera framing the head.
 *
 *   bench_raster [--quick] [--reps N] [--fast-only] [--size 128|512]
 *
 * --fast-only skips the scalar path (no speed-up columns: quicker runs while
 * tuning); --size keeps one of the two scenes.
 * Prints a Markdown table; experiments/bench/README.md records its output. Times are
 * medians over reps; ratios compare paths measured side by side. */
#define _POSIX_C_SOURCE 200809L
#define GS_PI 3.14159265358979323846
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "../bench_util.h"
#include "gazesplat/raster.h"

typedef struct {
    int n, C;
    float *means, *log_scales, *quats, *opac, *feat;
} scene;

static uint64_t rng_state;
static double urand(void)
{
    rng_state = rng_state * 6364136223846793005ULL + 1442695040888963407ULL;
    return (double)(rng_state >> 11) * (1.0 / 9007199254740992.0);
}

/* Quaternion (wxyz) rotating +z onto unit normal nrm. */
static void quat_from_z(const double nrm[3], float q[4])
{
    double w = 1.0 + nrm[2], x = -nrm[1], y = nrm[0];
    double len = sqrt(w * w + x * x + y * y);
    if (len < 1e-9) {
        q[0] = 0, q[1] = 1, q[2] = 0, q[3] = 0;
        return;
    }
    q[0] = (float)(w / len), q[1] = (float)(x / len), q[2] = (float)(y / len), q[3] = 0;
}

/* Head: ellipsoid of radii (75, 100, 90) mm at the origin; eyes: spheres of
 * 12 mm at (+-32, -20, -72). Camera looks down +z from z = -distance. */
static void make_scene(scene *s, int n, int C, double spacing_scale)
{
    s->n = n, s->C = C;
    s->means = malloc(sizeof(float) * 3 * n);
    s->log_scales = malloc(sizeof(float) * 3 * n);
    s->quats = malloc(sizeof(float) * 4 * n);
    s->opac = malloc(sizeof(float) * n);
    s->feat = malloc(sizeof(float) * n * C);
    rng_state = 12345;
    int n_eye = n / 20;
    double area_head = 4 * GS_PI * 88 * 88, area_eye = 4 * GS_PI * 12 * 12;
    for (int i = 0; i < n; i++) {
        int eye = i < n_eye ? 1 + (i & 1) : 0;
        double u = urand() * 2 - 1, phi = urand() * 2 * GS_PI, r = sqrt(1 - u * u);
        double d[3] = {r * cos(phi), r * sin(phi), u}, p[3], nrm[3], spacing;
        if (eye) {
            double c[3] = {eye == 1 ? -32 : 32, -20, -72};
            for (int k = 0; k < 3; k++)
                p[k] = c[k] + 12 * d[k], nrm[k] = d[k];
            spacing = sqrt(area_eye / (n_eye / 2));
        } else {
            double R[3] = {75, 100, 90};
            double g[3];
            for (int k = 0; k < 3; k++)
                p[k] = R[k] * d[k], g[k] = d[k] / R[k];
            double gl = sqrt(g[0] * g[0] + g[1] * g[1] + g[2] * g[2]);
            for (int k = 0; k < 3; k++)
                nrm[k] = g[k] / gl;
            spacing = sqrt(area_head / (n - n_eye));
        }
        for (int k = 0; k < 3; k++)
            s->means[3 * i + k] = (float)p[k];
        double t = spacing * spacing_scale * (0.7 + 0.6 * urand());
        s->log_scales[3 * i + 0] = (float)log(t);
        s->log_scales[3 * i + 1] = (float)log(t * (0.6 + 0.4 * urand()));
        s->log_scales[3 * i + 2] = (float)log(eye ? t : 0.15 * t);
        quat_from_z(nrm, s->quats + 4 * i);
        s->opac[i] = (float)(0.5 + 3.0 * urand());
        for (int c = 0; c < C; c++)
            s->feat[(size_t)i * C + c] = (float)urand();
    }
}

/* One configuration under test: a path and a thread count with its own
 * workspace and buffers. */
typedef struct {
    gs_raster_path path;
    const char *isa; /* fast path's instruction set */
    int threads;
    gs_raster *r;
    gs_pool *pool;
    float *F, *A, *grad;
    double *tf, *tb;
    double *ph[4]; /* per rep: projection, sort, binning, compositing ms */
    gs_raster_stats st;
} config;

typedef struct {
    gs_camera cam;
    gs_gaussians g;
    float *vF;
    size_t HW, C, n;
} problem;

static void problem_init(problem *pb, const scene *s, int size)
{
    memset(pb, 0, sizeof *pb);
    pb->cam.width = pb->cam.height = size;
    pb->cam.fx = pb->cam.fy = (float)(size * 2.4);
    pb->cam.cx = pb->cam.cy = (float)(size * 0.5);
    float V[12] = {1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 600};
    memcpy(pb->cam.viewmat, V, sizeof V);
    gs_gaussians g = {s->n, s->C, s->means, s->log_scales, s->quats, s->opac, s->feat};
    pb->g = g;
    pb->HW = (size_t)size * size, pb->C = (size_t)s->C, pb->n = (size_t)s->n;
    pb->vF = malloc(sizeof(float) * pb->C * pb->HW);
    for (size_t i = 0; i < pb->C * pb->HW; i++)
        pb->vF[i] = (float)(i % 7) * 0.01f - 0.03f;
}

static int spin_us = -1; /* --spin: the pools' spin time; -1 keeps the default */
static int no_records;    /* --no-records: forwards keep no records (renders) */

static int config_init(config *c, const problem *pb, gs_raster_path path, const char *isa,
                       int threads, int reps)
{
    c->path = path;
    c->isa = isa;
    c->threads = threads;
    c->r = gs_raster_create();
    gs_error err;
    if (isa && gs_raster_set_isa(c->r, isa, &err)) {
        fprintf(stderr, "bench_raster: %s\n", err.msg);
        return 1;
    }
    if (no_records)
        gs_raster_set_records(c->r, 0); /* the backward evaluates again */
    c->pool = path == GS_RASTER_FAST ? gs_pool_create(threads) : NULL;
    if (c->pool && spin_us >= 0)
        gs_pool_set_spin_us(c->pool, spin_us);
    c->F = malloc(sizeof(float) * pb->C * pb->HW);
    c->A = malloc(sizeof(float) * pb->HW);
    c->grad = calloc(pb->n * (11 + pb->C), sizeof(float));
    c->tf = malloc(sizeof(double) * reps);
    c->tb = malloc(sizeof(double) * reps);
    for (int q = 0; q < 4; q++)
        c->ph[q] = malloc(sizeof(double) * reps);
    return 0;
}

static int config_rep(config *c, const problem *pb, int k)
{
    size_t n = pb->n;
    gs_gaussian_grads G = {c->grad, c->grad + 3 * n, c->grad + 6 * n, c->grad + 10 * n,
                           c->grad + 11 * n};
    gs_raster_options opt = {.antialiased = 0, .path = c->path};
    gs_error err;
    double t0 = now_ms();
    int rc = gs_raster_forward(c->r, c->pool, &pb->cam, &pb->g, NULL, &opt, c->F, c->A, NULL,
                               &err);
    double t1 = now_ms();
    if (!rc)
        rc = gs_raster_backward(c->r, c->pool, pb->vF, NULL, NULL, &G, NULL, &err);
    double t2 = now_ms();
    if (rc) {
        fprintf(stderr, "bench_raster: %s\n", err.msg);
        return rc;
    }
    gs_raster_get_stats(c->r, &c->st);
    if (k >= 0) {
        c->tf[k] = t1 - t0, c->tb[k] = t2 - t1;
        c->ph[0][k] = c->st.ms_project, c->ph[1][k] = c->st.ms_sort;
        c->ph[2][k] = c->st.ms_bin, c->ph[3][k] = c->st.ms_composite;
    }
    return 0;
}

static void config_free(config *c)
{
    gs_raster_destroy(c->r);
    gs_pool_destroy(c->pool);
    free(c->F), free(c->A), free(c->grad), free(c->tf), free(c->tb);
    for (int q = 0; q < 4; q++)
        free(c->ph[q]);
}

#define MAX_ISA 3
#define MAX_CONFIGS (1 + 2 * MAX_ISA)

int main(int argc, char **argv)
{
    int reps = 15, fast_only = 0, only_size = 0, n_isa = 0;
    const char *isa[MAX_ISA];
    char isa_list[64] = "";
    for (int i = 1; i < argc; i++) {
        if (!strcmp(argv[i], "--quick"))
            reps = 3;
        else if (!strcmp(argv[i], "--fast-only"))
            fast_only = 1;
        else if (!strcmp(argv[i], "--size") && i + 1 < argc)
            only_size = atoi(argv[++i]);
        else if (!strcmp(argv[i], "--reps") && i + 1 < argc)
            reps = atoi(argv[++i]);
        else if (!strcmp(argv[i], "--no-records"))
            no_records = 1;
        else if (!strcmp(argv[i], "--spin") && i + 1 < argc)
            spin_us = atoi(argv[++i]);
        else if (!strcmp(argv[i], "--isa") && i + 1 < argc && strlen(argv[i + 1]) < sizeof isa_list)
            strcpy(isa_list, argv[++i]);
        else {
            fprintf(stderr, "usage: bench_raster [--quick] [--reps N] [--fast-only] [--size 128|512]\n"
                            "                    [--isa avx512,avx2,generic] [--spin US] [--no-records]\n"
                            "  --isa: the fast path's instruction sets to compare, interleaved\n"
                            "         (default: avx512 and avx2, those this CPU runs)\n"
                            "  --spin: microseconds the pools spin between jobs (default %d)\n"
                            "  --no-records: the forward keeps no records for the backward (as\n"
                            "         renders do); the backward then evaluates the Gaussians again\n",
                    GS_POOL_DEFAULT_SPIN_US);
            return 2;
        }
    }
    if (reps < 1)
        reps = 1;
    if (isa_list[0]) {
        for (char *tok = strtok(isa_list, ","); tok; tok = strtok(NULL, ","))
            if (n_isa < MAX_ISA)
                isa[n_isa++] = tok;
    } else {
        static const char *const dflt[] = {"avx512", "avx2"};
        gs_raster *probe = gs_raster_create();
        for (int k = 0; k < 2; k++)
            if (!gs_raster_set_isa(probe, dflt[k], NULL))
                isa[n_isa++] = dflt[k];
        gs_raster_destroy(probe);
        if (!n_isa)
            isa[n_isa++] = "generic";
    }
    struct { int n, size; } cases[] = {{20000, 128}, {30000, 512}};
    printf("| Gaussians, size, C | path | threads | fwd ms | bwd ms | fwd speed-up | bwd speed-up | "
           "contributors/px | tile pairs |\n|---|---|---|---|---|---|---|---|---|\n");
    for (int c = 0; c < 2; c++) {
        if (only_size && only_size != cases[c].size)
            continue;
        scene s;
        make_scene(&s, cases[c].n, 32, cases[c].size == 128 ? 1.4 : 0.9);
        problem pb;
        problem_init(&pb, &s, cases[c].size);
        int nrep = cases[c].size > 128 && reps > 5 ? 5 : reps;
        config cf[MAX_CONFIGS];
        int ncf = 0;
        if (config_init(&cf[ncf++], &pb, GS_RASTER_SCALAR, NULL, 1, nrep))
            return 1;
        for (int k = 0; k < n_isa; k++)
            for (int t = 1; t <= 2; t++)
                if (config_init(&cf[ncf++], &pb, GS_RASTER_FAST, isa[k], t, nrep))
                    return 1;
        /* Interleaved: every rep runs each configuration once, so a change in
         * machine load hits all of them alike. k = -1 warms up. */
        int j0 = fast_only ? 1 : 0;
        for (int k = -1; k < nrep; k++)
            for (int j = j0; j < ncf; j++)
                if (config_rep(&cf[j], &pb, k))
                    return 1;
        double px = (double)cases[c].size * cases[c].size;
        double rf = fast_only ? NAN : median(cf[0].tf, nrep);
        double rb = fast_only ? NAN : median(cf[0].tb, nrep);
        for (int j = 0; j < ncf; j++) {
            if (j >= j0) {
                double f = median(cf[j].tf, nrep), b = median(cf[j].tb, nrep);
                char path[32];
                snprintf(path, sizeof path, "%s%s", j ? "fast " : "scalar", j ? cf[j].isa : "");
                printf("| %dk, %d², 32 | %s | %d | %.2f | %.2f | %.1f× | %.1f× | %.1f | %zu |\n",
                       cases[c].n / 1000, cases[c].size, path, cf[j].threads, f, b, rf / f,
                       rb / b, cf[j].st.contributions / px, cf[j].st.intersections);
            }
        }
        /* Where the forward's time goes: medians of each phase. */
        printf("\n| forward phases, %dk, %d² | path | threads | projection ms | sort ms | "
               "binning ms | compositing ms |\n|---|---|---|---|---|---|---|\n",
               cases[c].n / 1000, cases[c].size);
        for (int j = j0; j < ncf; j++)
            printf("| | %s%s | %d | %.2f | %.2f | %.2f | %.2f |\n", j ? "fast " : "scalar",
                   j ? cf[j].isa : "", cf[j].threads, median(cf[j].ph[0], nrep),
                   median(cf[j].ph[1], nrep), median(cf[j].ph[2], nrep),
                   median(cf[j].ph[3], nrep));
        printf("\n");
        for (int j = 0; j < ncf; j++)
            config_free(&cf[j]);
        free(pb.vF);
        free(s.means), free(s.log_scales), free(s.quats), free(s.opac), free(s.feat);
    }
    return 0;
}
