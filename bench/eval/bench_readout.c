/* How well does the synthesis readout (gs_eval_gaze_readout) read gaze?
 * On ground-truth targets of the committed test pairing (256 px, white
 * outside the head, open eyes), each reading is compared with the truth:
 *
 *   exact       the target itself (the floor)
 *   shift 1 px  moved right by one pixel (edge repeated)
 *   shift 3 px  moved right 2, down 2 (beyond a pixel: the alignment)
 *   shift 5, 4  moved right 5, down 4: beyond the alignment's default 4
 *               px, then with --readout-shift's largest, 8 px
 *   blur 0.7    Gaussian blur, sigma 0.7 px; then 1, 1.5 and 2 px, the
 *               softness of a model's eye region
 *   64 px       averaged over 4 x 4 blocks to 64 x 64 and scaled back up
 *               bilinearly: what a 64-pixel RGB map can carry
 *   jpeg 90     saved as JPEG, quality 90, and decoded
 *   noise 3     pixel noise, sigma 3 levels (a fixed hash)
 *   turn 2      the same scene rendered with its gaze turned by 2 degrees
 *               (a direction per target): read against that gaze, and the
 *               angle read between the two images against 2; then the
 *               same blurred by sigma 1.5 px
 *
 * The same changes as experiments/eval/estimator_sensitivity.py applies to the
 * learned estimator, so the two instruments can be set side by side.
 *
 *   bench_readout [--count N] [--threads N] [--soft PX]
 *
 * --soft sets the readout's soft_max_px (the image softness it tries).
 *
 * Prints a Markdown table (mean, median, largest error in degrees) and the
 * mean time of a reading; experiments/eval/README.md records its output. */
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

enum { V_EXACT, V_SHIFT1, V_SHIFT3, V_SHIFT54, V_SHIFT54_8, V_BLUR, V_BLUR10,
       V_BLUR15, V_BLUR20, V_DOWN4, V_JPEG, V_NOISE, V_TURN, V_TURN_DELTA,
       V_TURNB, V_TURNB_DELTA, V_COUNT };
static const char *const vname[V_COUNT] = {
    "exact (the floor)", "shift 1 px", "shift (2, 2) px",
    "shift (5, 4) px, alignment up to 4 px (the default)",
    "shift (5, 4) px, alignment up to 8 px", "blur σ 0.7 px",
    "blur σ 1 px", "blur σ 1.5 px", "blur σ 2 px",
    "down to 64 px (4 × 4 mean) and up again (bilinear)",
    "JPEG quality 90", "noise σ 3 levels", "gaze turned 2°: error",
    "gaze turned 2°: |angle read − 2°|",
    "gaze turned 2°, blur σ 1.5 px: error",
    "gaze turned 2°, blur σ 1.5 px: |angle read − 2°|"};

static void shift(const uint8_t *in, uint8_t *out, int dx, int dy)
{
    for (int y = 0; y < S; y++)
        for (int x = 0; x < S; x++) {
            int sx = x - dx < 0 ? 0 : x - dx, sy = y - dy < 0 ? 0 : y - dy;
            memcpy(out + 3 * ((size_t)y * S + x),
                   in + 3 * ((size_t)sy * S + sx), 3);
        }
}

#define KR 6 /* the blur kernel's radius: 3 sigma at the largest, 2 px */

/* One pass of a (2 KR + 1)-tap kernel k along x (dx 1) or y (dx 0), edges
 * clamped. */
static void blur_pass(const float *in, float *out, const float *k, int dx)
{
    for (int y = 0; y < S; y++)
        for (int x = 0; x < S; x++)
            for (int c = 0; c < 3; c++) {
                float a = 0;
                for (int d = -KR; d <= KR; d++) {
                    int q = (dx ? x : y) + d;
                    q = q < 0 ? 0 : q >= S ? S - 1 : q;
                    a += k[d + KR] * in[3 * (dx ? (size_t)y * S + q
                                                : (size_t)q * S + x) + c];
                }
                out[3 * ((size_t)y * S + x) + c] = a;
            }
}

static void blur(const uint8_t *in, uint8_t *out, double sigma)
{
    float k[2 * KR + 1], ks = 0;
    for (int d = -KR; d <= KR; d++)
        ks += k[d + KR] = (float)exp(-0.5 * d * d / (sigma * sigma));
    for (int d = 0; d < 2 * KR + 1; d++)
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

/* 4 x 4 block means (a 64 x 64 image), then bilinear back to 256 px with
 * pixel centres aligned (edges clamped). */
static void down_up(const uint8_t *in, uint8_t *out)
{
    enum { F = 4, L = S / F };
    float lo[3 * L * L];
    for (int y = 0; y < L; y++)
        for (int x = 0; x < L; x++)
            for (int c = 0; c < 3; c++) {
                float a = 0;
                for (int j = 0; j < F; j++)
                    for (int i = 0; i < F; i++)
                        a += in[3 * ((size_t)(F * y + j) * S + F * x + i) + c];
                lo[3 * (y * L + x) + c] = a / (F * F);
            }
    for (int y = 0; y < S; y++) {
        float fy = (y + 0.5f) / F - 0.5f;
        int y0 = (int)floorf(fy);
        float wy = fy - y0;
        int ya = y0 < 0 ? 0 : y0, yb = y0 + 1 >= L ? L - 1 : y0 + 1;
        for (int x = 0; x < S; x++) {
            float fx = (x + 0.5f) / F - 0.5f;
            int x0 = (int)floorf(fx);
            float wx = fx - x0;
            int xa = x0 < 0 ? 0 : x0, xb = x0 + 1 >= L ? L - 1 : x0 + 1;
            for (int c = 0; c < 3; c++) {
                float v = (1 - wy) * ((1 - wx) * lo[3 * (ya * L + xa) + c] +
                                      wx * lo[3 * (ya * L + xb) + c]) +
                          wy * ((1 - wx) * lo[3 * (yb * L + xa) + c] +
                                wx * lo[3 * (yb * L + xb) + c]);
                out[3 * ((size_t)y * S + x) + c] =
                    (uint8_t)(v < 0 ? 0 : v > 255 ? 255 : v + 0.5f);
            }
        }
    }
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
    double soft = 0;
    for (int i = 1; i < argc; i++) {
        if (!strcmp(argv[i], "--count") && i + 1 < argc)
            count = atoi(argv[++i]);
        else if (!strcmp(argv[i], "--threads") && i + 1 < argc)
            threads = atoi(argv[++i]);
        else if (!strcmp(argv[i], "--soft") && i + 1 < argc)
            soft = atof(argv[++i]);
        else {
            fprintf(stderr, "usage: bench_readout [--count N] [--threads N] [--soft PX]\n");
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
    uint8_t *gt2 = malloc(3 * S * S);
    double *errs = malloc(sizeof *errs * V_COUNT * (size_t)count);
    if (!pool || !gt || !img || !gt2 || !errs || gs_eval_pairs_make(&spec, &ps, &err)) {
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
        for (int v = 0; v < V_COUNT; v++) {
            if (v == V_TURN_DELTA || v == V_TURNB_DELTA)
                continue;
            gs_synth_scene truth = sc;
            switch (v) {
            case V_EXACT: memcpy(img, gt, 3 * S * S); break;
            case V_SHIFT1: shift(gt, img, 1, 0); break;
            case V_SHIFT3: shift(gt, img, 2, 2); break;
            case V_SHIFT54:
            case V_SHIFT54_8: shift(gt, img, 5, 4); break;
            case V_BLUR: blur(gt, img, 0.7); break;
            case V_BLUR10: blur(gt, img, 1.0); break;
            case V_BLUR15: blur(gt, img, 1.5); break;
            case V_BLUR20: blur(gt, img, 2.0); break;
            case V_DOWN4: down_up(gt, img); break;
            case V_JPEG:
                if (jpeg(gt, img))
                    return 1;
                break;
            case V_NOISE: noise(gt, img, 3.0); break;
            case V_TURN:
            case V_TURNB: {
                double a = 2.39996 * n; /* golden angle: spread directions */
                truth.gaze_pitch += 2 * DEG * sin(a);
                truth.gaze_yaw += 2 * DEG * cos(a) / cos(sc.gaze_pitch);
                if (render(&truth, pool, img))
                    return 1;
                if (v == V_TURNB) {
                    memcpy(gt2, img, 3 * S * S);
                    blur(gt2, img, 1.5);
                }
                break;
            }
            }
            gs_eval_readout rd;
            gs_eval_readout_options ro;
            gs_eval_readout_options_default(&ro);
            ro.soft_max_px = soft;
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
            if (v == V_TURN || v == V_TURNB) {
                double moved = gs_eval_angle_deg(truth.gaze_pitch,
                                                 truth.gaze_yaw,
                                                 sc.gaze_pitch, sc.gaze_yaw);
                double read = gs_eval_angle_deg(rd.pitch, rd.yaw,
                                                sc.gaze_pitch, sc.gaze_yaw);
                errs[(v + 1) * count + n] = fabs(read - moved);
            }
        }
        n++;
    }
    printf("Synthesis readout on %d open-eyed ground-truth targets of the "
           "test pairing, 256 px, %d threads, softness tried up to %.2f px: "
           "degrees against the true gaze\n\n| image | mean | median | "
           "largest |\n|---|---:|---:|---:|\n",
           n, threads, soft);
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
    free(gt2);
    free(errs);
    gs_eval_pairs_free(&ps);
    gs_pool_destroy(pool);
    return 0;
}
