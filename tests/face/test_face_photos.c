/* The pipeline on real photos: face counts of the cascade, plausible head
 * poses, normalize -> denormalize round trip, paste-back, masks, and the
 * clear errors (no face, tiny face, landmarks off the image). */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "face_photos.h"
#include "gs_test.h"

#define DEG 57.29577951308232

static const gs_face_shape_model *sp;
static gs_face_detector *det;

/* PSNR over the pixels where mask > 127. */
static double psnr_masked(const gs_io_image *a, const gs_io_image *b, const uint8_t *mask)
{
    double se = 0;
    size_t n = 0;
    for (int y = 0; y < a->height; y++)
        for (int x = 0; x < a->width; x++) {
            if (mask[(size_t)y * a->width + x] <= 127)
                continue;
            for (int c = 0; c < 3; c++) {
                double d = (double)a->data[(size_t)y * a->stride + 3 * x + c] -
                           b->data[(size_t)y * b->stride + 3 * x + c];
                se += d * d;
            }
            n += 3;
        }
    return n ? 10 * log10(255.0 * 255.0 / (se / (double)n + 1e-12)) : 0;
}

/* Faces the cascade finds (min_neighbors 5, alt2); dlib's HOG detector
 * (one upsampling) finds 2, 4, 1, 3, 3, 5, 4 (docs/face.md). */
static void counts(void)
{
    static const char *const names[] = {"astronaut", "sample1", "sample2", "sample3",
                                        "sample4",   "sample5", "sample6"};
    static const int want[] = {1, 2, 1, 3, 1, 5, 4};
    for (int i = 0; i < 7; i++) {
        gs_io_image img;
        if (photo_load(names[i], &img))
            continue;
        gs_face_detection d[16];
        int n = -1;
        gs_error err;
        CHECK_MSG(gs_face_detect(det, &img, NULL, d, 16, &n, &err) == GS_OK, "%s", err.msg);
        CHECK_MSG(n == want[i], "%s: %d faces, want %d", names[i], n, want[i]);
        for (int k = 1; k < n && k < 16; k++)
            CHECK(d[k].cascade.right - d[k].cascade.left <=
                  d[k - 1].cascade.right - d[k - 1].cascade.left);
        gs_io_image_free(&img);
    }
}

/* Pose on astronaut, round trip, paste-back, masks. */
static void astronaut(const gs_io_image *img)
{
    gs_face_result r;
    gs_error err;
    CHECK_MSG(gs_face_analyze(det, sp, img, NULL, &r, &err) == GS_OK, "%s", err.msg);
    CHECK_EQ_INT(r.n_faces, 1);
    printf("astronaut: box %d,%d,%d,%d head pitch %.2f yaw %.2f deg, centre (%.1f, %.1f, %.1f) "
           "mm, reprojection %.2f px\n", r.box.left, r.box.top, r.box.right, r.box.bottom,
           r.pose.pitch * DEG, r.pose.yaw * DEG, r.pose.t[0], r.pose.t[1], r.pose.t[2],
           r.pose.rms_px);
    CHECK(fabs(r.pose.pitch * DEG) < 30 && fabs(r.pose.yaw * DEG) < 30);
    CHECK(r.pose.t[2] > 300 && r.pose.t[2] < 1500);
    CHECK(r.pose.rms_px < 5);
    /* The face centre lands on the normalized image centre. */
    double c_uv[2], c_n[2];
    CHECK(gs_geom_project(r.k, r.pose.t, c_uv) == GS_OK);
    gs_geom_norm_pixel(&r.norm, c_uv, c_n);
    CHECK_CLOSE(c_n[0], 256, 1e-6, 0);
    CHECK_CLOSE(c_n[1], 256, 1e-6, 0);
    /* The eyes sit left and right of the centre, above it. */
    CHECK(r.uv_n[36][0] < 256 && r.uv_n[45][0] > 256 && r.uv_n[36][1] < 256);

    gs_io_image norm, back;
    CHECK_MSG(gs_face_normalize_image(img, &r.norm, &norm, &err) == GS_OK, "%s", err.msg);
    CHECK_MSG(gs_face_denormalize_image(&norm, &r.norm, img->width, img->height, &back, &err) ==
                  GS_OK, "%s", err.msg);
    uint8_t *face = malloc((size_t)img->width * img->height);
    CHECK(gs_face_mask((const double(*)[2])r.uv, GS_FACE_MASK_FACE, 0, 0, img->width,
                       img->height, face, &err) == GS_OK);
    double p = psnr_masked(img, &back, face);
    printf("normalize -> denormalize round trip: %.2f dB on the face\n", p);
    CHECK_MSG(p >= 35, "round trip %.2f dB < 35", p);

    /* Paste-back of the unmodified normalized face changes little; of a
     * flat grey face through the eye mask, only the eyes. */
    gs_io_image photo = {img->width, img->height, img->stride, malloc(img->stride * img->height)};
    memcpy(photo.data, img->data, img->stride * img->height);
    CHECK(gs_face_paste_back(&photo, &norm, &r.norm, face, &err) == GS_OK);
    p = psnr_masked(img, &photo, face);
    printf("paste-back of the unmodified face: %.2f dB\n", p);
    CHECK(p >= 35);
    uint8_t *eyes = malloc((size_t)img->width * img->height);
    CHECK(gs_face_mask((const double(*)[2])r.uv, GS_FACE_MASK_EYES, 2, 4, img->width,
                       img->height, eyes, &err) == GS_OK);
    memset(norm.data, 128, norm.stride * norm.height);
    memcpy(photo.data, img->data, img->stride * img->height);
    CHECK(gs_face_paste_back(&photo, &norm, &r.norm, eyes, &err) == GS_OK);
    size_t changed_out = 0, grey_in = 0, eye_px = 0;
    for (size_t i = 0; i < (size_t)img->width * img->height; i++) {
        int diff = memcmp(photo.data + 3 * i, img->data + 3 * i, 3) != 0;
        if (eyes[i] == 0)
            changed_out += diff;
        if (eyes[i] == 255) {
            eye_px++;
            grey_in += photo.data[3 * i] == 128 && photo.data[3 * i + 1] == 128;
        }
    }
    CHECK_EQ_INT(changed_out, 0);
    CHECK(eye_px > 100 && grey_in == eye_px);

    /* Masks: eyes inside the face; the face without eyes excludes them. */
    uint8_t *no_eyes = malloc((size_t)img->width * img->height);
    CHECK(gs_face_mask((const double(*)[2])r.uv, GS_FACE_MASK_FACE_NO_EYES, 0, 0, img->width,
                       img->height, no_eyes, &err) == GS_OK);
    size_t face_px = 0, eyes_outside = 0;
    for (size_t i = 0; i < (size_t)img->width * img->height; i++) {
        face_px += face[i] == 255;
        eyes_outside += eyes[i] == 255 && face[i] == 0;
    }
    int c37x = (int)((r.uv[37][0] + r.uv[40][0]) / 2), c37y = (int)((r.uv[37][1] + r.uv[40][1]) / 2);
    CHECK(no_eyes[(size_t)c37y * img->width + c37x] == 0);
    CHECK(face[(size_t)c37y * img->width + c37x] == 255);
    CHECK(face_px > 5000 && face_px < 20000);
    CHECK(eyes_outside < 50);
    CHECK(gs_face_mask((const double(*)[2])r.uv, (gs_face_mask_kind)9, 0, 0, img->width,
                       img->height, face, &err) == GS_ERR_ARG);
    free(face);
    free(eyes);
    free(no_eyes);
    free(photo.data);
    gs_io_image_free(&norm);
    gs_io_image_free(&back);
}

static void errors(const gs_io_image *img)
{
    gs_face_result r;
    gs_error err;
    gs_face_opts o;
    /* No face: skimage's camera.png. */
    gs_io_image cam;
    if (photo_load("camera", &cam) == 0) {
        CHECK(gs_face_analyze(det, sp, &cam, NULL, &r, &err) == GS_ERR_ARG);
        printf("camera.png: %s\n", err.msg);
        CHECK(strstr(err.msg, "no face") != NULL);
        gs_io_image_free(&cam);
    }
    /* Index past the faces. */
    gs_face_opts_default(&o);
    o.index = 1;
    CHECK(gs_face_analyze(det, sp, img, &o, &r, &err) == GS_ERR_ARG);
    CHECK(strstr(err.msg, "index 1") != NULL);
    /* Tiny face: the astronaut shrunk 8x (a 11 px face). */
    gs_io_image small = {64, 64, 192, malloc(64 * 64 * 3)};
    for (int y = 0; y < 64; y++)
        for (int x = 0; x < 64; x++)
            memcpy(small.data + y * 192 + 3 * x, img->data + (size_t)(8 * y) * img->stride + 24 * x,
                   3);
    int rc = gs_face_analyze(det, sp, &small, NULL, &r, &err);
    CHECK(rc == GS_ERR_ARG);
    printf("tiny face: %s\n", err.msg);
    o.index = 0;
    o.use_box = 1;
    o.box = (gs_face_box){22, 10, 33, 21};
    CHECK(gs_face_analyze(NULL, sp, &small, &o, &r, &err) == GS_ERR_ARG);
    printf("tiny box: %s\n", err.msg);
    CHECK(strstr(err.msg, "too small") != NULL);
    free(small.data);
    /* Landmarks off the image: the face box on the top-left quarter crop,
     * which cuts the face through the middle. */
    gs_io_image crop = {224, 130, img->stride, img->data};
    o.box = (gs_face_box){179, 83, 266, 170};
    CHECK(gs_face_analyze(NULL, sp, &crop, &o, &r, &err) == GS_ERR_ARG);
    printf("cut face: %s\n", err.msg);
    CHECK(strstr(err.msg, "outside the") != NULL);
    /* Empty image, bad intrinsics. */
    gs_io_image empty = {0, 0, 0, NULL};
    CHECK(gs_face_analyze(det, sp, &empty, NULL, &r, &err) == GS_ERR_ARG);
    o.box = (gs_face_box){179, 83, 266, 170};
    o.use_k = 1;
    memset(o.k, 0, sizeof o.k);
    CHECK(gs_face_analyze(NULL, sp, img, &o, &r, &err) == GS_ERR_ARG);
}

int main(void)
{
    gs_io_image img;
    int rc = photo_load("astronaut", &img);
    if (rc)
        return rc;
    gs_error err;
    sp = photo_shape_model();
    CHECK(sp != NULL);
    CHECK_MSG(gs_face_detector_load(NULL, &det, &err) == GS_OK, "%s", err.msg);
    gs_face_detector *bad = NULL;
    CHECK(gs_face_detector_load("/nonexistent.xml", &bad, &err) == GS_ERR_IO && !bad);
    if (sp && det) {
        counts();
        astronaut(&img);
        errors(&img);
    }
    gs_face_detector_destroy(det);
    gs_io_image_free(&img);
    GS_TEST_END();
}
