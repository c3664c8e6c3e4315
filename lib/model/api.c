/* The public face of the model: subjects, rendering and fitting. */
#define _POSIX_C_SOURCE 200809L
#include <float.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "gazesplat/clock.h"
#include "frame.h"
#include "gazesplat/geom.h"
#include "gazesplat/nn.h"

/* ---- subjects ---- */

#define GS_SUBJECT_MAGIC 0x42555347u /* "GSUB" */
#define GS_SUBJECT_VERSION 1u

typedef struct wbuf {
    uint8_t *p;
    size_t n, cap;
} wbuf;

static void put(wbuf *b, const void *v, size_t n)
{
    /* Little-endian hosts only (checked at build time in CMake); the
     * bytes are the in-memory representation. */
    if (b->p && b->n + n <= b->cap)
        memcpy(b->p + b->n, v, n);
    b->n += n;
}

size_t gs_subject_encode(const gs_subject *s, uint8_t *buf, size_t cap)
{
    wbuf b = {buf, 0, cap};
    uint32_t magic = GS_SUBJECT_MAGIC, ver = GS_SUBJECT_VERSION;
    uint32_t dim = (uint32_t)s->code_dim;
    put(&b, &magic, 4);
    put(&b, &ver, 4);
    put(&b, &dim, 4);
    put(&b, s->code, sizeof(float) * (size_t)s->code_dim);
    put(&b, s->head_R, sizeof s->head_R);
    put(&b, s->head_t, sizeof s->head_t);
    put(&b, &s->gaze_pitch, 8);
    put(&b, &s->gaze_yaw, 8);
    put(&b, s->colour_gain, sizeof s->colour_gain);
    put(&b, s->colour_bias, sizeof s->colour_bias);
    put(&b, &s->fit_psnr, 4);
    put(&b, &s->fit_ssim, 4);
    return b.n;
}

static int all_finite_d(const double *v, int n)
{
    for (int i = 0; i < n; i++)
        if (!isfinite(v[i]))
            return 0;
    return 1;
}

static int all_finite_f(const float *v, int n)
{
    for (int i = 0; i < n; i++)
        if (!isfinite(v[i]))
            return 0;
    return 1;
}

size_t gs_subject_encoded_len(const uint8_t *buf, size_t len)
{
    uint32_t dim;
    if (!buf || len < 12)
        return 0;
    memcpy(&dim, buf + 8, 4);
    if (dim < 1 || dim > GS_MODEL_MAX_CODE)
        return 0;
    gs_subject s;
    memset(&s, 0, sizeof s);
    s.code_dim = (int)dim;
    return gs_subject_encode(&s, NULL, 0);
}

int gs_subject_decode(const uint8_t *buf, size_t len, gs_subject *out,
                      gs_error *err)
{
    uint32_t magic, ver, dim;
    if (!buf || len < 12)
        return gs_error_set(err, GS_ERR_FORMAT, "subject: %zu bytes", len);
    memcpy(&magic, buf, 4);
    memcpy(&ver, buf + 4, 4);
    memcpy(&dim, buf + 8, 4);
    if (magic != GS_SUBJECT_MAGIC)
        return gs_error_set(err, GS_ERR_FORMAT, "subject: bad magic");
    if (ver != GS_SUBJECT_VERSION)
        return gs_error_set(err, GS_ERR_UNSUPPORTED, "subject: version %u",
                            ver);
    if (dim < 1 || dim > GS_MODEL_MAX_CODE)
        return gs_error_set(err, GS_ERR_FORMAT, "subject: code_dim %u", dim);
    gs_subject s;
    memset(&s, 0, sizeof s);
    s.code_dim = (int)dim;
    size_t need = gs_subject_encode(&s, NULL, 0);
    if (len != need)
        return gs_error_set(err, GS_ERR_FORMAT,
                            "subject: %zu bytes, %zu expected", len, need);
    const uint8_t *p = buf + 12;
#define GET(dst, n) do { memcpy((dst), p, (n)); p += (n); } while (0)
    GET(s.code, 4 * (size_t)dim);
    GET(s.head_R, sizeof s.head_R);
    GET(s.head_t, sizeof s.head_t);
    GET(&s.gaze_pitch, 8);
    GET(&s.gaze_yaw, 8);
    GET(s.colour_gain, sizeof s.colour_gain);
    GET(s.colour_bias, sizeof s.colour_bias);
    GET(&s.fit_psnr, 4);
    GET(&s.fit_ssim, 4);
#undef GET
    if (!all_finite_f(s.code, s.code_dim) || !all_finite_d(s.head_R, 9) ||
        !all_finite_d(s.head_t, 3) || !isfinite(s.gaze_pitch) ||
        !isfinite(s.gaze_yaw) || !all_finite_f(s.colour_gain, 3) ||
        !all_finite_f(s.colour_bias, 3))
        return gs_error_set(err, GS_ERR_NONFINITE, "subject: non-finite value");
    *out = s;
    return GS_OK;
}

/* ---- checks ---- */

static int check_rotation(const double R[9], gs_error *err)
{
    if (!all_finite_d(R, 9))
        return gs_error_set(err, GS_ERR_NONFINITE, "head rotation not finite");
    double rt[9], e = 0;
    gs_geom_mat3_transpose(R, rt);
    gs_geom_mat3_mul(rt, R, rt);
    for (int i = 0; i < 9; i++)
        e = fmax(e, fabs(rt[i] - (i % 4 == 0 ? 1.0 : 0.0)));
    if (e > 1e-3)
        return gs_error_set(err, GS_ERR_ARG,
                            "head rotation is not orthonormal (error %g)", e);
    return GS_OK;
}

static int check_pose(const double R[9], const double t[3], gs_error *err)
{
    int rc = check_rotation(R, err);
    if (rc)
        return rc;
    if (!all_finite_d(t, 3))
        return gs_error_set(err, GS_ERR_NONFINITE,
                            "head translation not finite");
    if (!(t[2] > 100.0 && t[2] < 5000.0))
        return gs_error_set(err, GS_ERR_ARG,
                            "head distance %.1f mm outside 100..5000", t[2]);
    double p, y;
    /* The head frame's z points into the head; a frontal head has z along
     * the camera's +z, and its angles are those of -z. */
    double z[3] = {-R[2], -R[5], -R[8]};
    gs_geom_vec_to_pitchyaw(z, &p, &y);
    /* Degrees for the target table, with its slack for the rounding of
     * the angles re-derived from R (model_internal.h). */
    const double slack = GS_MODEL_RANGE_SLACK_DEG;
    rc = gs_model_check_range_slack(GS_TARGET_HEAD_PITCH,
                                    p / GS_MODEL_DEG_TO_RAD, slack, err);
    if (!rc)
        rc = gs_model_check_range_slack(GS_TARGET_HEAD_YAW,
                                        y / GS_MODEL_DEG_TO_RAD, slack, err);
    return rc;
}

static int check_gaze(double pitch, double yaw, gs_error *err)
{
    const double slack = GS_MODEL_RANGE_SLACK_DEG;
    int rc = gs_model_check_range_slack(GS_TARGET_GAZE_PITCH,
                                        pitch / GS_MODEL_DEG_TO_RAD, slack, err);
    if (!rc)
        rc = gs_model_check_range_slack(GS_TARGET_GAZE_YAW,
                                        yaw / GS_MODEL_DEG_TO_RAD, slack, err);
    return rc;
}

static int check_subject(const gs_model *m, const gs_subject *s,
                         gs_error *err)
{
    if (s->code_dim != gs_model_code_dim(&m->cfg))
        return gs_error_set(err, GS_ERR_ARG,
                            "subject code_dim %d, model has %d", s->code_dim,
                            gs_model_code_dim(&m->cfg));
    if (!all_finite_f(s->code, s->code_dim) ||
        !all_finite_f(s->colour_gain, 3) || !all_finite_f(s->colour_bias, 3))
        return gs_error_set(err, GS_ERR_NONFINITE, "subject not finite");
    return check_pose(s->head_R, s->head_t, err);
}

/* ---- rendering ---- */

static float srgb_byte(float v)
{
    v = v < 0 ? 0 : v > 1 ? 1 : v;
    return floorf(v * 255.0f + 0.5f);
}

/* rgb8 over the image box b from the float image under the colour
 * transform tf (gain, bias); refuses a non-finite pixel. */
static int convert_box(gs_model_ctx *c, const float tf[6], const int b[4],
                       gs_error *err)
{
    int S = c->S;
    size_t plane = (size_t)S * S;
    for (int y = b[1]; y < b[3]; y++) {
        uint8_t *row = c->rgb8 + (size_t)y * 3 * S;
        for (int k = 0; k < 3; k++) {
            const float *src = c->rgb + k * plane + (size_t)y * S;
            int bad = 0;
            for (int x = b[0]; x < b[2]; x++) {
                float v = tf[k] * src[x] + tf[3 + k];
                bad |= !(fabsf(v) <= FLT_MAX); /* NaN or infinite */
                row[3 * x + k] = (uint8_t)srgb_byte(bad ? 0.0f : v);
            }
            if (bad)
                return gs_error_set(err, GS_ERR_NONFINITE,
                                    "render: non-finite pixel in row %d", y);
        }
    }
    return GS_OK;
}

/* Writes the frame's image with the subject's colour transform; refuses a
 * non-finite pixel. The context keeps its 8-bit image: when the transform
 * is the last one, only what the render changed is converted again. */
static int write_image(gs_model_ctx *c, const gs_subject *s, uint8_t *rgb,
                       size_t stride, gs_error *err)
{
    int S = c->S, all[4] = {0, 0, S, S};
    float tf[6];
    memcpy(tf, s->colour_gain, 3 * sizeof(float));
    memcpy(tf + 3, s->colour_bias, 3 * sizeof(float));
    const int *box = all;
    if (c->rgb8_valid && !memcmp(tf, c->rgb8_tf, sizeof tf))
        box = c->rgb_dirty;
    c->rgb8_valid = 0;
    if (box[0] < box[2] && box[1] < box[3]) {
        int rc = convert_box(c, tf, box, err);
        if (rc)
            return rc;
    }
    c->rgb8_valid = 1;
    memcpy(c->rgb8_tf, tf, sizeof tf);
    memset(c->rgb_dirty, 0, sizeof c->rgb_dirty);
    for (int y = 0; y < S; y++)
        memcpy(rgb + (size_t)y * stride, c->rgb8 + (size_t)y * 3 * S,
               3 * (size_t)S);
    return GS_OK;
}

/* The light part of a code is in the head frame (training labels: the
 * scene's lights turned into the head). The lights stay where they are in
 * the camera when the head turns, so a view at another head pose sees them
 * turned the other way: each colour's direction vector goes from the
 * subject's head frame (R_s) to the view's (R_v), dh' = R_v^T R_s dh; the
 * ambient colour is the same in any frame. */
void gs_model_light_to_view(float *code, int code_dim, const double R_s[9],
                            const double R_v[9])
{
    float *l = code + code_dim - GS_MODEL_LIGHT_DIM;
    for (int c = 0; c < 3; c++) {
        double dh[3] = {l[3 * c], l[3 * c + 1], l[3 * c + 2]}, d[3], o[3];
        gs_geom_mat3_vec(R_s, dh, d);
        gs_geom_mat3_tvec(R_v, d, o);
        for (int k = 0; k < 3; k++)
            l[3 * c + k] = (float)o[k];
    }
}

static void frame_of(const gs_subject *s, const gs_view *v, gs_frame *fr)
{
    memset(fr, 0, sizeof *fr);
    memcpy(fr->code, s->code, sizeof(float) * (size_t)s->code_dim);
    const double *R = v && v->use_head ? v->head_R : s->head_R;
    const double *t = v && v->use_head ? v->head_t : s->head_t;
    if (v && !v->light_on_head && memcmp(R, s->head_R, sizeof fr->head_R))
        gs_model_light_to_view(fr->code, s->code_dim, s->head_R, R);
    memcpy(fr->head_R, R, sizeof fr->head_R);
    memcpy(fr->head_t, t, sizeof fr->head_t);
    fr->gaze[0] = v ? v->gaze_pitch : s->gaze_pitch;
    fr->gaze[1] = v ? v->gaze_yaw : s->gaze_yaw;
}

int gs_model_render(gs_model_ctx *c, gs_pool *pool, const gs_subject *s,
                    const gs_view *view, uint8_t *rgb, size_t stride,
                    gs_error *err)
{
    if (!c || !s || !view || !rgb)
        return gs_error_set(err, GS_ERR_ARG, "render: NULL argument");
    if (stride < 3 * (size_t)c->S)
        return gs_error_set(err, GS_ERR_ARG, "render: stride %zu < %d",
                            stride, 3 * c->S);
    int rc = check_subject(c->m, s, err);
    if (!rc)
        rc = check_gaze(view->gaze_pitch, view->gaze_yaw, err);
    if (!rc && view->use_head)
        rc = check_pose(view->head_R, view->head_t, err);
    if (rc)
        return rc;
    gs_frame fr;
    frame_of(s, view, &fr);
    /* A gaze-only render of a subject the context keeps no render of starts
     * with the subject at its own gaze: the anchor every later gaze of it
     * renders from (frame.h), so that the bytes of a render depend on the
     * model, the subject and the view alone, not on what the context
     * rendered before (one more incremental render, the first time). */
    if (!view->use_head && gs_frame_wants_anchor(c, &fr) &&
        (view->gaze_pitch != s->gaze_pitch || view->gaze_yaw != s->gaze_yaw)) {
        gs_frame own;
        frame_of(s, NULL, &own);
        rc = gs_frame_render(c, pool, &own, NULL, err);
        if (rc)
            return rc;
    }
    rc = gs_frame_render(c, pool, &fr, NULL, err);
    if (rc)
        return rc;
    return write_image(c, s, rgb, stride, err);
}

/* ---- fitting ---- */

void gs_fit_options_default(gs_fit_options *o)
{
    memset(o, 0, sizeof *o);
    o->max_iters = 200;
    o->plateau_rel = 1e-3;
    o->code_prior = GS_FIT_CODE_PRIOR_MODEL;
    gs_geom_mat3_identity(o->head_R);
}

/* The fitted variables, one flat vector for a small Adam. */
enum { V_GAZE = 0, V_ROT = 2, V_TRANS = 5, V_GAIN = 8, V_BIAS = 11,
       V_CODE = 14 };

typedef struct fit_state {
    double x[V_CODE + GS_MODEL_MAX_CODE];
    double g[V_CODE + GS_MODEL_MAX_CODE];
    double m1[V_CODE + GS_MODEL_MAX_CODE], m2[V_CODE + GS_MODEL_MAX_CODE];
    double lr[V_CODE + GS_MODEL_MAX_CODE];
    int n;
} fit_state;

static void adam_update(fit_state *s, int t)
{
    const double b1 = 0.9, b2 = 0.999, eps = 1e-8;
    for (int i = 0; i < s->n; i++) {
        s->m1[i] = b1 * s->m1[i] + (1 - b1) * s->g[i];
        s->m2[i] = b2 * s->m2[i] + (1 - b2) * s->g[i] * s->g[i];
        double mh = s->m1[i] / (1 - pow(b1, t));
        double vh = s->m2[i] / (1 - pow(b2, t));
        s->x[i] -= s->lr[i] * mh / (sqrt(vh) + eps);
    }
}

/* Image loss of the current frame against target under weights w:
 * pred' = w (gain pred + bias) + (1 - w) target, loss = L1 + 0.1 SSIM.
 * Fills d_rgb (d loss / d pred) and the colour gradients. */
typedef struct fit_bufs {
    float *target, *w, *pred, *dpred, *ssim_scratch;
    size_t ssim_len;
    int shared; /* pred, dpred and ssim_scratch are another's */
} fit_bufs;

static double image_loss(gs_model_ctx *c, gs_pool *pool, fit_bufs *b, const fit_state *s,
                         double *dgain, double *dbias)
{
    int S = c->S;
    size_t plane = (size_t)S * S;
    for (int k = 0; k < 3; k++) {
        double gn = s->x[V_GAIN + k], bi = s->x[V_BIAS + k];
        for (size_t i = 0; i < plane; i++) {
            float w = b->w[i];
            float v = (float)(gn * c->rgb[k * plane + i] + bi);
            b->pred[k * plane + i] = w * v + (1 - w) * b->target[k * plane + i];
        }
    }
    float l1 = 0, ls = 0;
    gs_nn_l1_forward(&l1, b->pred, b->target, NULL, 3, (int)plane);
    memset(b->dpred, 0, 3 * plane * sizeof(float));
    gs_nn_l1_backward(b->dpred, 1.0f, b->pred, b->target, NULL, 3, (int)plane);
    /* the SSIM's loss and gradient in one pass, on the pool: the bytes of
     * its forward and backward run one after the other */
    gs_nn_ssim_loss_fused(pool, &ls, b->dpred, 0.1f, b->pred, b->target, 3, S, S,
                          GS_NN_SSIM_ZERO, b->ssim_scratch, b->ssim_len);
    for (int k = 0; k < 3; k++) {
        double gn = s->x[V_GAIN + k];
        double sg = 0, sb = 0;
        for (size_t i = 0; i < plane; i++) {
            float d = b->dpred[k * plane + i] * b->w[i];
            sg += (double)d * c->rgb[k * plane + i];
            sb += d;
            b->dpred[k * plane + i] = (float)(d * gn);
        }
        dgain[k] = sg;
        dbias[k] = sb;
    }
    return (double)l1 + 0.1 * (double)ls;
}

static void state_to_frame(const gs_model_ctx *c, const fit_state *s,
                           const double R0[9], gs_frame *fr)
{
    memset(fr, 0, sizeof *fr);
    for (int k = 0; k < c->D; k++)
        fr->code[k] = (float)s->x[V_CODE + k];
    double dR[9];
    gs_geom_rodrigues(s->x + V_ROT, dR);
    gs_geom_mat3_mul(dR, R0, fr->head_R);
    for (int k = 0; k < 3; k++)
        fr->head_t[k] = s->x[V_TRANS + k];
    fr->gaze[0] = s->x[V_GAZE];
    fr->gaze[1] = s->x[V_GAZE + 1];
}

/* The image (planar, 0..1) and the mask's weights a fit's loss compares
 * against. */
static void fit_target_fill(fit_bufs *b, int S, const uint8_t *rgb, size_t stride,
                            const uint8_t *mask)
{
    size_t plane = (size_t)S * S;
    for (int y = 0; y < S; y++)
        for (int x = 0; x < S; x++) {
            size_t i = (size_t)y * S + x;
            for (int k = 0; k < 3; k++)
                b->target[k * plane + i] = rgb[(size_t)y * stride + 3 * x + k] / 255.0f;
            b->w[i] = mask ? mask[i] / 255.0f : 1.0f;
        }
}

static int fit_bufs_init(fit_bufs *b, const gs_model_ctx *c,
                         const uint8_t *rgb, size_t stride,
                         const uint8_t *mask)
{
    int S = c->S;
    size_t plane = (size_t)S * S;
    b->ssim_len = gs_nn_ssim_fused_scratch_size(3, S, S, GS_NN_SSIM_ZERO);
    b->target = malloc(3 * plane * sizeof(float));
    b->w = malloc(plane * sizeof(float));
    b->pred = malloc(3 * plane * sizeof(float));
    b->dpred = malloc(3 * plane * sizeof(float));
    b->ssim_scratch = malloc(b->ssim_len * sizeof(float));
    if (!b->target || !b->w || !b->pred || !b->dpred || !b->ssim_scratch)
        return GS_ERR_NOMEM;
    fit_target_fill(b, S, rgb, stride, mask);
    return GS_OK;
}

static void fit_bufs_free(fit_bufs *b)
{
    free(b->target);
    free(b->w);
    if (b->shared)
        return;
    free(b->pred);
    free(b->dpred);
    free(b->ssim_scratch);
}

static void fit_init(const gs_model_ctx *c, const gs_fit_options *o,
                     fit_state *s)
{
    memset(s, 0, sizeof *s);
    s->n = V_CODE + c->D;
    s->x[V_GAZE] = o->known_gaze ? o->gaze_pitch : 0.0;
    s->x[V_GAZE + 1] = o->known_gaze ? o->gaze_yaw : 0.0;
    for (int k = 0; k < 3; k++) {
        s->x[V_TRANS + k] = o->known_head ? o->head_t[k] : 0.0;
        s->x[V_GAIN + k] = 1.0;
    }
    if (!o->known_head)
        s->x[V_TRANS + 2] = c->m->cfg.d_n_mm;
    for (int k = 0; k < c->D; k++)
        s->x[V_CODE + k] = o->code_start ? o->code_start[k]
                                         : c->m->p.code_mean[k];
    for (int k = 0; k < 2; k++)
        s->lr[V_GAZE + k] = o->known_gaze ? 0.0 : 0.01;
    for (int k = 0; k < 3; k++) {
        s->lr[V_ROT + k] = o->known_head ? 0.0 : 0.004;
        s->lr[V_TRANS + k] = o->known_head ? 0.0 : 1.0;
        s->lr[V_GAIN + k] = o->lr_colour > 0 ? o->lr_colour : GS_FIT_LR_COLOUR_DEFAULT;
        s->lr[V_BIAS + k] = s->lr[V_GAIN + k];
    }
    const double lr_code = gs_model_fit_code_rate(c->m, o->lr_code);
    for (int k = 0; k < c->D; k++)
        s->lr[V_CODE + k] = o->code_fixed && o->code_fixed[k] ? 0.0 : lr_code;
}

/* PSNR over the weighted pixels of the composite in b->pred. */
static float weighted_psnr(const fit_bufs *b, int S)
{
    size_t plane = (size_t)S * S;
    double se = 0, wsum = 0;
    for (int k = 0; k < 3; k++)
        for (size_t i = 0; i < plane; i++) {
            double e = b->pred[k * plane + i] - b->target[k * plane + i];
            se += e * e;
            wsum += b->w[i];
        }
    double mse = wsum > 0 ? se / wsum : 0;
    return (float)(mse > 1e-12 ? -10.0 * log10(mse) : 120.0);
}

/* The image flipped left to right, packed (S x S x 3); NULL when out of
 * memory. */
static uint8_t *mirror_image(const uint8_t *rgb, size_t stride, int S)
{
    uint8_t *f = malloc(3 * (size_t)S * S);
    if (f)
        for (int y = 0; y < S; y++)
            for (int x = 0; x < S; x++)
                memcpy(f + 3 * ((size_t)y * S + x),
                       rgb + (size_t)y * stride + 3 * (size_t)(S - 1 - x), 3);
    return f;
}

/* Pixel weights of the mirrored image from the input's mask. */
static void mirror_weights(const uint8_t *mask, int S, float *w)
{
    for (int y = 0; y < S; y++)
        for (int x = 0; x < S; x++)
            w[(size_t)y * S + x] = mask[(size_t)y * S + (S - 1 - x)] / 255.0f;
}

/* The mirrored view's gradient, in the fit's variables: the view is
 * gs_frame_mirror of the fit's frame (S = diag(-1, 1, 1): rotation S R S,
 * so a left perturbation w becomes -S w; translation S t; the gaze's yaw
 * and the lights' x negated), and each map is its own inverse. */
static void add_mirrored_grad(const gs_model_ctx *c, const gs_frame_grad *fm,
                              const double *dgain, const double *dbias,
                              double *g)
{
    g[V_GAZE] += fm->gaze[0];
    g[V_GAZE + 1] -= fm->gaze[1];
    g[V_ROT] += fm->rot[0];
    g[V_ROT + 1] -= fm->rot[1];
    g[V_ROT + 2] -= fm->rot[2];
    g[V_TRANS] -= fm->trans[0];
    g[V_TRANS + 1] += fm->trans[1];
    g[V_TRANS + 2] += fm->trans[2];
    for (int k = 0; k < 3; k++) {
        g[V_GAIN + k] += dgain[k];
        g[V_BIAS + k] += dbias[k];
    }
    float code[GS_MODEL_MAX_CODE];
    memcpy(code, fm->code, (size_t)c->D * sizeof code[0]);
    gs_frame_mirror_code(code, c->D);
    for (int k = 0; k < c->D; k++)
        g[V_CODE + k] += code[k];
}

/* Buffers of image i > 0 share image 0's scratch (pred, dpred, SSIM):
 * the context holds one forward at a time, so the images' losses run one
 * after another. Only the target and the weights are the image's own. */
static int fit_bufs_init_with(fit_bufs *b, const fit_bufs *with,
                              const gs_model_ctx *c, const uint8_t *rgb,
                              size_t stride, const uint8_t *mask)
{
    if (!with)
        return fit_bufs_init(b, c, rgb, stride, mask);
    fit_bufs own = *with;
    own.target = malloc(3 * (size_t)c->S * c->S * sizeof(float));
    own.w = malloc((size_t)c->S * c->S * sizeof(float));
    *b = own;
    b->shared = 1;
    if (!own.target || !own.w)
        return GS_ERR_NOMEM;
    fit_target_fill(b, c->S, rgb, stride, mask);
    return GS_OK;
}

/* One image's buffers (and its mirror's, o->mirror); 0 or GS_ERR_NOMEM. */
static int fit_image_bufs(const gs_model_ctx *c, const gs_fit_image *im,
                          int mirror, const fit_bufs *with, fit_bufs *b,
                          fit_bufs *bm)
{
    if (fit_bufs_init_with(b, with, c, im->rgb, im->stride, im->mask))
        return GS_ERR_NOMEM;
    if (!mirror)
        return GS_OK;
    uint8_t *flip = mirror_image(im->rgb, im->stride, c->S);
    int rc = flip ? fit_bufs_init_with(bm, with ? with : b, c, flip,
                                       3 * (size_t)c->S, NULL)
                  : GS_ERR_NOMEM;
    free(flip); /* bm holds it as floats */
    if (!rc && im->mask)
        mirror_weights(im->mask, c->S, bm->w);
    return rc;
}

void gs_fit_image_from_options(gs_fit_image *im, const uint8_t *rgb,
                               size_t stride, const gs_fit_options *o)
{
    memset(im, 0, sizeof *im);
    im->rgb = rgb;
    im->stride = stride;
    gs_geom_mat3_identity(im->head_R);
    if (!o)
        return;
    im->mask = o->mask;
    im->known_gaze = o->known_gaze;
    im->gaze_pitch = o->gaze_pitch;
    im->gaze_yaw = o->gaze_yaw;
    im->known_head = o->known_head;
    memcpy(im->head_R, o->head_R, sizeof im->head_R);
    memcpy(im->head_t, o->head_t, sizeof im->head_t);
}

/* What the fit of several images keeps per image. */
typedef struct fit_one {
    fit_state s, best;
    fit_bufs b, bm; /* bm: the mirrored view's (o.mirror) */
    gs_frame_grad fg, fgm;
    double R0[9];
    double dgain[3], dbias[3], dgm[3], dbm[3];
    double gprior[GS_CODE_PRIOR_DIM];
} fit_one;

static void fit_ones_free(fit_one *f, int k)
{
    for (int i = 0; f && i < k; i++) {
        fit_bufs_free(&f[i].b);
        fit_bufs_free(&f[i].bm);
    }
    free(f);
}

/* The options' checks shared by both fits; the prior weight resolved. */
static int fit_check_options(const gs_model_ctx *c, gs_fit_options *o,
                             gs_error *err)
{
    int rc = GS_OK;
    if (!(o->lr_code >= 0 && o->lr_code <= 10 && o->lr_colour >= 0 &&
          o->lr_colour <= 10))
        rc = gs_error_set(err, GS_ERR_ARG,
                          "fit: rates %g (code) and %g (colour): want [0, 10], "
                          "0 for the defaults", o->lr_code, o->lr_colour);
    if (o->code_prior == GS_FIT_CODE_PRIOR_MODEL)
        o->code_prior = c->m->cfg.fit_code_prior;
    if (!rc && !gs_code_prior_weight_ok(o->code_prior))
        rc = gs_error_set(err, GS_ERR_ARG,
                          "fit: code prior weight %g: want [0, 10], 0 for "
                          "none, -1 for the model's",
                          o->code_prior);
    if (!rc && !gs_code_prior_weight_ok(o->id_prior))
        rc = gs_error_set(err, GS_ERR_ARG,
                          "fit: identity prior weight %g: want [0, 10], 0 for "
                          "none", o->id_prior);
    if (!rc && o->mirror != 0 && o->mirror != 1)
        rc = gs_error_set(err, GS_ERR_ARG, "fit: mirror %d: want 0 or 1",
                          o->mirror);
    if (!rc && (o->anneal < 0 || o->anneal > GS_FIT_ANNEAL_MAX))
        rc = gs_error_set(err, GS_ERR_ARG,
                          "fit: anneal %d: want 0..%d halvings of the rates",
                          o->anneal, GS_FIT_ANNEAL_MAX);
    for (int k = 0; !rc && o->code_start && k < c->D; k++)
        if (!isfinite(o->code_start[k]))
            rc = gs_error_set(err, GS_ERR_ARG,
                              "fit: code_start[%d] is not finite", k);
    return rc;
}

static int fit_check_images(const gs_model_ctx *c, const gs_fit_image *im,
                            int k, gs_error *err)
{
    if (k < 1 || k > GS_FIT_IMAGES_MAX)
        return gs_error_set(err, GS_ERR_ARG, "fit: %d images: want 1..%d", k,
                            GS_FIT_IMAGES_MAX);
    for (int i = 0; i < k; i++) {
        int rc = GS_OK;
        if (!im[i].rgb)
            return gs_error_set(err, GS_ERR_ARG, "fit: image %d is NULL", i);
        if (im[i].stride < 3 * (size_t)c->S)
            return gs_error_set(err, GS_ERR_ARG, "fit: image %d: stride %zu < %d",
                                i, im[i].stride, 3 * c->S);
        if (im[i].known_gaze)
            rc = check_gaze(im[i].gaze_pitch, im[i].gaze_yaw, err);
        if (!rc && im[i].known_head)
            rc = check_pose(im[i].head_R, im[i].head_t, err);
        if (rc && k > 1 && err) { /* name the image, keep the reason */
            char why[sizeof err->msg];
            snprintf(why, sizeof why, "%s", err->msg);
            gs_error_set(err, rc, "fit: image %d: %s", i, why);
        }
        if (rc)
            return rc;
    }
    return GS_OK;
}

/* The fitted subject of image f (its best iterate), rendered once more for
 * its figures. */
static int fit_result(gs_model_ctx *c, gs_pool *pool, fit_one *f,
                      gs_subject *out, gs_error *err)
{
    gs_frame fr;
    state_to_frame(c, &f->best, f->R0, &fr);
    int rc = gs_frame_forward(c, pool, &fr, GS_STREAM_BOTH, 0, err);
    if (rc)
        return rc;
    /* Composites the best render into b.pred for the figures. */
    double dg[3], db[3];
    image_loss(c, pool, &f->b, &f->best, dg, db);
    int S = c->S;
    float ls = 0;
    gs_nn_ssim_loss_fused(pool, &ls, NULL, 0.0f, f->b.pred, f->b.target, 3, S, S,
                          GS_NN_SSIM_ZERO, f->b.ssim_scratch, f->b.ssim_len);
    gs_subject r;
    memset(&r, 0, sizeof r);
    r.code_dim = c->D;
    for (int k = 0; k < c->D; k++)
        r.code[k] = fr.code[k];
    memcpy(r.head_R, fr.head_R, sizeof r.head_R);
    memcpy(r.head_t, fr.head_t, sizeof r.head_t);
    r.gaze_pitch = fr.gaze[0];
    r.gaze_yaw = fr.gaze[1];
    for (int k = 0; k < 3; k++) {
        r.colour_gain[k] = (float)f->best.x[V_GAIN + k];
        r.colour_bias[k] = (float)f->best.x[V_BIAS + k];
    }
    r.fit_psnr = weighted_psnr(&f->b, S);
    r.fit_ssim = 1.0f - ls;
    *out = r;
    return GS_OK;
}

/* Image f's gradient in the fit's variables, from its view's (and its
 * mirror's) frame gradient, colours and code prior. */
static void fit_gradient(const gs_model_ctx *c, fit_one *f, int use_prior,
                         int V_PRIOR, const double *gid, int mirror)
{
    fit_state *s = &f->s;
    memset(s->g, 0, sizeof s->g);
    s->g[V_GAZE] = f->fg.gaze[0];
    s->g[V_GAZE + 1] = f->fg.gaze[1];
    for (int k = 0; k < 3; k++) {
        s->g[V_ROT + k] = f->fg.rot[k];
        s->g[V_TRANS + k] = f->fg.trans[k];
        s->g[V_GAIN + k] = f->dgain[k];
        s->g[V_BIAS + k] = f->dbias[k];
    }
    for (int k = 0; k < c->D; k++)
        s->g[V_CODE + k] = f->fg.code[k];
    for (int k = 0; use_prior && k < GS_CODE_PRIOR_DIM; k++)
        s->g[V_PRIOR + k] += f->gprior[k];
    for (int k = 0; gid && k < c->m->cfg.id_dim; k++)
        s->g[V_CODE + k] += gid[k];
    if (mirror)
        add_mirrored_grad(c, &f->fgm, f->dgm, f->dbm, s->g);
}

/* Image f's loss at its current state (and its gradient when `backward`),
 * with its code prior and, for gid != NULL, the identity prior. */
static int fit_image_step(gs_model_ctx *c, gs_pool *pool, fit_one *f,
                          const gs_fit_options *o, const gs_code_prior *prior,
                          int V_PRIOR, const gs_id_prior *idp, double *gid,
                          int backward, double *loss, gs_error *err)
{
    gs_frame fr;
    state_to_frame(c, &f->s, f->R0, &fr);
    int rc = gs_frame_forward(c, pool, &fr, GS_STREAM_BOTH, 0, err);
    if (rc)
        return rc;
    double l = image_loss(c, pool, &f->b, &f->s, f->dgain, f->dbias);
    memset(f->gprior, 0, sizeof f->gprior);
    if (prior)
        l += gs_code_prior_eval(prior, o->code_prior, f->s.x + V_PRIOR,
                                f->gprior);
    if (idp)
        l += gs_id_prior_eval(idp, o->id_prior, f->s.x + V_CODE, gid);
    /* The mirrored view: the input's gradient first (the context holds
     * one forward at a time), then the mirrored view's loss and
     * gradient, so the loss the fit tracks is the sum of both. */
    if ((o->mirror || backward) && isfinite(l)) {
        memset(&f->fg, 0, sizeof f->fg);
        rc = gs_frame_backward(c, pool, f->b.dpred, NULL, NULL, NULL, NULL,
                               &f->fg, err);
    }
    if (!rc && o->mirror && isfinite(l)) {
        memset(&f->fgm, 0, sizeof f->fgm);
        gs_frame frm;
        gs_frame_mirror(&fr, c->D, &frm);
        rc = gs_frame_forward(c, pool, &frm, GS_STREAM_BOTH, 0, err);
        if (!rc)
            l += image_loss(c, pool, &f->bm, &f->s, f->dgm, f->dbm);
        if (!rc && isfinite(l))
            rc = gs_frame_backward(c, pool, f->bm.dpred, NULL, NULL, NULL,
                                   NULL, &f->fgm, err);
    }
    *loss = l;
    return rc;
}

int gs_model_fit(gs_model_ctx *c, gs_pool *pool, const uint8_t *rgb,
                 size_t stride, const gs_fit_options *opt, gs_subject *out,
                 gs_fit_report *report, gs_error *err)
{
    if (!c || !rgb || !out)
        return gs_error_set(err, GS_ERR_ARG, "fit: NULL argument");
    if (stride < 3 * (size_t)c->S)
        return gs_error_set(err, GS_ERR_ARG, "fit: stride %zu < %d", stride,
                            3 * c->S);
    gs_fit_options o;
    if (opt)
        o = *opt;
    else
        gs_fit_options_default(&o);
    gs_fit_image im;
    gs_fit_image_from_options(&im, rgb, stride, &o);
    o.known_gaze = o.known_head = 0;
    o.mask = NULL;
    return gs_model_fit_images(c, pool, &im, 1, &o, out, report, err);
}

int gs_model_fit_images(gs_model_ctx *c, gs_pool *pool, const gs_fit_image *im,
                        int k, const gs_fit_options *opt, gs_subject *out,
                        gs_fit_report *report, gs_error *err)
{
    if (!c || !im || !out)
        return gs_error_set(err, GS_ERR_ARG, "fit: NULL argument");
    gs_fit_options o;
    if (opt)
        o = *opt;
    else
        gs_fit_options_default(&o);
    if (o.known_gaze || o.known_head || o.mask)
        return gs_error_set(err, GS_ERR_ARG,
                            "fit: several images take their labels and masks "
                            "from gs_fit_image, not from the options");
    int rc = fit_check_images(c, im, k, err);
    if (!rc)
        rc = fit_check_options(c, &o, err);
    /* the prior (weight > 0): on the stack, made before anything is
     * allocated; its slots are [expression | lights] after the identity */
    gs_code_prior prior;
    const int use_prior = o.code_prior > 0;
    const int V_PRIOR = V_CODE + c->m->cfg.id_dim;
    if (!rc && use_prior)
        rc = gs_code_prior_make(c->m, &prior, err);
    if (rc)
        return rc;
    gs_id_prior *idp = NULL; /* the identity prior (weight > 0) */
    if (o.id_prior > 0 && (rc = gs_id_prior_make(c->m, &idp, err)))
        return rc;
    int iters = o.max_iters > 0 ? o.max_iters : 200;
    double plateau = o.plateau_rel > 0 ? o.plateau_rel : 1e-3;

    fit_one *f = calloc((size_t)k, sizeof *f);
    gs_subject *res = calloc((size_t)k, sizeof *res);
    for (int i = 0; f && res && !rc && i < k; i++)
        rc = fit_image_bufs(c, &im[i], o.mirror, i ? &f[0].b : NULL, &f[i].b,
                            &f[i].bm);
    if (!f || !res || rc) {
        fit_ones_free(f, f ? k : 0);
        free(res);
        gs_id_prior_free(idp);
        return gs_error_set(err, GS_ERR_NOMEM, "fit: out of memory");
    }
    for (int i = 0; i < k; i++) {
        gs_fit_options oi = o;
        oi.known_gaze = im[i].known_gaze;
        oi.gaze_pitch = im[i].gaze_pitch;
        oi.gaze_yaw = im[i].gaze_yaw;
        oi.known_head = im[i].known_head;
        memcpy(oi.head_R, im[i].head_R, sizeof oi.head_R);
        memcpy(oi.head_t, im[i].head_t, sizeof oi.head_t);
        fit_init(c, &oi, &f[i].s);
        if (im[i].known_head)
            memcpy(f[i].R0, im[i].head_R, sizeof f[i].R0);
        else
            gs_geom_mat3_identity(f[i].R0);
    }
    const int id_dim = c->m->cfg.id_dim;
    double t0 = gs_clock_s(), best_loss = INFINITY, first = NAN, hist[20];
    int it = 0, plateaued = 0, halvings = 0, since = 0, on_time = 0;
    for (; it < iters; it++) {
        if (o.cancel && o.cancel(o.cancel_arg)) {
            rc = gs_error_set(err, GS_ERR_CANCELLED,
                              "fit cancelled at iteration %d", it);
            break;
        }
        /* The sum of the images' losses; every image but the last has its
         * gradient taken at once (one forward at a time), the last's waits
         * for the stopping tests, as a fit of one image always did. */
        double loss = 0, gid[GS_MODEL_MAX_CODE] = {0};
        for (int i = 0; !rc && i < k && isfinite(loss); i++) {
            double li = 0;
            rc = fit_image_step(c, pool, &f[i], &o, use_prior ? &prior : NULL,
                                V_PRIOR, i == 0 ? idp : NULL, gid, i < k - 1,
                                &li, err);
            loss += li;
        }
        if (rc)
            break;
        if (!isfinite(loss)) {
            rc = gs_error_set(err, GS_ERR_NONFINITE,
                              "fit diverged at iteration %d (loss %g, first "
                              "%g)", it, loss, first);
            break;
        }
        if (it == 0)
            first = loss;
        if (loss < best_loss) {
            best_loss = loss;
            for (int i = 0; i < k; i++)
                f[i].best = f[i].s;
        }
        hist[it % 20] = loss;
        if (it >= 20 && it - since >= 20 &&
            hist[(it + 1) % 20] - loss < plateau * loss) {
            if (halvings == o.anneal) {
                plateaued = 1;
                break;
            }
            /* anneal: the steps shrink and the fit goes on from here */
            halvings++;
            since = it;
            for (int i = 0; i < k; i++)
                for (int j = 0; j < f[i].s.n; j++)
                    f[i].s.lr[j] *= 0.5;
        }
        if (o.time_budget_s > 0 && gs_clock_s() - t0 > o.time_budget_s) {
            on_time = it + 1 < iters;
            break;
        }
        fit_one *last = &f[k - 1];
        if (!o.mirror) {
            memset(&last->fg, 0, sizeof last->fg);
            rc = gs_frame_backward(c, pool, last->b.dpred, NULL, NULL, NULL,
                                   NULL, &last->fg, err);
            if (rc)
                break;
        }
        for (int i = 0; i < k; i++)
            fit_gradient(c, &f[i], use_prior, V_PRIOR, i == 0 && idp ? gid : NULL,
                         o.mirror);
        /* One identity: its gradient is the sum over the images, in their
         * order, and every image's copy takes the same Adam step from the
         * same start, so the copies stay equal bit for bit. */
        for (int j = 0; k > 1 && j < id_dim; j++) {
            double sum = f[0].s.g[V_CODE + j];
            for (int i = 1; i < k; i++)
                sum += f[i].s.g[V_CODE + j];
            for (int i = 0; i < k; i++)
                f[i].s.g[V_CODE + j] = sum;
        }
        for (int i = 0; !rc && i < k; i++)
            for (int j = 0; j < f[i].s.n; j++)
                if (!isfinite(f[i].s.g[j])) {
                    rc = gs_error_set(err, GS_ERR_NONFINITE,
                                      "fit: non-finite gradient at iteration "
                                      "%d", it);
                    break;
                }
        if (rc)
            break;
        for (int i = 0; i < k; i++) {
            fit_state *s = &f[i].s;
            adam_update(s, it + 1);
            /* bound_expression: the expression stays where training put it. */
            for (int e = 0; o.bound_expression && e < GS_MODEL_EXPR_DIM; e++) {
                double *v = &s->x[V_CODE + id_dim + e];
                *v = fmax(gs_model_expr_lo[e], fmin(gs_model_expr_hi[e], *v));
            }
            /* The gaze stays inside the model's documented range. */
            s->x[V_GAZE] = fmax(-GS_MODEL_MAX_GAZE_PITCH,
                                fmin(GS_MODEL_MAX_GAZE_PITCH, s->x[V_GAZE]));
            s->x[V_GAZE + 1] = fmax(-GS_MODEL_MAX_GAZE_YAW,
                                    fmin(GS_MODEL_MAX_GAZE_YAW, s->x[V_GAZE + 1]));
        }
    }
    for (int i = 0; !rc && i < k; i++)
        rc = fit_result(c, pool, &f[i], &res[i], err);
    if (!rc)
        memcpy(out, res, (size_t)k * sizeof *out);
    if (report) {
        memset(report, 0, sizeof *report);
        report->iters = it;
        report->seconds = gs_clock_s() - t0;
        report->loss_first = first;
        report->loss_last = best_loss;
        report->stopped_on_plateau = plateaued;
        report->stopped_on_time = on_time;
        report->halvings = halvings;
    }
    fit_ones_free(f, k);
    free(res);
    gs_id_prior_free(idp);
    return rc;
}

/* ---- per-image fine-tuning ---- */

void gs_finetune_options_default(gs_finetune_options *o)
{
    memset(o, 0, sizeof *o);
    o->iters = 50;
    o->lr = 1e-3;
    o->parts = GS_FT_DEFAULT;
    o->mirror = 1;
}

static const struct {
    const char *name;
    unsigned bit;
} ft_names[] = {{"face", GS_FT_FACE}, {"eye", GS_FT_EYE}, {"renderer", GS_FT_RENDERER},
                {"mlp", GS_FT_MLP}, {"geometry", GS_FT_GEOMETRY},
                {"face-geometry", GS_FT_FACE_GEOMETRY}};
#define N_FT_NAMES (sizeof ft_names / sizeof ft_names[0])

int gs_finetune_parts_parse(const char *s, unsigned *parts, gs_error *err)
{
    if (!s || !parts)
        return gs_error_set(err, GS_ERR_ARG, "finetune parts: NULL argument");
    unsigned bits = 0;
    const char *p = s;
    for (;;) {
        size_t n = strcspn(p, ",");
        size_t k = 0;
        while (k < N_FT_NAMES && !(strlen(ft_names[k].name) == n && !strncmp(p, ft_names[k].name, n)))
            k++;
        if (n == 0)
            return gs_error_set(err, GS_ERR_ARG, "finetune parts: an empty name in '%.64s'", s);
        if (k == N_FT_NAMES)
            return gs_error_set(err, GS_ERR_ARG,
                                "finetune parts: '%.*s' in '%.64s' is none of face, eye, renderer, "
                                "mlp, geometry, face-geometry", (int)(n < 32 ? n : 32), p, s);
        bits |= ft_names[k].bit;
        p += n;
        if (*p == '\0')
            break;
        p++; /* a comma: another name must follow */
    }
    *parts = bits;
    return GS_OK;
}

const char *gs_finetune_parts_name(unsigned parts, char *buf, size_t cap)
{
    size_t n = 0;
    if (cap)
        buf[0] = '\0';
    for (size_t k = 0; k < N_FT_NAMES; k++)
        if ((parts & ft_names[k].bit) && n < cap) {
            int w = snprintf(buf + n, cap - n, "%s%s", n ? "," : "", ft_names[k].name);
            n += w > 0 ? (size_t)w : 0;
        }
    return buf;
}

/* Learning-rate multipliers of the training run (train.c). */
static double part_lr(int group)
{
    switch (group) {
    case GS_PG_GAUSS_XYZ: return 10.0;
    case GS_PG_GAUSS_FEAT: return 5.0;
    default: return 1.0;
    }
}

typedef struct ft_run {
    gs_model *m;
    gs_model_ctx *c;
    float *grad, *orig, *best; /* grad: all parameters; orig/best: tuned */
    int idx[GS_MODEL_MAX_TENSORS], n;
    size_t tuned;
    gs_model_params g;
    gs_nn_adam *adam;
} ft_run;

/* Copies the tuned tensors between the model and a packed buffer. */
static void ft_pack(ft_run *r, float *buf, int to_model)
{
    size_t o = 0;
    for (int i = 0; i < r->n; i++) {
        const gs_ptensor *t = &r->m->t[r->idx[i]];
        float *p = r->m->params + t->offset;
        if (to_model)
            memcpy(p, buf + o, t->count * sizeof(float));
        else
            memcpy(buf + o, p, t->count * sizeof(float));
        o += t->count;
    }
}

static void ft_free(ft_run *r)
{
    gs_model_ctx_destroy(r->c);
    gs_nn_adam_destroy(r->adam);
    free(r->grad);
    free(r->orig);
    free(r->best);
}

static int ft_init(ft_run *r, gs_model *m, unsigned parts, gs_error *err)
{
    memset(r, 0, sizeof *r);
    r->m = m;
    gs_nn_param_group groups[GS_MODEL_MAX_TENSORS];
    for (int i = 0; i < m->ntensors; i++)
        if (gs_model_tensor_part(&m->t[i]) & parts) {
            r->idx[r->n++] = i;
            r->tuned += m->t[i].count;
        }
    if (!r->n)
        return gs_error_set(err, GS_ERR_ARG,
                            "finetune: parts 0x%x name no tensor", parts);
    r->c = gs_model_ctx_create(m);
    r->grad = calloc(m->nparams, sizeof(float));
    r->orig = malloc(r->tuned * sizeof(float));
    r->best = malloc(r->tuned * sizeof(float));
    if (!r->c || !r->grad || !r->orig || !r->best)
        return gs_error_set(err, GS_ERR_NOMEM, "finetune: out of memory");
    gs_model_bind(m, r->grad, &r->g);
    for (int i = 0; i < r->n; i++) {
        const gs_ptensor *t = &m->t[r->idx[i]];
        groups[i].param = m->params + t->offset;
        groups[i].grad = r->grad + t->offset;
        groups[i].n = t->count;
        groups[i].lr_mult = part_lr(t->group);
    }
    gs_nn_adam_config ac = gs_nn_adam_default_config();
    int rc = gs_nn_adam_create(&r->adam, groups, r->n, &ac, err);
    if (rc)
        return rc;
    ft_pack(r, r->orig, 0);
    memcpy(r->best, r->orig, r->tuned * sizeof(float));
    return GS_OK;
}

/* Feature pixels within r of the outline of a coverage map [fs, fs]
 * (coverage under 0.5 there) get 0, the rest 1 (gs_finetune_options.
 * outline_px): the colours learn inside the model's own outline only. On
 * the outline, the input's background may fall on Gaussians seen edge-on,
 * which would take its colour over a surface that faces the camera at
 * another head pose (docs/model.md, "Per-image fine-tuning"). */
static void outline_mask(const float *alpha, int fs, int r, float *inner)
{
    for (int y = 0; y < fs; y++)
        for (int x = 0; x < fs; x++) {
            int in = 1;
            for (int dy = -r; dy <= r && in; dy++)
                for (int dx = -r; dx <= r && in; dx++) {
                    int yy = y + dy, xx = x + dx;
                    in = yy >= 0 && xx >= 0 && yy < fs && xx < fs &&
                         alpha[yy * fs + xx] >= 0.5f;
                }
            inner[y * fs + x] = (float)in;
        }
}

int gs_model_finetune(gs_model *m, gs_pool *pool, const gs_subject *s,
                      const uint8_t *rgb, size_t stride,
                      const gs_finetune_options *opt,
                      gs_finetune_report *report, gs_error *err)
{
    if (!m || !s || !rgb)
        return gs_error_set(err, GS_ERR_ARG, "finetune: NULL argument");
    gs_finetune_options o;
    if (opt)
        o = *opt;
    else
        gs_finetune_options_default(&o);
    gs_fit_image im;
    gs_fit_image_from_options(&im, rgb, stride, NULL);
    im.mask = o.mask;
    o.mask = NULL;
    return gs_model_finetune_images(m, pool, s, &im, 1, &o, report, err);
}

/* What a fine-tune over several images keeps per (subject, image) pair. */
typedef struct ft_one {
    fit_state fs;   /* the subject's colour transform, for image_loss */
    fit_bufs b, bm; /* bm: the mirrored view's (o.mirror) */
    gs_frame fr, frm;
    float *inner, *inner_m; /* outline masks (o.outline_px) */
} ft_one;

static void ft_ones_free(ft_one *f, int k)
{
    for (int i = 0; f && i < k; i++) {
        fit_bufs_free(&f[i].b);
        fit_bufs_free(&f[i].bm);
        free(f[i].inner);
        free(f[i].inner_m);
    }
    free(f);
}

/* Pair f's gradient at the context's current forward (its own), added
 * to r->g, and its mirror's (o->mirror). */
static int ft_pair_backward(ft_run *r, gs_pool *pool, ft_one *f,
                            const gs_finetune_options *o, int masked, int it,
                            gs_error *err)
{
    gs_frame_grad fg;
    memset(&fg, 0, sizeof fg);
    int rc = gs_frame_backward(r->c, pool, f->b.dpred, NULL, NULL, NULL, &r->g,
                               &fg, err);
    if (!rc && o->mirror) { /* the mirrored view adds its gradient */
        double dgm[3], dbm[3];
        rc = gs_frame_forward(r->c, pool, &f->frm, GS_STREAM_BOTH, 1, err);
        if (!rc && !isfinite(image_loss(r->c, pool, &f->bm, &f->fs, dgm, dbm)))
            rc = gs_error_set(err, GS_ERR_NONFINITE,
                              "finetune: mirrored view diverged at step %d", it);
        if (!rc && masked) { /* its own outline, from its first view */
            if (it == 0)
                outline_mask(r->c->alpha, r->c->fs, o->outline_px, f->inner_m);
            rc = gs_frame_set_feature_mask(r->c, f->inner_m, err);
        }
        memset(&fg, 0, sizeof fg);
        if (!rc)
            rc = gs_frame_backward(r->c, pool, f->bm.dpred, NULL, NULL, NULL,
                                   &r->g, &fg, err);
        if (!rc && masked)
            rc = gs_frame_set_feature_mask(r->c, f->inner, err);
    }
    return rc;
}

/* Pair f's loss at the model's current parameters and the PSNR of its
 * composite; its gradient too when `backward` (else the context keeps its
 * forward for ft_pair_backward). */
static int ft_pair_step(ft_run *r, gs_pool *pool, ft_one *f,
                        const gs_finetune_options *o, int masked, int it,
                        int backward, double *loss, double *psnr,
                        gs_error *err)
{
    int rc = gs_frame_forward(r->c, pool, &f->fr, GS_STREAM_BOTH, 1, err);
    if (!rc && masked) {
        if (it == 0)
            outline_mask(r->c->alpha, r->c->fs, o->outline_px, f->inner);
        rc = gs_frame_set_feature_mask(r->c, f->inner, err);
    }
    if (rc)
        return rc;
    double dg[3], db[3];
    *loss = image_loss(r->c, pool, &f->b, &f->fs, dg, db);
    *psnr = weighted_psnr(&f->b, r->c->S);
    if (!backward || !isfinite(*loss))
        return GS_OK;
    return ft_pair_backward(r, pool, f, o, masked, it, err);
}

int gs_model_finetune_images(gs_model *m, gs_pool *pool, const gs_subject *s,
                             const gs_fit_image *im, int k,
                             const gs_finetune_options *opt,
                             gs_finetune_report *report, gs_error *err)
{
    if (!m || !s || !im)
        return gs_error_set(err, GS_ERR_ARG, "finetune: NULL argument");
    if (k < 1 || k > GS_FIT_IMAGES_MAX)
        return gs_error_set(err, GS_ERR_ARG, "finetune: %d images: want 1..%d",
                            k, GS_FIT_IMAGES_MAX);
    gs_finetune_options o;
    if (opt)
        o = *opt;
    else
        gs_finetune_options_default(&o);
    if (o.mask)
        return gs_error_set(err, GS_ERR_ARG,
                            "finetune: several images take their masks from "
                            "gs_fit_image, not from the options");
    int iters = o.iters > 0 ? o.iters : 50;
    double lr = o.lr > 0 ? o.lr : 1e-3;
    unsigned parts = o.parts ? o.parts : GS_FT_DEFAULT;
    if (!isfinite(o.lr) || o.lr > 1.0 || iters > 100000 || !isfinite(o.plateau_rel) ||
        isnan(o.time_budget_s) ||
        (parts & ~GS_FT_ALL_PARTS))
        return gs_error_set(err, GS_ERR_ARG,
                            "finetune: lr %g (want <= 1), iterations %d "
                            "(<= 100000) or parts 0x%x out of range",
                            o.lr, o.iters, parts);
    if (o.mirror != 0 && o.mirror != 1)
        return gs_error_set(err, GS_ERR_ARG, "finetune: mirror %d: want 0 or 1",
                            o.mirror);
    if (o.outline_px < 0 || o.outline_px > 8)
        return gs_error_set(err, GS_ERR_ARG,
                            "finetune: outline %d px: want 0..8", o.outline_px);
    int rc = GS_OK;
    for (int i = 0; i < k; i++) {
        if (!im[i].rgb)
            return gs_error_set(err, GS_ERR_ARG, "finetune: image %d is NULL", i);
        if ((rc = check_subject(m, &s[i], err)))
            return rc;
        if ((size_t)m->cfg.image_size * 3 > im[i].stride)
            return gs_error_set(err, GS_ERR_ARG, "finetune: stride %zu < %d",
                                im[i].stride, 3 * m->cfg.image_size);
    }
    ft_run r;
    ft_one *f = calloc((size_t)k, sizeof *f);
    rc = f ? ft_init(&r, m, parts, err)
           : gs_error_set(err, GS_ERR_NOMEM, "finetune: out of memory");
    if (rc) {
        free(f);
        return rc;
    }
    int masked = o.outline_px > 0 && (parts & (GS_FT_FACE | GS_FT_EYE | GS_FT_MLP));
    size_t fplane = (size_t)r.c->fs * r.c->fs;
    for (int i = 0; !rc && i < k; i++) {
        ft_one *p = &f[i];
        gs_fit_image mi = im[i];
        mi.mask = im[i].mask;
        if (fit_image_bufs(r.c, &mi, o.mirror, i ? &f[0].b : NULL, &p->b, &p->bm))
            rc = GS_ERR_NOMEM;
        p->inner = malloc(fplane * sizeof(float));
        p->inner_m = malloc(fplane * sizeof(float));
        if (!p->inner || !p->inner_m)
            rc = GS_ERR_NOMEM;
        /* The subject's colour transform, fixed: image_loss reads it here. */
        for (int c3 = 0; c3 < 3; c3++) {
            p->fs.x[V_GAIN + c3] = s[i].colour_gain[c3];
            p->fs.x[V_BIAS + c3] = s[i].colour_bias[c3];
        }
        frame_of(&s[i], NULL, &p->fr);
        gs_frame_mirror(&p->fr, s[i].code_dim, &p->frm);
    }
    if (rc)
        rc = gs_error_set(err, GS_ERR_NOMEM, "finetune: out of memory");
    double t0 = gs_clock_s(), best = INFINITY, first = NAN;
    float psnr_first = NAN, psnr_best = NAN;
    double hist[20];
    int it = 0, stopped_on_time = 0, plateaued = 0;
    for (; !rc && it <= iters; it++) {
        if (o.cancel && o.cancel(o.cancel_arg)) {
            rc = gs_error_set(err, GS_ERR_CANCELLED,
                              "finetune cancelled at step %d", it);
            break;
        }
        /* The pairs' gradients accumulate: every pair but the last has its
         * gradient taken at once (one forward at a time), the last's waits
         * for the stopping tests, as one image's always did. */
        gs_nn_adam_zero_grad(r.adam);
        double loss = 0, psnr = 0;
        for (int i = 0; !rc && i < k && isfinite(loss); i++) {
            double li = 0, pi = 0;
            rc = ft_pair_step(&r, pool, &f[i], &o, masked, it, i < k - 1, &li,
                              &pi, err);
            loss += li;
            psnr += pi;
        }
        if (rc)
            break;
        float psnr_now = (float)(psnr / k);
        if (!isfinite(loss)) {
            rc = gs_error_set(err, GS_ERR_NONFINITE,
                              "finetune diverged at step %d (loss %g, "
                              "first %g)", it, loss, first);
            break;
        }
        if (it == 0) {
            first = loss;
            psnr_first = psnr_now;
        }
        if (loss < best) {
            best = loss;
            psnr_best = psnr_now;
            if (it > 0)
                ft_pack(&r, r.best, 0);
        }
        if (it == iters)
            break; /* the last step's result is measured, not stepped from */
        hist[it % 20] = loss;
        if (o.plateau_rel > 0 && it >= 20 && hist[(it + 1) % 20] - loss < o.plateau_rel * loss) {
            plateaued = 1;
            break;
        }
        if (o.time_budget_s > 0 && gs_clock_s() - t0 > o.time_budget_s) {
            stopped_on_time = 1;
            break;
        }
        rc = ft_pair_backward(&r, pool, &f[k - 1], &o, masked, it, err);
        if (rc)
            break;
        double gn = 0;
        rc = gs_nn_adam_step(r.adam, lr, &gn);
        if (rc == GS_ERR_NONFINITE) {
            rc = gs_error_set(err, GS_ERR_NONFINITE,
                              "finetune: non-finite gradient at step %d "
                              "(loss %g)", it, loss);
            break;
        }
        if (rc) {
            rc = gs_error_set(err, rc, "finetune: optimizer step failed");
            break;
        }
    }
    /* The best iterate, or on any error the parameters of before. */
    ft_pack(&r, rc ? r.orig : r.best, 1);
    if (!rc)
        m->tuned |= parts;
    if (report) {
        memset(report, 0, sizeof *report);
        report->iters = it;
        report->seconds = gs_clock_s() - t0;
        report->loss_first = first;
        report->loss_best = best;
        report->psnr_first = psnr_first;
        report->psnr_best = psnr_best;
        report->params_tuned = r.tuned;
        report->stopped_on_time = stopped_on_time;
        report->stopped_on_plateau = plateaued;
    }
    ft_free(&r);
    ft_ones_free(f, k);
    return rc;
}
