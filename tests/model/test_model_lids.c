/* Lids that follow the gaze (gs_model_add_lids, docs/model.md): which face
 * Gaussians become lids and where they go in the face stream; a model
 * whose lids do not move (k = 0) rasterizes the same feature maps as the
 * model it came from; the file keeps the lids; pruning keeps them; bad
 * arguments and configurations are refused. The gradients are checked by
 * test_model_streams and test_streams_reference, incremental renders by
 * test_model_incremental, transfers by test_model_transfer. */
#include <math.h>
#include <string.h>
#include <unistd.h>

#include "gazesplat/nn.h"
#include "gs_test.h"
#include "model_test_util.h"

static double dist(const float *x, const float *c)
{
    double s = 0;
    for (int k = 0; k < 3; k++)
        s += ((double)x[k] - c[k]) * ((double)x[k] - c[k]);
    return sqrt(s);
}

/* Tensor name of model m (NULL when it has none). */
static const gs_ptensor *tensor(const gs_model *m, const char *name)
{
    for (int t = 0; t < m->ntensors; t++)
        if (!strcmp(m->t[t].name, name))
            return &m->t[t];
    return NULL;
}

/* Floats per face Gaussian of face tensor name. */
static size_t width(const gs_model *m, const char *name)
{
    return tensor(m, name)->count / (size_t)m->cfg.n_face;
}

/* Row of face tensor name of model m for face Gaussian i. */
static const float *row(const gs_model *m, const char *name, int i)
{
    return m->params + tensor(m, name)->offset + (size_t)i * width(m, name);
}

static const char *const k_face[] = {"face.xyz", "face.log_scale", "face.quat",
                                     "face.opacity", "face.colour", "face.feat",
                                     "face.lambda"};

/* The same face Gaussian: every face tensor's row equal. */
static int same_row(const gs_model *a, int i, const gs_model *b, int j)
{
    for (size_t t = 0; t < sizeof k_face / sizeof k_face[0]; t++) {
        size_t w = width(a, k_face[t]);
        if (memcmp(row(a, k_face[t], i), row(b, k_face[t], j), w * sizeof(float)))
            return 0;
    }
    return 1;
}

/* sum_p w_p cover_p of frame fr (the eye stream's coverage, training's
 * eye-cover loss with weights w). */
static double cover_obj(gs_model_ctx *c, const gs_frame *fr, const float *w)
{
    gs_error err;
    if (gs_frame_forward(c, NULL, fr, GS_STREAM_BOTH, 1, &err) != GS_OK ||
        gs_frame_eye_cover(c, NULL, &err) != GS_OK)
        return NAN;
    double s = 0;
    for (int i = 0; i < c->fs * c->fs; i++)
        s += (double)w[i] * c->cover[i];
    return s;
}

/* The eye-cover loss's gradient (gs_frame_eye_cover, then
 * gs_frame_backward with cover_grad) against central differences: the
 * lids' knots, their positions, the eyes' positions and opacities, the
 * gaze's pitch. */
static void cover_grad_check(gs_model *l)
{
    for (int q = 0; q < 2 * GS_LID_NU * GS_LID_NV; q++)
        l->p.lid_k[q] = 0.5f + 0.02f * (float)(q % 11);
    gs_model_ctx *c = gs_model_ctx_create(l);
    int fs = l->cfg.feat_size;
    float *w = malloc((size_t)fs * fs * sizeof(float));
    float *grad = calloc(l->nparams, sizeof(float));
    CHECK(c && w && grad);
    if (!c || !w || !grad)
        goto out;
    gs_frame fr;
    frame_default(l, &fr);
    fr.gaze[0] = -0.4;
    uint64_t r = 99;
    for (int i = 0; i < fs * fs; i++) {
        r = r * 6364136223846793005ull + 1442695040888963407ull;
        w[i] = (float)((r >> 40) % 1000) / 1000.0f - 0.3f;
    }
    double f0 = cover_obj(c, &fr, w);
    CHECK(isfinite(f0));
    gs_model_params g;
    gs_model_bind(l, grad, &g);
    gs_frame_grad fg;
    memset(&fg, 0, sizeof fg);
    gs_error err;
    c->cover_grad = w;
    CHECK(gs_frame_backward(c, NULL, NULL, NULL, NULL, NULL, &g, &fg, &err) == GS_OK);
    c->cover_grad = NULL;
    const char *names[] = {"face.lid_k", "face.xyz", "eye.xyz", "eye.opacity"};
    int bad = 0, n = 0;
    for (size_t t = 0; t < sizeof names / sizeof names[0]; t++) {
        const gs_ptensor *pt = tensor(l, names[t]);
        CHECK_MSG(pt != NULL, "no tensor %s", names[t]);
        if (!pt)
            continue;
        /* the entries with the largest gradients: where it matters */
        for (int rep = 0; rep < 3; rep++) {
            size_t best = 0;
            double bv = -1;
            for (size_t i = 0; i < pt->count; i++) {
                double v = fabs(grad[pt->offset + i]);
                if (v > bv)
                    bv = v, best = i;
            }
            float *x = l->params + pt->offset + best, x0 = *x;
            double h = !strcmp(names[t], "face.lid_k") ? 0.02 : 0.05;
            *x = x0 + (float)h;
            double up = cover_obj(c, &fr, w);
            *x = x0 - (float)h;
            double dn = cover_obj(c, &fr, w);
            *x = x0;
            double num = (up - dn) / (2 * h), ana = grad[pt->offset + best];
            double tol = 0.1 * fmax(fabs(num), fabs(ana)) + 1e-3 * (1 + fabs(f0));
            n++;
            bad += fabs(num - ana) > tol;
            printf("cover gradient %-12s [%zu]: analytic %+.5e numeric %+.5e\n", names[t],
                   best, ana, num);
            grad[pt->offset + best] = 0; /* the next largest next time */
        }
    }
    gs_frame f2 = fr;
    f2.gaze[0] = fr.gaze[0] + 0.002;
    double up = cover_obj(c, &f2, w);
    f2.gaze[0] = fr.gaze[0] - 0.002;
    double dn = cover_obj(c, &f2, w);
    double num = (up - dn) / 0.004;
    n++;
    bad += fabs(num - fg.gaze[0]) > 0.1 * fmax(fabs(num), fabs(fg.gaze[0])) + 1e-3;
    printf("cover gradient gaze pitch: analytic %+.5e numeric %+.5e\n", fg.gaze[0], num);
    CHECK_MSG(bad == 0, "%d of %d eye-cover gradients disagree", bad, n);
out:
    free(w);
    free(grad);
    gs_model_ctx_destroy(c);
}

int main(void)
{
    gs_nn_blas_set_threads(1);
    gs_error err = {0, ""};
    gs_model *m = tiny_model(1, 7);
    CHECK(m != NULL);
    if (!m)
        return 1;
    gs_model *l = NULL;
    CHECK_MSG(gs_model_add_lids(m, GS_MODEL_LID_RADIUS_MM, &l, &err) == GS_OK, "%s",
              err.msg);
    if (!l)
        return 1;
    int nf = m->cfg.n_face, n0 = l->cfg.n_lid0, n1 = l->cfg.n_lid1, nl = n0 + n1,
        nm = nf - nl;
    printf("tiny model: %d face Gaussians, lids %d + %d\n", nf, n0, n1);
    CHECK(l->cfg.n_face == nf && n0 > 10 && n1 > 10 && abs(n0 - n1) <= n0 / 4);
    CHECK(gs_model_has_lids(l) && !gs_model_has_lids(m));

    /* The others in their order, then eye 0's lids, then eye 1's: each a
     * row of m, lids within the radius of their eye's centre, the others
     * beyond both. */
    const float *ec = m->p.eye_centre;
    int j = 0, order_ok = 1, place_ok = 1;
    for (int i = 0; i < nf; i++) {
        const float *x = row(m, "face.xyz", i);
        double d0 = dist(x, ec), d1 = dist(x, ec + 3);
        int lid = d0 < GS_MODEL_LID_RADIUS_MM || d1 < GS_MODEL_LID_RADIUS_MM;
        if (!lid)
            order_ok &= j < nm && same_row(m, i, l, j++);
    }
    CHECK_MSG(order_ok && j == nm, "the others are not m's rows in order (%d of %d)", j,
              nm);
    for (int e = 0; e < 2; e++) {
        int i = 0;
        for (int q = 0; q < (e ? n1 : n0); q++) {
            int lj = nm + (e ? n0 : 0) + q;
            const float *x = row(l, "face.xyz", lj);
            double d = dist(x, ec + 3 * e), o = dist(x, ec + 3 * (1 - e));
            place_ok &= d < GS_MODEL_LID_RADIUS_MM && d <= o;
            /* the next row of m that is eye e's lid */
            for (; i < nf; i++) {
                const float *y = row(m, "face.xyz", i);
                double a = dist(y, ec + 3 * e), b = dist(y, ec + 3 * (1 - e));
                if (a < GS_MODEL_LID_RADIUS_MM && a <= b)
                    break;
            }
            order_ok &= i < nf && same_row(m, i, l, lj);
            i++;
            const float *uv = l->p.lid_uv + 2 * (size_t)(lj - nm);
            place_ok &= uv[0] >= 0 && uv[0] <= GS_LID_NU - 1 && uv[1] >= 0 &&
                        uv[1] <= GS_LID_NV - 1;
        }
    }
    CHECK_MSG(order_ok, "the lids are not m's rows in order");
    CHECK_MSG(place_ok, "a lid beyond the radius or off its grid");
    int kz = 1;
    for (int q = 0; q < 2 * GS_LID_NU * GS_LID_NV; q++)
        kz &= l->p.lid_k[q] == 0.0f;
    CHECK_MSG(kz, "the lids' k do not start at 0");

    /* k = 0: the merged feature map is m's (the same Gaussians, other
     * indices: only exact depth ties could blend in another order) at any
     * gaze; the guidance source leaves the lids out, so the image differs. */
    gs_model_ctx *cm = gs_model_ctx_create(m), *cl = gs_model_ctx_create(l);
    CHECK(cm && cl);
    gs_frame fr;
    frame_default(m, &fr);
    size_t nmap = (size_t)m->cfg.channels * m->cfg.feat_size * m->cfg.feat_size;
    double worst = 0;
    for (int g = 0; g < 3; g++) {
        fr.gaze[0] = 0.4 * (g - 1);
        CHECK(gs_frame_forward(cm, NULL, &fr, GS_STREAM_BOTH, 1, &err) == GS_OK);
        CHECK(gs_frame_forward(cl, NULL, &fr, GS_STREAM_BOTH, 1, &err) == GS_OK);
        for (size_t i = 0; i < nmap; i++)
            worst = fmax(worst, fabs((double)cm->fmap[i] - cl->fmap[i]));
    }
    printf("k = 0: feature maps within %.2e of the model without lids\n", worst);
    CHECK_MSG(worst <= 1e-5, "k = 0 moved the feature map by %.3g", worst);
    gs_model_ctx_destroy(cm);
    gs_model_ctx_destroy(cl);

    /* The file keeps the lids (configuration and tensors). */
    char path[128];
    snprintf(path, sizeof path, "test_model_lids_%d.safetensors", (int)getpid());
    for (int q = 0; q < 2 * GS_LID_NU * GS_LID_NV; q++)
        l->p.lid_k[q] = 0.01f * (float)(q % 23);
    CHECK(gs_model_save(l, path, &err) == GS_OK);
    gs_model *r = NULL;
    CHECK_MSG(gs_model_load(path, &r, &err) == GS_OK, "%s", err.msg);
    if (r) {
        CHECK(!memcmp(&r->cfg, &l->cfg, sizeof r->cfg));
        CHECK(r->nparams == l->nparams &&
              !memcmp(r->params, l->params, l->nparams * sizeof(float)));
        CHECK(r->p.lid_k && r->p.lid_uv);
        gs_model_destroy(r);
    }
    unlink(path);

    /* Pruning keeps every lid (last, with k and places) and counts them. */
    gs_model *p = NULL;
    int keep = nl + 40;
    CHECK_MSG(gs_model_prune(l, NULL, keep, &p, &err) == GS_OK, "%s", err.msg);
    if (p) {
        CHECK(p->cfg.n_face == keep && p->cfg.n_lid0 == n0 && p->cfg.n_lid1 == n1);
        int lids_ok = 1;
        for (int q = 0; q < nl; q++)
            lids_ok &= same_row(l, nm + q, p, keep - nl + q);
        CHECK_MSG(lids_ok, "pruning changed a lid");
        CHECK(!memcmp(p->p.lid_k, l->p.lid_k, 2 * GS_LID_NU * GS_LID_NV * sizeof(float)));
        CHECK(!memcmp(p->p.lid_uv, l->p.lid_uv, 2 * (size_t)nl * sizeof(float)));
        gs_model_destroy(p);
    }
    CHECK(gs_model_prune(l, NULL, 3, &p, &err) == GS_OK);
    if (p) { /* fewer than the lids: the lids and one other */
        CHECK(p->cfg.n_face == nl + 1);
        gs_model_destroy(p);
    }

    /* Refused: lids twice, a bad radius, NULL, a model without the
     * explicit eye rotation or the eye stream; configurations with more
     * lids than face Gaussians or lids without two streams. */
    gs_model *x = NULL;
    CHECK(gs_model_add_lids(l, 16.0, &x, &err) == GS_ERR_ARG && !x);
    printf("refused: %s\n", err.msg);
    CHECK(gs_model_add_lids(m, 0.0, &x, &err) == GS_ERR_ARG && !x);
    CHECK(gs_model_add_lids(m, NAN, &x, &err) == GS_ERR_ARG && !x);
    CHECK(gs_model_add_lids(NULL, 16.0, &x, &err) == GS_ERR_ARG);
    m->cfg.eye_rotation = 0;
    CHECK(gs_model_add_lids(m, 16.0, &x, &err) == GS_ERR_ARG && !x);
    printf("refused: %s\n", err.msg);
    m->cfg.eye_rotation = 1;
    gs_model_config cfg = l->cfg;
    cfg.n_lid0 = nf;
    CHECK(gs_model_config_check(&cfg, &err) == GS_ERR_FORMAT);
    printf("refused: %s\n", err.msg);
    cfg = l->cfg;
    cfg.two_stream = 0;
    CHECK(gs_model_config_check(&cfg, &err) == GS_ERR_FORMAT);
    printf("refused: %s\n", err.msg);
    cfg.two_stream = 1;
    cfg.n_lid1 = -1;
    CHECK(gs_model_config_check(&cfg, &err) == GS_ERR_FORMAT);

    cover_grad_check(l);
    gs_model_destroy(l);
    gs_model_destroy(m);
    GS_TEST_END();
}
