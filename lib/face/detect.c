/* Face boxes: an OpenCV cascade, boxes mapped to dlib's HOG convention,
 * largest first. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>

#include "cv_face_shim.h"
#include "face_internal.h"

struct gs_face_detector {
    gs_cvf_cascade *cascade;
};

int gs_face_detector_load(const char *path, gs_face_detector **out, gs_error *err)
{
    if (!out)
        return gs_error_set(err, GS_ERR_ARG, "face detector: NULL output");
    if (!path)
        path = GS_FACE_CASCADE_DEFAULT;
    /* Checked here: OpenCV would print its own complaint. */
    FILE *f = fopen(path, "rb");
    if (!f)
        return gs_error_set(err, GS_ERR_IO, "face detector: cannot open cascade %.200s", path);
    fclose(f);
    gs_face_detector *d = calloc(1, sizeof *d);
    if (!d)
        return gs_error_set(err, GS_ERR_NOMEM, "face detector: out of memory");
    int rc = gs_cvf_cascade_load(path, &d->cascade, err);
    if (rc) {
        free(d);
        return rc;
    }
    *out = d;
    return GS_OK;
}

void gs_face_detector_destroy(gs_face_detector *d)
{
    if (!d)
        return;
    gs_cvf_cascade_free(d->cascade);
    free(d);
}

void gs_face_detect_opts_default(gs_face_detect_opts *o)
{
    o->scale_factor = 1.1;
    o->min_neighbors = 5;
    o->min_size = 0;
}

gs_face_box gs_face_box_from_cascade(int x, int y, int w, int h)
{
    /* Centres in pixel-index units (a box of pixels x..x+w-1). */
    double cx = x + (w - 1) * 0.5 + GS_FACE_BOX_DX * w;
    double cy = y + (h - 1) * 0.5 + GS_FACE_BOX_DY * w;
    int side = (int)lround(GS_FACE_BOX_SCALE * w);
    if (side < 1)
        side = 1;
    gs_face_box b;
    b.left = (int)lround(cx - (side - 1) * 0.5);
    b.top = (int)lround(cy - (side - 1) * 0.5);
    b.right = b.left + side - 1;
    b.bottom = b.top + side - 1;
    return b;
}

/* Largest first; equal sizes top to bottom, then left to right. */
static int by_size(const void *pa, const void *pb)
{
    const gs_face_detection *a = pa, *b = pb;
    int wa = a->cascade.right - a->cascade.left, wb = b->cascade.right - b->cascade.left;
    if (wa != wb)
        return wa > wb ? -1 : 1;
    if (a->cascade.top != b->cascade.top)
        return a->cascade.top < b->cascade.top ? -1 : 1;
    return (a->cascade.left > b->cascade.left) - (a->cascade.left < b->cascade.left);
}

int gs_face_detect(gs_face_detector *d, const gs_io_image *img, const gs_face_detect_opts *opts,
                   gs_face_detection *out, int cap, int *n, gs_error *err)
{
    gs_face_detect_opts def;
    if (!opts) {
        gs_face_detect_opts_default(&def);
        opts = &def;
    }
    if (!d || !img || !img->data || img->width < 1 || img->height < 1 || !n || cap < 0 ||
        (cap > 0 && !out))
        return gs_error_set(err, GS_ERR_ARG, "face detector: bad arguments");
    if (!(opts->scale_factor > 1.0 && opts->scale_factor < 4.0) || opts->min_neighbors < 0 ||
        (opts->min_size != 0 && opts->min_size < 8))
        return gs_error_set(err, GS_ERR_ARG,
                            "face detector: options out of range (scale %g, neighbours %d, "
                            "min size %d)", opts->scale_factor, opts->min_neighbors,
                            opts->min_size);
    int min_size = opts->min_size;
    if (min_size == 0) {
        int shorter = img->width < img->height ? img->width : img->height;
        min_size = shorter / 16 > 24 ? shorter / 16 : 24;
    }
    int *r = NULL, nr = 0;
    int rc = gs_cvf_detect(d->cascade, img, opts->scale_factor, opts->min_neighbors, min_size,
                           &r, &nr, err);
    if (rc)
        return rc;
    gs_face_detection *all = nr ? malloc((size_t)nr * sizeof *all) : NULL;
    if (nr && !all) {
        free(r);
        return gs_error_set(err, GS_ERR_NOMEM, "face detector: out of memory");
    }
    for (int i = 0; i < nr; i++) {
        const int *q = r + 4 * i;
        all[i].cascade = (gs_face_box){q[0], q[1], q[0] + q[2] - 1, q[1] + q[3] - 1};
        all[i].box = gs_face_box_from_cascade(q[0], q[1], q[2], q[3]);
    }
    free(r);
    if (nr > 1)
        qsort(all, (size_t)nr, sizeof *all, by_size);
    for (int i = 0; i < nr && i < cap; i++)
        out[i] = all[i];
    free(all);
    *n = nr;
    return GS_OK;
}
