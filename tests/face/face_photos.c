#define _POSIX_C_SOURCE 200809L
#include "face_photos.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

const char *photo_path(const char *name, char *buf, size_t cap)
{
    if (!strcmp(name, "astronaut") || !strcmp(name, "camera"))
        snprintf(buf, cap, "%s/%s.png", GS_SKIMAGE_DATA, name);
    else
        snprintf(buf, cap, "%s/%s.jpg", GS_FACE_ASSETS, name);
    return access(buf, R_OK) == 0 ? buf : NULL;
}

int photo_load(const char *name, gs_io_image *img)
{
    char path[1024];
    if (!photo_path(name, path, sizeof path)) {
        printf("SKIP: test photo %s missing (run scripts/fetch-test-assets.sh)\n", path);
        return GS_TEST_SKIP;
    }
    gs_error err;
    if (gs_io_image_read(path, NULL, img, &err) != GS_OK) {
        fprintf(stderr, "%s: %s\n", path, err.msg);
        return 1;
    }
    return 0;
}

const gs_face_shape_model *photo_shape_model(void)
{
    static gs_face_shape_model *model;
    static int tried;
    if (!tried) {
        gs_error err;
        tried = 1;
        if (gs_face_shape_model_load(NULL, &model, &err) != GS_OK)
            fprintf(stderr, "shape model: %s\n", err.msg);
    }
    return model;
}

static int write_ppm(const char *path, const gs_io_image *img)
{
    FILE *f = fopen(path, "wb");
    if (!f)
        return -1;
    fprintf(f, "P6\n%d %d\n255\n", img->width, img->height);
    for (int y = 0; y < img->height; y++)
        fwrite(img->data + (size_t)y * img->stride, 3, (size_t)img->width, f);
    return fclose(f) ? -1 : 0;
}

static int temp_ppm(const gs_io_image *img, char *ppm, size_t cap)
{
    snprintf(ppm, cap, "/tmp/gs_face_ref_XXXXXX");
    int fd = mkstemp(ppm);
    if (fd < 0)
        return -1;
    close(fd);
    if (write_ppm(ppm, img)) {
        unlink(ppm);
        return -1;
    }
    return 0;
}

int dlib_landmarks(const char *dlib_ref, const gs_io_image *imgs, int n_img, const int *n,
                   const gs_face_box *boxes, int *pts)
{
    enum { MAXI = 16 };
    char ppm[MAXI][64];
    size_t cap = 1 << 16, len = 0;
    char *cmd = malloc(cap);
    int total = 0, made = 0, rc = -1;
    if (!cmd || n_img > MAXI)
        goto done;
    len = (size_t)snprintf(cmd, cap, "'%s' landmarks '%s'", dlib_ref, GS_FACE_SHAPE_MODEL_DEFAULT);
    for (int i = 0; i < n_img; i++, made++) {
        if (temp_ppm(&imgs[i], ppm[i], sizeof ppm[i]))
            goto done;
        len += (size_t)snprintf(cmd + len, cap - len, " '%s' %d", ppm[i], n[i]);
        for (int b = 0; b < n[i] && len < cap - 64; b++, total++)
            len += (size_t)snprintf(cmd + len, cap - len, " %d %d %d %d", boxes[total].left,
                                    boxes[total].top, boxes[total].right, boxes[total].bottom);
    }
    FILE *p = popen(cmd, "r");
    if (!p)
        goto done;
    int got = 0;
    while (got < total * 2 * GS_FACE_LANDMARKS && fscanf(p, "%d %d", &pts[got], &pts[got + 1]) == 2)
        got += 2;
    rc = pclose(p) == 0 && got == total * 2 * GS_FACE_LANDMARKS ? 0 : -1;
done:
    for (int i = 0; i < made; i++)
        unlink(ppm[i]);
    free(cmd);
    return rc;
}

int dlib_hog(const char *dlib_ref, const gs_io_image *img, gs_face_box *boxes, int cap)
{
    char ppm[64], cmd[1200];
    if (temp_ppm(img, ppm, sizeof ppm))
        return -1;
    snprintf(cmd, sizeof cmd, "'%s' hog '%s' 1", dlib_ref, ppm);
    FILE *p = popen(cmd, "r");
    if (!p) {
        unlink(ppm);
        return -1;
    }
    int n = 0;
    gs_face_box b;
    while (fscanf(p, "%d %d %d %d", &b.left, &b.top, &b.right, &b.bottom) == 4) {
        if (n < cap)
            boxes[n] = b;
        n++;
    }
    int rc = pclose(p);
    unlink(ppm);
    return rc == 0 ? n : -1;
}
