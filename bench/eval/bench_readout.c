/* How well does the synthesis readout (gs_eval_gaze_readout) read gaze?
 * On ground-truth targets of the committed test pairing (256 px, white
 * outside the head, open eyes), each reading is compared with the truth:
 *
 *   exact       the target itself (the floor)
 *   shift 1 px  moved right by one pixel (edge repeated)
 *   shift 3 px  moved right 2, down 2 (beyond a pixel: the alignment)
 *   shift 5, 4  moved right 5, down 4: beyond the alignment's default 4
 *               px, then with --readout-shift's largest, 8 px
 *   blur 0.7    Gaussian blur, sigma 0.7 px
 *   jpeg 90     saved as JPEG, quality 90, and decoded
 *   noise 3     pixel noise, sigma 3 levels (a fixed hash)
 *   turn 2      the same scene rendered with its gaze turned by 2 degrees
 *               (a direction per target): read against that gaze, and the
 *               angle read between the two images against 2
 *
 * The same changes as bench/eval/estimator_sensitivity.py applies to the
 * learned estimator, so the two instruments can be set side by side.
 *
 *   bench_readout [--count N] [--threads N]
 *
 * Prints a Markdown table (mean, median, largest error in degrees) and the
 * mean time of a reading; bench/eval/README.md records its output. */
#define _POSIX_C_SOURCE 200809L
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "../bench_util.h"
#include "gazesplat/eval.h"
#include "gazesplat/image_io.h"
#include "gazesplat/pool.h"

#define S 256
#define DEG (3.14159265358979323846 / 180.0)

enum { V_EXACT, V_SHIFT1, V_SHIFT3, V_SHIFT54, V_SHIFT54_8, V_BLUR, V_JPEG,
       V_NOISE, V_TURN, V_TURN_DELTA, V_COUNT };
static const char *const vname[V_COUNT] = {
    "exact (the floor)", "shift 1 px", "shift (2, 2) px",
    "shift (5, 4) px, alignment up to 4 px (the default)",
    "shift (5, 4) px, alignment up to 8 px", "blur σ 0.7 px",
    "JPEG quality 90", "noise σ 3 levels", "gaze turned 2°: error",
    "gaze turned 2°: |angle read − 2°|"};

static void shift(const uint8_t *in, uint8_t *out, int dx, int dy)
{
    for (int y = 0; y < S; y++)
        for (int x = 0; x < S; x++) {
            int sx = x - dx < 0 ? 0 : x - dx, sy = y - dy < 0 ? 0 : y - dy;
            memcpy(out + 3 * ((size_t)y * S + x),
                   in + 3 * ((size_t)sy * S + sx), 3);
        }
}

/* One pass of a 7-tap kernel k along x (dx 1) or y (dx 0), edges
 * clamped. */
static void blur_pass(const float *in, float *out, const float k[7], int dx)
{
    for (int y = 0; y < S; y++)
        for (int x = 0; x < S; x++)
            for (int c = 0; c < 3; c++) {
                float a = 0;
                for (int d = -3; d <= 3; d++) {
                    int q = (dx ? x : y) + d;
                    q = q < 0 ? 0 : q >= S ? S - 1 : q;
                    a += k[d + 3] * in[3 * (dx ? (size_t)y * S + q
                                               : (size_t)q * S + x) + c];
                }
                out[3 * ((size_t)y * S + x) + c] = a;
            }
}

static void blur(const uint8_t *in, uint8_t *out, double sigma)
{
    float k[7], ks = 0;
    for (int d = -3; d <= 3; d++)
        ks += k[d + 3] = (float)exp(-0.5 * d * d / (sigma * sigma));
    for (int d = 0; d < 7; d++)
        k[d] /= ks;
    float *a = malloc(sizeof *a * 6 * S * S);
    if (!a)
        exit(1);
    float *b = a + 3 * S * S;
    for (size_t i = 0; i < 3 * (size_t)S * S; i++)
        a[i] = in[i];
    blur_pass(a, b, k, 1);
    blur_pass(b, a, k, 0);
    for (size_t i = 0; i < 3 * (size_t)S * S; i++)
        out[i] = (uint8_t)(a[i] < 0 ? 0 : a[i] > 255 ? 255 : a[i] + 0.5f);
    free(a);
}

static int jpeg(const uint8_t *in, uint8_t *out)
{
    gs_io_image img = {S, S, 3 * S, (unsigned char *)in}, dec = {0};
    void *buf = NULL;
    size_t len = 0;
    gs_error err = {0, ""};
    int rc = gs_io_image_encode(&img, GS_IO_JPEG, 90, &buf, &len, &err);
    if (!rc)
        rc = gs_io_image_decode(buf, len, NULL, &dec, &err);
    free(buf);
    if (rc || dec.width != S || dec.height != S) {
        fprintf(stderr, "bench_readout: jpeg: %s\n", err.msg);
        gs_io_image_free(&dec);
        return 1;
    }
    for (int y = 0; y < S; y++)
        memcpy(out + (size_t)y * 3 * S, dec.data + (size_t)y * dec.stride,
               3 * S);
    gs_io_image_free(&dec);
    return 0;
}

static void noise(const uint8_t *in, uint8_t *out, double sigma)
{
    uint64_t h = 0x9e3779b97f4a7c15ULL;
    for (size_t i = 0; i < 3 * (size_t)S * S; i++) {
        /* sum of 4 uniforms: near-Gaussian, variance 4/12 per unit */
        double u = 0;
        for (int k = 0; k < 4; k++) {
            h ^= h >> 31;
            h *= 0xbf58476d1ce4e5b9ULL;
            h ^= h >> 29;
            u += (double)(h >> 11) / 9007199254740992.0 - 0.5;
        }
        double v = in[i] + sigma * u * sqrt(3.0);
        out[i] = (uint8_t)(v < 0 ? 0 : v > 255 ? 255 : v + 0.5);
    }
}

static int render(const gs_synth_scene *sc, gs_pool *pool, uint8_t *out)
{
    gs_synth_sample s = {0};
    gs_error err = {0, ""};
    if (gs_eval_render_scene(sc, S, 0, 0, pool, &s, &err)) {
        fprintf(stderr, "bench_readout: %s\n", err.msg);
        return 1;
    }
    for (int y = 0; y < S; y++)
        memcpy(out + (size_t)y * 3 * S, s.rgb + (size_t)y * s.stride, 3 * S);
    gs_synth_sample_free(&s);
    return 0;
}

int main(int argc, char **argv)
{
    int count = 24, threads = 2;
    for (int i = 1; i < argc; i++) {
        if (!strcmp(argv[i], "--count") && i + 1 < argc)
            count = atoi(argv[++i]);
        else if (!strcmp(argv[i], "--threads") && i + 1 < argc)
            threads = atoi(argv[++i]);
        else {
            fprintf(stderr, "usage: bench_readout [--count N] [--threads N]\n");
            return 2;
        }
    }
    if (count < 1 || count > 1000 || threads < 1 || threads > 64) {
        fprintf(stderr, "bench_readout: --count 1..1000, --threads 1..64\n");
        return 2;
    }
    gs_pool *pool = gs_pool_create(threads);
    gs_eval_pairs_spec spec;
    gs_eval_pairs_spec_default(&spec);
    gs_eval_pairs ps;
    gs_error err = {0, ""};
    uint8_t *gt = malloc(3 * S * S), *img = malloc(3 * S * S);
    double *errs = malloc(sizeof *errs * V_COUNT * (size_t)count);
    if (!pool || !gt || !img || !errs || gs_eval_pairs_make(&spec, &ps, &err)) {
        fprintf(stderr, "bench_readout: %s\n", err.msg[0] ? err.msg : "setup");
        return 1;
    }
    double ms = 0, ms8 = 0;
    int reads = 0, n = 0;
    long renders = 0, renders8 = 0;
    /* Every 7th pair's target (spread over identities and inputs), open
     * eyes only. */
    for (int i = 0; n < count && i < ps.n * 7; i += 7) {
        gs_synth_scene in, sc;
        gs_eval_pair_scenes(&ps.p[i % ps.n], &in, &sc);
        if (gs_eval_expr_narrowed(&sc.expr))
            continue;
        if (render(&sc, pool, gt))
            return 1;
        for (int v = 0; v < V_TURN_DELTA; v++) {
            gs_synth_scene truth = sc;
            switch (v) {
            case V_EXACT: memcpy(img, gt, 3 * S * S); break;
            case V_SHIFT1: shift(gt, img, 1, 0); break;
            case V_SHIFT3: shift(gt, img, 2, 2); break;
            case V_SHIFT54:
            case V_SHIFT54_8: shift(gt, img, 5, 4); break;
            case V_BLUR: blur(gt, img, 0.7); break;
            case V_JPEG:
                if (jpeg(gt, img))
                    return 1;
                break;
            case V_NOISE: noise(gt, img, 3.0); break;
            case V_TURN: {
                double a = 2.39996 * n; /* golden angle: spread directions */
                truth.gaze_pitch += 2 * DEG * sin(a);
                truth.gaze_yaw += 2 * DEG * cos(a) / cos(sc.gaze_pitch);
                if (render(&truth, pool, img))
                    return 1;
                break;
            }
            }
            gs_eval_readout rd;
            gs_eval_readout_options ro;
            gs_eval_readout_options_default(&ro);
            if (v == V_SHIFT54_8)
                ro.max_shift_px = 8;
            double t0 = now_ms();
            /* The readout is given the scene (the target's), never the
             * truth of the image it reads. */
            if (gs_eval_gaze_readout(&sc, S, 0, 0, img, 3 * S, &ro, pool,
                                     &rd, &err)) {
                fprintf(stderr, "bench_readout: %s\n", err.msg);
                return 1;
            }
            if (v == V_SHIFT54_8) { /* timed apart: a wider search */
                ms8 += now_ms() - t0;
                renders8 += rd.renders;
            } else {
                ms += now_ms() - t0;
                reads++;
                renders += rd.renders;
            }
            errs[v * count + n] = gs_eval_angle_deg(
                rd.pitch, rd.yaw, truth.gaze_pitch, truth.gaze_yaw);
            if (v == V_TURN) {
                double moved = gs_eval_angle_deg(truth.gaze_pitch,
                                                 truth.gaze_yaw,
                                                 sc.gaze_pitch, sc.gaze_yaw);
                double read = gs_eval_angle_deg(rd.pitch, rd.yaw,
                                                sc.gaze_pitch, sc.gaze_yaw);
                errs[V_TURN_DELTA * count + n] = fabs(read - moved);
            }
        }
        n++;
    }
    printf("Synthesis readout on %d open-eyed ground-truth targets of the "
           "test pairing, 256 px, %d threads: degrees against the true "
           "gaze\n\n| image | mean | median | largest |\n|---|---:|---:|---:|\n",
           n, threads);
    for (int v = 0; v < V_COUNT; v++) {
        double *e = errs + (size_t)v * count, sum = 0, mx = 0;
        for (int k = 0; k < n; k++) {
            sum += e[k];
            mx = e[k] > mx ? e[k] : mx;
        }
        printf("| %s | %.2f | %.2f | %.2f |\n", vname[v], sum / n,
               median(e, n), mx);
    }
    printf("\nmean %.0f ms and %.0f renders per reading (%d readings at the "
           "default alignment); %.0f ms and %.0f renders with alignment up "
           "to 8 px\n",
           ms / reads, (double)renders / reads, reads, ms8 / n,
           (double)renders8 / n);
    free(gt);
    free(img);
    free(errs);
    gs_eval_pairs_free(&ps);
    gs_pool_destroy(pool);
    return 0;
}
