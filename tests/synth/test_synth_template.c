/* The neutral template: points on the surface with unit outward normals,
 * all four regions present and in the right places, landmarks equal to
 * the rendered labels of the mean head, independent of the thread count. */
#include <string.h>

#include "gs_test.h"
#include "synth_internal.h"
#include "synth_test_util.h"

int main(void)
{
    gs_synth_template t, t3;
    gs_error err;
    CHECK(gs_synth_template_build(0.1, NULL, &t, &err) == GS_ERR_ARG);
    CHECK(gs_synth_template_build(4.0, NULL, &t, &err) == GS_OK);
    gs_pool *pool = gs_pool_create(3);
    CHECK(gs_synth_template_build(4.0, pool, &t3, &err) == GS_OK);
    gs_pool_destroy(pool);
    CHECK_EQ_INT(t.n, t3.n);
    if (t.n == t3.n)
        CHECK(memcmp(t.xyz, t3.xyz, (size_t)t.n * 3 * sizeof(float)) == 0 &&
              memcmp(t.normal, t3.normal, (size_t)t.n * 3 * sizeof(float)) == 0 &&
              memcmp(t.region, t3.region, (size_t)t.n) == 0);
    gs_synth_template_free(&t3);

    gs_synth_identity id;
    gs_synth_expression ex;
    gs_synth_identity_mean(&id);
    gs_synth_expression_neutral(&ex);
    head_model h;
    gs_synth_head_build(&id, &ex, 0, 0, &h);
    int count[4] = {0};
    double worst_surface = 0, worst_normal = 0, worst_eye = 0;
    int outward_bad = 0;
    for (int i = 0; i < t.n; i++) {
        const float *p = &t.xyz[3 * i], *n = &t.normal[3 * i];
        int r = t.region[i];
        CHECK(r >= 0 && r < 4);
        count[r & 3]++;
        double nn = sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
        worst_normal = fmax(worst_normal, fabs(nn - 1.0));
        v3 pv = v3_make(p[0], p[1], p[2]), nv = v3_make(n[0], n[1], n[2]);
        if (r <= GS_SYNTH_REGION_FACE) {
            worst_surface = fmax(worst_surface, fabs(gs_synth_head_sdf(&h, pv)));
            /* Outward: the field grows along the normal. */
            outward_bad += gs_synth_head_sdf(&h, v3_add(pv, v3_scale(nv, 0.5f))) <= 0.0f;
        } else {
            const eye_model *e = &h.eye[r == GS_SYNTH_REGION_RIGHT_EYE ? 0 : 1];
            worst_eye = fmax(worst_eye, fabs(gs_synth_eyeball_sdf(e, pv)));
            CHECK(e->side == (r == GS_SYNTH_REGION_RIGHT_EYE ? 0 : 1));
        }
        for (int c = 0; c < 3; c++)
            CHECK(t.rgb[3 * i + c] >= 0.0f && t.rgb[3 * i + c] <= 1.0f);
    }
    printf("template: %d points (head %d, face %d, left eye %d, right eye %d)\n",
           t.n, count[0], count[1], count[2], count[3]);
    CHECK(count[0] > 1000 && count[1] > 1000 && count[2] > 50 && count[3] > 50);
    CHECK(abs(count[2] - count[3]) <= 2);
    CHECK_MSG(worst_surface < 5e-3, "head points off the surface by %.4f mm", worst_surface);
    CHECK_MSG(worst_eye < 1e-3, "eye points off the eyeball by %.4f mm", worst_eye);
    CHECK_MSG(worst_normal < 1e-5, "normals not unit: %.3g", worst_normal);
    CHECK_MSG(outward_bad <= t.n / 1000, "%d normals point inward", outward_bad);
    /* Landmarks match the labels of the mean head seen frontally. */
    gs_synth_scene s;
    gs_synth_scene_default(&s, 600);
    gs_synth_camera cam;
    gs_synth_camera_single(64, 600, 260, &cam);
    gs_synth_labels l;
    CHECK(gs_synth_labels_compute(&s, &cam, &l, NULL) == GS_OK);
    double worst_lm = 0;
    for (int i = 0; i < 68; i++)
        for (int a = 0; a < 3; a++)
            worst_lm = fmax(worst_lm, fabs(t.landmarks[i][a] - l.lm3d_head[i][a]));
    CHECK_MSG(worst_lm == 0.0, "template landmarks differ from labels by %.3g", worst_lm);
    /* Eye centres: right eye at -x. */
    CHECK(t.eye_centre[0][0] < -20 && t.eye_centre[1][0] > 20);
    CHECK_CLOSE(t.eyeball_radius_mm, 12.0, 1e-6, 0);
    gs_synth_template_free(&t);
    CHECK(t.xyz == NULL && t.n == 0);
    GS_TEST_END();
}
