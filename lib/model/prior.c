/* The fit's prior on the code's expression and lights: a Gaussian with the
 * mean and covariance those slots have over the training sampler's scenes
 * (docs/model.md, "Fitting", the code prior). */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "model_internal.h"

/* In-place Cholesky of the symmetric positive definite n x n matrix a
 * (lower triangle), then its inverse into inv, exactly symmetric; y: n
 * doubles of scratch. 0, or -1 when a is not positive definite. */
int gs_spd_inverse(double *a, int n, double *inv, double *y)
{
    for (int j = 0; j < n; j++) {
        double d = a[j * n + j];
        for (int k = 0; k < j; k++)
            d -= a[j * n + k] * a[j * n + k];
        if (!(d > 0))
            return -1;
        d = sqrt(d);
        a[j * n + j] = d;
        for (int i = j + 1; i < n; i++) {
            double v = a[i * n + j];
            for (int k = 0; k < j; k++)
                v -= a[i * n + k] * a[j * n + k];
            a[i * n + j] = v / d;
        }
    }
    /* inv = L^-T L^-1, column by column: solve L y = e_c, then L^T x = y */
    for (int c = 0; c < n; c++) {
        for (int i = 0; i < n; i++) {
            double v = i == c ? 1.0 : 0.0;
            for (int k = 0; k < i; k++)
                v -= a[i * n + k] * y[k];
            y[i] = v / a[i * n + i];
        }
        for (int i = n - 1; i >= 0; i--) {
            double v = y[i];
            for (int k = i + 1; k < n; k++)
                v -= a[k * n + i] * inv[k * n + c];
            inv[i * n + c] = v / a[i * n + i];
        }
    }
    /* exactly symmetric, so that a prior's gradient is its loss's */
    for (int i = 0; i < n; i++)
        for (int j = 0; j < i; j++)
            inv[i * n + j] = inv[j * n + i] = 0.5 * (inv[i * n + j] + inv[j * n + i]);
    return 0;
}

/* The identity codes' Gaussian: n = id_dim, mean[n], prec[n * n]. */
struct gs_id_prior {
    int n;
    double *mean, *prec;
};

void gs_id_prior_free(gs_id_prior *p)
{
    if (!p)
        return;
    free(p->mean);
    free(p->prec);
    free(p);
}

int gs_id_prior_make(const gs_model *m, gs_id_prior **out, gs_error *err)
{
    *out = NULL;
    const int n = m->cfg.id_dim, T = m->cfg.n_train_ids;
    if (T < 2 || !m->p.codes)
        return gs_error_set(err, GS_ERR_ARG,
                            "identity prior: wants 2 or more training "
                            "identities, the model has %d", T);
    gs_id_prior *p = calloc(1, sizeof *p);
    double *cov = calloc((size_t)n * n, sizeof(double));
    double *y = calloc((size_t)n, sizeof(double));
    if (p) {
        p->n = n;
        p->mean = calloc((size_t)n, sizeof(double));
        p->prec = calloc((size_t)n * n, sizeof(double));
    }
    if (!p || !cov || !y || !p->mean || !p->prec) {
        gs_id_prior_free(p);
        free(cov);
        free(y);
        return gs_error_set(err, GS_ERR_NOMEM, "identity prior: out of memory");
    }
    const float *codes = m->p.codes;
    for (int t = 0; t < T; t++)
        for (int i = 0; i < n; i++)
            p->mean[i] += codes[(size_t)t * n + i] / (double)T;
    double tr = 0;
    for (int i = 0; i < n; i++)
        for (int j = 0; j <= i; j++) {
            double c = 0;
            for (int t = 0; t < T; t++)
                c += (codes[(size_t)t * n + i] - p->mean[i]) *
                     (codes[(size_t)t * n + j] - p->mean[j]);
            c /= T;
            cov[i * n + j] = cov[j * n + i] = c;
            tr += i == j ? c : 0.0;
        }
    /* fewer identities than slots, or slots training left alone: a
     * ridge of 1 % of the mean variance keeps the precision finite */
    for (int i = 0; i < n; i++)
        cov[i * n + i] += 0.01 * tr / n + 1e-12;
    int bad = gs_spd_inverse(cov, n, p->prec, y);
    free(cov);
    free(y);
    if (bad) {
        gs_id_prior_free(p);
        return gs_error_set(err, GS_ERR_STATE,
                            "identity prior: the learned codes' covariance is "
                            "not positive definite");
    }
    *out = p;
    return GS_OK;
}

double gs_id_prior_eval(const gs_id_prior *p, double weight, const double *x,
                        double *grad)
{
    const int n = p->n;
    double q = 0;
    for (int i = 0; i < n; i++) {
        double pd = 0;
        for (int j = 0; j < n; j++)
            pd += p->prec[i * n + j] * (x[j] - p->mean[j]);
        q += (x[i] - p->mean[i]) * pd;
        if (grad)
            grad[i] += 2.0 * weight / n * pd;
    }
    return weight / n * q;
}

double gs_code_prior_eval(const gs_code_prior *p, double weight,
                          const double *x, double *grad)
{
    enum { N = GS_CODE_PRIOR_DIM };
    double d[N], q = 0;
    for (int i = 0; i < N; i++)
        d[i] = x[i] - p->mean[i];
    for (int i = 0; i < N; i++) {
        double pd = 0;
        for (int j = 0; j < N; j++)
            pd += p->prec[i * N + j] * d[j];
        q += d[i] * pd;
        if (grad)
            grad[i] += 2.0 * weight / N * pd;
    }
    return weight / N * q;
}
