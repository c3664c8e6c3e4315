/* Head pose and the whole analysis: photo -> box -> 68 landmarks -> pose
 * -> normalization. */
#include <math.h>
#include <string.h>

#include "cv_face_shim.h"
#include "face_internal.h"

#define MAX_DETECTIONS 64

/* iBUG indices of the model points, in geom's model order: the 6 of
 * both models, then the 7 nose points of the synthetic head's. */
static const int model_ibug[13] = {36, 39, 42, 45, 31, 35, 27, 28, 29, 30, 32, 33, 34};

void gs_face_default_intrinsics(int width, int height, double k[9])
{
    double f = width > height ? width : height;
    const double kk[9] = {f, 0, width * 0.5, 0, f, height * 0.5, 0, 0, 1};
    memcpy(k, kk, sizeof kk);
}

static int check_k(const double k[9], gs_error *err)
{
    for (int i = 0; i < 9; i++)
        if (!isfinite(k[i]))
            return gs_error_set(err, GS_ERR_NONFINITE, "head pose: non-finite intrinsics");
    if (!(k[0] > 0 && k[4] > 0) || k[1] != 0 || k[3] != 0 || k[6] != 0 || k[7] != 0 ||
        k[8] != 1)
        return gs_error_set(err, GS_ERR_ARG,
                            "head pose: intrinsics must be [[fx,0,cx],[0,fy,cy],[0,0,1]], f > 0");
    return GS_OK;
}

int gs_face_model6(gs_face_pose_model model, double out[6][3])
{
    if (model == GS_FACE_POSE_GENERIC)
        gs_geom_face_model6(out);
    else if (model == GS_FACE_POSE_SYNTH)
        gs_geom_face_model6_synth(out);
    else
        return GS_ERR_ARG;
    return GS_OK;
}

int gs_face_head_pose(const double uv[][2], const double k[9], gs_face_pose *out, gs_error *err)
{
    return gs_face_head_pose_model(uv, k, GS_FACE_POSE_GENERIC, out, err);
}

int gs_face_head_pose_model(const double uv[][2], const double k[9], gs_face_pose_model which,
                            gs_face_pose *out, gs_error *err)
{
    if (!uv || !k || !out)
        return gs_error_set(err, GS_ERR_ARG, "head pose: NULL argument");
    int rc = check_k(k, err);
    if (rc)
        return rc;
    /* The model centred on its face centre (of the six points), so that t
     * is the face centre. SYNTH solves from 13 points: on the exact
     * landmarks of synthetic test heads the six alone give a rotation
     * error of 4.8 deg on average (p90 9.9, max 25: the six are nearly
     * coplanar, so the tilt is ill-conditioned and EPnP can start in the
     * mirrored minimum), the 13 2.1 deg (p90 3.9, max 6.4;
     * bench_pose_points). */
    double model[13][3], centre[3], img[13][2];
    if (gs_face_model6(which, model) != GS_OK)
        return gs_error_set(err, GS_ERR_ARG, "head pose: unknown face model %d", (int)which);
    int n = 6;
    if (which == GS_FACE_POSE_SYNTH) {
        double nose[7][3];
        gs_geom_face_nose7_synth(nose);
        memcpy(model[6], nose, sizeof nose);
        n = 13;
    }
    gs_geom_face_centre6((const double(*)[3])model, centre);
    for (int i = 0; i < n; i++) {
        for (int j = 0; j < 3; j++)
            model[i][j] -= centre[j];
        img[i][0] = uv[model_ibug[i]][0];
        img[i][1] = uv[model_ibug[i]][1];
        if (!isfinite(img[i][0]) || !isfinite(img[i][1]))
            return gs_error_set(err, GS_ERR_NONFINITE, "head pose: non-finite landmark");
    }
    gs_face_pose p = {{0}, {0}, {0}, 0, 0, 0};
    rc = gs_cvf_solve_pnp((const double(*)[3])model, (const double(*)[2])img, n, k, p.rvec, p.t,
                          err);
    if (rc)
        return rc;
    if (!(p.t[2] > 0) || !isfinite(p.t[0]) || !isfinite(p.t[1]))
        return gs_error_set(err, GS_ERR_ARG, "head pose: no solution in front of the camera");
    gs_geom_rodrigues(p.rvec, p.R);
    gs_geom_head_pitchyaw(p.R, &p.pitch, &p.yaw);
    double ss = 0;
    for (int i = 0; i < n; i++) {
        double x[3], q[2];
        gs_geom_mat3_vec(p.R, model[i], x);
        for (int j = 0; j < 3; j++)
            x[j] += p.t[j];
        if (gs_geom_project(k, x, q) != GS_OK)
            return gs_error_set(err, GS_ERR_ARG, "head pose: a model point behind the camera");
        ss += (q[0] - img[i][0]) * (q[0] - img[i][0]) + (q[1] - img[i][1]) * (q[1] - img[i][1]);
    }
    p.rms_px = sqrt(ss / n);
    *out = p;
    return GS_OK;
}

void gs_face_opts_default(gs_face_opts *o)
{
    memset(o, 0, sizeof *o);
    o->pose_model = GS_FACE_POSE_GENERIC;
    o->norm_size = 512;
    o->norm_distance_mm = GS_GEOM_NORM_DISTANCE_MM;
    o->norm_focal = 0; /* gs_geom_norm_focal(norm_size) */
    gs_face_detect_opts_default(&o->detect);
}

/* The box to use: the caller's, or detection `index` (largest first). */
static int pick_box(gs_face_detector *det, const gs_io_image *img, const gs_face_opts *o,
                    gs_face_result *res, gs_error *err)
{
    if (o->use_box) {
        res->box = o->box;
        return GS_OK;
    }
    if (!det)
        return gs_error_set(err, GS_ERR_ARG, "face: no detector and no box");
    gs_face_detection d[MAX_DETECTIONS];
    int n = 0;
    int rc = gs_face_detect(det, img, &o->detect, d, MAX_DETECTIONS, &n, err);
    if (rc)
        return rc;
    res->n_faces = n;
    if (n == 0)
        return gs_error_set(err, GS_ERR_ARG, "face: no face found in the %dx%d image",
                            img->width, img->height);
    if (o->index < 0 || o->index >= n || o->index >= MAX_DETECTIONS)
        return gs_error_set(err, GS_ERR_ARG, "face: index %d but %d face%s found", o->index, n,
                            n == 1 ? "" : "s");
    res->box = d[o->index].box;
    return GS_OK;
}

static int landmarks(const gs_face_shape_model *sp, const gs_io_image *img,
                     gs_face_result *res, gs_error *err)
{
    int w = res->box.right - res->box.left + 1;
    if (w < GS_FACE_MIN_BOX || res->box.bottom - res->box.top + 1 < GS_FACE_MIN_BOX)
        return gs_error_set(err, GS_ERR_ARG, "face: face too small (%d px box, need %d)", w,
                            GS_FACE_MIN_BOX);
    if (gs_face_shape_model_parts(sp) != GS_FACE_LANDMARKS)
        return gs_error_set(err, GS_ERR_ARG, "face: the shape model has %d parts, not 68",
                            gs_face_shape_model_parts(sp));
    int rc = gs_face_shape_predict(sp, img, res->box, &res->pts[0][0], &res->uv[0][0], err);
    if (rc)
        return rc;
    for (int i = 0; i < GS_FACE_LANDMARKS; i++) {
        const double *p = res->uv[i];
        if (!(p[0] >= 0 && p[1] >= 0 && p[0] <= img->width && p[1] <= img->height))
            return gs_error_set(err, GS_ERR_ARG,
                                "face: landmark %d at (%.1f, %.1f) outside the %dx%d image", i,
                                p[0], p[1], img->width, img->height);
    }
    return GS_OK;
}

static int normalize(const gs_face_opts *o, gs_face_result *res, gs_error *err)
{
    int size = o->norm_size;
    if (size < 16 || size > 4096)
        return gs_error_set(err, GS_ERR_ARG, "face: normalized size %d outside 16..4096", size);
    double f_n = o->norm_focal > 0 ? o->norm_focal : gs_geom_norm_focal(size);
    double d_n = o->norm_distance_mm > 0 ? o->norm_distance_mm : GS_GEOM_NORM_DISTANCE_MM;
    int rc = gs_geom_normalize(res->k, res->pose.t, res->pose.R, d_n, f_n, size, size,
                               &res->norm, err);
    if (rc)
        return rc;
    for (int i = 0; i < GS_FACE_LANDMARKS; i++)
        gs_geom_norm_pixel(&res->norm, res->uv[i], res->uv_n[i]);
    double r_n[9];
    gs_geom_norm_rot(&res->norm, res->pose.R, r_n);
    gs_geom_head_pitchyaw(r_n, &res->head_pitch_n, &res->head_yaw_n);
    return GS_OK;
}

/* Landmarks -> head pose -> normalization. */
static int pose_and_normalize(const gs_face_opts *o, gs_face_result *res, gs_error *err)
{
    int rc = gs_face_head_pose_model((const double(*)[2])res->uv, res->k, o->pose_model,
                                     &res->pose, err);
    return rc ? rc : normalize(o, res, err);
}

int gs_face_analyze(gs_face_detector *det, const gs_face_shape_model *sp, const gs_io_image *img,
                    const gs_face_opts *opts, gs_face_result *out, gs_error *err)
{
    gs_face_opts def;
    if (!opts) {
        gs_face_opts_default(&def);
        opts = &def;
    }
    if (!sp || !img || !img->data || img->width < 1 || img->height < 1 || !out)
        return gs_error_set(err, GS_ERR_ARG, "face: no model or empty image");
    gs_face_result res;
    memset(&res, 0, sizeof res);
    res.image_width = img->width;
    res.image_height = img->height;
    if (opts->use_k)
        memcpy(res.k, opts->k, sizeof res.k);
    else
        gs_face_default_intrinsics(img->width, img->height, res.k);
    int rc = pick_box(det, img, opts, &res, err);
    if (!rc)
        rc = landmarks(sp, img, &res, err);
    if (!rc)
        rc = pose_and_normalize(opts, &res, err);
    if (rc)
        return rc;
    *out = res;
    return GS_OK;
}

int gs_face_analyze_landmarks(const double uv[][2], int width, int height,
                              const gs_face_opts *opts, gs_face_result *out, gs_error *err)
{
    gs_face_opts def;
    if (!opts) {
        gs_face_opts_default(&def);
        opts = &def;
    }
    if (!uv || !out || width < 1 || height < 1)
        return gs_error_set(err, GS_ERR_ARG, "face: no landmarks or an empty image");
    gs_face_result res;
    memset(&res, 0, sizeof res);
    res.image_width = width;
    res.image_height = height;
    if (opts->use_k)
        memcpy(res.k, opts->k, sizeof res.k);
    else
        gs_face_default_intrinsics(width, height, res.k);
    double lo[2] = {INFINITY, INFINITY}, hi[2] = {-INFINITY, -INFINITY};
    for (int i = 0; i < GS_FACE_LANDMARKS; i++) {
        const double *p = uv[i];
        if (!isfinite(p[0]) || !isfinite(p[1]))
            return gs_error_set(err, GS_ERR_NONFINITE, "face: landmark %d is not finite", i);
        if (!(p[0] >= 0 && p[1] >= 0 && p[0] <= width && p[1] <= height))
            return gs_error_set(err, GS_ERR_ARG,
                                "face: landmark %d at (%.1f, %.1f) outside the %dx%d image", i,
                                p[0], p[1], width, height);
        res.uv[i][0] = p[0];
        res.uv[i][1] = p[1];
        /* dlib's integer points: pixel centres at integers */
        res.pts[i][0] = (int)floor(p[0]);
        res.pts[i][1] = (int)floor(p[1]);
        for (int c = 0; c < 2; c++) {
            lo[c] = fmin(lo[c], p[c]);
            hi[c] = fmax(hi[c], p[c]);
        }
    }
    res.box = (gs_face_box){(int)floor(lo[0]), (int)floor(lo[1]), (int)floor(hi[0]),
                            (int)floor(hi[1])};
    int rc = pose_and_normalize(opts, &res, err);
    if (rc)
        return rc;
    *out = res;
    return GS_OK;
}
