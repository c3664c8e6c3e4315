/* The head distance field for 4 points at once (GCC vector extensions:
 * SSE on x86-64, NEON on ARM, plain code elsewhere).
 *
 * Lane for lane this is the computation of head_sdf_impl in head.c with
 * G = 0: the same operations in the same order, and the same skip
 * decisions made per lane (a part is evaluated when any lane needs it and
 * merged only into the lanes that do). Every operation is an IEEE single
 * add, multiply, divide, compare or square root, so each lane equals
 * gs_synth_head_sdf bit for bit; tests/synth checks it. Edit both
 * together. */
#include "synth_internal.h"

#if defined(__SSE__)
#include <xmmintrin.h>
#endif

typedef float f4 __attribute__((vector_size(16)));
typedef int32_t m4 __attribute__((vector_size(16)));

typedef struct p4 {
    f4 x, y, z;
} p4;

#define V_INLINE static inline __attribute__((always_inline))

V_INLINE f4 splat(float a) { return (f4){a, a, a, a}; }
V_INLINE m4 msplat(int32_t a) { return (m4){a, a, a, a}; }
V_INLINE f4 sel(m4 m, f4 a, f4 b) { return (f4)((m & (m4)a) | (~m & (m4)b)); }
V_INLINE int any(m4 m) { return (m[0] | m[1] | m[2] | m[3]) != 0; }
V_INLINE f4 vmax(f4 a, f4 b) { return sel(a > b, a, b); }
V_INLINE f4 vabs(f4 a) { return (f4)((m4)a & msplat(0x7fffffff)); }
V_INLINE f4 vsqrt(f4 a)
{
#if defined(__SSE__)
    return (f4)_mm_sqrt_ps((__m128)a);
#else
    f4 r = a;
    for (int i = 0; i < 4; i++)
        r[i] = sqrtf(a[i]);
    return r;
#endif
}

V_INLINE p4 p4_sub(p4 p, v3 c)
{
    p4 r = {p.x - c.x, p.y - c.y, p.z - c.z};
    return r;
}
V_INLINE f4 dot4(p4 a, p4 b) { return a.x * b.x + a.y * b.y + a.z * b.z; }
V_INLINE f4 dotv(v3 n, p4 p) { return n.x * p.x + n.y * p.y + n.z * p.z; }

/* clampf(x, lo, hi) = x < lo ? lo : (x > hi ? hi : x) */
V_INLINE f4 vclamp01(f4 x)
{
    f4 zero = splat(0.0f), one = splat(1.0f);
    return sel(x < zero, zero, sel(x > one, one, x));
}

V_INLINE f4 ell4(const sd_ell *e, p4 p)
{
    p4 q = p4_sub(p, e->c);
    p4 a = {q.x * e->ir.x, q.y * e->ir.y, q.z * e->ir.z};
    p4 b = {a.x * e->ir.x, a.y * e->ir.y, a.z * e->ir.z};
    f4 k0 = vsqrt(dot4(a, a)), k1 = vsqrt(dot4(b, b));
    f4 d = k0 * (k0 - 1.0f) / k1;
    float inner = -minf(e->r.x, minf(e->r.y, e->r.z));
    return sel(k1 < splat(1e-6f), splat(inner), d);
}

V_INLINE f4 capsule4(const sd_capsule *c, p4 p)
{
    v3 ba = v3_sub(c->b, c->a);
    p4 pa = p4_sub(p, c->a);
    float bb = v3_dot(ba, ba);
    f4 h = vclamp01(dotv(ba, pa) / bb);
    p4 q = {pa.x - ba.x * h, pa.y - ba.y * h, pa.z - ba.z * h};
    f4 l = vsqrt(dot4(q, q));
    return l - (c->ra + (c->rb - c->ra) * h);
}

V_INLINE f4 sphere4(v3 c, float r, p4 p)
{
    p4 q = p4_sub(p, c);
    return vsqrt(dot4(q, q)) - r;
}

V_INLINE f4 smin4(f4 a, f4 b, float k)
{
    f4 h = vclamp01(0.5f + 0.5f * (b - a) / k);
    return (b + (a - b) * h) - k * h * (1.0f - h);
}

V_INLINE f4 smax4(f4 a, f4 b, float k) { return -smin4(-a, -b, k); }
V_INLINE f4 omin(f4 a, f4 b) { return sel(b < a, b, a); }
V_INLINE f4 omax(f4 a, f4 b) { return sel(b > a, b, a); }

/* Masks of lanes for which a shape is NOT beyond `gap` (so it matters). */
V_INLINE m4 near_sphere(p4 p, v3 c, float r, f4 gap)
{
    f4 t = gap + r;
    p4 q = p4_sub(p, c);
    m4 beyond = (t <= splat(0.0f)) | (dot4(q, q) >= t * t);
    return ~beyond;
}

V_INLINE m4 beyond_q(f4 qx, f4 qy, f4 qz, f4 gap)
{
    f4 zero = splat(0.0f);
    m4 neg = gap <= zero;
    m4 inside_ok = vmax(qx, vmax(qy, qz)) >= gap;
    qx = vmax(qx, zero);
    qy = vmax(qy, zero);
    qz = vmax(qz, zero);
    m4 outside_ok = qx * qx + qy * qy + qz * qz >= gap * gap;
    return (neg & inside_ok) | (~neg & outside_ok);
}

V_INLINE m4 near_box(p4 p, v3 c, v3 r, f4 gap)
{
    return ~beyond_q(vabs(p.x - c.x) - r.x, vabs(p.y - c.y) - r.y,
                     vabs(p.z - c.z) - r.z, gap);
}

V_INLINE m4 near_aabb(p4 p, const box3 *b, f4 gap)
{
    return ~beyond_q(vmax(b->lo.x - p.x, p.x - b->hi.x),
                     vmax(b->lo.y - p.y, p.y - b->hi.y),
                     vmax(b->lo.z - p.z, p.z - b->hi.z), gap);
}

V_INLINE p4 jaw4(const head_model *h, p4 p)
{
    const float *m = h->jaw_rot;
    p4 q = p4_sub(p, h->jaw_pivot);
    p4 r = {m[0] * q.x + m[1] * q.y + m[2] * q.z,
            m[3] * q.x + m[4] * q.y + m[5] * q.z,
            m[6] * q.x + m[7] * q.y + m[8] * q.z};
    r.x = r.x + h->jaw_pivot.x;
    r.y = r.y + h->jaw_pivot.y;
    r.z = r.z + h->jaw_pivot.z;
    return r;
}

V_INLINE p4 smile4(const head_model *h, p4 p)
{
    float w = h->mouth_w, s = h->smile;
    f4 x = p.x / (1.0f + 0.12f * s);
    f4 u = x / w;
    float up = 7.0f * s, back = 5.0f * s;
    p4 r = {x, p.y + up * u * u, p.z - back * u * u};
    return r;
}

V_INLINE f4 neck4(const head_model *h, p4 p)
{
    f4 qx = p.x - h->neck_c[0], qz = p.z - h->neck_c[2];
    f4 ax = qx / h->neck_r[0], az = qz / h->neck_r[1];
    f4 bx = ax / h->neck_r[0], bz = az / h->neck_r[1];
    f4 k0 = vsqrt(ax * ax + az * az), k1 = vsqrt(bx * bx + bz * bz);
    f4 side = sel(k1 < splat(1e-6f), splat(-minf(h->neck_r[0], h->neck_r[1])),
                  k0 * (k0 - 1.0f) / k1);
    f4 cap = h->neck_y0 - p.y;
    return omax(side, cap);
}

V_INLINE f4 hair4(const head_model *h, p4 p)
{
    v3 n = v3_make(h->hair_plane[0], h->hair_plane[1], h->hair_plane[2]);
    return smax4(ell4(&h->hair, p),
                 dotv(n, p) + h->hair_plane[3] + h->hair_curve * p.x * p.x, 3.0f);
}

V_INLINE f4 eyeball4(const eye_model *e, p4 p)
{
    return omin(sphere4(e->c, e->r_sclera, p), sphere4(e->cornea_c, e->r_cornea, p));
}

V_INLINE f4 lid4(const eye_model *e, p4 p)
{
    f4 de = eyeball4(e, p);
    f4 shell = omax(de - (e->lid_gap + e->lid_thick), e->lid_gap - de);
    p4 q = p4_sub(p, e->c);
    f4 up = -dotv(e->n_up, q), lo = -dotv(e->n_lo, q);
    return omax(shell, omin(up, lo));
}

/* Blend constants: the same values as head.c. */
#define K_FACE 14.0f
#define K_NOSE 5.0f
#define K_LIP 4.0f
#define K_CHEEK 12.0f
#define K_LID 2.5f

#define VUNION_ELL(M, E, Q, K)                                               \
    do {                                                                     \
        m4 m_ = (M) & near_box((Q), (E)->c, (E)->r, d + (K));                \
        if (any(m_))                                                         \
            d = sel(m_, smin4(d, ell4((E), (Q)), (K)), d);                   \
    } while (0)
#define VSUB_ELL(M, E, Q, K)                                                 \
    do {                                                                     \
        m4 m_ = (M) & near_box((Q), (E)->c, (E)->r, (K) - d);                \
        if (any(m_))                                                         \
            d = sel(m_, smax4(d, -ell4((E), (Q)), (K)), d);                  \
    } while (0)

static f4 head_sdf4(const head_model *h, p4 p)
{
    const m4 all = msplat(-1);
    f4 d = ell4(&h->cranium, p);
    VUNION_ELL(all, &h->face, p, K_FACE);
    p4 pj = h->mouth_open > 0.0f ? jaw4(h, p) : p;
    m4 mj = near_aabb(pj, &h->jaw_box, d + K_FACE);
    if (any(mj)) {
        VUNION_ELL(mj, &h->jaw, pj, K_FACE);
        for (int i = 0; i < 2; i++) {
            const sd_capsule *c = &h->jawbone[i];
            m4 m = mj & near_sphere(pj, v3_scale(v3_add(c->a, c->b), 0.5f),
                                    h->jawbone_r, d + K_FACE);
            if (any(m))
                d = sel(m, smin4(d, capsule4(c, pj), K_FACE), d);
        }
        VUNION_ELL(mj, &h->chin, pj, 10.0f);
    }
    m4 mm = near_aabb(p, &h->mid_box, d + K_CHEEK);
    if (any(mm)) {
        VUNION_ELL(mm, &h->brow, p, 10.0f);
        for (int i = 0; i < 2; i++) {
            VUNION_ELL(mm, &h->zyg[i], p, K_CHEEK);
            VUNION_ELL(mm, &h->cheek[i], p, K_CHEEK);
        }
    }
    m4 ms = near_aabb(p, &h->socket_box, 6.0f - d);
    if (any(ms))
        for (int i = 0; i < 2; i++)
            VSUB_ELL(ms, &h->socket[i], p, 6.0f);
    m4 mn = near_aabb(p, &h->nose_box, vmax(d + K_NOSE, 1.5f - d));
    if (any(mn)) {
        m4 m = mn & near_sphere(p, h->nose_bc, h->nose_br, d + K_NOSE);
        if (any(m)) {
            f4 n = smin4(capsule4(&h->bridge, p), ell4(&h->nose_tip, p), 6.0f);
            for (int i = 0; i < 2; i++)
                n = smin4(n, ell4(&h->nose_wing[i], p), 4.0f);
            d = sel(m, smin4(d, n, K_NOSE), d);
        }
        for (int i = 0; i < 2; i++)
            VSUB_ELL(mn, &h->nostril[i], p, 1.5f);
    }
    m4 mo = near_aabb(p, &h->mouth_box, vmax(d + K_LIP, 2.0f - d));
    if (any(mo)) {
        m4 m = mo & (near_sphere(p, h->lips_bc, h->lips_br, d + K_LIP) |
                     near_sphere(pj, h->lips_bc, h->lips_br, d + K_LIP));
        if (any(m)) {
            f4 lu = ell4(&h->lip_up, smile4(h, p));
            f4 lo = ell4(&h->lip_lo, smile4(h, pj));
            d = sel(m, smin4(d, smin4(lu, lo, 1.0f), K_LIP), d);
        }
        if (h->mouth_open > 0.02f) {
            m4 mc = mo & near_sphere(p, h->cavity.c, h->cavity.rmax, 2.0f - d);
            if (any(mc))
                d = sel(mc, smax4(d, -ell4(&h->cavity, p), 2.0f), d);
        }
    }
    for (int i = 0; i < 2 && h->has_ears; i++) {
        m4 m = near_box(p, h->ear[i].c, h->ear[i].r, d + 3.0f);
        if (any(m))
            d = sel(m, smin4(d, ell4(&h->ear[i], p), 3.0f), d);
    }
    m4 mk = (h->neck_y0 - p.y) < d + 12.0f;
    if (any(mk))
        d = sel(mk, smin4(d, neck4(h, p), 12.0f), d);
    if (h->has_hair) {
        v3 n = v3_make(h->hair_plane[0], h->hair_plane[1], h->hair_plane[2]);
        m4 m = near_box(p, h->hair.c, h->hair.r, d + 2.0f) &
               (dotv(n, p) + h->hair_plane[3] < d + 2.0f);
        if (any(m))
            d = sel(m, smin4(d, hair4(h, p), 2.0f), d);
    }
    m4 me = near_aabb(p, &h->eyes_box, vmax(d + K_LID, h->eye[0].lid_gap - d));
    if (any(me)) {
        for (int i = 0; i < 2; i++) {
            const eye_model *e = &h->eye[i];
            m4 m = me & near_sphere(p, e->c, e->lid_bound_r, d + K_LID);
            if (any(m))
                d = sel(m, smin4(d, lid4(e, p), K_LID), d);
        }
        for (int i = 0; i < 2; i++) {
            const eye_model *e = &h->eye[i];
            m4 m = me & near_sphere(p, e->c, e->bound_r, e->lid_gap - d);
            if (any(m))
                d = sel(m, omax(d, e->lid_gap - eyeball4(e, p)), d);
        }
    }
    return omax(d, p.y - h->neck_cut_y);
}

void gs_synth_head_sdf4(const head_model *h, const float x[4],
                        const float y[4], const float z[4], float out[4])
{
    p4 p;
    for (int i = 0; i < 4; i++) {
        p.x[i] = x[i];
        p.y[i] = y[i];
        p.z[i] = z[i];
    }
    f4 d = head_sdf4(h, p);
    for (int i = 0; i < 4; i++)
        out[i] = d[i];
}
