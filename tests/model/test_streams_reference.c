/* Compares the model's two Gaussian streams (gs_frame_forward_streams and
 * gs_frame_backward_streams) with the PyTorch reference streams_reference.py
 * (float64 torch, rebuilt from the definition in docs/model.md).
 *
 * Usage: test_streams_reference export DIR   writes each case's inputs
 *        test_streams_reference check DIR    compares with the reference
 *
 * ctest runs export, the script, then check (fixtures). Each case is a tiny
 * model whose stream parameters are all perturbed away from their
 * initialisation (so no path is trivially zero: the residual eye rotation,
 * W_e tau, the pose MLP's pose inputs), one frame with a non-trivial head
 * pose and a gaze near the documented limits, and a random upstream gradient
 * on each camera-frame tensor. Checked: the camera-frame Gaussians, the
 * gradient of every stream tensor and of tau, the gaze, the head rotation
 * (left perturbation) and translation; the tensors the streams do not touch
 * (fixed, codes, renderer) must get exactly zero. Tolerance per value:
 * |got - want| <= ATOL_REL max|want| + RTOL |want|.
 *
 * The lids cases (gs_model_add_lids) check the lids' turn about the
 * eyeball centre by their share of the pitch, and its gradients (k, the
 * pitch, W_e and tau through the centre).
 *
 * The single-stream case found a real gap, since fixed: the gaze enters
 * that ablation only through the pose MLP, whose input gradient the C code
 * did not carry to the gaze. */
#define _POSIX_C_SOURCE 200809L
#include <errno.h>
#include <string.h>
#include <sys/stat.h>

#include "gazesplat/image_io.h"
#include "gs_test.h"
#include "model_test_util.h"

#define ATOL_REL 1e-5
#define RTOL 1e-5

typedef struct stream_case {
    const char *name;
    int two_stream, eye_rotation;
    int lids; /* gs_model_add_lids, then every lid's k moved by +0.7 */
    double head[3]; /* pitch, yaw, roll */
    double gaze[2]; /* pitch, yaw */
    uint64_t seed;
} stream_case;

/* Gaze limits 50 / 60 deg (0.8727 / 1.0472 rad, model.h); head pitch/yaw 70 (1.2217). */
static const stream_case g_cases[] = {
    {"two_stream", 1, 1, 0, {0.4, -0.7, 0.15}, {0.85, -1.02}, 21},
    {"two_stream_far", 1, 1, 0, {-0.6, 1.15, -0.25}, {-0.86, 1.04}, 22},
    {"no_eye_rotation", 1, 0, 0, {0.4, -0.7, 0.15}, {-0.8, 0.95}, 23},
    {"single_stream", 0, 1, 0, {0.3, 0.6, -0.1}, {0.82, 1.0}, 24},
    {"lids", 1, 1, 1, {0.4, -0.7, 0.15}, {0.85, -1.02}, 25},
    {"lids_far", 1, 1, 1, {-0.6, 1.15, -0.25}, {-0.86, 1.04}, 26},
};
#define NCASES (int)(sizeof g_cases / sizeof g_cases[0])

static const char *g_dir;
static uint64_t g_rng;

static float uni(float bound) /* uniform in [-bound, bound) */
{
    g_rng = g_rng * 6364136223846793005ull + 1442695040888963407ull;
    return bound * ((float)(g_rng >> 40) / 8388608.0f - 1.0f);
}

/* The tiny model of model_test_util.h with the case's stream switches. */
static gs_model *make_model(const stream_case *sc)
{
    gs_model_config cfg;
    tiny_config(&cfg);
    cfg.two_stream = sc->two_stream;
    gs_model *m = NULL;
    gs_error err;
    if (gs_model_create(&cfg, sc->seed, &m, &err) != GS_OK) {
        fprintf(stderr, "%s: %s\n", sc->name, err.msg);
        return NULL;
    }
    m->cfg.eye_rotation = sc->eye_rotation; /* a run-time switch */
    if (sc->lids) {
        gs_model *l = NULL;
        int rc = gs_model_add_lids(m, GS_MODEL_LID_RADIUS_MM, &l, &err);
        gs_model_destroy(m);
        if (rc != GS_OK) {
            fprintf(stderr, "%s: %s\n", sc->name, err.msg);
            return NULL;
        }
        m = l;
    }
    return m;
}

static void path_of(char *out, size_t len, const stream_case *sc,
                    const char *prefix, const char *name)
{
    snprintf(out, len, "%s/%s/%s%s.npy", g_dir, sc->name, prefix, name);
}

static int save(const stream_case *sc, const char *prefix, const char *name,
                int rank, const size_t *shape, const float *data)
{
    char path[512];
    gs_error err;
    path_of(path, sizeof path, sc, prefix, name);
    int rc = gs_io_npy_write(path, GS_IO_F32, rank, shape, data, &err);
    CHECK_MSG(rc == GS_OK, "%s: %s", path, err.msg);
    return rc == GS_OK;
}

/* DIR/case/prefix+name.npy; NULL (and a failure) when missing or of another
 * element count. */
static float *load(const stream_case *sc, const char *prefix, const char *name,
                   size_t want_count)
{
    char path[512];
    gs_io_array a;
    gs_error err;
    path_of(path, sizeof path, sc, prefix, name);
    if (gs_io_npy_read(path, 0, &a, &err) != GS_OK) {
        CHECK_MSG(0, "%s: %s", path, err.msg);
        return NULL;
    }
    if (a.dtype != GS_IO_F32 || gs_io_array_count(&a) != want_count) {
        CHECK_MSG(0, "%s: %zu values, want %zu", path, gs_io_array_count(&a),
                  want_count);
        gs_io_array_free(&a);
        return NULL;
    }
    return a.data;
}

static int has_grad(const gs_ptensor *t)
{
    return t->group != GS_PG_FIXED && t->group != GS_PG_CODES &&
           t->group != GS_PG_RENDERER;
}

/* Stream parameters away from their initialisation. */
static void perturb(gs_model *m)
{
    static const float bound[GS_PG_COUNT] = {
        [GS_PG_GAUSS_XYZ] = 0.5f, [GS_PG_GAUSS_ATTR] = 0.1f,
        [GS_PG_GAUSS_FEAT] = 0.2f, [GS_PG_MLP] = 0.1f};
    for (int i = 0; i < m->ntensors; i++) {
        const gs_ptensor *t = &m->t[i];
        if (!has_grad(t))
            continue;
        for (size_t k = 0; k < t->count; k++)
            m->params[t->offset + k] += uni(bound[t->group]);
    }
}

/* The frame's doubles rounded to float, so both sides see the same. */
static void make_frame(const gs_model *m, const stream_case *sc, gs_frame *fr)
{
    memset(fr, 0, sizeof *fr);
    gs_geom_rot_from_pitchyaw(sc->head[0], sc->head[1], sc->head[2],
                              fr->head_R);
    for (int k = 0; k < 9; k++)
        fr->head_R[k] = (float)fr->head_R[k];
    fr->head_t[0] = 12.5;
    fr->head_t[1] = -20.25;
    fr->head_t[2] = m->cfg.d_n_mm;
    fr->gaze[0] = (float)sc->gaze[0];
    fr->gaze[1] = (float)sc->gaze[1];
    for (int k = 0; k < gs_model_code_dim(&m->cfg); k++)
        fr->code[k] = uni(0.5f);
}

/* Upstream gradients on the camera-frame tensors: mean, scale, quat, opac,
 * feat ([n x 3, 3, 4, 1, C]). */
static const char *const g_out[5] = {"mean", "scale", "quat", "opac", "feat"};

static float **gauss(gs_model_ctx *c, int grad, int k)
{
    float **g[5] = {&c->g_mean, &c->g_scale, &c->g_quat, &c->g_opac,
                    &c->g_feat};
    float **v[5] = {&c->v_mean, &c->v_scale, &c->v_quat, &c->v_opac,
                    &c->v_feat};
    return grad ? v[k] : g[k];
}

static size_t width(const gs_model_ctx *c, int k)
{
    const size_t w[5] = {3, 3, 4, 1, (size_t)c->C};
    return w[k];
}

static int export_case(const stream_case *sc)
{
    char dir[512];
    snprintf(dir, sizeof dir, "%s/%s", g_dir, sc->name);
    if (mkdir(dir, 0755) != 0 && errno != EEXIST) {
        CHECK_MSG(0, "cannot create %s", dir);
        return 0;
    }
    g_rng = sc->seed;
    gs_model *m = make_model(sc);
    if (!m)
        return 0;
    perturb(m);
    for (int j = 0; m->p.lid_k && j < 2 * GS_LID_NU * GS_LID_NV; j++)
        m->p.lid_k[j] += 0.7f; /* lids that move, some twice as far */
    CHECK_MSG(!sc->lids || gs_model_n_lid(&m->cfg) > 10, "%s: %d lids",
              sc->name, gs_model_n_lid(&m->cfg));
    int ok = 1;
    for (int i = 0; i < m->ntensors && ok; i++) {
        const gs_ptensor *t = &m->t[i];
        size_t shape[4];
        for (int k = 0; k < t->ndim; k++)
            shape[k] = (size_t)t->shape[k];
        if (t->group != GS_PG_RENDERER)
            ok = save(sc, "param.", t->name, t->ndim, shape,
                      m->params + t->offset);
    }
    gs_frame fr;
    make_frame(m, sc, &fr);
    int D = gs_model_code_dim(&m->cfg), nf = m->cfg.n_face;
    int n = nf + (sc->two_stream ? 2 * m->cfg.n_eye_each : 0);
    float R[9], t[3], gz[2] = {(float)fr.gaze[0], (float)fr.gaze[1]};
    float cfg[9] = {(float)nf, (float)m->cfg.n_eye_each,
                    (float)m->cfg.feat_dim, (float)D,
                    (float)m->cfg.channels, (float)sc->two_stream,
                    (float)sc->eye_rotation, (float)m->cfg.n_lid0,
                    (float)m->cfg.n_lid1};
    for (int k = 0; k < 9; k++)
        R[k] = (float)fr.head_R[k];
    for (int k = 0; k < 3; k++)
        t[k] = (float)fr.head_t[k];
    size_t s7 = 9, sD = (size_t)D, s33[2] = {3, 3}, s3 = 3, s2 = 2;
    ok = ok && save(sc, "", "config", 1, &s7, cfg) &&
         save(sc, "", "code", 1, &sD, fr.code) &&
         save(sc, "", "head_R", 2, s33, R) && save(sc, "", "head_t", 1, &s3, t) &&
         save(sc, "", "gaze", 1, &s2, gz);
    const size_t w[5] = {3, 3, 4, 1, (size_t)m->cfg.channels};
    for (int k = 0; k < 5 && ok; k++) {
        size_t len = (size_t)n * w[k], shape[2] = {(size_t)n, w[k]};
        float *v = malloc(len * sizeof(float));
        for (size_t i = 0; i < len; i++)
            v[i] = uni(1.0f);
        /* Eye Gaussians are isotropic: the rasterizer's gradient of their
         * quaternion is zero, and the streams drop it (frame.c). */
        if (k == 2)
            memset(v + 4 * (size_t)nf, 0, (len - 4 * (size_t)nf) * sizeof(float));
        char name[16];
        snprintf(name, sizeof name, "v_%s", g_out[k]);
        ok = save(sc, "", name, k == 3 ? 1 : 2, shape, v);
        free(v);
    }
    gs_model_destroy(m);
    return ok;
}

static void compare(const stream_case *sc, const char *what, const float *got,
                    const float *want, size_t n)
{
    double big = 0.0, worst = 0.0;
    for (size_t i = 0; i < n; i++) {
        big = fmax(big, fabs((double)want[i]));
        worst = fmax(worst, fabs((double)got[i] - want[i]));
    }
    char label[160];
    snprintf(label, sizeof label, "%s %s", sc->name, what);
    printf("%-44s n=%-6zu max|want| %.3e  max|diff| %.2e (%.1e of max)\n",
           label, n, big, worst, big > 0 ? worst / big : 0.0);
    gs_check_arrays(label, got, want, n, ATOL_REL * big + 1e-12, RTOL);
}

/* Loads what export wrote into m, fr and the context's upstream grads. */
static int load_inputs(const stream_case *sc, gs_model *m, gs_frame *fr)
{
    for (int i = 0; i < m->ntensors; i++) {
        const gs_ptensor *t = &m->t[i];
        if (t->group == GS_PG_RENDERER)
            continue;
        float *a = load(sc, "param.", t->name, t->count);
        if (!a)
            return 0;
        memcpy(m->params + t->offset, a, t->count * sizeof(float));
        free(a);
    }
    int D = gs_model_code_dim(&m->cfg);
    float *code = load(sc, "", "code", (size_t)D);
    float *R = load(sc, "", "head_R", 9), *t = load(sc, "", "head_t", 3);
    float *gz = load(sc, "", "gaze", 2);
    int ok = code && R && t && gz;
    if (ok) {
        memset(fr, 0, sizeof *fr);
        memcpy(fr->code, code, (size_t)D * sizeof(float));
        for (int k = 0; k < 9; k++)
            fr->head_R[k] = R[k];
        for (int k = 0; k < 3; k++)
            fr->head_t[k] = t[k];
        fr->gaze[0] = gz[0];
        fr->gaze[1] = gz[1];
    }
    free(code); free(R); free(t); free(gz);
    return ok;
}

static void check_case(const stream_case *sc)
{
    gs_model *m = make_model(sc);
    gs_model_ctx *c = m ? gs_model_ctx_create(m) : NULL;
    float *grad = m ? calloc(m->nparams, sizeof(float)) : NULL;
    gs_frame fr;
    if (!c || !grad || !load_inputs(sc, m, &fr)) {
        CHECK_MSG(0, "%s: cannot set up the case", sc->name);
        goto done;
    }
    gs_frame_forward_streams(c, NULL, &fr, 1);
    c->stream = GS_STREAM_BOTH;
    for (int k = 0; k < 5; k++) {
        size_t len = (size_t)c->n * width(c, k);
        char name[16];
        snprintf(name, sizeof name, "v_%s", g_out[k]);
        float *v = load(sc, "", name, len);
        if (!v)
            goto done;
        memcpy(*gauss(c, 1, k), v, len * sizeof(float));
        free(v);
    }
    gs_model_params g;
    gs_model_bind(m, grad, &g);
    gs_frame_grad fg;
    memset(&fg, 0, sizeof fg);
    gs_frame_backward_streams(c, NULL, &g, &fg);

    for (int k = 0; k < 5; k++) {
        size_t len = (size_t)c->n * width(c, k);
        float *want = load(sc, "out.", g_out[k], len);
        if (want)
            compare(sc, g_out[k], *gauss(c, 0, k), want, len);
        free(want);
    }
    for (int i = 0; i < m->ntensors; i++) {
        const gs_ptensor *t = &m->t[i];
        const float *got = grad + t->offset;
        if (!has_grad(t)) {
            size_t nz = 0;
            for (size_t k = 0; k < t->count; k++)
                nz += got[k] != 0.0f;
            CHECK_MSG(nz == 0, "%s: %s has %zu non-zero gradients", sc->name,
                      t->name, nz);
            continue;
        }
        float *want = load(sc, "grad.", t->name, t->count);
        if (want)
            compare(sc, t->name, got, want, t->count);
        free(want);
    }
    int D = gs_model_code_dim(&m->cfg);
    float rot[3], trans[3], gaze[2] = {(float)fg.gaze[0], (float)fg.gaze[1]};
    for (int k = 0; k < 3; k++) {
        rot[k] = (float)fg.rot[k];
        trans[k] = (float)fg.trans[k];
    }
    const char *fname[4] = {"code", "rot", "trans", "gaze"};
    const float *fgot[4] = {fg.code, rot, trans, gaze};
    const size_t flen[4] = {(size_t)D, 3, 3, 2};
    for (int k = 0; k < 4; k++) {
        float *want = load(sc, "grad.", fname[k], flen[k]);
        if (want)
            compare(sc, fname[k], fgot[k], want, flen[k]);
        free(want);
    }
done:
    free(grad);
    gs_model_ctx_destroy(c);
    gs_model_destroy(m);
}

int main(int argc, char **argv)
{
    if (argc != 3 || (strcmp(argv[1], "export") && strcmp(argv[1], "check"))) {
        fprintf(stderr, "usage: %s export|check DIR\n", argv[0]);
        return 2;
    }
    g_dir = argv[2];
    int exporting = strcmp(argv[1], "export") == 0;
    if (exporting && mkdir(g_dir, 0755) != 0 && errno != EEXIST)
        return fprintf(stderr, "cannot create %s\n", g_dir), 1;
    for (int i = 0; i < NCASES; i++) {
        if (exporting)
            export_case(&g_cases[i]);
        else
            check_case(&g_cases[i]);
    }
    GS_TEST_END();
}
