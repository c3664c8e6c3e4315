/* gs_synth: procedural heads with exact ground truth.
 *
 * A parametric head family (skull, brow ridge, nose, cheeks, lips, chin,
 * ears, hair cap as one smooth signed distance field; two analytic
 * eyeballs with cornea, textured iris and pupil; eyelids that follow gaze
 * pitch and blink) rendered by sphere tracing. For any identity,
 * expression, head pose, gaze, lighting and pinhole camera the image and
 * every label are known exactly.
 *
 * Units and frames are those of gazesplat/geom.h: millimetres, radians,
 * OpenCV camera frame, head frame (x toward the subject's left, y down,
 * z into the head) with its origin at the face centre of the identity's
 * neutral face (mean of the iBUG 36/39/42/45 eye-corner centre and the
 * 31/35 nose-wing centre). Pixel centres are at +0.5.
 *
 * Eyes are named from the subject: "right eye" = iBUG 36-41, image left
 * in a frontal view, -x in the head frame; index GS_SYNTH_EYE_RIGHT = 0.
 *
 * Model facts: sclera sphere radius ~12 mm, corneal sphere ~7.8 mm
 * passing through the limbus, iris radius ~6 mm (a disc on the limbus
 * plane), pupil radius 1-3.5 mm. Both eyes' visual axes (lines of sight)
 * are parallel to the head-frame gaze (target at infinity). By default the
 * optical axes equal them; with angle kappa (gs_synth_kappa, off by
 * default) each eye's optical axis, along which the eyeball renders, is
 * its visual axis turned temporally and downward by the identity's kappa.
 * The cornea does not refract: the pupil is seen where its 3D centre
 * projects.
 *
 * Identity seeds: train, validation and test identities come from
 * disjoint seed ranges (GS_SYNTH_SEED_*). Everything is deterministic:
 * the same inputs give the same bytes for any thread count. */
#ifndef GAZESPLAT_SYNTH_H
#define GAZESPLAT_SYNTH_H

#include <stddef.h>
#include <stdint.h>

#include "gazesplat/error.h"
#include "gazesplat/geom.h"
#include "gazesplat/pool.h"

#ifdef __cplusplus
extern "C" {
#endif

/* ---- identities ---- */

typedef enum gs_synth_split {
    GS_SYNTH_TRAIN = 0,
    GS_SYNTH_VAL = 1,
    GS_SYNTH_TEST = 2
} gs_synth_split;

/* Identity seed ranges [first, first + count): disjoint by construction. */
#define GS_SYNTH_SEED_TRAIN_FIRST 0ULL
#define GS_SYNTH_SEED_VAL_FIRST 1000000000ULL
#define GS_SYNTH_SEED_TEST_FIRST 2000000000ULL
#define GS_SYNTH_SEED_SPLIT_COUNT 1000000000ULL

/* Identity parameters, each in [-1, 1]; 0 is the mean identity. */
enum gs_synth_id_param {
    GS_SYNTH_ID_HEAD_SIZE, GS_SYNTH_ID_HEAD_WIDTH, GS_SYNTH_ID_HEAD_LENGTH,
    GS_SYNTH_ID_HEAD_HEIGHT, GS_SYNTH_ID_FACE_LENGTH, GS_SYNTH_ID_FACE_WIDTH,
    GS_SYNTH_ID_FOREHEAD_SLOPE, GS_SYNTH_ID_BROW_RIDGE,
    GS_SYNTH_ID_EYE_SPACING, GS_SYNTH_ID_EYE_HEIGHT, GS_SYNTH_ID_EYE_DEPTH,
    GS_SYNTH_ID_EYE_OPENING, GS_SYNTH_ID_CANTHAL_TILT,
    GS_SYNTH_ID_EYEBALL_SIZE, GS_SYNTH_ID_IRIS_SIZE, GS_SYNTH_ID_NOSE_LENGTH,
    GS_SYNTH_ID_NOSE_WIDTH, GS_SYNTH_ID_NOSE_PROJECTION,
    GS_SYNTH_ID_NOSE_BRIDGE, GS_SYNTH_ID_NOSE_TIP, GS_SYNTH_ID_CHEEKBONES,
    GS_SYNTH_ID_CHEEK_FULLNESS, GS_SYNTH_ID_JAW_WIDTH,
    GS_SYNTH_ID_CHIN_PROJECTION, GS_SYNTH_ID_CHIN_HEIGHT,
    GS_SYNTH_ID_MOUTH_WIDTH, GS_SYNTH_ID_UPPER_LIP, GS_SYNTH_ID_LOWER_LIP,
    GS_SYNTH_ID_MOUTH_HEIGHT, GS_SYNTH_ID_EAR_SIZE,
    GS_SYNTH_ID_EAR_PROTRUSION, GS_SYNTH_ID_NECK_WIDTH,
    GS_SYNTH_ID_SKIN_TONE, GS_SYNTH_ID_SKIN_WARMTH, GS_SYNTH_ID_SKIN_TEXTURE,
    GS_SYNTH_ID_SKIN_SHINE, GS_SYNTH_ID_FRECKLES, GS_SYNTH_ID_LIP_COLOUR,
    GS_SYNTH_ID_CHEEK_BLUSH, GS_SYNTH_ID_IRIS_HUE,
    GS_SYNTH_ID_IRIS_BRIGHTNESS, GS_SYNTH_ID_IRIS_PATTERN,
    GS_SYNTH_ID_SCLERA_TINT, GS_SYNTH_ID_HAIR_COLOUR, GS_SYNTH_ID_HAIR_RED,
    GS_SYNTH_ID_HAIR_AMOUNT, GS_SYNTH_ID_HAIRLINE,
    GS_SYNTH_ID_BROW_THICKNESS, GS_SYNTH_ID_BROW_ARCH,
    GS_SYNTH_ID_LASH_DARKNESS, GS_SYNTH_ID_PUPIL_SIZE,
    GS_SYNTH_ID_COUNT
};

typedef struct gs_synth_identity {
    uint64_t seed;                 /* also seeds the texture patterns */
    float p[GS_SYNTH_ID_COUNT];    /* each in [-1, 1] */
} gs_synth_identity;

/* Name of parameter i ("head_size", ...), or NULL when out of range. */
const char *gs_synth_identity_name(int i);
/* Identity of a seed: parameters drawn uniformly in [-1, 1], in enum
 * order, from xoshiro256** seeded by splitmix64(seed ^ a constant). */
void gs_synth_identity_from_seed(uint64_t seed, gs_synth_identity *id);
/* The mean identity: all parameters 0, seed 0. */
void gs_synth_identity_mean(gs_synth_identity *id);
/* Seed of the k-th identity of a split (k < GS_SYNTH_SEED_SPLIT_COUNT). */
uint64_t gs_synth_split_seed(gs_synth_split split, uint64_t k);
/* Which split a seed belongs to, or -1 if none. */
int gs_synth_seed_split(uint64_t seed);

/* ---- per-frame expression ---- */
typedef struct gs_synth_expression {
    float mouth_open;  /* 0 closed .. 1 wide open (jaw ~14 deg) */
    float smile;       /* 0 .. 1 */
    float brow_raise;  /* -1 (frown) .. 1 (raised) */
    float squint;      /* 0 .. 1 */
    float blink;       /* 0 open .. 1 closed */
    float pupil;       /* -1 constricted .. 1 dilated, around the identity's */
} gs_synth_expression;

/* Names of the expression fields, in struct order (6 of them). */
#define GS_SYNTH_EXPR_COUNT 6
const char *gs_synth_expression_name(int i);
void gs_synth_expression_neutral(gs_synth_expression *ex);
/* Writes field i (as in gs_synth_expression_name) into out[i]. */
void gs_synth_expression_to_array(const gs_synth_expression *ex,
                                  float out[GS_SYNTH_EXPR_COUNT]);

/* ---- scene ---- */
typedef struct gs_synth_light {
    float dir[3];  /* unit vector toward the light, world frame */
    float rgb[3];  /* linear radiance */
} gs_synth_light;

typedef struct gs_synth_scene {
    gs_synth_identity identity;
    gs_synth_expression expr;
    double head_R[9];      /* head to world rotation */
    double head_t[3];      /* face centre in the world frame, mm */
    double gaze_pitch;     /* gaze in the head frame, radians */
    double gaze_yaw;
    int n_lights;          /* 0..2 */
    gs_synth_light light[2];
    float ambient[3];      /* linear */
    float bg_top[3], bg_bottom[3]; /* background gradient, linear */
    int specular;          /* 0 disables every specular term (tests) */
    /* Angle kappa of the identity (gs_synth_kappa_draw): kappa 0 (the
     * default) renders optical = visual axis and writes no kappa labels;
     * 1: each eye's optical axis is its visual axis (the gaze) turned
     * temporally by kappa_h and down by kappa_v (radians, the visual
     * axis is nasal and up of the optical one for positive values). */
    int kappa;
    double kappa_h, kappa_v;
} gs_synth_scene;

/* A neutral, frontal scene: mean identity, head at (0, 0, distance_mm)
 * facing the world origin, gaze (0, 0), one white key light. */
void gs_synth_scene_default(gs_synth_scene *s, double distance_mm);

/* Ranges of the random scenes (radians, mm). */
typedef struct gs_synth_ranges {
    double head_yaw, head_pitch, head_roll;   /* uniform in +-value */
    double gaze_yaw, gaze_pitch;              /* head frame, +-value */
    double distance_mm[2];                    /* camera distance range */
    float expression_prob;   /* chance of a non-neutral expression */
    float blink_prob;        /* chance of a (partial) blink */
} gs_synth_ranges;

/* Defaults of the issue: head yaw +-60, pitch +-40, roll +-10 deg; gaze
 * yaw +-50, pitch +-40 deg; distance 550..750 mm; expression 0.5, blink 0.05. */
void gs_synth_ranges_default(gs_synth_ranges *r);

/* Random scene for `identity_seed` drawn with `scene_seed`: head pose
 * (the face centre at (0, 0, distance) plus up to 20 mm jitter), gaze,
 * expression, 1-2 lights, ambient and background. */
void gs_synth_scene_random(uint64_t identity_seed, uint64_t scene_seed,
                           const gs_synth_ranges *ranges, gs_synth_scene *s);

/* ---- angle kappa: visual vs optical axis ----
 * The line of sight (visual axis: fixation point, nodal points, fovea) is
 * not the eyeball's optical axis: the fovea lies temporal and slightly
 * below the optical axis's pole, so in front of the eye the visual axis
 * points nasally (about 5 deg) and up (about 1.5 deg) of the optical one
 * (docs/synth.md, "Angle kappa", for the sources). Gaze labels mean the
 * visual axis. Each identity draws its own (h, v) from independent normal
 * distributions truncated at +-3 sd (redrawn beyond), from a stream of
 * its seed alone, so an identity keeps its kappa in every scene, split
 * position and thread count; both eyes share it, mirrored (nasal is +x
 * for the right eye, -x for the left). */
typedef struct gs_synth_kappa {
    int enabled;          /* 0 (default): no kappa, outputs as before */
    double h_mean_deg, h_sd_deg;  /* horizontal, nasal positive */
    double v_mean_deg, v_sd_deg;  /* vertical, visual axis up positive */
} gs_synth_kappa;

/* The "literature" preset: h 5.0 +- 1.3 deg, v 1.5 +- 1.0 deg. */
void gs_synth_kappa_literature(gs_synth_kappa *k);
/* GS_ERR_ARG unless every value is finite, |means| <= 15 deg and the sds
 * are in [0, 5] deg (the message names the field). */
int gs_synth_kappa_check(const gs_synth_kappa *k, gs_error *err);
/* The kappa of an identity (radians): 0, 0 when disabled. */
void gs_synth_kappa_draw(const gs_synth_kappa *k, uint64_t identity_seed,
                         double *h, double *v);
/* Sets scene->kappa, kappa_h, kappa_v from k for the scene's identity. */
void gs_synth_scene_set_kappa(const gs_synth_kappa *k, gs_synth_scene *s);
/* K of eye `eye` (GS_SYNTH_EYE_*) for kappa (h, v) radians: the eye's
 * rotation is R(gaze) K, so its visual axis K^T (-z) points along the
 * gaze and its optical axis R(gaze) K (-z) is the gaze turned temporally
 * by h and down by v. K = rot_from_pitchyaw(-v, +h right eye / -h left). */
void gs_synth_kappa_rotation(int eye, double h, double v, double K[9]);

/* ---- cameras and rigs ---- */
typedef struct gs_synth_camera {
    double K[9];        /* intrinsics, pixel centres at +0.5 */
    double R[9];        /* world to camera rotation */
    double t[3];        /* world to camera translation: X_c = R X_w + t */
    int width, height;
} gs_synth_camera;

/* Camera at the world origin looking along +z, square image of `size`
 * pixels whose width spans `field_mm` at distance_mm. */
void gs_synth_camera_single(int size, double distance_mm, double field_mm,
                            gs_synth_camera *cam);

/* 18-camera rig after ETH-XGaze's dome (not its calibration): 3 rows at
 * pitch +20, 0, -20 deg x 6 columns at yaw -62.5..62.5 deg (step 25) on a
 * sphere of radius distance_mm around the point (0, 0, distance_mm), each
 * aimed at it; row-major from the top-left as seen by the subject's
 * camera. Square images of `size`, width spanning field_mm at the centre. */
#define GS_SYNTH_ETHX_CAMERAS 18
int gs_synth_camera_ethx(int index, int size, double distance_mm,
                         double field_mm, gs_synth_camera *cam);

/* The normalized camera of a scene seen by `base`: same centre, rotated
 * by the normalization R, focal f_n |c| / d_n (see geom.h), so the image
 * is the normalized face image of size x size. d_n_mm <= 0 or f_n <= 0
 * select the defaults (680 mm, 1600 px at 512). */
int gs_synth_camera_normalized(const gs_synth_scene *s,
                               const gs_synth_camera *base, int size,
                               double d_n_mm, double f_n,
                               gs_synth_camera *out, gs_error *err);

/* ---- samples ---- */
enum gs_synth_mask {
    GS_SYNTH_MASK_HEAD = 0,   /* everything of the head: skin, hair, eyes, neck */
    GS_SYNTH_MASK_FACE = 1,   /* face skin (forehead to chin, lids and lips
                                 included, eyeballs, hair, ears, neck excluded) */
    GS_SYNTH_MASK_LEFT_EYE = 2,  /* visible eyeball of the subject's left eye */
    GS_SYNTH_MASK_RIGHT_EYE = 3, /* visible eyeball of the subject's right eye */
    GS_SYNTH_MASK_COUNT = 4
};
#define GS_SYNTH_EYE_RIGHT 0
#define GS_SYNTH_EYE_LEFT 1
#define GS_SYNTH_LANDMARKS 68

typedef struct gs_synth_labels {
    /* camera */
    double K[9], cam_R[9], cam_t[3];
    int width, height;
    /* head pose in this camera: X_cam = head_R X_head + head_t */
    double head_R[9], head_t[3], head_rvec[3];
    double head_pitch, head_yaw, head_roll;
    /* gaze (unit vectors, from the face centre; both eyes are parallel):
     * the visual axis (line of sight) */
    double gaze_head[3], gaze_head_pitch, gaze_head_yaw;
    double gaze_cam[3], gaze_cam_pitch, gaze_cam_yaw;
    /* angle kappa (has_kappa 1 when the scene had it on; else the rest is
     * 0 and the optical axes equal the gaze): the identity's kappa
     * (radians) and each eye's optical axis [right, left], along which
     * its eyeball renders, in the head, camera and normalized frames */
    int has_kappa;
    double kappa_h, kappa_v;
    double optical_head[2][3], optical_head_pitch[2], optical_head_yaw[2];
    double optical_cam[2][3], optical_cam_pitch[2], optical_cam_yaw[2];
    double optical_norm_pitch[2], optical_norm_yaw[2];
    /* normalization of this image (defaults at d_n 680 mm, f_n for this
     * size): normalized gaze and head angles, and the full transform */
    gs_geom_norm norm;
    double gaze_norm_pitch, gaze_norm_yaw, head_norm_pitch, head_norm_yaw;
    /* points, camera frame mm and pixels */
    double face_centre[3], face_centre_uv[2];
    double eye_centre[2][3], eye_centre_uv[2][2];
    double pupil_centre[2][3], pupil_uv[2][2];
    double pupil_radius_mm, iris_radius_mm, eyeball_radius_mm;
    double lm3d[GS_SYNTH_LANDMARKS][3];      /* camera frame */
    double lm3d_head[GS_SYNTH_LANDMARKS][3]; /* head frame */
    double lm2d[GS_SYNTH_LANDMARKS][2];
    /* what generated it */
    gs_synth_identity identity;
    gs_synth_expression expr;
} gs_synth_labels;

typedef struct gs_synth_sample {
    int width, height;
    size_t stride;       /* bytes per RGB row, >= 3 * width */
    uint8_t *rgb;        /* 8-bit sRGB, interleaved, top row first */
    uint8_t *mask;       /* GS_SYNTH_MASK_COUNT planes of width*height,
                            0 or 255 */
    gs_synth_labels labels;
} gs_synth_sample;

/* Allocates buffers for width x height (stride 3 * width); free with
 * gs_synth_sample_free. GS_ERR_ARG for sizes outside 1..8192. */
int gs_synth_sample_alloc(gs_synth_sample *s, int width, int height,
                          gs_error *err);
void gs_synth_sample_free(gs_synth_sample *s);
static inline uint8_t *gs_synth_sample_mask(const gs_synth_sample *s, int m)
{
    return s->mask + (size_t)m * (size_t)s->width * (size_t)s->height;
}

typedef struct gs_synth_render_opts {
    int supersample;   /* 1 (default) or 2: 2x2 samples per pixel */
    int open_lids;     /* 0 (default). 1, for tests of the eyes: both lids
                          pulled back to 85 deg above and below the eye's
                          front, so lids never cover the iris (gaze pitch
                          moves the lids, which would hide part of the
                          pupil). The eye landmarks (36-47) then lie on the
                          opened margins; the eye corners, the face centre
                          and every other label are unchanged. */
    int region[4];     /* x0, y0, x1, y1: render only the 16 x 16 tiles
                          that meet [x0, x1) x [y0, y1); other pixels and
                          mask bytes are left as they were. The pixels
                          rendered are exactly those of a whole render.
                          All 0 (default): the whole image. */
} gs_synth_render_opts;

/* Renders `scene` through `cam` into `out` (allocated to the camera's
 * size) and fills all labels. `pool` may be NULL; opts may be NULL (the
 * defaults). */
int gs_synth_render(const gs_synth_scene *scene, const gs_synth_camera *cam,
                    const gs_synth_render_opts *opts, gs_pool *pool,
                    gs_synth_sample *out, gs_error *err);

/* Labels only (no pixels): the same values gs_synth_render fills. */
int gs_synth_labels_compute(const gs_synth_scene *scene,
                            const gs_synth_camera *cam, gs_synth_labels *lab,
                            gs_error *err);

/* ---- neutral template for Gaussian initialisation ---- */
enum gs_synth_region {
    GS_SYNTH_REGION_HEAD = 0,      /* skin/hair outside the face region */
    GS_SYNTH_REGION_FACE = 1,
    GS_SYNTH_REGION_LEFT_EYE = 2,
    GS_SYNTH_REGION_RIGHT_EYE = 3
};

typedef struct gs_synth_template {
    int n;              /* points */
    float *xyz;         /* n x 3, head frame mm */
    float *normal;      /* n x 3, unit, outward */
    float *rgb;         /* n x 3, albedo in [0, 1], sRGB */
    uint8_t *region;    /* n, gs_synth_region */
    double landmarks[GS_SYNTH_LANDMARKS][3];  /* head frame mm */
    double eye_centre[2][3];
    double eyeball_radius_mm;
} gs_synth_template;

/* Surface points of the mean identity with neutral expression and gaze
 * (0, 0): head surface points on a grid of `spacing_mm` (projected onto
 * the surface, one per cell) plus points on each eyeball's front
 * (spacing about the same). Free with gs_synth_template_free. */
int gs_synth_template_build(double spacing_mm, gs_pool *pool,
                            gs_synth_template *t, gs_error *err);
void gs_synth_template_free(gs_synth_template *t);

/* ---- on-the-fly generator ---- */
typedef enum gs_synth_rig {
    GS_SYNTH_RIG_SINGLE = 0,     /* one frontal camera */
    GS_SYNTH_RIG_ETHX = 1,       /* 18 cameras: sample i is camera i % 18 of
                                    frame i / 18 (the views share a scene) */
    GS_SYNTH_RIG_NORMALIZED = 2  /* normalized face images (default d_n, f_n) */
} gs_synth_rig;

typedef struct gs_synth_gen_config {
    gs_synth_split split;
    uint64_t identities;   /* identities drawn from the split, >= 1 */
    uint64_t seed;         /* scene stream seed */
    int size;              /* square image size */
    gs_synth_rig rig;
    int supersample;       /* 1 or 2 */
    gs_synth_ranges ranges;
    gs_synth_kappa kappa;  /* off by default */
} gs_synth_gen_config;

void gs_synth_gen_config_default(gs_synth_gen_config *c);

/* Scene and camera of sample `index` of a configuration: with
 * f = index (index / 18 for the ETH-XGaze-like rig), identity
 * k = hash(hash(seed, f), 0x6964) mod identities of the split and scene
 * seed hash(seed, f). Pure function of (config, index). */
int gs_synth_gen_scene(const gs_synth_gen_config *c, uint64_t index,
                       gs_synth_scene *scene, gs_synth_camera *cam,
                       gs_error *err);
/* Renders sample `index` into out (allocated by the caller at size). */
int gs_synth_gen_sample(const gs_synth_gen_config *c, uint64_t index,
                        gs_pool *pool, gs_synth_sample *out, gs_error *err);

/* ---- datasets on disk ---- */
typedef void (*gs_synth_progress_fn)(void *ctx, uint64_t done, uint64_t total);

typedef struct gs_synth_dataset_opts {
    uint64_t first, count;   /* generator indices [first, first + count) */
    int masks;               /* also write masks/NNNNNNNN.png */
    gs_synth_progress_fn progress;  /* called after each image, may be NULL */
    void *progress_ctx;
} gs_synth_dataset_opts;

/* Writes dir/images/NNNNNNNN.png (N = generator index), dir/masks/... (R
 * head, G face, B 255 left eye / 128 right eye), dir/labels.jsonl (one
 * gs_synth_labels_json object per image plus "index" and "mask") and
 * dir/README.md describing every field. dir is created if missing (its
 * parent must exist); existing files are overwritten. */
int gs_synth_dataset_write(const char *dir, const gs_synth_gen_config *c,
                           const gs_synth_dataset_opts *o, gs_pool *pool,
                           gs_error *err);

/* The generator configuration of a dataset gs_synth_dataset_write wrote,
 * read back from its README.md (split, identities, scene seed, size, rig,
 * supersampling, kappa; default ranges), and its index range (first,
 * count; either may be NULL). GS_ERR_IO when the README cannot be read,
 * GS_ERR_FORMAT when it is not one (the message names the file). */
int gs_synth_dataset_config_read(const char *dir, gs_synth_gen_config *c,
                                 uint64_t *first, uint64_t *count, gs_error *err);

/* A contact sheet: `rows` identities of a split (one per row, each with
 * its own slight head pose and lighting) x a 3x3 gaze grid (pitch +25, 0,
 * -25 deg by yaw +35, 0, -35 deg, head frame) of normalized face images of
 * tile x tile px, 2x2 supersampled. *rgb (malloc'd, 3 * width * height
 * bytes, stride 3 * width) is freed by the caller with free(). */
int gs_synth_contact_sheet(gs_synth_split split, int rows, int tile,
                           gs_pool *pool, uint8_t **rgb, int *width,
                           int *height, gs_error *err);

/* ---- label text ---- */
/* One JSON object (no newline) with every label of `s`, `image` naming
 * the image file. Returns the length written, or the length needed when
 * cap is too small (like snprintf), or a negative gs_status. */
int gs_synth_labels_json(const gs_synth_labels *l, const char *image,
                         char *buf, size_t cap);

#ifdef __cplusplus
}
#endif
#endif
