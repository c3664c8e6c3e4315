/* The training's gaze loss (gs_train_options.gaze_net): a tiny model and
 * an untrained loss estimator (its weights do not matter for the plumbing).
 * Checked: the reported gaze angle is finite and in (0, 180] degrees; the
 * loss's image gradient reaches the model (one step with weight 10 moves
 * the parameters differently from one with weight 0, while two runs with
 * weight 0 are identical bytes: the estimator alone changes nothing); the
 * estimator's weights are left unchanged; a bad weight is refused. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "gazesplat/gaze.h"
#include "gazesplat/nn.h"
#include "gazesplat/train.h"
#include "gs_test.h"
#include "model_test_util.h"

static char g_path[128];

/* A fresh tiny model trained `steps` steps with the gaze loss at weight w
 * (net NULL: none); its parameters are copied into *params. */
static int run(gs_gaze_net *net, double w, long steps, float **params,
               size_t *n, gs_train_report *rep)
{
    gs_model_spec spec;
    gs_model_spec_default(&spec);
    spec.preset = "tiny";
    spec.train_identities = 2;
    gs_model *m = NULL;
    gs_error err = {0, ""};
    if (gs_model_new(&spec, 5, &m, &err) != GS_OK)
        return fprintf(stderr, "%s\n", err.msg), -1;
    gs_train_options o;
    gs_train_options_default(&o);
    o.out_path = g_path;
    o.steps = steps;
    o.checkpoint_every = 0;
    o.gaze_net = net;
    o.gaze_weight = w;
    int rc = gs_train(m, &o, NULL, rep, &err);
    if (rc)
        fprintf(stderr, "train: %s\n", err.msg);
    *n = m->nparams;
    *params = malloc(m->nparams * sizeof(float));
    if (*params)
        memcpy(*params, m->params, m->nparams * sizeof(float));
    gs_model_destroy(m);
    return rc;
}

int main(void)
{
    gs_nn_blas_set_threads(1);
    snprintf(g_path, sizeof g_path, "test_model_gaze_loss_%d.safetensors",
             (int)getpid());
    gs_gaze_spec gs;
    gs_gaze_spec_default(&gs, GS_GAZE_VGG);
    gs_gaze_net *net = NULL;
    gs_error err = {0, ""};
    CHECK(gs_gaze_net_create(&gs, 3, &net, &err) == GS_OK);
    size_t nw = gs_gaze_net_param_count(net);
    float *w0 = malloc(nw * sizeof(float));
    memcpy(w0, gs_gaze_net_params(net), nw * sizeof(float));

    float *a = NULL, *b = NULL, *c = NULL;
    size_t n = 0;
    gs_train_report ra, rb, rc;
    CHECK(run(net, 0.0, 2, &a, &n, &ra) == GS_OK);
    CHECK(run(net, 0.0, 2, &b, &n, &rb) == GS_OK);
    CHECK(run(net, 10.0, 2, &c, &n, &rc) == GS_OK);
    CHECK_MSG(a && b && memcmp(a, b, n * sizeof(float)) == 0,
              "weight 0 twice: the parameters differ");
    size_t moved = 0;
    for (size_t i = 0; a && c && i < n; i++)
        moved += a[i] != c[i];
    CHECK_MSG(moved > 0, "the gaze loss did not reach the model");
    CHECK_MSG(isfinite(rc.final_gaze_deg) && rc.final_gaze_deg > 0 &&
                  rc.final_gaze_deg <= 180,
              "gaze angle %g deg", rc.final_gaze_deg);
    printf("gaze loss: angle %.2f deg, %zu of %zu parameters moved by it\n",
           rc.final_gaze_deg, moved, n);
    CHECK_MSG(memcmp(w0, gs_gaze_net_params(net), nw * sizeof(float)) == 0,
              "training changed the estimator's weights");
    /* a bad weight */
    float *d = NULL;
    gs_train_report rd;
    CHECK(run(net, -1.0, 1, &d, &n, &rd) == GS_ERR_ARG);
    free(a); free(b); free(c); free(d); free(w0);
    gs_gaze_net_destroy(net);
    remove(g_path);
    char opt[160];
    snprintf(opt, sizeof opt, "%s.opt", g_path);
    remove(opt);
    GS_TEST_END();
}
