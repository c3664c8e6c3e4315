/* Landmarks identical to dlib's: all 68 points of our predictor against
 * dlib::shape_predictor (tests/face/dlib_ref.cpp, Debian's libdlib) for the
 * same boxes: astronaut.png with fixed boxes (dlib's HOG box, shifted and
 * scaled ones, one past the image borders) and every face our detector
 * finds in astronaut.png and the face-api demo photos. */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "face_photos.h"
#include "gs_test.h"

#define MAX_BOXES 64

static const char *const names[] = {"astronaut", "sample1", "sample2", "sample3",
                                    "sample4",   "sample5", "sample6"};
#define N_PHOTOS 7

int main(int argc, char **argv)
{
    if (argc < 2) {
        fprintf(stderr, "usage: test_face_dlib DLIB_REF\n");
        return 2;
    }
    gs_io_image img[N_PHOTOS + 1];
    for (int i = 0; i < N_PHOTOS; i++) {
        int rc = photo_load(names[i], &img[i + 1]);
        if (rc)
            return rc;
    }
    img[0] = img[1]; /* astronaut twice: fixed boxes, then detected ones */
    const gs_face_shape_model *sp = photo_shape_model();
    gs_face_detector *det = NULL;
    gs_error err;
    CHECK(sp != NULL);
    CHECK_MSG(gs_face_detector_load(NULL, &det, &err) == GS_OK, "%s", err.msg);
    if (!sp || !det)
        GS_TEST_END();
    static gs_face_box boxes[MAX_BOXES];
    static int ours[MAX_BOXES][2 * GS_FACE_LANDMARKS], ref[MAX_BOXES][2 * GS_FACE_LANDMARKS];
    int counts[N_PHOTOS + 1], total = 4;
    const gs_face_box fixed[4] = {
        {179, 83, 266, 170}, {170, 80, 270, 180}, {185, 90, 255, 160}, {-20, -20, 400, 400}};
    memcpy(boxes, fixed, sizeof fixed);
    counts[0] = 4;
    for (int i = 1; i <= N_PHOTOS; i++) {
        gs_face_detection d[16];
        int n = 0;
        CHECK_MSG(gs_face_detect(det, &img[i], NULL, d, 16, &n, &err) == GS_OK, "%s", err.msg);
        counts[i] = n < 16 ? n : 16;
        for (int k = 0; k < counts[i] && total < MAX_BOXES; k++)
            boxes[total++] = d[k].box;
    }
    int b = 0;
    for (int i = 0; i <= N_PHOTOS; i++)
        for (int k = 0; k < counts[i]; k++, b++)
            CHECK_MSG(gs_face_shape_predict(sp, &img[i], boxes[b], ours[b], NULL, &err) == GS_OK,
                      "%s", err.msg);
    CHECK_MSG(dlib_landmarks(argv[1], img, N_PHOTOS + 1, counts, boxes, &ref[0][0]) == 0,
              "dlib_ref failed");
    int same = 0;
    for (b = 0; b < total; b++) {
        int bad = 0;
        for (int k = 0; k < 2 * GS_FACE_LANDMARKS; k += 2)
            if (ours[b][k] != ref[b][k] || ours[b][k + 1] != ref[b][k + 1]) {
                if (bad++ < 3)
                    fprintf(stderr, "  face %d point %d: ours (%d,%d) dlib (%d,%d)\n", b, k / 2,
                            ours[b][k], ours[b][k + 1], ref[b][k], ref[b][k + 1]);
            }
        CHECK_MSG(bad == 0, "face %d box (%d,%d,%d,%d): %d of 68 points differ", b,
                  boxes[b].left, boxes[b].top, boxes[b].right, boxes[b].bottom, bad);
        same += bad == 0;
    }
    printf("%d of %d faces (%d photos) identical to dlib, all 68 points\n", same, total,
           N_PHOTOS);
    gs_face_detector_destroy(det);
    for (int i = 1; i <= N_PHOTOS; i++)
        gs_io_image_free(&img[i]);
    GS_TEST_END();
}
