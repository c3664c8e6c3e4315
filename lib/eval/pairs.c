/* The evaluation pairing: held-out identities (or, as a diagnostic, the
 * training ones), input scenes chosen to cover
 * the head-pose bins and the hard cases, targets chosen to cover the
 * gaze-change bins. Everything is a pure function of the seeds. */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "gazesplat/eval.h"
#include "gazesplat/geom.h"
#include "eval_internal.h"

#define DEG (3.14159265358979323846 / 180.0)
/* Rejection sampling gives up after this many draws (never reached with
 * the documented ranges; the rarest class is accepted ~1 in 60). */
#define MAX_DRAWS 200000

void gs_eval_ranges(gs_synth_ranges *r)
{
    gs_synth_ranges_default(r);
    r->head_yaw = 50 * DEG;
    r->head_pitch = 30 * DEG;
    r->head_roll = 5 * DEG;
    r->gaze_yaw = 40 * DEG;
    r->gaze_pitch = 30 * DEG;
    r->blink_prob = 0.1f;
}

int gs_eval_angle_bin(double deg)
{
    if (!(deg >= 0) || deg < 15)
        return GS_EVAL_BIN_0_15;
    if (deg < 30)
        return GS_EVAL_BIN_15_30;
    return deg < 50 ? GS_EVAL_BIN_30_50 : GS_EVAL_BIN_OVER_50;
}

const char *gs_eval_bin_name(int bin)
{
    static const char *const names[GS_EVAL_BINS] = {"0-15", "15-30", "30-50",
                                                    "50+"};
    return bin >= 0 && bin < GS_EVAL_BINS ? names[bin] : "?";
}

int gs_eval_expr_narrowed(const gs_synth_expression *ex)
{
    return ex->squint >= 0.35f || ex->blink >= 0.3f;
}

int gs_eval_scene_harsh(const gs_synth_scene *s)
{
    float amb = (s->ambient[0] + s->ambient[1] + s->ambient[2]) / 3;
    return s->n_lights == 1 && amb < 0.2f && fabsf(s->light[0].dir[0]) >= 0.5f;
}

double gs_eval_angle_deg(double p0, double y0, double p1, double y1)
{
    double a[3], b[3];
    gs_geom_pitchyaw_to_vec(p0, y0, a);
    gs_geom_pitchyaw_to_vec(p1, y1, b);
    return gs_geom_vec3_angle(a, b) / DEG;
}

void gs_eval_pairs_spec_default(gs_eval_pairs_spec *s)
{
    s->split = GS_SYNTH_TEST;
    s->identities = 15;
    s->inputs = 10;
    s->targets = 10;
    s->seed = 1;
}

void gs_eval_pairs_free(gs_eval_pairs *ps)
{
    free(ps->p);
    ps->p = NULL;
    ps->n = 0;
}

static uint64_t splitmix(uint64_t x)
{
    x += 0x9e3779b97f4a7c15ULL;
    x = (x ^ (x >> 30)) * 0xbf58476d1ce4e5b9ULL;
    x = (x ^ (x >> 27)) * 0x94d049bb133111ebULL;
    return x ^ (x >> 31);
}

static uint64_t mix4(uint64_t a, uint64_t b, uint64_t c, uint64_t d)
{
    return splitmix(splitmix(splitmix(splitmix(a) ^ b) ^ c) ^ d);
}

void gs_eval_pair_scenes(const gs_eval_pair *p, gs_synth_scene *input,
                         gs_synth_scene *target)
{
    gs_synth_ranges r;
    gs_eval_ranges(&r);
    gs_synth_scene_random(p->identity_seed, p->input_scene, &r, input);
    gs_synth_scene t;
    gs_synth_scene_random(p->identity_seed, p->target_scene, &r, &t);
    *target = *input;
    target->gaze_pitch = t.gaze_pitch;
    target->gaze_yaw = t.gaze_yaw;
    if (p->head_change) {
        memcpy(target->head_R, t.head_R, sizeof t.head_R);
        memcpy(target->head_t, t.head_t, sizeof t.head_t);
    }
}

/* Angle of the head's forward axis from the line of sight to the face
 * centre: the head pose in its normalized camera, whatever the size. */
static double head_deg(const gs_synth_scene *s)
{
    double z[3] = {s->head_R[2], s->head_R[5], s->head_R[8]};
    return gs_geom_vec3_angle(z, s->head_t) / DEG;
}

/* Normalized head pitch and yaw of a scene (camera at the world origin). */
static int head_norm_angles(const gs_synth_scene *s, double *pitch,
                            double *yaw, gs_error *err)
{
    double k[9] = {800, 0, 0, 0, 800, 0, 0, 0, 1};
    gs_geom_norm n;
    int rc = gs_geom_normalize(k, s->head_t, s->head_R, 680, 800, 256, 256,
                               &n, err);
    if (rc)
        return rc;
    double r[9];
    gs_geom_norm_rot(&n, s->head_R, r);
    gs_geom_head_pitchyaw(r, pitch, yaw);
    return GS_OK;
}

int gs_eval_pair_derive(gs_eval_pair *p, gs_error *err)
{
    gs_synth_scene in, tg;
    gs_eval_pair_scenes(p, &in, &tg);
    double ip, iy, tp, ty;
    int rc = head_norm_angles(&in, &ip, &iy, err);
    if (!rc)
        rc = head_norm_angles(&tg, &tp, &ty, err);
    if (rc)
        return rc;
    p->gaze_change_deg = gs_eval_angle_deg(in.gaze_pitch, in.gaze_yaw,
                                           tg.gaze_pitch, tg.gaze_yaw);
    p->head_deg = head_deg(&tg);
    p->head_change_deg = gs_eval_angle_deg(ip, iy, tp, ty);
    p->narrowed = gs_eval_expr_narrowed(&in.expr);
    p->harsh = gs_eval_scene_harsh(&in);
    return GS_OK;
}

/* First input scene seed of (identity k, input i) meeting its class. */
static int pick_input(const gs_eval_pairs_spec *sp, int k, int i,
                      uint64_t *seed, gs_error *err)
{
    gs_synth_ranges r;
    gs_eval_ranges(&r);
    uint64_t id = gs_synth_split_seed(sp->split, (uint64_t)k);
    /* The class rotates with the identity so that the first two inputs of
     * every identity (a prefix of the file) already cover all classes. */
    int c = (i + 2 * k) % 10;
    int want_bin = c % 3, narrowed = c == 3, harsh = c == 4;
    for (uint64_t a = 0; a < MAX_DRAWS; a++) {
        uint64_t s = mix4(sp->seed, 0x696e ^ (uint64_t)k, (uint64_t)i, a);
        gs_synth_scene sc;
        gs_synth_scene_random(id, s, &r, &sc);
        if (gs_eval_angle_bin(head_deg(&sc)) != want_bin ||
            gs_eval_expr_narrowed(&sc.expr) != narrowed ||
            gs_eval_scene_harsh(&sc) != harsh)
            continue;
        *seed = s;
        return GS_OK;
    }
    return gs_error_set(err, GS_ERR_LIMIT, "eval: no input scene for "
                        "identity %d input %d", k, i);
}

/* First target scene seed giving the wanted gaze-change bin (and, with a
 * head change, a target head pose still inside 0..50 deg). */
static int pick_target(const gs_eval_pairs_spec *sp, gs_eval_pair *p, int j,
                       gs_error *err)
{
    int want = j % 3;
    for (uint64_t a = 0; a < MAX_DRAWS; a++) {
        p->target_scene = mix4(sp->seed, p->input_scene, (uint64_t)j, a);
        int rc = gs_eval_pair_derive(p, err);
        if (rc)
            return rc;
        if (gs_eval_angle_bin(p->gaze_change_deg) == want &&
            p->head_deg < 50)
            return GS_OK;
    }
    return gs_error_set(err, GS_ERR_LIMIT, "eval: no target %d for input "
                        "%d", j, p->input);
}

int gs_eval_pairs_make(const gs_eval_pairs_spec *sp, gs_eval_pairs *out,
                       gs_error *err)
{
    out->n = 0;
    out->p = NULL;
    if (sp->split != GS_SYNTH_TEST && sp->split != GS_SYNTH_VAL &&
        sp->split != GS_SYNTH_TRAIN)
        return gs_error_set(err, GS_ERR_ARG, "eval: pairs come from the test, "
                            "validation or training identities");
    if (sp->identities < 1 || sp->identities > 100000 || sp->inputs < 1 ||
        sp->inputs > 1000 || sp->targets < 1 || sp->targets > 1000)
        return gs_error_set(err, GS_ERR_ARG, "eval: pairs spec out of range "
                            "(identities 1..100000, inputs and targets "
                            "1..1000)");
    size_t n = (size_t)sp->identities * sp->inputs * sp->targets;
    if (n > 10000000)
        return gs_error_set(err, GS_ERR_LIMIT, "eval: %zu pairs", n);
    gs_eval_pair *p = calloc(n, sizeof *p);
    if (!p)
        return gs_error_set(err, GS_ERR_NOMEM, "eval: out of memory");
    size_t q = 0;
    int rc = GS_OK;
    for (int i = 0; i < sp->inputs && !rc; i++)
        for (int k = 0; k < sp->identities && !rc; k++) {
            uint64_t s = 0;
            rc = pick_input(sp, k, i, &s, err);
            for (int j = 0; j < sp->targets && !rc; j++, q++) {
                gs_eval_pair *e = &p[q];
                e->input = i * sp->identities + k;
                e->identity = k;
                e->identity_seed = gs_synth_split_seed(sp->split,
                                                       (uint64_t)k);
                e->input_scene = s;
                e->head_change = j % 2;
                rc = pick_target(sp, e, j, err);
            }
        }
    if (rc) {
        free(p);
        return rc;
    }
    out->p = p;
    out->n = (int)n;
    return GS_OK;
}

static const char CSV_HEADER[] =
    "pair,input,identity,identity_seed,input_scene,target_scene,"
    "head_change,gaze_change_deg,head_deg,head_change_deg,narrowed,harsh";

int gs_eval_pairs_write(FILE *f, const gs_eval_pairs *ps, gs_error *err)
{
    int split = ps->n > 0 ? gs_synth_seed_split(ps->p[0].identity_seed)
                          : GS_SYNTH_TEST;
    fprintf(f, "# gazesplat eval pairs v1: %s-split identities; scenes from "
               "gs_synth_scene_random(identity_seed, scene_seed, "
               "gs_eval_ranges); docs/eval.md\n%s\n",
            split == GS_SYNTH_VAL     ? "validation"
            : split == GS_SYNTH_TRAIN ? "training"
                                      : "test",
            CSV_HEADER);
    for (int i = 0; i < ps->n; i++) {
        const gs_eval_pair *p = &ps->p[i];
        fprintf(f, "%d,%d,%d,%llu,%llu,%llu,%d,%.3f,%.3f,%.3f,%d,%d\n", i,
                p->input, p->identity, (unsigned long long)p->identity_seed,
                (unsigned long long)p->input_scene,
                (unsigned long long)p->target_scene, p->head_change,
                p->gaze_change_deg, p->head_deg, p->head_change_deg,
                p->narrowed, p->harsh);
    }
    if (ferror(f))
        return gs_error_set(err, GS_ERR_IO, "eval: cannot write the pairs");
    return GS_OK;
}

/* Parses one data line into *p (seeds and stated derived values). */
static int parse_line(char *line, int *index, gs_eval_pair *p)
{
    char *s = line, *e;
    unsigned long long u[6];
    double d[3];
    for (int k = 0; k < 6; k++) {
        if (*s < '0' || *s > '9')
            return -1;
        u[k] = strtoull(s, &e, 10);
        if (*e != ',')
            return -1;
        s = e + 1;
    }
    long hc = strtol(s, &e, 10);
    if (e == s || *e != ',')
        return -1;
    s = e + 1;
    for (int k = 0; k < 3; k++) {
        d[k] = strtod(s, &e);
        if (e == s || *e != ',' || !isfinite(d[k]))
            return -1;
        s = e + 1;
    }
    long nw = strtol(s, &e, 10);
    if (e == s || *e != ',')
        return -1;
    s = e + 1;
    long hs = strtol(s, &e, 10);
    if (e == s || (*e != '\0' && *e != '\n' && *e != '\r'))
        return -1;
    if (u[1] > 100000000ULL || u[2] > 100000000ULL || hc < 0 || hc > 1)
        return -1;
    *index = (int)(u[0] > 2000000000ULL ? -1 : (long long)u[0]);
    p->input = (int)u[1];
    p->identity = (int)u[2];
    p->identity_seed = u[3];
    p->input_scene = u[4];
    p->target_scene = u[5];
    p->head_change = (int)hc;
    p->gaze_change_deg = d[0];
    p->head_deg = d[1];
    p->head_change_deg = d[2];
    p->narrowed = (int)nw;
    p->harsh = (int)hs;
    return 0;
}

/* The stated derived values must be the generator's (to the 3 decimals
 * written), and the identity the k-th of its split (a held-out one, test
 * or validation, or a training one for the seen-identity diagnostic). */
static int check_pair(const gs_eval_pair *got, int line, gs_error *err)
{
    gs_eval_pair p = *got;
    int split = gs_synth_seed_split(p.identity_seed);
    if ((split != GS_SYNTH_TEST && split != GS_SYNTH_VAL &&
         split != GS_SYNTH_TRAIN) ||
        p.identity_seed != gs_synth_split_seed((gs_synth_split)split,
                                               (uint64_t)p.identity))
        return gs_error_set(err, GS_ERR_FORMAT, "eval pairs line %d: "
                            "identity_seed is not identity %d of a split",
                            line, p.identity);
    int rc = gs_eval_pair_derive(&p, err);
    if (rc)
        return rc;
    if (fabs(p.gaze_change_deg - got->gaze_change_deg) > 2e-3 ||
        fabs(p.head_deg - got->head_deg) > 2e-3 ||
        fabs(p.head_change_deg - got->head_change_deg) > 2e-3 ||
        p.narrowed != got->narrowed || p.harsh != got->harsh)
        return gs_error_set(err, GS_ERR_FORMAT, "eval pairs line %d: derived "
                            "values differ from this generator's (gaze "
                            "change %.3f, head %.3f deg)", line,
                            p.gaze_change_deg, p.head_deg);
    return GS_OK;
}

static int append(gs_eval_pairs *out, int *cap, const gs_eval_pair *p)
{
    if (out->n == *cap) {
        int nc = *cap ? 2 * *cap : 256;
        gs_eval_pair *np = realloc(out->p, (size_t)nc * sizeof *np);
        if (!np)
            return -1;
        out->p = np;
        *cap = nc;
    }
    out->p[out->n++] = *p;
    return 0;
}

int gs_eval_pairs_read(FILE *f, gs_eval_pairs *out, gs_error *err)
{
    char line[512];
    int cap = 0, lineno = 0, header = 0, rc = GS_OK;
    out->n = 0;
    out->p = NULL;
    while (!rc && fgets(line, sizeof line, f)) {
        lineno++;
        if (!strchr(line, '\n') && !feof(f))
            rc = gs_error_set(err, GS_ERR_FORMAT, "eval pairs line %d: too "
                              "long", lineno);
        else if (line[0] == '#' || line[0] == '\n')
            continue;
        else if (!header) {
            line[strcspn(line, "\r\n")] = 0;
            header = 1;
            if (strcmp(line, CSV_HEADER) != 0)
                rc = gs_error_set(err, GS_ERR_FORMAT, "eval pairs line %d: "
                                  "want the header '%s'", lineno, CSV_HEADER);
        } else {
            gs_eval_pair p;
            int idx;
            if (parse_line(line, &idx, &p) || idx != out->n)
                rc = gs_error_set(err, GS_ERR_FORMAT, "eval pairs line %d: "
                                  "bad row (want pair %d)", lineno, out->n);
            else if (out->n > 0 && p.input != out->p[out->n - 1].input &&
                     p.input != out->p[out->n - 1].input + 1)
                rc = gs_error_set(err, GS_ERR_FORMAT, "eval pairs line %d: "
                                  "inputs must be grouped and in order",
                                  lineno);
            else if (out->n > 0 && p.input == out->p[out->n - 1].input &&
                     (p.input_scene != out->p[out->n - 1].input_scene ||
                      p.identity != out->p[out->n - 1].identity))
                rc = gs_error_set(err, GS_ERR_FORMAT, "eval pairs line %d: "
                                  "one input, two scenes", lineno);
            else if (out->n > 0 &&
                     gs_synth_seed_split(p.identity_seed) !=
                         gs_synth_seed_split(out->p[0].identity_seed))
                rc = gs_error_set(err, GS_ERR_FORMAT, "eval pairs line %d: "
                                  "identities of two splits mixed",
                                  lineno);
            else if (!(rc = check_pair(&p, lineno, err)) &&
                     append(out, &cap, &p))
                rc = gs_error_set(err, GS_ERR_NOMEM, "eval: out of memory");
        }
    }
    if (!rc && (ferror(f) || out->n == 0))
        rc = gs_error_set(err, ferror(f) ? GS_ERR_IO : GS_ERR_FORMAT,
                          "eval pairs: %s", ferror(f) ? "read error"
                                                      : "no pairs");
    if (rc)
        gs_eval_pairs_free(out);
    return rc;
}

int gs_eval_scene_camera(const gs_synth_scene *scene, int size, double d_n_mm,
                         double f_n, gs_synth_camera *cam, gs_error *err)
{
    gs_synth_camera base;
    gs_synth_camera_single(size, 600.0, 260.0, &base);
    return gs_synth_camera_normalized(scene, &base, size, d_n_mm, f_n, cam,
                                      err);
}

int gs_eval_render_scene(const gs_synth_scene *scene, int size, double d_n_mm,
                         double f_n, gs_pool *pool, gs_synth_sample *out,
                         gs_error *err)
{
    gs_synth_camera cam;
    int rc = gs_eval_scene_camera(scene, size, d_n_mm, f_n, &cam, err);
    if (!rc)
        rc = gs_synth_sample_alloc(out, size, size, err);
    if (rc)
        return rc;
    gs_synth_render_opts o = {.supersample = 1};
    rc = gs_synth_render(scene, &cam, &o, pool, out, err);
    if (rc) {
        gs_synth_sample_free(out);
        return rc;
    }
    /* The model is trained on heads over white (docs/model.md). */
    const uint8_t *head = gs_synth_sample_mask(out, GS_SYNTH_MASK_HEAD);
    for (int y = 0; y < size; y++)
        for (int x = 0; x < size; x++)
            if (!head[(size_t)y * size + x])
                memset(out->rgb + (size_t)y * out->stride + 3 * (size_t)x,
                       255, 3);
    return GS_OK;
}
