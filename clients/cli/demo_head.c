/* The demo scene: a stylised head made of Gaussians, centred at the world
 * origin, facing -z (toward a camera at z = -4), x right, y down.
 *
 * Skin and hair are flat discs on an ellipsoid shell, oriented along the
 * surface normal; eyes, brows and lips are discs facing the camera just in
 * front of the shell; the nose is a chain of small ellipsoids standing out
 * of it. Lighting is baked into the colours (one light from the upper left
 * front) so the shape reads in a plain degree-0 SH render. The seed jitters
 * positions and colours and picks the iris colour; the same seed gives the
 * same bytes. */
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "cli.h"
#include "gazesplat/ply.h"

#define HEAD_MAX_SPLATS 8192

/* Head ellipsoid semi-axes. */
static const float AX = 0.80f, AY = 1.02f, AZ = 0.88f;

typedef struct splat {
    float pos[3], sigma[3], quat[4], rgb[3], opacity;
} splat;

typedef struct head {
    splat *s;
    int n;
    uint64_t rng;
    float skin[3], hair[3], iris[3];
} head;

/* splitmix64 -> uniform in [-1, 1). */
static float jitter(head *h)
{
    uint64_t z = (h->rng += 0x9e3779b97f4a7c15ull);
    z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ull;
    z = (z ^ (z >> 27)) * 0x94d049bb133111ebull;
    z ^= z >> 31;
    return (float)(z >> 40) / (float)(1u << 23) - 1.0f;
}

static void normalize3(float v[3])
{
    float l = sqrtf(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
    v[0] /= l, v[1] /= l, v[2] /= l;
}

/* Baked diffuse light: ambient plus a light toward the upper left front. */
static float shade(const float n[3])
{
    float l[3] = {-0.45f, -0.55f, -0.70f};
    normalize3(l);
    float d = n[0] * l[0] + n[1] * l[1] + n[2] * l[2];
    return 0.45f + 0.55f * (d > 0 ? d : 0);
}

/* Quaternion (wxyz) turning +z into n: a disc lying in the tangent plane. */
static void quat_to_normal(const float n[3], float q[4])
{
    if (1.0f + n[2] < 1e-6f) {
        q[0] = 0, q[1] = 1, q[2] = 0, q[3] = 0;
        return;
    }
    q[0] = 1.0f + n[2], q[1] = -n[1], q[2] = n[0], q[3] = 0;
    float l = sqrtf(q[0] * q[0] + q[1] * q[1] + q[2] * q[2]);
    q[0] /= l, q[1] /= l, q[2] /= l;
}

/* Rotation by angle about z: for camera-facing discs. */
static void quat_about_z(float angle, float q[4])
{
    q[0] = cosf(0.5f * angle), q[1] = 0, q[2] = 0, q[3] = sinf(0.5f * angle);
}

static void add(head *h, const float pos[3], const float sigma[3], const float q[4],
                const float rgb[3], float k, float opacity)
{
    if (h->n == HEAD_MAX_SPLATS)
        return;
    splat *s = &h->s[h->n++];
    for (int i = 0; i < 3; i++) {
        s->pos[i] = pos[i];
        s->sigma[i] = sigma[i];
        float c = rgb[i] * k * (1.0f + 0.03f * jitter(h));
        s->rgb[i] = c < 0 ? 0 : c > 1 ? 1 : c;
    }
    memcpy(s->quat, q, sizeof s->quat);
    s->opacity = opacity;
}

/* z of the head surface (front side) at (x, y); the shell's silhouette
 * value where (x, y) lies outside. */
static float surface_z(float x, float y)
{
    float r = 1.0f - (x / AX) * (x / AX) - (y / AY) * (y / AY);
    return -AZ * sqrtf(r > 0 ? r : 0);
}

/* Hair covers the top, the back and the sides above the ears. */
static int is_hair(const float u[3])
{
    return u[1] < -0.58f || (u[2] > 0.1f && u[1] < 0.42f) || (fabsf(u[0]) > 0.8f && u[1] < -0.1f);
}

/* Skin and hair: n points of a Fibonacci sphere mapped onto the ellipsoid. */
static void add_shell(head *h, int n)
{
    const float golden = 2.39996323f;
    for (int i = 0; i < n; i++) {
        float u[3], p[3], nrm[3], q[4];
        u[1] = -1.0f + (2.0f * (float)i + 1.0f) / (float)n;
        float r = sqrtf(1.0f - u[1] * u[1]);
        u[0] = r * cosf(golden * (float)i);
        u[2] = r * sinf(golden * (float)i);
        int hair = is_hair(u);
        float lift = hair ? 1.04f : 1.0f;
        p[0] = AX * u[0] * lift + 0.004f * jitter(h);
        p[1] = AY * u[1] * lift + 0.004f * jitter(h);
        p[2] = AZ * u[2] * lift + 0.004f * jitter(h);
        nrm[0] = u[0] / AX, nrm[1] = u[1] / AY, nrm[2] = u[2] / AZ;
        normalize3(nrm);
        quat_to_normal(nrm, q);
        float sig[3] = {hair ? 0.055f : 0.042f, hair ? 0.05f : 0.042f, 0.008f};
        float rgb[3];
        memcpy(rgb, hair ? h->hair : h->skin, sizeof rgb);
        /* A little colour on the cheeks. */
        float b = 0;
        for (int side = -1; side <= 1; side += 2)
            b += expf(-((u[0] - 0.5f * (float)side) * (u[0] - 0.5f * (float)side) +
                        (u[1] - 0.22f) * (u[1] - 0.22f)) / 0.015f);
        if (!hair && u[2] < 0)
            rgb[0] += 0.06f * b, rgb[1] -= 0.04f * b, rgb[2] -= 0.03f * b;
        add(h, p, sig, q, rgb, shade(nrm) * (hair ? 1.0f + 0.2f * jitter(h) : 1.0f), 0.92f);
    }
}

/* Neck: an elliptic cylinder under the head, in the chin's shadow. */
static void add_neck(head *h)
{
    for (float y = 0.70f; y < 1.50f; y += 0.06f) {
        for (int k = 0; k < 32; k++) {
            float a = 6.2831853f * (float)k / 32.0f;
            float nrm[3] = {cosf(a) / 0.42f, 0, sinf(a) / 0.36f}, q[4];
            float p[3] = {0.42f * cosf(a), y, 0.12f + 0.36f * sinf(a)};
            float sig[3] = {0.045f, 0.04f, 0.008f};
            normalize3(nrm);
            quat_to_normal(nrm, q);
            add(h, p, sig, q, h->skin, 0.8f * shade(nrm), 0.92f);
        }
    }
}

/* Shoulders: the top of a wide ellipsoid in a shirt colour. */
static void add_shoulders(head *h)
{
    static const float shirt[3] = {0.22f, 0.34f, 0.55f};
    for (int i = 0; i < 900; i++) {
        float u[3], nrm[3], q[4];
        u[1] = -1.0f + (float)i / 900.0f; /* upper half only */
        float r = sqrtf(1.0f - u[1] * u[1]);
        u[0] = r * cosf(2.39996323f * (float)i);
        u[2] = r * sinf(2.39996323f * (float)i);
        float p[3] = {1.6f * u[0], 2.15f + 0.75f * u[1], 0.2f + 0.6f * u[2]};
        float sig[3] = {0.07f, 0.06f, 0.01f};
        nrm[0] = u[0] / 1.6f, nrm[1] = u[1] / 0.75f, nrm[2] = u[2] / 0.6f;
        normalize3(nrm);
        quat_to_normal(nrm, q);
        add(h, p, sig, q, shirt, shade(nrm), 0.95f);
    }
}

static void add_ears(head *h)
{
    for (int side = -1; side <= 1; side += 2) {
        for (int i = 0; i < 70; i++) {
            float u[3], nrm[3], q[4];
            u[1] = -1.0f + (2.0f * (float)i + 1.0f) / 70.0f;
            float r = sqrtf(1.0f - u[1] * u[1]);
            u[0] = r * cosf(2.39996323f * (float)i);
            u[2] = r * sinf(2.39996323f * (float)i);
            float p[3] = {(float)side * 0.79f + 0.07f * u[0], 0.05f + 0.17f * u[1], 0.05f + 0.11f * u[2]};
            float sig[3] = {0.03f, 0.03f, 0.006f};
            nrm[0] = u[0] / 0.07f, nrm[1] = u[1] / 0.17f, nrm[2] = u[2] / 0.11f;
            normalize3(nrm);
            quat_to_normal(nrm, q);
            add(h, p, sig, q, h->skin, 0.9f * shade(nrm), 0.92f);
        }
    }
}

/* A disc facing the camera at (x, y, z), turned by angle in the image plane. */
static void add_flat(head *h, float x, float y, float z, float sx, float sy, float angle,
                     const float rgb[3], float k, float opacity)
{
    float p[3] = {x, y, z}, sig[3] = {sx, sy, 0.004f}, q[4];
    quat_about_z(angle, q);
    add(h, p, sig, q, rgb, k, opacity);
}

/* Inside the almond outline of an eye (half sizes w, hh), 0..1 scale. */
static int in_almond(float dx, float dy, float w, float hh)
{
    float t = dx / w, lim = hh * (1.0f - t * t);
    return fabsf(t) <= 1.0f && fabsf(dy) <= lim;
}

static void add_eye(head *h, float cx, float cy)
{
    static const float white[3] = {0.96f, 0.95f, 0.93f}, lid[3] = {0.22f, 0.13f, 0.10f};
    static const float black[3] = {0.02f, 0.02f, 0.02f}, glint[3] = {1, 1, 1};
    const float w = 0.13f, hh = 0.065f, z = surface_z(cx, cy) - 0.015f;
    for (float dy = -hh; dy <= hh + 1e-4f; dy += 0.018f)
        for (float dx = -w; dx <= w + 1e-4f; dx += 0.02f)
            if (in_almond(dx, dy, w + 0.01f, hh + 0.01f))
                add_flat(h, cx + dx, cy + dy, z, 0.014f, 0.012f, 0, white, 1.0f, 0.97f);
    for (float dx = -w - 0.01f; dx <= w + 0.011f; dx += 0.011f) {
        float t = dx / (w + 0.01f), ylid = -hh * (1.0f - t * t);
        add_flat(h, cx + dx, cy + ylid, z - 0.004f, 0.011f, 0.006f, atanf(2.0f * hh * t / w),
                 lid, 1.0f, 0.95f);
    }
    /* Iris rings, clipped to the almond, then pupil and a glint. */
    static const float ring_r[4] = {0, 0.018f, 0.034f, 0.047f};
    static const int ring_n[4] = {1, 7, 13, 18};
    for (int r = 0; r < 4; r++) {
        for (int k = 0; k < ring_n[r]; k++) {
            float a = 6.2831853f * (float)k / (float)ring_n[r];
            float dx = ring_r[r] * cosf(a), dy = ring_r[r] * sinf(a);
            if (in_almond(dx, dy, w, hh))
                add_flat(h, cx + dx, cy + dy, z - 0.006f, r == 3 ? 0.008f : 0.013f,
                         r == 3 ? 0.008f : 0.013f, 0, h->iris, r == 3 ? 0.55f : 1.0f, 0.97f);
        }
    }
    add_flat(h, cx, cy, z - 0.009f, 0.018f, 0.018f, 0, black, 1.0f, 0.99f);
    add_flat(h, cx - 0.018f, cy - 0.018f, z - 0.012f, 0.007f, 0.007f, 0, glint, 1.0f, 0.9f);
}

static void add_brow(head *h, float cx, float side)
{
    for (float t = -1.0f; t <= 1.001f; t += 0.2f) {
        float x = cx + side * 0.15f * t, y = -0.25f - 0.04f * (1.0f - t * t) + 0.015f * t;
        float slope = side * (0.08f * t - 0.015f) / 0.15f;
        add_flat(h, x, y, surface_z(x, y) - 0.012f, 0.028f, 0.011f, atanf(slope), h->hair, 0.9f,
                 0.9f);
    }
}

/* Nose: a chain of ellipsoids along the bridge to the tip, wings,
 * nostrils and the shadow under it. */
static void add_nose(head *h)
{
    static const float dark[3] = {0.28f, 0.13f, 0.10f};
    const float id[4] = {1, 0, 0, 0};
    for (int i = 0; i <= 12; i++) {
        float t = (float)i / 12.0f, y = -0.08f + 0.28f * t;
        float d = 0.02f + 0.12f * t * sqrtf(t);
        float p[3] = {0, y, surface_z(0, y) - 0.6f * d};
        float sig[3] = {0.028f + 0.012f * t, 0.03f, 0.6f * d + 0.015f};
        float front[3] = {0, -0.25f, -1}, left[3] = {-0.8f, -0.1f, -0.6f}, right[3] = {0.8f, -0.1f, -0.6f};
        normalize3(front), normalize3(left), normalize3(right);
        add(h, p, sig, id, h->skin, shade(front), 0.9f);
        for (int side = -1; side <= 1; side += 2) {
            float ps[3] = {(float)side * (0.03f + 0.01f * t), y, p[2] + 0.3f * d};
            float ss[3] = {0.018f, 0.03f, 0.5f * d + 0.01f};
            add(h, ps, ss, id, h->skin, shade(side < 0 ? left : right), 0.9f);
        }
    }
    float ztip = surface_z(0, 0.2f);
    float tip[3] = {0, 0.2f, ztip - 0.13f}, stip[3] = {0.045f, 0.04f, 0.04f};
    float nt[3] = {-0.2f, -0.2f, -1};
    normalize3(nt);
    add(h, tip, stip, id, h->skin, shade(nt), 0.95f);
    for (int side = -1; side <= 1; side += 2) {
        float wing[3] = {(float)side * 0.065f, 0.22f, ztip - 0.07f}, sw[3] = {0.03f, 0.03f, 0.03f};
        float nw[3] = {(float)side * 0.7f, 0, -0.7f};
        normalize3(nw);
        add(h, wing, sw, id, h->skin, 0.92f * shade(nw), 0.95f);
        add_flat(h, (float)side * 0.03f, 0.255f, ztip - 0.115f, 0.016f, 0.009f, 0, dark, 1.0f,
                 0.9f);
    }
    add_flat(h, 0, 0.29f, surface_z(0, 0.29f) - 0.02f, 0.07f, 0.02f, 0, h->skin, 0.6f, 0.5f);
}

static void add_lips(head *h)
{
    static const float upper[3] = {0.66f, 0.22f, 0.24f}, lower[3] = {0.78f, 0.30f, 0.32f};
    static const float line[3] = {0.33f, 0.10f, 0.10f};
    const float ym = 0.45f;
    for (float x = -0.19f; x <= 0.191f; x += 0.02f) {
        float hu = 0.04f * (1.0f - (x / 0.21f) * (x / 0.21f)) + 0.01f;
        float hl = 0.055f * (1.0f - (x / 0.2f) * (x / 0.2f)) + 0.01f;
        float z = surface_z(x, ym) - 0.02f;
        add_flat(h, x, ym - 0.5f * hu, z, 0.014f, 0.5f * hu + 0.004f, 0, upper, 1.0f, 0.93f);
        add_flat(h, x, ym + 0.5f * hl, z, 0.014f, 0.5f * hl + 0.004f, 0, lower, 1.0f, 0.93f);
        add_flat(h, x, ym, z - 0.003f, 0.014f, 0.004f, 0, line, 1.0f, 0.9f);
    }
}

static void set_rgb(float c[3], float r, float g, float b)
{
    c[0] = r, c[1] = g, c[2] = b;
}

/* Moves the splats into an SH degree-0 scene. */
static int to_scene(const head *h, gs_ply_scene *out)
{
    int rc = gs_ply_alloc_sh(out, h->n, 0, 1, NULL);
    if (rc)
        return rc;
    for (int i = 0; i < h->n; i++) {
        const splat *s = &h->s[i];
        for (int k = 0; k < 3; k++) {
            out->means[3 * i + k] = s->pos[k];
            out->log_scales[3 * i + k] = logf(s->sigma[k]);
            out->f_dc[3 * i + k] = (s->rgb[k] - 0.5f) / (float)GS_PLY_SH_C0;
        }
        memcpy(out->quats + 4 * i, s->quat, sizeof s->quat);
        out->opacity_logits[i] = logf(s->opacity / (1.0f - s->opacity));
    }
    gs_ply_features_from_sh(out);
    return GS_OK;
}

int cli_demo_head(unsigned long seed, gs_ply_scene *out)
{
    head h;
    memset(&h, 0, sizeof h);
    h.rng = (uint64_t)seed * 0x2545f4914f6cdd1dull + 1;
    h.s = malloc(HEAD_MAX_SPLATS * sizeof *h.s);
    if (!h.s)
        return GS_ERR_NOMEM;
    set_rgb(h.skin, 0.92f + 0.04f * jitter(&h), 0.72f + 0.04f * jitter(&h), 0.60f + 0.04f * jitter(&h));
    set_rgb(h.hair, 0.24f, 0.15f, 0.09f);
    static const float irises[3][3] = {{0.28f, 0.48f, 0.72f}, {0.42f, 0.26f, 0.12f}, {0.30f, 0.52f, 0.30f}};
    memcpy(h.iris, irises[seed % 3], sizeof h.iris);
    add_shell(&h, 2600);
    add_neck(&h);
    add_shoulders(&h);
    add_ears(&h);
    for (int side = -1; side <= 1; side += 2) {
        add_eye(&h, 0.30f * (float)side, -0.10f);
        add_brow(&h, 0.30f * (float)side, (float)side);
    }
    add_nose(&h);
    add_lips(&h);
    int rc = to_scene(&h, out);
    free(h.s);
    return rc;
}
