/* The 6-point face model of the mean synthetic head shipped in lib/geom
 * (gs_geom_face_model6_synth) equals the landmarks of the neutral template
 * it was generated from (`gazesplat synth --face-model6`): rebuilt here, so
 * a change of the head model that moves them fails until the numbers are
 * regenerated. */
#include <math.h>
#include <stdio.h>

#include "gazesplat/geom.h"
#include "gazesplat/synth.h"
#include "gs_test.h"

int main(void)
{
    static const int ibug[6] = {36, 39, 42, 45, 31, 35};
    gs_synth_template t;
    gs_error err = {0, ""};
    CHECK_MSG(gs_synth_template_build(20.0, NULL, &t, &err) == GS_OK, "%s", err.msg);
    double m[6][3], c[3], worst = 0;
    gs_geom_face_model6_synth(m);
    for (int i = 0; i < 6; i++)
        for (int j = 0; j < 3; j++) {
            double d = fabs(m[i][j] - t.landmarks[ibug[i]][j]);
            worst = fmax(worst, d);
            /* The shipped numbers are rounded to 1e-4 mm. */
            CHECK_MSG(d <= 1e-4, "point %d (iBUG %d) axis %d: shipped %.4f, template %.6f; "
                      "regenerate with `gazesplat synth --face-model6`", i, ibug[i], j,
                      m[i][j], t.landmarks[ibug[i]][j]);
        }
    static const int nose[7] = {27, 28, 29, 30, 32, 33, 34};
    double n7[7][3];
    gs_geom_face_nose7_synth(n7);
    for (int i = 0; i < 7; i++)
        for (int j = 0; j < 3; j++) {
            double d = fabs(n7[i][j] - t.landmarks[nose[i]][j]);
            worst = fmax(worst, d);
            CHECK_MSG(d <= 1e-4, "nose point %d (iBUG %d) axis %d: shipped %.4f, template %.6f; "
                      "regenerate with `gazesplat synth --face-model6`", i, nose[i], j,
                      n7[i][j], t.landmarks[nose[i]][j]);
        }
    /* The nose tip stands out toward the camera (-z) of the eye corners. */
    CHECK(n7[3][2] < m[1][2] - 20 && n7[3][2] < m[4][2]);
    /* The head frame's origin is the face centre of these very points. */
    gs_geom_face_centre6((const double(*)[3])m, c);
    CHECK_MSG(gs_geom_vec3_norm(c) < 1e-3, "face centre of the model %.5f mm from the origin",
              gs_geom_vec3_norm(c));
    /* Plausible: right eye at -x, outer corners lateral and deeper than
     * the inner ones, nose wings below the eyes (y down). */
    CHECK(m[0][0] < m[1][0] && m[1][0] < 0 && m[2][0] > 0 && m[3][0] > m[2][0]);
    CHECK(m[0][2] > m[1][2] && m[3][2] > m[2][2]);
    CHECK(m[4][1] > m[0][1] && m[5][1] > m[3][1]);
    printf("face model (synth): template landmarks match within %.2g mm\n", worst);
    gs_synth_template_free(&t);
    GS_TEST_END();
}
