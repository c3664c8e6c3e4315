/* The neutral template for Gaussian initialisation: surface points of the
 * mean head with normals, albedo and region labels, plus its landmarks.
 *
 * Head surface: a grid of `spacing` over the head's bounding box; blocks
 * of 8^3 cells far from the surface are skipped with one field value (the
 * field is close to 1-Lipschitz), each remaining cell centre near the
 * surface is projected onto it by Newton steps and kept when it lands in
 * its own cell, so the points are about `spacing` apart and never
 * duplicated. Slabs of the grid run in parallel into their own buffers,
 * joined in order: the result does not depend on the thread count.
 * Eyes: a Fibonacci sphere on each eyeball union (sclera, corneal cap),
 * within 100 degrees of the optical axis. */
#include <stdlib.h>
#include <string.h>

#include "synth_internal.h"

#define BLOCK 8

typedef struct tpoint {
    float xyz[3], n[3], rgb[3];
    uint8_t region;
} tpoint;

typedef struct tbuf {
    tpoint *p;
    int n, cap;
    int failed;
} tbuf;

typedef struct tctx {
    const head_model *h;
    float spacing;
    v3 lo;
    int nx, ny, nz;
    tbuf *slabs; /* one per block row in z */
} tctx;

static void tbuf_push(tbuf *b, const tpoint *p)
{
    if (b->failed)
        return;
    if (b->n == b->cap) {
        int cap = b->cap ? 2 * b->cap : 1024;
        tpoint *q = realloc(b->p, (size_t)cap * sizeof *q);
        if (!q) {
            b->failed = 1;
            return;
        }
        b->p = q;
        b->cap = cap;
    }
    b->p[b->n++] = *p;
}

static float to_srgb(float c)
{
    c = clampf(c, 0.0f, 1.0f);
    return c <= 0.0031308f ? 12.92f * c : 1.055f * powf(c, 1.0f / 2.4f) - 0.055f;
}

static void set_rgb(tpoint *t, v3 lin)
{
    t->rgb[0] = to_srgb(lin.x);
    t->rgb[1] = to_srgb(lin.y);
    t->rgb[2] = to_srgb(lin.z);
}

/* Projects a cell centre onto the surface; 1 when it lands in the cell. */
static int surface_point(const head_model *h, v3 c, float s, tpoint *out)
{
    v3 p = c, g = v3_make(0, 0, 1);
    float d = 0.0f;
    for (int i = 0; i < 8; i++) {
        d = gs_synth_head_sdf_grad(h, p, &g);
        float gg = v3_dot(g, g);
        if (gg < 1e-8f)
            return 0;
        p = v3_sub(p, v3_scale(g, d / gg));
    }
    d = gs_synth_head_sdf_grad(h, p, &g);
    v3 q = v3_sub(p, c);
    if (fabsf(d) > 1e-3f * s || fabsf(q.x) > 0.5f * s || fabsf(q.y) > 0.5f * s ||
        fabsf(q.z) > 0.5f * s)
        return 0;
    if (p.y > h->neck_cut_y - 1.0f) /* the flat cut under the neck */
        return 0;
    v3 n = v3_norm(g);
    int mat = gs_synth_head_material(h, p);
    out->xyz[0] = p.x;
    out->xyz[1] = p.y;
    out->xyz[2] = p.z;
    out->n[0] = n.x;
    out->n[1] = n.y;
    out->n[2] = n.z;
    set_rgb(out, gs_synth_skin_albedo(h, p, mat));
    out->region = gs_synth_head_is_face(h, p, mat) ? GS_SYNTH_REGION_FACE
                                                   : GS_SYNTH_REGION_HEAD;
    return 1;
}

/* All points of the blocks whose z-block index is `task`. */
static void slab_task(void *vctx, int task, int worker)
{
    (void)worker;
    tctx *t = vctx;
    tbuf *b = &t->slabs[task];
    const float s = t->spacing, half_diag = 0.5f * s * BLOCK * 1.7321f;
    for (int by = 0; by < t->ny; by += BLOCK)
        for (int bx = 0; bx < t->nx; bx += BLOCK) {
            int bz = task * BLOCK;
            v3 bc = v3_add(t->lo, v3_make(s * ((float)bx + 0.5f * BLOCK),
                                          s * ((float)by + 0.5f * BLOCK),
                                          s * ((float)bz + 0.5f * BLOCK)));
            if (fabsf(gs_synth_head_sdf(t->h, bc)) > 1.25f * half_diag + s)
                continue;
            for (int z = bz; z < bz + BLOCK && z < t->nz; z++)
                for (int y = by; y < by + BLOCK && y < t->ny; y++)
                    for (int x = bx; x < bx + BLOCK && x < t->nx; x++) {
                        v3 c = v3_add(t->lo, v3_make(s * ((float)x + 0.5f),
                                                     s * ((float)y + 0.5f),
                                                     s * ((float)z + 0.5f)));
                        if (fabsf(gs_synth_head_sdf(t->h, c)) > s)
                            continue;
                        tpoint pt;
                        if (surface_point(t->h, c, s, &pt))
                            tbuf_push(b, &pt);
                    }
        }
}

/* Albedo of an eyeball surface point (linear). */
static v3 eye_albedo(const head_model *h, const eye_model *e, v3 p)
{
    v3 rel = v3_sub(p, e->c);
    float along = v3_dot(rel, e->axis);
    if (along < e->iris_d)
        return h->sclera;
    v3 q = v3_sub(rel, v3_scale(e->axis, along)); /* off-axis part */
    float r = v3_len(q);
    if (r < e->pupil_r)
        return v3_make(0.008f, 0.008f, 0.009f);
    if (r < e->iris_r)
        return v3_lerp(h->iris_b, h->iris_a, 0.55f);
    return h->sclera;
}

static void eye_points(const head_model *h, int side, float s, tbuf *b)
{
    const eye_model *e = &h->eye[side];
    int region = e->side == 0 ? GS_SYNTH_REGION_RIGHT_EYE : GS_SYNTH_REGION_LEFT_EYE;
    const float golden = 2.39996323f, cos_max = -0.17364818f; /* 100 deg */
    for (int sphere = 0; sphere < 2; sphere++) {
        v3 c = sphere ? e->cornea_c : e->c;
        float r = sphere ? e->r_cornea : e->r_sclera;
        int n = (int)(4.0f * 3.14159265f * r * r / (s * s)) + 1;
        for (int i = 0; i < n; i++) {
            float z = 1.0f - 2.0f * ((float)i + 0.5f) / (float)n;
            float rr = sqrtf(maxf(0.0f, 1.0f - z * z)), a = golden * (float)i;
            v3 u = v3_make(rr * cosf(a), rr * sinf(a), z);
            v3 p = v3_add(c, v3_scale(u, r));
            if (v3_dot(v3_norm(v3_sub(p, e->c)), e->axis) < cos_max)
                continue;
            /* On the union: not inside the other sphere. */
            v3 oc = sphere ? e->c : e->cornea_c;
            float orad = sphere ? e->r_sclera : e->r_cornea;
            if (v3_len(v3_sub(p, oc)) < orad)
                continue;
            tpoint t;
            t.xyz[0] = p.x;
            t.xyz[1] = p.y;
            t.xyz[2] = p.z;
            t.n[0] = u.x;
            t.n[1] = u.y;
            t.n[2] = u.z;
            set_rgb(&t, eye_albedo(h, e, p));
            t.region = (uint8_t)region;
            tbuf_push(b, &t);
        }
    }
}

static int fill_template(const tbuf *slabs, int nslabs, const tbuf *eyes,
                         gs_synth_template *t)
{
    int n = eyes->n;
    for (int i = 0; i < nslabs; i++)
        n += slabs[i].n;
    t->n = n;
    t->xyz = malloc((size_t)n * 3 * sizeof(float));
    t->normal = malloc((size_t)n * 3 * sizeof(float));
    t->rgb = malloc((size_t)n * 3 * sizeof(float));
    t->region = malloc((size_t)n);
    if (!t->xyz || !t->normal || !t->rgb || !t->region)
        return GS_ERR_NOMEM;
    int k = 0;
    for (int i = 0; i <= nslabs; i++) {
        const tbuf *b = i < nslabs ? &slabs[i] : eyes;
        for (int j = 0; j < b->n; j++, k++) {
            memcpy(&t->xyz[3 * k], b->p[j].xyz, sizeof b->p[j].xyz);
            memcpy(&t->normal[3 * k], b->p[j].n, sizeof b->p[j].n);
            memcpy(&t->rgb[3 * k], b->p[j].rgb, sizeof b->p[j].rgb);
            t->region[k] = b->p[j].region;
        }
    }
    return GS_OK;
}

int gs_synth_template_build(double spacing_mm, gs_pool *pool,
                            gs_synth_template *t, gs_error *err)
{
    memset(t, 0, sizeof *t);
    if (!(spacing_mm >= 0.5 && spacing_mm <= 20.0))
        return gs_error_set(err, GS_ERR_ARG,
                            "template: spacing %g mm outside 0.5..20", spacing_mm);
    head_model *h = malloc(sizeof *h);
    if (!h)
        return gs_error_set(err, GS_ERR_NOMEM, "template: out of memory");
    gs_synth_identity id;
    gs_synth_expression ex;
    gs_synth_identity_mean(&id);
    gs_synth_expression_neutral(&ex);
    gs_synth_head_build(&id, &ex, 0.0, 0.0, h);
    tctx c;
    c.h = h;
    c.spacing = (float)spacing_mm;
    float r = h->bound_r;
    c.lo = v3_sub(h->bound_c, v3_make(r, r, r));
    c.nx = c.ny = c.nz = (int)ceilf(2.0f * r / c.spacing);
    int nslabs = (c.nz + BLOCK - 1) / BLOCK;
    c.slabs = calloc((size_t)nslabs, sizeof *c.slabs);
    tbuf eyes = {0};
    int rc = c.slabs ? GS_OK : GS_ERR_NOMEM;
    if (rc == GS_OK) {
        gs_pool_for(pool, nslabs, slab_task, &c);
        for (int e = 0; e < 2; e++)
            eye_points(h, e, c.spacing, &eyes);
        for (int i = 0; i < nslabs; i++)
            rc = c.slabs[i].failed ? GS_ERR_NOMEM : rc;
        rc = eyes.failed ? GS_ERR_NOMEM : rc;
    }
    if (rc == GS_OK)
        rc = fill_template(c.slabs, nslabs, &eyes, t);
    if (rc == GS_OK) {
        gs_synth_head_landmarks(h, t->landmarks);
        for (int e = 0; e < 2; e++) {
            t->eye_centre[e][0] = h->eye[e].c.x;
            t->eye_centre[e][1] = h->eye[e].c.y;
            t->eye_centre[e][2] = h->eye[e].c.z;
        }
        t->eyeball_radius_mm = h->eye[0].r_sclera;
    }
    for (int i = 0; c.slabs && i < nslabs; i++)
        free(c.slabs[i].p);
    free(c.slabs);
    free(eyes.p);
    free(h);
    if (rc != GS_OK) {
        gs_synth_template_free(t);
        return gs_error_set(err, rc, "template: out of memory");
    }
    return GS_OK;
}

void gs_synth_template_free(gs_synth_template *t)
{
    free(t->xyz);
    free(t->normal);
    free(t->rgb);
    free(t->region);
    memset(t, 0, sizeof *t);
}
