/* The iris localizer on the real photos (astronaut, face-api sample1..6):
 * how far its centre moves when the photo is cropped 2 px off (four
 * directions) or scaled by 0.95 and 1.05, once mapped back to the
 * original pixels. Every face the cascade finds; its box is mapped into
 * each changed photo (the detector's own jitter left out; also half-pixel
 * shifts by resampling, which integer crops cannot show), the 68
 * landmarks and the iris are found again there. The radius range comes
 * from the pose's scale (focal length over the face distance).
 *
 * Prints a table (docs/face.md records it) and checks that of the eyes
 * located (status OK) in the original and the changed photo, the median
 * move is <= 0.1 of the iris radius and the 90th percentile <= 0.25 of
 * it, and that at least half the eyes are located in the originals; the
 * moves over 0.2 of the radius are listed (the largest is not bounded: on
 * a blurred, dim eye the fit can jump between two nearby solutions). Exits 77
 * (skipped) when the photos are missing. */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "face_photos.h"
#include "gs_test.h"

#define MAXM 1024

/* One change of the photo: a crop offset (dx, dy; half a pixel by
 * bilinear resampling) or a scale s. */
typedef struct change {
    const char *name;
    double dx, dy, s;
} change;

static const change changes[] = {
    {"crop +2 px x", 2, 0, 1},     {"crop -2 px x", -2, 0, 1},     {"crop +2 px y", 0, 2, 1},
    {"crop -2 px y", 0, -2, 1},    {"shift 0.5 px x", 0.5, 0, 1}, {"shift 0.5 px y", 0, 0.5, 1},
    {"scale 0.95", 0, 0, 0.95},    {"scale 1.05", 0, 0, 1.05}};
#define NCH (int)(sizeof changes / sizeof changes[0])

/* The changed photo: out(X) = in(X / s + d) in geom.h pixels (bilinear,
 * edges repeated), computed only inside roi (x0, y0, x1, y1 of the
 * original photo, mapped; black elsewhere: nothing reads there). */
static int apply(const gs_io_image *in, const change *c, const int roi[4], gs_io_image *out)
{
    int w = (int)lround(in->width * c->s), h = (int)lround(in->height * c->s);
    out->width = w;
    out->height = h;
    out->stride = 3 * (size_t)w;
    out->data = calloc(out->stride, (size_t)h);
    if (!out->data)
        return -1;
    int x0 = (int)floor((roi[0] - c->dx) * c->s), x1 = (int)ceil((roi[2] - c->dx) * c->s);
    int y0 = (int)floor((roi[1] - c->dy) * c->s), y1 = (int)ceil((roi[3] - c->dy) * c->s);
    x0 = x0 < 0 ? 0 : x0;
    y0 = y0 < 0 ? 0 : y0;
    x1 = x1 > w ? w : x1;
    y1 = y1 > h ? h : y1;
    for (int y = y0; y < y1; y++)
        for (int x = x0; x < x1; x++) {
            double u = (x + 0.5) / c->s + c->dx - 0.5, v = (y + 0.5) / c->s + c->dy - 0.5;
            u = u < 0 ? 0 : u > in->width - 1 ? in->width - 1 : u;
            v = v < 0 ? 0 : v > in->height - 1 ? in->height - 1 : v;
            int i = (int)u, j = (int)v;
            int i1 = i + 1 < in->width ? i + 1 : i, j1 = j + 1 < in->height ? j + 1 : j;
            double fu = u - i, fv = v - j;
            for (int k = 0; k < 3; k++) {
                const unsigned char *p = in->data;
                size_t st = in->stride;
                double a = p[j * st + 3 * i + k] * (1 - fu) + p[j * st + 3 * i1 + k] * fu;
                double b = p[j1 * st + 3 * i + k] * (1 - fu) + p[j1 * st + 3 * i1 + k] * fu;
                out->data[(size_t)y * out->stride + 3 * x + k] =
                    (unsigned char)lround(a * (1 - fv) + b * fv);
            }
        }
    return 0;
}

/* A dlib box (pixel centres at integers) through the change. */
static gs_face_box map_box(gs_face_box b, const change *c)
{
    gs_face_box o;
    o.left = (int)lround((b.left + 0.5 - c->dx) * c->s - 0.5);
    o.top = (int)lround((b.top + 0.5 - c->dy) * c->s - 0.5);
    o.right = (int)lround((b.right + 0.5 - c->dx) * c->s - 0.5);
    o.bottom = (int)lround((b.bottom + 0.5 - c->dy) * c->s - 0.5);
    return o;
}

/* Landmarks for `box` and both irises; 0 on success. */
static int irises(const gs_io_image *img, gs_face_box box, gs_face_iris ir[2],
                  double uv[GS_FACE_LANDMARKS][2])
{
    gs_face_opts fo;
    gs_face_opts_default(&fo);
    fo.use_box = 1;
    fo.box = box;
    gs_face_result r;
    gs_error err;
    if (gs_face_analyze(NULL, photo_shape_model(), img, &fo, &r, &err) != GS_OK)
        return -1;
    memcpy(uv, r.uv, sizeof r.uv);
    double dist = sqrt(r.pose.t[0] * r.pose.t[0] + r.pose.t[1] * r.pose.t[1] +
                       r.pose.t[2] * r.pose.t[2]);
    gs_face_iris_opts o;
    gs_face_iris_opts_default(&o);
    gs_face_iris_opts_scale(&o, r.k[0] / dist);
    for (int e = 0; e < 2; e++) {
        double eye[6][2];
        memcpy(eye, r.uv[36 + 6 * e], sizeof eye);
        if (gs_face_iris_locate(img, (const double(*)[2])eye, &o, &ir[e], &err) != GS_OK)
            return -1;
    }
    return 0;
}

/* The q-quantile of n sorted values (q = 1: the largest). */
static double q(const double *v, int n, double p)
{
    if (n <= 0)
        return NAN;
    int i = (int)ceil(p * n) - 1;
    return v[i < 0 ? 0 : i >= n ? n - 1 : i];
}

static int cmp(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

int main(void)
{
    static const char *const names[] = {"astronaut", "sample1", "sample2", "sample3",
                                        "sample4",   "sample5", "sample6"};
    gs_face_detector *det = NULL;
    gs_error err;
    if (gs_face_detector_load(NULL, &det, &err) != GS_OK) {
        printf("SKIP: %s\n", err.msg);
        return GS_TEST_SKIP;
    }
    if (!photo_shape_model()) {
        gs_face_detector_destroy(det);
        return GS_TEST_SKIP;
    }
    static double px[NCH][MAXM], rel[NCH][MAXM], all_px[NCH * MAXM], all_rel[NCH * MAXM];
    int n[NCH] = {0}, lost[NCH] = {0}, eyes = 0, located = 0, faces = 0, na = 0;
    for (size_t f = 0; f < sizeof names / sizeof names[0]; f++) {
        gs_io_image img;
        int rc = photo_load(names[f], &img);
        if (rc == GS_TEST_SKIP) {
            gs_face_detector_destroy(det);
            return GS_TEST_SKIP;
        }
        CHECK(rc == 0);
        if (rc)
            continue;
        gs_face_detection d[16];
        int nd = 0;
        CHECK(gs_face_detect(det, &img, NULL, d, 16, &nd, &err) == GS_OK);
        gs_face_iris ir0[16][2];
        int ok0[16] = {0};
        /* The faces' boxes grown by their size: all the landmark model and
         * the localizer read. */
        int roi[4] = {img.width, img.height, 0, 0};
        for (int i = 0; i < nd && i < 16; i++) {
            int bw = d[i].box.right - d[i].box.left + 1;
            roi[0] = d[i].box.left - bw < roi[0] ? d[i].box.left - bw : roi[0];
            roi[1] = d[i].box.top - bw < roi[1] ? d[i].box.top - bw : roi[1];
            roi[2] = d[i].box.right + bw > roi[2] ? d[i].box.right + bw : roi[2];
            roi[3] = d[i].box.bottom + bw > roi[3] ? d[i].box.bottom + bw : roi[3];
        }
        for (int i = 0; i < nd && i < 16; i++) {
            double uv0[GS_FACE_LANDMARKS][2];
            if (irises(&img, d[i].box, ir0[i], uv0))
                continue;
            ok0[i] = 1;
            faces++;
            for (int e = 0; e < 2; e++) {
                eyes++;
                located += ir0[i][e].status == GS_FACE_IRIS_OK;
            }
        }
        for (int c = 0; c < NCH; c++) {
            gs_io_image ch;
            CHECK(apply(&img, &changes[c], roi, &ch) == 0);
            for (int i = 0; i < nd && i < 16; i++) {
                gs_face_iris ir1[2];
                double uv1[GS_FACE_LANDMARKS][2];
                if (!ok0[i] || irises(&ch, map_box(d[i].box, &changes[c]), ir1, uv1))
                    continue;
                for (int e = 0; e < 2; e++) {
                    const gs_face_iris *r0 = &ir0[i][e];
                    if (r0->status != GS_FACE_IRIS_OK)
                        continue;
                    if (ir1[e].status != GS_FACE_IRIS_OK) {
                        lost[c]++;
                        continue;
                    }
                    /* Back to the original pixels: X = X' / s + d. */
                    double x = ir1[e].centre[0] / changes[c].s + changes[c].dx;
                    double y = ir1[e].centre[1] / changes[c].s + changes[c].dy;
                    double m = hypot(x - r0->centre[0], y - r0->centre[1]);
                    if (m > 0.2 * r0->radius)
                        printf("%s face %d eye %d, %s: moved %.2f px (radius %.2f px, eye "
                               "width %.1f px; confidence %.2f, then %.2f)\n", names[f], i, e,
                               changes[c].name, m, r0->radius, r0->eye_width, r0->confidence,
                               ir1[e].confidence);
                    if (n[c] < MAXM) {
                        px[c][n[c]] = m;
                        rel[c][n[c]] = m / r0->radius;
                        n[c]++;
                        all_px[na] = m;
                        all_rel[na] = m / r0->radius;
                        na++;
                    }
                }
            }
            free(ch.data);
        }
        gs_io_image_free(&img);
    }
    gs_face_detector_destroy(det);
    printf("%d faces, %d eyes, %d located (status OK) in the original photos\n\n", faces, eyes,
           located);
    printf("| change | eyes | no longer OK | median px | p90 px | max px | median / radius | "
           "p90 / radius | max / radius |\n|---|---|---|---|---|---|---|---|---|\n");
    for (int c = 0; c < NCH; c++) {
        qsort(px[c], (size_t)n[c], sizeof(double), cmp);
        qsort(rel[c], (size_t)n[c], sizeof(double), cmp);
        printf("| %s | %d | %d | %.2f | %.2f | %.2f | %.3f | %.3f | %.3f |\n", changes[c].name,
               n[c], lost[c], q(px[c], n[c], 0.5), q(px[c], n[c], 0.9), q(px[c], n[c], 1),
               q(rel[c], n[c], 0.5), q(rel[c], n[c], 0.9), q(rel[c], n[c], 1));
    }
    qsort(all_px, (size_t)na, sizeof(double), cmp);
    qsort(all_rel, (size_t)na, sizeof(double), cmp);
    double med = q(all_rel, na, 0.5), p90 = q(all_rel, na, 0.9);
    printf("| all | %d | | %.2f | %.2f | %.2f | %.3f | %.3f | %.3f |\n", na, q(all_px, na, 0.5),
           q(all_px, na, 0.9), q(all_px, na, 1), med, p90, q(all_rel, na, 1));
    CHECK_MSG(2 * located >= eyes, "only %d of %d eyes located", located, eyes);
    CHECK_MSG(na > 0 && med <= 0.1, "median move %.3f of the radius", med);
    CHECK_MSG(na > 0 && p90 <= 0.25, "p90 move %.3f of the radius", p90);
    printf("%d checks, %d failures\n", gs_test_checks, gs_test_failures);
    return gs_test_failures != 0;
}
