/* Compares the estimator's forward and backward (to the image and to every
 * weight) with the PyTorch reference of gaze_reference.py, both archs.
 * Usage: test_gaze_reference DIR (holding the script's files).
 * Tolerance |got - want| <= 1e-5 + 1e-4 |want| (float32 against float64).
 * Gradients are prefilled with 0.5 and compared with reference + 0.5,
 * which also checks that backward accumulates. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>

#include "gaze_internal.h"
#include "gazesplat/nn.h"
#include "gazesplat/safetensors.h"
#include "gs_test.h"

#define ATOL 1e-5
#define RTOL 1e-4

static const float *ref(const gs_st_file *f, const char *arch, const char *what,
                        size_t *count)
{
    char name[128];
    snprintf(name, sizeof name, "%s.%s", arch, what);
    const gs_st_tensor *t = gs_st_find(f, name);
    if (!t || t->dtype != GS_ST_F32) {
        fprintf(stderr, "reference tensor %s missing\n", name);
        exit(1);
    }
    *count = t->nbytes / sizeof(float);
    return t->data;
}

static void check_arch(const char *dir, const gs_st_file *f, const char *arch)
{
    char path[1024];
    snprintf(path, sizeof path, "%s/%s.safetensors", dir, arch);
    gs_gaze_net *n = NULL;
    gs_error err = {0, ""};
    int rc = gs_gaze_net_load(path, &n, &err);
    CHECK_MSG(rc == GS_OK, "load %s: %s", path, err.msg);
    if (rc)
        return;
    size_t ni, nd, no, nimg;
    const float *img = ref(f, arch, "img", &nimg), *dout = ref(f, arch, "dout", &nd);
    const float *want = ref(f, arch, "out", &no), *dimg_ref = ref(f, arch, "dimg", &ni);
    char name[128];
    snprintf(name, sizeof name, "%s.img", arch);
    const gs_st_tensor *timg = gs_st_find(f, name);
    int H = (int)timg->shape[1], W = (int)timg->shape[2];
    float out[4];
    CHECK(gs_gaze_net_forward(n, NULL, img, W, H, out, &err) == GS_OK);
    snprintf(name, sizeof name, "%s out", arch);
    gs_check_arrays(name, out, want, 4, ATOL, RTOL);

    size_t np = gs_gaze_net_param_count(n);
    float *dimg = malloc(nimg * sizeof *dimg), *dp = malloc(np * sizeof *dp);
    float *want_img = malloc(nimg * sizeof *dimg);
    for (size_t i = 0; i < nimg; i++)
        dimg[i] = 0.5f, want_img[i] = dimg_ref[i] + 0.5f;
    for (size_t i = 0; i < np; i++)
        dp[i] = 0.5f;
    CHECK(gs_gaze_net_backward(n, NULL, dout, dimg, dp, &err) == GS_OK);
    snprintf(name, sizeof name, "%s dimg", arch);
    gs_check_arrays(name, dimg, want_img, nimg, ATOL, RTOL);
    for (int i = 0; i < n->g.ntensors; i++) {
        const gz_tensor *t = &n->g.t[i];
        char what[96];
        size_t c;
        snprintf(what, sizeof what, "grad.%s", t->name);
        const float *g = ref(f, arch, what, &c);
        CHECK_MSG(c == t->count, "%s %s: %zu values, want %zu", arch, t->name, c, t->count);
        float *w2 = malloc(c * sizeof *w2);
        for (size_t k = 0; k < c; k++)
            w2[k] = g[k] + 0.5f;
        snprintf(name, sizeof name, "%s d%s", arch, t->name);
        gs_check_arrays(name, dp + t->off, w2, c, ATOL, RTOL);
        free(w2);
    }
    free(dimg);
    free(dp);
    free(want_img);
    gs_gaze_net_destroy(n);
}

int main(int argc, char **argv)
{
    if (argc != 2) {
        fprintf(stderr, "usage: test_gaze_reference DIR\n");
        return 2;
    }
    gs_nn_blas_set_threads(1);
    char path[1024];
    snprintf(path, sizeof path, "%s/reference.safetensors", argv[1]);
    gs_st_file *f = NULL;
    gs_error err = {0, ""};
    if (gs_st_open(path, NULL, &f, &err)) {
        fprintf(stderr, "%s: %s\n", path, err.msg);
        return 1;
    }
    check_arch(argv[1], f, "resnet");
    check_arch(argv[1], f, "vgg");
    gs_st_close(f);
    GS_TEST_END();
}
