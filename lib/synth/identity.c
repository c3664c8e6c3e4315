/* Identity parameters, expressions, seed ranges and random scenes. */
#include <string.h>

#include "synth_internal.h"

static const char *const id_names[GS_SYNTH_ID_COUNT] = {
    "head_size", "head_width", "head_length", "head_height", "face_length",
    "face_width", "forehead_slope", "brow_ridge", "eye_spacing",
    "eye_height", "eye_depth", "eye_opening", "canthal_tilt",
    "eyeball_size", "iris_size", "nose_length", "nose_width",
    "nose_projection", "nose_bridge", "nose_tip", "cheekbones",
    "cheek_fullness", "jaw_width", "chin_projection", "chin_height",
    "mouth_width", "upper_lip", "lower_lip", "mouth_height", "ear_size",
    "ear_protrusion", "neck_width", "skin_tone", "skin_warmth",
    "skin_texture", "skin_shine", "freckles", "lip_colour", "cheek_blush",
    "iris_hue", "iris_brightness", "iris_pattern", "sclera_tint",
    "hair_colour", "hair_red", "hair_amount", "hairline", "brow_thickness",
    "brow_arch", "lash_darkness", "pupil_size"};

static const char *const expr_names[GS_SYNTH_EXPR_COUNT] = {
    "mouth_open", "smile", "brow_raise", "squint", "blink", "pupil"};

/* Domain separation: identity parameters and scenes never share streams
 * even when their seeds are equal. */
#define IDENTITY_STREAM 0x6964656e74697479ULL /* "identity" */
#define SCENE_STREAM 0x7363656e65736565ULL    /* "sceneseed" */

const char *gs_synth_identity_name(int i)
{
    return i >= 0 && i < GS_SYNTH_ID_COUNT ? id_names[i] : NULL;
}

void gs_synth_identity_from_seed(uint64_t seed, gs_synth_identity *id)
{
    gs_rng r;
    gs_rng_seed(&r, seed ^ IDENTITY_STREAM);
    id->seed = seed;
    for (int i = 0; i < GS_SYNTH_ID_COUNT; i++)
        id->p[i] = (float)gs_rng_uniform(&r, -1.0, 1.0);
}

void gs_synth_identity_mean(gs_synth_identity *id)
{
    memset(id, 0, sizeof *id);
}

uint64_t gs_synth_split_seed(gs_synth_split split, uint64_t k)
{
    static const uint64_t first[3] = {GS_SYNTH_SEED_TRAIN_FIRST,
                                      GS_SYNTH_SEED_VAL_FIRST,
                                      GS_SYNTH_SEED_TEST_FIRST};
    int s = split >= GS_SYNTH_TRAIN && split <= GS_SYNTH_TEST ? (int)split : 0;
    return first[s] + k % GS_SYNTH_SEED_SPLIT_COUNT;
}

int gs_synth_seed_split(uint64_t seed)
{
    if (seed < GS_SYNTH_SEED_VAL_FIRST)
        return GS_SYNTH_TRAIN;
    if (seed < GS_SYNTH_SEED_TEST_FIRST)
        return GS_SYNTH_VAL;
    if (seed < GS_SYNTH_SEED_TEST_FIRST + GS_SYNTH_SEED_SPLIT_COUNT)
        return GS_SYNTH_TEST;
    return -1;
}

const char *gs_synth_expression_name(int i)
{
    return i >= 0 && i < GS_SYNTH_EXPR_COUNT ? expr_names[i] : NULL;
}

void gs_synth_expression_neutral(gs_synth_expression *ex)
{
    memset(ex, 0, sizeof *ex);
}

void gs_synth_expression_to_array(const gs_synth_expression *ex,
                                  float out[GS_SYNTH_EXPR_COUNT])
{
    out[0] = ex->mouth_open;
    out[1] = ex->smile;
    out[2] = ex->brow_raise;
    out[3] = ex->squint;
    out[4] = ex->blink;
    out[5] = ex->pupil;
}

static void set3(float *d, float a, float b, float c)
{
    d[0] = a;
    d[1] = b;
    d[2] = c;
}

void gs_synth_scene_default(gs_synth_scene *s, double distance_mm)
{
    memset(s, 0, sizeof *s);
    gs_synth_identity_mean(&s->identity);
    gs_synth_expression_neutral(&s->expr);
    gs_geom_mat3_identity(s->head_R);
    s->head_t[2] = distance_mm;
    s->n_lights = 1;
    /* Key light above-left of the camera. */
    float d[3] = {-0.35f, -0.45f, -0.82f};
    float n = sqrtf(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
    set3(s->light[0].dir, d[0] / n, d[1] / n, d[2] / n);
    set3(s->light[0].rgb, 0.95f, 0.93f, 0.9f);
    set3(s->ambient, 0.32f, 0.33f, 0.35f);
    set3(s->bg_top, 0.18f, 0.2f, 0.24f);
    set3(s->bg_bottom, 0.08f, 0.09f, 0.1f);
    s->specular = 1;
}

void gs_synth_ranges_default(gs_synth_ranges *r)
{
    const double deg = 3.14159265358979323846 / 180.0;
    r->head_yaw = 60 * deg;
    r->head_pitch = 40 * deg;
    r->head_roll = 10 * deg;
    r->gaze_yaw = 50 * deg;
    r->gaze_pitch = 40 * deg;
    r->distance_mm[0] = 550;
    r->distance_mm[1] = 750;
    r->expression_prob = 0.5f;
    r->blink_prob = 0.05f;
}

static float uf(gs_rng *r, double lo, double hi)
{
    return (float)gs_rng_uniform(r, lo, hi);
}

static void random_light(gs_rng *r, gs_synth_light *l, float power)
{
    /* From the camera's half space, mostly above. */
    float d[3] = {uf(r, -1, 1), uf(r, -1, 0.5), -uf(r, 0.3, 1.2)};
    float n = sqrtf(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
    set3(l->dir, d[0] / n, d[1] / n, d[2] / n);
    float warm = uf(r, -0.15, 0.15);
    set3(l->rgb, power * (1 + warm), power, power * (1 - warm));
}

static void random_expression(gs_rng *r, const gs_synth_ranges *rg,
                              gs_synth_expression *ex)
{
    float u_expr = uf(r, 0, 1), u_blink = uf(r, 0, 1);
    float mo = uf(r, 0, 1), sm = uf(r, 0, 1), br = uf(r, -1, 1),
          sq = uf(r, 0, 1), bl = uf(r, 0.3, 1), pu = uf(r, -1, 1);
    gs_synth_expression_neutral(ex);
    if (u_expr < rg->expression_prob) {
        ex->mouth_open = mo * mo;
        ex->smile = sm;
        ex->brow_raise = br;
        ex->squint = 0.7f * sq * sq;
    }
    if (u_blink < rg->blink_prob)
        ex->blink = bl;
    ex->pupil = pu;
}

void gs_synth_scene_random(uint64_t identity_seed, uint64_t scene_seed,
                           const gs_synth_ranges *rg, gs_synth_scene *s)
{
    gs_rng r;
    gs_rng_seed(&r, scene_seed ^ SCENE_STREAM);
    gs_synth_scene_default(s, 600.0);
    gs_synth_identity_from_seed(identity_seed, &s->identity);
    double yaw = gs_rng_uniform(&r, -rg->head_yaw, rg->head_yaw);
    double pitch = gs_rng_uniform(&r, -rg->head_pitch, rg->head_pitch);
    double roll = gs_rng_uniform(&r, -rg->head_roll, rg->head_roll);
    gs_geom_rot_from_pitchyaw(pitch, yaw, roll, s->head_R);
    s->head_t[0] = gs_rng_uniform(&r, -20, 20);
    s->head_t[1] = gs_rng_uniform(&r, -20, 20);
    s->head_t[2] = gs_rng_uniform(&r, rg->distance_mm[0], rg->distance_mm[1]);
    s->gaze_yaw = gs_rng_uniform(&r, -rg->gaze_yaw, rg->gaze_yaw);
    s->gaze_pitch = gs_rng_uniform(&r, -rg->gaze_pitch, rg->gaze_pitch);
    random_expression(&r, rg, &s->expr);
    s->n_lights = gs_rng_uniform(&r, 0, 1) < 0.5 ? 1 : 2;
    random_light(&r, &s->light[0], uf(&r, 0.6, 1.1));
    random_light(&r, &s->light[1], uf(&r, 0.15, 0.5));
    float amb = uf(&r, 0.12, 0.4), tint = uf(&r, -0.1, 0.1);
    set3(s->ambient, amb * (1 + tint), amb, amb * (1 - tint));
    for (int i = 0; i < 3; i++) {
        s->bg_top[i] = uf(&r, 0.02, 0.6);
        s->bg_bottom[i] = s->bg_top[i] * uf(&r, 0.3, 1.0);
    }
    s->specular = 1;
}
