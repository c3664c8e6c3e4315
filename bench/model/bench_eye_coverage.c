/* Where the eye stream shows, in the merged map and at the image's size:
 * the groundwork for drawing the eyeball at the image's resolution.
 *
 *   bench_eye_coverage --model FILE [--count N] [--images DIR]
 *                      [--head-range Y,P]
 *
 * For the first N (default 20) samples of the model's own training stream
 * (its training identities, seed 1, the default head range or the one of
 * --head-range, as `train --head-range`), each rendered
 * from the identity's learned code and the sample's true expression, lights,
 * head pose and gaze (gs_model_training_subject: what a training step sees),
 * the merged streams are rasterized once more with one channel that is 1
 * on the eye stream and 0 on the face stream: each pixel's share of eyeball
 * (beta), both at the feature map's size (as the renderer reads it) and at
 * the image's (a camera of the same view, image / feature size times finer).
 * Printed, as means over the samples:
 *   - beta over the visible eyeball (the generator's eye masks): how much
 *     of what should be eyeball the eye stream covers;
 *   - beta over the skin ring around it (pixels within 6 image pixels of
 *     an eye mask, outside it): how much eyeball shows through the lids;
 *   - the eye Gaussians' size (largest axis, in image pixels at their
 *     depth) and opacity, medians;
 *   - the eye masks' PSNR of the renderer's image, and of a direct
 *     composite at the image's size, image (1 - beta) + E (the model's
 *     own image when config.eye_direct is set), E the eye stream's own
 *     colour (its Gaussians' first three feature channels) composited in
 *     the same pass: what the eye stream's Gaussians draw without the
 *     renderer.
 * --images DIR writes, for the first 4 samples, the eye band of the target,
 * the model's image, the direct composite and beta at the image's size as
 * DIR/N_{target,model,direct,beta}.ppm. */
#define _POSIX_C_SOURCE 200809L
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "frame.h"
#include "gazesplat/raster.h"
#include "gazesplat/synth.h"
#include "gazesplat/train.h"
#include "model_internal.h"

enum { RING_PX = 6 };

static void die(const char *what, const gs_error *e)
{
    fprintf(stderr, "bench_eye_coverage: %s: %s\n", what, e ? e->msg : "failed");
    exit(1);
}

/* Rows 70..139, columns 40..215 of a 256-px image (scaled for others). */
static int cmp_float(const void *a, const void *b)
{
    float x = *(const float *)a, y = *(const float *)b;
    return (x > y) - (x < y);
}

/* The median of v[n] (sorted in place). */
static double median(float *v, int n)
{
    qsort(v, (size_t)n, sizeof *v, cmp_float);
    return n % 2 ? v[n / 2] : 0.5 * ((double)v[n / 2 - 1] + v[n / 2]);
}

static void write_band(const char *dir, int idx, const char *name,
                       const float *img, int S, int grey)
{
    char path[4200];
    snprintf(path, sizeof path, "%s/%d_%s.ppm", dir, idx, name);
    FILE *f = fopen(path, "wb");
    if (!f) {
        fprintf(stderr, "bench_eye_coverage: cannot write %s\n", path);
        return;
    }
    int x0 = 40 * S / 256, y0 = 70 * S / 256, w = 176 * S / 256, h = 70 * S / 256;
    size_t plane = (size_t)S * S;
    fprintf(f, "P6 %d %d 255\n", w, h);
    for (int y = y0; y < y0 + h; y++)
        for (int x = x0; x < x0 + w; x++)
            for (int k = 0; k < 3; k++) {
                float v = img[(grey ? 0 : (size_t)k * plane) + (size_t)y * S + x];
                v = v < 0 ? 0 : v > 1 ? 1 : v;
                fputc((int)lrintf(v * 255.0f), f);
            }
    fclose(f);
}

int main(int argc, char **argv)
{
    const char *path = NULL, *images = NULL;
    int count = 20;
    double hy = 0, hp = 0; /* 0: the trainer's default */
    for (int i = 1; i < argc; i++) {
        if (!strcmp(argv[i], "--model") && i + 1 < argc)
            path = argv[++i];
        else if (!strcmp(argv[i], "--count") && i + 1 < argc)
            count = atoi(argv[++i]);
        else if (!strcmp(argv[i], "--images") && i + 1 < argc)
            images = argv[++i];
        else if (!strcmp(argv[i], "--head-range") && i + 1 < argc) {
            char tail;
            if (sscanf(argv[++i], "%lf,%lf%c", &hy, &hp, &tail) != 2 ||
                hy == 0 || hp == 0 || gs_train_check_head_range(hy, hp, NULL)) {
                fprintf(stderr, "bench_eye_coverage: --head-range '%s': want "
                                "YAW,PITCH degrees within 1..60 and 1..40\n",
                        argv[i]);
                return 2;
            }
        } else {
            fprintf(stderr, "usage: bench_eye_coverage --model FILE [--count N] "
                            "[--images DIR] [--head-range Y,P]\n");
            return 2;
        }
    }
    if (!path || count < 1) {
        fprintf(stderr, "bench_eye_coverage: --model FILE and --count >= 1\n");
        return 2;
    }
    gs_error err = {0, ""};
    gs_model *m = NULL;
    if (gs_model_load(path, &m, &err))
        die(path, &err);
    if (!m->cfg.two_stream || m->cfg.n_train_ids < 1)
        die(path, &(gs_error){GS_ERR_ARG, "needs two streams and training codes"});
    int S = m->cfg.image_size, fs = m->cfg.feat_size, C = m->cfg.channels;
    size_t plane = (size_t)S * S;

    /* the trainer's sample stream, seed 1, its head range */
    gs_train_options topt;
    gs_train_options_default(&topt);
    topt.head_yaw_deg = hy, topt.head_pitch_deg = hp;
    gs_synth_gen_config gen;
    gs_train_sample_config(m, &topt, &gen);
    gs_synth_sample smp;
    if (gs_synth_sample_alloc(&smp, S, S, &err))
        die("sample", &err);

    gs_model_ctx *c = gs_model_ctx_create(m);
    gs_raster *r = gs_raster_create();
    float *out4 = malloc(4 * plane * sizeof *out4), *alpha = malloc(plane * sizeof *alpha);
    float *bg4 = calloc(4 * plane, sizeof *bg4), *direct = malloc(3 * plane * sizeof *direct);
    float *target = malloc(3 * plane * sizeof *target);
    uint8_t *eye = malloc(plane), *ring = malloc(plane);
    float *feat4 = NULL;
    if (!c || !r || !out4 || !alpha || !bg4 || !direct || !target || !eye || !ring)
        die("memory", NULL);
    /* [size: map, image][eyeball, ring]: beta weighted by mask area */
    double bsum[2][2] = {{0, 0}, {0, 0}}, wsum[2][2] = {{0, 0}, {0, 0}};
    double se_model = 0, se_direct = 0, n_eye = 0;
    /* the eye Gaussians as rendered: sigma (largest axis) in image pixels
     * at their depth, and opacity; means over samples of their medians */
    double sig_px = 0, opac = 0;
    float *tmp = NULL;
    for (int idx = 0; idx < count; idx++) {
        gs_synth_scene scene;
        gs_synth_camera scam;
        if (gs_synth_gen_scene(&gen, (uint64_t)idx, &scene, &scam, &err) ||
            gs_synth_gen_sample(&gen, (uint64_t)idx, NULL, &smp, &err))
            die("sample", &err);
        int k = -1;
        for (int j = 0; j < m->cfg.n_train_ids && k < 0; j++)
            if (gs_synth_split_seed(GS_SYNTH_TRAIN, (uint64_t)j) == smp.labels.identity.seed)
                k = j;
        gs_subject sub;
        if (gs_model_training_subject(m, k, &scene, &smp.labels, &sub, &err))
            die("subject", &err);
        gs_frame fr;
        memset(&fr, 0, sizeof fr);
        memcpy(fr.code, sub.code, sizeof(float) * (size_t)sub.code_dim);
        memcpy(fr.head_R, sub.head_R, sizeof fr.head_R);
        memcpy(fr.head_t, sub.head_t, sizeof fr.head_t);
        fr.gaze[0] = sub.gaze_pitch;
        fr.gaze[1] = sub.gaze_yaw;
        if (gs_frame_forward(c, NULL, &fr, GS_STREAM_BOTH, 1, &err))
            die("forward", &err);

        {
            int ne = c->n - c->nf;
            gs_camera cam;
            gs_frame_camera(m, fr.head_t, &cam);
            double up = (double)S / fs;
            if (!tmp && !(tmp = malloc(2 * (size_t)ne * sizeof *tmp)))
                die("memory", NULL);
            for (int i = 0; i < ne; i++) {
                const float *ls = c->g_scale + 3 * (size_t)(c->nf + i);
                float l = ls[0] > ls[1] ? ls[0] : ls[1];
                l = l > ls[2] ? l : ls[2];
                tmp[i] = (float)(up * cam.fx * exp(l) / c->g_mean[3 * (size_t)(c->nf + i) + 2]);
                tmp[ne + i] = 1.0f / (1.0f + expf(-c->g_opac[c->nf + i]));
            }
            sig_px += median(tmp, ne);
            opac += median(tmp + ne, ne);
        }
        /* masks at the image's size: eyeball, and the skin ring around it */
        const uint8_t *le = gs_synth_sample_mask(&smp, GS_SYNTH_MASK_LEFT_EYE);
        const uint8_t *re = gs_synth_sample_mask(&smp, GS_SYNTH_MASK_RIGHT_EYE);
        for (size_t i = 0; i < plane; i++)
            eye[i] = (le[i] | re[i]) != 0;
        for (int y = 0; y < S; y++)
            for (int x = 0; x < S; x++) {
                int near = 0;
                for (int dy = -RING_PX; dy <= RING_PX && !near; dy++)
                    for (int dx = -RING_PX; dx <= RING_PX && !near; dx++) {
                        int yy = y + dy, xx = x + dx;
                        near = yy >= 0 && yy < S && xx >= 0 && xx < S &&
                               eye[(size_t)yy * S + xx];
                    }
                ring[(size_t)y * S + x] = near && !eye[(size_t)y * S + x];
            }

        /* one pass per size: the eye stream's colour (premultiplied by
         * nothing: the rasterizer composites it) and its indicator */
        if (!feat4 && !(feat4 = malloc((size_t)c->n * 4 * sizeof *feat4)))
            die("memory", NULL);
        for (int i = 0; i < c->n; i++) {
            float ind = i >= c->nf ? 1.0f : 0.0f;
            for (int q = 0; q < 3; q++)
                feat4[4 * i + q] = ind * c->g_feat[(size_t)i * C + q];
            feat4[4 * i + 3] = ind;
        }
        gs_gaussians g = {.n = c->n, .channels = 4, .means = c->g_mean,
                          .log_scales = c->g_scale, .quats = c->g_quat,
                          .opacity_logits = c->g_opac, .features = feat4};
        gs_raster_options ro = {.antialiased = 0, .path = GS_RASTER_FAST};
        for (int size = 0; size < 2; size++) {
            int n = size ? S : fs, f = S / n;
            gs_camera cam;
            gs_frame_camera(m, fr.head_t, &cam);
            float s = (float)n / (float)fs;
            cam.fx *= s, cam.fy *= s;
            cam.cx *= s, cam.cy *= s;
            cam.width = cam.height = n;
            if (gs_raster_forward(r, NULL, &cam, &g, bg4, &ro, out4, alpha, NULL, &err))
                die("raster", &err);
            const float *beta = out4 + 3 * (size_t)n * n;
            for (int y = 0; y < n; y++)
                for (int x = 0; x < n; x++) {
                    double we = 0, wr = 0; /* shares of the pixel's area */
                    for (int yy = y * f; yy < (y + 1) * f; yy++)
                        for (int xx = x * f; xx < (x + 1) * f; xx++) {
                            we += eye[(size_t)yy * S + xx];
                            wr += ring[(size_t)yy * S + xx];
                        }
                    double b = beta[(size_t)y * n + x];
                    bsum[size][0] += we * b;
                    wsum[size][0] += we;
                    bsum[size][1] += wr * b;
                    wsum[size][1] += wr;
                }
        }
        /* out4 holds the image-size pass: the direct composite over the
         * renderer's image (for an eye_direct model, the model's image) */
        const float *rend = c->eye_direct ? c->rgb_main : c->rgb;
        for (size_t i = 0; i < plane; i++) {
            float b = out4[3 * plane + i];
            b = b < 0 ? 0 : b > 1 ? 1 : b;
            for (int q = 0; q < 3; q++) {
                size_t j = (size_t)q * plane + i;
                direct[j] = rend[j] * (1 - b) + out4[j];
                target[j] = smp.rgb[(i / (size_t)S) * smp.stride + 3 * (i % (size_t)S) + (size_t)q] /
                            255.0f;
                if (eye[i]) {
                    double d0 = rend[j] - target[j], d1 = direct[j] - target[j];
                    se_model += d0 * d0;
                    se_direct += d1 * d1;
                    n_eye += 1;
                }
            }
        }
        if (images && idx < 4) {
            write_band(images, idx, "target", target, S, 0);
            write_band(images, idx, "model", rend, S, 0);
            write_band(images, idx, "direct", direct, S, 0);
            write_band(images, idx, "beta", out4 + 3 * plane, S, 1);
        }
    }
    if (hy > 0)
        printf("%s, %d training samples (seed 1, head range %g,%g):\n", path,
               count, hy, hp);
    else
        printf("%s, %d training samples (seed 1, the default head range):\n",
               path, count);
    printf("| eye stream's share (beta) | at %d px (the map) | at %d px (the image) |\n",
           fs, S);
    printf("|---|---:|---:|\n");
    printf("| visible eyeball (eye masks) | %.3f | %.3f |\n",
           bsum[0][0] / wsum[0][0], bsum[1][0] / wsum[1][0]);
    printf("| skin within %d px of it | %.3f | %.3f |\n", RING_PX,
           bsum[0][1] / wsum[0][1], bsum[1][1] / wsum[1][1]);
    printf("eye Gaussians: sigma %.2g px at %d px (%.2g px at %d px, where the "
           "rasterizer's dilation alone is %.2f px), opacity %.2f (medians)\n",
           sig_px / count, S, sig_px / count * fs / S, fs, sqrt(GS_RASTER_EPS2D),
           opac / count);
    printf("eye masks' PSNR: the renderer's image %.2f dB, the direct composite "
           "at %d px %.2f dB (%s)\n",
           10 * log10(n_eye / se_model), S, 10 * log10(n_eye / se_direct),
           m->cfg.eye_direct ? "the model's image: config.eye_direct"
                             : "the model's image is the renderer's");
    free(feat4);
    free(tmp);
    free(out4), free(alpha), free(bg4), free(direct), free(target), free(eye), free(ring);
    gs_raster_destroy(r);
    gs_model_ctx_destroy(c);
    gs_synth_sample_free(&smp);
    gs_model_destroy(m);
    return 0;
}
