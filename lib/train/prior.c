/* The fit's code prior computed from the training sampler (lib/model's
 * prior.c holds the result as a table, so that fitting draws no scenes):
 * the mean and covariance of the code's [expression | lights] slots over
 * PRIOR_DRAWS scenes of m's sampler, then the precision. The scenes'
 * expressions and lights do not depend on the model (its identities and
 * image size), so one table serves every model; test_code_prior checks it
 * against this for several models to the bit, and prints a new one when
 * the sampler changes. */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "gazesplat/synth.h"
#include "gazesplat/train.h"
#include "../model/model_internal.h"

/* Scenes drawn for the statistics: enough that the covariance's smallest
 * kept directions are stable. */
#define PRIOR_DRAWS 4096

int gs_train_code_prior(const gs_model *m, gs_code_prior *p, gs_error *err)
{
    enum { N = GS_CODE_PRIOR_DIM };
    gs_train_options to;
    gs_train_options_default(&to);
    gs_synth_gen_config gen;
    gs_train_sample_config(m, &to, &gen);
    double sum[N] = {0}, cov[N * N] = {0};
    for (int s = 0; s < PRIOR_DRAWS; s++) {
        gs_synth_scene sc;
        gs_synth_camera cam;
        int rc = gs_synth_gen_scene(&gen, (uint64_t)s, &sc, &cam, err);
        if (rc)
            return rc;
        float v[N];
        gs_synth_expression_to_array(&sc.expr, v);
        gs_model_light_code(&sc, v + GS_MODEL_EXPR_DIM);
        for (int i = 0; i < N; i++) {
            sum[i] += v[i];
            for (int j = 0; j <= i; j++)
                cov[i * N + j] += (double)v[i] * v[j];
        }
    }
    double tr = 0;
    for (int i = 0; i < N; i++)
        p->mean[i] = sum[i] / PRIOR_DRAWS;
    for (int i = 0; i < N; i++)
        for (int j = 0; j <= i; j++) {
            double c = cov[i * N + j] / PRIOR_DRAWS - p->mean[i] * p->mean[j];
            cov[i * N + j] = cov[j * N + i] = c;
            if (i == j)
                tr += c;
        }
    /* The light code's three colours of one direction move almost
     * together (a light's tint is within +-15 %): the covariance is
     * nearly singular there. A ridge of 1 % of the mean variance keeps
     * the precision finite: a code off that subspace is unlikely, not
     * impossible. */
    for (int i = 0; i < N; i++)
        cov[i * N + i] += 0.01 * tr / N;
    double y[N];
    if (gs_spd_inverse(cov, N, p->prec, y))
        return gs_error_set(err, GS_ERR_STATE,
                            "code prior: the sampler's covariance is not "
                            "positive definite");
    return GS_OK;
}
