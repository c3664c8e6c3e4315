/* A fresh model: neutral Gaussians from the synthetic head's template,
 * MLPs and renderer at their initial values, from a preset (gs_model_new)
 * or a full configuration. Training starts here; a program that only
 * loads, fits and renders a model never does (no synthetic head). */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "gazesplat/synth.h"
#include "gazesplat/train.h"
#include "../model/model_internal.h"

/* Distance weights of the face stream (plain distances, not squared): a
 * Gaussian within D1 of a landmark follows the code fully, beyond D2 it
 * follows the head pose only. */
#define GS_LAMBDA_D1_MM 20.0
#define GS_LAMBDA_D2_MM 40.0
/* Eye Gaussians cover each eyeball's front cap up to this angle. */
#define GS_EYE_CAP_DEG 75.0

typedef struct rng64 {
    uint64_t s;
} rng64;

static uint64_t rng_next(rng64 *r)
{
    uint64_t z = (r->s += 0x9e3779b97f4a7c15ULL);
    z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ULL;
    z = (z ^ (z >> 27)) * 0x94d049bb133111ebULL;
    return z ^ (z >> 31);
}

static double rng_uniform(rng64 *r)
{
    return (double)(rng_next(r) >> 11) * (1.0 / 9007199254740992.0);
}

static double rng_normal(rng64 *r)
{
    double u = rng_uniform(r), v = rng_uniform(r);
    if (u < 1e-300)
        u = 1e-300;
    return sqrt(-2.0 * log(u)) * cos(6.283185307179586 * v);
}

/* Which template points the face stream keeps: head and face surface
 * facing the front half (a normalized camera never sees the back of the
 * head or below the neck), plus the eye regions in the single-stream
 * ablation. */
static int keep_point(const gs_synth_template *t, int i, int two_stream)
{
    int r = t->region[i];
    if (two_stream && (r == GS_SYNTH_REGION_LEFT_EYE ||
                       r == GS_SYNTH_REGION_RIGHT_EYE))
        return 0;
    if (t->normal[3 * i + 2] > 0.3f)
        return 0;
    if (t->xyz[3 * i + 1] > 125.0f)
        return 0;
    return 1;
}

/* Quaternion (wxyz) turning e_z to unit n. */
static void quat_from_z(const float n[3], float q[4])
{
    double w = 1.0 + n[2];
    if (w < 1e-6) { /* n = -z: half turn about x */
        q[0] = 0; q[1] = 1; q[2] = 0; q[3] = 0;
        return;
    }
    double x = -n[1], y = n[0], z = 0.0;
    double s = sqrt(w * w + x * x + y * y + z * z);
    q[0] = (float)(w / s); q[1] = (float)(x / s);
    q[2] = (float)(y / s); q[3] = (float)(z / s);
}

static void init_mlp(const gs_mlp *m, rng64 *r, float last_scale)
{
    for (int l = 0; l < m->nl; l++) {
        int ic = m->dims[l], oc = m->dims[l + 1];
        double b = 1.0 / sqrt((double)ic);
        float k = l + 1 == m->nl ? last_scale : 1.0f;
        for (size_t i = 0; i < (size_t)ic * oc; i++)
            m->w[l][i] = k * (float)((2.0 * rng_uniform(r) - 1.0) * b);
        for (int i = 0; i < oc; i++)
            m->b[l][i] = k * (float)((2.0 * rng_uniform(r) - 1.0) * b);
    }
}

static void init_face(gs_model *m, const gs_synth_template *t, rng64 *r)
{
    gs_model_params *p = &m->p;
    int C = m->cfg.channels, F = m->cfg.feat_dim, j = 0;
    double sp = m->cfg.template_spacing_mm;
    for (int i = 0; i < t->n; i++) {
        if (!keep_point(t, i, m->cfg.two_stream))
            continue;
        memcpy(p->f_xyz + 3 * j, t->xyz + 3 * i, 3 * sizeof(float));
        quat_from_z(t->normal + 3 * i, p->f_quat + 4 * j);
        p->f_scale[3 * j] = p->f_scale[3 * j + 1] = (float)log(0.6 * sp);
        p->f_scale[3 * j + 2] = (float)log(0.2 * sp);
        p->f_opacity[j] = 1.5f; /* sigmoid 0.82 */
        for (int k = 0; k < 3; k++)
            p->f_colour[(size_t)j * C + k] = t->rgb[3 * i + k];
        for (int k = 0; k < F; k++)
            p->f_feat[(size_t)j * F + k] = (float)(0.5 * rng_normal(r));
        double dmin = 1e30;
        for (int l = 0; l < GS_SYNTH_LANDMARKS; l++) {
            double d = 0;
            for (int k = 0; k < 3; k++) {
                double e = t->xyz[3 * i + k] - t->landmarks[l][k];
                d += e * e;
            }
            dmin = d < dmin ? d : dmin;
        }
        double lam = (GS_LAMBDA_D2_MM - sqrt(dmin)) /
                     (GS_LAMBDA_D2_MM - GS_LAMBDA_D1_MM);
        p->f_lambda[j] = (float)(lam < 0 ? 0 : lam > 1 ? 1 : lam);
        j++;
    }
}

/* Fibonacci points on the front cap of each eyeball, coloured as pupil,
 * iris and sclera by their angle from the optical axis (-z). */
static void init_eyes(gs_model *m, const gs_synth_template *t, rng64 *r)
{
    gs_model_params *p = &m->p;
    int each = m->cfg.n_eye_each, C = m->cfg.channels, F = m->cfg.feat_dim;
    double rad = t->eyeball_radius_mm;
    double cap = 1.0 - cos(GS_EYE_CAP_DEG * GS_MODEL_PI / 180.0);
    double area = 2.0 * GS_MODEL_PI * rad * rad * cap / each;
    float s = (float)log(0.6 * sqrt(area));
    for (int e = 0; e < 2; e++) {
        for (int k = 0; k < 3; k++)
            p->eye_centre[3 * e + k] = (float)t->eye_centre[e][k];
        for (int i = 0; i < each; i++) {
            int g = e * each + i;
            double z = 1.0 - cap * (i + 0.5) / each; /* cos of the angle */
            double rr = sqrt(1.0 - z * z);
            double phi = i * 2.399963229728653;
            double dir[3] = {rr * cos(phi), rr * sin(phi), -z};
            for (int k = 0; k < 3; k++)
                p->e_xyz[3 * g + k] = (float)(t->eye_centre[e][k] +
                                              rad * dir[k]);
            double ang = acos(z) * 180.0 / GS_MODEL_PI;
            float c = ang < 8.0 ? 0.05f : ang < 28.0 ? 0.35f : 0.9f;
            p->e_colour[(size_t)g * C] = c;
            p->e_colour[(size_t)g * C + 1] = ang < 28.0 ? 0.8f * c : c;
            p->e_colour[(size_t)g * C + 2] = ang < 28.0 ? 0.6f * c : c;
            p->e_scale[g] = s;
            p->e_opacity[g] = 2.2f; /* sigmoid 0.9 */
            for (int k = 0; k < F; k++)
                p->e_feat[(size_t)g * F + k] = (float)(0.5 * rng_normal(r));
        }
    }
}

static int count_face(const gs_synth_template *t, int two_stream)
{
    int n = 0;
    for (int i = 0; i < t->n; i++)
        n += keep_point(t, i, two_stream);
    return n;
}

int gs_model_create(const gs_model_config *cfg_in, uint64_t seed,
                    gs_model **out, gs_error *err)
{
    gs_synth_template t;
    int rc = gs_synth_template_build(cfg_in->template_spacing_mm, NULL, &t,
                                     err);
    if (rc)
        return rc;
    gs_model_config cfg = *cfg_in;
    cfg.n_face = count_face(&t, cfg.two_stream);
    gs_model *m = NULL;
    rc = gs_model_alloc(&cfg, "model", &m, err);
    if (rc) {
        gs_synth_template_free(&t);
        return rc;
    }
    gs_model_bind(m, m->params, &m->p);
    rng64 r = {seed ^ 0x6d6f64656cULL};
    init_face(m, &t, &r);
    init_eyes(m, &t, &r);
    gs_model_params *p = &m->p;
    init_mlp(&p->face_e, &r, 0.01f);
    init_mlp(&p->face_p, &r, 0.01f);
    init_mlp(&p->eye, &r, 0.01f);
    for (int e = 0; e < 2; e++)
        init_mlp(&p->eye_rot[e], &r, 0.0f); /* residual rotation = I */
    gs_renderer_init(&m->rcfg, m->params + m->rend_offset,
                     gs_renderer_param_count(&m->rcfg), rng_next(&r));
    if (p->codes)
        for (size_t i = 0; i < (size_t)cfg.n_train_ids * cfg.id_dim; i++)
            p->codes[i] = (float)(0.01 * rng_normal(&r));
    gs_synth_template_free(&t);
    m->id = gs_model_param_id(m);
    *out = m;
    return GS_OK;
}

void gs_model_spec_default(gs_model_spec *s)
{
    memset(s, 0, sizeof *s);
    s->preset = "cpu";
    s->train_identities = 64;
    s->guidance = -1;
    s->two_stream = -1;
    s->eye_rotation = -1;
    s->guide_source = -1;
    s->lids = -1;
    s->supersample = -1;
    s->eye_direct = -1;
}

int gs_model_new(const gs_model_spec *s, uint64_t seed, gs_model **out,
                 gs_error *err)
{
    gs_model_config c;
    gs_model_config_default(&c);
    const char *preset = s->preset ? s->preset : "cpu";
    if (strcmp(preset, "tiny") == 0) {
        c.template_spacing_mm = 6.0;
        c.n_eye_each = 150;
        c.feat_dim = 16;
        c.id_dim = 8;
        c.hidden = 32;
        c.feat_size = 32;
        c.image_size = 128;
        c.focal = 1600.0 * 128 / 512;
    } else if (strcmp(preset, "paper") == 0) {
        c.template_spacing_mm = 1.5;
        c.n_eye_each = 2000;
        c.feat_dim = 128;
        c.id_dim = 80;
        c.hidden = 256;
        c.feat_size = 128;
        c.image_size = 512;
        c.focal = 1600.0;
    } else if (strcmp(preset, "cpu") != 0) {
        return gs_error_set(err, GS_ERR_ARG,
                            "unknown model preset '%s' (cpu, tiny, paper)",
                            preset);
    }
    c.n_train_ids = s->train_identities;
    if (s->guidance >= 0)
        c.guidance = s->guidance;
    if (s->two_stream >= 0)
        c.two_stream = s->two_stream;
    if (s->eye_rotation >= 0)
        c.eye_rotation = s->eye_rotation;
    if (s->guide_source >= 0)
        c.guide_source = s->guide_source;
    if (s->supersample >= 0)
        c.supersample = s->supersample;
    if (s->eye_direct >= 0)
        c.eye_direct = s->eye_direct;
    c.n_face = 1; /* counted from the template by gs_model_create */
    int rc = gs_model_create(&c, seed, out, err);
    if (rc || s->lids != 1)
        return rc;
    gs_model *l = NULL;
    rc = gs_model_add_lids(*out, GS_MODEL_LID_RADIUS_MM, &l, err);
    gs_model_destroy(*out);
    *out = l;
    return rc;
}
