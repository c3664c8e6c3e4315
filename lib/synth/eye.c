/* Eyeballs: analytic intersection of the sclera + cornea union and the
 * appearance of sclera, iris and pupil. */
#include "synth_internal.h"

/* Entry distance of the ray into sphere (c, r), or INFINITY. */
static float sphere_entry(v3 c, float r, v3 o, v3 d, float tmin)
{
    v3 oc = v3_sub(o, c);
    float b = v3_dot(oc, d);
    float cc = v3_dot(oc, oc) - r * r;
    float disc = b * b - cc;
    if (disc < 0.0f)
        return INFINITY;
    float s = sqrtf(disc);
    float t = -b - s;
    if (t < tmin) /* starting inside or the sphere is behind */
        return INFINITY;
    return t;
}

float gs_synth_eye_intersect(const eye_model *e, v3 o, v3 d, float tmin,
                             float tmax, int *on_cornea)
{
    /* The union's entry is the earlier of the two spheres' entries: a
     * sphere's entry point cannot lie inside the other sphere unless the
     * ray entered that one first. */
    float ts = sphere_entry(e->c, e->r_sclera, o, d, tmin);
    float tc = sphere_entry(e->cornea_c, e->r_cornea, o, d, tmin);
    float t = minf(ts, tc);
    if (!(t <= tmax))
        return INFINITY;
    *on_cornea = tc < ts;
    return t;
}
