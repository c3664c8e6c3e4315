/* The 68 iBUG landmarks of a built head, in its head frame.
 *
 * Eye points are exact: the lid margins are where the wedge planes meet
 * the inner lid surface (eyeball distance = lid gap); 36/39 and 42/45 are
 * the ends of the lid axis. Every other point is the first surface hit of
 * a ray aimed at an anatomical place computed from the primitives (nose
 * bridge, tip and wings, lip contours, brow curve, a jaw contour), so each
 * lies on the rendered surface. Jaw points are fixed 3D points, not the
 * view-dependent silhouette that annotators follow in profile views. */
#include "synth_internal.h"

static const float PI_F = 3.14159265358979f;

/* First hit of the ray o + t dir (dir unit) with the head surface;
 * falls back to the start point if nothing is hit within 400 mm. */
static v3 cast(const head_model *h, v3 o, v3 dir)
{
    float t = 0.0f;
    for (int i = 0; i < 400 && t < 400.0f; i++) {
        v3 p = v3_add(o, v3_scale(dir, t));
        float d = gs_synth_head_sdf(h, p);
        if (d < 1e-4f)
            return p;
        t += 0.8f * d;
    }
    return o;
}

/* Newton projection onto the surface, for points already close to it. */
static v3 project(const head_model *h, v3 p)
{
    for (int i = 0; i < 12; i++) {
        v3 g;
        float d = gs_synth_head_sdf_grad(h, p, &g);
        float gg = v3_dot(g, g);
        if (gg < 1e-12f)
            break;
        p = v3_sub(p, v3_scale(g, d / gg));
        if (fabsf(d) < 1e-5f)
            break;
    }
    return p;
}

static v3 frontal(const head_model *h, float x, float y)
{
    return cast(h, v3_make(x, y, -250.0f), v3_make(0, 0, 1));
}

static void put(double lm[68][3], int i, v3 p)
{
    lm[i][0] = p.x;
    lm[i][1] = p.y;
    lm[i][2] = p.z;
}

/* Point of the inner lid edge in direction dir from the eye centre. */
static v3 lid_margin(const eye_model *e, v3 dir)
{
    float lo = 0.5f * e->r_sclera, hi = e->bound_r + e->lid_gap + 1.0f;
    for (int i = 0; i < 40; i++) {
        float mid = 0.5f * (lo + hi);
        float d = gs_synth_eyeball_sdf(e, v3_add(e->c, v3_scale(dir, mid)));
        if (d < e->lid_gap)
            lo = mid;
        else
            hi = mid;
    }
    return v3_add(e->c, v3_scale(dir, 0.5f * (lo + hi)));
}

static v3 margin_dir(const eye_model *e, float psi, int upper)
{
    v3 m = upper ? e->up_dir : e->lo_dir;
    return v3_add(v3_scale(e->lid_x, cosf(psi)), v3_scale(m, sinf(psi)));
}

static void eye_landmarks(const head_model *h, double lm[68][3])
{
    /* psi = 0 is the outer corner, pi the inner one. */
    static const int right[6][2] = {{0, 1}, {1, 1}, {2, 1}, {3, 1}, {2, 0}, {1, 0}};
    static const int left[6][2] = {{3, 1}, {2, 1}, {1, 1}, {0, 1}, {1, 0}, {2, 0}};
    for (int side = 0; side < 2; side++) {
        const eye_model *e = &h->eye[side];
        const int(*order)[2] = side == 0 ? right : left;
        int base = side == 0 ? 36 : 42;
        for (int k = 0; k < 6; k++) {
            float psi = PI_F * (float)order[k][0] / 3.0f;
            put(lm, base + k, lid_margin(e, margin_dir(e, psi, order[k][1])));
        }
    }
}

static void jaw_landmarks(const head_model *h, double lm[68][3])
{
    /* A contour from the right side (0) under the chin (8) to the left (16)
     * on an ellipse in the frontal plane; each ray comes from outside
     * toward the face's vertical axis at a depth that moves from the chin
     * (front) to the cheek sides (back). */
    float yc = h->eye[0].c.y + 10.0f;
    float chin_bottom = h->chin.c.y + h->chin.r.y;
    float a = fabsf(h->jawbone[1].a.x - h->jawbone[0].a.x), bb = chin_bottom - yc;
    float zf = h->chin.c.z + 0.4f * h->chin.r.z;
    float zs = h->jawbone[0].a.z - 20.0f;
    for (int i = 0; i <= 16; i++) {
        float al = PI_F * (1.0f - (float)i / 16.0f);
        float ca = cosf(al), sa = sinf(al);
        float z = zf + (zs - zf) * fabsf(ca);
        v3 target = v3_make(0, yc, z);
        v3 o = v3_make(a * ca * 1.6f, yc + bb * sa * 1.6f, z);
        put(lm, i, cast(h, o, v3_norm(v3_sub(target, o))));
    }
}

static void brow_landmarks(const head_model *h, double lm[68][3])
{
    float mid = 0.5f * (h->eye[0].c.x + h->eye[1].c.x);
    for (int k = 0; k < 5; k++) {
        /* 17..21: right brow outer -> inner; 22..26: left inner -> outer. */
        float t_r = 0.95f - 0.225f * (float)k, t_l = 0.05f + 0.225f * (float)k;
        for (int side = 0; side < 2; side++) {
            float t = side == 0 ? t_r : t_l;
            float s = side == 0 ? -1.0f : 1.0f;
            float ax = h->brow_x0 + t * (h->brow_x1 - h->brow_x0);
            float yc = h->brow_y[side] -
                       h->brow_arch * sinf(PI_F * powf(t, 0.8f)) + 2.5f * t;
            put(lm, (side == 0 ? 17 : 22) + k, frontal(h, mid + s * ax, yc));
        }
    }
}

static void nose_landmarks(const head_model *h, double lm[68][3])
{
    float x = h->bridge.a.x;
    float y27 = 0.5f * (h->eye[0].c.y + h->eye[1].c.y) - 2.0f;
    float y30 = h->nose_tip.c.y;
    for (int k = 0; k < 4; k++)
        put(lm, 27 + k, frontal(h, x, y27 + (y30 - y27) * (float)k / 3.0f));
    /* 31..35 along the base of the nose, right wing to left wing. */
    float yb = h->nose_wing[0].c.y + 0.5f * h->nose_wing[0].r.y;
    float wx = 0.85f * fabsf(h->nose_wing[1].c.x - x);
    for (int k = 0; k < 5; k++) {
        float u = -1.0f + 0.5f * (float)k;
        float y = yb + 1.5f * (1.0f - fabsf(u));
        put(lm, 31 + k, frontal(h, x + u * wx, y));
    }
}

/* Lip contour point at relative position u in [-1, 1] across the mouth:
 * top/bottom outer edges and the inner line, smile and jaw applied. */
static v3 lip_point(const head_model *h, float u, int which)
{
    float s = h->smile;
    float w = h->mouth_w * (1.0f + 0.12f * s);
    float x = u * w * 0.98f;
    float lift = 7.0f * s * u * u, back = 5.0f * s * u * u;
    const sd_ell *e = which <= 1 ? &h->lip_up : &h->lip_lo;
    float f = sqrtf(maxf(0.0f, 1.0f - u * u));
    float y, z = e->c.z - e->r.z * f * 0.9f + back;
    switch (which) {
    case 0: y = e->c.y - 0.85f * e->r.y * f; break;        /* upper outer */
    case 1: y = h->mouth_y; break;                         /* upper inner */
    case 2: y = h->mouth_y; break;                         /* lower inner */
    default: y = e->c.y + 0.85f * e->r.y * f; break;       /* lower outer */
    }
    v3 p = v3_make(x, y - lift, z);
    if (which >= 2) { /* the lower lip moves with the jaw */
        v3 q = v3_sub(p, h->jaw_pivot);
        p = v3_add(m3_tmul(h->jaw_rot, q), h->jaw_pivot);
    }
    if (which == 2)
        p.y += 0.5f * h->cavity.r.y * f;
    if (which == 1)
        p.y -= 0.5f * h->cavity.r.y * f;
    return project(h, p);
}

static void mouth_landmarks(const head_model *h, double lm[68][3])
{
    /* Outer: 48 right corner, 49-53 upper (right to left), 54 left corner,
     * 55-59 lower (left to right). Inner: 60 right, 61-63 upper, 64 left,
     * 65-67 lower (left to right). */
    static const float up_u[5] = {-0.62f, -0.3f, 0.0f, 0.3f, 0.62f};
    static const float lo_u[5] = {0.62f, 0.3f, 0.0f, -0.3f, -0.62f};
    static const float in_u[3] = {-0.4f, 0.0f, 0.4f};
    put(lm, 48, lip_point(h, -1.0f, 1));
    put(lm, 54, lip_point(h, 1.0f, 1));
    for (int k = 0; k < 5; k++) {
        put(lm, 49 + k, lip_point(h, up_u[k], 0));
        put(lm, 55 + k, lip_point(h, lo_u[k], 3));
    }
    put(lm, 60, lip_point(h, -0.9f, 1));
    put(lm, 64, lip_point(h, 0.9f, 1));
    for (int k = 0; k < 3; k++) {
        put(lm, 61 + k, lip_point(h, in_u[k], 1));
        put(lm, 65 + k, lip_point(h, -in_u[k], 2));
    }
}

void gs_synth_head_face_points(const head_model *h, double lm[68][3])
{
    nose_landmarks(h, lm);
    eye_landmarks(h, lm);
}

void gs_synth_head_landmarks(const head_model *h, double lm[68][3])
{
    jaw_landmarks(h, lm);
    brow_landmarks(h, lm);
    nose_landmarks(h, lm);
    eye_landmarks(h, lm);
    mouth_landmarks(h, lm);
}
