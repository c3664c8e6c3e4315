/* A frame through the model.
 *
 * Face stream (paper Eq. 2), per face Gaussian i with feature f_i and the
 * distance weight lambda_i (1 near the landmarks, 0 far away):
 *   oE = E([f_i, tau]), oP = P([f_i, PE(rvec(R_head))])
 *   x  = x0 + 4 mm (lambda oE.pos + (1 - lambda) oP.pos)
 *   s  = s0 + 0.2 (lambda oE.scale + (1 - lambda) oP.scale), same for the
 *        quaternion and the opacity logit
 *   c  = c0 + oE.feat + oP.feat
 * Colour is not blended by lambda: identity-dependent appearance (skin tone,
 * hair colour) lives outside the landmark zone too.
 * Eye stream (paper Eq. 4-5), per eye e with eyeball centre c_e:
 *   R_e = R_res,e(PE(gaze)) Ry(yaw) Rx(-pitch)   (R_res initialised to I)
 *   x   = c_e + W_e tau + R_e (x0 - c_e) + 1 mm o.pos,  o = Eye([f, tau, PE(gaze)])
 *   isotropic log-scale s0 + 0.2 o.scale, opacity a0 + 0.2 o.opacity,
 *   c = c0 + o.feat
 * Both streams are moved into the camera by the head pose (x_cam = R x + t,
 * q_cam = q_R q), rasterized at feat_size with a white RGB background and
 * turned into the image by the renderer. */
#include <limits.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "frame.h"
#include "gazesplat/geom.h"
#include "gazesplat/nn.h"

/* ---- small rotation helpers (wxyz quaternions) ---- */

static void quat_mul(const double a[4], const double b[4], double o[4])
{
    o[0] = a[0] * b[0] - a[1] * b[1] - a[2] * b[2] - a[3] * b[3];
    o[1] = a[0] * b[1] + a[1] * b[0] + a[2] * b[3] - a[3] * b[2];
    o[2] = a[0] * b[2] - a[1] * b[3] + a[2] * b[0] + a[3] * b[1];
    o[3] = a[0] * b[3] + a[1] * b[2] - a[2] * b[1] + a[3] * b[0];
}

/* o = L(q)^T v: the gradient of v through q (x) . (o = q^-1 v for unit q). */
static void quat_lmul_t(const double q[4], const double v[4], double o[4])
{
    double a = q[0], b = q[1], c = q[2], d = q[3];
    o[0] = a * v[0] + b * v[1] + c * v[2] + d * v[3];
    o[1] = -b * v[0] + a * v[1] + d * v[2] - c * v[3];
    o[2] = -c * v[0] - d * v[1] + a * v[2] + b * v[3];
    o[3] = -d * v[0] + c * v[1] - b * v[2] + a * v[3];
}

/* Rotation matrix of a unit quaternion. */
static void quat_to_mat(const double q[4], double r[9])
{
    double w = q[0], x = q[1], y = q[2], z = q[3];
    r[0] = 1 - 2 * (y * y + z * z); r[1] = 2 * (x * y - w * z);
    r[2] = 2 * (x * z + w * y);
    r[3] = 2 * (x * y + w * z); r[4] = 1 - 2 * (x * x + z * z);
    r[5] = 2 * (y * z - w * x);
    r[6] = 2 * (x * z - w * y); r[7] = 2 * (y * z + w * x);
    r[8] = 1 - 2 * (x * x + y * y);
}

/* dq[4] (unit q) from dR[9] through quat_to_mat. */
static void quat_to_mat_backward(const double q[4], const double d[9],
                                 double dq[4])
{
    double w = q[0], x = q[1], y = q[2], z = q[3];
    dq[0] = 2 * (-z * d[1] + y * d[2] + z * d[3] - x * d[5] - y * d[6] +
                 x * d[7]);
    dq[1] = 2 * (y * d[1] + z * d[2] + y * d[3] - 2 * x * d[4] - w * d[5] +
                 z * d[6] + w * d[7] - 2 * x * d[8]);
    dq[2] = 2 * (-2 * y * d[0] + x * d[1] + w * d[2] + x * d[3] + z * d[5] -
                 w * d[6] + z * d[7] - 2 * y * d[8]);
    dq[3] = 2 * (-2 * z * d[0] - w * d[1] + x * d[2] + w * d[3] -
                 2 * z * d[4] + y * d[5] + x * d[6] + y * d[7]);
}

static void mat_to_quat(const double r[9], double q[4])
{
    double tr = r[0] + r[4] + r[8];
    if (tr > 0) {
        double s = sqrt(tr + 1.0) * 2;
        q[0] = 0.25 * s; q[1] = (r[7] - r[5]) / s;
        q[2] = (r[2] - r[6]) / s; q[3] = (r[3] - r[1]) / s;
    } else if (r[0] > r[4] && r[0] > r[8]) {
        double s = sqrt(1.0 + r[0] - r[4] - r[8]) * 2;
        q[0] = (r[7] - r[5]) / s; q[1] = 0.25 * s;
        q[2] = (r[1] + r[3]) / s; q[3] = (r[2] + r[6]) / s;
    } else if (r[4] > r[8]) {
        double s = sqrt(1.0 + r[4] - r[0] - r[8]) * 2;
        q[0] = (r[2] - r[6]) / s; q[1] = (r[1] + r[3]) / s;
        q[2] = 0.25 * s; q[3] = (r[5] + r[7]) / s;
    } else {
        double s = sqrt(1.0 + r[8] - r[0] - r[4]) * 2;
        q[0] = (r[3] - r[1]) / s; q[1] = (r[2] + r[6]) / s;
        q[2] = (r[5] + r[7]) / s; q[3] = 0.25 * s;
    }
}

void gs_frame_camera(const gs_model *m, const double head_t[3],
                     gs_camera *cam)
{
    /* A normalized image of a face at distance |t| has focal f_n |t| / d_n
     * (the normalization scales depth, not the image). */
    const gs_model_config *k = &m->cfg;
    double dist = sqrt(head_t[0] * head_t[0] + head_t[1] * head_t[1] +
                       head_t[2] * head_t[2]);
    double f = k->focal * dist / k->d_n_mm * k->feat_size / k->image_size;
    memset(cam, 0, sizeof *cam);
    cam->fx = cam->fy = (float)f;
    cam->cx = cam->cy = 0.5f * (float)k->feat_size;
    cam->width = cam->height = k->feat_size;
    cam->viewmat[0] = cam->viewmat[5] = cam->viewmat[10] = 1.0f;
}

/* ---- face stream ---- */

/* One forward block: the MLP inputs of rows [r0, r1), both MLPs, then
 * the head-frame Gaussians and their camera-frame copies. */
typedef struct face_fwd_job {
    gs_model_ctx *c;
    const gs_frame *fr;
    const double *qR;
    const float *pe;   /* PE(rvec) [| PE(gaze)], npe floats */
    int npe;
    int keep_e;        /* fe_out already holds the expression MLP's rows */
} face_fwd_job;

static void face_assemble(gs_model_ctx *c, const double qR[4], int from,
                          int to);
static void to_camera(gs_model_ctx *c, const gs_frame *fr, int from, int to,
                      const double qR[4]);

static void face_fwd_task(void *ctx, int b, int worker)
{
    const face_fwd_job *j = ctx;
    gs_model_ctx *c = j->c;
    const gs_model_params *p = &c->m->p;
    int F = c->F, D = c->D, O = GS_FACE_OUT(c->C);
    int de = p->face_e.dims[0], dp = p->face_p.dims[0];
    int r0 = b * c->fblk, r1 = r0 + c->fblk < c->nf ? r0 + c->fblk : c->nf;
    /* the block's rows of the training buffers, or this thread's scratch */
    float *ein, *pin, *eact, *pact;
    if (c->fe_act) {
        ein = c->fe_in + (size_t)r0 * de;
        pin = c->fp_in + (size_t)r0 * dp;
        eact = c->fe_act + gs_mlp_act_size(&p->face_e, r0);
        pact = c->fp_act + gs_mlp_act_size(&p->face_p, r0);
    } else {
        ein = c->scr->face + (size_t)worker * gs_ctx_face_scratch_each(c);
        pin = ein + (size_t)c->fblk * de;
        eact = pin + (size_t)c->fblk * dp;
        pact = eact + gs_mlp_act_size(&p->face_e, c->fblk);
    }
    for (int i = r0; i < r1; i++) {
        float *a = ein + (size_t)(i - r0) * de, *bb = pin + (size_t)(i - r0) * dp;
        if (!j->keep_e) {
            memcpy(a, p->f_feat + (size_t)i * F, F * sizeof(float));
            memcpy(a + F, j->fr->code, D * sizeof(float));
        }
        memcpy(bb, p->f_feat + (size_t)i * F, F * sizeof(float));
        memcpy(bb + F, j->pe, j->npe * sizeof(float));
    }
    if (!j->keep_e)
        gs_mlp_forward(&p->face_e, ein, r1 - r0, eact,
                       c->fe_out + (size_t)r0 * O);
    gs_mlp_forward(&p->face_p, pin, r1 - r0, pact, c->fp_out + (size_t)r0 * O);
    face_assemble(c, j->qR, r0, r1);
    to_camera(c, j->fr, r0, r1, j->qR);
}

/* The face stream: MLPs, head-frame Gaussians, into the camera. */
static int face_forward(gs_model_ctx *c, gs_pool *pool, const gs_frame *fr,
                        const double qR[4], int force)
{
    if (!c->fe_act && gs_ctx_face_scratch(c, gs_pool_threads(pool)))
        return GS_ERR_NOMEM;
    double rvec[3];
    float pe[GS_PE_DIM(3) + GS_PE_DIM(2)];
    gs_geom_rot_to_rodrigues(fr->head_R, rvec);
    gs_model_pe(rvec, 3, pe);
    int npe = GS_PE_DIM(3);
    if (!c->m->cfg.two_stream) {
        gs_model_pe(fr->gaze, 2, pe + npe);
        npe += GS_PE_DIM(2);
    }
    /* The expression MLP sees [f_i, code] only: a render at another head
     * pose with the same code and parameters keeps its rows (the same
     * bytes: each block's rows are a function of its inputs). Only a
     * context without training buffers keeps them, since a backward reads
     * the activations, which a render puts in a thread's scratch. */
    int D = c->D;
    int keep = !force && !c->fe_act && c->fe_valid &&
               !memcmp(c->fe_code, fr->code, (size_t)D * sizeof(float));
    face_fwd_job j = {c, fr, qR, pe, npe, keep};
    c->fe_valid = 0;
    c->n_fe_kept += (uint64_t)keep;
    gs_pool_for(pool, c->nfblk, face_fwd_task, &j);
    if (!force && !c->fe_act) {
        memcpy(c->fe_code, fr->code, (size_t)D * sizeof(float));
        c->fe_valid = 1;
    }
    return GS_OK;
}

/* Head-frame face Gaussians [from, to) from the MLP outputs. */
static void face_assemble(gs_model_ctx *c, const double qR[4], int from,
                          int to)
{
    const gs_model_params *p = &c->m->p;
    int C = c->C, O = GS_FACE_OUT(C);
    for (int i = from; i < to; i++) {
        const float *oe = c->fe_out + (size_t)i * O;
        const float *op = c->fp_out + (size_t)i * O;
        float l = p->f_lambda[i], lp = 1.0f - l;
        float *xh = c->x_head + 3 * (size_t)i;
        for (int k = 0; k < 3; k++)
            xh[k] = p->f_xyz[3 * i + k] +
                    GS_MODEL_POS_SCALE * (l * oe[k] + lp * op[k]);
        float *feat = c->g_feat + (size_t)i * C;
        for (int k = 0; k < C; k++)
            feat[k] = p->f_colour[(size_t)i * C + k] + oe[3 + k] + op[3 + k];
        const float *ae = oe + 3 + C, *ap = op + 3 + C;
        for (int k = 0; k < 3; k++)
            c->g_scale[3 * i + k] = p->f_scale[3 * i + k] +
                                    GS_MODEL_ATTR_SCALE *
                                        (l * ae[k] + lp * ap[k]);
        double q[4], qc[4];
        for (int k = 0; k < 4; k++) {
            q[k] = p->f_quat[4 * i + k] +
                   GS_MODEL_ATTR_SCALE * (l * ae[3 + k] + lp * ap[3 + k]);
            c->q_head[4 * i + k] = (float)q[k];
        }
        quat_mul(qR, q, qc);
        for (int k = 0; k < 4; k++)
            c->g_quat[4 * i + k] = (float)qc[k];
        c->g_opac[i] = p->f_opacity[i] +
                       GS_MODEL_ATTR_SCALE * (l * ae[7] + lp * ap[7]);
    }
}

/* ---- eye stream ---- */

/* The eye MLP for a render (no backward follows): its first layer's
 * input is [f_i, tau, PE(gaze)], so W0 [f_i, tau] + b0, fixed for a
 * subject, is kept, and a gaze adds only W0 PE(gaze), one vector for every
 * Gaussian; half the MLP's work. The sums are grouped differently from
 * gs_mlp_forward's: equal within float rounding. */
static void eye_mlp_render(gs_model_ctx *c, const gs_frame *fr)
{
    const gs_mlp *m = &c->m->p.eye;
    int ne = c->ne, F = c->F, D = c->D, fd = F + D, ic = m->dims[0],
        h = m->dims[1];
    if (!c->eye_base_valid ||
        memcmp(c->eye_base_code, fr->code, (size_t)D * sizeof(float))) {
        for (int i = 0; i < ne; i++) { /* [f_i | tau] rows in e_in */
            float *a = c->e_in + (size_t)i * fd;
            memcpy(a, c->m->p.e_feat + (size_t)i * F, F * sizeof(float));
            memcpy(a + F, fr->code, D * sizeof(float));
        }
        gs_nn_linear_forward(c->eye_base, c->e_in, c->eye_w0, m->b[0], ne, fd,
                             h);
        memcpy(c->eye_base_code, fr->code, (size_t)D * sizeof(float));
        c->eye_base_valid = 1;
    }
    for (int o = 0; o < h; o++) {
        const float *w = m->w[0] + (size_t)o * ic + fd;
        float s = 0.0f;
        for (int k = 0; k < GS_PE_DIM(2); k++)
            s += w[k] * c->er_in[k];
        c->eye_v[o] = s;
    }
    for (int i = 0; i < ne; i++) {
        const float *b = c->eye_base + (size_t)i * h;
        float *pre = c->e_act + (size_t)i * h;
        for (int o = 0; o < h; o++)
            pre[o] = b[o] + c->eye_v[o];
    }
    gs_mlp_forward_after_first(m, ne, c->e_act, c->e_out);
}

/* Eye stream: rotations and centres, the MLP (for_render: eye_mlp_render),
 * the Gaussians in the head frame. */
static void eye_forward(gs_model_ctx *c, const gs_frame *fr, int for_render)
{
    const gs_model *m = c->m;
    const gs_model_params *p = &m->p;
    int ne = c->ne, F = c->F, D = c->D, C = c->C, O = GS_EYE_OUT(C);
    int de = p->eye.dims[0], each = m->cfg.n_eye_each;
    gs_model_pe(fr->gaze, 2, c->er_in);
    gs_geom_rot_from_pitchyaw(fr->gaze[0], fr->gaze[1], 0.0, c->eye_Rg);
    for (int e = 0; e < 2; e++) {
        float o[4];
        gs_mlp_forward(&p->eye_rot[e], c->er_in, 1, c->er_act[e], o);
        double q[4] = {1.0 + o[0], o[1], o[2], o[3]};
        double nq = sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] +
                         q[3] * q[3]);
        for (int k = 0; k < 4; k++) {
            c->eye_q[e][k] = q[k];
            q[k] /= nq;
        }
        quat_to_mat(q, c->eye_Rres[e]);
        if (m->cfg.eye_rotation)
            gs_geom_mat3_mul(c->eye_Rres[e], c->eye_Rg, c->eye_R[e]);
        else
            gs_geom_mat3_identity(c->eye_R[e]);
        for (int k = 0; k < 3; k++) {
            double s = p->eye_centre[3 * e + k];
            const float *w = p->eye_centre_w + (size_t)(3 * e + k) * D;
            for (int j = 0; j < D; j++)
                s += (double)w[j] * fr->code[j];
            c->eye_c[e][k] = s;
        }
    }
    if (for_render) {
        eye_mlp_render(c, fr);
    } else {
        for (int i = 0; i < ne; i++) {
            float *a = c->e_in + (size_t)i * de;
            memcpy(a, p->e_feat + (size_t)i * F, F * sizeof(float));
            memcpy(a + F, fr->code, D * sizeof(float));
            memcpy(a + F + D, c->er_in, GS_PE_DIM(2) * sizeof(float));
        }
        gs_mlp_forward(&p->eye, c->e_in, ne, c->e_act, c->e_out);
    }
    for (int i = 0; i < ne; i++) {
        int e = i < each ? 0 : 1;
        const double *R = c->eye_R[e];
        const float *o = c->e_out + (size_t)i * O;
        double r[3];
        for (int k = 0; k < 3; k++)
            r[k] = p->e_xyz[3 * i + k] - p->eye_centre[3 * e + k];
        int g = c->nf + i;
        float *xh = c->x_head + 3 * (size_t)g;
        for (int k = 0; k < 3; k++)
            xh[k] = (float)(c->eye_c[e][k] + R[3 * k] * r[0] +
                            R[3 * k + 1] * r[1] + R[3 * k + 2] * r[2] +
                            GS_MODEL_EYE_POS_SCALE * o[k]);
        float *feat = c->g_feat + (size_t)g * C;
        for (int k = 0; k < C; k++)
            feat[k] = p->e_colour[(size_t)i * C + k] + o[3 + k];
        float s = p->e_scale[i] + GS_MODEL_ATTR_SCALE * o[3 + C];
        c->g_scale[3 * g] = c->g_scale[3 * g + 1] = c->g_scale[3 * g + 2] = s;
        c->g_opac[g] = p->e_opacity[i] + GS_MODEL_ATTR_SCALE * o[4 + C];
    }
}

/* Moves head-frame positions [from, to) into the camera. */
static void to_camera(gs_model_ctx *c, const gs_frame *fr, int from, int to,
                      const double qR[4])
{
    const double *R = fr->head_R, *t = fr->head_t;
    for (int i = from; i < to; i++) {
        const float *x = c->x_head + 3 * (size_t)i;
        float *o = c->g_mean + 3 * (size_t)i;
        for (int k = 0; k < 3; k++)
            o[k] = (float)(R[3 * k] * x[0] + R[3 * k + 1] * x[1] +
                           R[3 * k + 2] * x[2] + t[k]);
        if (i >= c->nf)
            for (int k = 0; k < 4; k++)
                c->g_quat[4 * (size_t)i + k] = (float)qR[k];
    }
}

/* ---- lids ---- */

/* The pitch the lids follow. */
static double lid_pitch_of(const gs_model_ctx *c, const gs_frame *fr)
{
    return c->lid_hold ? c->lid_pitch : fr->gaze[0];
}

/* Lid j's turn about its eyeball's centre: Rx(a), a = -k_j pitch (the
 * eyeball's own turn for a pitch p is Rx(-p): k_j = 1 turns with it). */
static double lid_angle(const gs_model_ctx *c, const gs_frame *fr, int j)
{
    const gs_model_params *p = &c->m->p;
    int i0;
    float w[4];
    float k = gs_lid_k(p->lid_k, p->lid_uv, j < c->nl0 ? 0 : 1, j, &i0, w);
    return -(double)k * lid_pitch_of(c, fr);
}

/* Lid Gaussians into the camera: each face-stream position x (x_head)
 * and quaternion q (q_head) turned about its eyeball's centre c_e (after
 * eye_forward): x' = c_e + Rx(a) (x - c_e), q' = qx(a) q. */
static void lid_forward(gs_model_ctx *c, const gs_frame *fr, const double qR[4])
{
    const double *R = fr->head_R, *t = fr->head_t;
    for (int j = 0; j < c->nl; j++) {
        int i = c->nm + j, e = j < c->nl0 ? 0 : 1;
        double a = lid_angle(c, fr, j), ca = cos(a), sa = sin(a);
        const float *x = c->x_head + 3 * (size_t)i;
        const double *ce = c->eye_c[e];
        double r[3] = {x[0] - ce[0], x[1] - ce[1], x[2] - ce[2]};
        double xr[3] = {ce[0] + r[0], ce[1] + ca * r[1] - sa * r[2],
                        ce[2] + sa * r[1] + ca * r[2]};
        float *o = c->g_mean + 3 * (size_t)i;
        for (int k = 0; k < 3; k++)
            o[k] = (float)(R[3 * k] * xr[0] + R[3 * k + 1] * xr[1] +
                           R[3 * k + 2] * xr[2] + t[k]);
        const float *qh = c->q_head + 4 * (size_t)i;
        double qx[4] = {cos(0.5 * a), sin(0.5 * a), 0, 0};
        double q[4] = {qh[0], qh[1], qh[2], qh[3]}, ql[4], qc[4];
        quat_mul(qx, q, ql);
        quat_mul(qR, ql, qc);
        for (int k = 0; k < 4; k++)
            c->g_quat[4 * (size_t)i + k] = (float)qc[k];
    }
}

static int same_face_key(const gs_model_ctx *c, const gs_frame *fr)
{
    const gs_frame *k = &c->face_key;
    if (memcmp(k->code, fr->code, sizeof k->code) ||
        memcmp(k->head_R, fr->head_R, sizeof k->head_R) ||
        memcmp(k->head_t, fr->head_t, sizeof k->head_t))
        return 0;
    if (!c->m->cfg.two_stream && memcmp(k->gaze, fr->gaze, sizeof k->gaze))
        return 0;
    return 1;
}

static int streams_forward(gs_model_ctx *c, gs_pool *pool, const gs_frame *fr,
                           int force_face)
{
    double qR[4];
    mat_to_quat(fr->head_R, qR);
    /* A cached face stream serves a training forward only when its
     * activations went into the training buffers: one a render computed
     * without them (each block through a thread's scratch), or one from
     * before gs_model_ctx_trim freed them, would leave the backward other
     * activations (every fit's first step is at the same frame: a fit
     * stopped there and run again got another gradient). */
    int saved = !c->fe_act || c->face_saved;
    if (force_face || !c->face_valid || !saved || !same_face_key(c, fr)) {
        c->face_valid = 0;
        if (face_forward(c, pool, fr, qR, force_face))
            return GS_ERR_NOMEM;
        c->face_key = *fr;
        c->face_valid = 1;
        c->face_saved = c->fe_act != NULL;
        c->face_fresh = 1;
        c->face_map_valid = 0;
        c->inc_valid = 0; /* g_* no longer holds inc_key's face */
    } else {
        c->face_fresh = 0;
    }
    if (c->ne) {
        eye_forward(c, fr, 0);
        to_camera(c, fr, c->nf, c->n, qR);
        lid_forward(c, fr, qR);
    }
    c->fr = *fr;
    return GS_OK;
}

int gs_frame_forward_streams(gs_model_ctx *c, gs_pool *pool,
                             const gs_frame *fr, int force_face)
{
    if (gs_ctx_train_alloc(c))
        return GS_ERR_NOMEM;
    return streams_forward(c, pool, fr, force_face);
}

/* The Gaussians [first, first + count) as a raster input. */
static gs_gaussians gaussians_of(const gs_model_ctx *c, int first, int count)
{
    gs_gaussians g = {
        .n = count, .channels = c->C,
        .means = c->g_mean + 3 * (size_t)first,
        .log_scales = c->g_scale + 3 * (size_t)first,
        .quats = c->g_quat + 4 * (size_t)first,
        .opacity_logits = c->g_opac + first,
        .features = c->g_feat + (size_t)first * c->C};
    return g;
}

/* dst [C, plane]: the background of a map of plane pixels (it is constant
 * per channel, so c->bg's first pixel of each channel). */
static void fill_bg(const gs_model_ctx *c, float *dst, size_t plane)
{
    size_t fsz = (size_t)c->fs * c->fs;
    for (int k = 0; k < c->C; k++)
        for (size_t i = 0; i < plane; i++)
            dst[k * plane + i] = c->bg[k * fsz];
}

/* raster_at above the model's size: g through cam at fsr = k fs pixels
 * (k = 2..4, the same view: focal and principal point times k), each
 * feature and alpha pixel the mean of its k x k block (a box filter: the
 * map's value over the pixel's area rather than at its centre). */
static int raster_super(gs_model_ctx *c, gs_raster *r, gs_pool *pool,
                        gs_camera *cam, const gs_gaussians *g, int fsr,
                        float *out, float *alpha, gs_error *err)
{
    int fs = c->fs, C = c->C, k = fsr / fs;
    size_t plane = (size_t)fsr * fsr, want = (2 * (size_t)C + 1) * plane;
    if (want > c->ss_cap) {
        float *b = malloc(want * sizeof *b);
        if (!b)
            return gs_error_set(err, GS_ERR_NOMEM,
                                "model: supersampled map (%zu floats)", want);
        free(c->ss_buf);
        c->ss_buf = b;
        c->ss_cap = want;
    }
    float *hi = c->ss_buf, *ahi = hi + (size_t)C * plane, *bg = ahi + plane;
    fill_bg(c, bg, plane);
    float s = (float)k;
    cam->fx *= s, cam->fy *= s;
    cam->cx *= s, cam->cy *= s;
    cam->width = cam->height = fsr;
    gs_raster_options ro = {.antialiased = 0, .path = GS_RASTER_FAST};
    int rc = gs_raster_forward(r, pool, cam, g, bg, &ro, hi, ahi, NULL, err);
    if (rc)
        return rc;
    float inv = 1.0f / (float)(k * k);
    for (int ch = 0; ch <= C; ch++) { /* channel C: alpha */
        const float *src = ch < C ? hi + ch * plane : ahi;
        float *dst = ch < C ? out + (size_t)ch * fs * fs : alpha;
        for (int y = 0; y < fs; y++)
            for (int x = 0; x < fs; x++) {
                float a = 0.0f;
                for (int dy = 0; dy < k; dy++)
                    for (int dx = 0; dx < k; dx++)
                        a += src[(size_t)(k * y + dy) * fsr + k * x + dx];
                dst[(size_t)y * fs + x] = a * inv;
            }
    }
    return GS_OK;
}

/* Rasterizes g into out [C, fs, fs] at the feature size fsr: at fs
 * directly; below, through a camera of the same view at fsr pixels into
 * lo [C, fsr, fsr] (scratch), resampled bilinearly to fs. Only renders
 * (no backward follows) ask for fsr < fs. render: no backward follows, so
 * the rasterizer keeps no records for one. from > 0 (only for a render
 * at fs): out and alpha hold the map of g's first `from` Gaussians, and
 * only the tiles the rest reach are composited
 * (gs_raster_options.changed_from). */
static int raster_at(gs_model_ctx *c, gs_raster *r, gs_pool *pool,
                     const gs_gaussians *g, int fsr, int render, int from,
                     float *out, float *alpha, float *lo, gs_error *err)
{
    gs_raster_set_records(r, !render);
    gs_camera cam;
    gs_frame_camera(c->m, c->fr.head_t, &cam);
    gs_raster_options ro = {.antialiased = 0, .path = GS_RASTER_FAST,
                            .changed_from = from};
    if (fsr == c->fs)
        return gs_raster_forward(r, pool, &cam, g, c->bg, &ro, out, alpha,
                                 NULL, err);
    if (fsr > c->fs)
        return raster_super(c, r, pool, &cam, g, fsr, out, alpha, err);
    float s = (float)fsr / (float)c->fs;
    cam.fx *= s, cam.fy *= s;
    cam.cx = cam.cy = 0.5f * (float)fsr;
    cam.width = cam.height = fsr;
    fill_bg(c, c->bg_crop, (size_t)fsr * fsr);
    int rc = gs_raster_forward(r, pool, &cam, g, c->bg_crop, &ro, lo, alpha,
                               NULL, err);
    if (!rc && gs_nn_resize_bilinear_forward(out, lo, c->C, fsr, fsr, c->fs,
                                             c->fs))
        rc = gs_error_set(err, GS_ERR_STATE, "model: feature resampling");
    return rc;
}

/* The face stream alone into c->fmap_face (the guidance source and the
 * face-only training render) at feature size fsr, unless it is current. */
static int face_map(gs_model_ctx *c, gs_pool *pool, int fsr, int render,
                    gs_error *err)
{
    if (c->face_map_valid && c->face_map_fs == fsr)
        return GS_OK;
    c->face_map_valid = 0;
    gs_gaussians g = gaussians_of(c, 0, c->nm); /* the lids move: not */
    int rc = raster_at(c, c->raster_face, pool, &g, fsr, render, 0, c->fmap_face,
                       c->alpha_face, c->v_fmap_face, err);
    if (!rc) {
        c->face_map_valid = 1;
        c->face_map_fs = fsr;
    }
    return rc;
}

/* The eye_direct buffers, each made on first use (rgb_main also comes
 * and goes with the sweep cache's slots, which swap it). */
static int direct_alloc(gs_model_ctx *c)
{
    size_t n = (size_t)c->n, plane = (size_t)c->S * c->S;
    if (!c->raster_dir)
        c->raster_dir = gs_raster_create();
    float **b[] = {&c->dir_feat, &c->dir_vfeat, &c->dir_out, &c->dir_alpha,
                   &c->rgb_main, &c->dir_dmain, &c->dir_d};
    size_t len[] = {4 * n, 4 * n, 4 * plane, plane, 3 * plane, 3 * plane,
                    4 * plane};
    for (size_t i = 0; i < sizeof b / sizeof b[0]; i++)
        if (!*b[i])
            *b[i] = malloc(len[i] * sizeof(float));
    if (!c->dir_bg)
        c->dir_bg = calloc(4 * plane, sizeof(float));
    int ok = c->raster_dir && c->dir_bg;
    for (size_t i = 0; i < sizeof b / sizeof b[0]; i++)
        ok = ok && *b[i];
    return ok ? GS_OK : GS_ERR_NOMEM;
}

/* The eye stream at the image's size (config.eye_direct), after the
 * renderer wrote c->rgb: every Gaussian rasterized through the map's view
 * at S x S pixels with the eye stream's colour and an indicator (face
 * Gaussians: zeros; they occlude), so that E (3 planes) is the eye
 * stream's composited colour and beta its share of each pixel; the image
 * becomes rgb_main (1 - beta) + E. Only the tiles the eye stream can
 * reach are rasterized (a crop with the full image's frustum: each pixel
 * as the whole image's); elsewhere beta and E are 0 and the image is the
 * renderer's. render: no backward follows. */
static int direct_forward(gs_model_ctx *c, gs_pool *pool, int render,
                          gs_error *err)
{
    size_t n = (size_t)c->n, plane = (size_t)c->S * c->S;
    if (direct_alloc(c))
        return gs_error_set(err, GS_ERR_NOMEM, "eye direct: out of memory");
    for (size_t i = 0; i < n; i++) {
        float ind = i >= (size_t)c->nf ? 1.0f : 0.0f;
        for (int k = 0; k < 3; k++)
            c->dir_feat[4 * i + k] = ind * c->g_feat[i * (size_t)c->C + k];
        c->dir_feat[4 * i + 3] = ind;
    }
    gs_gaussians g = gaussians_of(c, 0, c->n);
    g.channels = 4;
    g.features = c->dir_feat;
    gs_camera full;
    gs_frame_camera(c->m, c->fr.head_t, &full);
    float s = (float)c->S / (float)c->fs;
    full.fx *= s, full.fy *= s;
    full.cx *= s, full.cy *= s;
    full.width = full.height = c->S;
    int *d = c->dir_box;
    gs_frame_eye_tiles(c, &full, d);
    memcpy(c->rgb_main, c->rgb, 3 * plane * sizeof(float));
    c->dir_valid = 1;
    if (d[0] >= d[2] || d[1] >= d[3]) /* no eye in the image */
        return GS_OK;
    gs_camera cam = full;
    cam.cx -= (float)d[0], cam.cy -= (float)d[1];
    int w = d[2] - d[0], h = d[3] - d[1], S = c->S;
    cam.width = w, cam.height = h;
    gs_raster_options ro = {.antialiased = 0, .path = GS_RASTER_FAST};
    int rc = gs_raster_set_frustum(c->raster_dir, &full, err);
    if (!rc) {
        gs_raster_set_records(c->raster_dir, !render);
        rc = gs_raster_forward(c->raster_dir, pool, &cam, &g, c->dir_bg, &ro,
                               c->dir_out, c->dir_alpha, NULL, err);
    }
    if (rc) {
        c->dir_valid = 0;
        return rc;
    }
    size_t cp = (size_t)w * h;
    const float *beta = c->dir_out + 3 * cp;
    for (int k = 0; k < 3; k++)
        for (int y = 0; y < h; y++) {
            float *o = c->rgb + k * plane + (size_t)(d[1] + y) * S + d[0];
            const float *e = c->dir_out + k * cp + (size_t)y * w;
            const float *b = beta + (size_t)y * w;
            for (int x = 0; x < w; x++)
                o[x] = o[x] * (1.0f - b[x]) + e[x];
        }
    return GS_OK;
}

/* Takes the eye stream's composite off the live image (the renderer's
 * own image comes back over the last crop), before an incremental render
 * re-renders part of it; those pixels join c->rgb_dirty. */
static void direct_undo(gs_model_ctx *c)
{
    const int *d = c->dir_box;
    int S = c->S;
    if (d[0] >= d[2] || d[1] >= d[3])
        return;
    for (int k = 0; k < 3; k++)
        for (int y = d[1]; y < d[3]; y++) {
            size_t at = ((size_t)k * S + y) * S + d[0];
            memcpy(c->rgb + at, c->rgb_main + at,
                   (size_t)(d[2] - d[0]) * sizeof(float));
        }
    gs_frame_box_union(c->rgb_dirty, d);
}

/* gs_frame_forward with the feature map rasterized at fsr pixels; render:
 * no backward follows (gs_frame_render). */
static int forward_at(gs_model_ctx *c, gs_pool *pool, const gs_frame *fr,
                      int stream, int force_face, int fsr, int render,
                      gs_error *err)
{
    if (force_face) /* training: the parameters change between calls */
        gs_sweep_drop(c);
    else /* fmap, rgb and g_* are overwritten: keep the render elsewhere */
        gs_sweep_stash(c);
    c->inc_valid = 0;
    c->rgb8_valid = 0;
    c->cover_valid = 0;
    c->dir_valid = 0;
    if (!render && gs_ctx_train_alloc(c))
        return gs_error_set(err, GS_ERR_NOMEM,
                            "model: out of memory for the training buffers");
    if (streams_forward(c, pool, fr, force_face))
        return gs_error_set(err, GS_ERR_NOMEM, "model: out of memory");
    c->stream = stream;
    int first = 0, count = c->n;
    if (stream == GS_STREAM_FACE)
        count = c->nf;
    else if (stream == GS_STREAM_EYE) {
        first = c->nf;
        count = c->ne;
    }
    gs_gaussians g = gaussians_of(c, first, count);
    /* the face-only map: the guidance source, or a training loss term */
    c->used_src = c->src_mode && stream == GS_STREAM_BOTH;
    c->used_face_map = c->ne > 0 && stream == GS_STREAM_BOTH &&
                       (c->used_src || c->face_loss);
    int rc = GS_OK, from = 0;
    if (c->used_face_map) {
        rc = face_map(c, pool, fsr, render, err);
        if (rc)
            return rc;
        /* A render's merged map is the face-only map except where the
         * lids and the eyes reach: start from it and composite only the
         * tiles they are binned to (the same bits as all of them). */
        if (render && fsr == c->fs) {
            size_t px = (size_t)c->fs * c->fs;
            memcpy(c->fmap, c->fmap_face, px * (size_t)c->C * sizeof(float));
            memcpy(c->alpha, c->alpha_face, px * sizeof(float));
            from = c->nm;
        }
    }
    rc = raster_at(c, c->raster, pool, &g, fsr, render, from, c->fmap,
                   c->alpha, c->v_fmap, err);
    if (rc)
        return rc;
    c->used_eye_map = c->ne > 0 && stream == GS_STREAM_BOTH && c->eye_loss &&
                      c->fmap_eye;
    if (c->used_eye_map) { /* the eye stream alone, for its training loss */
        gs_gaussians ge = gaussians_of(c, c->nf, c->ne);
        rc = raster_at(c, c->raster_eye, pool, &ge, fsr, render, 0, c->fmap_eye,
                       c->alpha_eye, c->v_fmap_eye, err);
        if (rc)
            return rc;
    }
    float *acts;
    size_t alen;
    if (gs_ctx_render_acts(c, &acts, &alen))
        return gs_error_set(err, GS_ERR_NOMEM, "model: out of memory");
    rc = gs_renderer_forward_src(&c->m->rcfg, &c->m->p.rend, c->fmap,
                                 fr->code, c->used_src ? c->fmap_face : NULL,
                                 c->fs, c->fs, acts, alen, c->rgb, pool);
    if (rc)
        return gs_error_set(err, rc, "model: renderer forward failed");
    if (c->eye_direct && stream == GS_STREAM_BOTH)
        return direct_forward(c, pool, render, err);
    return GS_OK;
}

int gs_frame_forward(gs_model_ctx *c, gs_pool *pool, const gs_frame *fr,
                     int stream, int force_face, gs_error *err)
{
    return forward_at(c, pool, fr, stream, force_face, c->ss * c->fs, 0, err);
}

int gs_frame_eye_cover(gs_model_ctx *c, gs_pool *pool, gs_error *err)
{
    size_t n = (size_t)c->n, fsz = (size_t)c->fs * c->fs;
    if (!c->ne || c->stream != GS_STREAM_BOTH)
        return gs_error_set(err, GS_ERR_STATE,
                            "eye cover: needs a forward of both streams");
    if (c->ss > 1)
        return gs_error_set(err, GS_ERR_ARG,
                            "eye cover: not with a supersampled model");
    if (!c->raster_cov) {
        c->raster_cov = gs_raster_create();
        c->cov_ind = calloc(n, sizeof(float));
        c->v_ind = calloc(n, sizeof(float));
        c->cov_bg = calloc(fsz, sizeof(float));
        c->cover = calloc(2 * fsz, sizeof(float)); /* and its alpha */
        if (!c->raster_cov || !c->cov_ind || !c->v_ind || !c->cov_bg ||
            !c->cover) {
            gs_raster_destroy(c->raster_cov);
            free(c->cov_ind), free(c->v_ind), free(c->cov_bg), free(c->cover);
            c->raster_cov = NULL;
            c->cov_ind = c->v_ind = c->cov_bg = c->cover = NULL;
            return gs_error_set(err, GS_ERR_NOMEM, "eye cover: out of memory");
        }
        for (size_t i = (size_t)c->nf; i < n; i++)
            c->cov_ind[i] = 1.0f;
    }
    gs_gaussians g = gaussians_of(c, 0, c->n);
    g.channels = 1;
    g.features = c->cov_ind;
    gs_camera cam;
    gs_frame_camera(c->m, c->fr.head_t, &cam);
    gs_raster_options ro = {.antialiased = 0, .path = GS_RASTER_FAST};
    gs_raster_set_records(c->raster_cov, 1);
    int rc = gs_raster_forward(c->raster_cov, pool, &cam, &g, c->cov_bg, &ro,
                               c->cover, c->cover + fsz, NULL, err);
    c->cover_valid = rc == GS_OK;
    return rc;
}

/* ---- incremental renders ---- */

/* Pixel box (x0 y0 x1 y1, exclusive) that contains the rasterizer's
 * radius box of a Gaussian at camera position x with largest log-scale ls,
 * in the full map (camera cam) and in any crop of it rendered with cam's
 * frustum (raster_box). The projected covariance's largest eigenvalue is at
 * most (f s / z)^2 (1 + a^2 + b^2), a and b the Jacobian's x/z and y/z after
 * its frustum clamp, which only moves them toward the centre: |x/z| and
 * |y/z| bound them. Then the 0.3 px^2 dilation and gsplat's eigenvalue
 * floor (its square-root term floored at 0.1: lambda grows by 0.1 at most),
 * and radius = ceil(3 sqrt(lambda)) (+1), with 0.1 px against rounding (the
 * rasterizer works in float). The tiles the rasterizer bins to are those
 * its radius box meets, so they meet this box. A box that cannot be
 * bounded covers everything. */
static void splat_box(const gs_camera *cam, const float *x, const float *ls,
                      int b[4])
{
    double z = x[2], big = 1e6;
    if (!(z > GS_RASTER_NEAR)) { /* culled by the rasterizer */
        b[0] = b[1] = b[2] = b[3] = 0;
        return;
    }
    double a = x[0] / z, c = x[1] / z;
    double s = fmax(cam->fx, cam->fy) * exp(fmax(ls[0], fmax(ls[1], ls[2]))) / z;
    double r = 3.0 * sqrt(s * s * (1.0 + a * a + c * c) + 0.4) + 1.1;
    double u = cam->fx * x[0] / z + cam->cx, v = cam->fy * x[1] / z + cam->cy;
    double lo[2] = {u - r, v - r}, hi[2] = {u + r, v + r};
    int lim[2] = {cam->width, cam->height};
    for (int k = 0; k < 2; k++) {
        if (!(lo[k] > -big && hi[k] < big)) /* also NaN: keep it */
            lo[k] = -big, hi[k] = big;
        b[k] = (int)floor(fmax(lo[k], -1.0));
        b[k + 2] = (int)ceil(fmin(hi[k], lim[k] + 1.0));
    }
}

/* Tile-aligned box (pixels of cam, x0 y0 x1 y1, x1 y1 exclusive, clipped
 * to its image; empty when x0 >= x1) of every tile the moving Gaussians
 * (lids and eye stream) can reach. The rasterizer bins a Gaussian to each
 * tile its 3-sigma box touches and composites it on any pixel of those
 * tiles where its alpha passes 1/255, so its reach is a set of whole
 * tiles: those of the union of splat_box. */
void gs_frame_eye_tiles(const gs_model_ctx *c, const gs_camera *cam, int r[4])
{
    int lo[2] = {INT_MAX, INT_MAX}, hi[2] = {INT_MIN, INT_MIN};
    for (int i = c->nm; i < c->n; i++) { /* the lids and the eye stream */
        int b[4];
        splat_box(cam, c->g_mean + 3 * (size_t)i, c->g_scale + 3 * (size_t)i, b);
        if (b[0] >= b[2] || b[1] >= b[3]) /* behind the camera */
            continue;
        for (int k = 0; k < 2; k++) {
            lo[k] = b[k] < lo[k] ? b[k] : lo[k];
            hi[k] = b[k + 2] > hi[k] ? b[k + 2] : hi[k];
        }
    }
    const int T = GS_RASTER_TILE, lim[2] = {cam->width, cam->height};
    for (int k = 0; k < 2; k++) {
        int a = lo[k] > 0 ? lo[k] : 0, e = hi[k] < lim[k] ? hi[k] : lim[k];
        if (a >= e) {
            r[0] = r[1] = r[2] = r[3] = 0;
            return;
        }
        int t1 = (e + T - 1) / T * T;
        r[k] = a / T * T;
        r[k + 2] = t1 < lim[k] ? t1 : lim[k];
    }
}

void gs_frame_box_union(int a[4], const int b[4])
{
    if (b[0] >= b[2] || b[1] >= b[3])
        return;
    if (a[0] >= a[2] || a[1] >= a[3]) {
        memcpy(a, b, 4 * sizeof *a);
        return;
    }
    a[0] = b[0] < a[0] ? b[0] : a[0], a[1] = b[1] < a[1] ? b[1] : a[1];
    a[2] = b[2] > a[2] ? b[2] : a[2], a[3] = b[3] > a[3] ? b[3] : a[3];
}

/* box grown by m on every side, clipped to [0, n)^2 */
static void box_grow(const int b[4], int m, int n, int o[4])
{
    o[0] = b[0] - m > 0 ? b[0] - m : 0, o[1] = b[1] - m > 0 ? b[1] - m : 0;
    o[2] = b[2] + m < n ? b[2] + m : n, o[3] = b[3] + m < n ? b[3] + m : n;
}

void gs_frame_face_boxes(const gs_model_ctx *c, const gs_camera *cam,
                         int16_t *fbox)
{
    for (int i = 0; i < c->nf; i++) {
        int b[4];
        splat_box(cam, c->g_mean + 3 * (size_t)i, c->g_scale + 3 * (size_t)i, b);
        for (int k = 0; k < 4; k++) /* within [-1, edge + 1] */
            fbox[4 * (size_t)i + k] = (int16_t)b[k];
    }
}

static void gather_one(const gs_gaussians *src, int i, const gs_frame_soa *dst,
                       int k)
{
    size_t C = (size_t)src->channels;
    memcpy(dst->mean + 3 * (size_t)k, src->means + 3 * (size_t)i,
           3 * sizeof(float));
    memcpy(dst->scale + 3 * (size_t)k, src->log_scales + 3 * (size_t)i,
           3 * sizeof(float));
    memcpy(dst->quat + 4 * (size_t)k, src->quats + 4 * (size_t)i,
           4 * sizeof(float));
    dst->opac[k] = src->opacity_logits[i];
    memcpy(dst->feat + (size_t)k * C, src->features + (size_t)i * C,
           C * sizeof(float));
}

/* The order is kept, and the rasterizer sorts by (depth, index) and culls
 * what misses the image, so the crop renders exactly as with every
 * Gaussian: only the projection of the far ones (most of the face) is
 * saved. */
gs_gaussians gs_frame_gather(const gs_gaussians *src, int nf,
                             const int16_t *fbox, const int d[4],
                             const gs_frame_soa *dst)
{
    int k = 0;
    for (int i = 0; i < nf; i++) {
        const int16_t *b = fbox + 4 * (size_t)i;
        if (b[0] < d[2] && b[2] > d[0] && b[1] < d[3] && b[3] > d[1])
            gather_one(src, i, dst, k++);
    }
    for (int i = nf; i < src->n; i++)
        gather_one(src, i, dst, k++);
    gs_gaussians g = {.n = k, .channels = src->channels, .means = dst->mean,
                      .log_scales = dst->scale, .quats = dst->quat,
                      .opacity_logits = dst->opac, .features = dst->feat};
    return g;
}

int gs_frame_raster_crop(gs_raster *r, gs_pool *pool, const gs_camera *full,
                         const int d[4], const gs_gaussians *g,
                         const float *bg, float *out, float *alpha,
                         float *depth, gs_error *err)
{
    gs_camera cam = *full;
    cam.cx -= (float)d[0], cam.cy -= (float)d[1];
    cam.width = d[2] - d[0], cam.height = d[3] - d[1];
    /* the full image's frustum: the Jacobian's clamp as in the full render */
    int rc = gs_raster_set_frustum(r, full, err);
    if (rc)
        return rc;
    gs_raster_options ro = {.antialiased = 0, .path = GS_RASTER_FAST};
    gs_raster_set_records(r, 0); /* renders only */
    return gs_raster_forward(r, pool, &cam, g, bg, &ro, out, alpha, depth,
                             err);
}

/* A value moved by more than float rounding. The crop's camera
 * has its centre shifted, which rounds the splats' pixel offsets
 * differently from the full render's: values then differ by a few ulps
 * all over the crop (about 1e-7 of 0.4), which are not changes: what
 * moves by less than 1e-6 (1 + |old|) keeps its value. */
int gs_frame_moved(float old, float now)
{
    return fabsf(now - old) > 1e-6f * (1.0f + fabsf(old)) || isnan(now);
}

/* Rasterizes the Gaussians that can reach the box d (tile-aligned) and
 * writes into c->fmap the values that moved; ch is the bounding box of
 * those feature pixels (empty when none did): the renderer need only
 * revisit that. A value that did not move keeps the one the image was
 * rendered from. */
static int raster_box(gs_model_ctx *c, gs_pool *pool, const gs_camera *full,
                      const int d[4], int ch[4], gs_error *err)
{
    int w = d[2] - d[0], h = d[3] - d[1], fs = c->fs, C = c->C;
    size_t plane = (size_t)w * h;
    fill_bg(c, c->bg_crop, plane);
    gs_gaussians all = {.n = c->n, .channels = C, .means = c->g_mean,
                        .log_scales = c->g_scale, .quats = c->g_quat,
                        .opacity_logits = c->g_opac, .features = c->g_feat};
    gs_frame_soa kept = {c->k_mean, c->k_scale, c->k_quat, c->k_opac,
                         c->k_feat};
    gs_gaussians g = gs_frame_gather(&all, c->nm, c->fbox, d, &kept);
    float *out = c->v_fmap, *alpha = c->v_fmap_face; /* scratch here */
    int rc = gs_frame_raster_crop(c->raster_crop, pool, full, d, &g,
                                  c->bg_crop, out, alpha, NULL, err);
    if (rc)
        return rc;
    ch[0] = ch[1] = INT_MAX, ch[2] = ch[3] = INT_MIN;
    for (int k = 0; k < C; k++)
        for (int y = 0; y < h; y++) {
            float *dst = c->fmap + ((size_t)k * fs + d[1] + y) * fs + d[0];
            const float *src = out + k * plane + (size_t)y * w;
            for (int x = 0; x < w; x++)
                if (gs_frame_moved(dst[x], src[x])) {
                    int gx = d[0] + x, gy = d[1] + y;
                    ch[0] = gx < ch[0] ? gx : ch[0], ch[2] = gx >= ch[2] ? gx + 1 : ch[2];
                    ch[1] = gy < ch[1] ? gy : ch[1], ch[3] = gy >= ch[3] ? gy + 1 : ch[3];
                    dst[x] = src[x];
                }
        }
    if (ch[0] == INT_MAX)
        ch[0] = ch[1] = ch[2] = ch[3] = 0;
    return GS_OK;
}

/* Re-renders the output over the reach of the feature box d; the image
 * pixels rewritten join c->rgb_dirty. */
static int render_box(gs_model_ctx *c, gs_pool *pool, const int d[4])
{
    const int R = GS_RENDERER_REACH_PX, fs = c->fs, C = c->C, S = c->S;
    int in[4], keep[4], d4[4] = {4 * d[0], 4 * d[1], 4 * d[2], 4 * d[3]};
    box_grow(d, (2 * R + 3) / 4, fs, in); /* what the kept pixels read */
    box_grow(d4, R, S, keep);             /* what the change can reach */
    int w = in[2] - in[0], h = in[3] - in[1];
    float *x = c->v_fmap, *out = c->v_rgb; /* scratch here */
    for (int k = 0; k < C; k++)
        for (int y = 0; y < h; y++)
            memcpy(x + ((size_t)k * h + y) * w,
                   c->fmap + ((size_t)k * fs + in[1] + y) * fs + in[0],
                   (size_t)w * sizeof(float));
    float *acts;
    size_t alen;
    int rc = gs_ctx_render_acts(c, &acts, &alen);
    if (rc)
        return rc;
    rc = gs_renderer_forward_vec(&c->m->rcfg, &c->m->p.rend, x, c->gvec, h, w,
                                 acts, alen, out, pool);
    if (rc)
        return rc;
    int W4 = 4 * w, H4 = 4 * h;
    for (int k = 0; k < 3; k++)
        for (int y = keep[1]; y < keep[3]; y++)
            memcpy(c->rgb + ((size_t)k * S + y) * S + keep[0],
                   out + ((size_t)k * H4 + y - 4 * in[1]) * W4 + keep[0] -
                       4 * in[0],
                   (size_t)(keep[2] - keep[0]) * sizeof(float));
    gs_frame_box_union(c->rgb_dirty, keep);
    if (c->anc_valid)
        gs_frame_box_union(c->anc_rbox, keep);
    return GS_OK;
}

/* ---- rendering for display ---- */

/* Only the eye stream, into the camera (the face part of g_* is the live
 * render's). */
static void eye_streams(gs_model_ctx *c, const gs_frame *fr)
{
    double qR[4];
    mat_to_quat(fr->head_R, qR);
    eye_forward(c, fr, 1);
    to_camera(c, fr, c->nf, c->n, qR);
    lid_forward(c, fr, qR);
    c->fr = *fr;
}

/* Keeps the full render just made (fmap, rgb, inc_rect) as the anchor of
 * the incremental renders after it. Without the memory for it, the
 * incremental renders go on from the last one, as exact to a few ulps. */
static void anchor_set(gs_model_ctx *c)
{
    size_t fsz = (size_t)c->fs * c->fs * c->C, isz = (size_t)c->S * c->S * 3;
    c->anc_valid = 0;
    if (c->eye_direct)
        return;
    if (!c->anc_fmap)
        c->anc_fmap = malloc(fsz * sizeof(float));
    if (!c->anc_rgb)
        c->anc_rgb = malloc(isz * sizeof(float));
    if (!c->anc_fmap || !c->anc_rgb)
        return;
    memcpy(c->anc_fmap, c->fmap, fsz * sizeof(float));
    memcpy(c->anc_rgb, c->rgb, isz * sizeof(float));
    memcpy(c->anc_rect, c->inc_rect, sizeof c->anc_rect);
    memset(c->anc_fbox, 0, sizeof c->anc_fbox);
    memset(c->anc_rbox, 0, sizeof c->anc_rbox);
    c->anc_valid = 1;
}

/* Puts back the anchor's values over what the last incremental render
 * wrote (anc_fbox in fmap, anc_rbox in rgb; the 8-bit image follows rgb
 * there through rgb_dirty). */
static void anchor_restore(gs_model_ctx *c)
{
    if (!c->anc_valid)
        return;
    const int *f = c->anc_fbox, *r = c->anc_rbox;
    int fs = c->fs, S = c->S;
    for (int k = 0; f[0] < f[2] && k < c->C; k++)
        for (int y = f[1]; y < f[3]; y++) {
            size_t o = ((size_t)k * fs + y) * fs + f[0];
            memcpy(c->fmap + o, c->anc_fmap + o, (size_t)(f[2] - f[0]) * sizeof(float));
        }
    for (int k = 0; r[0] < r[2] && k < 3; k++)
        for (int y = r[1]; y < r[3]; y++) {
            size_t o = ((size_t)k * S + y) * S + r[0];
            memcpy(c->rgb + o, c->anc_rgb + o, (size_t)(r[2] - r[0]) * sizeof(float));
        }
    if (r[0] < r[2])
        gs_frame_box_union(c->rgb_dirty, r);
    memset(c->anc_fbox, 0, sizeof c->anc_fbox);
    memset(c->anc_rbox, 0, sizeof c->anc_rbox);
}

static int render_full(gs_model_ctx *c, gs_pool *pool, const gs_frame *fr,
                       gs_error *err)
{
    int rc = forward_at(c, pool, fr, GS_STREAM_BOTH, 0, c->fs, 1, err);
    if (rc)
        return rc;
    if (c->src_mode) {
        float *acts;
        size_t alen;
        if (gs_ctx_render_acts(c, &acts, &alen))
            return gs_error_set(err, GS_ERR_NOMEM, "model: out of memory");
        rc = gs_renderer_guide_vector(&c->m->rcfg, &c->m->p.rend,
                                      c->fmap_face, fr->code, c->fs, c->fs,
                                      acts, alen, c->gvec, pool);
        if (rc)
            return gs_error_set(err, rc, "model: guidance vector failed");
    }
    gs_camera cam;
    gs_frame_camera(c->m, fr->head_t, &cam);
    gs_frame_eye_tiles(c, &cam, c->inc_rect);
    gs_frame_face_boxes(c, &cam, c->fbox);
    c->inc_key = *fr;
    c->inc_valid = 1;
    c->n_full++;
    anchor_set(c);
    return GS_OK;
}

static int render_inc(gs_model_ctx *c, gs_pool *pool, const gs_frame *fr,
                      gs_error *err)
{
    gs_camera cam;
    c->inc_valid = 0; /* until the update is complete */
    eye_streams(c, fr);
    gs_frame_camera(c->m, fr->head_t, &cam);
    int now[4], dirty[4];
    if (c->eye_direct)
        direct_undo(c);
    else
        anchor_restore(c);
    gs_frame_eye_tiles(c, &cam, now);
    memcpy(dirty, c->anc_valid ? c->anc_rect : c->inc_rect, sizeof dirty);
    gs_frame_box_union(dirty, now);
    if (dirty[0] < dirty[2] && dirty[1] < dirty[3]) {
        int changed[4];
        int rc = raster_box(c, pool, &cam, dirty, changed, err);
        if (rc)
            return rc;
        if (c->anc_valid)
            gs_frame_box_union(c->anc_fbox, changed);
        if (changed[0] < changed[2])
            rc = render_box(c, pool, changed);
        if (rc)
            return gs_error_set(err, rc, "model: incremental renderer failed");
        c->inc_stats[0] += (double)(dirty[2] - dirty[0]) * (dirty[3] - dirty[1]);
        c->inc_stats[1] += (double)(changed[2] - changed[0]) * (changed[3] - changed[1]);
    }
    if (c->eye_direct) { /* the eye stream over the renderer's new image */
        int rc = direct_forward(c, pool, 1, err);
        if (rc)
            return rc;
        gs_frame_box_union(c->rgb_dirty, c->dir_box);
    }
    memcpy(c->inc_rect, now, sizeof now);
    c->inc_key = *fr;
    c->inc_valid = 1;
    c->n_inc++;
    return GS_OK;
}

int gs_frame_wants_anchor(const gs_model_ctx *c, const gs_frame *fr)
{
    if (!c->inc_ok || c->render_fs != c->fs || c->render_full || c->eye_direct)
        return 0;
    if (c->inc_valid && gs_frame_same_subject_pose(&c->inc_key, fr))
        return 0;
    for (int i = 0; c->slots && i < c->sweep_n - 1; i++)
        if (c->slots[i].valid && gs_frame_same_subject_pose(&c->slots[i].key, fr))
            return 0;
    return 1;
}

int gs_frame_render(gs_model_ctx *c, gs_pool *pool, const gs_frame *fr,
                    int *incremental, gs_error *err)
{
    int rc, inc = 0;
    c->last_inc = 0;
    if (incremental)
        *incremental = 0;
    /* Without incremental renders: the model does not allow them, the
     * feature map is rasterized at another size than the crops would be,
     * or every render starts from scratch (face stream included). */
    if (!c->inc_ok || c->render_fs != c->fs || c->render_full) {
        rc = forward_at(c, pool, fr, GS_STREAM_BOTH, c->render_full,
                        c->render_fs, 1, err);
        c->n_full += rc == GS_OK;
        return rc;
    }
    if (!c->inc_valid || !gs_frame_same_subject_pose(&c->inc_key, fr))
        gs_sweep_select(c, fr);
    inc = c->inc_valid && gs_frame_same_subject_pose(&c->inc_key, fr);
    rc = inc ? render_inc(c, pool, fr, err) : render_full(c, pool, fr, err);
    if (rc)
        return rc;
    c->last_inc = inc;
    if (incremental)
        *incremental = inc;
    return GS_OK;
}

/* ---- backward ---- */

/* Scratch layout: [0, mlp) MLP scratch, then two blocks of `blk` floats
 * for the output and input gradients of one MLP. */
static void scratch_parts(const gs_model_ctx *c, float **mlp, float **dout,
                          float **din)
{
    size_t blk = c->scratch_blk;
    *mlp = c->scratch;
    *dout = c->scratch + c->scratch_len - 2 * blk;
    *din = c->scratch + c->scratch_len - blk;
}

/* One backward block of one pass (0: the expression MLP E, weight lambda;
 * 1: the pose MLP P, weight 1 - lambda). */
typedef struct face_bwd_job {
    gs_model_ctx *c;
    const gs_model_params *gp;
    const double *qR;
    int pass;
    int weights;   /* the MLP's weight gradients are wanted */
    int need_din;  /* its input gradient */
    int code, gz;  /* the code's (E), the gaze encoding's (P, single stream) */
} face_bwd_job;

/* Block b's weight gradients of mlp in c->blk_grad, as a gs_mlp. */
static void block_grads(const gs_model_ctx *c, const gs_mlp *mlp, int b,
                        gs_mlp *out)
{
    float *g = c->blk_grad + (size_t)b * c->blk_grad_len;
    memset(out, 0, sizeof *out);
    for (int l = 0; l < mlp->nl; l++) {
        out->w[l] = g;
        g += (size_t)mlp->dims[l] * mlp->dims[l + 1];
        out->b[l] = g;
        g += mlp->dims[l + 1];
    }
}

static void face_bwd_task(void *ctx, int b, int worker)
{
    (void)worker;
    const face_bwd_job *j = ctx;
    gs_model_ctx *c = j->c;
    const gs_model_params *p = &c->m->p, *gp = j->gp;
    int C = c->C, O = GS_FACE_OUT(C), F = c->F, D = c->D, pass = j->pass;
    const double *R = c->fr.head_R, *qR = j->qR;
    int r0 = b * c->fblk, r1 = r0 + c->fblk < c->nf ? r0 + c->fblk : c->nf;
    float *sc, *d_o, *dinp;
    scratch_parts(c, &sc, &d_o, &dinp);
    for (int i = r0; i < r1; i++) {
        float l = p->f_lambda[i], w = pass == 0 ? l : 1.0f - l;
        float *d = d_o + (size_t)i * O;
        const float *vm = c->v_mean + 3 * (size_t)i;
        double dx[3];
        for (int k = 0; k < 3; k++)
            dx[k] = R[k] * vm[0] + R[3 + k] * vm[1] + R[6 + k] * vm[2];
        for (int k = 0; k < 3; k++)
            d[k] = (float)(GS_MODEL_POS_SCALE * w * dx[k]);
        memcpy(d + 3, c->v_feat + (size_t)i * C, C * sizeof(float));
        for (int k = 0; k < 3; k++)
            d[3 + C + k] = GS_MODEL_ATTR_SCALE * w * c->v_scale[3 * i + k];
        /* q_cam = L(qR) q: dq = L(qR)^T dq_cam */
        const float *vq = c->v_quat + 4 * (size_t)i;
        double vqd[4] = {vq[0], vq[1], vq[2], vq[3]}, dq[4];
        quat_lmul_t(qR, vqd, dq);
        for (int k = 0; k < 4; k++)
            d[6 + C + k] = (float)(GS_MODEL_ATTR_SCALE * w * dq[k]);
        d[10 + C] = GS_MODEL_ATTR_SCALE * w * c->v_opac[i];
        if (gp && pass == 0) {
            for (int k = 0; k < 3; k++) {
                gp->f_xyz[3 * i + k] += (float)dx[k];
                gp->f_scale[3 * i + k] += c->v_scale[3 * i + k];
            }
            for (int k = 0; k < 4; k++)
                gp->f_quat[4 * i + k] += (float)dq[k];
            gp->f_opacity[i] += c->v_opac[i];
            float *dc = gp->f_colour + (size_t)i * C;
            for (int k = 0; k < C; k++)
                dc[k] += c->v_feat[(size_t)i * C + k];
        }
    }
    const gs_mlp *mlp = pass == 0 ? &p->face_e : &p->face_p;
    const float *in = pass == 0 ? c->fe_in : c->fp_in;
    const float *act = pass == 0 ? c->fe_act : c->fp_act;
    int dw = mlp->dims[0], n = r1 - r0;
    gs_mlp gb; /* this block's weight gradients, or none */
    memset(&gb, 0, sizeof gb);
    if (j->weights) {
        memset(c->blk_grad + (size_t)b * c->blk_grad_len, 0,
               gs_mlp_param_count(mlp) * sizeof(float));
        block_grads(c, mlp, b, &gb);
    }
    float *din = j->need_din ? dinp + (size_t)r0 * dw : NULL;
    if (din)
        memset(din, 0, (size_t)n * dw * sizeof(float));
    gs_mlp_backward(mlp, &gb, in + (size_t)r0 * dw, n,
                    act + gs_mlp_act_size(mlp, r0), d_o + (size_t)r0 * O, din,
                    sc + gs_mlp_scratch_size(mlp, r0));
    if (!din)
        return;
    float *red = c->blk_red + (size_t)b * (D + GS_PE_DIM(2));
    memset(red, 0, (size_t)(D + GS_PE_DIM(2)) * sizeof(float));
    for (int i = 0; i < n; i++) {
        const float *di = din + (size_t)i * dw;
        if (gp)
            for (int k = 0; k < F; k++)
                gp->f_feat[(size_t)(r0 + i) * F + k] += di[k];
        if (j->code)
            for (int k = 0; k < D; k++)
                red[k] += di[F + k];
        if (j->gz) /* P's input: [f | PE(rvec) | PE(gaze)] */
            for (int k = 0; k < GS_PE_DIM(2); k++)
                red[D + k] += di[F + GS_PE_DIM(3) + k];
    }
}

static void face_backward(gs_model_ctx *c, gs_pool *pool,
                          const gs_model_params *gp, gs_frame_grad *fg,
                          const double qR[4])
{
    const gs_model_params *p = &c->m->p;
    int D = c->D;
    for (int pass = 0; pass < 2; pass++) {
        const gs_mlp *gm = gp ? (pass == 0 ? &gp->face_e : &gp->face_p) : NULL;
        face_bwd_job j = {c, gp, qR, pass, 0, 0, 0, 0};
        j.weights = gm && gm->w[0];
        /* The pose MLP's input gradient matters for the features and, in
         * the single-stream ablation, for the gaze it also sees (rvec(R)
         * is a stop-gradient, docs/model.md). */
        j.code = pass == 0 && fg;
        j.gz = pass == 1 && fg && !c->m->cfg.two_stream;
        j.need_din = gp || j.code || j.gz;
        /* Nothing asked of this pass (the pose MLP in a fit: no parameter
         * gradients, rvec(R) a stop-gradient): its backward would only
         * fill scratch. */
        if (!j.weights && !j.need_din)
            continue;
        gs_pool_for(pool, c->nfblk, face_bwd_task, &j);
        /* the blocks' sums, block by block */
        const gs_mlp *mlp = pass == 0 ? &p->face_e : &p->face_p;
        float dpe[GS_PE_DIM(2)] = {0};
        for (int b = 0; b < c->nfblk; b++) {
            if (j.weights) {
                gs_mlp gb;
                block_grads(c, mlp, b, &gb);
                for (int l = 0; l < mlp->nl; l++) {
                    size_t nw = (size_t)mlp->dims[l] * mlp->dims[l + 1];
                    for (size_t q = 0; q < nw; q++)
                        gm->w[l][q] += gb.w[l][q];
                    for (int q = 0; q < mlp->dims[l + 1]; q++)
                        gm->b[l][q] += gb.b[l][q];
                }
            }
            const float *red = c->blk_red + (size_t)b * (D + GS_PE_DIM(2));
            if (j.code)
                for (int k = 0; k < D; k++)
                    fg->code[k] += red[k];
            if (j.gz)
                for (int k = 0; k < GS_PE_DIM(2); k++)
                    dpe[k] += red[D + k];
        }
        if (j.gz)
            gs_model_pe_backward(c->fr.gaze, 2, dpe, fg->gaze);
    }
}

/* dce[e] (the gradient of eyeball centre e, c_e = c_e,0 + W_e tau) into
 * W_e and tau. */
static void centre_backward(const gs_model_ctx *c, const gs_model_params *gp,
                            gs_frame_grad *fg, const double dce[2][3])
{
    const float *W = c->m->p.eye_centre_w;
    int D = c->D;
    for (int e = 0; e < 2; e++)
        for (int k = 0; k < 3; k++) {
            const float *w = W + (size_t)(3 * e + k) * D;
            if (gp && gp->eye_centre_w) {
                float *dw = gp->eye_centre_w + (size_t)(3 * e + k) * D;
                for (int j = 0; j < D; j++)
                    dw[j] += (float)(dce[e][k] * c->fr.code[j]);
            }
            if (fg)
                for (int j = 0; j < D; j++)
                    fg->code[j] += (float)(dce[e][k] * w[j]);
        }
}

/* The lids' turn backward (after pose_grad, before face_backward): the
 * gradients of the turned Gaussians in v_mean / v_quat are saved to
 * lid_save and replaced by those of the unturned ones, as face_backward
 * reads them (camera frame: R dx, L(qR) dq); the turn's own gradients go
 * to k, the pitch, the eyeball centre's W_e and tau. lid_restore puts the
 * saved ones back. */
static void lid_backward(gs_model_ctx *c, const gs_model_params *gp,
                         gs_frame_grad *fg, const double qR[4])
{
    const gs_model_params *p = &c->m->p;
    const double *R = c->fr.head_R;
    double pitch = lid_pitch_of(c, &c->fr), dce[2][3] = {{0}}, dpitch = 0;
    for (int j = 0; j < c->nl; j++) {
        int i = c->nm + j, e = j < c->nl0 ? 0 : 1;
        float *vm = c->v_mean + 3 * (size_t)i, *vq = c->v_quat + 4 * (size_t)i;
        memcpy(c->lid_save + 7 * (size_t)j, vm, 3 * sizeof(float));
        memcpy(c->lid_save + 7 * (size_t)j + 3, vq, 4 * sizeof(float));
        int i0; /* a = -k pitch, k bilinear in the eye's knots */
        float wk[4];
        float kj = gs_lid_k(p->lid_k, p->lid_uv, e, j, &i0, wk);
        double a = -(double)kj * pitch, ca = cos(a), sa = sin(a);
        /* position: x' = c + Rx(a) (x - c); g = dL/dx' (head frame) */
        double g[3];
        for (int k = 0; k < 3; k++)
            g[k] = R[k] * vm[0] + R[3 + k] * vm[1] + R[6 + k] * vm[2];
        const float *xh = c->x_head + 3 * (size_t)i;
        const double *ce = c->eye_c[e];
        double r[3] = {xh[0] - ce[0], xh[1] - ce[1], xh[2] - ce[2]};
        double dx[3] = {g[0], ca * g[1] + sa * g[2], -sa * g[1] + ca * g[2]};
        for (int k = 0; k < 3; k++)
            dce[e][k] += g[k] - dx[k];
        double da = g[1] * (-sa * r[1] - ca * r[2]) + g[2] * (ca * r[1] - sa * r[2]);
        /* quaternion: q_cam = qR (qx q); dq' = L(qR)^T dq_cam */
        double u[4] = {vq[0], vq[1], vq[2], vq[3]}, w[4], dq[4], vr[4];
        quat_lmul_t(qR, u, w);
        /* qx q with qx = (h0, h1, 0, 0): dq = L(qx)^T w, dqx = Rt(q)^T w */
        double h0 = cos(0.5 * a), h1 = sin(0.5 * a), qx[4] = {h0, h1, 0, 0};
        const float *q = c->q_head + 4 * (size_t)i;
        quat_lmul_t(qx, w, dq);
        /* qx q = (h0 q0 - h1 q1, h0 q1 + h1 q0, h0 q2 - h1 q3, h0 q3 + h1 q2) */
        double dh0 = w[0] * q[0] + w[1] * q[1] + w[2] * q[2] + w[3] * q[3];
        double dh1 = -w[0] * q[1] + w[1] * q[0] - w[2] * q[3] + w[3] * q[2];
        da += 0.5 * (-h1 * dh0 + h0 * dh1);
        /* what face_backward reads: R dx and L(qR) dq */
        for (int k = 0; k < 3; k++)
            vm[k] = (float)(R[3 * k] * dx[0] + R[3 * k + 1] * dx[1] +
                            R[3 * k + 2] * dx[2]);
        quat_mul(qR, dq, vr);
        for (int k = 0; k < 4; k++)
            vq[k] = (float)vr[k];
        if (gp) {
            float dk = (float)(-pitch * da);
            gp->lid_k[i0] += wk[0] * dk, gp->lid_k[i0 + 1] += wk[1] * dk;
            gp->lid_k[i0 + GS_LID_NU] += wk[2] * dk;
            gp->lid_k[i0 + GS_LID_NU + 1] += wk[3] * dk;
        }
        dpitch += -(double)kj * da;
    }
    if (fg && !c->lid_hold)
        fg->gaze[0] += dpitch;
    centre_backward(c, gp, fg, dce);
}

static void lid_restore(gs_model_ctx *c)
{
    for (int j = 0; j < c->nl; j++) {
        size_t i = (size_t)(c->nm + j);
        memcpy(c->v_mean + 3 * i, c->lid_save + 7 * (size_t)j, 3 * sizeof(float));
        memcpy(c->v_quat + 4 * i, c->lid_save + 7 * (size_t)j + 3,
               4 * sizeof(float));
    }
}

static void pose_grad(gs_model_ctx *c, gs_frame_grad *fg)
{
    /* mean = R x + t: dt = sum dmean, dw = sum (R x) x dmean.
     * q_cam = q_w q_cam: dw = 1/2 (-dq_w v + w dq_v + v x dq_v). */
    const double *t = c->fr.head_t;
    for (int i = 0; i < c->n; i++) {
        const float *vm = c->v_mean + 3 * (size_t)i;
        const float *mc = c->g_mean + 3 * (size_t)i;
        double rx[3] = {mc[0] - t[0], mc[1] - t[1], mc[2] - t[2]};
        fg->trans[0] += vm[0];
        fg->trans[1] += vm[1];
        fg->trans[2] += vm[2];
        fg->rot[0] += rx[1] * vm[2] - rx[2] * vm[1];
        fg->rot[1] += rx[2] * vm[0] - rx[0] * vm[2];
        fg->rot[2] += rx[0] * vm[1] - rx[1] * vm[0];
        if (i >= c->nf)
            continue; /* isotropic eye Gaussians: rotation has no effect */
        const float *q = c->g_quat + 4 * (size_t)i;
        const float *dq = c->v_quat + 4 * (size_t)i;
        double w = q[0], v[3] = {q[1], q[2], q[3]};
        double dv[3] = {dq[1], dq[2], dq[3]};
        double cr[3] = {v[1] * dv[2] - v[2] * dv[1],
                        v[2] * dv[0] - v[0] * dv[2],
                        v[0] * dv[1] - v[1] * dv[0]};
        for (int k = 0; k < 3; k++)
            fg->rot[k] += 0.5 * (-dq[0] * v[k] + w * dv[k] + cr[k]);
    }
}

static void rot_pitchyaw_partials(double p, double y, double dp[9],
                                  double dy[9])
{
    /* R = Ry(y) Rx(-p). */
    double ry[9], rx[9];
    gs_geom_rot_y(y, ry);
    gs_geom_rot_x(-p, rx);
    double cy = cos(y), sy = sin(y), cp = cos(-p), sp = sin(-p);
    const double dry[9] = {-sy, 0, cy, 0, 0, 0, -cy, 0, -sy}; /* d Ry / dy */
    const double drx[9] = {0, 0, 0, 0, -sp, -cp, 0, cp, -sp}; /* d Rx(u) / du */
    gs_geom_mat3_mul(dry, rx, dy);
    gs_geom_mat3_mul(ry, drx, dp);
    for (int k = 0; k < 9; k++)
        dp[k] = -dp[k]; /* du/dp = -1 */
}

static void eye_backward(gs_model_ctx *c, const gs_model_params *gp,
                         gs_frame_grad *fg)
{
    const gs_model *m = c->m;
    const gs_model_params *p = &m->p;
    int ne = c->ne, nf = c->nf, C = c->C, O = GS_EYE_OUT(C), F = c->F,
        D = c->D, each = m->cfg.n_eye_each;
    const double *R = c->fr.head_R;
    double dRe[2][9] = {{0}}, dce[2][3] = {{0}};
    float *sc, *d_o, *dinp;
    scratch_parts(c, &sc, &d_o, &dinp);
    for (int i = 0; i < ne; i++) {
        int e = i < each ? 0 : 1, g = nf + i;
        const float *vm = c->v_mean + 3 * (size_t)g;
        double dx[3];
        for (int k = 0; k < 3; k++)
            dx[k] = R[k] * vm[0] + R[3 + k] * vm[1] + R[6 + k] * vm[2];
        double r[3];
        for (int k = 0; k < 3; k++)
            r[k] = p->e_xyz[3 * i + k] - p->eye_centre[3 * e + k];
        const double *Re = c->eye_R[e];
        for (int k = 0; k < 3; k++) {
            dce[e][k] += dx[k];
            for (int j = 0; j < 3; j++)
                dRe[e][3 * k + j] += dx[k] * r[j];
        }
        float *d = d_o + (size_t)i * O;
        for (int k = 0; k < 3; k++)
            d[k] = (float)(GS_MODEL_EYE_POS_SCALE * dx[k]);
        memcpy(d + 3, c->v_feat + (size_t)g * C, C * sizeof(float));
        float ds = c->v_scale[3 * g] + c->v_scale[3 * g + 1] +
                   c->v_scale[3 * g + 2];
        d[3 + C] = GS_MODEL_ATTR_SCALE * ds;
        d[4 + C] = GS_MODEL_ATTR_SCALE * c->v_opac[g];
        if (gp) {
            for (int k = 0; k < 3; k++)
                gp->e_xyz[3 * i + k] += (float)(Re[k] * dx[0] +
                                                Re[3 + k] * dx[1] +
                                                Re[6 + k] * dx[2]);
            gp->e_scale[i] += ds;
            gp->e_opacity[i] += c->v_opac[g];
            float *dc = gp->e_colour + (size_t)i * C;
            for (int k = 0; k < C; k++)
                dc[k] += c->v_feat[(size_t)g * C + k];
        }
    }
    int de = p->eye.dims[0];
    memset(dinp, 0, (size_t)ne * de * sizeof(float));
    gs_mlp nog;
    memset(&nog, 0, sizeof nog);
    gs_mlp_backward(&p->eye, gp ? &gp->eye : &nog, c->e_in, ne, c->e_act, d_o,
                    dinp, sc);
    float dpe[GS_PE_DIM(2)] = {0};
    for (int i = 0; i < ne; i++) {
        const float *di = dinp + (size_t)i * de;
        if (gp)
            for (int k = 0; k < F; k++)
                gp->e_feat[(size_t)i * F + k] += di[k];
        if (fg)
            for (int k = 0; k < D; k++)
                fg->code[k] += di[F + k];
        for (int k = 0; k < GS_PE_DIM(2); k++)
            dpe[k] += di[F + D + k];
    }
    centre_backward(c, gp, fg, dce); /* eyeball centres: c_e + W_e tau */
    /* Rotations: R_e = R_res,e R_g. */
    double dgaze[2] = {0, 0};
    if (m->cfg.eye_rotation) {
        double dp9[9], dy9[9];
        rot_pitchyaw_partials(c->fr.gaze[0], c->fr.gaze[1], dp9, dy9);
        for (int e = 0; e < 2; e++) {
            const double *Rr = c->eye_Rres[e], *Rg = c->eye_Rg;
            double dRg[9] = {0}, dRr[9] = {0};
            for (int i = 0; i < 3; i++)
                for (int j = 0; j < 3; j++)
                    for (int k = 0; k < 3; k++) {
                        dRg[3 * k + j] += Rr[3 * i + k] * dRe[e][3 * i + j];
                        dRr[3 * i + k] += dRe[e][3 * i + j] * Rg[3 * k + j];
                    }
            for (int k = 0; k < 9; k++) {
                dgaze[0] += dRg[k] * dp9[k];
                dgaze[1] += dRg[k] * dy9[k];
            }
            /* Through normalize(q) and quat_to_mat. */
            const double *q = c->eye_q[e];
            double nq = sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] +
                             q[3] * q[3]);
            double qn[4] = {q[0] / nq, q[1] / nq, q[2] / nq, q[3] / nq};
            double dqn[4], dot = 0;
            quat_to_mat_backward(qn, dRr, dqn);
            for (int k = 0; k < 4; k++)
                dot += dqn[k] * qn[k];
            float dout4[4];
            for (int k = 0; k < 4; k++)
                dout4[k] = (float)((dqn[k] - dot * qn[k]) / nq);
            float din[GS_PE_DIM(2)] = {0};
            float rsc[2 * 32 + 2 * GS_PE_DIM(2)];
            gs_mlp_backward(&p->eye_rot[e], gp ? &gp->eye_rot[e] : &nog,
                            c->er_in, 1, c->er_act[e], dout4, din, rsc);
            for (int k = 0; k < GS_PE_DIM(2); k++)
                dpe[k] += din[k];
        }
    }
    if (fg) {
        gs_model_pe_backward(c->fr.gaze, 2, dpe, dgaze);
        fg->gaze[0] += dgaze[0];
        fg->gaze[1] += dgaze[1];
    }
}

void gs_frame_clear_gaussian_grads(gs_model_ctx *c)
{
    size_t n = (size_t)c->n;
    memset(c->v_mean, 0, n * 3 * sizeof(float));
    memset(c->v_scale, 0, n * 3 * sizeof(float));
    memset(c->v_quat, 0, n * 4 * sizeof(float));
    memset(c->v_opac, 0, n * sizeof(float));
    memset(c->v_feat, 0, n * (size_t)c->C * sizeof(float));
}

void gs_frame_mirror(const gs_frame *fr, int code_dim, gs_frame *out)
{
    static const double sg[3] = {-1, 1, 1};
    gs_frame m = *fr;
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++)
            m.head_R[3 * i + j] = sg[i] * fr->head_R[3 * i + j] * sg[j];
    m.head_t[0] = -fr->head_t[0];
    m.gaze[1] = -fr->gaze[1];
    gs_frame_mirror_code(m.code, code_dim);
    *out = m;
}

void gs_frame_mirror_code(float *code, int code_dim)
{
    float *l = code + code_dim - GS_MODEL_LIGHT_DIM;
    for (int k = 0; k < 3; k++) /* the three light directions' x */
        l[3 * k] = -l[3 * k];
}


/* dst = src with every channel's pixels outside the mask zeroed. */
static void mask_map(const float *src, const float *mask, int C, size_t plane,
                     float *dst)
{
    for (int k = 0; k < C; k++)
        for (size_t i = 0; i < plane; i++)
            dst[k * plane + i] = src[k * plane + i] * mask[i];
}

/* gs_raster_backward of a map rasterized by gs_frame_forward, given the
 * gradient v [C, fs, fs] of the map the renderer saw: at k fs (a
 * supersampled model) each of a pixel's k x k samples takes v / k^2. */
static int raster_back(gs_model_ctx *c, gs_raster *r, gs_pool *pool,
                       const float *v, gs_gaussian_grads *gg, gs_error *err)
{
    int k = c->ss, fs = c->fs, fsr = k * fs;
    if (k == 1)
        return gs_raster_backward(r, pool, v, NULL, NULL, gg, NULL, err);
    size_t plane = (size_t)fsr * fsr;
    if ((size_t)c->C * plane > c->ss_cap) /* a forward at fsr made it */
        return gs_error_set(err, GS_ERR_STATE, "model: backward before forward");
    float inv = 1.0f / (float)(k * k), *hi = c->ss_buf;
    for (int ch = 0; ch < c->C; ch++)
        for (int y = 0; y < fsr; y++) {
            const float *src = v + ((size_t)ch * fs + y / k) * fs;
            float *dst = hi + ch * plane + (size_t)y * fsr;
            for (int x = 0; x < fsr; x++)
                dst[x] = src[x / k] * inv;
        }
    return gs_raster_backward(r, pool, hi, NULL, NULL, gg, NULL, err);
}

/* The renderer's weight gradients a backward is asked for: none for a fit
 * (grads NULL) or for a fine-tune that leaves the renderer as it is (its
 * part of grads unbound, as finetune.c does). The renderer's
 * input gradients are the same bits either way. */
static const gs_renderer_params *rend_grads(const gs_model_params *grads)
{
    return grads && grads->rend.rgb0.w ? &grads->rend : NULL;
}

/* Long on purpose (a hot path): the backward of one forward, running the
 * renderer, the rasterizer and the streams in the reverse of the forward
 * order over the state that forward saved; split, the steps would pass
 * that state around whole. */
int gs_frame_backward(gs_model_ctx *c, gs_pool *pool, const float *d_rgb,
                      const float *d_fmap, const float *d_fmap_face,
                      const float *d_fmap_eye, const gs_model_params *grads,
                      gs_frame_grad *fg, gs_error *err)
{
    size_t fsz = (size_t)c->fs * c->fs * c->C;
    if (!c->train_ready)
        return gs_error_set(err, GS_ERR_STATE,
                            "model: a backward needs a training forward first");
    if (c->feat_mask && d_fmap_eye)
        return gs_error_set(err, GS_ERR_ARG,
                            "model: a feature mask with the eye-only map");
    if (grads) /* parameter gradients: training, the parameters change */
        gs_sweep_drop(c);
    if (d_fmap)
        memcpy(c->v_fmap, d_fmap, fsz * sizeof(float));
    else
        memset(c->v_fmap, 0, fsz * sizeof(float));
    if (c->used_face_map && d_fmap_face)
        memcpy(c->v_fmap_face, d_fmap_face, fsz * sizeof(float));
    else
        memset(c->v_fmap_face, 0, fsz * sizeof(float));
    const int *box = c->dir_box;
    int direct = d_rgb && c->dir_valid,
        crop = direct && box[0] < box[2] && box[1] < box[3];
    if (direct) { /* rgb = rgb_main (1 - beta) + E over the crop */
        int S = c->S, w = box[2] - box[0], h = box[3] - box[1];
        size_t plane = (size_t)S * S, cp = crop ? (size_t)w * h : 0;
        memcpy(c->dir_dmain, d_rgb, 3 * plane * sizeof(float));
        const float *beta = c->dir_out + 3 * cp;
        float *db = c->dir_d + 3 * cp;
        memset(db, 0, cp * sizeof(float));
        for (int k = 0; crop && k < 3; k++)
            for (int y = 0; y < h; y++) {
                size_t at = k * plane + (size_t)(box[1] + y) * S + box[0];
                const float *dr = d_rgb + at, *mn = c->rgb_main + at;
                const float *b = beta + (size_t)y * w;
                float *dm = c->dir_dmain + at;
                float *de = c->dir_d + k * cp + (size_t)y * w;
                float *dbr = db + (size_t)y * w;
                for (int x = 0; x < w; x++) {
                    de[x] = dr[x];
                    dm[x] = dr[x] * (1.0f - b[x]);
                    dbr[x] -= dr[x] * mn[x];
                }
            }
    }
    if (d_rgb) {
        int rc = gs_renderer_backward_src(
            &c->m->rcfg, &c->m->p.rend, c->r_act, c->r_act_len, c->fmap,
            c->fr.code, c->used_src ? c->fmap_face : NULL,
            direct ? c->dir_dmain : d_rgb, c->fs, c->fs,
            rend_grads(grads), c->v_fmap,
            c->used_src ? c->v_fmap_face : NULL, fg ? fg->code : NULL, pool);
        if (rc)
            return gs_error_set(err, rc, "model: renderer backward failed");
    }
    int first = c->stream == GS_STREAM_EYE ? c->nf : 0;
    gs_gaussian_grads gg = {c->v_mean + 3 * (size_t)first,
                            c->v_scale + 3 * (size_t)first,
                            c->v_quat + 4 * (size_t)first, c->v_opac + first,
                            c->v_feat + (size_t)first * c->C};
    int rc;
    if (c->feat_mask) { /* the features' gradient from the masked maps */
        size_t plane = (size_t)c->fs * c->fs;
        gs_frame_clear_gaussian_grads(c);
        mask_map(c->v_fmap, c->feat_mask, c->C, plane, c->v_fmap_m);
        rc = raster_back(c, c->raster, pool, c->v_fmap_m, &gg, err);
        if (!rc && c->used_face_map) {
            gs_gaussian_grads gf = {c->v_mean, c->v_scale, c->v_quat,
                                    c->v_opac, c->v_feat};
            mask_map(c->v_fmap_face, c->feat_mask, c->C, plane,
                     c->v_fmap_face_m);
            rc = raster_back(c, c->raster_face, pool, c->v_fmap_face_m, &gf,
                             err);
        }
        if (rc)
            return rc;
        memcpy(c->v_feat_keep, c->v_feat,
               (size_t)c->n * c->C * sizeof(float));
    }
    gs_frame_clear_gaussian_grads(c);
    rc = raster_back(c, c->raster, pool, c->v_fmap, &gg, err);
    if (rc)
        return rc;
    if (c->used_face_map) { /* the face-only map adds to the face stream */
        gs_gaussian_grads gf = {c->v_mean, c->v_scale, c->v_quat, c->v_opac,
                                c->v_feat};
        rc = raster_back(c, c->raster_face, pool, c->v_fmap_face, &gf, err);
        if (rc)
            return rc;
    }
    if (c->cover_grad && c->cover_valid) { /* the eye stream's coverage */
        gs_gaussian_grads gc = {c->v_mean, c->v_scale, c->v_quat, c->v_opac,
                                c->v_ind};
        rc = gs_raster_backward(c->raster_cov, pool, c->cover_grad, NULL,
                                NULL, &gc, NULL, err);
        if (rc)
            return rc;
    }
    if (c->used_eye_map && d_fmap_eye) { /* the eye-only map: eye stream */
        size_t e = (size_t)c->nf;
        gs_gaussian_grads ge = {c->v_mean + 3 * e, c->v_scale + 3 * e,
                                c->v_quat + 4 * e, c->v_opac + e,
                                c->v_feat + e * c->C};
        rc = raster_back(c, c->raster_eye, pool, d_fmap_eye, &ge, err);
        if (rc)
            return rc;
    }
    if (c->feat_mask)
        memcpy(c->v_feat, c->v_feat_keep, (size_t)c->n * c->C * sizeof(float));
    if (crop) { /* the eye stream at the image's size: every Gaussian's
                     geometry, the eye stream's colours (not masked by a
                     feature mask: the eyes are far from the outline it
                     is for) */
        memset(c->dir_vfeat, 0, 4 * (size_t)c->n * sizeof(float));
        gs_gaussian_grads gd = {c->v_mean, c->v_scale, c->v_quat, c->v_opac,
                                c->dir_vfeat};
        rc = gs_raster_backward(c->raster_dir, pool, c->dir_d, NULL, NULL,
                                &gd, NULL, err);
        if (rc)
            return rc;
        for (size_t i = (size_t)c->nf; i < (size_t)c->n; i++)
            for (int k = 0; k < 3; k++)
                c->v_feat[i * (size_t)c->C + k] += c->dir_vfeat[4 * i + k];
    }
    gs_frame_backward_streams(c, pool, grads, fg);
    return GS_OK;
}

void gs_frame_backward_streams(gs_model_ctx *c, gs_pool *pool,
                               const gs_model_params *grads, gs_frame_grad *fg)
{
    double qR[4];
    mat_to_quat(c->fr.head_R, qR);
    if (fg)
        pose_grad(c, fg);
    if (c->stream != GS_STREAM_EYE) {
        lid_backward(c, grads, fg, qR);
        face_backward(c, pool, grads, fg, qR);
        lid_restore(c);
    }
    if (c->ne && c->stream != GS_STREAM_FACE)
        eye_backward(c, grads, fg);
}
