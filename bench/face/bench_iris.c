/* How well does the iris localizer (gs_face_iris_locate) find the iris
 * centre where the truth is exact? Synthetic heads of the test split,
 * scenes drawn as the evaluation draws them (gs_synth_scene_random with
 * gs_eval_ranges: head yaw +-50, pitch +-30, roll +-5 deg; gaze yaw +-40,
 * pitch +-30 deg; expressions half the time, blinks 10 %), rendered at the
 * normalized camera at 256 px (d_n 680 mm, f_n 800 px), the localizer fed
 * the label's own 6 contour points of each eye and the radius range of
 * the normalized scale (gs_face_iris_opts_scale, f_n / d_n). The truth is the label's
 * projected iris centre (pupil_uv: the iris disc's centre through K; the
 * cornea does not refract in lib/synth).
 *
 *   bench_iris [--count N] [--first K] [--auto] [--open-lids]
 *              [--supersample 2] [--val] [--verbose]
 *
 * --auto: the radius range from the eye width instead of the scale;
 * --open-lids: lids pulled back (open_lids render option) so no lid
 * covers the iris; --supersample 2: 2 x 2 samples per pixel (the
 * evaluation renders 1); --val: validation-split identities (where the
 * localizer's constants were chosen) instead of the test split;
 * --verbose: one line per eye. Eyes the face hides (less than half of the contour's
 * pixels on the rendered eyeball: the nose at large head yaw) are counted
 * apart. Prints Markdown tables: centre error (median, p95, max, px) and
 * how many eyes were flagged, by eye-in-head gaze angle, by head angle
 * (forward axis against the normalized camera's axis), for narrowed eyes
 * (squint >= 0.35 or blink >= 0.3) by how closed they are, and the radius
 * error. docs/face.md records its output. */
#define _POSIX_C_SOURCE 200809L
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "gazesplat/eval.h"
#include "gazesplat/face.h"
#include "gazesplat/synth.h"

#define S 256
#define DEG (3.14159265358979323846 / 180.0)
#define MAXE 8192

typedef struct stat {
    double e[MAXE];
    int n, flagged;
} stat;

static void add(stat *s, int ok, double err)
{
    if (!ok) {
        s->flagged++;
        return;
    }
    if (s->n < MAXE)
        s->e[s->n++] = err;
}

static int cmp(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

static double pct(const stat *s, double q)
{
    if (!s->n)
        return NAN;
    int i = (int)ceil(q * s->n) - 1;
    return s->e[i < 0 ? 0 : i >= s->n ? s->n - 1 : i];
}

static void row(const char *name, stat *s)
{
    qsort(s->e, (size_t)s->n, sizeof s->e[0], cmp);
    printf("| %s | %d | %d | %.2f | %.2f | %.2f |\n", name, s->n + s->flagged, s->flagged,
           pct(s, 0.5), pct(s, 0.95), s->n ? s->e[s->n - 1] : NAN);
}

static void header(const char *what)
{
    printf("\n| %s | eyes | flagged | median px | p95 px | max px |\n|---|---|---|---|---|---|\n",
           what);
}

/* Fraction of the contour's pixels on the rendered eyeball. */
static double contour_seen(const gs_synth_sample *s, int e)
{
    const double(*pg)[2] = (const double(*)[2])&s->labels.lm2d[36 + 6 * e];
    const uint8_t *m = gs_synth_sample_mask(s, e == GS_SYNTH_EYE_RIGHT ? GS_SYNTH_MASK_RIGHT_EYE
                                                                        : GS_SYNTH_MASK_LEFT_EYE);
    int in = 0, both = 0;
    for (int y = 0; y < s->height; y++)
        for (int x = 0; x < s->width; x++) {
            int inside = 0;
            double qx = x + 0.5, qy = y + 0.5;
            for (int a = 0, b = 5; a < 6; b = a++)
                if ((pg[a][1] > qy) != (pg[b][1] > qy) &&
                    qx < pg[a][0] + (qy - pg[a][1]) * (pg[b][0] - pg[a][0]) / (pg[b][1] - pg[a][1]))
                    inside = !inside;
            in += inside;
            both += inside && m[(size_t)y * s->width + x];
        }
    return in ? (double)both / in : 0;
}

int main(int argc, char **argv)
{
    int count = 300, autor = 0, open = 0, verbose = 0, ss = 1;
    gs_synth_split split = GS_SYNTH_TEST;
    uint64_t first = 0;
    for (int i = 1; i < argc; i++) {
        if (!strcmp(argv[i], "--count") && i + 1 < argc)
            count = atoi(argv[++i]);
        else if (!strcmp(argv[i], "--first") && i + 1 < argc)
            first = strtoull(argv[++i], NULL, 10);
        else if (!strcmp(argv[i], "--auto"))
            autor = 1;
        else if (!strcmp(argv[i], "--supersample") && i + 1 < argc)
            ss = atoi(argv[++i]) == 2 ? 2 : 1;
        else if (!strcmp(argv[i], "--val"))
            split = GS_SYNTH_VAL;
        else if (!strcmp(argv[i], "--verbose"))
            verbose = 1;
        else if (!strcmp(argv[i], "--open-lids"))
            open = 1;
        else {
            fprintf(stderr, "usage: bench_iris [--count N] [--first K] [--auto] [--open-lids] "
                            "[--supersample 2] [--val] [--verbose]\n");
            return 2;
        }
    }
    gs_synth_ranges rg;
    gs_eval_ranges(&rg);
    static stat gaze[3], head[3], narrow[3], all_open, hidden, radius;
    const char *bins[3] = {"0-15°", "15-30°", "30-50°"};
    gs_synth_sample smp;
    gs_error err;
    if (gs_synth_sample_alloc(&smp, S, S, &err)) {
        fprintf(stderr, "%s\n", err.msg);
        return 1;
    }
    gs_synth_render_opts ro = {.supersample = ss, .open_lids = open};
    for (int i = 0; i < count; i++) {
        uint64_t k = first + (uint64_t)i;
        gs_synth_scene sc;
        gs_synth_scene_random(gs_synth_split_seed(split, k % 100), 7000 + k, &rg, &sc);
        gs_synth_camera base, cam;
        gs_synth_camera_single(S, 600, 260, &base);
        if (gs_synth_camera_normalized(&sc, &base, S, 680, 800, &cam, &err) ||
            gs_synth_render(&sc, &cam, &ro, NULL, &smp, &err)) {
            fprintf(stderr, "scene %d: %s\n", i, err.msg);
            return 1;
        }
        const gs_synth_labels *l = &smp.labels;
        gs_io_image img = {S, S, smp.stride, smp.rgb};
        gs_face_iris_opts o;
        gs_face_iris_opts_default(&o);
        if (!autor)
            gs_face_iris_opts_scale(&o, l->norm.f_n / l->norm.d_n_mm);
        double hz[3] = {l->head_R[2], l->head_R[5], l->head_R[8]};
        double hdeg = gs_geom_vec3_angle(hz, (double[3]){0, 0, 1}) / DEG;
        double fwd[3] = {0, 0, -1};
        double gdeg = gs_geom_vec3_angle(l->gaze_head, fwd) / DEG;
        int narrowed = gs_eval_expr_narrowed(&sc.expr);
        for (int e = 0; e < 2; e++) {
            gs_face_iris ir;
            if (gs_face_iris_locate(&img, (const double(*)[2])&l->lm2d[36 + 6 * e], &o, &ir,
                                    &err)) {
                fprintf(stderr, "scene %d eye %d: %s\n", i, e, err.msg);
                return 1;
            }
            int ok = ir.status == GS_FACE_IRIS_OK;
            double d = hypot(ir.centre[0] - l->pupil_uv[e][0], ir.centre[1] - l->pupil_uv[e][1]);
            if (verbose)
                printf("scene %d eye %d status %d error %.2f (%+.2f %+.2f) r %.2f pupil %.2f "
                       "visible %.2f contrast %.0f residual %.1f sd %.2f conf %.2f seen %.2f "
                       "gaze %.0f head %.0f narrowed %d pupil_err %.2f\n",
                       i, e, ir.status, d, ir.centre[0] - l->pupil_uv[e][0],
                       ir.centre[1] - l->pupil_uv[e][1], ir.radius, ir.pupil_radius, ir.visible,
                       ir.contrast, ir.residual, ir.centre_sd_px, ir.confidence,
                       contour_seen(&smp, e), gdeg, hdeg, narrowed,
                       hypot(ir.pupil_centre[0] - l->pupil_uv[e][0],
                             ir.pupil_centre[1] - l->pupil_uv[e][1]));
            if (narrowed) {
                double c = fmax(sc.expr.squint, sc.expr.blink);
                add(&narrow[c < 0.6 ? 0 : c < 0.8 ? 1 : 2], ok, d);
                continue;
            }
            if (contour_seen(&smp, e) < 0.5) {
                add(&hidden, ok, d);
                continue;
            }
            add(&all_open, ok, d);
            int gb = gdeg < 15 ? 0 : gdeg < 30 ? 1 : 2, hb = hdeg < 15 ? 0 : hdeg < 30 ? 1 : 2;
            add(&gaze[gb], ok, d);
            add(&head[hb], ok, d);
            if (ok) {
                double rt = l->K[0] * l->iris_radius_mm / l->pupil_centre[e][2];
                add(&radius, 1, fabs(ir.radius - rt));
            }
        }
    }
    gs_synth_sample_free(&smp);
    printf("%d scenes (%d eyes), 256 px normalized, radius range %s%s%s\n", count, 2 * count,
           autor ? "from the eye width" : "of the normalized scale",
           open ? ", lids pulled back" : "", ss == 2 ? ", 2 x 2 supersampled" : "");
    header("open eyes");
    row("all", &all_open);
    header("open eyes, gaze in the head");
    for (int b = 0; b < 3; b++)
        row(bins[b], &gaze[b]);
    header("open eyes, head against the camera");
    for (int b = 0; b < 3; b++)
        row(bins[b], &head[b]);
    header("narrowed or closing eyes, max(squint, blink)");
    row("0.3-0.6", &narrow[0]);
    row("0.6-0.8", &narrow[1]);
    row("0.8-1", &narrow[2]);
    header("eyes hidden by the face");
    row("contour < 50 % on the eyeball", &hidden);
    header("radius error, open eyes located");
    row("abs(radius - iris_radius_mm f / z)", &radius);
    return 0;
}
