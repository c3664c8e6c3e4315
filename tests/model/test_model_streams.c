/* Gradient check of the two streams (everything between the
 * parameters / frame inputs and the Gaussians handed to the rasterizer):
 * the objective is a fixed random linear function of the camera-frame
 * Gaussians, smooth but for the LeakyReLU kinks. The forward is float32,
 * so the steps are large enough (1e-2..3e-2) to stay above the float
 * quantization of the Gaussians; central differences then agree to ~1%. The
 * rasterizer and the renderer have their own checks (tests/raster,
 * test_renderer_*); test_model_grad checks the assembled pipeline.
 * The tiny model's face stream spans several of the blocks the streams run
 * in (frame.c), so the checks cover the sums across blocks; and the
 * streams on a pool of two give the bytes they give on no pool. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "gazesplat/pool.h"
#include "gs_test.h"
#include "model_test_util.h"

typedef struct probe {
    gs_model *m;
    gs_model_ctx *c;
    float *w[5];
    size_t len[5];
} probe;

static float **garr(gs_model_ctx *c, int k)
{
    float **a[5] = {&c->g_mean, &c->g_scale, &c->g_quat, &c->g_opac,
                    &c->g_feat};
    return a[k];
}

static float **varr(gs_model_ctx *c, int k)
{
    float **a[5] = {&c->v_mean, &c->v_scale, &c->v_quat, &c->v_opac,
                    &c->v_feat};
    return a[k];
}

static double objective(probe *p, const gs_frame *fr)
{
    gs_frame_forward_streams(p->c, NULL, fr, 1);
    p->c->stream = GS_STREAM_BOTH;
    double s = 0;
    for (int k = 0; k < 5; k++) {
        const float *g = *garr(p->c, k);
        for (size_t i = 0; i < p->len[k]; i++)
            s += (double)p->w[k][i] * g[i];
    }
    return s;
}

static int failures, checks;

static void compare(const char *what, double ana, double num)
{
    double err = fabs(ana - num);
    double tol = 0.1 * fmax(fabs(num), fabs(ana)) + 2e-3;
    checks++;
    if (getenv("GS_VERBOSE") || err > tol)
        printf("  %s%-30s analytic %+.6e numeric %+.6e\n",
               err > tol ? "MISMATCH " : "", what, ana, num);
    if (err > tol)
        failures++;
}

static void run(int eye_rotation, int lids)
{
    probe p;
    p.m = tiny_model(1, 11);
    if (lids) {
        p.m = with_lids(p.m);
        CHECK(p.m && gs_model_n_lid(&p.m->cfg) > 10);
        printf("  %d lid Gaussians\n", gs_model_n_lid(&p.m->cfg));
    }
    CHECK(p.m != NULL);
    p.m->cfg.eye_rotation = eye_rotation;
    p.c = gs_model_ctx_create(p.m);
    int n = p.c->n;
    size_t per[5] = {3, 3, 4, 1, (size_t)p.c->C};
    unsigned r = 777;
    for (int k = 0; k < 5; k++) {
        p.len[k] = per[k] * (size_t)n;
        p.w[k] = malloc(p.len[k] * sizeof(float));
        for (size_t i = 0; i < p.len[k]; i++) {
            r = r * 1103515245u + 12345u;
            p.w[k][i] = ((r >> 8) & 0xffff) / 65536.0f - 0.5f;
        }
    }
    /* Eye Gaussians are isotropic: their rotation is not a parameter. */
    for (size_t i = 4 * (size_t)p.c->nf; i < p.len[2]; i++)
        p.w[2][i] = 0.0f;
    /* The pose MLP sees rvec(R) without a gradient (documented); silence
     * its pose inputs so the rotation check is exact. */
    gs_mlp *fp = &p.m->p.face_p;
    for (int o = 0; o < fp->dims[1]; o++)
        for (int i = p.m->cfg.feat_dim; i < fp->dims[0]; i++)
            fp->w[0][(size_t)o * fp->dims[0] + i] = 0.0f;
    /* A non-trivial residual eye rotation. */
    for (int e = 0; e < 2; e++) {
        gs_mlp *er = &p.m->p.eye_rot[e];
        int L = er->nl - 1;
        for (int i = 0; i < er->dims[L + 1] * er->dims[L]; i++)
            er->w[L][i] = 0.03f * (float)((i % 7) - 3 + e);
    }
    gs_frame fr;
    frame_default(p.m, &fr);
    /* Near the origin: camera-frame floats at 680 mm would quantize the
     * objective at 6e-5 mm per coordinate. The streams do not care. */
    fr.head_t[0] = 1.0;
    fr.head_t[1] = -2.0;
    fr.head_t[2] = 3.0;
    objective(&p, &fr);
    for (int k = 0; k < 5; k++)
        memcpy(*varr(p.c, k), p.w[k], p.len[k] * sizeof(float));
    float *grad = calloc(p.m->nparams, sizeof(float));
    gs_model_params g;
    gs_model_bind(p.m, grad, &g);
    gs_frame_grad fg;
    memset(&fg, 0, sizeof fg);
    gs_frame_backward_streams(p.c, NULL, &g, &fg);
    CHECK_MSG(p.c->nfblk > 1, "the face stream is one block (%d Gaussians)", p.c->nf);
    {   /* forward and backward on a pool of two: the same bytes */
        gs_pool *pool = gs_pool_create(2);
        gs_model_ctx *c2 = gs_model_ctx_create(p.m);
        float *grad2 = calloc(p.m->nparams, sizeof(float));
        CHECK(pool && c2 && grad2);
        if (pool && c2 && grad2) {
            gs_frame_forward_streams(c2, pool, &fr, 1);
            c2->stream = GS_STREAM_BOTH;
            int same = 1;
            for (int k = 0; k < 5; k++) {
                same &= memcmp(*garr(c2, k), *garr(p.c, k), p.len[k] * sizeof(float)) == 0;
                memcpy(*varr(c2, k), p.w[k], p.len[k] * sizeof(float));
            }
            CHECK_MSG(same, "the Gaussians differ on a pool");
            gs_model_params g2;
            gs_model_bind(p.m, grad2, &g2);
            gs_frame_grad fg2;
            memset(&fg2, 0, sizeof fg2);
            gs_frame_backward_streams(c2, pool, &g2, &fg2);
            CHECK_MSG(memcmp(grad, grad2, p.m->nparams * sizeof(float)) == 0 &&
                          memcmp(&fg, &fg2, sizeof fg) == 0,
                      "the gradients differ on a pool");
        }
        free(grad2);
        gs_model_ctx_destroy(c2);
        gs_pool_destroy(pool);
    }
    char name[96];
    for (int k = 0; k < gs_model_code_dim(&p.m->cfg); k++) {
        gs_frame f2 = fr;
        double h = 3e-2;
        f2.code[k] = fr.code[k] + (float)h;
        double up = objective(&p, &f2);
        f2.code[k] = fr.code[k] - (float)h;
        double dn = objective(&p, &f2);
        double hh = ((double)(fr.code[k] + (float)h) -
                     (double)(fr.code[k] - (float)h));
        snprintf(name, sizeof name, "code[%d]", k);
        compare(name, fg.code[k], (up - dn) / hh);
    }
    for (int k = 0; k < 2; k++) {
        gs_frame f2 = fr;
        double h = 3e-3;
        f2.gaze[k] += h;
        double up = objective(&p, &f2);
        f2.gaze[k] -= 2 * h;
        double dn = objective(&p, &f2);
        snprintf(name, sizeof name, "gaze[%d]", k);
        compare(name, fg.gaze[k], (up - dn) / (2 * h));
    }
    for (int k = 0; k < 3; k++) {
        gs_frame f2 = fr;
        double h = 1e-3;
        f2.head_t[k] += h;
        double up = objective(&p, &f2);
        f2.head_t[k] -= 2 * h;
        double dn = objective(&p, &f2);
        snprintf(name, sizeof name, "head_t[%d]", k);
        compare(name, fg.trans[k], (up - dn) / (2 * h));
        double w[3] = {0, 0, 0}, dR[9];
        double fx[2];
        for (int sgn = 0; sgn < 2; sgn++) {
            w[k] = sgn ? -1e-4 : 1e-4;
            gs_geom_rodrigues(w, dR);
            f2 = fr;
            gs_geom_mat3_mul(dR, fr.head_R, f2.head_R);
            fx[sgn] = objective(&p, &f2);
        }
        snprintf(name, sizeof name, "head_rot[%d]", k);
        compare(name, fg.rot[k], (fx[0] - fx[1]) / 2e-4);
    }
    /* Parameters: directional derivatives per tensor. */
    for (int ti = 0; ti < p.m->ntensors; ti++) {
        const gs_ptensor *t = &p.m->t[ti];
        if (t->group == GS_PG_FIXED || t->group == GS_PG_CODES ||
            t->group == GS_PG_RENDERER)
            continue;
        /* Hidden MLP layers: below this objective's float32 noise floor
         * at steps that cross no LeakyReLU kink; test_model_mlp checks
         * gs_mlp exactly, and the rest of this test checks the paths
         * into and out of the MLPs. */
        if (strncmp(t->name, "mlp.", 4) == 0 && !strstr(t->name, ".l2.") &&
            !(strstr(t->name, "face_p.l1.") || strstr(t->name, "rot0.l1.") ||
              strstr(t->name, "rot1.l1.")))
            continue;
        float *save = malloc(t->count * sizeof(float));
        float *dir = malloc(t->count * sizeof(float));
        memcpy(save, p.m->params + t->offset, t->count * sizeof(float));
        double ana = 0;
        /* A sparse direction: a dense one moves every pre-activation of
         * an MLP layer at once and crosses LeakyReLU kinks. */
        memset(dir, 0, t->count * sizeof(float));
        for (int j = 0; j < 8; j++) {
            r = r * 1103515245u + 12345u;
            size_t i = (r >> 4) % t->count;
            dir[i] = ((r >> 16) & 1) ? 1.0f : -1.0f;
        }
        for (size_t i = 0; i < t->count; i++)
            ana += (double)dir[i] * grad[t->offset + i];
        double h = 3e-3, fx[2];
        for (int sgn = 0; sgn < 2; sgn++) {
            for (size_t i = 0; i < t->count; i++)
                p.m->params[t->offset + i] =
                    save[i] + (float)((sgn ? -h : h) * dir[i]);
            fx[sgn] = objective(&p, &fr);
        }
        memcpy(p.m->params + t->offset, save, t->count * sizeof(float));
        snprintf(name, sizeof name, "%s", t->name);
        compare(name, ana, (fx[0] - fx[1]) / (2 * h));
        free(save);
        free(dir);
    }
    free(grad);
    for (int k = 0; k < 5; k++)
        free(p.w[k]);
    gs_model_ctx_destroy(p.c);
    gs_model_destroy(p.m);
}

int main(void)
{
    for (int er = 1; er >= 0; er--) {
        printf("eye_rotation %d\n", er);
        run(er, 0);
    }
    printf("lids\n");
    run(1, 1);
    printf("%d gradients compared\n", checks);
    CHECK_MSG(failures == 0, "%d stream gradient mismatches", failures);
    GS_TEST_END();
}
