/* Adam over parameter groups with global gradient-norm clipping.
 * The object, its copy of the groups, the chunk table and both moment
 * arrays are one allocation.
 *
 * The parameters are cut into fixed chunks (ADAM_CHUNK of a group at a
 * time), the pool's tasks: the update is element by element, so any
 * thread count gives the same bytes; the squared norm is summed per chunk
 * (four running sums, combined in a fixed order) and then chunk by chunk,
 * so it too is the same for any thread count, with or without a pool. */
#include "gazesplat/nn.h"
#include "gazesplat/pool.h"

#include <limits.h>
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#define ADAM_CHUNK 32768

typedef struct adam_chunk {
    int group;
    size_t from, n; /* elements [from, from + n) of the group */
} adam_chunk;

struct gs_nn_adam {
    gs_nn_adam_config cfg;
    long t;
    int ngroups;
    gs_nn_param_group *groups; /* [ngroups] */
    size_t *offset;            /* [ngroups] first moment index of each group */
    float *m, *v;              /* [total] each */
    int nchunks;
    adam_chunk *chunks;        /* [nchunks] */
    double *partial;           /* [nchunks] squared norms */
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
    size_t ng = (size_t)ngroups, nch = 0;
    for (int i = 0; i < ngroups; i++)
        nch += (groups[i].n + ADAM_CHUNK - 1) / ADAM_CHUNK;
    if (nch > INT_MAX)
        return gs_error_set(err, GS_ERR_LIMIT, "adam: too many parameters");
    size_t off_groups = align64(sizeof(gs_nn_adam));
    size_t off_offset = align64(off_groups + ng * sizeof(gs_nn_param_group));
    size_t off_chunks = align64(off_offset + ng * sizeof(size_t));
    size_t off_partial = align64(off_chunks + nch * sizeof(adam_chunk));
    size_t off_m = align64(off_partial + nch * sizeof(double));
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
    a->chunks = carve(base, off_chunks);
    a->partial = carve(base, off_partial);
    a->nchunks = (int)nch;
    size_t at = 0;
    int k = 0;
    for (int i = 0; i < ngroups; i++) {
        a->groups[i] = groups[i];
        a->offset[i] = at;
        at += groups[i].n;
        for (size_t f = 0; f < groups[i].n; f += ADAM_CHUNK) {
            size_t left = groups[i].n - f;
            a->chunks[k].group = i;
            a->chunks[k].from = f;
            a->chunks[k].n = left < ADAM_CHUNK ? left : ADAM_CHUNK;
            k++;
        }
    }
    *out = a;
    return GS_OK;
}

void gs_nn_adam_destroy(gs_nn_adam *adam)
{
    free(adam);
}

/* The squared gradient of chunk k, in double: four running sums over
 * j mod 4, then (s0 + s1) + (s2 + s3). */
static void norm_task(void *ctx, int k, int worker)
{
    (void)worker;
    gs_nn_adam *a = ctx;
    const adam_chunk *ch = &a->chunks[k];
    const float *g = a->groups[ch->group].grad + ch->from;
    double s[4] = {0, 0, 0, 0};
    size_t j = 0;
    for (; j + 4 <= ch->n; j += 4)
        for (int q = 0; q < 4; q++)
            s[q] += (double)g[j + q] * g[j + q];
    for (; j < ch->n; j++)
        s[j & 3] += (double)g[j] * g[j];
    a->partial[k] = (s[0] + s[1]) + (s[2] + s[3]);
}

/* The PyTorch single-tensor Adam update, in its operation order. */
typedef struct update_job {
    gs_nn_adam *a;
    double lr;
    float clip, bc2_sqrt;
    double bc1;
} update_job;

static void update_task(void *ctx, int k, int worker)
{
    (void)worker;
    const update_job *u = ctx;
    gs_nn_adam *a = u->a;
    const adam_chunk *ch = &a->chunks[k];
    const gs_nn_param_group *grp = &a->groups[ch->group];
    const gs_nn_adam_config *c = &a->cfg;
    size_t at = a->offset[ch->group] + ch->from;
    float *restrict m = a->m + at, *restrict v = a->v + at;
    float *restrict param = grp->param + ch->from;
    const float *restrict grad = grp->grad + ch->from;
    float step_size = (float)(u->lr * grp->lr_mult / u->bc1);
    float b1 = (float)c->beta1, b2 = (float)c->beta2, eps = (float)c->eps;
    float a1 = (float)(1.0 - c->beta1), a2 = (float)(1.0 - c->beta2);
    float clip = u->clip, bc2_sqrt = u->bc2_sqrt;
    for (size_t j = 0; j < ch->n; j++) {
        float g = grad[j] * clip;
        m[j] = m[j] * b1 + g * a1;
        v[j] = v[j] * b2 + a2 * (g * g);
        float denom = sqrtf(v[j]) / bc2_sqrt + eps;
        param[j] += -step_size * (m[j] / denom);
    }
}

int gs_nn_adam_step_pool(gs_nn_adam *adam, gs_pool *pool, double lr,
                         double *grad_norm_out)
{
    if (!adam || !(lr >= 0.0) || !isfinite(lr))
        return GS_ERR_ARG;
    gs_pool_for(pool, adam->nchunks, norm_task, adam);
    double ss = 0.0;
    for (int k = 0; k < adam->nchunks; k++)
        ss += adam->partial[k];
    double norm = sqrt(ss);
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
    update_job u = {adam, lr, clip, 0.0f, 0.0};
    u.bc1 = 1.0 - pow(adam->cfg.beta1, (double)adam->t);
    u.bc2_sqrt = (float)sqrt(1.0 - pow(adam->cfg.beta2, (double)adam->t));
    gs_pool_for(pool, adam->nchunks, update_task, &u);
    return GS_OK;
}

int gs_nn_adam_step(gs_nn_adam *adam, double lr, double *grad_norm_out)
{
    return gs_nn_adam_step_pool(adam, NULL, lr, grad_norm_out);
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
