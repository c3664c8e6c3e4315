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

/* Runs dlib_ref with `args` on a temporary PPM of img; returns the
 * process's stdout as a stream (caller pcloses) or NULL. */
static FILE *run_ref(const char *dlib_ref, const gs_io_image *img, const char *mode,
                     const char *args, char *ppm, size_t cap)
{
    snprintf(ppm, cap, "/tmp/gs_face_ref_XXXXXX");
    int fd = mkstemp(ppm);
    if (fd < 0)
        return NULL;
    close(fd);
    if (write_ppm(ppm, img)) {
        unlink(ppm);
        return NULL;
    }
    size_t n = strlen(dlib_ref) + strlen(ppm) + strlen(args) + strlen(mode) + 64;
    char *cmd = malloc(n);
    if (!cmd)
        return NULL;
    if (!strcmp(mode, "hog"))
        snprintf(cmd, n, "'%s' hog '%s' %s", dlib_ref, ppm, args);
    else
        snprintf(cmd, n, "'%s' landmarks '%s' '%s' %s", dlib_ref, GS_FACE_SHAPE_MODEL_DEFAULT,
                 ppm, args);
    FILE *p = popen(cmd, "r");
    free(cmd);
    return p;
}

int dlib_landmarks(const char *dlib_ref, const gs_io_image *img, const gs_face_box *boxes,
                   int n, int *pts)
{
    char args[4096] = "", ppm[64];
    size_t len = 0;
    for (int i = 0; i < n && len < sizeof args - 64; i++)
        len += (size_t)snprintf(args + len, sizeof args - len, " %d %d %d %d", boxes[i].left,
                                boxes[i].top, boxes[i].right, boxes[i].bottom);
    FILE *p = run_ref(dlib_ref, img, "landmarks", args, ppm, sizeof ppm);
    if (!p)
        return -1;
    int got = 0;
    while (got < n * 2 * GS_FACE_LANDMARKS &&
           fscanf(p, "%d %d", &pts[got], &pts[got + 1]) == 2)
        got += 2;
    int rc = pclose(p);
    unlink(ppm);
    return rc == 0 && got == n * 2 * GS_FACE_LANDMARKS ? 0 : -1;
}

int dlib_hog(const char *dlib_ref, const gs_io_image *img, gs_face_box *boxes, int cap)
{
    char ppm[64];
    FILE *p = run_ref(dlib_ref, img, "hog", "1", ppm, sizeof ppm);
    if (!p)
        return -1;
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
