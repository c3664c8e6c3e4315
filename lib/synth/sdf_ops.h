/* Signed-distance primitives and smooth operators with optional analytic
 * gradients. Each takes `G` (a compile-time constant at the call site):
 * with G = 0 only the distance is computed, so one body serves both the
 * marching loop and the normal evaluation. */
#ifndef GS_SYNTH_SDF_OPS_H
#define GS_SYNTH_SDF_OPS_H

#include "synth_internal.h"

#define SDF_INLINE static inline __attribute__((always_inline))

typedef struct sdg {
    float d;
    v3 g;
} sdg;

SDF_INLINE sdg sdg_make(float d, v3 g)
{
    sdg r = {d, g};
    return r;
}

/* Ellipsoid, the usual bound d = k0 (k0 - 1) / k1 with k0 = |q/r|,
 * k1 = |q/r^2|: exact on the surface, close nearby, a little
 * conservative far away (the marcher steps 0.9 of it). */
SDF_INLINE sdg sd_ellipsoid(const sd_ell *e, v3 p, const int G)
{
    v3 q = v3_sub(p, e->c);
    v3 a = v3_mul(q, e->ir);
    v3 b = v3_mul(a, e->ir);
    float k0 = v3_len(a), k1 = v3_len(b);
    sdg out;
    if (k1 < 1e-6f) {
        return sdg_make(-minf(e->r.x, minf(e->r.y, e->r.z)), v3_make(0, 0, 1));
    }
    out.d = k0 * (k0 - 1.0f) / k1;
    if (G) {
        /* d k0/dq = b / k0, d k1/dq = (b / r^2) / k1 */
        v3 dk0 = v3_scale(b, 1.0f / k0);
        v3 dk1 = v3_scale(v3_mul(b, e->ir2), 1.0f / k1);
        float c0 = (2.0f * k0 - 1.0f) / k1, c1 = -k0 * (k0 - 1.0f) / (k1 * k1);
        out.g = v3_add(v3_scale(dk0, c0), v3_scale(dk1, c1));
    } else {
        out.g = v3_make(0, 0, 0);
    }
    return out;
}

/* Capsule whose radius goes linearly from ra (at a) to rb (at b). */
SDF_INLINE sdg sd_capsule_var(const sd_capsule *c, v3 p, const int G)
{
    v3 ba = v3_sub(c->b, c->a), pa = v3_sub(p, c->a);
    float bb = v3_dot(ba, ba);
    float h = clampf(v3_dot(pa, ba) / bb, 0.0f, 1.0f);
    v3 q = v3_sub(pa, v3_scale(ba, h));
    float l = v3_len(q);
    sdg out;
    out.d = l - mixf(c->ra, c->rb, h);
    if (G) {
        out.g = l > 1e-6f ? v3_scale(q, 1.0f / l) : v3_make(0, 0, -1);
        if (h > 0.0f && h < 1.0f)
            out.g = v3_sub(out.g, v3_scale(ba, (c->rb - c->ra) / bb));
    } else {
        out.g = v3_make(0, 0, 0);
    }
    return out;
}

SDF_INLINE sdg sd_sphere(v3 c, float r, v3 p, const int G)
{
    v3 q = v3_sub(p, c);
    float l = v3_len(q);
    sdg out;
    out.d = l - r;
    out.g = G ? (l > 1e-6f ? v3_scale(q, 1.0f / l) : v3_make(0, 0, -1))
              : v3_make(0, 0, 0);
    return out;
}

/* Polynomial smooth minimum of radius k (quadratic, compact support: the
 * result equals min(a, b) when |a - b| >= k). The gradient is exactly the
 * h-weighted blend of the two gradients. */
SDF_INLINE sdg op_smin(sdg a, sdg b, float k, const int G)
{
    float h = clampf(0.5f + 0.5f * (b.d - a.d) / k, 0.0f, 1.0f);
    sdg out;
    out.d = mixf(b.d, a.d, h) - k * h * (1.0f - h);
    out.g = G ? v3_lerp(b.g, a.g, h) : a.g;
    return out;
}

SDF_INLINE sdg op_neg(sdg a)
{
    return sdg_make(-a.d, v3_scale(a.g, -1.0f));
}

/* Smooth maximum (intersection); smooth subtraction is smax(a, -b). */
SDF_INLINE sdg op_smax(sdg a, sdg b, float k, const int G)
{
    return op_neg(op_smin(op_neg(a), op_neg(b), k, G));
}

SDF_INLINE sdg op_min(sdg a, sdg b) { return b.d < a.d ? b : a; }
SDF_INLINE sdg op_max(sdg a, sdg b) { return b.d > a.d ? b : a; }

/* Signed distance to a plane through o with unit normal n (positive on
 * the side n points to). */
SDF_INLINE sdg sd_plane(v3 n, v3 o, v3 p)
{
    return sdg_make(v3_dot(n, v3_sub(p, o)), n);
}

#endif
