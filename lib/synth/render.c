/* Sphere-tracing renderer of a built head: rays in the head frame, the
 * head SDF marched up to the analytic eyeball hit, Lambert (wrapped for
 * skin) + Blinn specular shading with a corneal highlight, masks. Rows are
 * split into fixed blocks so the bytes never depend on the thread count. */
#include <stdlib.h>
#include <string.h>

#include "render_internal.h"

enum { K_BG = 0, K_HEAD, K_FACE, K_EYE_R, K_EYE_L, K_COUNT };

#define ROWS_PER_TASK 16
#define MAX_STEPS 160
#define AO_DIST 3.5f

static float srgb_encode(float c)
{
    return c <= 0.0031308f ? 12.92f * c : 1.055f * powf(c, 1.0f / 2.4f) - 0.055f;
}

static uint8_t to_u8(const render_ctx *r, float c)
{
    int i = (int)(clampf(c, 0.0f, 1.0f) * (float)(SRGB_LUT - 1) + 0.5f);
    return r->lut[i];
}

static v3 background(const render_ctx *r, float v)
{
    return v3_lerp(r->bg_top, r->bg_bottom, clampf(v / (float)r->height, 0, 1));
}

/* Sum of the lights' diffuse (wrapped by `wrap`) and Blinn terms. */
static void lighting(const render_ctx *r, v3 n, v3 view, float wrap,
                     float shininess, v3 *diff, v3 *spec)
{
    *diff = v3_make(0, 0, 0);
    *spec = v3_make(0, 0, 0);
    for (int i = 0; i < r->nl; i++) {
        float nl = v3_dot(n, r->ldir[i]);
        float w = clampf((nl + wrap) / (1.0f + wrap), 0.0f, 1.0f);
        *diff = v3_add(*diff, v3_scale(r->lrgb[i], w));
        if (r->specular && nl > 0.0f) {
            v3 hv = v3_norm(v3_add(r->ldir[i], view));
            float nh = maxf(0.0f, v3_dot(n, hv));
            *spec = v3_add(*spec, v3_scale(r->lrgb[i], powf(nh, shininess)));
        }
    }
}

/* Skin shading once the normal, material and ambient occlusion are known. */
static v3 shade_skin(const render_ctx *r, v3 p, v3 d, v3 n, int mat,
                     float ao_dist)
{
    const head_model *h = &r->head;
    v3 alb = gs_synth_skin_albedo(h, p, mat);
    float ao = 0.35f + 0.65f * clampf(ao_dist / AO_DIST, 0.0f, 1.0f);
    v3 view = v3_scale(d, -1.0f), diff, spec;
    float shin = mat == MAT_HAIR ? 12.0f : (mat == MAT_LIPS ? 40.0f : 24.0f);
    lighting(r, n, view, mat == MAT_HAIR ? 0.1f : 0.35f, shin, &diff, &spec);
    v3 c = v3_mul(alb, v3_add(v3_scale(r->ambient, ao), diff));
    float ks = h->shine * (mat == MAT_LIPS ? 2.0f : (mat == MAT_HAIR ? 0.6f : 1.0f));
    return v3_add(c, v3_scale(spec, ks * ao));
}

static v3 iris_albedo(const head_model *h, const eye_model *e, v3 q,
                      float rad)
{
    v3 rel = v3_sub(q, e->iris_c);
    float ca = v3_dot(rel, e->iris_u), sa = v3_dot(rel, e->iris_v);
    float len = sqrtf(ca * ca + sa * sa);
    if (len > 0.0f) {
        ca /= len;
        sa /= len;
    }
    float s = (rad - e->pupil_r) / (e->iris_r - e->pupil_r);
    uint32_t seed = h->tex_seed + 101u;
    float streak = gs_synth_noise3(v3_make(22.0f * ca, 22.0f * sa, 1.2f * s), seed);
    float crypt = gs_synth_noise3(v3_make(7.0f * ca, 7.0f * sa, 3.0f * s), seed + 7u);
    float t = clampf(0.55f + h->iris_pattern * (0.5f * streak + 0.35f * crypt),
                     0.0f, 1.0f);
    v3 a = v3_lerp(h->iris_b, h->iris_a, t);
    /* Collarette (lighter ring near the pupil), dark limbal ring. */
    float coll = expf(-(s - 0.3f) * (s - 0.3f) / 0.01f);
    a = v3_scale(a, 1.0f + 0.25f * coll);
    a = v3_scale(a, 1.0f - 0.6f * smoothstepf(0.8f, 1.0f, s));
    return a;
}

static v3 shade_eye(const render_ctx *r, const eye_model *e, v3 o, v3 d,
                    float t, int on_cornea)
{
    const head_model *h = &r->head;
    v3 p = v3_add(o, v3_scale(d, t));
    v3 view = v3_scale(d, -1.0f), diff, spec, alb;
    v3 n_sclera = v3_norm(v3_sub(p, e->c));
    v3 n_diff = n_sclera;
    float spec_k = 0.12f, shin = 60.0f;
    v3 n_spec = n_sclera;
    alb = h->sclera;
    if (on_cornea) {
        float dn = v3_dot(d, e->axis);
        float ti = dn < -1e-4f ? v3_dot(v3_sub(e->iris_c, o), e->axis) / dn : t;
        v3 q = v3_add(o, v3_scale(d, ti));
        float rad = v3_len(v3_sub(q, e->iris_c));
        if (rad < e->pupil_r) {
            alb = v3_make(0.008f, 0.008f, 0.009f);
            n_diff = v3_scale(e->axis, 1.0f);
        } else if (rad < e->iris_r) {
            alb = iris_albedo(h, e, q, rad);
            n_diff = e->axis;
        }
        n_spec = v3_norm(v3_sub(p, e->cornea_c));
        spec_k = 1.6f;
        shin = 300.0f;
    } else {
        /* Faint veins toward the corners. */
        float vein = gs_synth_noise3(v3_scale(p, 1.3f), h->tex_seed + 55u);
        float side = 1.0f - fabsf(v3_dot(n_sclera, e->axis));
        alb = v3_make(alb.x, alb.y * (1.0f - 0.12f * side * (0.5f + 0.5f * vein)),
                      alb.z * (1.0f - 0.15f * side * (0.5f + 0.5f * vein)));
    }
    /* The lids shade the eyeball near their margins. */
    float dl = gs_synth_lid_sdf(e, p);
    float occl = 0.35f + 0.65f * smoothstepf(e->lid_gap, 3.0f, dl);
    lighting(r, n_diff, view, 0.2f, shin, &diff, &spec);
    v3 c = v3_mul(alb, v3_add(v3_scale(r->ambient, occl), v3_scale(diff, occl)));
    if (r->specular) {
        v3 sd, ss;
        lighting(r, n_spec, view, 0.0f, shin, &sd, &ss);
        c = v3_add(c, v3_scale(ss, spec_k * occl));
    }
    return c;
}

static v3 pixel_dir(const render_ctx *r, float u, float v)
{
    const float *a = r->A;
    return v3_norm(v3_make(a[0] * u + a[1] * v + a[2], a[3] * u + a[4] * v + a[5],
                           a[6] * u + a[7] * v + a[8]));
}

/* Cone marching. A cone has axis u (the centre ray of a block of pixels)
 * and chord radius a (|dir - u| <= a for every ray of the block). The ball
 * of radius d around o + t u holds every ray point q(s) with
 * s <= (t + d) / (1 + a), hence the step rule; the march stops where the
 * ball no longer clears the cone, and no ray of the block meets the
 * surface before the t it returns. */
typedef struct cone {
    v3 u;
    float a, t;
    int done;
} cone;

static void cone_init(const render_ctx *r, cone *c, int x0, int y0, int x1,
                      int y1, float t)
{
    c->u = pixel_dir(r, 0.5f * (float)(x0 + x1), 0.5f * (float)(y0 + y1));
    float a = 0.0f;
    const float cx[2] = {(float)x0, (float)x1}, cy[2] = {(float)y0, (float)y1};
    for (int i = 0; i < 4; i++)
        a = maxf(a, v3_len(v3_sub(pixel_dir(r, cx[i & 1], cy[i >> 1]), c->u)));
    c->a = a * 1.05f + 1e-4f;
    c->t = t;
    c->done = t == INFINITY;
}

/* One step of cone c given the field d0 at its current point. */
static void cone_step(const render_ctx *r, cone *c, float d0, int step)
{
    const head_model *h = &r->head;
    float d = 0.9f * d0;
    if (d <= c->t * c->a + 0.25f || step >= 63) {
        c->done = 1;
        return;
    }
    c->t = (c->t + d) / (1.0f + c->a);
    if (c->t > v3_len(v3_sub(r->o, h->bound_c)) + h->bound_r) {
        c->t = INFINITY;
        c->done = 1;
    }
}

/* Marches n cones to completion, four at a time. */
static void march_cones(const render_ctx *r, cone *cs, int n)
{
    for (int k = 0; k < n; k += 4) {
        int m = n - k < 4 ? n - k : 4;
        for (int step = 0;; step++) {
            int live = 0;
            float x[4], y[4], z[4], dist[4];
            for (int l = 0; l < 4; l++) {
                const cone *c = &cs[k + (l < m ? l : 0)];
                float t = c->done ? 0.0f : c->t;
                v3 p = v3_add(r->o, v3_scale(c->u, t));
                x[l] = p.x;
                y[l] = p.y;
                z[l] = p.z;
                live += l < m && !c->done;
            }
            if (!live)
                break;
            gs_synth_head_sdf4(&r->head, x, y, z, dist);
            for (int l = 0; l < m; l++)
                if (!cs[k + l].done)
                    cone_step(r, &cs[k + l], dist[l], step);
        }
    }
}

#define TILE ROWS_PER_TASK
#define SUB 4
#define MAX_RAYS (SUB * SUB * 4)

/* One ray of a sub-tile through the phases: setup, march, shade. */
typedef struct ray_state {
    v3 d;            /* head-frame direction, unit */
    float v_px;      /* image row of the sample (background gradient) */
    float t, tlim, t_eye;
    int eye, on_cornea, hit, steps;
    int kind;
    v3 p, n;         /* skin hit point and normal */
    int mat;
    float ao;        /* field value at the ambient-occlusion probe */
    v3 c;            /* colour */
} ray_state;

/* Bounding sphere and eyes for one ray; the march starts at t_start. */
static void ray_setup(const render_ctx *r, ray_state *s, float t_start)
{
    const head_model *h = &r->head;
    s->kind = K_BG;
    s->eye = -1;
    s->hit = 0;
    s->steps = 0;
    s->t = INFINITY;
    s->tlim = 0.0f;
    s->t_eye = INFINITY;
    v3 oc = v3_sub(r->o, h->bound_c);
    float b = v3_dot(oc, s->d), c = v3_dot(oc, oc) - h->bound_r * h->bound_r;
    float disc = b * b - c;
    if (disc <= 0.0f)
        return;
    float sq = sqrtf(disc);
    float t0 = maxf(-b - sq, 1.0f), t1 = -b + sq;
    if (t1 <= t0)
        return;
    for (int i = 0; i < 2; i++) {
        int oc_i = 0;
        float te = gs_synth_eye_intersect(&h->eye[i], r->o, s->d, t0, t1, &oc_i);
        if (te < s->t_eye) {
            s->t_eye = te;
            s->eye = i;
            s->on_cornea = oc_i;
        }
    }
    s->tlim = minf(t1, s->t_eye);
    s->t = maxf(t0, t_start);
}

/* True while ray s still marches. */
static int ray_active(const ray_state *s)
{
    return !s->hit && s->steps < MAX_STEPS && s->t < s->tlim;
}

/* Sphere tracing of every ray, four at a time: lanes take the next
 * unfinished ray as soon as theirs is done. Each ray sees exactly the
 * steps a one-ray march would take, so packing changes no result. */
static void march_rays(const render_ctx *r, ray_state *rays, int n)
{
    int lane[4] = {-1, -1, -1, -1}, next = 0;
    for (;;) {
        int live = 0;
        for (int l = 0; l < 4; l++) {
            while (lane[l] < 0 && next < n) {
                if (ray_active(&rays[next]))
                    lane[l] = next;
                next++;
            }
            live += lane[l] >= 0;
        }
        if (!live)
            return;
        int some = 0; /* idle lanes repeat a live lane's point */
        while (lane[some] < 0)
            some++;
        float x[4], y[4], z[4], dist[4];
        for (int l = 0; l < 4; l++) {
            const ray_state *s = &rays[lane[l] >= 0 ? lane[l] : lane[some]];
            v3 p = v3_add(r->o, v3_scale(s->d, s->t));
            x[l] = p.x;
            y[l] = p.y;
            z[l] = p.z;
        }
        gs_synth_head_sdf4(&r->head, x, y, z, dist);
        for (int l = 0; l < 4; l++) {
            if (lane[l] < 0)
                continue;
            ray_state *s = &rays[lane[l]];
            float eps = 0.01f + r->px_angle * s->t * 0.4f;
            s->steps++;
            if (dist[l] < eps)
                s->hit = 1;
            else
                s->t += 0.9f * dist[l];
            if (!ray_active(s))
                lane[l] = -1;
        }
    }
}

/* Normals and materials, then the ambient-occlusion probes four at a
 * time, then colours. */
static void shade_rays(const render_ctx *r, ray_state *rays, int n)
{
    const head_model *h = &r->head;
    int skin[MAX_RAYS] = {0}, ns = 0;
    for (int i = 0; i < n; i++) {
        ray_state *s = &rays[i];
        if (s->hit && s->t < s->t_eye) {
            v3 g;
            s->p = v3_add(r->o, v3_scale(s->d, s->t));
            gs_synth_head_surface(h, s->p, &g, &s->mat);
            s->n = v3_norm(g);
            s->kind = gs_synth_head_is_face(h, s->p, s->mat) ? K_FACE : K_HEAD;
            skin[ns++] = i;
        } else if (s->eye >= 0) {
            const eye_model *e = &h->eye[s->eye];
            s->kind = e->side == 0 ? K_EYE_R : K_EYE_L;
            s->c = shade_eye(r, e, r->o, s->d, s->t_eye, s->on_cornea);
        } else {
            s->kind = K_BG;
            s->c = background(r, s->v_px);
        }
    }
    for (int k = 0; k < ns; k += 4) {
        float x[4], y[4], z[4], dist[4];
        for (int l = 0; l < 4; l++) {
            const ray_state *s = &rays[skin[k + l < ns ? k + l : k]];
            v3 q = v3_add(s->p, v3_scale(s->n, AO_DIST));
            x[l] = q.x;
            y[l] = q.y;
            z[l] = q.z;
        }
        gs_synth_head_sdf4(h, x, y, z, dist);
        for (int l = 0; l < 4 && k + l < ns; l++)
            rays[skin[k + l]].ao = dist[l];
    }
    for (int k = 0; k < ns; k++) {
        ray_state *s = &rays[skin[k]];
        s->c = shade_skin(r, s->p, s->d, s->n, s->mat, s->ao);
    }
}

/* Writes pixel (x, y) from its ns consecutive samples. */
static void write_pixel(const render_ctx *r, int x, int y, const ray_state *s,
                        int ns)
{
    gs_synth_sample *out = r->out;
    size_t plane = (size_t)r->width * (size_t)r->height;
    uint8_t *row = out->rgb + (size_t)y * out->stride;
    v3 acc = v3_make(0, 0, 0);
    int count[K_COUNT] = {0};
    for (int k = 0; k < ns; k++) {
        acc = v3_add(acc, s[k].c);
        count[s[k].kind]++;
    }
    acc = v3_scale(acc, 1.0f / (float)ns);
    row[3 * x] = to_u8(r, acc.x);
    row[3 * x + 1] = to_u8(r, acc.y);
    row[3 * x + 2] = to_u8(r, acc.z);
    /* The pixel's class is its most frequent hit; ties favour the eyes,
     * then the face. Head = at least half the samples hit. */
    static const int prio[K_COUNT] = {K_EYE_L, K_EYE_R, K_FACE, K_HEAD, K_BG};
    int best = K_BG;
    for (int k = 0; k < K_COUNT; k++)
        if (count[prio[k]] > count[best])
            best = prio[k];
    size_t i = (size_t)y * (size_t)r->width + (size_t)x;
    int head = 2 * (ns - count[K_BG]) >= ns;
    out->mask[i + plane * GS_SYNTH_MASK_HEAD] = head ? 255 : 0;
    out->mask[i + plane * GS_SYNTH_MASK_FACE] = best == K_FACE ? 255 : 0;
    out->mask[i + plane * GS_SYNTH_MASK_LEFT_EYE] = best == K_EYE_L ? 255 : 0;
    out->mask[i + plane * GS_SYNTH_MASK_RIGHT_EYE] = best == K_EYE_R ? 255 : 0;
}

/* All samples of the sub-tile [x0, x1) x [y0, y1), pixel-major. */
static void render_subtile(const render_ctx *r, int x0, int y0, int x1,
                           int y1, float t_start)
{
    ray_state rays[MAX_RAYS];
    int ss = r->ss, ns = ss * ss, n = 0;
    for (int y = y0; y < y1; y++)
        for (int x = x0; x < x1; x++)
            for (int sy = 0; sy < ss; sy++)
                for (int sx = 0; sx < ss; sx++) {
                    float u = (float)x + (ss == 1 ? 0.5f : 0.25f + 0.5f * (float)sx);
                    float v = (float)y + (ss == 1 ? 0.5f : 0.25f + 0.5f * (float)sy);
                    ray_state *s = &rays[n++];
                    s->d = pixel_dir(r, u, v);
                    s->v_px = v;
                    ray_setup(r, s, t_start);
                }
    march_rays(r, rays, n);
    shade_rays(r, rays, n);
    int k = 0;
    for (int y = y0; y < y1; y++)
        for (int x = x0; x < x1; x++, k += ns)
            write_pixel(r, x, y, &rays[k], ns);
}

/* A band of TILE rows: cone-march each TILE x TILE tile, then its
 * SUB x SUB sub-tiles from the tile's start, then their rays. */
static void render_rows(void *vctx, int task, int worker)
{
    (void)worker;
    const render_ctx *r = vctx;
    const head_model *h = &r->head;
    int y0 = (r->ry0 / TILE + task) * TILE;
    int y1 = y0 + TILE < r->height ? y0 + TILE : r->height;
    float t_near = maxf(0.0f, v3_len(v3_sub(r->o, h->bound_c)) - h->bound_r);
    enum { NSUB = (TILE / SUB) * (TILE / SUB) };
    for (int x0 = r->rx0 / TILE * TILE; x0 < r->rx1; x0 += TILE) {
        int x1 = x0 + TILE < r->width ? x0 + TILE : r->width;
        cone tile;
        cone_init(r, &tile, x0, y0, x1, y1, t_near);
        march_cones(r, &tile, 1);
        cone subs[NSUB];
        int box[NSUB][4], n = 0;
        for (int sy = y0; sy < y1; sy += SUB)
            for (int sx = x0; sx < x1; sx += SUB) {
                box[n][0] = sx;
                box[n][1] = sy;
                box[n][2] = sx + SUB < x1 ? sx + SUB : x1;
                box[n][3] = sy + SUB < y1 ? sy + SUB : y1;
                cone_init(r, &subs[n], box[n][0], box[n][1], box[n][2],
                          box[n][3], tile.t);
                n++;
            }
        march_cones(r, subs, n);
        for (int i = 0; i < n; i++)
            render_subtile(r, box[i][0], box[i][1], box[i][2], box[i][3],
                           subs[i].t);
    }
}

static v3 to_v3(const double *a)
{
    return v3_make((float)a[0], (float)a[1], (float)a[2]);
}

void gs_synth_render_setup(render_ctx *r, const gs_synth_scene *s,
                           const gs_synth_camera *cam, int ss)
{
    /* Head to camera: R_hc = R_c R_hw, t_hc = R_c t_hw + t_c. */
    double rhc[9], thc[3], kinv[9], a[9], o[3];
    gs_geom_mat3_mul(cam->R, s->head_R, rhc);
    gs_geom_mat3_vec(cam->R, s->head_t, thc);
    for (int i = 0; i < 3; i++)
        thc[i] += cam->t[i];
    gs_geom_mat3_tvec(rhc, thc, o);
    r->o = v3_make((float)-o[0], (float)-o[1], (float)-o[2]);
    gs_geom_mat3_inverse(cam->K, kinv);
    double rt[9];
    gs_geom_mat3_transpose(rhc, rt);
    gs_geom_mat3_mul(rt, kinv, a);
    for (int i = 0; i < 9; i++)
        r->A[i] = (float)a[i];
    r->px_angle = (float)(1.0 / cam->K[0]);
    r->nl = s->n_lights < 0 ? 0 : (s->n_lights > 2 ? 2 : s->n_lights);
    for (int i = 0; i < r->nl; i++) {
        double l[3] = {s->light[i].dir[0], s->light[i].dir[1], s->light[i].dir[2]};
        gs_geom_vec3_normalize(l);
        gs_geom_mat3_tvec(s->head_R, l, l); /* world -> head */
        r->ldir[i] = to_v3(l);
        r->lrgb[i] = v3_make(s->light[i].rgb[0], s->light[i].rgb[1], s->light[i].rgb[2]);
    }
    r->ambient = v3_make(s->ambient[0], s->ambient[1], s->ambient[2]);
    r->bg_top = v3_make(s->bg_top[0], s->bg_top[1], s->bg_top[2]);
    r->bg_bottom = v3_make(s->bg_bottom[0], s->bg_bottom[1], s->bg_bottom[2]);
    r->specular = s->specular;
    r->width = cam->width;
    r->height = cam->height;
    r->ss = ss;
    r->rx0 = r->ry0 = 0;
    r->rx1 = r->width;
    r->ry1 = r->height;
    for (int i = 0; i < SRGB_LUT; i++) {
        float c = srgb_encode((float)i / (float)(SRGB_LUT - 1));
        r->lut[i] = (uint8_t)(c * 255.0f + 0.5f);
    }
}

void gs_synth_render_pixels(render_ctx *r, gs_pool *pool)
{
    int ntasks = (r->ry1 + TILE - 1) / TILE - r->ry0 / TILE;
    gs_pool_for(pool, ntasks, render_rows, r);
}
