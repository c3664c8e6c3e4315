/* Masks agree with the landmark hulls, and with each other, for random
 * scenes over the whole range (head yaw +-60, pitch +-40, roll +-10 deg;
 * gaze +-50 yaw, +-40 pitch; expressions, squints and blinks):
 * - almost every pixel of an eye mask lies in the hull of that eye's six
 *   landmarks (grown by 1.5 px: the lid margins bulge between points);
 * - most of that hull is eye, for eyes that face the camera (within
 *   FACING_DEG: beyond it the nose and the brow hide part of the far eye)
 *   and see into the lid opening (the camera inside the wedge between the
 *   two lid margin planes) with its four lid landmarks in sight (the brow
 *   hides the upper lid when the head is pitched down, the nose the far
 *   eye when turned). The landmarks lie on the lid margins where
 *   they meet the eyeball; a lid is 2.2 mm thick, so a camera outside the
 *   wedge (below a raised lower lid: a head pitched up, a squint, a smile;
 *   above a lowered upper lid: a blink, a downward gaze) sees the lid's
 *   outer edge in front of those points, and the visible eye is narrower
 *   than their hull;
 * - the hull of all 68 landmarks is face or eye, for faces within
 *   FACE_YAW_DEG of frontal (toward a profile the hull spans the air
 *   between the nose, the lips and the chin);
 * - face and eye masks are disjoint and inside the head mask. */
#include "gs_test.h"
#include "synth_internal.h"
#include "synth_test_util.h"

enum { SIZE = 160, SCENES = 48 };
#define FACING_DEG 40.0
#define FACE_YAW_DEG 45.0

/* Whether the camera (head frame) lies inside the lid opening of an eye:
 * on the open side of both margin planes (n_up, n_lo point into the lids). */
/* Whether the head leaves the straight line from the camera to each of an
 * eye's four lid landmarks (not the corners, tucked into the canthi) free up
 * to 4 mm before the point (they sit on the inner edge of the 2.2 mm lid
 * margin, which the line may graze near its end). */
static int landmarks_in_sight(const head_model *h, const double cam[3],
                              const double (*lm)[3])
{
    v3 o = v3_make((float)cam[0], (float)cam[1], (float)cam[2]);
    for (int i = 1; i < 6; i++) {
        if (i == 3)
            continue; /* the inner corner */
        v3 d = v3_sub(v3_make((float)lm[i][0], (float)lm[i][1], (float)lm[i][2]), o);
        float len = v3_len(d), t = 0.0f;
        d = v3_scale(d, 1.0f / len);
        while (t < len - 4.0f) {
            float dist = gs_synth_head_sdf(h, v3_add(o, v3_scale(d, t)));
            if (dist < 0.01f) {
                if (getenv("GS_TEST_VERBOSE"))
                    printf("    landmark %d hidden at %.1f of %.1f mm\n", i, (double)t,
                           (double)len);
                return 0;
            }
            t += 0.9f * dist;
        }
    }
    return 1;
}

static int sees_into_opening(const eye_model *e, const double cam[3])
{
    v3 q = v3_sub(v3_make((float)cam[0], (float)cam[1], (float)cam[2]), e->c);
    return v3_dot(e->n_up, q) < 0.0f && v3_dot(e->n_lo, q) < 0.0f;
}

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

/* Pixel box [x0, x1) x [y0, y1) holding every pixel centre within 2 px of
 * the hull, clipped to the image. */
static void hull_box(const hull *h, int box[4])
{
    double lo[2] = {1e9, 1e9}, hi[2] = {-1e9, -1e9};
    for (int i = 0; i < h->n; i++)
        for (int c = 0; c < 2; c++) {
            lo[c] = fmin(lo[c], h->p[i][c]);
            hi[c] = fmax(hi[c], h->p[i][c]);
        }
    for (int c = 0; c < 2; c++) {
        double a = floor(lo[c] - 3.0), b = ceil(hi[c] + 3.0);
        box[2 * c] = a < 0 ? 0 : (a > SIZE ? SIZE : (int)a);
        box[2 * c + 1] = b < 0 ? 0 : (b > SIZE ? SIZE : (int)b);
    }
}

int main(void)
{
    gs_synth_sample s;
    CHECK(gs_synth_sample_alloc(&s, SIZE, SIZE, NULL) == GS_OK);
    size_t plane = (size_t)SIZE * SIZE;
    double worst_in = 1, worst_cover = 1, worst_face = 1;
    int eyes_in = 0, eyes_cover = 0, blinks = 0, faces = 0;
    double hy_max = 0, hp_max = 0;
    for (uint64_t k = 0; k < SCENES; k++) {
        gs_synth_ranges r;
        gs_synth_ranges_default(&r);
        r.blink_prob = 0.2f;
        gs_synth_scene sc;
        gs_synth_scene_random(gs_synth_split_seed(GS_SYNTH_VAL, k), k, &r, &sc);
        gs_synth_camera base, cam;
        gs_synth_camera_single(SIZE, 600, 260, &base);
        CHECK(gs_synth_camera_normalized(&sc, &base, SIZE, 0, 0, &cam, NULL) == 0);
        CHECK(gs_synth_render(&sc, &cam, NULL, NULL, &s, NULL) == GS_OK);
        const gs_synth_labels *lab = &s.labels;
        hy_max = fmax(hy_max, fabs(lab->head_yaw) / DEG);
        hp_max = fmax(hp_max, fabs(lab->head_pitch) / DEG);
        blinks += sc.expr.blink > 0;
        head_model hm;
        gs_synth_head_build(&sc.identity, &sc.expr, sc.gaze_pitch, sc.gaze_yaw, &hm);
        double cam_head[3]; /* camera centre in the head frame: -R^T t */
        gs_geom_mat3_tvec(lab->head_R, lab->head_t, cam_head);
        for (int j = 0; j < 3; j++)
            cam_head[j] = -cam_head[j];
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
            int box[4];
            hull_box(&h, box);
            for (int y = 0; y < SIZE; y++)
                for (int x = 0; x < SIZE; x++) {
                    /* Outside the box the hull is more than 2 px away. */
                    double d = x < box[0] || x >= box[1] || y < box[2] || y >= box[3]
                                   ? 2.0
                                   : hull_dist(&h, x + 0.5, y + 0.5);
                    int eye = m[(size_t)y * SIZE + x] != 0;
                    in_mask += eye;
                    in_hull += d <= 0;
                    mask_in_hull += eye && d <= 1.5;
                    if (d <= -1.0) {
                        hull_core++;
                        core_eye += eye;
                    }
                }
            /* Angle between the face's forward direction (-z of the
             * head) and the direction from the eye to the camera. */
            double fwd[3] = {-lab->head_R[2], -lab->head_R[5], -lab->head_R[8]},
                   to_cam[3] = {-lab->eye_centre[e][0], -lab->eye_centre[e][1],
                                -lab->eye_centre[e][2]};
            double facing = gs_geom_vec3_angle(fwd, to_cam) / DEG;
            double fin = in_mask ? (double)mask_in_hull / in_mask : 1;
            double fcov = hull_core ? (double)core_eye / hull_core : 1;
            worst_in = fmin(worst_in, fin);
            eyes_in += in_mask > 0;
            CHECK_MSG(fin >= 0.97, "scene %llu eye %d: %d mask px, %.3f inside the landmark "
                      "hull (+1.5 px)", (unsigned long long)k, e, in_mask, fin);
            int open = sees_into_opening(&hm.eye[e], cam_head) &&
                       landmarks_in_sight(&hm, cam_head,
                                          (const double(*)[3])lab->lm3d_head[e == 0 ? 36 : 42]);
            if (facing <= FACING_DEG && open) {
                worst_cover = fmin(worst_cover, fcov);
                eyes_cover++;
                CHECK_MSG(fcov >= 0.9 && (in_mask > 20 || hull_core < 20),
                          "scene %llu eye %d (facing %.0f deg, blink %.2f): %d mask px, "
                          "hull interior %.3f eye", (unsigned long long)k, e, facing,
                          (double)sc.expr.blink, in_mask, fcov);
            }
            if (getenv("GS_TEST_VERBOSE"))
                printf("  scene %llu eye %d: head %.0f %.0f facing %.0f open %d blink %.2f: "
                       "mask %d in hull %.3f, hull %d core eye %.3f\n", (unsigned long long)k,
                       e, lab->head_pitch / DEG, lab->head_yaw / DEG, facing, open,
                       (double)sc.expr.blink, in_mask, fin, hull_core, fcov);
            (void)in_hull;
        }
        /* Face: the hull of all landmarks is face or eye. */
        hull h;
        hull_build(&h, (const double(*)[2])s.labels.lm2d, 68);
        int core = 0, covered = 0;
        int box[4];
        hull_box(&h, box);
        for (int y = box[2]; y < box[3]; y++)
            for (int x = box[0]; x < box[1]; x++) {
                if (hull_dist(&h, x + 0.5, y + 0.5) > -1.0)
                    continue;
                size_t i = (size_t)y * SIZE + x;
                core++;
                covered += face[i] || s.mask[i + 2 * plane] || s.mask[i + 3 * plane];
            }
        double ff = core ? (double)covered / core : 0;
        if (fabs(lab->head_yaw) <= FACE_YAW_DEG * DEG) {
            worst_face = fmin(worst_face, ff);
            faces++;
            CHECK_MSG(ff >= 0.99, "scene %llu (head yaw %.0f deg): landmark hull %.4f face "
                      "or eye", (unsigned long long)k, lab->head_yaw / DEG, ff);
        }
        char name[32];
        snprintf(name, sizeof name, "masks_%02llu", (unsigned long long)k);
        dump_ppm(&s, name);
    }
    printf("masks: %d scenes (|head yaw| <= %.0f, |pitch| <= %.0f deg, %d blinks): eye "
           "pixels in their landmark hull >= %.3f (%d eyes), hull interior eye >= %.3f "
           "(%d eyes facing the camera within %.0f deg and seeing into the lid opening), "
           "landmark hull face/eye >= %.4f (%d faces within %.0f deg of frontal)\n", SCENES,
           hy_max, hp_max, blinks, worst_in, eyes_in, worst_cover, eyes_cover, FACING_DEG,
           worst_face, faces, FACE_YAW_DEG);
    CHECK_MSG(eyes_cover >= SCENES / 3 && faces >= SCENES / 2,
              "only %d eyes and %d faces checked", eyes_cover, faces);
    gs_synth_sample_free(&s);
    GS_TEST_END();
}
