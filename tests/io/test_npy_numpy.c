/* The npy code against numpy itself: files we write are what np.save
 * writes, files numpy writes (versions 1-3) read back right, and the
 * dtypes and orders we do not support are refused.
 * usage: test_npy_numpy PYTHON SCRIPT */
#define _POSIX_C_SOURCE 200809L /* mkdtemp */

#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "gazesplat/image_io.h"
#include "gs_test.h"

static char dir[] = "npy_numpy_XXXXXX";

static void path_of(char *buf, size_t cap, const char *name)
{
    snprintf(buf, cap, "%s/%s.npy", dir, name);
}

static void write_c_files(void)
{
    float f[24], scalar = 2.5f, vec[7];
    unsigned char u[60];
    size_t sf[3] = {2, 3, 4}, su[3] = {4, 5, 3}, sv[1] = {7};
    char p[256];
    for (int i = 0; i < 24; i++)
        f[i] = (float)i * 0.5f - 3.0f;
    for (int i = 0; i < 60; i++)
        u[i] = (unsigned char)(i * 7 % 256);
    for (int i = 0; i < 7; i++)
        vec[i] = (float)i;
    path_of(p, sizeof p, "c_f32");
    CHECK_EQ_INT(gs_io_npy_write(p, GS_IO_F32, 3, sf, f, NULL), GS_OK);
    path_of(p, sizeof p, "c_u8");
    CHECK_EQ_INT(gs_io_npy_write(p, GS_IO_U8, 3, su, u, NULL), GS_OK);
    path_of(p, sizeof p, "c_scalar");
    CHECK_EQ_INT(gs_io_npy_write(p, GS_IO_F32, 0, NULL, &scalar, NULL), GS_OK);
    path_of(p, sizeof p, "c_vec");
    CHECK_EQ_INT(gs_io_npy_write(p, GS_IO_F32, 1, sv, vec, NULL), GS_OK);
}

/* Reads name and checks dtype, shape and that element i == want(i). */
static void check_file(const char *name, gs_io_dtype dtype, int rank, const size_t *shape,
                       double (*want)(size_t))
{
    char p[256];
    gs_io_array a;
    gs_error err = {0};
    path_of(p, sizeof p, name);
    int rc = gs_io_npy_read(p, 0, &a, &err);
    CHECK_MSG(rc == GS_OK, "%s: rc %d (%s)", name, rc, err.msg);
    if (rc)
        return;
    CHECK_MSG(a.dtype == dtype && a.rank == rank, "%s: dtype %d rank %d", name, a.dtype, a.rank);
    for (int d = 0; d < rank && d < a.rank; d++)
        CHECK_MSG(a.shape[d] == shape[d], "%s: dim %d is %zu, want %zu", name, d, a.shape[d],
                  shape[d]);
    size_t n = gs_io_array_count(&a), bad = 0;
    for (size_t i = 0; i < n; i++) {
        double v = dtype == GS_IO_F32 ? ((float *)a.data)[i] : ((unsigned char *)a.data)[i];
        if (v != want(i) && bad++ < 3)
            fprintf(stderr, "%s[%zu] = %g, want %g\n", name, i, v, want(i));
    }
    CHECK_MSG(bad == 0, "%s: %zu wrong values", name, bad);
    gs_io_array_free(&a);
}

static double want_f32_4d(size_t i) { return (double)i / 8.0 - 4.0; }
static double want_u8_2d(size_t i) { return (double)(i * 21 % 256); }
static double want_scalar(size_t i) { return -1.25 + 0.0 * (double)i; }
static double want_range(size_t i) { return (double)i; }

static void check_refused(const char *name, int code)
{
    char p[256];
    gs_io_array a;
    gs_error err = {0};
    path_of(p, sizeof p, name);
    int rc = gs_io_npy_read(p, 0, &a, &err);
    CHECK_MSG(rc == code, "%s: rc %d (%s), want %d", name, rc, err.msg, code);
    if (rc == GS_OK)
        gs_io_array_free(&a);
    else
        printf("%s refused: %s\n", name, err.msg);
}

int main(int argc, char **argv)
{
    char cmd[1024];
    if (argc != 3) {
        fprintf(stderr, "usage: %s PYTHON SCRIPT\n", argv[0]);
        return 2;
    }
    if (!mkdtemp(dir)) {
        perror("mkdtemp");
        return 1;
    }
    write_c_files();
    snprintf(cmd, sizeof cmd, "'%s' '%s' '%s'", argv[1], argv[2], dir);
    CHECK_MSG(system(cmd) == 0, "%s failed", cmd);
    size_t s4[4] = {2, 3, 4, 5}, s2[2] = {3, 4}, s0[2] = {0, 5}, s1[1] = {5};
    check_file("py_f32_4d", GS_IO_F32, 4, s4, want_f32_4d);
    check_file("py_u8_2d", GS_IO_U8, 2, s2, want_u8_2d);
    check_file("py_scalar", GS_IO_F32, 0, NULL, want_scalar);
    check_file("py_empty", GS_IO_F32, 2, s0, want_range);
    check_file("py_v2", GS_IO_F32, 1, s1, want_range);
    check_file("py_v3", GS_IO_F32, 1, s1, want_range);
    check_refused("py_f64", GS_ERR_UNSUPPORTED);
    check_refused("py_be", GS_ERR_UNSUPPORTED);
    check_refused("py_fortran", GS_ERR_UNSUPPORTED);
    check_refused("py_i32", GS_ERR_UNSUPPORTED);
    check_refused("py_rank5", GS_ERR_UNSUPPORTED);
    snprintf(cmd, sizeof cmd, "rm -rf '%s'", dir);
    if (system(cmd) != 0)
        fprintf(stderr, "could not remove %s\n", dir);
    GS_TEST_END();
}
