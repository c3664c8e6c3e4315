/* Geometry of the head model:
 * - eyelids (and the rest of the head) never cut into an eyeball, for
 *   random identities, gazes, squints and blinks, and for every corner of
 *   the gaze range (+-40 deg pitch x +-50 deg yaw) with the eyes open,
 *   squinting, half and fully closed, and with the lids opened
 *   (render option open_lids);
 * - the 4-wide field equals the scalar field bit for bit, and the field's
 *   part skipping leaves the surface unchanged;
 * - analytic gradients match finite differences;
 * - the analytic eyeball intersection agrees with the eyeball field;
 * - landmarks lie on the surface and the neutral face centre is the head
 *   origin. */
#include <string.h>

#include "gs_test.h"
#include "synth_internal.h"
#include "synth_test_util.h"

static void random_head(gs_rng *r, int i, head_model *h)
{
    gs_synth_identity id;
    gs_synth_identity_from_seed(gs_synth_split_seed(GS_SYNTH_TRAIN, (uint64_t)i),
                                &id);
    gs_synth_expression ex;
    gs_synth_expression_neutral(&ex);
    ex.mouth_open = (float)gs_rng_uniform(r, 0, 1) * (i % 3 == 0);
    ex.smile = (float)gs_rng_uniform(r, 0, 1) * (i % 2);
    ex.brow_raise = (float)gs_rng_uniform(r, -1, 1);
    ex.squint = (float)gs_rng_uniform(r, 0, 1) * (i % 4 == 1);
    ex.blink = (float)gs_rng_uniform(r, 0, 1) * (i % 5 == 2);
    ex.pupil = (float)gs_rng_uniform(r, -1, 1);
    gs_synth_head_build(&id, &ex, gs_rng_uniform(r, -40, 40) * DEG,
                        gs_rng_uniform(r, -50, 50) * DEG, h);
}

/* Heads at the extremes: a corner of the gaze range (4), with no, full
 * squint, half and full blink (4), lids as built or opened (2). */
enum { EXTREME_HEADS = 32 };
static void extreme_head(gs_rng *r, int i, head_model *h)
{
    gs_synth_identity id;
    gs_synth_identity_from_seed(gs_synth_split_seed(GS_SYNTH_TEST, (uint64_t)i),
                                &id);
    gs_synth_expression ex;
    gs_synth_expression_neutral(&ex);
    int corner = i % 4, lids = (i / 4) % 4;
    ex.squint = lids == 1 ? 1.0f : 0.0f;
    ex.blink = lids == 2 ? 0.5f : (lids == 3 ? 1.0f : 0.0f);
    ex.pupil = (float)gs_rng_uniform(r, -1, 1);
    gs_synth_head_build(&id, &ex, (corner & 1 ? 40 : -40) * DEG,
                        (corner & 2 ? 50 : -50) * DEG, h);
    if (i >= 16)
        gs_synth_head_open_lids(h);
}

/* Uniform point on a sphere. */
static v3 sphere_point(gs_rng *r)
{
    double z = gs_rng_uniform(r, -1, 1), a = gs_rng_uniform(r, 0, 6.283185307);
    double s = sqrt(1 - z * z);
    return v3_make((float)(s * cos(a)), (float)(s * sin(a)), (float)z);
}

static void test_lids_clear_eyeballs(void)
{
    gs_rng r;
    gs_rng_seed(&r, 1);
    double worst = 1e9;
    int n = 0;
    for (int i = 0; i < 60 + EXTREME_HEADS; i++) {
        head_model h;
        if (i < 60)
            random_head(&r, i, &h);
        else
            extreme_head(&r, i - 60, &h);
        for (int e = 0; e < 2; e++) {
            const eye_model *eye = &h.eye[e];
            for (int k = 0; k < 400; k++) {
                /* A point on the eyeball union: the sclera sphere, or the
                 * corneal sphere where it sticks out. */
                v3 u = sphere_point(&r);
                v3 p = k % 2 ? v3_add(eye->c, v3_scale(u, eye->r_sclera))
                             : v3_add(eye->cornea_c, v3_scale(u, eye->r_cornea));
                if (gs_synth_eyeball_sdf(eye, p) < -1e-3f)
                    continue; /* inside the other sphere: not on the union */
                float d = gs_synth_head_sdf(&h, p);
                float d0 = gs_synth_head_sdf_nocull(&h, p);
                float dl = gs_synth_lid_sdf(eye, p);
                float m = minf(d, minf(d0, dl));
                worst = m - eye->lid_gap < worst ? m - eye->lid_gap : worst;
                n++;
                if (m < eye->lid_gap - 1e-3f) {
                    CHECK_MSG(0, "head %d eye %d: head surface %.4f mm from the "
                              "eyeball at (%.2f %.2f %.2f) (lid %.4f), gap %.2f",
                              i, e, (double)m, p.x, p.y, p.z, (double)dl,
                              (double)eye->lid_gap);
                    return;
                }
            }
        }
    }
    printf("lids: %d eyeball surface points, head surface at least %.4f mm "
           "beyond the lid gap\n", n, worst);
}

static void test_vector_field(void)
{
    gs_rng r;
    gs_rng_seed(&r, 2);
    long n = 0, vec_bad = 0, cull_bad = 0;
    double worst_cull = 0;
    for (int i = 0; i < 24; i++) {
        head_model h;
        random_head(&r, i, &h);
        for (int k = 0; k < 4000; k++) {
            float x[4], y[4], z[4], out[4];
            float s = k % 2 ? 160.0f : 50.0f;
            for (int l = 0; l < 4; l++) {
                x[l] = (float)gs_rng_uniform(&r, -s, s);
                y[l] = (float)gs_rng_uniform(&r, -s, s) + 20.0f * (float)(k % 3);
                z[l] = (float)gs_rng_uniform(&r, -s, s);
            }
            gs_synth_head_sdf4(&h, x, y, z, out);
            for (int l = 0; l < 4; l++, n++) {
                v3 p = v3_make(x[l], y[l], z[l]);
                float d = gs_synth_head_sdf(&h, p);
                if (memcmp(&d, &out[l], sizeof d) != 0 && vec_bad++ < 3)
                    fprintf(stderr, "  sdf4 lane %d: %.9g vs scalar %.9g\n", l,
                            (double)out[l], (double)d);
                if (fabsf(d) < 1.0f) {
                    double e = fabs(d - gs_synth_head_sdf_nocull(&h, p));
                    worst_cull = e > worst_cull ? e : worst_cull;
                    if (e > 0.05 && cull_bad++ < 3)
                        fprintf(stderr, "  head %d: skipping parts changes the "
                                "field at (%.2f %.2f %.2f) by %.4f mm\n", i,
                                p.x, p.y, p.z, e);
                }
            }
        }
    }
    CHECK_MSG(vec_bad == 0, "%ld of %ld 4-wide values differ from the scalar "
              "field", vec_bad, n);
    /* Skipped parts are exact no-ops for the true distances; the
     * ellipsoid approximation of very flat parts (a barely open mouth
     * cavity) can reach a little further, by hundredths of a mm. */
    CHECK_MSG(cull_bad == 0, "skipping parts moved the field near the surface "
              "by up to %.3g mm (tolerance 0.05)", worst_cull);
    printf("field: %ld points, 4-wide identical, skipping changes the field "
           "near the surface by at most %.4f mm\n", n, worst_cull);
}

static void test_gradients(void)
{
    gs_rng r;
    gs_rng_seed(&r, 3);
    int bad = 0, n = 0;
    double worst = 0;
    for (int i = 0; i < 12; i++) {
        head_model h;
        random_head(&r, i, &h);
        for (int k = 0; k < 300; k++) {
            v3 p = v3_make((float)gs_rng_uniform(&r, -80, 80),
                           (float)gs_rng_uniform(&r, -120, 120),
                           (float)gs_rng_uniform(&r, -60, 120));
            v3 g;
            float d = gs_synth_head_sdf_grad(&h, p, &g);
            if (fabsf(d) > 6.0f)
                continue;
            /* Central differences; skip points on creases (hard max/min,
             * clamps), where the gradient jumps. */
            const float e = 1e-2f;
            float fd[3];
            for (int a = 0; a < 3; a++) {
                v3 dp = v3_make(a == 0 ? e : 0, a == 1 ? e : 0, a == 2 ? e : 0);
                fd[a] = (gs_synth_head_sdf(&h, v3_add(p, dp)) -
                         gs_synth_head_sdf(&h, v3_sub(p, dp))) / (2 * e);
            }
            v3 g2, gm;
            gs_synth_head_sdf_grad(&h, v3_add(p, v3_make(e, e, e)), &g2);
            gs_synth_head_sdf_grad(&h, v3_sub(p, v3_make(e, e, e)), &gm);
            if (v3_len(v3_sub(g2, gm)) > 0.05f)
                continue;
            double err = fabs(fd[0] - g.x) + fabs(fd[1] - g.y) + fabs(fd[2] - g.z);
            worst = err > worst ? err : worst;
            n++;
            if (err > 2e-2 && bad++ < 3)
                fprintf(stderr, "  gradient at (%.2f %.2f %.2f): analytic "
                        "(%.4f %.4f %.4f) vs differences (%.4f %.4f %.4f)\n",
                        p.x, p.y, p.z, g.x, g.y, g.z, fd[0], fd[1], fd[2]);
        }
    }
    CHECK_MSG(bad == 0 && n > 500, "%d of %d gradients off (worst |diff|_1 "
              "%.3g, tolerance 2e-2)", bad, n, worst);
}

static void test_eye_intersection(void)
{
    gs_rng r;
    gs_rng_seed(&r, 4);
    head_model h;
    random_head(&r, 7, &h);
    int bad = 0, hits = 0;
    for (int k = 0; k < 5000; k++) {
        const eye_model *e = &h.eye[k % 2];
        v3 o = v3_add(e->c, v3_scale(sphere_point(&r), 60.0f));
        v3 target = v3_add(e->c, v3_scale(sphere_point(&r), 14.0f));
        v3 d = v3_norm(v3_sub(target, o));
        int oc;
        float t = gs_synth_eye_intersect(e, o, d, 0.0f, 1e9f, &oc);
        if (t == INFINITY) {
            /* Then the ray never comes inside the eyeball. */
            float tt = 0;
            for (int s = 0; s < 200 && tt < 120; s++) {
                float dist = gs_synth_eyeball_sdf(e, v3_add(o, v3_scale(d, tt)));
                if (dist < -1e-3f)
                    bad++;
                tt += maxf(dist, 0.05f);
            }
            continue;
        }
        hits++;
        float dist = gs_synth_eyeball_sdf(e, v3_add(o, v3_scale(d, t)));
        if (fabsf(dist) > 1e-3f && bad++ < 3)
            fprintf(stderr, "  eye hit at t %.3f has eyeball distance %.5f\n",
                    (double)t, (double)dist);
        /* Nothing of the eyeball before the hit. */
        if (gs_synth_eyeball_sdf(e, v3_add(o, v3_scale(d, 0.5f * t))) <= 0.0f)
            bad++;
    }
    CHECK_MSG(bad == 0 && hits > 1000, "eye intersection: %d bad, %d hits", bad,
              hits);
}

static void test_landmarks(void)
{
    gs_rng r;
    gs_rng_seed(&r, 5);
    double worst_surface = 0, worst_centre = 0;
    for (int i = 0; i < 20; i++) {
        gs_synth_identity id;
        gs_synth_identity_from_seed((uint64_t)i * 7919u, &id);
        gs_synth_expression ex;
        gs_synth_expression_neutral(&ex);
        head_model h;
        gs_synth_head_build(&id, &ex, 0.0, 0.0, &h);
        double lm[68][3], six[6][3], c[3];
        gs_synth_head_landmarks(&h, lm);
        static const int idx[6] = {36, 39, 42, 45, 31, 35};
        for (int k = 0; k < 6; k++)
            memcpy(six[k], lm[idx[k]], sizeof six[k]);
        gs_geom_face_centre6(six, c);
        worst_centre = fmax(worst_centre, gs_geom_vec3_norm(c));
        for (int k = 0; k < 68; k++) {
            if (k >= 36 && k < 48)
                continue; /* eye points sit on the lid margin edge */
            v3 p = v3_make((float)lm[k][0], (float)lm[k][1], (float)lm[k][2]);
            worst_surface = fmax(worst_surface, fabs(gs_synth_head_sdf(&h, p)));
        }
        /* Eye corners: outer further out than inner, right eye at -x. */
        CHECK(lm[36][0] < lm[39][0] && lm[39][0] < 0 && lm[42][0] > 0 &&
              lm[45][0] > lm[42][0]);
        /* Upper lid points above the lower ones (y down). */
        CHECK(lm[37][1] < lm[41][1] && lm[38][1] < lm[40][1]);
        CHECK(lm[43][1] < lm[47][1] && lm[44][1] < lm[46][1]);
        /* Chin below the nose tip below the eyes; mouth corners apart. */
        CHECK(lm[8][1] > lm[57][1] && lm[57][1] > lm[30][1] &&
              lm[30][1] > lm[36][1]);
        CHECK(lm[48][0] < lm[54][0]);
    }
    CHECK_MSG(worst_surface < 0.01, "landmark off the surface by %.4f mm",
              worst_surface);
    CHECK_MSG(worst_centre < 1e-3, "neutral face centre %.5f mm from the head "
              "origin", worst_centre);
}

int main(void)
{
    test_lids_clear_eyeballs();
    test_vector_field();
    test_gradients();
    test_eye_intersection();
    test_landmarks();
    GS_TEST_END();
}
