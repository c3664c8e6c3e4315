/* Internal layout of a gs_model: configuration, the parameter table and the
 * stream kernels shared by rendering, fitting and training. */
#ifndef GS_MODEL_INTERNAL_H
#define GS_MODEL_INTERNAL_H

#include <stddef.h>
#include <stdint.h>

#include "gazesplat/model.h"
#include "gazesplat/train.h"
#include "gazesplat/raster.h"
#include "renderer.h"

/* ---- configuration (stored in the model file's __metadata__) ---- */
typedef struct gs_model_config {
    int n_face;       /* face-stream Gaussians */
    int n_eye_each;   /* eye-stream Gaussians per eye */
    int feat_dim;     /* per-Gaussian latent feature F */
    int id_dim;       /* identity part of the code */
    int hidden;       /* MLP width */
    int channels;     /* rasterized feature channels (32) */
    int feat_size;    /* feature map edge */
    int image_size;   /* output edge = 4 feat_size */
    int guidance;     /* gs_renderer guidance mode */
    int guide_source; /* gs_renderer guide source; files without the key
                         (before it existed) mean BLOCK */
    int two_stream;   /* 0: single-stream ablation */
    int eye_rotation; /* 0: no explicit eye rotation (ablation) */
    int n_train_ids;  /* auto-decoder codes kept in the file (may be 0) */
    int n_lid0, n_lid1; /* lid Gaussians of eye 0 and eye 1: the last
                           n_lid0 + n_lid1 face Gaussians, eye 0's first
                           (gs_model_add_lids; files without the keys: 0) */
    int supersample;  /* k: the feature map is rasterized at k feat_size and
                         each pixel is the mean of k x k (1..4; files
                         without the key: 1, point-sampled) */
    int eye_direct;   /* 1: the eye stream also drawn at the image's size
                         and composited over the renderer's image
                         (docs/model.md, "The eye at the image's size");
                         needs two streams; files without the key: 0 */
    double template_spacing_mm; /* face Gaussian spacing at creation */
    double d_n_mm;    /* normalized camera distance */
    double focal;     /* normalized camera focal at image_size, pixels */
    double fit_code_prior; /* the weight of the fit's code prior that suits
                              this model (gs_fit_options.code_prior's
                              default; 0..10; files without the key: 0) */
    double fit_code_rate;  /* the fit's Adam rate for the code that suits
                              this model (gs_fit_options.lr_code's default;
                              0: GS_FIT_LR_CODE_DEFAULT, else (0, 10];
                              files without the key: 0) */
} gs_model_config;

/* The latent code tau = [identity (id_dim) | expression (6) | light (12)].
 * Expression and light are per-frame labels in training (the synthetic
 * generator knows them) and free variables when fitting a new face. */
#define GS_MODEL_PI 3.14159265358979323846
#define GS_MODEL_EXPR_DIM 6
#define GS_MODEL_LIGHT_DIM 12
/* Where training put each expression slot (the synthetic sampler's
 * support: mouth_open, smile, squint and blink from 0, brow_raise and
 * pupil from -1; squint at most 0.7): a fit keeps a code's expression in
 * it when gs_fit_options.bound_expression is set. */
static const float gs_model_expr_lo[GS_MODEL_EXPR_DIM] = {0, 0, -1, 0, 0, -1};
static const float gs_model_expr_hi[GS_MODEL_EXPR_DIM] = {1, 1, 1, 0.7f, 1, 1};
/* The library's own checks of a view or a fit's labels (subject.c) see a gaze
 * in radians and a head pose as a rotation, and convert them back to
 * degrees for the target table: deg -> rad -> deg, and the head's angles
 * re-derived from R = Ry(yaw) Rx(-pitch) by asin / atan2, each round by a
 * few ulps (about 1e-13 deg at 70 deg), so exactly +-70 requested may come
 * back as 70.0000000000001. They allow GS_MODEL_RANGE_SLACK_DEG past each
 * limit: far above that rounding, far below any angle that matters, so a
 * target the table accepted (with no slack, as the daemon and the CLI
 * check the degrees they were given) can never be refused here. */
#define GS_MODEL_RANGE_SLACK_DEG 1e-9
int gs_model_check_range_slack(gs_target_field f, double v, double slack,
                               gs_error *err);

static inline int gs_model_code_dim(const gs_model_config *c)
{
    return c->id_dim + GS_MODEL_EXPR_DIM + GS_MODEL_LIGHT_DIM;
}

/* Positional encodings: x, sin(2^k x), cos(2^k x) for k = 0..3. */
#define GS_PE_FREQS 4
#define GS_PE_DIM(n) ((n) * (1 + 2 * GS_PE_FREQS))
void gs_model_pe(const double *x, int n, float *out);
/* d x[n] += the gradient through the encoding from dout[GS_PE_DIM(n)]. */
void gs_model_pe_backward(const double *x, int n, const float *dout,
                          double *dx);

/* Output layout of the face MLPs: position 3, feature C, log-scale 3,
 * quaternion 4, opacity 1. Eye MLP: position 3, feature C, log-scale 1,
 * opacity 1. */
#define GS_FACE_OUT(C) (3 + (C) + 8)
#define GS_EYE_OUT(C) (3 + (C) + 2)

/* Scale factors of the MLP outputs (keep the raw outputs O(1)). */
#define GS_MODEL_POS_SCALE 4.0f   /* mm per unit of position output */
#define GS_MODEL_ATTR_SCALE 0.2f  /* paper: 0.2 for scale/rotation/opacity */
#define GS_MODEL_EYE_POS_SCALE 1.0f

/* The lids' field of k: knots every 30 degrees of azimuth (u: atan2(x,
 * -z) of the rest position about the eyeball's centre, -90..90) and every
 * 15 degrees of elevation (v: atan2(-y, -z), -90..90), clamped at the
 * ends. */
#define GS_LID_NU 7
#define GS_LID_NV 13
#define GS_LID_DU_DEG 30.0
#define GS_LID_DV_DEG 15.0
/* k of lid j (eye e) and the bilinear weights of its four knots (first
 * knot index into the eye's [NV, NU] grid: i, i + 1, i + NU, i + NU + 1). */
static inline float gs_lid_k(const float *K, const float *uv, int e, int j,
                             int *i0, float w[4])
{
    float u = uv[2 * j], v = uv[2 * j + 1];
    int a = (int)u, b = (int)v;
    a = a < 0 ? 0 : a > GS_LID_NU - 2 ? GS_LID_NU - 2 : a;
    b = b < 0 ? 0 : b > GS_LID_NV - 2 ? GS_LID_NV - 2 : b;
    float fu = u - (float)a, fv = v - (float)b;
    w[0] = (1 - fu) * (1 - fv), w[1] = fu * (1 - fv);
    w[2] = (1 - fu) * fv, w[3] = fu * fv;
    const float *k = K + (size_t)e * GS_LID_NU * GS_LID_NV;
    int i = b * GS_LID_NU + a;
    *i0 = e * GS_LID_NU * GS_LID_NV + i;
    return w[0] * k[i] + w[1] * k[i + 1] + w[2] * k[i + GS_LID_NU] +
           w[3] * k[i + GS_LID_NU + 1];
}

/* Lid Gaussians of a configuration (GS_MODEL_LID_RADIUS_MM: train.h). */
static inline int gs_model_n_lid(const gs_model_config *c)
{
    return c->n_lid0 + c->n_lid1;
}

/* ---- parameter table ---- */
enum gs_pgroup {
    GS_PG_GAUSS_XYZ, GS_PG_GAUSS_ATTR, GS_PG_GAUSS_FEAT, GS_PG_MLP,
    GS_PG_RENDERER, GS_PG_CODES, GS_PG_FIXED, GS_PG_COUNT
};

typedef struct gs_ptensor {
    char name[64];
    int ndim;
    int64_t shape[4];
    size_t offset, count;  /* floats, into the parameter array */
    int group;
} gs_ptensor;

#define GS_MODEL_MAX_TENSORS 96

typedef struct gs_mlp {
    int nl;          /* layers */
    int dims[5];     /* dims[0] input .. dims[nl] output */
    float *w[4], *b[4];
} gs_mlp;

/* Pointers into one parameter (or gradient) array. */
typedef struct gs_model_params {
    /* face stream [n_face x ...] */
    float *f_xyz, *f_scale, *f_quat, *f_opacity, *f_colour, *f_feat;
    /* eye stream [2 n_eye_each x ...], right eye first */
    float *e_xyz, *e_scale, *e_opacity, *e_colour, *e_feat;
    float *eye_centre_w;   /* [2, 3, code_dim]: eyeball centre shift */
    gs_mlp face_e;         /* [feat, code] -> GS_FACE_OUT */
    gs_mlp face_p;         /* [feat, PE(pose)] -> GS_FACE_OUT */
    gs_mlp eye;            /* [feat, code, PE(gaze)] -> GS_EYE_OUT */
    gs_mlp eye_rot[2];     /* PE(gaze) -> quaternion residual */
    gs_renderer_params rend;
    float *codes;          /* [n_train_ids, id_dim] auto-decoder codes */
    float *code_mean;      /* [code_dim]: starting point of a fit */
    /* fixed (not trained) */
    float *f_lambda;       /* [n_face]: lambda_tau, distance weight */
    /* lids (NULL without): the share k of the gaze's pitch by which a lid
     * Gaussian turns, a field over the eyeball's directions per eye,
     * [2, GS_LID_NV, GS_LID_NU] (trained, GS_PG_GAUSS_XYZ), read at each
     * lid Gaussian's grid place [n_lid, 2] (u, v; fixed) bilinearly */
    float *lid_k, *lid_uv;
    float *eye_centre;     /* [2, 3] */
} gs_model_params;

struct gs_model {
    gs_model_config cfg;
    gs_renderer_config rcfg;
    int ntensors;
    gs_ptensor t[GS_MODEL_MAX_TENSORS];
    size_t nparams;
    size_t rend_offset;    /* the renderer's packed block */
    float *params;
    gs_model_params p;
    uint64_t id;     /* gs_model_param_id of what it was loaded, created or
                        pruned with; clones and copies carry it over */
    unsigned tuned;  /* GS_FT_* parts fine-tuned since (gs_model_finetune) */
};

/* 1 when a and b have the same tensor table (names, offsets, counts). */
int gs_model_same_layout(const gs_model *a, const gs_model *b);
/* A 64-bit hash of m's tensor table and parameter values. */
uint64_t gs_model_param_id(const gs_model *m);
/* The GS_FT_* part a tensor belongs to (0: never tuned: codes, fixed). */
unsigned gs_model_tensor_part(const gs_ptensor *t);

/* Builds the tensor table of cfg and carves p out of base. */
int gs_model_layout(const gs_model_config *cfg, gs_model *m, gs_error *err);
/* A new model of cfg's layout with zeroed parameters (p not yet bound);
 * `what` names the caller in the out-of-memory message. */
int gs_model_alloc(const gs_model_config *cfg, const char *what, gs_model **out,
                   gs_error *err);
/* m's tensor called name, or NULL. */
const gs_ptensor *gs_model_find_tensor(const gs_model *m, const char *name);
void gs_model_bind(const gs_model *m, float *base, gs_model_params *p);
int gs_model_config_check(const gs_model_config *c, gs_error *err);
/* A code prior weight a fit, a model file or gs_model_set_fit_code_prior
 * accepts: [0, 10] (0: none); NaN is not. */
static inline int gs_code_prior_weight_ok(double w)
{
    return w >= 0.0 && w <= 10.0;
}
/* A fit code rate a model file or gs_model_set_fit_code_rate accepts:
 * [0, 10] (0: the library's default); NaN is not. */
static inline int gs_code_rate_ok(double r)
{
    return r >= 0.0 && r <= 10.0;
}


/* Creates a model with fresh parameters from the synthetic template. */
int gs_model_create(const gs_model_config *cfg, uint64_t seed, gs_model **out,
                    gs_error *err);
int gs_model_save(const gs_model *m, const char *path, gs_error *err);
void gs_model_config_default(gs_model_config *c);

/* The light part of tau for a synthetic scene (head frame). */
struct gs_synth_scene;
void gs_model_light_code(const struct gs_synth_scene *s, float out[12]);

/* The fit's code prior (prior.c): mean and precision of the code's
 * [expression | lights] slots over the training sampler's scenes
 * (gs_train_sample_config with the default options; deterministic). */
#define GS_CODE_PRIOR_DIM (GS_MODEL_EXPR_DIM + GS_MODEL_LIGHT_DIM)
typedef struct gs_code_prior {
    double mean[GS_CODE_PRIOR_DIM];
    double prec[GS_CODE_PRIOR_DIM * GS_CODE_PRIOR_DIM];
} gs_code_prior;
/* Its values, one for every model (prior_table.c, written by
 * test_code_prior --print from gs_train_code_prior, which draws the
 * sampler's scenes: lib/train). */
extern const gs_code_prior gs_code_prior_table;
int gs_train_code_prior(const struct gs_model *m, gs_code_prior *p, gs_error *err);
/* In-place Cholesky of the symmetric positive definite n x n matrix a
 * (lower triangle), then its inverse into inv, exactly symmetric; y: n
 * doubles of scratch. 0, or -1 when a is not positive definite. */
int gs_spd_inverse(double *a, int n, double *inv, double *y);
/* weight / N * (x - mean)^T prec (x - mean) over x = [expression | lights]
 * (N = GS_CODE_PRIOR_DIM: the mean of the squared Mahalanobis terms, about
 * `weight` for a code drawn from the sampler); adds its gradient into grad
 * when grad is not NULL. */
double gs_code_prior_eval(const gs_code_prior *p, double weight,
                          const double *x, double *grad);
/* The fit's prior on the code's identity slots (gs_fit_options.id_prior):
 * a Gaussian with the learned identity codes' mean and covariance. */
typedef struct gs_id_prior gs_id_prior;
int gs_id_prior_make(const struct gs_model *m, gs_id_prior **out,
                     gs_error *err);
void gs_id_prior_free(gs_id_prior *p);
/* weight / n * (x - mean)^T prec (x - mean) over x = the id_dim identity
 * slots; adds its gradient into grad when not NULL. */
double gs_id_prior_eval(const gs_id_prior *p, double weight, const double *x,
                        double *grad);
/* Turns a code's light from head pose R_s to R_v (lights fixed in the
 * camera). */
void gs_model_light_to_view(float *code, int code_dim, const double R_s[9],
                            const double R_v[9]);

/* ---- MLP kernels ---- */
/* Activation floats an MLP needs for a batch of n (pre-activations of the
 * hidden layers, post-activations, output). */
size_t gs_mlp_act_size(const gs_mlp *m, int n);
/* The MLP's weights and biases, floats. */
size_t gs_mlp_param_count(const gs_mlp *m);
/* out[n, dims[nl]] from in[n, dims[0]]; LeakyReLU 0.01 after hidden
 * layers. acts: gs_mlp_act_size floats, kept for the backward. */
void gs_mlp_forward(const gs_mlp *m, const float *in, int n, float *acts,
                    float *out);
/* The rest of gs_mlp_forward when the first layer's pre-activations
 * (n x dims[1]) are already in acts (where gs_mlp_forward puts them). */
void gs_mlp_forward_after_first(const gs_mlp *m, int n, float *acts,
                                float *out);
/* Accumulates weight gradients into g and din[n, dims[0]] (may be NULL). */
void gs_mlp_backward(const gs_mlp *m, const gs_mlp *g, const float *in, int n,
                     const float *acts, const float *dout, float *din,
                     float *scratch);
size_t gs_mlp_scratch_size(const gs_mlp *m, int n);

#endif
