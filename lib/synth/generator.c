/* The on-the-fly sample generator: a pure function of (config, index). */
#include <string.h>

#include "synth_internal.h"

void gs_synth_gen_config_default(gs_synth_gen_config *c)
{
    memset(c, 0, sizeof *c);
    c->split = GS_SYNTH_TRAIN;
    c->identities = 100;
    c->seed = 0;
    c->size = 128;
    c->rig = GS_SYNTH_RIG_NORMALIZED;
    c->supersample = 1;
    gs_synth_ranges_default(&c->ranges);
}

/* Field of view of the plain cameras: the face fills about half the
 * width at the nominal distance. */
#define GEN_DISTANCE_MM 600.0
#define GEN_FIELD_MM 260.0

int gs_synth_gen_scene(const gs_synth_gen_config *c, uint64_t index,
                       gs_synth_scene *scene, gs_synth_camera *cam,
                       gs_error *err)
{
    if (c->identities < 1 || c->identities > GS_SYNTH_SEED_SPLIT_COUNT)
        return gs_error_set(err, GS_ERR_ARG,
                            "synth: identities must be in 1..%llu",
                            (unsigned long long)GS_SYNTH_SEED_SPLIT_COUNT);
    if (c->split < GS_SYNTH_TRAIN || c->split > GS_SYNTH_TEST)
        return gs_error_set(err, GS_ERR_ARG, "synth: bad split %d", (int)c->split);
    if (c->size < 1 || c->size > 8192)
        return gs_error_set(err, GS_ERR_ARG, "synth: size %d outside 1..8192",
                            c->size);
    /* The dome's 18 views of one frame share its scene. */
    uint64_t frame = c->rig == GS_SYNTH_RIG_ETHX ? index / GS_SYNTH_ETHX_CAMERAS : index;
    uint64_t h = gs_synth_hash2(c->seed, frame);
    uint64_t k = gs_synth_hash2(h, 0x6964ULL) % c->identities;
    int krc = c->kappa.enabled ? gs_synth_kappa_check(&c->kappa, err) : GS_OK;
    if (krc != GS_OK)
        return krc;
    gs_synth_scene_random(gs_synth_split_seed(c->split, k), h, &c->ranges, scene);
    if (c->kappa.enabled)
        gs_synth_scene_set_kappa(&c->kappa, scene);
    switch (c->rig) {
    case GS_SYNTH_RIG_SINGLE:
        gs_synth_camera_single(c->size, GEN_DISTANCE_MM, GEN_FIELD_MM, cam);
        return GS_OK;
    case GS_SYNTH_RIG_ETHX:
        /* The dome is centred on the head's nominal position. */
        return gs_synth_camera_ethx((int)(index % GS_SYNTH_ETHX_CAMERAS), c->size,
                                    scene->head_t[2], GEN_FIELD_MM * 1.2, cam) == GS_OK
                   ? GS_OK
                   : gs_error_set(err, GS_ERR_ARG, "synth: bad camera");
    case GS_SYNTH_RIG_NORMALIZED: {
        gs_synth_camera base;
        gs_synth_camera_single(c->size, GEN_DISTANCE_MM, GEN_FIELD_MM, &base);
        return gs_synth_camera_normalized(scene, &base, c->size, 0.0, 0.0, cam,
                                          err);
    }
    }
    return gs_error_set(err, GS_ERR_ARG, "synth: bad rig %d", (int)c->rig);
}

int gs_synth_gen_sample(const gs_synth_gen_config *c, uint64_t index,
                        gs_pool *pool, gs_synth_sample *out, gs_error *err)
{
    gs_synth_scene scene;
    gs_synth_camera cam;
    int rc = gs_synth_gen_scene(c, index, &scene, &cam, err);
    if (rc != GS_OK)
        return rc;
    gs_synth_render_opts o = {.supersample = c->supersample};
    return gs_synth_render(&scene, &cam, &o, pool, out, err);
}
