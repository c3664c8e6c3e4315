/* The parametric head: building primitives from identity + expression +
 * gaze, and the signed distance field of the head surface.
 *
 * The surface is a smooth union of ellipsoids and capsules (cranium,
 * maxilla, jaw, chin, brow ridge, cheekbones, cheeks, nose, lips, ears,
 * neck, hair cap) with smooth subtractions (eye sockets, nostrils, mouth
 * cavity), plus one eyelid shell per eye, and finally a hard carve of a
 * thin gap around each eyeball so that nothing of the head ever enters an
 * eyeball, whatever the blend radii do.
 *
 * Build frame: millimetres, head axes, roughly centred at the face centre;
 * the final head frame subtracts the exact face centre of the identity's
 * neutral face (see gs_synth_head_build). */
#include <string.h>

#include "sdf_ops.h"

static const float DEG = 0.017453292519943295f;

/* Blend radii (mm) of the smooth unions; constants so that the compiler
 * folds the divisions of op_smin. */
#define K_FACE 14.0f
#define K_NOSE 5.0f
#define K_LIP 4.0f
#define K_CHEEK 12.0f
#define K_LID 2.5f

/* ---- building ---- */

typedef struct build_ctx {
    float sc;  /* overall scale */
    v3 off;    /* subtracted after scaling */
    const double *kappa; /* NULL, or the identity's (h, v) kappa, radians */
} build_ctx;

static v3 at(const build_ctx *b, float x, float y, float z)
{
    return v3_sub(v3_make(x * b->sc, y * b->sc, z * b->sc), b->off);
}

static void ell_update(sd_ell *e)
{
    e->ir = v3_make(1.0f / e->r.x, 1.0f / e->r.y, 1.0f / e->r.z);
    e->ir2 = v3_mul(e->ir, e->ir);
    e->rmax = maxf(e->r.x, maxf(e->r.y, e->r.z));
}

static sd_ell ell(const build_ctx *b, v3 c, float rx, float ry, float rz)
{
    sd_ell e;
    e.c = c;
    e.r = v3_make(rx * b->sc, ry * b->sc, rz * b->sc);
    ell_update(&e);
    return e;
}

/* sRGB component to linear. */
static float lin(float s)
{
    return s <= 0.04045f ? s / 12.92f : powf((s + 0.055f) / 1.055f, 2.4f);
}

static v3 srgb(float r, float g, float b)
{
    return v3_make(lin(r / 255.0f), lin(g / 255.0f), lin(b / 255.0f));
}

/* Piecewise-linear colour ramp over t in [0, 1]. */
static v3 ramp(const v3 *c, int n, float t)
{
    t = clampf(t, 0.0f, 1.0f) * (float)(n - 1);
    int i = (int)t;
    if (i >= n - 1)
        return c[n - 1];
    return v3_lerp(c[i], c[i + 1], t - (float)i);
}

static float rmax(const sd_ell *e)
{
    return e->rmax;
}

/* The lid opening: the wedge between the margins at angles th_u (upper)
 * and th_l (lower) about the lid axis, measured from the eye's front
 * (-z made normal to the axis) toward up (-y). */
static void set_lid_wedge(eye_model *e, float th_u, float th_l)
{
    v3 u = e->lid_x;
    v3 f0 = v3_make(0, 0, -1);
    f0 = v3_norm(v3_sub(f0, v3_scale(u, v3_dot(u, f0))));
    v3 up0 = v3_make(0, -1, 0);
    up0 = v3_sub(up0, v3_scale(u, v3_dot(u, up0)));
    up0 = v3_norm(v3_sub(up0, v3_scale(f0, v3_dot(f0, up0))));
    e->up_dir = v3_add(v3_scale(f0, cosf(th_u)), v3_scale(up0, sinf(th_u)));
    e->lo_dir = v3_add(v3_scale(f0, cosf(th_l)), v3_scale(up0, sinf(th_l)));
    e->n_up = v3_add(v3_scale(f0, -sinf(th_u)), v3_scale(up0, cosf(th_u)));
    e->n_lo = v3_add(v3_scale(f0, sinf(th_l)), v3_scale(up0, -cosf(th_l)));
}

static void build_eye(const build_ctx *b, const float *p,
                      const gs_synth_expression *ex, double gp, double gy,
                      int side, eye_model *e)
{
    float s = side == 0 ? -1.0f : 1.0f;
    float half_ipd = 0.5f * (63.0f + 4.0f * p[GS_SYNTH_ID_EYE_SPACING]);
    e->side = side;
    e->c = at(b, s * half_ipd, -24.0f + 2.5f * p[GS_SYNTH_ID_EYE_HEIGHT],
              6.0f + 2.0f * p[GS_SYNTH_ID_EYE_DEPTH]);
    e->r_sclera = b->sc * (12.0f + 0.5f * p[GS_SYNTH_ID_EYEBALL_SIZE]);
    e->r_cornea = 7.8f / 12.0f * e->r_sclera;
    e->iris_r = b->sc * (6.0f + 0.3f * p[GS_SYNTH_ID_IRIS_SIZE]);
    float limbus = sqrtf(e->r_sclera * e->r_sclera - e->iris_r * e->iris_r);
    e->cornea_off =
        limbus - sqrtf(e->r_cornea * e->r_cornea - e->iris_r * e->iris_r);
    e->iris_d = limbus - 0.35f;
    float pupil = 2.0f + 0.5f * p[GS_SYNTH_ID_PUPIL_SIZE] + 1.2f * ex->pupil;
    e->pupil_r = clampf(pupil, 1.0f, 3.5f) * b->sc;
    /* Optical axis: the eye rotation maps -z to the gaze vector (the
     * visual axis), turned by the identity's kappa when it has one. */
    double r[9], mz[3] = {0, 0, -1}, a[3];
    gs_geom_rot_from_pitchyaw(gp, gy, 0.0, r);
    if (b->kappa) {
        /* The gaze is the visual axis; the eyeball turns by kappa more. */
        double k[9];
        gs_synth_kappa_rotation(side, b->kappa[0], b->kappa[1], k);
        gs_geom_mat3_mul(r, k, r);
    }
    gs_geom_mat3_vec(r, mz, a);
    e->axis = v3_make((float)a[0], (float)a[1], (float)a[2]);
    e->cornea_c = v3_add(e->c, v3_scale(e->axis, e->cornea_off));
    e->iris_c = v3_add(e->c, v3_scale(e->axis, e->iris_d));
    /* Iris texture axes follow the eye (columns 0 and 1 of r: the eye's
     * own x and y), so the pattern turns with the eyeball. */
    e->iris_u = v3_make((float)r[0], (float)r[3], (float)r[6]);
    e->iris_v = v3_make((float)r[1], (float)r[4], (float)r[7]);
    e->bound_r = maxf(e->r_sclera, e->cornea_off + e->r_cornea);
    /* Lids. */
    e->lid_gap = 0.25f * b->sc;
    e->lid_thick = 2.2f * b->sc;
    e->lid_bound_r = e->bound_r + e->lid_gap + e->lid_thick;
    float yawc = 14.0f * DEG;
    float tilt = (6.0f + 4.0f * p[GS_SYNTH_ID_CANTHAL_TILT]) * DEG;
    /* u: from the inner toward the outer corner (outer = lateral, higher,
     * further back). */
    v3 u = v3_norm(v3_make(s * cosf(yawc) * cosf(tilt), -sinf(tilt),
                           sinf(yawc) * cosf(tilt)));
    e->lid_x = u;
    float open = p[GS_SYNTH_ID_EYE_OPENING];
    float th_u = (22.0f + 4.0f * open) * DEG + 0.85f * (float)gp -
                 10.0f * DEG * ex->squint;
    float th_l = -(17.0f + 3.0f * open) * DEG + 0.3f * (float)gp +
                 8.0f * DEG * ex->squint;
    th_u = mixf(th_u, th_l - 1.0f * DEG, clampf(ex->blink, 0.0f, 1.0f));
    set_lid_wedge(e, th_u, th_l);
}

static void build_appearance(const gs_synth_identity *id, head_model *h)
{
    const float *p = id->p;
    v3 skin_ramp[4] = {srgb(240, 208, 188), srgb(214, 168, 136),
                       srgb(160, 112, 80), srgb(92, 60, 44)};
    float tone = 0.5f + 0.5f * p[GS_SYNTH_ID_SKIN_TONE];
    v3 skin = ramp(skin_ramp, 4, tone);
    float warm = 0.06f * p[GS_SYNTH_ID_SKIN_WARMTH];
    h->skin = v3_make(skin.x * (1 + warm), skin.y, skin.z * (1 - 1.5f * warm));
    float lr = 0.5f + 0.5f * p[GS_SYNTH_ID_LIP_COLOUR];
    h->lip_col = v3_mul(h->skin, v3_make(0.95f, mixf(0.62f, 0.45f, lr),
                                         mixf(0.65f, 0.5f, lr)));
    h->mouth_col = srgb(70, 22, 24);
    v3 hair_ramp[5] = {srgb(20, 16, 14), srgb(55, 36, 24), srgb(110, 75, 45),
                       srgb(170, 130, 80), srgb(215, 190, 140)};
    v3 hair = ramp(hair_ramp, 5, 0.5f + 0.5f * p[GS_SYNTH_ID_HAIR_COLOUR]);
    float red = 0.25f * maxf(0.0f, p[GS_SYNTH_ID_HAIR_RED]);
    h->hair_col = v3_make(hair.x * (1 + red), hair.y, hair.z * (1 - red));
    h->brow_col = v3_scale(h->hair_col, 0.55f);
    v3 iris_ramp[6] = {srgb(45, 28, 18),  srgb(95, 60, 30),
                       srgb(120, 100, 50), srgb(80, 110, 70),
                       srgb(70, 110, 150), srgb(130, 145, 155)};
    v3 iris = ramp(iris_ramp, 6, 0.5f + 0.5f * p[GS_SYNTH_ID_IRIS_HUE]);
    iris = v3_scale(iris, 1.0f + 0.35f * p[GS_SYNTH_ID_IRIS_BRIGHTNESS]);
    h->iris_a = iris;
    h->iris_b = v3_scale(iris, 0.45f);
    float st = 0.5f + 0.5f * p[GS_SYNTH_ID_SCLERA_TINT];
    h->sclera = v3_lerp(srgb(238, 236, 230), srgb(232, 218, 200), st);
    h->skin_tex = 0.07f + 0.05f * p[GS_SYNTH_ID_SKIN_TEXTURE];
    h->shine = 0.06f + 0.04f * p[GS_SYNTH_ID_SKIN_SHINE];
    h->freckles = maxf(0.0f, p[GS_SYNTH_ID_FRECKLES] - 0.3f);
    h->blush = 0.1f + 0.08f * p[GS_SYNTH_ID_CHEEK_BLUSH];
    h->lash = 0.75f + 0.2f * p[GS_SYNTH_ID_LASH_DARKNESS];
    h->iris_pattern = 0.5f + 0.3f * p[GS_SYNTH_ID_IRIS_PATTERN];
    h->tex_seed = (uint32_t)(id->seed ^ (id->seed >> 32)) * 2654435761u;
}

static box3 box_empty(void)
{
    box3 b = {v3_make(1e30f, 1e30f, 1e30f), v3_make(-1e30f, -1e30f, -1e30f)};
    return b;
}

static void box_add(box3 *b, v3 c, v3 r)
{
    b->lo = v3_make(minf(b->lo.x, c.x - r.x), minf(b->lo.y, c.y - r.y),
                    minf(b->lo.z, c.z - r.z));
    b->hi = v3_make(maxf(b->hi.x, c.x + r.x), maxf(b->hi.y, c.y + r.y),
                    maxf(b->hi.z, c.z + r.z));
}

static void box_add_ell(box3 *b, const sd_ell *e)
{
    box_add(b, e->c, e->r);
}

static void box_add_capsule(box3 *b, const sd_capsule *c)
{
    float r = maxf(c->ra, c->rb);
    box_add(b, c->a, v3_make(r, r, r));
    box_add(b, c->b, v3_make(r, r, r));
}

static void box_grow(box3 *b, float m)
{
    b->lo = v3_sub(b->lo, v3_make(m, m, m));
    b->hi = v3_add(b->hi, v3_make(m, m, m));
}

/* Boxes of the part groups used by the field to skip far groups. */
static void compute_group_boxes(head_model *h)
{
    h->jaw_box = box_empty();
    box_add_ell(&h->jaw_box, &h->jaw);
    box_add_ell(&h->jaw_box, &h->chin);
    for (int i = 0; i < 2; i++)
        box_add_capsule(&h->jaw_box, &h->jawbone[i]);
    h->mid_box = box_empty();
    box_add_ell(&h->mid_box, &h->brow);
    h->socket_box = box_empty();
    h->nose_box = box_empty();
    box_add_capsule(&h->nose_box, &h->bridge);
    box_add_ell(&h->nose_box, &h->nose_tip);
    h->eyes_box = box_empty();
    for (int i = 0; i < 2; i++) {
        box_add_ell(&h->mid_box, &h->zyg[i]);
        box_add_ell(&h->mid_box, &h->cheek[i]);
        box_add_ell(&h->socket_box, &h->socket[i]);
        box_add_ell(&h->nose_box, &h->nose_wing[i]);
        box_add_ell(&h->nose_box, &h->nostril[i]);
        float r = h->eye[i].lid_bound_r;
        box_add(&h->eyes_box, h->eye[i].c, v3_make(r, r, r));
    }
    /* Lips move with the smile warp and the jaw: grow their box by the
     * largest displacement either can cause. */
    h->mouth_box = box_empty();
    box_add_ell(&h->mouth_box, &h->lip_up);
    box_add_ell(&h->mouth_box, &h->lip_lo);
    box_grow(&h->mouth_box, 3.0f + 12.0f * h->smile + 25.0f * h->mouth_open);
    if (h->mouth_open > 0.02f)
        box_add_ell(&h->mouth_box, &h->cavity);
}

/* Skull, maxilla, jaw, chin, brow ridge, cheekbones and cheeks. */
static void build_skull_face(const build_ctx *b, const float *p, float smile,
                             head_model *h)
{
    float hw = 1.0f + 0.06f * p[GS_SYNTH_ID_HEAD_WIDTH];
    float hl = 1.0f + 0.05f * p[GS_SYNTH_ID_HEAD_LENGTH];
    float hh = 1.0f + 0.05f * p[GS_SYNTH_ID_HEAD_HEIGHT];
    float fl = 1.0f + 0.07f * p[GS_SYNTH_ID_FACE_LENGTH];
    float fw = 1.0f + 0.06f * p[GS_SYNTH_ID_FACE_WIDTH];
    float fs = p[GS_SYNTH_ID_FOREHEAD_SLOPE], br = p[GS_SYNTH_ID_BROW_RIDGE];
    float jw = 1.0f + 0.08f * p[GS_SYNTH_ID_JAW_WIDTH];
    float cp = p[GS_SYNTH_ID_CHIN_PROJECTION], ch = p[GS_SYNTH_ID_CHIN_HEIGHT];
    float cb = p[GS_SYNTH_ID_CHEEKBONES], cf = p[GS_SYNTH_ID_CHEEK_FULLNESS];
    h->cranium = ell(b, at(b, 0, -40 - 4 * p[GS_SYNTH_ID_HEAD_HEIGHT], 70 + 4 * fs),
                     74 * hw, 95 * hh, 88 * hl);
    h->face = ell(b, at(b, 0, 8 * fl, 20), 64 * fw, 50 * fl, 38);
    h->jaw = ell(b, at(b, 0, 50 * fl, 22), 42 * jw, 34 * fl, 34);
    h->chin = ell(b, at(b, 0, 76 * fl + 3 * ch, -1 - 3 * cp), 23 * jw,
                  16 * (1 + 0.1f * ch), 13);
    h->brow = ell(b, at(b, 0, -44, -3 - 2 * br), 52, 10, 13 * (1 + 0.12f * br));
    for (int i = 0; i < 2; i++) {
        float s = i == 0 ? -1.0f : 1.0f;
        h->jawbone[i].a = at(b, s * 50 * jw, 38 * fl, 50);
        h->jawbone[i].b = at(b, s * 15 * jw, 80 * fl + 3 * ch, -3 - 2 * cp);
        h->jawbone[i].ra = 9.0f * b->sc;
        h->jawbone[i].rb = 11.0f * b->sc;
        h->zyg[i] = ell(b, at(b, s * 54 * fw * (1 + 0.05f * cb), -8, 16 - 2 * cb),
                        16, 12, 15);
        /* A smile lifts the cheeks and pushes them out and forward. */
        h->cheek[i] = ell(b, at(b, s * (40 * fw + 2 * smile), 12 - 4 * smile,
                                8 - 2 * cf - 2 * smile),
                          22, 20, 12 + 2 * cf);
    }
    h->ear_x = 72.0f * hw;
}

static void build_nose(const build_ctx *b, const float *p, head_model *h)
{
    float nl = 1.0f + 0.1f * p[GS_SYNTH_ID_NOSE_LENGTH];
    float np = p[GS_SYNTH_ID_NOSE_PROJECTION], nb = p[GS_SYNTH_ID_NOSE_BRIDGE];
    float nw = 1.0f + 0.12f * p[GS_SYNTH_ID_NOSE_WIDTH];
    float nt = 1.0f + 0.1f * p[GS_SYNTH_ID_NOSE_TIP];
    h->bridge.a = at(b, 0, -28, -11 - 2 * nb);
    h->bridge.b = at(b, 0, -28 + 40 * nl, -27 - 3 * np);
    h->bridge.ra = 5.0f * b->sc;
    h->bridge.rb = 6.5f * nt * b->sc;
    h->nose_tip = ell(b, at(b, 0, -28 + 42 * nl, -24 - 3 * np), 9 * nw * nt, 8, 8);
    for (int i = 0; i < 2; i++) {
        float s = i == 0 ? -1.0f : 1.0f;
        h->nose_wing[i] = ell(b, at(b, s * 12 * nw, -28 + 47 * nl, -11 - np), 7, 6, 8);
        h->nostril[i] = ell(b, at(b, s * 6 * nw, -28 + 50 * nl, -19 - 2 * np),
                            3.5f, 2.2f, 5);
    }
}

/* Lips, the mouth cavity (when open) and the jaw rotation, which opens
 * about a transverse axis near the ears by up to 0.25 rad. */
static void build_mouth(const build_ctx *b, const float *p,
                        const gs_synth_expression *ex, head_model *h)
{
    float fl = 1.0f + 0.07f * p[GS_SYNTH_ID_FACE_LENGTH];
    float mw = 1.0f + 0.1f * p[GS_SYNTH_ID_MOUTH_WIDTH];
    float ul = 1.0f + 0.2f * p[GS_SYNTH_ID_UPPER_LIP];
    float ll = 1.0f + 0.2f * p[GS_SYNTH_ID_LOWER_LIP];
    float my = 44 * fl + 3 * p[GS_SYNTH_ID_MOUTH_HEIGHT];
    float open = clampf(ex->mouth_open, 0.0f, 1.0f);
    h->mouth_open = open;
    h->smile = clampf(ex->smile, 0.0f, 1.0f);
    h->mouth_w = 24 * mw * b->sc;
    h->mouth_y = at(b, 0, my, 0).y;
    h->lip_up = ell(b, at(b, 0, my - 4.2f * ul, -13.5f), 23 * mw, 4.6f * ul, 7);
    h->lip_lo = ell(b, at(b, 0, my + 4.8f * ll, -12), 20 * mw, 5.0f * ll, 7);
    h->cavity = ell(b, at(b, 0, my + 1 + 3 * open, -3), 19 * mw, 0.2f + 8 * open, 14);
    h->jaw_pivot = at(b, 0, -5, 60);
    double jr[9];
    gs_geom_rot_x(-0.25 * open, jr); /* head -> closed-jaw frame: back up */
    for (int i = 0; i < 9; i++)
        h->jaw_rot[i] = (float)jr[i];
}

/* Ears, the neck (cut flat 150 mm below the face centre) and the hair cap
 * (the cranium grown by the hair thickness, behind the hairline). */
static void build_ears_neck_hair(const build_ctx *b, const float *p,
                                 head_model *h)
{
    h->has_ears = 1;
    float es = 1.0f + 0.12f * p[GS_SYNTH_ID_EAR_SIZE];
    float ep = p[GS_SYNTH_ID_EAR_PROTRUSION];
    for (int i = 0; i < 2; i++) {
        float s = i == 0 ? -1.0f : 1.0f;
        h->ear[i] = ell(b, at(b, s * (h->ear_x + 3 * ep), -18, 60), 6, 28 * es,
                        16 * es);
    }
    float nk = 1.0f + 0.08f * p[GS_SYNTH_ID_NECK_WIDTH];
    h->neck_r[0] = 47 * nk * b->sc;
    h->neck_r[1] = 44 * nk * b->sc;
    v3 nc = at(b, 0, 30, 55);
    h->neck_c[0] = nc.x;
    h->neck_c[1] = nc.y;
    h->neck_c[2] = nc.z;
    h->neck_y0 = nc.y;
    h->neck_cut_y = at(b, 0, 150, 0).y;
    float ha = p[GS_SYNTH_ID_HAIR_AMOUNT];
    h->has_hair = ha > -0.7f;
    h->hair = h->cranium;
    float thick = (6.0f + 4.0f * ha) * b->sc;
    h->hair.r = v3_add(h->hair.r, v3_make(thick, thick, thick));
    h->hair.c = v3_add(h->hair.c, v3_make(0, -0.5f * thick, 0));
    ell_update(&h->hair);
    /* The hairline plane holds the x-axis, the front hairline and the nape;
     * its normal points to the face side. */
    v3 hf = at(b, 0, -96 - 10 * p[GS_SYNTH_ID_HAIRLINE], -12);
    v3 dir = v3_sub(at(b, 0, 35, 150), hf);
    v3 n = v3_norm(v3_make(0, dir.z, -dir.y));
    if (v3_dot(n, v3_sub(at(b, 0, 0, -20), hf)) < 0)
        n = v3_scale(n, -1.0f);
    h->hair_plane[0] = n.x;
    h->hair_plane[1] = n.y;
    h->hair_plane[2] = n.z;
    h->hair_plane[3] = -v3_dot(n, hf);
    h->hair_curve = (10.0f + 6.0f * p[GS_SYNTH_ID_HAIRLINE]) / (60.0f * 60.0f);
}

/* Brows are colour only; brow_raise moves them. */
static void build_brows(const build_ctx *b, const float *p,
                        const gs_synth_expression *ex, head_model *h)
{
    h->brow_raise = clampf(ex->brow_raise, -1.0f, 1.0f);
    h->brow_y[0] = h->brow_y[1] = at(b, 0, -40, 0).y - 4.0f * h->brow_raise;
    h->brow_arch = (3.0f + 1.5f * p[GS_SYNTH_ID_BROW_ARCH]) * b->sc;
    h->brow_thick = (7.5f + 2.0f * p[GS_SYNTH_ID_BROW_THICKNESS]) * b->sc;
    h->brow_x0 = 12.0f * b->sc;
    h->brow_x1 = 56.0f * b->sc;
}

/* Bounds of the parts the field skips when far (see beyond()). */
static void build_bounds(const build_ctx *b, head_model *h)
{
    h->jawbone_r = 0.5f * v3_len(v3_sub(h->jawbone[0].b, h->jawbone[0].a)) +
                   maxf(h->jawbone[0].ra, h->jawbone[0].rb);
    h->nose_bc = v3_scale(v3_add(h->bridge.a, h->nose_tip.c), 0.5f);
    float r = maxf(v3_len(v3_sub(h->bridge.a, h->nose_bc)),
                   v3_len(v3_sub(h->bridge.b, h->nose_bc))) + h->bridge.rb;
    r = maxf(r, v3_len(v3_sub(h->nose_tip.c, h->nose_bc)) + rmax(&h->nose_tip));
    for (int i = 0; i < 2; i++)
        r = maxf(r, v3_len(v3_sub(h->nose_wing[i].c, h->nose_bc)) +
                        rmax(&h->nose_wing[i]));
    h->nose_br = r + 6.0f;
    h->lips_bc = v3_scale(v3_add(h->lip_up.c, h->lip_lo.c), 0.5f);
    h->lips_br = 0.5f * v3_len(v3_sub(h->lip_up.c, h->lip_lo.c)) +
                 maxf(rmax(&h->lip_up), rmax(&h->lip_lo)) + 3.0f + 12.0f * h->smile;
    compute_group_boxes(h);
    /* Everything: generous around the cranium and the neck. */
    h->bound_c = at(b, 0, -10, 55);
    h->bound_r = 175.0f * b->sc;
}

static void build_raw(const gs_synth_identity *id,
                      const gs_synth_expression *ex, double gp, double gy,
                      const double *kappa, v3 off, head_model *h)
{
    const float *p = id->p;
    build_ctx b = {1.0f + 0.05f * p[GS_SYNTH_ID_HEAD_SIZE], off, kappa};
    memset(h, 0, sizeof *h);
    h->offset = off;
    build_skull_face(&b, p, clampf(ex->smile, 0.0f, 1.0f), h);
    /* Eyes before the sockets, which are placed around them. */
    for (int i = 0; i < 2; i++) {
        build_eye(&b, p, ex, gp, gy, i, &h->eye[i]);
        h->socket[i] = ell(&b, v3_add(h->eye[i].c, v3_make(0, -1 * b.sc, -12 * b.sc)),
                           20, 14, 13);
    }
    build_nose(&b, p, h);
    build_mouth(&b, p, ex, h);
    build_ears_neck_hair(&b, p, h);
    build_brows(&b, p, ex, h);
    build_bounds(&b, h);
    build_appearance(id, h);
}

void gs_synth_head_build(const gs_synth_identity *id,
                         const gs_synth_expression *ex, double gaze_pitch,
                         double gaze_yaw, head_model *h)
{
    gs_synth_head_build_kappa(id, ex, gaze_pitch, gaze_yaw, NULL, h);
}

void gs_synth_head_build_kappa(const gs_synth_identity *id,
                               const gs_synth_expression *ex, double gaze_pitch,
                               double gaze_yaw, const double *kappa, head_model *h)
{
    /* The head frame origin is the face centre of the neutral face: build
     * it once at the origin, measure, and rebuild shifted. */
    gs_synth_expression neutral;
    gs_synth_expression_neutral(&neutral);
    build_raw(id, &neutral, 0.0, 0.0, NULL, v3_make(0, 0, 0), h);
    double lm[68][3] = {{0}}, six[6][3], fc[3];
    gs_synth_head_face_points(h, lm);
    static const int idx[6] = {36, 39, 42, 45, 31, 35};
    for (int i = 0; i < 6; i++)
        for (int k = 0; k < 3; k++)
            six[i][k] = lm[idx[i]][k];
    gs_geom_face_centre6(six, fc);
    build_raw(id, ex, gaze_pitch, gaze_yaw, kappa,
              v3_make((float)fc[0], (float)fc[1], (float)fc[2]), h);
}

void gs_synth_head_open_lids(head_model *h)
{
    for (int i = 0; i < 2; i++)
        set_lid_wedge(&h->eye[i], 85.0f * DEG, -85.0f * DEG);
}

/* ---- distance field ---- */

SDF_INLINE sdg eyeball_sdf(const eye_model *e, v3 p, const int G)
{
    return op_min(sd_sphere(e->c, e->r_sclera, p, G),
                  sd_sphere(e->cornea_c, e->r_cornea, p, G));
}

/* Lid shell: gap < eyeball distance < gap + thick, outside the opening
 * wedge (above the upper plane or below the lower one). */
SDF_INLINE sdg lid_sdf(const eye_model *e, v3 p, const int G)
{
    sdg de = eyeball_sdf(e, p, G);
    sdg outer = sdg_make(de.d - (e->lid_gap + e->lid_thick), de.g);
    sdg inner = sdg_make(e->lid_gap - de.d, v3_scale(de.g, -1.0f));
    sdg shell = op_max(outer, inner);
    v3 q = v3_sub(p, e->c);
    sdg up = sdg_make(-v3_dot(e->n_up, q), v3_scale(e->n_up, -1.0f));
    sdg lo = sdg_make(-v3_dot(e->n_lo, q), v3_scale(e->n_lo, -1.0f));
    return op_max(shell, op_min(up, lo));
}

/* Hair cap: the cranium grown by the hair thickness, above the hairline:
 * a plane bent by a term in x^2 so that the line recedes at the temples
 * (never below the plane, so the plane alone bounds it for skipping). */
SDF_INLINE sdg hair_sdf(const head_model *h, v3 p, const int G)
{
    sdg e = sd_ellipsoid(&h->hair, p, G);
    v3 n = v3_make(h->hair_plane[0], h->hair_plane[1], h->hair_plane[2]);
    sdg pl = sdg_make(v3_dot(n, p) + h->hair_plane[3] + h->hair_curve * p.x * p.x,
                      v3_add(n, v3_make(2.0f * h->hair_curve * p.x, 0, 0)));
    return op_smax(e, pl, 3.0f, G);
}

/* Neck: elliptic cylinder along y, capped above at neck_y0. */
SDF_INLINE sdg neck_sdf(const head_model *h, v3 p, const int G)
{
    float qx = p.x - h->neck_c[0], qz = p.z - h->neck_c[2];
    float ax = qx / h->neck_r[0], az = qz / h->neck_r[1];
    float bx = ax / h->neck_r[0], bz = az / h->neck_r[1];
    float k0 = sqrtf(ax * ax + az * az), k1 = sqrtf(bx * bx + bz * bz);
    sdg side;
    if (k1 < 1e-6f) {
        side = sdg_make(-minf(h->neck_r[0], h->neck_r[1]), v3_make(1, 0, 0));
    } else {
        side.d = k0 * (k0 - 1.0f) / k1;
        if (G) {
            float c0 = (2.0f * k0 - 1.0f) / (k1 * k0);
            float c1 = -k0 * (k0 - 1.0f) / (k1 * k1 * k1);
            side.g = v3_make(bx * c0 + c1 * bx / (h->neck_r[0] * h->neck_r[0]), 0,
                             bz * c0 + c1 * bz / (h->neck_r[1] * h->neck_r[1]));
        } else {
            side.g = v3_make(0, 0, 0);
        }
    }
    sdg cap = sdg_make(h->neck_y0 - p.y, v3_make(0, -1, 0));
    return op_max(side, cap);
}

/* Point in the closed-jaw frame, and the transform of gradients back. */
SDF_INLINE v3 jaw_point(const head_model *h, v3 p)
{
    return v3_add(m3_mul(h->jaw_rot, v3_sub(p, h->jaw_pivot)), h->jaw_pivot);
}

SDF_INLINE sdg jaw_back(const head_model *h, sdg s, const int G)
{
    if (G)
        s.g = m3_tmul(h->jaw_rot, s.g);
    return s;
}

/* Lip warp for a smile: corners up, back and apart. p' = f(p), and the
 * gradient maps back through the Jacobian transpose. */
SDF_INLINE v3 smile_point(const head_model *h, v3 p, float *jy, float *jz)
{
    float w = h->mouth_w, s = h->smile;
    float x = p.x / (1.0f + 0.12f * s);
    float u = x / w;
    float up = 7.0f * s, back = 5.0f * s;
    *jy = up * 2.0f * u / w / (1.0f + 0.12f * s);
    *jz = -back * 2.0f * u / w / (1.0f + 0.12f * s);
    return v3_make(x, p.y + up * u * u, p.z - back * u * u);
}

SDF_INLINE sdg smile_back(const head_model *h, sdg s, float jy, float jz,
                          const int G)
{
    if (G) {
        float gx = s.g.x / (1.0f + 0.12f * h->smile) + jy * s.g.y + jz * s.g.z;
        s.g.x = gx;
    }
    return s;
}

/* Component distances kept for materials. */
typedef struct sdf_parts {
    float base, nose, lips, ear, neck, hair, lid, cavity;
} sdf_parts;

/* True when every point of a shape inside sphere (c, R) is at least
 * `gap` from p. A blend with radius k cannot change d when the shape is
 * d + k away (smooth union) or k - d away (smooth subtraction), so such
 * shapes are skipped: most of the field is only evaluated near the parts
 * that matter. */
/* The same for an axis-aligned box of half-extents r around c (a tighter
 * bound for the elongated ellipsoids): the box's signed distance is a
 * lower bound of the shape's, outside (Euclidean distance to the box) and
 * inside (largest per-axis excess, negative). */
SDF_INLINE int beyond_box(v3 p, v3 c, v3 r, float gap)
{
    float qx = fabsf(p.x - c.x) - r.x;
    float qy = fabsf(p.y - c.y) - r.y;
    float qz = fabsf(p.z - c.z) - r.z;
    if (gap <= 0.0f)
        return maxf(qx, maxf(qy, qz)) >= gap;
    qx = maxf(qx, 0.0f);
    qy = maxf(qy, 0.0f);
    qz = maxf(qz, 0.0f);
    return qx * qx + qy * qy + qz * qz >= gap * gap;
}

SDF_INLINE int beyond(v3 p, v3 c, float r, float gap)
{
    float t = gap + r;
    if (t <= 0.0f)
        return 1;
    v3 q = v3_sub(p, c);
    return v3_dot(q, q) >= t * t;
}


/* Smooth union / subtraction of an ellipsoid evaluated at q (a point in
 * the ellipsoid's frame: p itself or the closed-jaw point). */
#define UNION_ELL(E, Q, K, BACK)                                             \
    do {                                                                     \
        if (!SKIP(beyond_box((Q), (E)->c, (E)->r, d.d + (K))))               \
            d = op_smin(d, BACK(sd_ellipsoid((E), (Q), G)), (K), G);         \
    } while (0)
#define SUB_ELL(E, Q, K)                                                     \
    do {                                                                     \
        if (!SKIP(beyond_box((Q), (E)->c, (E)->r, (K) - d.d)))               \
            d = op_smax(d, op_neg(sd_ellipsoid((E), (Q), G)), (K), G);       \
    } while (0)
#define SKIP(cond) (C && (cond))
#define SAME(x) (x)
#define JAW(x) jaw_back(h, (x), G)

SDF_INLINE int beyond_aabb(v3 p, const box3 *b, float gap)
{
    float qx = maxf(b->lo.x - p.x, p.x - b->hi.x);
    float qy = maxf(b->lo.y - p.y, p.y - b->hi.y);
    float qz = maxf(b->lo.z - p.z, p.z - b->hi.z);
    if (gap <= 0.0f)
        return maxf(qx, maxf(qy, qz)) >= gap;
    qx = maxf(qx, 0.0f);
    qy = maxf(qy, 0.0f);
    qz = maxf(qz, 0.0f);
    return qx * qx + qy * qy + qz * qz >= gap * gap;
}

/* Parts are grouped (jaw, mid-face, sockets, nose, mouth, eyes); a group
 * whose box is beyond the blend of its largest radius is skipped whole,
 * then each member is tested on its own. A group holding unions (no-op
 * when d + k away) and subtractions (no-op when k - d away) is skipped
 * only when both hold: the larger of the two gaps. C = 0 evaluates every
 * part (the reference the tests compare the culled field with). */
/* Long on purpose (evaluated at every ray-march step): one culled pass
 * over the part groups, inlined per gradient and culling mode. */
SDF_INLINE sdg head_sdf_impl(const head_model *h, v3 p, const int G,
                             const int C, sdf_parts *parts)
{
    const float big = 1e9f;
    sdg d = sd_ellipsoid(&h->cranium, p, G);
    UNION_ELL(&h->face, p, K_FACE, SAME);
    /* The jaw group lives in the closed-jaw frame. */
    v3 pj = h->mouth_open > 0.0f ? jaw_point(h, p) : p;
    if (!SKIP(beyond_aabb(pj, &h->jaw_box, d.d + K_FACE))) {
        UNION_ELL(&h->jaw, pj, K_FACE, JAW);
        for (int i = 0; i < 2; i++) {
            const sd_capsule *c = &h->jawbone[i];
            if (!SKIP(beyond(pj, v3_scale(v3_add(c->a, c->b), 0.5f),
                             h->jawbone_r, d.d + K_FACE)))
                d = op_smin(d, JAW(sd_capsule_var(c, pj, G)), K_FACE, G);
        }
        UNION_ELL(&h->chin, pj, 10.0f, JAW);
    }
    if (!SKIP(beyond_aabb(p, &h->mid_box, d.d + K_CHEEK))) {
        UNION_ELL(&h->brow, p, 10.0f, SAME);
        for (int i = 0; i < 2; i++) {
            UNION_ELL(&h->zyg[i], p, K_CHEEK, SAME);
            UNION_ELL(&h->cheek[i], p, K_CHEEK, SAME);
        }
    }
    if (!SKIP(beyond_aabb(p, &h->socket_box, 6.0f - d.d)))
        for (int i = 0; i < 2; i++)
            SUB_ELL(&h->socket[i], p, 6.0f);
    if (parts)
        parts->base = d.d;
    /* Nose (with the nostrils carved into it). */
    float nose_d = big;
    if (!SKIP(beyond_aabb(p, &h->nose_box, maxf(d.d + K_NOSE, 1.5f - d.d)))) {
        if (!SKIP(beyond(p, h->nose_bc, h->nose_br, d.d + K_NOSE))) {
            sdg n = op_smin(sd_capsule_var(&h->bridge, p, G),
                            sd_ellipsoid(&h->nose_tip, p, G), 6.0f, G);
            for (int i = 0; i < 2; i++)
                n = op_smin(n, sd_ellipsoid(&h->nose_wing[i], p, G), 4.0f, G);
            nose_d = n.d;
            d = op_smin(d, n, K_NOSE, G);
        }
        for (int i = 0; i < 2; i++)
            SUB_ELL(&h->nostril[i], p, 1.5f);
    }
    if (parts)
        parts->nose = nose_d;
    /* Mouth: lips (bounds allow for the smile warp), then the cavity. */
    float lips_d = big;
    if (parts)
        parts->cavity = big;
    if (!SKIP(beyond_aabb(p, &h->mouth_box, maxf(d.d + K_LIP, 2.0f - d.d)))) {
        if (!SKIP(beyond(p, h->lips_bc, h->lips_br, d.d + K_LIP) &&
                  beyond(pj, h->lips_bc, h->lips_br, d.d + K_LIP))) {
            float jy, jz;
            v3 ps = smile_point(h, p, &jy, &jz);
            sdg lu = smile_back(h, sd_ellipsoid(&h->lip_up, ps, G), jy, jz, G);
            v3 pjs = smile_point(h, pj, &jy, &jz);
            sdg lo = JAW(smile_back(h, sd_ellipsoid(&h->lip_lo, pjs, G), jy, jz, G));
            sdg lips = op_smin(lu, lo, 1.0f, G);
            lips_d = lips.d;
            d = op_smin(d, lips, K_LIP, G);
        }
        if (h->mouth_open > 0.02f &&
            !SKIP(beyond(p, h->cavity.c, rmax(&h->cavity), 2.0f - d.d))) {
            sdg cav = op_neg(sd_ellipsoid(&h->cavity, p, G));
            if (parts) /* <= 0 where the cavity wall is the surface */
                parts->cavity = d.d - cav.d;
            d = op_smax(d, cav, 2.0f, G);
        }
    }
    if (parts)
        parts->lips = lips_d;
    /* Ears, neck, hair. */
    float ear_d = big;
    for (int i = 0; i < 2 && h->has_ears; i++) {
        if (SKIP(beyond_box(p, h->ear[i].c, h->ear[i].r, d.d + 3.0f)))
            continue;
        sdg e = sd_ellipsoid(&h->ear[i], p, G);
        ear_d = minf(ear_d, e.d);
        d = op_smin(d, e, 3.0f, G);
    }
    float neck_d = big;
    if (!SKIP(h->neck_y0 - p.y >= d.d + 12.0f)) {
        sdg nk = neck_sdf(h, p, G);
        neck_d = nk.d;
        d = op_smin(d, nk, 12.0f, G);
    }
    float hair_d = big;
    if (h->has_hair) {
        v3 n = v3_make(h->hair_plane[0], h->hair_plane[1], h->hair_plane[2]);
        if (!SKIP(beyond_box(p, h->hair.c, h->hair.r, d.d + 2.0f) ||
                  v3_dot(n, p) + h->hair_plane[3] >= d.d + 2.0f)) {
            sdg hair = hair_sdf(h, p, G);
            hair_d = hair.d;
            d = op_smin(d, hair, 2.0f, G);
        }
    }
    /* Lids, then the carve that keeps every eyeball clear: max(d, gap -
     * eyeball) can only matter where |q| < bound_r + gap - d. */
    float lid_min = big;
    if (!SKIP(beyond_aabb(p, &h->eyes_box,
                          maxf(d.d + K_LID, h->eye[0].lid_gap - d.d)))) {
        for (int i = 0; i < 2; i++) {
            const eye_model *e = &h->eye[i];
            if (SKIP(beyond(p, e->c, e->lid_bound_r, d.d + K_LID)))
                continue;
            sdg l = lid_sdf(e, p, G);
            lid_min = minf(lid_min, l.d);
            d = op_smin(d, l, K_LID, G);
        }
        for (int i = 0; i < 2; i++) {
            const eye_model *e = &h->eye[i];
            if (SKIP(beyond(p, e->c, e->bound_r, e->lid_gap - d.d)))
                continue;
            sdg de = eyeball_sdf(e, p, G);
            d = op_max(d, sdg_make(e->lid_gap - de.d, v3_scale(de.g, -1.0f)));
        }
    }
    d = op_max(d, sdg_make(p.y - h->neck_cut_y, v3_make(0, 1, 0)));
    if (parts) {
        parts->ear = ear_d;
        parts->neck = neck_d;
        parts->hair = hair_d;
        parts->lid = lid_min;
    }
    return d;
}

float gs_synth_head_sdf(const head_model *h, v3 p)
{
    return head_sdf_impl(h, p, 0, 1, NULL).d;
}

float gs_synth_head_sdf_nocull(const head_model *h, v3 p)
{
    return head_sdf_impl(h, p, 0, 0, NULL).d;
}

float gs_synth_head_sdf_grad(const head_model *h, v3 p, v3 *grad)
{
    sdg d = head_sdf_impl(h, p, 1, 1, NULL);
    *grad = d.g;
    return d.d;
}

float gs_synth_eyeball_sdf(const eye_model *e, v3 p)
{
    return eyeball_sdf(e, p, 0).d;
}

float gs_synth_lid_sdf(const eye_model *e, v3 p)
{
    return lid_sdf(e, p, 0).d;
}

static int material_of(const head_model *h, const sdf_parts *ps, float d)
{
    const sdf_parts s = *ps;
    const float tol = 0.35f;
    if (s.cavity < 0.5f && h->mouth_open > 0.02f)
        return MAT_MOUTH;
    if (s.lid <= d + tol)
        return MAT_LID;
    if (s.hair <= d + tol)
        return MAT_HAIR;
    if (s.ear <= d + tol)
        return MAT_EAR;
    if (s.lips <= d + 0.6f)
        return MAT_LIPS;
    if (s.neck <= d + tol && s.neck < s.base - 2.0f)
        return MAT_NECK;
    return MAT_SKIN;
}

int gs_synth_head_material(const head_model *h, v3 p)
{
    sdf_parts s;
    float d = head_sdf_impl(h, p, 0, 1, &s).d;
    return material_of(h, &s, d);
}

float gs_synth_head_surface(const head_model *h, v3 p, v3 *grad,
                            int *material)
{
    sdf_parts s;
    sdg d = head_sdf_impl(h, p, 1, 1, &s);
    *grad = d.g;
    *material = material_of(h, &s, d.d);
    return d.d;
}

int gs_synth_head_is_face(const head_model *h, v3 p, int material)
{
    if (material == MAT_HAIR || material == MAT_EAR || material == MAT_NECK)
        return 0;
    /* In front of the ears and below the top of the forehead. */
    float ear_front = h->ear[0].c.z - h->ear[0].r.z;
    float top = -(96.0f + 10.0f) - h->offset.y;
    return p.z < ear_front && p.y > top;
}

/* ---- albedo ---- */

static float fbm2(v3 p, uint32_t seed)
{
    return 0.65f * gs_synth_noise3(p, seed) +
           0.35f * gs_synth_noise3(v3_scale(p, 2.7f), seed + 17u);
}

/* Eyebrow density at a skin point: a curved band above each eye. */
static float brow_density(const head_model *h, v3 p)
{
    if (p.z > 25.0f)
        return 0.0f;
    int side = p.x < 0.0f ? 0 : 1;
    float ax = fabsf(p.x - 0.5f * (h->eye[0].c.x + h->eye[1].c.x));
    float x0 = h->brow_x0, x1 = h->brow_x1;
    if (ax < x0 - 3.0f || ax > x1 + 3.0f)
        return 0.0f;
    float t = clampf((ax - x0) / (x1 - x0), 0.0f, 1.0f);
    float yc = h->brow_y[side] - h->brow_arch * sinf(3.14159f * powf(t, 0.8f)) +
               2.5f * t;
    float half = h->brow_thick * (1.0f - 0.55f * t) * 0.5f;
    float dy = fabsf(p.y - yc);
    float band = 1.0f - smoothstepf(half * 0.6f, half * 1.3f, dy);
    float ends = smoothstepf(x0 - 3.0f, x0 + 2.0f, ax) *
                 (1.0f - smoothstepf(x1 - 4.0f, x1 + 3.0f, ax));
    /* Hair strands: noise stretched along the brow. */
    float strands = 0.5f + 0.5f * gs_synth_noise3(
        v3_make(p.x * 0.35f, p.y * 2.2f, p.z * 0.5f), h->tex_seed + 5u);
    return band * ends * (0.7f + 0.3f * strands);
}

v3 gs_synth_skin_albedo(const head_model *h, v3 p, int material)
{
    if (material == MAT_MOUTH) {
        /* Inside the mouth light falls off with depth behind the lips; a
         * band of upper teeth shows just under the upper lip. */
        float front = h->lip_up.c.z - h->lip_up.r.z;
        float depth = maxf(0.0f, p.z - front);
        float teeth = smoothstepf(h->mouth_y - 2.0f, h->mouth_y - 0.5f, p.y) *
                      (1.0f - smoothstepf(h->mouth_y + 2.0f, h->mouth_y + 3.5f, p.y)) *
                      (1.0f - smoothstepf(0.55f * h->mouth_w, 0.7f * h->mouth_w, fabsf(p.x))) *
                      (1.0f - smoothstepf(6.0f, 9.0f, depth));
        v3 c = v3_lerp(h->mouth_col, v3_make(0.55f, 0.52f, 0.46f), teeth);
        return v3_scale(c, expf(-depth / 9.0f));
    }
    if (material == MAT_HAIR) {
        float s = fbm2(v3_make(p.x * 0.8f, p.y * 0.12f, p.z * 0.8f), h->tex_seed + 9u);
        return v3_scale(h->hair_col, 0.75f + 0.35f * s);
    }
    /* Blotches at ~3 mm and pores at ~0.5 mm. */
    float n = gs_synth_noise3(v3_scale(p, 0.35f), h->tex_seed);
    float pores = gs_synth_noise3(v3_scale(p, 2.2f), h->tex_seed + 3u);
    v3 a = v3_scale(h->skin, 1.0f + h->skin_tex * n + 0.04f * pores);
    if (material == MAT_LIPS) {
        a = v3_lerp(a, h->lip_col, 0.85f);
        /* Darker line where the lips meet. */
        float line = 1.0f - smoothstepf(0.3f, 1.6f, fabsf(p.y - h->mouth_y));
        a = v3_scale(a, 1.0f - 0.55f * line * (1.0f - h->mouth_open));
        return a;
    }
    if (material == MAT_EAR || material == MAT_NECK) {
        float r = material == MAT_EAR ? 1.06f : 0.96f;
        return v3_make(a.x * r, a.y * 0.98f, a.z * 0.97f);
    }
    /* Cheek blush. */
    for (int i = 0; i < 2; i++) {
        v3 q = v3_sub(p, h->cheek[i].c);
        float w = expf(-(q.x * q.x + q.y * q.y) / (2.0f * 18.0f * 18.0f));
        a = v3_make(a.x * (1 + h->blush * w * 0.5f), a.y * (1 - h->blush * w * 0.6f),
                    a.z * (1 - h->blush * w * 0.5f));
    }
    if (h->freckles > 0.0f && p.y > -40.0f && p.y < 25.0f && p.z < 15.0f) {
        float f = gs_synth_noise3(v3_scale(p, 0.9f), h->tex_seed + 11u);
        float spot = smoothstepf(0.45f, 0.65f, f) * h->freckles;
        a = v3_make(a.x * (1 - 0.25f * spot), a.y * (1 - 0.35f * spot),
                    a.z * (1 - 0.45f * spot));
    }
    float brow = brow_density(h, p);
    if (brow > 0.0f)
        a = v3_lerp(a, h->brow_col, clampf(brow, 0.0f, 1.0f));
    if (material == MAT_LID) {
        /* Lashes along the upper margin, a pink wet line on the lower. */
        for (int i = 0; i < 2; i++) {
            const eye_model *e = &h->eye[i];
            v3 q = v3_sub(p, e->c);
            if (v3_len(q) > e->lid_bound_r + 1.0f)
                continue;
            float du = v3_dot(e->n_up, q), dl = v3_dot(e->n_lo, q);
            float front = v3_dot(q, v3_make(0, 0, -1));
            if (du > -0.5f && du < 1.6f && front > -4.0f)
                a = v3_lerp(a, v3_make(0.02f, 0.015f, 0.012f),
                            h->lash * (1.0f - smoothstepf(0.6f, 1.6f, du)));
            else if (dl > -0.5f && dl < 0.9f && du < 0.0f)
                a = v3_make(a.x * 1.05f, a.y * 0.8f, a.z * 0.8f);
        }
    }
    return a;
}
