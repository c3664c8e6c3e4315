/* Subjects (encoding, decoding) and the argument checks of the model's
 * public calls. */
#define _POSIX_C_SOURCE 200809L
#include <float.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "gazesplat/clock.h"
#include "frame.h"
#include "fit_internal.h"
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

int gs_model_check_pose(const double R[9], const double t[3], gs_error *err)
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

int gs_model_check_gaze(double pitch, double yaw, gs_error *err)
{
    const double slack = GS_MODEL_RANGE_SLACK_DEG;
    int rc = gs_model_check_range_slack(GS_TARGET_GAZE_PITCH,
                                        pitch / GS_MODEL_DEG_TO_RAD, slack, err);
    if (!rc)
        rc = gs_model_check_range_slack(GS_TARGET_GAZE_YAW,
                                        yaw / GS_MODEL_DEG_TO_RAD, slack, err);
    return rc;
}

int gs_model_check_subject(const gs_model *m, const gs_subject *s,
                         gs_error *err)
{
    if (s->code_dim != gs_model_code_dim(&m->cfg))
        return gs_error_set(err, GS_ERR_ARG,
                            "subject code_dim %d, model has %d", s->code_dim,
                            gs_model_code_dim(&m->cfg));
    if (!all_finite_f(s->code, s->code_dim) ||
        !all_finite_f(s->colour_gain, 3) || !all_finite_f(s->colour_bias, 3))
        return gs_error_set(err, GS_ERR_NONFINITE, "subject not finite");
    return gs_model_check_pose(s->head_R, s->head_t, err);
}
