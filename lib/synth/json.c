/* Labels as one line of JSON. Angles in radians (*_rad), points in
 * millimetres (*_mm) or pixels (*_px); NaN (a point behind the camera)
 * is written as null. */
#include <stdarg.h>
#include <stdio.h>
#include <string.h>

#include "synth_internal.h"

typedef struct jbuf {
    char *buf;
    size_t cap, len;
} jbuf;

static void put(jbuf *j, const char *fmt, ...) __attribute__((format(printf, 2, 3)));
static void put(jbuf *j, const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    size_t room = j->len < j->cap ? j->cap - j->len : 0;
    int n = vsnprintf(room ? j->buf + j->len : NULL, room, fmt, ap);
    va_end(ap);
    if (n > 0)
        j->len += (size_t)n;
}

static void num(jbuf *j, double v)
{
    if (isfinite(v))
        put(j, "%.10g", v);
    else
        put(j, "null");
}

static void arr(jbuf *j, const char *key, const double *v, int n)
{
    put(j, ",\"%s\":[", key);
    for (int i = 0; i < n; i++) {
        if (i)
            put(j, ",");
        num(j, v[i]);
    }
    put(j, "]");
}

/* Array of n rows of m numbers. */
static void arr2(jbuf *j, const char *key, const double *v, int n, int m)
{
    put(j, ",\"%s\":[", key);
    for (int i = 0; i < n; i++) {
        put(j, i ? ",[" : "[");
        for (int k = 0; k < m; k++) {
            if (k)
                put(j, ",");
            num(j, v[i * m + k]);
        }
        put(j, "]");
    }
    put(j, "]");
}

static void scalar(jbuf *j, const char *key, double v)
{
    put(j, ",\"%s\":", key);
    num(j, v);
}

/* JSON string body of s (file names: escape quotes, backslashes, controls). */
static void str(jbuf *j, const char *s)
{
    put(j, "\"");
    for (; *s; s++) {
        unsigned char c = (unsigned char)*s;
        if (c == '"' || c == '\\')
            put(j, "\\%c", c);
        else if (c < 0x20)
            put(j, "\\u%04x", c);
        else
            put(j, "%c", c);
    }
    put(j, "\"");
}

int gs_synth_labels_json(const gs_synth_labels *l, const char *image,
                         char *buf, size_t cap)
{
    static const char *const splits[3] = {"train", "val", "test"};
    jbuf j = {buf, cap, 0};
    if (cap)
        buf[0] = '\0';
    put(&j, "{\"image\":");
    str(&j, image ? image : "");
    put(&j, ",\"width\":%d,\"height\":%d", l->width, l->height);
    int split = gs_synth_seed_split(l->identity.seed);
    put(&j, ",\"identity_seed\":%llu,\"split\":\"%s\"",
        (unsigned long long)l->identity.seed, split >= 0 ? splits[split] : "none");
    arr(&j, "K", l->K, 9);
    arr(&j, "cam_R", l->cam_R, 9);
    arr(&j, "cam_t_mm", l->cam_t, 3);
    arr(&j, "head_R", l->head_R, 9);
    arr(&j, "head_t_mm", l->head_t, 3);
    arr(&j, "head_rvec", l->head_rvec, 3);
    scalar(&j, "head_pitch_rad", l->head_pitch);
    scalar(&j, "head_yaw_rad", l->head_yaw);
    scalar(&j, "head_roll_rad", l->head_roll);
    arr(&j, "gaze_head", l->gaze_head, 3);
    scalar(&j, "gaze_head_pitch_rad", l->gaze_head_pitch);
    scalar(&j, "gaze_head_yaw_rad", l->gaze_head_yaw);
    arr(&j, "gaze_cam", l->gaze_cam, 3);
    scalar(&j, "gaze_cam_pitch_rad", l->gaze_cam_pitch);
    scalar(&j, "gaze_cam_yaw_rad", l->gaze_cam_yaw);
    scalar(&j, "gaze_norm_pitch_rad", l->gaze_norm_pitch);
    scalar(&j, "gaze_norm_yaw_rad", l->gaze_norm_yaw);
    if (l->has_kappa) {
        /* Only with kappa on, so that datasets without it keep their bytes. */
        put(&j, ",\"gaze_axis\":\"visual\"");
        scalar(&j, "kappa_h_rad", l->kappa_h);
        scalar(&j, "kappa_v_rad", l->kappa_v);
        arr2(&j, "gaze_optical_head", &l->optical_head[0][0], 2, 3);
        arr(&j, "gaze_optical_head_pitch_rad", l->optical_head_pitch, 2);
        arr(&j, "gaze_optical_head_yaw_rad", l->optical_head_yaw, 2);
        arr2(&j, "gaze_optical_cam", &l->optical_cam[0][0], 2, 3);
        arr(&j, "gaze_optical_cam_pitch_rad", l->optical_cam_pitch, 2);
        arr(&j, "gaze_optical_cam_yaw_rad", l->optical_cam_yaw, 2);
        arr(&j, "gaze_optical_norm_pitch_rad", l->optical_norm_pitch, 2);
        arr(&j, "gaze_optical_norm_yaw_rad", l->optical_norm_yaw, 2);
    }
    scalar(&j, "head_norm_pitch_rad", l->head_norm_pitch);
    scalar(&j, "head_norm_yaw_rad", l->head_norm_yaw);
    arr(&j, "norm_R", l->norm.R, 9);
    arr(&j, "norm_W", l->norm.W, 9);
    arr(&j, "norm_K", l->norm.K_n, 9);
    scalar(&j, "norm_distance_mm", l->norm.d_n_mm);
    scalar(&j, "face_distance_mm", l->norm.distance_mm);
    arr(&j, "face_centre_mm", l->face_centre, 3);
    arr(&j, "face_centre_px", l->face_centre_uv, 2);
    arr2(&j, "eye_centre_mm", &l->eye_centre[0][0], 2, 3);
    arr2(&j, "eye_centre_px", &l->eye_centre_uv[0][0], 2, 2);
    arr2(&j, "pupil_centre_mm", &l->pupil_centre[0][0], 2, 3);
    arr2(&j, "pupil_centre_px", &l->pupil_uv[0][0], 2, 2);
    scalar(&j, "pupil_radius_mm", l->pupil_radius_mm);
    scalar(&j, "iris_radius_mm", l->iris_radius_mm);
    scalar(&j, "eyeball_radius_mm", l->eyeball_radius_mm);
    arr2(&j, "landmarks_px", &l->lm2d[0][0], GS_SYNTH_LANDMARKS, 2);
    arr2(&j, "landmarks_mm", &l->lm3d[0][0], GS_SYNTH_LANDMARKS, 3);
    arr2(&j, "landmarks_head_mm", &l->lm3d_head[0][0], GS_SYNTH_LANDMARKS, 3);
    put(&j, ",\"identity\":{");
    for (int i = 0; i < GS_SYNTH_ID_COUNT; i++) {
        put(&j, "%s\"%s\":", i ? "," : "", gs_synth_identity_name(i));
        num(&j, l->identity.p[i]);
    }
    put(&j, "},\"expression\":{");
    float ex[GS_SYNTH_EXPR_COUNT];
    gs_synth_expression_to_array(&l->expr, ex);
    for (int i = 0; i < GS_SYNTH_EXPR_COUNT; i++) {
        put(&j, "%s\"%s\":", i ? "," : "", gs_synth_expression_name(i));
        num(&j, ex[i]);
    }
    put(&j, "}}");
    if (j.len > 0x7fffffff)
        return GS_ERR_LIMIT;
    return (int)j.len;
}
