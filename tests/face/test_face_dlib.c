/* Landmarks identical to dlib's: all 68 points of our predictor against
 * dlib::shape_predictor (tests/face/dlib_ref.cpp, Debian's libdlib) for the
 * same boxes, on astronaut.png and the face-api demo photos with the boxes
 * of our detector. */
#include <stdio.h>
#include <string.h>

#include "face_photos.h"
#include "gs_test.h"

static int compare(const char *dlib_ref, const char *name, const gs_io_image *img,
                   const gs_face_box *boxes, int n)
{
    const gs_face_shape_model *sp = photo_shape_model();
    static int ours[16][2 * GS_FACE_LANDMARKS], ref[16][2 * GS_FACE_LANDMARKS];
    CHECK(sp != NULL);
    if (!sp)
        return 0;
    if (n > 16)
        n = 16;
    gs_error err;
    for (int i = 0; i < n; i++)
        CHECK_MSG(gs_face_shape_predict(sp, img, boxes[i], ours[i], NULL, &err) == GS_OK, "%s",
                  err.msg);
    CHECK_MSG(dlib_landmarks(dlib_ref, img, boxes, n, &ref[0][0]) == 0, "dlib_ref failed on %s",
              name);
    int same = 0;
    for (int i = 0; i < n; i++) {
        int bad = 0;
        for (int k = 0; k < GS_FACE_LANDMARKS; k++) {
            int dx = ours[i][2 * k] - ref[i][2 * k], dy = ours[i][2 * k + 1] - ref[i][2 * k + 1];
            if (dx || dy) {
                if (bad++ < 3)
                    fprintf(stderr, "  %s face %d point %d: ours (%d,%d) dlib (%d,%d)\n", name, i,
                            k, ours[i][2 * k], ours[i][2 * k + 1], ref[i][2 * k],
                            ref[i][2 * k + 1]);
            }
        }
        CHECK_MSG(bad == 0, "%s face %d box (%d,%d,%d,%d): %d of 68 points differ", name, i,
                  boxes[i].left, boxes[i].top, boxes[i].right, boxes[i].bottom, bad);
        same += bad == 0;
    }
    printf("%s: %d of %d faces identical to dlib (68 points each)\n", name, same, n);
    return n;
}

int main(int argc, char **argv)
{
    if (argc < 2) {
        fprintf(stderr, "usage: test_face_dlib DLIB_REF\n");
        return 2;
    }
    gs_io_image img;
    int rc = photo_load("astronaut", &img);
    if (rc)
        return rc;
    /* A fixed box (dlib's HOG box of this photo) and shifted variants. */
    const gs_face_box fixed[4] = {
        {179, 83, 266, 170}, {170, 80, 270, 180}, {185, 90, 255, 160}, {-20, -20, 400, 400}};
    compare(argv[1], "astronaut", &img, fixed, 4);
    gs_io_image_free(&img);
    GS_TEST_END();
}
