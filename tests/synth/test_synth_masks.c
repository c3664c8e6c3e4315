/* Masks agree with the landmark hulls, and with each other:
 * - almost every pixel of an eye mask lies in the hull of that eye's six
 *   landmarks (grown by 1.5 px: the lid margins bulge between points),
 *   and most of that hull is eye;
 * - the hull of all 68 landmarks is face or eye;
 * - face and eye masks are disjoint and inside the head mask. */
#include "gs_test.h"
#include "synth_test_util.h"

enum { SIZE = 160, SCENES = 16 };

/* Signed distance (px, positive outside) from (x, y) to the convex hull of
 * n points: the hull is built by gift wrapping. */
typedef struct hull {
    int n;
    double p[68][2];
} hull;

static double cross3(const double *o, const double *a, const double *b)
{
    return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0]);
}

/* Andrew's monotone chain. */
static void hull_build(hull *h, const double (*pts)[2], int n)
{
    double q[68][2];
    for (int i = 0; i < n; i++) {
        q[i][0] = pts[i][0];
        q[i][1] = pts[i][1];
    }
    for (int i = 1; i < n; i++) /* insertion sort by (x, y) */
        for (int j = i; j > 0 && (q[j - 1][0] > q[j][0] ||
                                  (q[j - 1][0] == q[j][0] && q[j - 1][1] > q[j][1]));
             j--) {
            double t0 = q[j][0], t1 = q[j][1];
            q[j][0] = q[j - 1][0];
            q[j][1] = q[j - 1][1];
            q[j - 1][0] = t0;
            q[j - 1][1] = t1;
        }
    double out[140][2];
    int k = 0;
    for (int i = 0; i < n; i++) {
        while (k >= 2 && cross3(out[k - 2], out[k - 1], q[i]) <= 0)
            k--;
        out[k][0] = q[i][0];
        out[k][1] = q[i][1];
        k++;
    }
    for (int i = n - 2, lo = k + 1; i >= 0; i--) {
        while (k >= lo && cross3(out[k - 2], out[k - 1], q[i]) <= 0)
            k--;
        out[k][0] = q[i][0];
        out[k][1] = q[i][1];
        k++;
    }
    h->n = k - 1;
    for (int i = 0; i < h->n; i++) {
        h->p[i][0] = out[i][0];
        h->p[i][1] = out[i][1];
    }
}

static double hull_dist(const hull *h, double x, double y)
{
    double out = -1e9, edge = 1e9, area = 0;
    for (int i = 0; i < h->n; i++) {
        const double *a = h->p[i], *b = h->p[(i + 1) % h->n];
        area += a[0] * b[1] - b[0] * a[1];
    }
    double sign = area > 0 ? 1.0 : -1.0;
    for (int i = 0; i < h->n; i++) {
        const double *a = h->p[i], *b = h->p[(i + 1) % h->n];
        double ex = b[0] - a[0], ey = b[1] - a[1], len = hypot(ex, ey);
        if (len < 1e-9)
            continue;
        /* Outward normal (ey, -ex) when the signed area is positive. */
        double s = sign * ((x - a[0]) * ey - (y - a[1]) * ex) / len;
        out = fmax(out, s);
        double t = ((x - a[0]) * ex + (y - a[1]) * ey) / (len * len);
        t = t < 0 ? 0 : (t > 1 ? 1 : t);
        edge = fmin(edge, hypot(x - a[0] - t * ex, y - a[1] - t * ey));
    }
    return out > 0 ? edge : out;
}

int main(void)
{
    gs_synth_sample s;
    CHECK(gs_synth_sample_alloc(&s, SIZE, SIZE, NULL) == GS_OK);
    size_t plane = (size_t)SIZE * SIZE;
    double worst_in = 1, worst_cover = 1, worst_face = 1;
    for (uint64_t k = 0; k < SCENES; k++) {
        gs_synth_ranges r;
        gs_synth_ranges_default(&r);
        r.head_yaw = 20 * DEG;
        r.head_pitch = 15 * DEG;
        r.gaze_yaw = 30 * DEG;
        r.gaze_pitch = 20 * DEG;
        r.expression_prob = 0.0f;
        r.blink_prob = 0.0f;
        gs_synth_scene sc;
        gs_synth_scene_random(gs_synth_split_seed(GS_SYNTH_VAL, k), k, &r, &sc);
        gs_synth_camera base, cam;
        gs_synth_camera_single(SIZE, 600, 260, &base);
        CHECK(gs_synth_camera_normalized(&sc, &base, SIZE, 0, 0, &cam, NULL) == 0);
        CHECK(gs_synth_render(&sc, &cam, NULL, NULL, &s, NULL) == GS_OK);
        const uint8_t *head = gs_synth_sample_mask(&s, GS_SYNTH_MASK_HEAD);
        const uint8_t *face = gs_synth_sample_mask(&s, GS_SYNTH_MASK_FACE);
        int overlap = 0, outside_head = 0;
        for (size_t i = 0; i < plane; i++) {
            int n = (face[i] != 0) + (s.mask[i + 2 * plane] != 0) +
                    (s.mask[i + 3 * plane] != 0);
            overlap += n > 1;
            outside_head += n > 0 && !head[i];
        }
        CHECK_MSG(overlap == 0 && outside_head == 0,
                  "scene %llu: %d pixels in two masks, %d outside the head",
                  (unsigned long long)k, overlap, outside_head);
        /* Eyes. */
        for (int e = 0; e < 2; e++) {
            int mask_id = e == GS_SYNTH_EYE_RIGHT ? GS_SYNTH_MASK_RIGHT_EYE
                                                  : GS_SYNTH_MASK_LEFT_EYE;
            const uint8_t *m = gs_synth_sample_mask(&s, mask_id);
            hull h;
            hull_build(&h, &s.labels.lm2d[e == 0 ? 36 : 42], 6);
            int in_mask = 0, in_hull = 0, mask_in_hull = 0, hull_core = 0,
                core_eye = 0;
            for (int y = 0; y < SIZE; y++)
                for (int x = 0; x < SIZE; x++) {
                    double d = hull_dist(&h, x + 0.5, y + 0.5);
                    int eye = m[(size_t)y * SIZE + x] != 0;
                    in_mask += eye;
                    in_hull += d <= 0;
                    mask_in_hull += eye && d <= 1.5;
                    if (d <= -1.0) {
                        hull_core++;
                        core_eye += eye;
                    }
                }
            double fin = in_mask ? (double)mask_in_hull / in_mask : 0;
            double fcov = hull_core ? (double)core_eye / hull_core : 1;
            worst_in = fmin(worst_in, fin);
            worst_cover = fmin(worst_cover, fcov);
            CHECK_MSG(in_mask > 20 && fin >= 0.97 && fcov >= 0.9,
                      "scene %llu eye %d: %d mask px, %.3f inside the landmark "
                      "hull (+1.5 px), hull interior %.3f eye", (unsigned long long)k,
                      e, in_mask, fin, fcov);
            (void)in_hull;
        }
        /* Face: the hull of all landmarks is face or eye. */
        hull h;
        hull_build(&h, (const double(*)[2])s.labels.lm2d, 68);
        int core = 0, covered = 0;
        for (int y = 0; y < SIZE; y++)
            for (int x = 0; x < SIZE; x++) {
                if (hull_dist(&h, x + 0.5, y + 0.5) > -1.0)
                    continue;
                size_t i = (size_t)y * SIZE + x;
                core++;
                covered += face[i] || s.mask[i + 2 * plane] || s.mask[i + 3 * plane];
            }
        double ff = core ? (double)covered / core : 0;
        worst_face = fmin(worst_face, ff);
        CHECK_MSG(ff >= 0.99, "scene %llu: landmark hull %.4f face or eye",
                  (unsigned long long)k, ff);
        char name[32];
        snprintf(name, sizeof name, "masks_%02llu", (unsigned long long)k);
        dump_ppm(&s, name);
    }
    printf("masks: eye pixels in their landmark hull >= %.3f, hull interior "
           "eye >= %.3f, landmark hull face/eye >= %.4f\n", worst_in,
           worst_cover, worst_face);
    gs_synth_sample_free(&s);
    GS_TEST_END();
}
