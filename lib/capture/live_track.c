/* Face tracking for the live stage: landmarks seeded from the previous
 * frame, the detector only to acquire a face, and a cheap confirming
 * detection on a crop every few frames (the landmark model has no
 * confidence: on a background it still returns a face-shaped set of
 * points, so "is it still a face" needs the detector). */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "gazesplat/live.h"

struct gs_live_track {
    gs_live_track_config cfg;
    gs_live_track_ops ops;
    int tracking;
    uint64_t track_id;
    int since_verify;
    double prev_uv[GS_FACE_LANDMARKS][2];
    /* The detector box relative to its landmarks' bounding box (centre
     * offset and side, in units of the landmarks' side), measured at the
     * last detection so seeded boxes keep the detector's framing. */
    double rel_dx, rel_dy, rel_scale;
};

gs_live_track_config gs_live_track_config_default(void)
{
    gs_live_track_config c = {15, 0.5, GS_FACE_MIN_BOX};
    return c;
}

int gs_live_track_create(const gs_live_track_config *cfg, const gs_live_track_ops *ops,
                         gs_live_track **out, gs_error *err)
{
    if (!ops || !ops->detect || !ops->landmarks || !out)
        return gs_error_set(err, GS_ERR_ARG, "track: ops needed");
    gs_live_track_config c = cfg ? *cfg : gs_live_track_config_default();
    if (c.verify_every < 0 || !(c.max_jump > 0 && c.max_jump <= 10) || c.min_box < 8)
        return gs_error_set(err, GS_ERR_ARG, "track: bad configuration");
    gs_live_track *t = calloc(1, sizeof *t);
    if (!t)
        return gs_error_set(err, GS_ERR_NOMEM, "track: out of memory");
    t->cfg = c;
    t->ops = *ops;
    t->rel_scale = 1.0;
    *out = t;
    return GS_OK;
}

void gs_live_track_destroy(gs_live_track *t)
{
    free(t);
}

/* Bounding box of the landmarks: centre and side (the larger extent). */
static void lm_bounds(const double uv[][2], double *cx, double *cy, double *side)
{
    double x0 = uv[0][0], x1 = x0, y0 = uv[0][1], y1 = y0;
    for (int i = 1; i < GS_FACE_LANDMARKS; i++) {
        x0 = fmin(x0, uv[i][0]);
        x1 = fmax(x1, uv[i][0]);
        y0 = fmin(y0, uv[i][1]);
        y1 = fmax(y1, uv[i][1]);
    }
    *cx = 0.5 * (x0 + x1);
    *cy = 0.5 * (y0 + y1);
    *side = fmax(fmax(x1 - x0, y1 - y0), 1.0);
}

static void learn_box(gs_live_track *t, gs_face_box b, const double uv[][2])
{
    double cx, cy, side;
    lm_bounds(uv, &cx, &cy, &side);
    /* dlib boxes: inclusive integer corners, centres at integers; landmarks
     * are geom.h pixels (+0.5). */
    double bcx = 0.5 * (b.left + b.right) + 0.5, bcy = 0.5 * (b.top + b.bottom) + 0.5;
    t->rel_dx = (bcx - cx) / side;
    t->rel_dy = (bcy - cy) / side;
    t->rel_scale = (double)(b.right - b.left + 1) / side;
}

gs_face_box gs_live_track_seed_box(const gs_live_track *t, const double uv[][2])
{
    double cx, cy, side;
    lm_bounds(uv, &cx, &cy, &side);
    double w = t->rel_scale * side;
    double bcx = cx + t->rel_dx * side - 0.5, bcy = cy + t->rel_dy * side - 0.5;
    gs_face_box b;
    b.left = (int)lround(bcx - 0.5 * (w - 1));
    b.top = (int)lround(bcy - 0.5 * (w - 1));
    b.right = b.left + (int)lround(w) - 1;
    b.bottom = b.top + (int)lround(w) - 1;
    return b;
}

/* Lost when the landmarks jumped or shrank/grew too much in one frame, or
 * their face is too small. */
static int plausible(const gs_live_track *t, const double prev[][2], const double cur[][2])
{
    double px, py, ps, cx, cy, cs;
    lm_bounds(prev, &px, &py, &ps);
    lm_bounds(cur, &cx, &cy, &cs);
    double j = t->cfg.max_jump;
    if (hypot(cx - px, cy - py) > j * ps)
        return 0;
    if (cs > ps * (1 + j) || cs * (1 + j) < ps)
        return 0;
    return t->rel_scale * cs >= t->cfg.min_box;
}

static int finite_lm(const double uv[][2])
{
    for (int i = 0; i < GS_FACE_LANDMARKS; i++)
        if (!isfinite(uv[i][0]) || !isfinite(uv[i][1]))
            return 0;
    return 1;
}

/* Confirms the tracked face with the detector on a crop twice its box,
 * looking only for faces at least half its size (cheap). */
static int verify(gs_live_track *t, const gs_io_image *img, gs_face_box b, int *ok,
                  gs_error *err)
{
    int w = b.right - b.left + 1;
    int x0 = b.left - w / 2, y0 = b.top - w / 2, x1 = b.right + w / 2 + 1,
        y1 = b.bottom + w / 2 + 1;
    x0 = x0 < 0 ? 0 : x0;
    y0 = y0 < 0 ? 0 : y0;
    x1 = x1 > img->width ? img->width : x1;
    y1 = y1 > img->height ? img->height : y1;
    *ok = 0;
    if (x1 - x0 < t->cfg.min_box || y1 - y0 < t->cfg.min_box)
        return GS_OK;
    gs_io_image crop = {x1 - x0, y1 - y0, img->stride, img->data + (size_t)y0 * img->stride +
                                                           (size_t)x0 * 3};
    gs_face_box found;
    return t->ops.detect(t->ops.ctx, &crop, w / 2, &found, ok, err);
}

static int acquire(gs_live_track *t, const gs_io_image *img, gs_live_track_state *st,
                   gs_error *err)
{
    int found = 0;
    gs_face_box b;
    st->detected = 1;
    int r = t->ops.detect(t->ops.ctx, img, t->cfg.min_box, &b, &found, err);
    if (r != GS_OK || !found || b.right - b.left + 1 < t->cfg.min_box)
        return r;
    r = t->ops.landmarks(t->ops.ctx, img, b, st->uv, err);
    if (r != GS_OK || !finite_lm(st->uv))
        return r;
    learn_box(t, b, st->uv);
    st->box = b;
    st->face = 1;
    t->tracking = 1;
    t->since_verify = 0;
    t->track_id++;
    return GS_OK;
}

static int follow(gs_live_track *t, const gs_io_image *img, gs_live_track_state *st,
                  gs_error *err)
{
    gs_face_box b = gs_live_track_seed_box(t, t->prev_uv);
    int r = t->ops.landmarks(t->ops.ctx, img, b, st->uv, err);
    if (r != GS_OK)
        return r;
    if (!finite_lm(st->uv) || !plausible(t, t->prev_uv, st->uv))
        return GS_OK;
    if (t->cfg.verify_every && ++t->since_verify >= t->cfg.verify_every) {
        int ok;
        t->since_verify = 0;
        if ((r = verify(t, img, b, &ok, err)) != GS_OK || !ok)
            return r;
    }
    st->box = b;
    st->face = 1;
    return GS_OK;
}

int gs_live_track_update(gs_live_track *t, const gs_io_image *img, const double k[9],
                         gs_live_track_state *st, gs_error *err)
{
    if (!t || !img || !img->data || !st || !k)
        return gs_error_set(err, GS_ERR_ARG, "track: NULL argument");
    memset(st, 0, sizeof *st);
    int r = GS_OK;
    if (t->tracking)
        r = follow(t, img, st, err);
    if (r == GS_OK && !st->face) {
        t->tracking = 0; /* lost (or never had one): detect in this frame */
        r = acquire(t, img, st, err);
    }
    if (r != GS_OK) {
        t->tracking = 0;
        return r;
    }
    st->track_id = t->track_id;
    if (!st->face)
        return GS_OK;
    memcpy(t->prev_uv, st->uv, sizeof t->prev_uv);
    st->openness = gs_live_eye_openness((const double(*)[2])st->uv);
    gs_error pe;
    if (gs_face_head_pose((const double(*)[2])st->uv, k, &st->pose, &pe) != GS_OK) {
        st->face = 0; /* a pose behind the camera: not a face we can use */
        t->tracking = 0;
    }
    return GS_OK;
}

/* ---- measurements ---- */

static double dist(const double a[2], const double b[2])
{
    return hypot(a[0] - b[0], a[1] - b[1]);
}

/* Eye aspect ratio of the eye whose six points start at i (36 or 42). */
static double ear(const double uv[][2], int i)
{
    double w = dist(uv[i], uv[i + 3]);
    if (w < 1e-6)
        return 0.0;
    return (dist(uv[i + 1], uv[i + 5]) + dist(uv[i + 2], uv[i + 4])) / (2.0 * w);
}

double gs_live_eye_openness(const double uv[][2])
{
    double e = 0.5 * (ear(uv, 36) + ear(uv, 42));
    double o = (e - 0.10) / 0.20;
    return o < 0 ? 0 : o > 1 ? 1 : o;
}

int gs_live_camera_gaze(const double R[9], const double t[3], double *pitch, double *yaw)
{
    double m[6][3], c[3], g[3] = {0, 0, 0};
    gs_geom_face_model6(m);
    gs_geom_face_centre6((const double(*)[3])m, c);
    for (int eye = 0; eye < 2; eye++) {
        double e[3], ec[3], d[3];
        for (int a = 0; a < 3; a++)
            e[a] = 0.5 * (m[2 * eye][a] + m[2 * eye + 1][a]) - c[a];
        gs_geom_mat3_vec(R, e, ec);
        for (int a = 0; a < 3; a++)
            ec[a] = -(ec[a] + t[a]);
        if (gs_geom_vec3_normalize(ec) != GS_OK)
            return GS_ERR_ARG;
        gs_geom_mat3_tvec(R, ec, d);
        for (int a = 0; a < 3; a++)
            g[a] += d[a];
    }
    return gs_geom_vec_to_pitchyaw(g, pitch, yaw);
}
