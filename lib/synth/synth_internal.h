/* Internal parts of lib/synth shared between its files: float vector maths,
 * the random generator, and the built head (primitives derived from an
 * identity, an expression and a gaze, in the head frame, millimetres). */
#ifndef GS_SYNTH_INTERNAL_H
#define GS_SYNTH_INTERNAL_H

#include <math.h>
#include <stdint.h>

#include "gazesplat/synth.h"

/* ---- float 3-vectors ---- */
typedef struct v3 {
    float x, y, z;
} v3;

static inline v3 v3_make(float x, float y, float z)
{
    v3 r = {x, y, z};
    return r;
}
static inline v3 v3_add(v3 a, v3 b) { return v3_make(a.x + b.x, a.y + b.y, a.z + b.z); }
static inline v3 v3_sub(v3 a, v3 b) { return v3_make(a.x - b.x, a.y - b.y, a.z - b.z); }
static inline v3 v3_scale(v3 a, float s) { return v3_make(a.x * s, a.y * s, a.z * s); }
static inline v3 v3_mul(v3 a, v3 b) { return v3_make(a.x * b.x, a.y * b.y, a.z * b.z); }
static inline float v3_dot(v3 a, v3 b) { return a.x * b.x + a.y * b.y + a.z * b.z; }
static inline float v3_len(v3 a) { return sqrtf(v3_dot(a, a)); }
static inline v3 v3_cross(v3 a, v3 b)
{
    return v3_make(a.y * b.z - a.z * b.y, a.z * b.x - a.x * b.z,
                   a.x * b.y - a.y * b.x);
}
static inline v3 v3_norm(v3 a)
{
    float l = v3_len(a);
    return l > 0.0f ? v3_scale(a, 1.0f / l) : a;
}
static inline v3 v3_lerp(v3 a, v3 b, float t)
{
    return v3_make(a.x + (b.x - a.x) * t, a.y + (b.y - a.y) * t,
                   a.z + (b.z - a.z) * t);
}
/* min/max without the NaN rules of fminf/fmaxf, which keep GCC from
 * inlining them (a call per use in the distance field). */
static inline float maxf(float a, float b) { return a > b ? a : b; }
static inline float minf(float a, float b) { return a < b ? a : b; }
static inline float clampf(float x, float lo, float hi)
{
    return x < lo ? lo : (x > hi ? hi : x);
}
static inline float mixf(float a, float b, float t) { return a + (b - a) * t; }
static inline float smoothstepf(float e0, float e1, float x)
{
    float t = clampf((x - e0) / (e1 - e0), 0.0f, 1.0f);
    return t * t * (3.0f - 2.0f * t);
}
/* Row-major 3x3 times vector, and its transpose. */
static inline v3 m3_mul(const float m[9], v3 v)
{
    return v3_make(m[0] * v.x + m[1] * v.y + m[2] * v.z,
                   m[3] * v.x + m[4] * v.y + m[5] * v.z,
                   m[6] * v.x + m[7] * v.y + m[8] * v.z);
}
static inline v3 m3_tmul(const float m[9], v3 v)
{
    return v3_make(m[0] * v.x + m[3] * v.y + m[6] * v.z,
                   m[1] * v.x + m[4] * v.y + m[7] * v.z,
                   m[2] * v.x + m[5] * v.y + m[8] * v.z);
}

/* ---- random numbers ----
 * splitmix64 (Steele, Lea, Flood 2014) expands a 64-bit seed; draws come
 * from xoshiro256** (Blackman, Vigna 2018) seeded by four splitmix64
 * outputs. Doubles take the top 53 bits. Stable across platforms. */
typedef struct gs_rng {
    uint64_t s[4];
} gs_rng;

uint64_t gs_synth_splitmix64(uint64_t *state);
/* Mixes two words into one seed (splitmix64 finaliser of a ^ rotated b). */
uint64_t gs_synth_hash2(uint64_t a, uint64_t b);
void gs_rng_seed(gs_rng *r, uint64_t seed);
uint64_t gs_rng_next(gs_rng *r);
double gs_rng_uniform(gs_rng *r, double lo, double hi);

/* Hash-based value noise in [-1, 1], smooth (C1), period-free. */
float gs_synth_noise3(v3 p, uint32_t seed);

/* ---- the built head ---- */

/* Axis-aligned ellipsoid. */
typedef struct sd_ell {
    v3 c, r;
    v3 ir, ir2;   /* 1/r and 1/r^2 */
    float rmax;   /* largest radius: bounding sphere */
} sd_ell;

typedef struct box3 {
    v3 lo, hi;
} box3;

typedef struct sd_capsule {
    v3 a, b;
    float ra, rb; /* radii at a and b (a round cone) */
} sd_capsule;

/* Materials of head-surface hits. */
enum {
    MAT_SKIN = 0,
    MAT_LIPS,
    MAT_HAIR,
    MAT_MOUTH,
    MAT_EAR,
    MAT_NECK,
    MAT_LID,
    MAT_COUNT
};

/* One eye, head frame. The eyeball is the union of the sclera sphere and
 * the corneal sphere (through the limbus); the iris is a disc on a plane
 * across the optical axis. Lids: a shell around the eyeball outside the
 * wedge between two planes through the lid axis (inner -> outer corner);
 * n_up/n_lo point into the covered side, up_dir/lo_dir run along the
 * margins toward the front. */
typedef struct eye_model {
    v3 c;              /* eyeball centre */
    v3 axis;           /* optical axis, unit, out of the eye */
    float r_sclera;    /* sclera sphere radius */
    float r_cornea;    /* corneal sphere radius */
    float cornea_off;  /* centre of the corneal sphere along axis */
    float iris_r, iris_d; /* iris radius; iris plane distance along axis */
    float pupil_r;
    v3 cornea_c, iris_c;
    v3 iris_u, iris_v; /* iris plane axes (for the texture angle) */
    float bound_r;     /* eyeball union fits in sphere(c, bound_r) */
    /* Lids: a shell around the eyeball (gap < offset < gap + thick) outside
     * the opening wedge between two planes through the lid axis. */
    float lid_gap, lid_thick;
    v3 lid_x;          /* lid axis (unit), inner toward outer corner */
    v3 n_up, n_lo;     /* outward normals of the two wedge planes */
    v3 up_dir, lo_dir; /* in-plane directions of the lid margins (front) */
    float lid_bound_r;
    int side;          /* 0 = subject's right (iBUG 36-41), 1 = left */
} eye_model;

typedef struct head_model {
    /* geometry */
    sd_ell cranium, face, jaw, chin, brow, cheek[2], zyg[2], nose_tip,
        nose_wing[2], lip_up, lip_lo, ear[2], hair, socket[2], nostril[2];
    sd_capsule bridge, jawbone[2];
    float neck_r[2], neck_c[3], neck_y0, neck_y1;
    float mouth_w, mouth_open, mouth_y;
    float smile;
    sd_ell cavity;
    float hair_plane[4]; /* hair where dot(n, p) + d + curve x^2 < 0 */
    float hair_curve;
    int has_hair, has_ears;
    float ear_x;       /* lateral position of the ears (build frame) */
    v3 jaw_pivot;
    float jaw_rot[9];  /* closed-jaw frame from head frame */
    float jawbone_r;           /* bounding radius of a jawbone capsule */
    v3 nose_bc, lips_bc;       /* bounding spheres of nose and lips */
    box3 jaw_box, mid_box, socket_box, nose_box, mouth_box, eyes_box;
    float nose_br, lips_br;
    eye_model eye[2];
    v3 bound_c;        /* bounding sphere of everything */
    float bound_r;
    float neck_cut_y;
    /* appearance, linear RGB */
    v3 skin, lip_col, hair_col, brow_col, iris_a, iris_b, sclera, mouth_col;
    float skin_tex, shine, freckles, blush, lash, iris_pattern;
    float brow_y[2], brow_arch, brow_thick, brow_x0, brow_x1;
    float brow_raise;
    uint32_t tex_seed;
    v3 offset;         /* face centre in the build frame */
} head_model;

/* Builds the head for an identity, expression and head-frame gaze. */
void gs_synth_head_build(const gs_synth_identity *id,
                         const gs_synth_expression *ex, double gaze_pitch,
                         double gaze_yaw, head_model *h);
/* The same with angle kappa: kappa NULL (none) or the identity's (h, v),
 * radians (gs_synth_kappa_rotation); gaze_* is then the visual axis. */
void gs_synth_head_build_kappa(const gs_synth_identity *id,
                               const gs_synth_expression *ex, double gaze_pitch,
                               double gaze_yaw, const double *kappa, head_model *h);
/* The scene's head: gs_synth_head_build_kappa with the scene's kappa. */
void gs_synth_head_build_scene(const gs_synth_scene *s, head_model *h);

/* Pulls both lids of a built head back to 85 degrees above and below the
 * eye's front (gs_synth_render_opts.open_lids): the wedge between them
 * leaves the cornea and iris in the open for any gaze of the range. */
void gs_synth_head_open_lids(head_model *h);

/* Signed distance (mm) of the head surface, eyeballs excluded. */
float gs_synth_head_sdf(const head_model *h, v3 p);
/* The same field with every part evaluated (no skipping): tests only. */
float gs_synth_head_sdf_nocull(const head_model *h, v3 p);
/* The same distance for 4 points (bit-identical per lane). */
void gs_synth_head_sdf4(const head_model *h, const float x[4],
                        const float y[4], const float z[4], float out[4]);
/* Same, with the analytic gradient. */
float gs_synth_head_sdf_grad(const head_model *h, v3 p, v3 *grad);
/* Material at a surface point. */
int gs_synth_head_material(const head_model *h, v3 p);
/* Distance, gradient and material in one evaluation. */
float gs_synth_head_surface(const head_model *h, v3 p, v3 *grad,
                            int *material);
/* Distance to the union sclera + cornea of one eye (exact outside). */
float gs_synth_eyeball_sdf(const eye_model *e, v3 p);
/* Lid shell distance of one eye (the lid part of the head SDF). */
float gs_synth_lid_sdf(const eye_model *e, v3 p);

/* First hit of the ray o + t d (d unit) with an eyeball union in
 * (tmin, tmax); returns t or INFINITY; *on_cornea says which sphere. */
float gs_synth_eye_intersect(const eye_model *e, v3 o, v3 d, float tmin,
                             float tmax, int *on_cornea);

/* Face-region test for a skin point (for the face mask and labels). */
int gs_synth_head_is_face(const head_model *h, v3 p, int material);

/* Albedo of a head surface point (linear RGB). */
v3 gs_synth_skin_albedo(const head_model *h, v3 p, int material);

/* The 68 landmarks, head frame, for the built head. */
void gs_synth_head_landmarks(const head_model *h, double lm[68][3]);
/* Only the nose (27-35) and eye (36-47) points, which define the face
 * centre; the other entries are left untouched. */
void gs_synth_head_face_points(const head_model *h, double lm[68][3]);

#endif
