/* Lab: can the iris localizer tell closed eyes from open ones where the
 * landmark model draws an open contour on a closed eye (sample2 of the
 * test photos: its contours read 0.19 and 0.23, over the gate's 0.13)?
 * Synthetic test-split heads at the 256 px normalized camera: each scene
 * open (blink 0) and closed (blink 1), both searched inside the open
 * scene's exact contours. Per face: whether either eye is located (status
 * OK) and the larger of the two eyes' sclera-iris contrast (NaN: no fit).
 *
 * Built like lid_measure.c (experiments/photos/README.md); closed_eyes [N]. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "gazesplat/face.h"
#include "gazesplat/synth.h"

#define DEG (3.14159265358979323846 / 180.0)
#define S 256

static int render(gs_synth_scene *sc, gs_synth_sample *smp)
{
    gs_synth_camera base, cam;
    gs_error err = {0, ""};
    gs_synth_camera_single(S, 650, 300, &base);
    int rc = gs_synth_camera_normalized(sc, &base, S, 0, 0, &cam, &err);
    if (!rc)
        rc = gs_synth_render(sc, &cam, NULL, NULL, smp, &err);
    if (rc)
        fprintf(stderr, "render: %s\n", err.msg);
    return rc;
}

int main(int argc, char **argv)
{
    int n = argc > 1 ? atoi(argv[1]) : 100;
    gs_synth_ranges rg;
    gs_synth_ranges_default(&rg);
    rg.head_yaw = 30 * DEG;
    rg.head_pitch = 20 * DEG;
    rg.blink_prob = 0;
    gs_synth_sample a = {0};
    gs_error err = {0, ""};
    if (gs_synth_sample_alloc(&a, S, S, &err))
        return 1;
    gs_face_iris_opts io;
    gs_face_iris_opts_default(&io);
    gs_face_iris_opts_scale(&io, 800.0 / 680.0);
    const double T[] = {10, 12, 15, 18, 20, 25};
    int none[2] = {0, 0}, below[2][6] = {{0}}, nofit[2] = {0, 0};
    for (int k = 0; k < n; k++) {
        gs_synth_scene sc;
        gs_synth_scene_random(gs_synth_split_seed(GS_SYNTH_TEST, (uint64_t)k), (uint64_t)k, &rg, &sc);
        sc.expr.blink = 0;
        if (render(&sc, &a))
            return 1;
        double uv[68][2];
        memcpy(uv, a.labels.lm2d, sizeof uv);
        for (int closed = 0; closed < 2; closed++) {
            if (closed) {
                sc.expr.blink = 1;
                if (render(&sc, &a))
                    return 1;
            }
            gs_io_image im = {S, S, a.stride, a.rgb};
            int ok = 0;
            double cmax = -INFINITY;
            for (int e = 0; e < 2; e++) {
                gs_face_iris r;
                if (gs_face_iris_locate(&im, (const double(*)[2])uv[36 + 6 * e], &io, &r, &err))
                    return 1;
                ok |= r.status == GS_FACE_IRIS_OK;
                if (isfinite(r.contrast) && r.contrast > cmax)
                    cmax = r.contrast;
            }
            if (!ok) {
                none[closed]++;
                nofit[closed] += !isfinite(cmax);
                for (int t = 0; t < 6; t++)
                    below[closed][t] += isfinite(cmax) && cmax < T[t];
            }
        }
    }
    printf("%d synthetic faces, searched inside the open eyes' exact contours\n", n);
    for (int closed = 0; closed < 2; closed++) {
        printf("%s: no eye located on %d; of those, no fit in either eye %d, the larger fitted "
               "contrast under", closed ? "closed" : "open  ", none[closed], nofit[closed]);
        for (int t = 0; t < 6; t++)
            printf(" %g: %d", T[t], below[closed][t]);
        printf("\n");
    }
    return 0;
}
