/* Angle kappa: each identity's visual axis vs its eyeballs' optical axes
 * (see synth.h and docs/synth.md, "Angle kappa"). */
#include <string.h>

#include "synth_internal.h"

#define DEG (3.14159265358979323846 / 180.0)
/* Stream of an identity's kappa: its seed alone ('kapa'). */
#define KAPPA_STREAM 0x6b617061ULL

void gs_synth_kappa_literature(gs_synth_kappa *k)
{
    memset(k, 0, sizeof *k);
    k->enabled = 1;
    k->h_mean_deg = 5.0;
    k->h_sd_deg = 1.3;
    k->v_mean_deg = 1.5;
    k->v_sd_deg = 1.0;
}

int gs_synth_kappa_check(const gs_synth_kappa *k, gs_error *err)
{
    const double v[4] = {k->h_mean_deg, k->h_sd_deg, k->v_mean_deg, k->v_sd_deg};
    static const char *const names[4] = {"horizontal mean", "horizontal sd",
                                         "vertical mean", "vertical sd"};
    for (int i = 0; i < 4; i++) {
        int sd = i & 1;
        if (!isfinite(v[i]) || (sd ? v[i] < 0.0 || v[i] > 5.0 : fabs(v[i]) > 15.0))
            return gs_error_set(err, GS_ERR_ARG, "synth: kappa %s %g deg outside %s",
                                names[i], v[i], sd ? "[0, 5]" : "[-15, 15]");
    }
    return GS_OK;
}

/* A standard normal draw truncated at +-3 (redrawn beyond), Box-Muller on
 * two uniforms in (0, 1]. */
static double normal3(gs_rng *r)
{
    for (;;) {
        double u1 = 1.0 - gs_rng_uniform(r, 0.0, 1.0);
        double u2 = gs_rng_uniform(r, 0.0, 1.0);
        double z = sqrt(-2.0 * log(u1)) * cos(2.0 * 3.14159265358979323846 * u2);
        if (fabs(z) <= 3.0)
            return z;
    }
}

void gs_synth_kappa_draw(const gs_synth_kappa *k, uint64_t identity_seed,
                         double *h, double *v)
{
    *h = *v = 0.0;
    if (!k || !k->enabled)
        return;
    gs_rng r;
    gs_rng_seed(&r, gs_synth_hash2(identity_seed, KAPPA_STREAM));
    double zh = normal3(&r), zv = normal3(&r);
    *h = (k->h_mean_deg + k->h_sd_deg * zh) * DEG;
    *v = (k->v_mean_deg + k->v_sd_deg * zv) * DEG;
}

void gs_synth_scene_set_kappa(const gs_synth_kappa *k, gs_synth_scene *s)
{
    s->kappa = k && k->enabled;
    gs_synth_kappa_draw(k, s->identity.seed, &s->kappa_h, &s->kappa_v);
}

void gs_synth_kappa_rotation(int eye, double h, double v, double K[9])
{
    /* Temporal is toward -x (yaw > 0) for the right eye, +x for the left;
     * the optical axis is below the visual one for v > 0. */
    gs_geom_rot_from_pitchyaw(-v, eye == GS_SYNTH_EYE_RIGHT ? h : -h, 0.0, K);
}

void gs_synth_head_build_scene(const gs_synth_scene *s, head_model *h)
{
    double k[2] = {s->kappa_h, s->kappa_v};
    gs_synth_head_build_kappa(&s->identity, &s->expr, s->gaze_pitch, s->gaze_yaw,
                              s->kappa ? k : NULL, h);
}
