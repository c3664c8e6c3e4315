/* The libjpeg/libpng codecs of lib/io against the OpenCV imgcodecs path
 * they replaced (cv_old.cpp), side by side in one process.
 *
 *   bench_image compare FILE...
 *       decodes each file both ways: size and the largest channel
 *       difference; encodes the decoded image both ways (PNG level 3, JPEG
 *       quality 95): whether the bytes are identical, and whether our PNG
 *       decodes back to the same pixels. Exit 1 when any pixel differs.
 *   bench_image speed JPEG [--reps N]
 *       median milliseconds of decoding JPEG and of encoding a 256x256
 *       crop of it as PNG (level 3), old and new interleaved rep by rep,
 *       and the ratio old/new.
 */
#define _POSIX_C_SOURCE 200809L

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "bench_util.h"
#include "cv_old.h"
#include "gazesplat/image_io.h"
#include "image_codec.h"

static unsigned char *slurp(const char *path, size_t *len)
{
    FILE *f = fopen(path, "rb");
    if (!f)
        return NULL;
    fseek(f, 0, SEEK_END);
    long n = ftell(f);
    fseek(f, 0, SEEK_SET);
    unsigned char *b = n > 0 ? malloc((size_t)n) : NULL;
    if (b && fread(b, 1, (size_t)n, f) != (size_t)n) {
        free(b);
        b = NULL;
    }
    fclose(f);
    *len = b ? (size_t)n : 0;
    return b;
}

static int max_diff(const gs_io_image *a, const gs_io_image *b, size_t *ndiff)
{
    int m = 0;
    *ndiff = 0;
    size_t n = (size_t)a->width * (size_t)a->height * 3;
    for (size_t i = 0; i < n; i++) {
        int d = abs((int)a->data[i] - (int)b->data[i]);
        *ndiff += d != 0;
        m = d > m ? d : m;
    }
    return m;
}

static const char *encode_cmp(const gs_io_image *img, gs_io_format fmt, int q, size_t *o,
                              size_t *n)
{
    unsigned char *a = NULL;
    void *b = NULL;
    *o = *n = 0;
    if (cvold_encode(img, fmt, q, &a, o) != 0)
        return "old failed";
    gs_error err = {0, ""};
    if (gs_io_image_encode(img, fmt, q, &b, n, &err) != GS_OK) {
        free(a);
        return "new failed";
    }
    const char *r = *o == *n && memcmp(a, b, *n) == 0 ? "identical" : "differ";
    if (fmt == GS_IO_PNG) {
        gs_io_image back;
        if (gs_io_image_decode(b, *n, NULL, &back, NULL) != GS_OK)
            r = "ours does not decode";
        else if (memcmp(back.data, img->data, img->stride * (size_t)img->height) != 0)
            r = "ours does not round-trip";
        gs_io_image_free(&back);
    }
    free(a);
    free(b);
    return r;
}

static int compare(int argc, char **argv)
{
    int bad = 0;
    for (int i = 0; i < argc; i++) {
        size_t len;
        unsigned char *buf = slurp(argv[i], &len);
        gs_io_image o = {0}, n = {0};
        gs_error err = {0, ""};
        int ro = buf ? cvold_decode(buf, len, &o) : -1;
        int rn = buf ? gs_io_image_decode(buf, len, NULL, &n, &err) : -1;
        if (ro != 0 || rn != GS_OK) {
            printf("%s: old %s, new %s%s%s\n", argv[i], ro ? "refused" : "decoded",
                   rn ? "refused: " : "decoded", rn ? err.msg : "", "");
            bad |= (ro == 0) != (rn == GS_OK);
        } else if (o.width != n.width || o.height != n.height) {
            printf("%s: old %dx%d, new %dx%d\n", argv[i], o.width, o.height, n.width, n.height);
            bad = 1;
        } else {
            size_t nd, so, sn, jo, jn;
            int m = max_diff(&o, &n, &nd);
            const char *png = encode_cmp(&n, GS_IO_PNG, 3, &so, &sn);
            const char *jpg = encode_cmp(&n, GS_IO_JPEG, 95, &jo, &jn);
            printf("%s: %dx%d max diff %d (%zu values differ); PNG-3 %s (%zu/%zu B), "
                   "JPEG-95 %s (%zu/%zu B)\n",
                   argv[i], n.width, n.height, m, nd, png, so, sn, jpg, jo, jn);
            bad |= m != 0;
        }
        gs_io_image_free(&o);
        gs_io_image_free(&n);
        free(buf);
    }
    return bad;
}

static int speed(const char *path, int reps)
{
    size_t len;
    unsigned char *buf = slurp(path, &len);
    gs_io_image img = {0};
    gs_error err = {0, ""};
    if (!buf || gs_io_image_decode(buf, len, NULL, &img, &err) != GS_OK || img.width < 256 ||
        img.height < 256) {
        fprintf(stderr, "bench_image: %s: cannot decode a JPEG of at least 256x256 (%s)\n", path,
                err.msg);
        return 2;
    }
    gs_io_image crop = {256, 256, img.stride, img.data};
    double *t = malloc(sizeof *t * 4 * (size_t)reps);
    for (int r = 0; r < reps; r++) {
        gs_io_image a = {0}, b = {0};
        double t0 = now_ms();
        cvold_decode(buf, len, &a);
        double t1 = now_ms();
        gs_jpeg_decode(buf, len, (size_t)1 << 30, 65535, &b, NULL);
        double t2 = now_ms();
        gs_io_image_free(&a);
        gs_io_image_free(&b);
        unsigned char *eo = NULL, *en = NULL;
        size_t lo, ln;
        double t3 = now_ms();
        cvold_encode(&crop, GS_IO_PNG, 3, &eo, &lo);
        double t4 = now_ms();
        gs_png_encode(&crop, 3, &en, &ln, NULL);
        double t5 = now_ms();
        free(eo);
        free(en);
        t[r] = t1 - t0;
        t[reps + r] = t2 - t1;
        t[2 * reps + r] = t4 - t3;
        t[3 * reps + r] = t5 - t4;
    }
    double dold = median(t, reps), dnew = median(t + reps, reps);
    double eold = median(t + 2 * reps, reps), enew = median(t + 3 * reps, reps);
    printf("decode %dx%d JPEG (%zu B): OpenCV %.3f ms, libjpeg %.3f ms, old/new %.2f\n",
           img.width, img.height, len, dold, dnew, dold / dnew);
    printf("encode 256x256 PNG level 3: OpenCV %.3f ms, libpng %.3f ms, old/new %.2f\n", eold,
           enew, eold / enew);
    printf("(median of %d reps, interleaved)\n", reps);
    free(t);
    gs_io_image_free(&img);
    free(buf);
    return 0;
}

int main(int argc, char **argv)
{
    if (argc >= 3 && strcmp(argv[1], "compare") == 0)
        return compare(argc - 2, argv + 2);
    if (argc >= 3 && strcmp(argv[1], "speed") == 0) {
        int reps = argc >= 5 && strcmp(argv[3], "--reps") == 0 ? atoi(argv[4]) : 50;
        return speed(argv[2], reps > 0 ? reps : 50);
    }
    fprintf(stderr, "usage: bench_image compare FILE... | speed JPEG [--reps N]\n");
    return 2;
}
