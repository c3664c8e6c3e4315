/* Detail transfer (docs/model.md, "Detail transfer"): a redirected image
 * that keeps what the fit could not reproduce. The model renders the
 * subject's own view (the input's gaze and head pose) and the target view;
 * the residual R = input - own view is carried to the target through the
 * model's geometry and added to the target render.
 *
 * Each target pixel p has the model's depth z_t(p), coverage a_t(p) and
 * eyeball-ness b(p) (eye-stream coverage x GS_XFER_EYE_GAIN, at most 1).
 * It takes the residual from two places of the input, weighted 1 - b and b:
 *   skin (moves with the head): X_t = z_t K_t^-1 (p, 1) in the target
 *     camera, X_s = R_s R_t^T (X_t - t_t) + t_s in the input's, p_s its
 *     projection; with the input's head pose p_s = p;
 *   eyeball (also turns with the gaze): the point, in the head frame,
 *     turned about its eyeball's centre by R_e,s R_e,t^T (the eye
 *     stream's rotations at the two gazes) before the same projection.
 * A place counts when the input sees it: on the head there, at X_s's depth
 * within GS_XFER_DEPTH_TOL, and of the same kind (a skin point must not
 * take the input's eyeball, nor an eyeball point its eyelid): the weight
 * is min(1, b_s / b) for the eyeball and min(1, (1 - b_s) / (1 - b)) for
 * the skin, b_s the input's eyeball-ness at p_s. Off the head in both views
 * the residual is taken in place. The subject's own view thus gives the
 * input back, and a zero residual gives the plain render.
 *
 * The model's eyeball is not the input's (its iris is drawn a little off
 * in place, size and colour), so the more the eye turns, the less of the
 * input's eyeball residual lands where the target's iris is: an eyeball
 * whose rotation from the input's gaze is theta degrees carries it times
 * W + (1 - W) exp(-(theta / GS_XFER_EYE_FALLOFF_DEG)^2), W the context's
 * transfer_eye_weight: all of it at the input's gaze (the input comes
 * back), W once the eye has turned a few degrees, and no jump between.
 *
 * The eyeball warp (the context's transfer_eye_warp_deg, W_deg > 0; same
 * head pose only). The model draws the eyeball from 64^2 features, far
 * blurrier than the input shows it, so where the input sees it the input's
 * own eyeball pixels, turned with the eye, make a better eyeball than the
 * render plus a residual. Per subject (with its own view):
 *   - a proxy eyeball per eye: the sphere about the eye stream's centre
 *     whose radius is its Gaussians' mean distance from it, with the iris
 *     on a plane inside the limbus (GS_XFER_IRIS_RATIO of the radius from
 *     the optical axis, R_g (0, 0, -1), R_g the gaze's rotation), as in an
 *     eye: the iris turns about the centre at that plane's distance, not
 *     the sphere's;
 *   - the eye opening ap(p) in [0, 1]: where the model's render changes
 *     when only the gaze changes (GS_XFER_PROBES renders at the input's
 *     gaze +- GS_XFER_PROBE_YAW / _PITCH), the largest change summed over
 *     RGB from GS_XFER_AP_LO to GS_XFER_AP_HI (8-bit units) mapped to 0..1.
 *     The probes hold the lids at the input's pitch (a model with lids
 *     moves them with the gaze), so the lids and the skin never count;
 *     the renderer learned where an eyeball shows.
 * Target pixel p inside the eye stream's tiles and the opening: its ray
 * meets a proxy eyeball at h (the iris plane inside the limbus), turned
 * back to the input's gaze h_s = c + R_g,s R_g,t^T (h - c) and projected to
 * q. The turn is the gaze's own, without the eye stream's learned residual
 * rotation: the input's pixels are a real eye, which turns by the gaze
 * change itself (the residual, for the model's drawn iris, read worse by
 * the estimator). It takes input(q) - render(p) with weight
 * w = ap(p) ap(q) exp(-(theta / W_deg)^2), theta that turn's angle, when
 * h_s faces the input's camera (0 otherwise), and the skin and eyeball
 * residuals above with 1 - w. The falloff keeps it to the turns the proxy
 * carries well: a large turn brings sclera from under the input's lids,
 * which the input never showed. At the input's own gaze q = p and the
 * input comes back.
 *
 * A photo's input may say more of its eyes (gs_xfer_eyes): its opening
 * (then the falloff is transfer_eye_warp_given_deg) and its irises. An
 * iris anchors the proxy whose own iris shows nearest to it at the input's
 * gaze: the proxy is scaled so its iris has that radius, and moved across
 * the input's view (at its iris's depth) so that it shows there. The warp
 * then turns the photo's iris where the photo has it, not where the
 * model's eye stream is; the model's eyeballs (eye_source, the maps) stay
 * as they are. With a given opening at the input's head pose, a point the
 * turn brings from where the input does not show it (its opening there
 * under 1: under a lid) takes the rest of its weight from the input's
 * pixel mirrored about its proxy's iris row, q' = (u, 2 v_i - v), where
 * the input shows that: the iris, and the sclera above and below it, are
 * much alike across that row, and the lids hide an eye's top or bottom.
 * Where that is hidden too, a point of the proxy's sclera takes the
 * input's sclera colour (sclera_colours), so that what the iris uncovers
 * reads as white of the eye. Without the fill such a point keeps the
 * input's own pixel in place, which left the photo's iris where it was
 * after a pitch change.
 *
 * Lids that follow the gaze (the context's transfer_lid_follow f > 0; a
 * given opening at the input's head pose). A real upper lid rises and
 * falls with the eye, the lower one a little; a photo's stay where they
 * were, so a look up slid the iris under the upper lid and a look down
 * bared a strip of sclera above it. Per eye: the given opening's upper and
 * lower margins per column near its iris (where the opening crosses 1/2;
 * a margin past the search does not move) and the vertical move dv of
 * the iris centre in the input's view from the input's gaze to the
 * target's. The upper margin moves by f dv, the lower by
 * GS_XFER_LID_LOWER f dv, times the hinge 1 - ((u - u_c) / w)^2 across the
 * opening's columns (the corners stay), the opening keeping at least
 * GS_XFER_LID_KEEP of its height. A target pixel of the column shows the
 * input's row v - s(v): s falls off linearly from a margin's move to 0
 * over the lid skin beside it (GS_XFER_LID_SKIN_UP radii above the upper,
 * _DOWN below the lower) and goes linearly from one margin's move to the
 * other's between them. The target's opening is the given one at
 * (u, v - s); inside the lids' box, where that is shut, the pixel is the
 * input's at (u, v - s), handing over to the rest over GS_XFER_LID_EDGE px
 * at the box's edge, so the photo's own lids show there, not the model's
 * eyeball or its renderer's spread of it. The boxes follow the opening
 * and the irises: a sweep redoes them, the kept target's and this one's,
 * with the eye stream's tiles.
 *
 * At another head pose the model's geometry places the input's detail a
 * pixel or two off, and the input's shading was lit at the old pose: a
 * head change carries only the skin residual's smooth part (Gaussian,
 * sigma GS_XFER_HEAD_SIGMA px) times the context's transfer_head_weight;
 * the eyeballs take none (the eye stream draws them at the new pose) and
 * off the head nothing is taken (the input's outline moved with the head).
 *
 * Gaze sweeps: when the target has the last one's subject, settings and
 * head pose, only the eye stream moved. The rasterizer changes no pixel
 * outside the tiles the eye stream reaches at the old or the new gaze,
 * and outside those b = 0 at both, so the skin's warp there (head poses
 * and the face's maps only) stands: the maps and the warp are redone over
 * that box alone, as the plain render redoes its features (frame.c). */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "frame.h"
#include "gazesplat/geom.h"
#include "gazesplat/pool.h"

/* Depth agreement (mm) for a head point to count as seen by the input. */
#define GS_XFER_DEPTH_TOL 6.0
/* Coverage above which a pixel is on the head. */
#define GS_XFER_ON_HEAD 0.5f
/* Eyeball-ness of a pixel: its eye-stream coverage times this, at most 1. */
#define GS_XFER_EYE_GAIN 4.0f
/* Gaze turn (degrees) over which an eyeball's residual weight falls from
 * 1 to the context's transfer_eye_weight. */
#define GS_XFER_EYE_FALLOFF_DEG 5.0
/* Smoothing of the residual carried to another head pose, px at 256 px
 * (scaled with the image size). */
#define GS_XFER_HEAD_SIGMA 2.0
/* The eyeball warp (the header): the proxy's iris (GS_XFER_IRIS_RATIO,
 * GS_XFER_IRIS_INSET) is in frame.h; here the probe gazes' offsets (rad)
 * and the change (summed over RGB, 8-bit units) over which a pixel
 * becomes the eye opening. */
#define GS_XFER_PROBES 4
#define GS_XFER_PROBE_YAW 0.4
#define GS_XFER_PROBE_PITCH 0.3
#define GS_XFER_AP_LO 20.0f
#define GS_XFER_AP_HI 80.0f
/* The fill's sclera colour (sclera_colours): open pixels this many iris
 * radii from the iris centre, and how many an eye needs. */
#define GS_XFER_SCLERA_IN 1.15
#define GS_XFER_SCLERA_OUT 4.0
#define GS_XFER_SCLERA_MIN 8
/* Lids that follow the gaze on a photo (the header): the given opening's
 * margins are searched GS_XFER_LID_REACH_U iris radii either side of an
 * iris centre and GS_XFER_LID_REACH_V above and below it (the lid skin
 * that moves: frame.h); an opening keeps at least
 * GS_XFER_LID_KEEP of its height; the lids' own pixels hand over to the
 * rest of the transfer over GS_XFER_LID_EDGE px at their box's edge. */
#define GS_XFER_LID_REACH_U 4.0
#define GS_XFER_LID_REACH_V 3.0
#define GS_XFER_LID_KEEP 0.3
#define GS_XFER_LID_EDGE 3

/* What is kept per subject: its own view (while subject and settings are
 * the same), the residual of its input, and its last target's maps and
 * warped residual. */
typedef struct xfer_subj {
    int valid;
    gs_subject key;
    int key_fs, key_full;
    uint8_t *src8;                 /* [S, S, 3] */
    float *src_z, *src_a, *src_e;  /* [S*S] depth mm, coverage, eye */
    double src_eR[2][9], src_ec[2][3]; /* its eyeball rotations, centres */
    double src_Rg[9];              /* its gaze's rotation (the warp's) */
    double src_er[2];              /* its proxy eyeballs' radii */
    int ap_valid;                  /* src_ap is this own view's, from
                                      open8 when ap_given, else probed */
    float *src_ap;                 /* [S*S] eye opening, 0..1 */
    int ap_given;
    uint8_t *open8;                /* [S*S] the opening it was given */
    unsigned ap_gen;               /* counts the openings given */
    /* the sclera's colour per eye (sclera_colours), for the input res
     * came from, the given opening of generation scl_gen and the irises
     * scl_at (centre, radius px) */
    int scl_valid;
    unsigned scl_gen;
    double scl_at[2][3];
    int scl_ok[2];
    float scl[2][3];
    /* the eye opening at another head pose (the warp there): tgt_ap is
     * for head pose tap_R, tap_t when tap_valid */
    int tap_valid;
    double tap_R[9], tap_t[3];
    float *tgt_ap;                 /* [S*S] */
    /* the residual res, kept with the input it came from while the own
     * view is kept */
    int res_valid;
    uint8_t *in8;                  /* [S, S, 3] */
    float *res;                    /* [3, S*S] residual, input's view */
    int smooth_valid;              /* res_smooth is res's */
    float *res_smooth;             /* [3, S*S] res smoothed (head changes) */
    /* the last target's maps and warped residual, kept with the own view
     * (tgt_valid): a target that changes only the gaze redoes them only
     * where the eye stream reaches (target_maps) */
    int tgt_valid;
    double tgt_R[9], tgt_t[3];     /* its head pose */
    int tgt_rect[4];               /* its eye stream's tiles, image px */
    int lid_rect[4];               /* the pixels its lids could change */
    int16_t *fbox;                 /* [nf, 4] its face Gaussians' boxes */
    float *tgt_z, *tgt_a, *tgt_e;  /* [S*S] */
    float *warped;                 /* [3, S*S] residual, target's view */
    uint64_t used;                 /* in a slot: when last live */
} xfer_subj;

struct gs_xfer {
    int S, nf;
    /* the live subject, and the others the context's sweep cache allows
     * (c->sweep_n - 1 slots: own views kept for several subjects, so that
     * requests alternating between them stay incremental) */
    xfer_subj cur;
    xfer_subj *slots;
    int nslots;
    uint64_t clock;
    double tgt_eR[2][9], tgt_ec[2][3]; /* this call's target's eyeballs */
    double tgt_Rg[9];                  /* its gaze's rotation */
    /* this call's proxy eyeballs (the warp's): radii, and shifts from the
     * eye centres (head frame); the own view's radii and no shift unless
     * given irises anchor them (eye_anchor) */
    double pr[2], pd[2][3];
    double ic[2][3];                   /* where their irises show in the
                                          input: centre, radius (image px) */
    /* this call's lids that follow the gaze (lid_frame), per eye */
    struct {
        int on;
        double uc, hw;                 /* hinge: centre column, half width */
        double su, sl;                 /* margin moves at uc (px, + down) */
        double hu, hl;                 /* lid skin moving above, below (px) */
        int box[4];                    /* the pixels it may change */
        float *top, *bot;              /* [S] the given opening's margins
                                          per column (NAN: none) */
        uint8_t *mu, *ml;              /* [S] whether each moves: not where
                                          the opening runs past the search */
    } lid[2];
    float *lid_m;                      /* [4, S]: the tops and bottoms */
    uint8_t *lid_f;                    /* [4, S]: mu and ml */
    /* scratch */
    gs_raster *raster, *raster_crop; /* whole images; crops of the target */
    gs_frame_soa k;                /* a crop's Gaussians, [n x ...] */
    float *feat;                   /* [n, 2]: face 1 0, eye 0 1 */
    float *af, *aa, *ad;           /* [2, S, S], [S*S], [S*S] */
    uint8_t *tgt8;                 /* [S, S, 3] */
    uint8_t *probe8;               /* [S, S, 3] the opening's probe renders */
};

static void subj_invalidate(xfer_subj *u)
{
    u->valid = u->res_valid = u->tgt_valid = u->ap_valid = u->tap_valid = 0;
    u->scl_valid = 0;
}

static void subj_free(xfer_subj *u)
{
    float *bufs[] = {u->src_z, u->src_a, u->src_e, u->res, u->res_smooth,
                     u->tgt_z, u->tgt_a, u->tgt_e, u->warped, u->src_ap,
                     u->tgt_ap};
    for (size_t i = 0; i < sizeof bufs / sizeof bufs[0]; i++)
        free(bufs[i]);
    free(u->src8);
    free(u->in8);
    free(u->open8);
    free(u->fbox);
    memset(u, 0, sizeof *u);
}

/* A subject's buffers for S x S images and nf face Gaussians; nonzero
 * when out of memory (u then holds none). */
static int subj_alloc(xfer_subj *u, int S, int nf)
{
    size_t px = (size_t)S * S;
    float **one[] = {&u->src_z, &u->src_a, &u->src_e, &u->tgt_z, &u->tgt_a,
                     &u->tgt_e, &u->src_ap, &u->tgt_ap};
    int fail = 0;
    for (size_t i = 0; i < sizeof one / sizeof one[0]; i++)
        fail |= !(*one[i] = malloc(px * sizeof(float)));
    fail |= !(u->res = malloc(3 * px * sizeof(float)));
    fail |= !(u->res_smooth = malloc(3 * px * sizeof(float)));
    fail |= !(u->warped = malloc(3 * px * sizeof(float)));
    fail |= !(u->src8 = malloc(3 * px)) || !(u->in8 = malloc(3 * px));
    fail |= !(u->open8 = malloc(px));
    fail |= !(u->fbox = malloc((size_t)(nf ? nf : 1) * 4 * sizeof(int16_t)));
    if (fail)
        subj_free(u);
    return fail;
}

static void slots_free(gs_xfer *x)
{
    for (int i = 0; i < x->nslots; i++)
        subj_free(&x->slots[i]);
    free(x->slots);
    x->slots = NULL;
    x->nslots = 0;
}

void gs_xfer_free(gs_xfer *x)
{
    if (!x)
        return;
    float *bufs[] = {x->feat, x->af, x->aa, x->ad, x->k.mean, x->k.scale,
                     x->k.quat, x->k.opac, x->k.feat, x->lid_m};
    for (size_t i = 0; i < sizeof bufs / sizeof bufs[0]; i++)
        free(bufs[i]);
    subj_free(&x->cur);
    slots_free(x);
    free(x->tgt8);
    free(x->probe8);
    free(x->lid_f);
    gs_raster_destroy(x->raster);
    gs_raster_destroy(x->raster_crop);
    free(x);
}

void gs_xfer_invalidate(gs_xfer *x)
{
    if (!x)
        return;
    subj_invalidate(&x->cur);
    for (int i = 0; i < x->nslots; i++)
        subj_invalidate(&x->slots[i]);
}

void gs_xfer_forget_target(gs_xfer *x)
{
    if (x)
        x->cur.tgt_valid = 0;
}

void gs_model_ctx_forget_transfer_targets(gs_model_ctx *c)
{
    gs_xfer *x = c ? c->xfer : NULL;
    if (!x)
        return;
    x->cur.tgt_valid = 0;
    for (int i = 0; i < x->nslots; i++)
        x->slots[i].tgt_valid = 0;
}

float *gs_xfer_eye_opening(gs_xfer *x)
{
    return x && x->cur.ap_valid ? x->cur.src_ap : NULL;
}

float *gs_xfer_target_opening(gs_xfer *x)
{
    return x && x->cur.tap_valid ? x->cur.tgt_ap : NULL;
}

void gs_xfer_target_maps(const gs_xfer *x, const float **z, const float **a,
                         const float **e)
{
    *z = x ? x->cur.tgt_z : NULL;
    *a = x ? x->cur.tgt_a : NULL;
    *e = x ? x->cur.tgt_e : NULL;
}

/* The scratch of the whole-image and crop passes for n Gaussians;
 * nonzero when out of memory. */
static int scratch_alloc(gs_xfer *x, int S, size_t n)
{
    size_t px = (size_t)S * S;
    x->raster = gs_raster_create();
    x->raster_crop = gs_raster_create();
    x->feat = calloc(n * 2, sizeof(float));
    x->af = malloc(2 * px * sizeof(float));
    x->aa = malloc(px * sizeof(float));
    x->ad = malloc(px * sizeof(float));
    x->tgt8 = malloc(3 * px);
    x->probe8 = malloc(3 * px);
    x->lid_m = malloc(4 * (size_t)S * sizeof(float));
    x->lid_f = malloc(4 * (size_t)S);
    for (int e = 0; x->lid_m && x->lid_f && e < 2; e++) {
        x->lid[e].top = x->lid_m + (size_t)(2 * e) * S;
        x->lid[e].bot = x->lid_m + (size_t)(2 * e + 1) * S;
        x->lid[e].mu = x->lid_f + (size_t)(2 * e) * S;
        x->lid[e].ml = x->lid_f + (size_t)(2 * e + 1) * S;
    }
    float **f[] = {&x->k.mean, &x->k.scale, &x->k.quat, &x->k.opac,
                   &x->k.feat};
    size_t per[] = {3, 3, 4, 1, 2};
    int fail = !x->raster || !x->raster_crop || !x->feat || !x->af ||
               !x->aa || !x->ad || !x->tgt8 || !x->probe8 || !x->lid_m ||
               !x->lid_f;
    for (size_t i = 0; i < sizeof f / sizeof f[0]; i++)
        fail |= !(*f[i] = malloc(n * per[i] * sizeof(float)));
    return fail;
}

static gs_xfer *xfer_get(gs_model_ctx *c)
{
    if (c->xfer)
        return c->xfer;
    gs_xfer *x = calloc(1, sizeof *x);
    if (!x)
        return NULL;
    x->S = c->S;
    x->nf = c->nf;
    if (scratch_alloc(x, c->S, (size_t)c->n) ||
        subj_alloc(&x->cur, c->S, c->nf)) {
        gs_xfer_free(x);
        return NULL;
    }
    for (int i = 0; i < c->n; i++)
        x->feat[2 * (size_t)i + (i < c->nf ? 0 : 1)] = 1.0f;
    c->xfer = x;
    c->xfer_free = gs_xfer_free;
    c->xfer_invalidate = gs_xfer_invalidate;
    return x;
}

/* The camera of an S x S image of a head at head_t. */
static void image_camera(const gs_model_ctx *c, const double head_t[3],
                         gs_camera *cam)
{
    gs_frame_camera(c->m, head_t, cam);
    float s = (float)c->S / (float)c->fs;
    cam->fx *= s, cam->fy *= s;
    cam->cx = cam->cy = 0.5f * (float)c->S;
    cam->width = cam->height = c->S;
}

/* The Gaussians the last render left in c->g_* (its frame) with the
 * features of the maps: face 1 0, eye 0 1. */
static gs_gaussians map_gaussians(const gs_model_ctx *c, const gs_xfer *x)
{
    gs_gaussians g = {.n = c->n, .channels = 2, .means = c->g_mean,
                      .log_scales = c->g_scale, .quats = c->g_quat,
                      .opacity_logits = c->g_opac, .features = x->feat};
    return g;
}

/* Depth (mm) of a pixel from its alpha and alpha-weighted depth sum. */
static float depth_of(float alpha, float depth_sum)
{
    return alpha > 1e-3f ? depth_sum / alpha : 0.0f;
}

/* Depth, coverage and eye coverage of the Gaussians of the last render
 * seen by cam (image resolution). */
static int aux_maps(gs_model_ctx *c, gs_xfer *x, gs_pool *pool,
                    const gs_camera *cam, float *z, float *a, float *e,
                    gs_error *err)
{
    gs_gaussians g = map_gaussians(c, x);
    gs_raster_options ro = {.antialiased = 0, .path = GS_RASTER_FAST};
    gs_raster_set_records(x->raster, 0);
    int rc = gs_raster_forward(x->raster, pool, cam, &g, NULL, &ro, x->af,
                               x->aa, x->ad, err);
    if (rc)
        return rc;
    size_t px = (size_t)x->S * x->S;
    for (size_t i = 0; i < px; i++) {
        a[i] = x->aa[i];
        z[i] = depth_of(x->aa[i], x->ad[i]);
        e[i] = x->af[px + i];
    }
    return GS_OK;
}

/* Pixel i of the target's maps from a crop's alpha, depth sum and eye
 * coverage. What moved by no more than the crop camera's rounding keeps
 * its value; coverage and depth are judged by the rasterizer's outputs, as
 * depth = sum / alpha would magnify the rounding where alpha is small. */
static void merge_pixel(gs_xfer *x, size_t i, float al, float sum, float eye)
{
    if (gs_frame_moved(x->cur.tgt_a[i], al) ||
        gs_frame_moved(x->cur.tgt_a[i] * x->cur.tgt_z[i], sum)) {
        x->cur.tgt_a[i] = al;
        x->cur.tgt_z[i] = depth_of(al, sum);
    }
    if (gs_frame_moved(x->cur.tgt_e[i], eye))
        x->cur.tgt_e[i] = eye;
}

/* The target's maps over the tile-aligned box d only, from the Gaussians
 * that can reach it. */
static int aux_crop(gs_model_ctx *c, gs_xfer *x, gs_pool *pool,
                    const gs_camera *ct, const int d[4], gs_error *err)
{
    gs_gaussians all = map_gaussians(c, x);
    gs_gaussians g = gs_frame_gather(&all, c->nm, x->cur.fbox, d, &x->k);
    int w = d[2] - d[0], h = d[3] - d[1], S = x->S;
    int rc = gs_frame_raster_crop(x->raster_crop, pool, ct, d, &g, NULL,
                                  x->af, x->aa, x->ad, err);
    if (rc)
        return rc;
    const float *eye = x->af + (size_t)w * h;
    for (int y = 0; y < h; y++)
        for (int xx = 0; xx < w; xx++) {
            size_t j = (size_t)y * w + xx;
            merge_pixel(x, (size_t)(d[1] + y) * S + d[0] + xx, x->aa[j],
                        x->ad[j], eye[j]);
        }
    return GS_OK;
}

/* The target's maps for the render c->g_* holds, seen by ct. With the
 * same head pose as the kept target (keep), the face Gaussians are the
 * same and only the eye stream moved: only its reach, at the kept gaze or
 * this one, is redone. d: the box that changed (the whole image on the
 * full path). */
static int target_maps(gs_model_ctx *c, gs_xfer *x, gs_pool *pool,
                       const gs_camera *ct, int keep, int d[4],
                       gs_error *err)
{
    int now[4], rc = GS_OK;
    gs_frame_eye_tiles(c, ct, now);
    if (keep) {
        memcpy(d, x->cur.tgt_rect, sizeof now);
        gs_frame_box_union(d, now);
        if (d[0] < d[2] && d[1] < d[3])
            rc = aux_crop(c, x, pool, ct, d, err);
    } else {
        rc = aux_maps(c, x, pool, ct, x->cur.tgt_z, x->cur.tgt_a, x->cur.tgt_e, err);
        gs_frame_face_boxes(c, ct, x->cur.fbox);
        d[0] = d[1] = 0, d[2] = d[3] = x->S;
    }
    memcpy(x->cur.tgt_rect, now, sizeof now);
    memcpy(x->tgt_eR, c->eye_R, sizeof x->tgt_eR);
    memcpy(x->tgt_Rg, c->eye_Rg, sizeof x->tgt_Rg);
    memcpy(x->tgt_ec, c->eye_c, sizeof x->tgt_ec);
    return rc;
}

static int same_subject(const gs_subject *a, const gs_subject *b)
{
    if (a->code_dim != b->code_dim ||
        memcmp(a->code, b->code, sizeof(float) * (size_t)a->code_dim) ||
        memcmp(a->head_R, b->head_R, sizeof a->head_R) ||
        memcmp(a->head_t, b->head_t, sizeof a->head_t) ||
        memcmp(a->colour_gain, b->colour_gain, sizeof a->colour_gain) ||
        memcmp(a->colour_bias, b->colour_bias, sizeof a->colour_bias))
        return 0;
    return a->gaze_pitch == b->gaze_pitch && a->gaze_yaw == b->gaze_yaw;
}

/* The four pixels (y * S + x) and weights of a bilinear sample of an
 * S x S image at continuous pixel coordinates (u, v), pixel centres at
 * +0.5, clamped to the image. */
typedef struct {
    size_t at[4];
    float w[4];
} bilinear_taps;

static bilinear_taps taps_at(int S, double u, double v)
{
    double x = u - 0.5, y = v - 0.5;
    x = x < 0 ? 0 : x > S - 1 ? S - 1 : x;
    y = y < 0 ? 0 : y > S - 1 ? S - 1 : y;
    int x0 = (int)x, y0 = (int)y;
    int x1 = x0 + 1 < S ? x0 + 1 : x0, y1 = y0 + 1 < S ? y0 + 1 : y0;
    float fx = (float)(x - x0), fy = (float)(y - y0);
    bilinear_taps t = {{(size_t)y0 * S + x0, (size_t)y0 * S + x1,
                        (size_t)y1 * S + x0, (size_t)y1 * S + x1},
                       {(1 - fy) * (1 - fx), (1 - fy) * fx, fy * (1 - fx), fy * fx}};
    return t;
}

/* Bilinear sample of plane p (S x S) at (u, v) (taps_at). */
static float bilinear(const float *p, int S, double u, double v)
{
    bilinear_taps t = taps_at(S, u, v);
    return t.w[0] * p[t.at[0]] + t.w[1] * p[t.at[1]] + t.w[2] * p[t.at[2]] +
           t.w[3] * p[t.at[3]];
}

/* The two views' geometry for the per-pixel warps. */
typedef struct {
    gs_camera ct, cs;     /* target and input cameras at image size */
    const double *Rt, *tt, *Rs, *ts; /* head poses: target, input */
    double eM[2][9];      /* per eye: R_e,s R_e,t^T (head frame) */
    int same_pose;
    float eye_w[2];       /* weight of each eyeball's residual */
    double gM[9];         /* the gaze's own turn R_g,s R_g,t^T (the warp) */
    float warp_w;         /* the eyeball warp's falloff; 0: off */
    int fill;             /* the given opening's fill (the header): hidden
                             points mirrored about the iris's row */
    int lid;              /* lids that follow the gaze (lid_frame) */
    double ray_o[3];      /* the target camera's centre, head frame */
    float head_w;         /* weight of the smoothed residual (head change) */
} xfer_geom;

/* The angle (degrees) of rotation M. */
static double turn_deg(const double M[9])
{
    double ct = 0.5 * (M[0] + M[4] + M[8] - 1.0);
    return acos(ct > 1 ? 1 : ct < -1 ? -1 : ct) * (180.0 / 3.14159265358979323846);
}

/* The weight of an eyeball's residual after a turn by M (the header). */
static float eye_weight(const double M[9], double floor_w)
{
    double r = turn_deg(M) / GS_XFER_EYE_FALLOFF_DEG;
    return (float)(floor_w + (1.0 - floor_w) * exp(-r * r));
}

/* Whether the eyeball warp runs: asked for, at the input's head pose (or
 * at any, transfer_eye_warp_head), and the model turns its eyes
 * explicitly (the ablation without is measured as the model it is). */
static int warp_on(const gs_model_ctx *c, int same_pose)
{
    return c->xfer_warp_deg > 0 && (same_pose || c->xfer_warp_head) &&
           c->m->cfg.eye_rotation;
}

static void geom_init(const gs_model_ctx *c, const gs_xfer *x, xfer_geom *g,
                      const double Rs[9], const double ts[3],
                      const double Rt[9], const double tt[3], int same_pose)
{
    /* the falloff: the given opening's at the input's pose (a head change
     * warps inside the probed target opening) */
    double wdeg = same_pose && x->cur.ap_given ? c->xfer_warp_given_deg : c->xfer_warp_deg;
    image_camera(c, tt, &g->ct);
    image_camera(c, ts, &g->cs);
    g->Rt = Rt, g->tt = tt, g->Rs = Rs, g->ts = ts;
    for (int e = 0; e < 2; e++) {
        double tT[9];
        gs_geom_mat3_transpose(x->tgt_eR[e], tT);
        gs_geom_mat3_mul(x->cur.src_eR[e], tT, g->eM[e]);
        g->eye_w[e] = eye_weight(g->eM[e], c->xfer_eye_w);
    }
    g->same_pose = same_pose;
    double tT[9];
    gs_geom_mat3_transpose(x->tgt_Rg, tT);
    gs_geom_mat3_mul(x->cur.src_Rg, tT, g->gM);
    int warp = warp_on(c, g->same_pose);
    double r = turn_deg(g->gM) / (warp ? wdeg : 1.0);
    g->warp_w = warp ? (float)exp(-r * r) : 0.0f;
    g->fill = warp && same_pose && x->cur.ap_given;
    g->lid = g->fill && c->xfer_lid > 0;
    double mt[3] = {-tt[0], -tt[1], -tt[2]};
    gs_geom_mat3_tvec(Rt, mt, g->ray_o);
}

/* Target pixel (px, py)'s surface point in the head frame. */
static void target_point(const gs_xfer *x, const xfer_geom *g, int px, int py,
                         double h[3])
{
    double z = x->cur.tgt_z[(size_t)py * x->S + px];
    double d[3] = {(px + 0.5 - g->ct.cx) / g->ct.fx * z - g->tt[0],
                   (py + 0.5 - g->ct.cy) / g->ct.fy * z - g->tt[1],
                   z - g->tt[2]};
    gs_geom_mat3_tvec(g->Rt, d, h);
}

/* Head-frame point h in the input's camera. */
static void input_point(const xfer_geom *g, const double h[3], double X[3])
{
    gs_geom_mat3_vec(g->Rs, h, X);
    for (int k = 0; k < 3; k++)
        X[k] += g->ts[k];
}

/* min(1, num / den), den > 0: the share of a pixel's kind that its source
 * place has. */
static float kind_ratio(float num, float den)
{
    return num >= den ? 1.0f : num / den;
}

static float eyeballness(const float *e, int S, double u, double v)
{
    float b = GS_XFER_EYE_GAIN * bilinear(e, S, u, v);
    return b > 1.0f ? 1.0f : b;
}

/* Projects X (input camera) to (u, v) and returns the weight of the place
 * for a target pixel of eyeball-ness b taking it as skin (eye = 0) or
 * eyeball (eye = 1): 0 unless the input sees X (in the image, on the head
 * and at X's depth there). */
static float seen_by_input(const gs_xfer *x, const xfer_geom *g,
                           const double X[3], int eye, float b, double *u,
                           double *v)
{
    int S = x->S;
    if (!(X[2] > 1.0))
        return 0.0f;
    *u = g->cs.fx * X[0] / X[2] + g->cs.cx;
    *v = g->cs.fy * X[1] / X[2] + g->cs.cy;
    if (!(*u >= 0 && *v >= 0 && *u <= S && *v <= S))
        return 0.0f;
    if (bilinear(x->cur.src_a, S, *u, *v) <= GS_XFER_ON_HEAD ||
        fabs(bilinear(x->cur.src_z, S, *u, *v) - X[2]) > GS_XFER_DEPTH_TOL)
        return 0.0f;
    float bs = eyeballness(x->cur.src_e, S, *u, *v);
    return eye ? kind_ratio(bs, b) : kind_ratio(1.0f - bs, 1.0f - b);
}

/* Where the input shows target pixel (px, py) of the head (skin, hair,
 * eyelids: moving with the head), h its head-frame point, and how much to
 * trust it. */
static float head_source(const gs_xfer *x, const xfer_geom *g, int px, int py,
                         const double h[3], float b, double *u, double *v)
{
    size_t i = (size_t)py * x->S + px;
    if (g->same_pose) { /* in place */
        *u = px + 0.5, *v = py + 0.5;
        return kind_ratio(1.0f - eyeballness(x->cur.src_e, x->S, *u, *v),
                          1.0f - b);
    }
    if (x->cur.tgt_a[i] <= GS_XFER_ON_HEAD) /* off the head: nothing */
        return 0.0f;
    double Xs[3];
    input_point(g, h, Xs);
    return seen_by_input(x, g, Xs, 0, b, u, v);
}

/* The same for a point h of an eyeball, which also turns with the gaze
 * about its centre: the nearest eyeball's rotation from the target's gaze
 * back to the input's. */
static float eye_source(const gs_xfer *x, const xfer_geom *g,
                        const double h[3], float b, double *u, double *v)
{
    int e = 0;
    double best = INFINITY;
    for (int k = 0; k < 2; k++) {
        double dd = 0;
        for (int j = 0; j < 3; j++)
            dd += (h[j] - x->tgt_ec[k][j]) * (h[j] - x->tgt_ec[k][j]);
        if (dd < best)
            best = dd, e = k;
    }
    double r[3], hs[3], Xs[3];
    for (int k = 0; k < 3; k++)
        r[k] = h[k] - x->tgt_ec[e][k];
    gs_geom_mat3_vec(g->eM[e], r, hs);
    for (int k = 0; k < 3; k++)
        hs[k] += x->cur.src_ec[e][k];
    input_point(g, hs, Xs);
    return g->eye_w[e] * seen_by_input(x, g, Xs, 1, b, u, v);
}

/* The eye's optical axis (head frame) for its rotation R: R (0, 0, -1). */
static void eye_axis(const double R[9], double a[3])
{
    a[0] = -R[2], a[1] = -R[5], a[2] = -R[8];
}

/* Target pixel (px, py)'s ray against the proxy eyeballs (the header):
 * the eye it meets first (-1: none), h the head-frame point (on the iris
 * plane inside the limbus), *iris whether it is there. */
static int proxy_hit(const gs_xfer *x, const xfer_geom *g, int px, int py,
                     double h[3], int *iris)
{
    double dc[3] = {(px + 0.5 - g->ct.cx) / g->ct.fx,
                    (py + 0.5 - g->ct.cy) / g->ct.fy, 1.0};
    double d[3];
    const double *o = g->ray_o;
    gs_geom_mat3_tvec(g->Rt, dc, d);
    double best = INFINITY, A = d[0] * d[0] + d[1] * d[1] + d[2] * d[2];
    int e = -1;
    for (int k = 0; k < 2; k++) {
        double r = x->pr[k], oc[3], B = 0, C = -r * r;
        for (int j = 0; j < 3; j++) {
            oc[j] = o[j] - x->tgt_ec[k][j] - x->pd[k][j];
            B += d[j] * oc[j];
            C += oc[j] * oc[j];
        }
        double D = B * B - A * C;
        double t = D >= 0 ? (-B - sqrt(D)) / A : -1.0;
        if (t > 0 && t < best)
            best = t, e = k;
    }
    if (e < 0)
        return -1;
    double c[3], r = x->pr[e], ax[3], ca = 0;
    for (int k = 0; k < 3; k++)
        c[k] = x->tgt_ec[e][k] + x->pd[e][k];
    eye_axis(x->tgt_Rg, ax);
    for (int k = 0; k < 3; k++) {
        h[k] = o[k] + best * d[k];
        ca += (h[k] - c[k]) * ax[k];
    }
    double limbus = sqrt(1.0 - GS_XFER_IRIS_RATIO * GS_XFER_IRIS_RATIO);
    *iris = 0;
    if (ca > limbus * r) { /* inside the limbus: on to the iris plane */
        double dp = r * (limbus - GS_XFER_IRIS_INSET), num = 0, den = 0;
        for (int k = 0; k < 3; k++) {
            num += (c[k] + dp * ax[k] - o[k]) * ax[k];
            den += d[k] * ax[k];
        }
        if (den < 0) { /* the ray goes into the eye */
            for (int k = 0; k < 3; k++)
                h[k] = o[k] + num / den * d[k];
            *iris = 1;
        }
    }
    return e;
}

/* Where the input shows target pixel (px, py)'s proxy eyeball point, at
 * (u, v), and the warp's weight for it there without the target's
 * opening (the header): 0 unless it faces the input's camera. *eye is the
 * proxy it meets (-1: none), *on_iris whether on its iris, *aq the input's
 * opening at (u, v), or -1 where the input cannot show the point at all. */
static float warp_source(const gs_xfer *x, const xfer_geom *g, int px, int py,
                         double *u, double *v, int *eye, float *aq, int *on_iris)
{
    double h[3], r[3], hs[3], n[3], nc[3], Xs[3];
    int iris = 0, e = proxy_hit(x, g, px, py, h, &iris);
    *eye = e;
    *on_iris = iris;
    *aq = -1.0f;
    if (e < 0)
        return 0.0f;
    for (int k = 0; k < 3; k++)
        r[k] = h[k] - x->tgt_ec[e][k] - x->pd[e][k];
    gs_geom_mat3_vec(g->gM, r, hs);
    if (iris)
        eye_axis(x->cur.src_Rg, n);
    else
        memcpy(n, hs, sizeof n);
    for (int k = 0; k < 3; k++)
        hs[k] += x->cur.src_ec[e][k] + x->pd[e][k];
    input_point(g, hs, Xs);
    gs_geom_mat3_vec(g->Rs, n, nc);
    if (!(Xs[2] > 1.0) || nc[0] * Xs[0] + nc[1] * Xs[1] + nc[2] * Xs[2] >= 0)
        return 0.0f;
    int S = x->S;
    *u = g->cs.fx * Xs[0] / Xs[2] + g->cs.cx;
    *v = g->cs.fy * Xs[1] / Xs[2] + g->cs.cy;
    if (!(*u >= 0 && *v >= 0 && *u <= S && *v <= S))
        return 0.0f;
    *aq = bilinear(x->cur.src_ap, S, *u, *v);
    return g->warp_w * *aq;
}

/* An interleaved 8-bit S x S RGB image at (u, v), bilinear (taps_at). */
static void bilinear_rgb8(const uint8_t *p, int S, double u, double v, float rgb[3])
{
    bilinear_taps t = taps_at(S, u, v);
    for (int k = 0; k < 3; k++)
        rgb[k] = t.w[0] * p[3 * t.at[0] + k] + t.w[1] * p[3 * t.at[1] + k] +
                 t.w[2] * p[3 * t.at[2] + k] + t.w[3] * p[3 * t.at[3] + k];
}

static int check_image(const uint8_t *p, size_t stride, int S, const char *what,
                       gs_error *err)
{
    if (!p)
        return gs_error_set(err, GS_ERR_ARG, "transfer: %s is NULL", what);
    if (stride < 3 * (size_t)S)
        return gs_error_set(err, GS_ERR_ARG, "transfer: %s stride %zu < %d",
                            what, stride, 3 * S);
    return GS_OK;
}

/* The subject's own view and its maps: rendered once per subject and
 * settings; a new one drops what was kept against the old. */
static int subj_matches(const gs_model_ctx *c, const xfer_subj *u,
                        const gs_subject *s)
{
    return u->valid && same_subject(&u->key, s) && u->key_fs == c->render_fs &&
           u->key_full == c->render_full;
}

static void subj_swap(xfer_subj *a, xfer_subj *b)
{
    xfer_subj t = *a;
    *a = *b, *b = t;
}

/* Makes s the live subject: its kept state when a slot has it; otherwise
 * the live one goes to a free or the least recently used slot (as many as
 * the context's sweep cache keeps other subjects' renders), and the live
 * state is left invalid, with buffers. Returns nonzero when out of memory. */
static int subj_select(const gs_model_ctx *c, gs_xfer *x, const gs_subject *s)
{
    if (subj_matches(c, &x->cur, s))
        return 0;
    int want = c->sweep_n - 1;
    if (want != x->nslots) { /* the cache was resized: start over */
        slots_free(x);
        if (want > 0 && !(x->slots = calloc((size_t)want, sizeof *x->slots)))
            return 1;
        x->nslots = want;
    }
    xfer_subj *v = NULL;
    for (int i = 0; i < x->nslots; i++) {
        xfer_subj *u = &x->slots[i];
        if (subj_matches(c, u, s)) {
            u->used = ++x->clock;
            subj_swap(&x->cur, u);
            return 0;
        }
        if (!v || (v->valid && (!u->valid || u->used < v->used)))
            v = u;
    }
    if (v && x->cur.valid) {
        x->cur.used = ++x->clock;
        subj_swap(&x->cur, v); /* v's buffers, or none yet */
    }
    subj_invalidate(&x->cur);
    return !x->cur.src8 && subj_alloc(&x->cur, x->S, x->nf);
}

/* Each eye's proxy radius: its Gaussians' mean distance from its centre
 * in the render c->x_head holds. */
static void proxy_radii(const gs_model_ctx *c, double r[2])
{
    int each = c->ne / 2;
    for (int e = 0; e < 2; e++) {
        double sum = 0;
        for (int i = 0; i < each; i++) {
            const float *xh = c->x_head + 3 * (size_t)(c->nf + e * each + i);
            double d2 = 0;
            for (int k = 0; k < 3; k++)
                d2 += (xh[k] - c->eye_c[e][k]) * (xh[k] - c->eye_c[e][k]);
            sum += sqrt(d2);
        }
        r[e] = each ? sum / each : 0.0;
    }
}

static double clamp_abs(double v, double lim)
{
    return v > lim ? lim : v < -lim ? -lim : v;
}

/* The eye opening (the header) of subject s seen at head pose R, t into
 * ap: the largest change over the probe gazes about its own gaze against
 * base, its render there at that gaze, mapped to 0..1. */
static int opening_probes(gs_model_ctx *c, gs_xfer *x, gs_pool *pool,
                          const gs_subject *s, const gs_view *at,
                          const uint8_t *base, float *ap, gs_error *err)
{
    static const double probe[GS_XFER_PROBES][2] = {
        {0, GS_XFER_PROBE_YAW}, {0, -GS_XFER_PROBE_YAW},
        {GS_XFER_PROBE_PITCH, 0}, {-GS_XFER_PROBE_PITCH, 0}};
    int S = x->S;
    size_t px = (size_t)S * S;
    memset(ap, 0, px * sizeof(float));
    for (int k = 0; k < GS_XFER_PROBES; k++) {
        gs_view v = *at;
        v.gaze_pitch = clamp_abs(s->gaze_pitch + probe[k][0], GS_MODEL_MAX_GAZE_PITCH);
        v.gaze_yaw = clamp_abs(s->gaze_yaw + probe[k][1], GS_MODEL_MAX_GAZE_YAW);
        /* the lids held at the subject's pitch: the opening is where the
         * eyeball shows, not where the lids go */
        c->lid_hold = 1;
        c->lid_pitch = s->gaze_pitch;
        int rc = gs_model_render(c, pool, s, &v, x->probe8, 3 * (size_t)S, err);
        c->lid_hold = 0;
        if (rc)
            return rc;
        for (size_t i = 0; i < px; i++) {
            const uint8_t *a = x->probe8 + 3 * i, *b = base + 3 * i;
            float d = (float)(abs(a[0] - b[0]) + abs(a[1] - b[1]) + abs(a[2] - b[2]));
            ap[i] = d > ap[i] ? d : ap[i];
        }
    }
    for (size_t i = 0; i < px; i++) {
        float w = (ap[i] - GS_XFER_AP_LO) / (GS_XFER_AP_HI - GS_XFER_AP_LO);
        ap[i] = w < 0.0f ? 0.0f : w > 1.0f ? 1.0f : w;
    }
    return GS_OK;
}

/* The live subject's eye opening in its own view (src_ap): the given one
 * (opening, S x S bytes, 255 = open), or probed. The kept target's warped
 * residual may stay when it changes: the warp acts only inside the eye
 * stream's tiles, which an incremental target redoes at both gazes.
 * Probing renders, so it runs before the target's render (whose Gaussians
 * the target's maps read). */
static int eye_opening(gs_model_ctx *c, gs_xfer *x, gs_pool *pool,
                       const gs_subject *s, const uint8_t *opening,
                       gs_error *err)
{
    size_t px = (size_t)x->S * x->S;
    if (opening) {
        if (x->cur.ap_valid && x->cur.ap_given &&
            !memcmp(x->cur.open8, opening, px))
            return GS_OK;
        memcpy(x->cur.open8, opening, px);
        x->cur.ap_gen++;
        for (size_t i = 0; i < px; i++)
            x->cur.src_ap[i] = opening[i] * (1.0f / 255.0f);
        x->cur.ap_valid = x->cur.ap_given = 1;
        return GS_OK;
    }
    if (x->cur.ap_valid && !x->cur.ap_given)
        return GS_OK;
    x->cur.ap_given = 0;
    gs_view own = {s->gaze_pitch, s->gaze_yaw, 0, {0}, {0}, 0};
    int rc = opening_probes(c, x, pool, s, &own, x->cur.src8, x->cur.src_ap, err);
    x->cur.ap_valid = !rc;
    return rc;
}

/* The live subject's eye opening at the target's head pose (tgt_ap; the
 * warp at a head change), kept while the target keeps that pose: probed
 * about the subject's own gaze, as its own view's is. Renders, so it runs
 * before the target's render; its base render goes to tgt8, which that
 * render then overwrites. */
static int target_opening(gs_model_ctx *c, gs_xfer *x, gs_pool *pool,
                          const gs_subject *s, const gs_view *view,
                          const double Rt[9], const double tt[3], gs_error *err)
{
    if (x->cur.tap_valid && !memcmp(x->cur.tap_R, Rt, sizeof x->cur.tap_R) &&
        !memcmp(x->cur.tap_t, tt, sizeof x->cur.tap_t))
        return GS_OK;
    x->cur.tap_valid = 0;
    gs_view at = {s->gaze_pitch, s->gaze_yaw, 1, {0}, {0}, view->light_on_head};
    memcpy(at.head_R, Rt, sizeof at.head_R);
    memcpy(at.head_t, tt, sizeof at.head_t);
    int S = x->S;
    int rc = gs_model_render(c, pool, s, &at, x->tgt8, 3 * (size_t)S, err);
    if (!rc)
        rc = opening_probes(c, x, pool, s, &at, x->tgt8, x->cur.tgt_ap, err);
    if (rc)
        return rc;
    memcpy(x->cur.tap_R, Rt, sizeof x->cur.tap_R);
    memcpy(x->cur.tap_t, tt, sizeof x->cur.tap_t);
    x->cur.tap_valid = 1;
    return GS_OK;
}

/* Where proxy eyeball e of radius r (mm), moved by d (head frame; NULL:
 * not moved), shows its iris in the input's image at the gaze of rotation
 * Rg: its centre uv (image px), its camera point X; returns its radius
 * there (px). proxy_iris_px: at the input's gaze, not moved. */
static double iris_view(const gs_xfer *x, const gs_subject *s,
                        const gs_camera *cs, int e, double r, const double Rg[9],
                        const double d[3], double uv[2], double X[3])
{
    double ax[3], h[3];
    double limbus = sqrt(1.0 - GS_XFER_IRIS_RATIO * GS_XFER_IRIS_RATIO);
    eye_axis(Rg, ax);
    for (int k = 0; k < 3; k++)
        h[k] = x->cur.src_ec[e][k] + (d ? d[k] : 0.0) +
               r * (limbus - GS_XFER_IRIS_INSET) * ax[k];
    gs_geom_mat3_vec(s->head_R, h, X);
    for (int k = 0; k < 3; k++)
        X[k] += s->head_t[k];
    uv[0] = cs->fx * X[0] / X[2] + cs->cx;
    uv[1] = cs->fy * X[1] / X[2] + cs->cy;
    return GS_XFER_IRIS_RATIO * r * cs->fx / X[2];
}

static double proxy_iris_px(const gs_xfer *x, const gs_subject *s,
                            const gs_camera *cs, int e, double r, double uv[2],
                            double X[3])
{
    return iris_view(x, s, cs, e, r, x->cur.src_Rg, NULL, uv, X);
}

/* This call's proxy eyeballs (x->pr, x->pd): the own view's, anchored to
 * the given irises at the input's head pose (model.h, gs_xfer_eyes). Each
 * proxy takes the iris that shows nearest to its own; a proxy two irises
 * would anchor keeps the nearer. Cheap, so redone every call and never
 * kept: the warp acts only inside the eye stream's tiles, which every
 * call redoes. */
static void eye_anchor(const gs_model_ctx *c, gs_xfer *x, const gs_subject *s,
                       const gs_xfer_eyes *eyes, int same_pose)
{
    memcpy(x->pr, x->cur.src_er, sizeof x->pr);
    memset(x->pd, 0, sizeof x->pd);
    gs_camera cs;
    image_camera(c, s->head_t, &cs);
    for (int e = 0; e < 2; e++) {
        double X[3];
        x->ic[e][2] = proxy_iris_px(x, s, &cs, e, x->pr[e], x->ic[e], X);
    }
    int n = eyes && same_pose ? eyes->n_iris : 0;
    if (n == 0)
        return;
    int pick[2] = {-1, -1};
    double dist[2] = {INFINITY, INFINITY};
    for (int e = 0; e < 2; e++)
        for (int j = 0; j < n; j++) {
            const double *ir = eyes->iris[j];
            double d = hypot(ir[0] - x->ic[e][0], ir[1] - x->ic[e][1]);
            if (d <= GS_XFER_IRIS_ANCHOR_MAX * ir[2] && d < dist[e])
                dist[e] = d, pick[e] = j;
        }
    if (pick[0] >= 0 && pick[0] == pick[1])
        pick[dist[0] <= dist[1] ? 1 : 0] = -1;
    for (int e = 0; e < 2; e++) {
        if (pick[e] < 0)
            continue;
        const double *ir = eyes->iris[pick[e]];
        double uv[2], X[3], sc = ir[2] / x->ic[e][2];
        x->pr[e] *= sc < 0.5 ? 0.5 : sc > 2.0 ? 2.0 : sc;
        proxy_iris_px(x, s, &cs, e, x->pr[e], uv, X);
        /* across the view at the iris's depth: it then shows at ir */
        double dc[3] = {(ir[0] - uv[0]) * X[2] / cs.fx,
                        (ir[1] - uv[1]) * X[2] / cs.fy, 0.0};
        gs_geom_mat3_tvec(s->head_R, dc, x->pd[e]);
        memcpy(x->ic[e], ir, sizeof x->ic[e]);
    }
}

/* The sclera's colour of each eye in the input (the fill's last resort,
 * the header): the mean of the open pixels of the given opening (>= 0.99)
 * between 1.15 and 4 iris radii from the eye's iris centre (the nearer
 * eye's) that are at least as bright as those pixels' mean grey (lashes
 * and lid shadow are darker). None for an eye with fewer than
 * GS_XFER_SCLERA_MIN of them. Kept while the input, the given opening and
 * the irises are the same. */
static void sclera_colours(gs_xfer *x)
{
    xfer_subj *u = &x->cur;
    if (u->scl_valid && u->scl_gen == u->ap_gen && !memcmp(u->scl_at, x->ic, sizeof u->scl_at))
        return;
    int S = x->S;
    double grey[2] = {0, 0};
    for (int pass = 0; pass < 2; pass++) {
        double sum[2][4] = {{0}};
        for (int y = 0; y < S; y++)
            for (int xx = 0; xx < S; xx++) {
                size_t i = (size_t)y * S + xx;
                if (u->src_ap[i] < 0.99f)
                    continue;
                double d0 = hypot(xx + 0.5 - x->ic[0][0], y + 0.5 - x->ic[0][1]);
                double d1 = hypot(xx + 0.5 - x->ic[1][0], y + 0.5 - x->ic[1][1]);
                int e = d0 <= d1 ? 0 : 1;
                double d = e ? d1 : d0, r = x->ic[e][2];
                if (d < GS_XFER_SCLERA_IN * r || d > GS_XFER_SCLERA_OUT * r)
                    continue;
                const uint8_t *p = u->in8 + 3 * i;
                double l = (p[0] + p[1] + p[2]) / 3.0;
                if (pass && l < grey[e])
                    continue;
                for (int k = 0; k < 3; k++)
                    sum[e][k] += p[k];
                sum[e][3] += 1.0;
                if (!pass)
                    grey[e] += l;
            }
        for (int e = 0; e < 2; e++) {
            if (!pass) {
                u->scl_ok[e] = sum[e][3] >= GS_XFER_SCLERA_MIN;
                grey[e] = u->scl_ok[e] ? grey[e] / sum[e][3] : 0.0;
                continue;
            }
            for (int k = 0; k < 3; k++) /* pass 1 has at least the brightest */
                u->scl[e][k] = u->scl_ok[e] ? (float)(sum[e][k] / sum[e][3]) : 0.0f;
        }
    }
    memcpy(u->scl_at, x->ic, sizeof u->scl_at);
    u->scl_gen = u->ap_gen;
    u->scl_valid = 1;
}

/* Whether pixel (u, v) (centres at +0.5) is nearer iris e's centre than
 * the other's. */
static int nearer_iris(const gs_xfer *x, int e, double u, double v)
{
    const double *a = x->ic[e], *b = x->ic[1 - e];
    return (u - a[0]) * (u - a[0]) + (v - a[1]) * (v - a[1]) <=
           (u - b[0]) * (u - b[0]) + (v - b[1]) * (v - b[1]);
}

/* This call's lids that follow the gaze (the header; g->lid): per eye the
 * given opening's upper and lower margins per column near its iris (where
 * the opening crosses 1/2, sub-pixel), the hinge across the columns that
 * have them, and the moves of the margins at the hinge's centre: the
 * iris's centre moves v_t - v_s in the input's view from the input's gaze
 * to the target's; the upper margin by follow times that, the lower by
 * GS_XFER_LID_LOWER of it, each held to 0.8 of the lid skin it pushes. */
static void lid_frame(const gs_model_ctx *c, gs_xfer *x, const gs_subject *s,
                      const xfer_geom *g)
{
    int S = x->S;
    const float *ap = x->cur.src_ap;
    gs_camera cs;
    image_camera(c, s->head_t, &cs);
    for (int e = 0; e < 2; e++) {
        x->lid[e].on = 0;
        memset(x->lid[e].box, 0, sizeof x->lid[e].box);
        if (!g->lid)
            continue;
        double r = x->ic[e][2];
        int u0 = (int)floor(x->ic[e][0] - GS_XFER_LID_REACH_U * r);
        int u1 = (int)ceil(x->ic[e][0] + GS_XFER_LID_REACH_U * r);
        int v0 = (int)floor(x->ic[e][1] - GS_XFER_LID_REACH_V * r);
        int v1 = (int)ceil(x->ic[e][1] + GS_XFER_LID_REACH_V * r);
        u0 = u0 < 0 ? 0 : u0, v0 = v0 < 0 ? 0 : v0;
        u1 = u1 > S ? S : u1, v1 = v1 > S ? S : v1;
        int c0 = S, c1 = -1;
        double lo = INFINITY, hi = -INFINITY;
        for (int u = 0; u < S; u++)
            x->lid[e].top[u] = x->lid[e].bot[u] = NAN;
        for (int u = u0; u < u1; u++) {
            int t = -1, b = -1;
            for (int v = v0; v < v1; v++)
                if (ap[(size_t)v * S + u] >= 0.5f && nearer_iris(x, e, u + 0.5, v + 0.5)) {
                    if (t < 0)
                        t = v;
                    b = v;
                }
            if (t < 0)
                continue;
            double top = t, bot = b + 1.0; /* pixel edges; sub-pixel below */
            if (t > v0 && ap[(size_t)(t - 1) * S + u] < 0.5f) {
                float a0 = ap[(size_t)(t - 1) * S + u], a1 = ap[(size_t)t * S + u];
                top = t - 0.5 + (0.5 - a0) / (a1 - a0);
            }
            if (b + 1 < v1 && ap[(size_t)(b + 1) * S + u] < 0.5f) {
                float a1 = ap[(size_t)b * S + u], a2 = ap[(size_t)(b + 1) * S + u];
                bot = b + 0.5 + (a1 - 0.5) / (a1 - a2);
            }
            x->lid[e].top[u] = (float)top;
            x->lid[e].bot[u] = (float)bot;
            x->lid[e].mu[u] = t > v0;  /* a margin inside the search */
            x->lid[e].ml[u] = b + 1 < v1;
            c0 = u < c0 ? u : c0, c1 = u > c1 ? u : c1;
            lo = top < lo ? top : lo, hi = bot > hi ? bot : hi;
        }
        if (c1 - c0 < 2)
            continue;
        double uv_s[2], uv_t[2], X[3];
        iris_view(x, s, &cs, e, x->pr[e], x->cur.src_Rg, x->pd[e], uv_s, X);
        iris_view(x, s, &cs, e, x->pr[e], x->tgt_Rg, x->pd[e], uv_t, X);
        double dv = uv_t[1] - uv_s[1];
        double hu = GS_XFER_LID_SKIN_UP * r, hl = GS_XFER_LID_SKIN_DOWN * r;
        double su = c->xfer_lid * dv, sl = GS_XFER_LID_LOWER * su;
        su = clamp_abs(su, 0.8 * hu);
        sl = clamp_abs(sl, 0.8 * hl);
        x->lid[e].on = 1;
        x->lid[e].uc = 0.5 * (c0 + c1 + 1);
        x->lid[e].hw = 0.5 * (c1 + 1 - c0);
        x->lid[e].su = su, x->lid[e].sl = sl;
        x->lid[e].hu = hu, x->lid[e].hl = hl;
        int *bx = x->lid[e].box;
        bx[0] = c0 - GS_XFER_LID_EDGE;
        bx[2] = c1 + 1 + GS_XFER_LID_EDGE;
        bx[1] = (int)floor(lo + (su < 0 ? su : 0) - hu) - GS_XFER_LID_EDGE;
        bx[3] = (int)ceil(hi + (sl > 0 ? sl : 0) + hl) + GS_XFER_LID_EDGE;
        bx[0] = bx[0] < 0 ? 0 : bx[0], bx[1] = bx[1] < 0 ? 0 : bx[1];
        bx[2] = bx[2] > S ? S : bx[2], bx[3] = bx[3] > S ? S : bx[3];
    }
}

/* Target pixel (px, py) under lids that follow the gaze (lid_frame): the
 * row *vs of the input it shows (the same column), the share *lw in
 * [0, 1] the lids' own pixels have there (1 inside their box, down to 0
 * over its edge) and, returned, the target's opening there: the given
 * opening at (u, vs). Outside every box: the pixel itself, share 0.
 * Above the upper margin the move falls off linearly over the lid skin
 * hu, below the lower over hl, between the margins it goes linearly
 * from one to the other; across, each is the hinge's share
 * 1 - ((u - uc) / hw)^2 of the move at its centre, so the corners stay. */
static float lid_at(const gs_xfer *x, int px, int py, double *vs, float *lw)
{
    int S = x->S, e = -1;
    double u = px + 0.5, v = py + 0.5;
    *vs = v;
    *lw = 0.0f;
    for (int k = 0; k < 2; k++) {
        const int *b = x->lid[k].box;
        if (x->lid[k].on && px >= b[0] && px < b[2] && py >= b[1] && py < b[3] &&
            (e < 0 || nearer_iris(x, k, u, v)))
            e = k;
    }
    if (e < 0)
        return x->cur.src_ap[(size_t)py * S + px];
    const int *b = x->lid[e].box;
    int m = px - b[0] + 1, t;
    t = b[2] - px, m = t < m ? t : m;
    t = py - b[1] + 1, m = t < m ? t : m;
    t = b[3] - py, m = t < m ? t : m;
    *lw = m >= GS_XFER_LID_EDGE ? 1.0f : (float)m / GS_XFER_LID_EDGE;
    double top = x->lid[e].top[px], bot = x->lid[e].bot[px];
    double q = (u - x->lid[e].uc) / x->lid[e].hw, a = 1.0 - q * q;
    if (a > 0.0 && !isnan(top)) {
        double su = x->lid[e].mu[px] ? a * x->lid[e].su : 0.0;
        double sl = x->lid[e].ml[px] ? a * x->lid[e].sl : 0.0;
        double h = bot - top, close = su - sl;
        if (close > (1.0 - GS_XFER_LID_KEEP) * h) { /* keep some opening */
            double k = (1.0 - GS_XFER_LID_KEEP) * h / close;
            su *= k, sl *= k;
        }
        double tt = top + su, bt = bot + sl, hu = x->lid[e].hu, hl = x->lid[e].hl, sh = 0.0;
        if (v > tt - hu && v <= tt)
            sh = su * (v - (tt - hu)) / hu;
        else if (v > tt && v < bt)
            sh = su + (sl - su) * (v - tt) / (bt - tt);
        else if (v >= bt && v < bt + hl)
            sh = sl * (1.0 - (v - bt) / hl);
        *vs = v - sh;
    }
    return bilinear(x->cur.src_ap, S, u, *vs);
}

static int check_eyes(const gs_xfer_eyes *eyes, gs_error *err)
{
    if (!eyes)
        return GS_OK;
    if (eyes->n_iris < 0 || eyes->n_iris > 2)
        return gs_error_set(err, GS_ERR_ARG, "transfer: %d irises given (0 to 2)",
                            eyes->n_iris);
    for (int j = 0; j < eyes->n_iris; j++) {
        const double *ir = eyes->iris[j];
        if (!isfinite(ir[0]) || !isfinite(ir[1]) || !isfinite(ir[2]) || !(ir[2] > 0))
            return gs_error_set(err, GS_ERR_ARG,
                                "transfer: iris %d is not a circle (centre %g, %g, "
                                "radius %g px)", j, ir[0], ir[1], ir[2]);
    }
    return GS_OK;
}

/* The subject's own view and its maps: rendered once per subject and
 * settings, kept for as many subjects as the sweep cache. */
static int own_view(gs_model_ctx *c, gs_xfer *x, gs_pool *pool,
                    const gs_subject *s, gs_error *err)
{
    if (subj_select(c, x, s))
        return gs_error_set(err, GS_ERR_NOMEM, "transfer: out of memory");
    if (x->cur.valid)
        return GS_OK;
    int S = x->S;
    gs_view own = {s->gaze_pitch, s->gaze_yaw, 0, {0}, {0}, 0};
    gs_camera cs;
    image_camera(c, s->head_t, &cs);
    int rc = gs_model_render(c, pool, s, &own, x->cur.src8, 3 * (size_t)S, err);
    if (!rc)
        rc = aux_maps(c, x, pool, &cs, x->cur.src_z, x->cur.src_a, x->cur.src_e, err);
    if (rc)
        return rc;
    memcpy(x->cur.src_eR, c->eye_R, sizeof x->cur.src_eR);
    memcpy(x->cur.src_Rg, c->eye_Rg, sizeof x->cur.src_Rg);
    memcpy(x->cur.src_ec, c->eye_c, sizeof x->cur.src_ec);
    proxy_radii(c, x->cur.src_er);
    x->cur.key = *s;
    x->cur.key_fs = c->render_fs;
    x->cur.key_full = c->render_full;
    x->cur.valid = 1;
    return GS_OK;
}

/* Residual of the input against its own view, planar, 8-bit units; kept
 * while the input is the same bytes. Returns whether it was kept. */
static int residual(gs_xfer *x, const uint8_t *input, size_t in_stride)
{
    int S = x->S, same = x->cur.res_valid;
    size_t px = (size_t)S * S, row = 3 * (size_t)S;
    for (int y = 0; y < S && same; y++)
        same = !memcmp(x->cur.in8 + y * row, input + y * in_stride, row);
    if (same)
        return 1;
    for (int y = 0; y < S; y++)
        memcpy(x->cur.in8 + y * row, input + y * in_stride, row);
    for (int k = 0; k < 3; k++)
        for (size_t i = 0; i < px; i++)
            x->cur.res[k * px + i] = (float)x->cur.in8[3 * i + k] -
                                 (float)x->cur.src8[3 * i + k];
    x->cur.res_valid = 1;
    x->cur.smooth_valid = 0;
    x->cur.scl_valid = 0;
    return 0;
}

/* One pass of a 1D filter w[0..2r] over an S x S plane, edges clamped:
 * along rows (step 1) or columns (step S). */
static void filter_pass(const float *in, float *out, int S, const float *w,
                        int r, int step)
{
    int along_rows = step == 1;
    for (int y = 0; y < S; y++)
        for (int c = 0; c < S; c++) {
            int at = along_rows ? c : y;
            const float *base = in + (along_rows ? (size_t)y * S : (size_t)c);
            float v = 0.0f;
            for (int j = -r; j <= r; j++) {
                int q = at + j < 0 ? 0 : at + j >= S ? S - 1 : at + j;
                v += w[j + r] * base[(size_t)q * step];
            }
            out[(size_t)y * S + c] = v;
        }
}

/* res smoothed by a Gaussian of sigma GS_XFER_HEAD_SIGMA (scaled to the
 * image size), separable, edges clamped; once per input. */
static int smooth_residual(gs_xfer *x)
{
    if (x->cur.smooth_valid)
        return GS_OK;
    int S = x->S;
    size_t px = (size_t)S * S;
    double sg = GS_XFER_HEAD_SIGMA * S / 256.0;
    int r = (int)ceil(3.0 * sg);
    float *w = malloc((size_t)(2 * r + 1) * sizeof(float));
    float *tmp = malloc(px * sizeof(float));
    if (!w || !tmp) {
        free(w);
        free(tmp);
        return GS_ERR_NOMEM;
    }
    double sum = 0;
    for (int j = -r; j <= r; j++)
        sum += w[j + r] = (float)exp(-0.5 * j * j / (sg * sg));
    for (int j = 0; j <= 2 * r; j++)
        w[j] = (float)(w[j] / sum);
    for (int k = 0; k < 3; k++) {
        filter_pass(x->cur.res + k * px, tmp, S, w, r, 1);
        filter_pass(tmp, x->cur.res_smooth + k * px, S, w, r, S);
    }
    free(w);
    free(tmp);
    x->cur.smooth_valid = 1;
    return GS_OK;
}

/* The residual carried to target pixel (px, py): from where the input
 * shows its head point (weight 1 - b) and its eyeball point (weight b);
 * at another head pose the smoothed skin residual alone, times head_w. */
static void warp_pixel(gs_xfer *x, const xfer_geom *g, int px, int py)
{
    size_t n = (size_t)x->S * x->S, i = (size_t)py * x->S + px;
    float b = GS_XFER_EYE_GAIN * x->cur.tgt_e[i];
    b = b > 1.0f ? 1.0f : b;
    double uh = 0, vh = 0, ue = 0, ve = 0, h[3];
    float wh = 0.0f, we = 0.0f;
    const float *res = g->same_pose ? x->cur.res : x->cur.res_smooth;
    if (g->same_pose || g->head_w > 0.0f) {
        target_point(x, g, px, py, h);
        if (b < 1.0f)
            wh = (1.0f - b) * head_source(x, g, px, py, h, b, &uh, &vh);
        if (b > 0.0f && g->same_pose)
            we = b * eye_source(x, g, h, b, &ue, &ve);
        if (!g->same_pose)
            wh *= g->head_w;
    }
    /* the eyeball warp, inside the eye stream's tiles (redone with them in
     * a sweep) and the opening */
    const int *tr = x->cur.tgt_rect;
    double uw = 0, vw = 0;
    float ww = 0.0f, src[3] = {0, 0, 0};
    const float *ap = g->same_pose ? x->cur.src_ap : x->cur.tgt_ap;
    /* lids that follow the gaze: the target's opening, and the share the
     * lids' own pixels (input(u, vl)) take where it is shut */
    float apt = 0.0f, lw = 0.0f, wl = 0.0f;
    double vl = py + 0.5;
    if (g->lid) {
        apt = lid_at(x, px, py, &vl, &lw);
        wl = (1.0f - apt) * lw;
    } else if (g->warp_w > 0.0f) {
        apt = ap[i];
    }
    if (g->warp_w > 0.0f && apt > 0.0f &&
        px >= tr[0] && px < tr[2] && py >= tr[1] && py < tr[3]) {
        int e, on_iris;
        float aq, wq = warp_source(x, g, px, py, &uw, &vw, &e, &aq, &on_iris);
        ww = apt * wq;
        /* hidden in the input: mirrored about its iris's row, then, on the
         * sclera, the sclera's colour (the fill) */
        float m = 0.0f, ms = 0.0f;
        double vm = 0.0;
        if (g->fill && aq >= 0.0f && aq < 1.0f) {
            vm = 2.0 * x->ic[e][1] - vw;
            if (vm >= 0 && vm <= x->S)
                m = (1.0f - aq) * bilinear(x->cur.src_ap, x->S, uw, vm);
            if (!on_iris && x->cur.scl_ok[e])
                ms = 1.0f - aq - m;
        }
        if (m > 0.0f || ms > 0.0f)
            ww = apt * (g->warp_w * (aq + m + ms));
        if (ww > 0.0f)
            bilinear_rgb8(x->cur.in8, x->S, uw, vw, src);
        if (ww > 0.0f && (m > 0.0f || ms > 0.0f)) {
            float sm[3] = {0, 0, 0};
            if (m > 0.0f)
                bilinear_rgb8(x->cur.in8, x->S, uw, vm, sm);
            for (int k = 0; k < 3; k++)
                src[k] = (aq * src[k] + m * sm[k] + ms * x->cur.scl[e][k]) / (aq + m + ms);
        }
    }
    wh *= 1.0f - ww - wl;
    we *= 1.0f - ww - wl;
    float lid[3] = {0, 0, 0};
    if (wl > 0.0f)
        bilinear_rgb8(x->cur.in8, x->S, px + 0.5, vl, lid);
    for (int k = 0; k < 3; k++) {
        const float *rk = res + k * n;
        float v = 0.0f;
        if (wh > 0.0f)
            v += wh * bilinear(rk, x->S, uh, vh);
        if (we > 0.0f)
            v += we * bilinear(rk, x->S, ue, ve);
        if (ww > 0.0f)
            v += ww * (src[k] - (float)x->tgt8[3 * i + k]);
        if (wl > 0.0f)
            v += wl * (lid[k] - (float)x->tgt8[3 * i + k]);
        x->cur.warped[k * n + i] = v;
    }
}

/* lrintf(v) for v in [0, 255] in the default rounding mode (to nearest,
 * ties to even) without a library call per value: v + 1.5 2^23 has no
 * fraction bits left. */
static uint8_t round_byte(float v)
{
    return (uint8_t)(int)((v + 0x1.8p23f) - 0x1.8p23f);
}

/* Row y of the output: the target render plus the warped residual,
 * rounded to 8 bits. */
static void compose_row(const gs_xfer *x, int y, uint8_t *o)
{
    int S = x->S;
    size_t px = (size_t)S * S;
    const uint8_t *t = x->tgt8 + (size_t)y * 3 * S;
    for (int xx = 0; xx < S; xx++) {
        size_t i = (size_t)y * S + xx;
        for (int k = 0; k < 3; k++) {
            float v = (float)t[3 * xx + k] + x->cur.warped[k * px + i];
            v = v < 0 ? 0 : v > 255 ? 255 : v;
            o[3 * xx + k] = round_byte(v);
        }
    }
}

/* The output in bands of rows, each warped over its part of the box d
 * first; a pixel depends on nothing another band writes. */
typedef struct {
    gs_xfer *x;
    const xfer_geom *g;
    const int *d;
    uint8_t *rgb;
    size_t stride;
} xfer_bands;

enum { XFER_BAND_ROWS = 8 };

static void band_task(void *ctx, int task, int worker)
{
    const xfer_bands *b = ctx;
    int S = b->x->S, y1 = (task + 1) * XFER_BAND_ROWS;
    (void)worker;
    for (int y = task * XFER_BAND_ROWS; y < y1 && y < S; y++) {
        if (y >= b->d[1] && y < b->d[3])
            for (int xx = b->d[0]; xx < b->d[2]; xx++)
                warp_pixel(b->x, b->g, xx, y);
        compose_row(b->x, y, b->rgb + (size_t)y * b->stride);
    }
}

int gs_model_render_transfer(gs_model_ctx *c, gs_pool *pool,
                             const gs_subject *s, const uint8_t *input,
                             size_t in_stride, const gs_view *view,
                             uint8_t *rgb, size_t stride, gs_error *err)
{
    return gs_model_render_transfer_eyes(c, pool, s, input, in_stride, NULL,
                                         view, rgb, stride, err);
}

int gs_model_render_transfer_eyes(gs_model_ctx *c, gs_pool *pool,
                                  const gs_subject *s, const uint8_t *input,
                                  size_t in_stride, const gs_xfer_eyes *eyes,
                                  const gs_view *view, uint8_t *rgb,
                                  size_t stride, gs_error *err)
{
    if (!c || !s || !view)
        return gs_error_set(err, GS_ERR_ARG, "transfer: NULL argument");
    int S = c->S, rc;
    if ((rc = check_image(input, in_stride, S, "input", err)) ||
        (rc = check_image(rgb, stride, S, "output", err)) ||
        (rc = check_eyes(eyes, err)))
        return rc;
    const uint8_t *opening = eyes ? eyes->opening : NULL;
    if (c->ne == 0)
        return gs_error_set(err, GS_ERR_ARG,
                            "transfer: the model has no eye stream (the "
                            "eyeball mask comes from it)");
    gs_xfer *x = xfer_get(c);
    if (!x)
        return gs_error_set(err, GS_ERR_NOMEM, "transfer: out of memory");
    const double *Rs = s->head_R, *ts = s->head_t;
    const double *Rt = view->use_head ? view->head_R : s->head_R;
    const double *tt = view->use_head ? view->head_t : s->head_t;
    c->last_xfer_inc = 0;
    if ((rc = own_view(c, x, pool, s, err)))
        return rc;
    int same_pose = !memcmp(Rs, Rt, 9 * sizeof(double)) &&
                    !memcmp(ts, tt, 3 * sizeof(double));
    if (warp_on(c, same_pose) && (rc = eye_opening(c, x, pool, s, opening, err)))
        return rc;
    eye_anchor(c, x, s, eyes, same_pose);
    if (warp_on(c, same_pose) && !same_pose &&
        (rc = target_opening(c, x, pool, s, view, Rt, tt, err)))
        return rc;
    /* only the gaze changed since the kept target: the face is the same */
    int keep = x->cur.tgt_valid && !memcmp(x->cur.tgt_R, Rt, sizeof x->cur.tgt_R) &&
               !memcmp(x->cur.tgt_t, tt, sizeof x->cur.tgt_t);
    x->cur.tgt_valid = 0; /* until this target is complete */
    gs_camera ct;
    image_camera(c, tt, &ct);
    int d[4];
    rc = gs_model_render(c, pool, s, view, x->tgt8, 3 * (size_t)S, err);
    if (!rc)
        rc = target_maps(c, x, pool, &ct, keep, d, err);
    if (rc)
        return rc;
    if (!residual(x, input, in_stride)) /* a new input: warp everything */
        d[0] = d[1] = 0, d[2] = d[3] = S;

    /* Outside d the maps are the kept target's, with no eye coverage at
     * either gaze (b = 0): head_source depends on the head poses and those
     * maps only, so the kept warped residual stands there. */
    xfer_geom g;
    geom_init(c, x, &g, Rs, ts, Rt, tt, same_pose);
    if (g.fill)
        sclera_colours(x);
    /* the lids move with the gaze: their boxes, now and at the kept
     * target, are redone with the eye stream's tiles */
    lid_frame(c, x, s, &g);
    int lids[4] = {0, 0, 0, 0};
    for (int e = 0; e < 2; e++)
        gs_frame_box_union(lids, x->lid[e].box);
    if (keep) {
        gs_frame_box_union(d, lids);
        gs_frame_box_union(d, x->cur.lid_rect);
    }
    memcpy(x->cur.lid_rect, lids, sizeof lids);
    g.head_w = c->xfer_head_w;
    if (!g.same_pose && g.head_w > 0.0f && smooth_residual(x))
        return gs_error_set(err, GS_ERR_NOMEM, "transfer: out of memory");
    xfer_bands b = {x, &g, d, rgb, stride};
    gs_pool_for(pool, (S + XFER_BAND_ROWS - 1) / XFER_BAND_ROWS, band_task,
                &b);

    memcpy(x->cur.tgt_R, Rt, sizeof x->cur.tgt_R);
    memcpy(x->cur.tgt_t, tt, sizeof x->cur.tgt_t);
    x->cur.tgt_valid = 1;
    c->last_xfer_inc = keep;
    c->n_xfer_inc += (uint64_t)keep;
    c->n_xfer_full += (uint64_t)!keep;
    c->xfer_px += keep ? (double)(d[2] - d[0]) * (d[3] - d[1]) : 0.0;
    return GS_OK;
}
