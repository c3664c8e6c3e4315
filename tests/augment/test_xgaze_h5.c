/* xgaze_h5: write, read back, the same bytes twice, and the checks. */
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "gazesplat/xgaze_h5.h"
#include "gs_test.h"

static int write_file(const char *path, size_t rows, int size)
{
    gs_h5_writer *w = NULL;
    gs_error err = {0, ""};
    size_t px = (size_t)size * size * 3;
    uint8_t *p = malloc(px * rows);
    float *g = malloc(rows * 2 * sizeof *g), *h = malloc(rows * 2 * sizeof *h);
    for (size_t i = 0; i < px * rows; i++)
        p[i] = (uint8_t)(i * 7 + i / 5);
    for (size_t i = 0; i < 2 * rows; i++) {
        g[i] = 0.01f * (float)i;
        h[i] = -0.02f * (float)i;
    }
    int rc = gs_h5_create(path, rows, size, &w, &err);
    /* Two writes, out of order. */
    if (rc == GS_OK)
        rc = gs_h5_write_rows(w, 2, rows - 2, p + 2 * px, g + 4, h + 4, &err);
    if (rc == GS_OK)
        rc = gs_h5_write_rows(w, 0, 2, p, g, h, &err);
    if (rc == GS_OK)
        rc = gs_h5_finish(w, &err);
    else
        gs_h5_abort(w);
    free(p);
    free(g);
    free(h);
    return rc;
}

static long read_all(const char *path, unsigned char **out)
{
    FILE *f = fopen(path, "rb");
    if (!f)
        return -1;
    fseek(f, 0, SEEK_END);
    long n = ftell(f);
    fseek(f, 0, SEEK_SET);
    *out = malloc((size_t)n);
    if (fread(*out, 1, (size_t)n, f) != (size_t)n)
        n = -1;
    fclose(f);
    return n;
}

int main(void)
{
    char a[64], b[64];
    snprintf(a, sizeof a, "/tmp/gs_test_h5_a_%d.h5", (int)getpid());
    snprintf(b, sizeof b, "/tmp/gs_test_h5_b_%d.h5", (int)getpid());
    CHECK(write_file(a, 5, 8) == GS_OK);
    CHECK(write_file(b, 5, 8) == GS_OK);
    unsigned char *x = NULL, *y = NULL;
    long nx = read_all(a, &x), ny = read_all(b, &y);
    CHECK(nx > 0 && nx == ny && memcmp(x, y, (size_t)nx) == 0); /* same rows, same bytes */
    free(x);
    free(y);
    gs_h5_reader *r = NULL;
    gs_h5_info info;
    gs_error err = {0, ""};
    CHECK(gs_h5_open(a, &r, &info, &err) == GS_OK);
    if (r) {
        CHECK_EQ_INT(info.rows, 5);
        CHECK_EQ_INT(info.height, 8);
        CHECK_EQ_INT(info.width, 8);
        CHECK(info.has_gaze && info.has_head);
        uint8_t patch[8 * 8 * 3];
        float g[2], h[2];
        CHECK(gs_h5_read_row(r, 3, patch, g, h, &err) == GS_OK);
        size_t px = 8 * 8 * 3, i0 = 3 * px;
        int same = 1;
        for (size_t i = 0; i < px; i++)
            same &= patch[i] == (uint8_t)((i0 + i) * 7 + (i0 + i) / 5);
        CHECK(same);
        CHECK_CLOSE(g[0], 0.06f, 1e-7, 0);
        CHECK_CLOSE(h[1], -0.14f, 1e-7, 0);
        CHECK(gs_h5_read_row(r, 5, patch, g, h, &err) == GS_ERR_ARG);
        gs_h5_close(r);
    }
    /* Not every row written: refused at finish. */
    gs_h5_writer *w = NULL;
    CHECK(gs_h5_create(b, 3, 4, &w, &err) == GS_OK);
    if (w) {
        uint8_t p[4 * 4 * 3] = {0};
        float g[2] = {0, 0};
        CHECK(gs_h5_write_rows(w, 0, 1, p, g, g, &err) == GS_OK);
        CHECK(gs_h5_write_rows(w, 2, 2, p, g, g, &err) == GS_ERR_ARG);
        CHECK(gs_h5_finish(w, &err) == GS_ERR_STATE && strstr(err.msg, "1 of 3"));
    }
    /* Not HDF5. */
    FILE *f = fopen(b, "wb");
    fputs("plain text", f);
    fclose(f);
    CHECK(gs_h5_open(b, &r, &info, &err) == GS_ERR_IO && strstr(err.msg, "cannot open"));
    CHECK(gs_h5_open("/nonexistent/x.h5", &r, &info, &err) == GS_ERR_IO);
    unlink(a);
    unlink(b);
    GS_TEST_END();
}
