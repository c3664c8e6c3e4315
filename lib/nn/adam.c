/* Adam over parameter groups with global gradient-norm clipping.
 * The object, its copy of the groups and both moment arrays are one
 * allocation. */
#include "gazesplat/nn.h"

#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

struct gs_nn_adam {
    gs_nn_adam_config cfg;
    long t;
    int ngroups;
    gs_nn_param_group *groups; /* [ngroups] */
    size_t *offset;            /* [ngroups] first moment index of each group */
    float *m, *v;              /* [total] each */
};

gs_nn_adam_config gs_nn_adam_default_config(void)
{
    gs_nn_adam_config c = {0.9, 0.999, 1e-8, 0.0};
    return c;
}

static size_t align64(size_t n)
{
    return (n + 63) & ~(size_t)63;
}

/* base + off bytes, as a void pointer for the carved arrays. */
static void *carve(void *base, size_t off)
{
    return (unsigned char *)base + off;
}

static int check_config(const gs_nn_adam_config *c, gs_error *err)
{
    if (!(c->beta1 >= 0.0 && c->beta1 < 1.0) ||
        !(c->beta2 >= 0.0 && c->beta2 < 1.0))
        return gs_error_set(err, GS_ERR_ARG, "adam: betas %g, %g not in [0, 1)",
                            c->beta1, c->beta2);
    if (!(c->eps > 0.0) || !isfinite(c->eps))
        return gs_error_set(err, GS_ERR_ARG, "adam: eps %g not > 0", c->eps);
    if (!isfinite(c->max_grad_norm))
        return gs_error_set(err, GS_ERR_ARG, "adam: max_grad_norm not finite");
    return GS_OK;
}

/* Validates the groups; *total = the number of parameters. */
static int check_groups(const gs_nn_param_group *groups, int ngroups,
                        size_t *total, gs_error *err)
{
    if (!groups || ngroups < 1)
        return gs_error_set(err, GS_ERR_ARG, "adam: no parameter groups");
    *total = 0;
    for (int i = 0; i < ngroups; i++) {
        const gs_nn_param_group *g = &groups[i];
        if (!g->param || !g->grad || g->n == 0)
            return gs_error_set(err, GS_ERR_ARG,
                                "adam: group %d has no data or n = 0", i);
        if (!(g->lr_mult >= 0.0) || !isfinite(g->lr_mult))
            return gs_error_set(err, GS_ERR_ARG,
                                "adam: group %d lr_mult %g not finite >= 0", i,
                                g->lr_mult);
        if (g->n > SIZE_MAX / (4 * sizeof(float)) - *total)
            return gs_error_set(err, GS_ERR_LIMIT, "adam: too many parameters");
        *total += g->n;
    }
    return GS_OK;
}

int gs_nn_adam_create(gs_nn_adam **out, const gs_nn_param_group *groups,
                      int ngroups, const gs_nn_adam_config *cfg, gs_error *err)
{
    if (!out)
        return gs_error_set(err, GS_ERR_ARG, "adam: out is NULL");
    *out = NULL;
    gs_nn_adam_config c = cfg ? *cfg : gs_nn_adam_default_config();
    size_t total = 0;
    int rc = check_config(&c, err);
    if (rc == GS_OK)
        rc = check_groups(groups, ngroups, &total, err);
    if (rc)
        return rc;
    size_t ng = (size_t)ngroups;
    size_t off_groups = align64(sizeof(gs_nn_adam));
    size_t off_offset = align64(off_groups + ng * sizeof(gs_nn_param_group));
    size_t off_m = align64(off_offset + ng * sizeof(size_t));
    size_t off_v = align64(off_m + total * sizeof(float));
    size_t bytes = off_v + total * sizeof(float);
    void *base = calloc(1, bytes);
    if (!base)
        return gs_error_set(err, GS_ERR_NOMEM, "adam: cannot allocate %zu bytes",
                            bytes);
    gs_nn_adam *a = base;
    a->cfg = c;
    a->ngroups = ngroups;
    a->groups = carve(base, off_groups);
    a->offset = carve(base, off_offset);
    a->m = carve(base, off_m);
    a->v = carve(base, off_v);
    size_t at = 0;
    for (int i = 0; i < ngroups; i++) {
        a->groups[i] = groups[i];
        a->offset[i] = at;
        at += groups[i].n;
    }
    *out = a;
    return GS_OK;
}

void gs_nn_adam_destroy(gs_nn_adam *adam)
{
    free(adam);
}

/* L2 norm of every gradient, summed in double in group order. */
static double grad_norm(const gs_nn_adam *a)
{
    double ss = 0.0;
    for (int i = 0; i < a->ngroups; i++) {
        const float *g = a->groups[i].grad;
        for (size_t j = 0; j < a->groups[i].n; j++)
            ss += (double)g[j] * g[j];
    }
    return sqrt(ss);
}

/* The PyTorch single-tensor Adam update, in its operation order. */
static void update_group(const gs_nn_param_group *grp, float *m, float *v,
                         const gs_nn_adam_config *c, float clip,
                         float step_size, float bc2_sqrt)
{
    float b1 = (float)c->beta1, b2 = (float)c->beta2, eps = (float)c->eps;
    float a1 = (float)(1.0 - c->beta1), a2 = (float)(1.0 - c->beta2);
    for (size_t j = 0; j < grp->n; j++) {
        float g = grp->grad[j] * clip;
        m[j] = m[j] * b1 + g * a1;
        v[j] = v[j] * b2 + a2 * (g * g);
        float denom = sqrtf(v[j]) / bc2_sqrt + eps;
        grp->param[j] += -step_size * (m[j] / denom);
    }
}

int gs_nn_adam_step(gs_nn_adam *adam, double lr, double *grad_norm_out)
{
    if (!adam || !(lr >= 0.0) || !isfinite(lr))
        return GS_ERR_ARG;
    double norm = grad_norm(adam);
    if (grad_norm_out)
        *grad_norm_out = norm;
    if (!isfinite(norm))
        return GS_ERR_NONFINITE; /* nothing changed: the caller skips */
    float clip = 1.0f;
    if (adam->cfg.max_grad_norm > 0.0) {
        double coef = adam->cfg.max_grad_norm / (norm + 1e-6);
        if (coef < 1.0)
            clip = (float)coef;
    }
    adam->t++;
    double bc1 = 1.0 - pow(adam->cfg.beta1, (double)adam->t);
    double bc2 = 1.0 - pow(adam->cfg.beta2, (double)adam->t);
    for (int i = 0; i < adam->ngroups; i++) {
        const gs_nn_param_group *grp = &adam->groups[i];
        float step_size = (float)(lr * grp->lr_mult / bc1);
        update_group(grp, adam->m + adam->offset[i], adam->v + adam->offset[i],
                     &adam->cfg, clip, step_size, (float)sqrt(bc2));
    }
    return GS_OK;
}

void gs_nn_adam_zero_grad(gs_nn_adam *adam)
{
    for (int i = 0; adam && i < adam->ngroups; i++)
        memset(adam->groups[i].grad, 0, adam->groups[i].n * sizeof(float));
}

long gs_nn_adam_steps(const gs_nn_adam *adam)
{
    return adam ? adam->t : 0;
}

int gs_nn_adam_set_steps(gs_nn_adam *adam, long t)
{
    if (!adam || t < 0)
        return GS_ERR_ARG;
    adam->t = t;
    return GS_OK;
}

int gs_nn_adam_moments(gs_nn_adam *adam, int g, float **m, float **v)
{
    if (!adam || g < 0 || g >= adam->ngroups)
        return GS_ERR_ARG;
    if (m)
        *m = adam->m + adam->offset[g];
    if (v)
        *v = adam->v + adam->offset[g];
    return GS_OK;
}
