/* The fast backward replays records of the forward's contributions; tiles
 * whose records did not fit the budget are evaluated again. Both ways must
 * give the same bytes, whichever tiles fit (that depends on which worker
 * composited which tile, so on scheduling): this runs one scene with the
 * default budget, with none (every tile evaluated again) and with budgets
 * that record only some tiles, on 1, 2 and 3 threads, and with records
 * switched off (gs_raster_set_records), and with the records freed between
 * a forward and its backward (gs_raster_trim), and compares bytes. */
#include "raster_internal.h"
#include "rt_util.h"

/* Tiles of the last forward that kept their records (of them, *filled
 * with at least one), and tiles in all. */
static void count_recorded(const gs_raster *r, int *rec, int *filled, int *all)
{
    *all = r->tiles_x * r->tiles_y;
    *rec = *filled = 0;
    for (int t = 0; t < *all; t++) {
        *rec += r->tile_rec[t].n != GS_REC_NONE;
        *filled += r->tile_rec[t].n != GS_REC_NONE && r->tile_rec[t].n > 0;
    }
}

static void run_scene(uint64_t seed, int n, int C, int W, int H, int aa)
{
    rt_scene s;
    rt_upstream u;
    rt_scene_for_grads(&s, &u, seed, n, C, W, H, aa, seed + 7, seed + 8);

    rt_result ref;
    gs_raster *r = gs_raster_create();
    rt_run_with(r, &s, GS_RASTER_FAST, NULL, &u, &ref);
    CHECK(ref.fwd_status == GS_OK && ref.bwd_status == GS_OK);
    int rec, filled, all;
    count_recorded(r, &rec, &filled, &all);
    CHECK_MSG(rec == all, "default budget: %d of %d tiles recorded", rec, all);
    size_t total = 0;
    for (int w = 0; w < r->n_arenas; w++)
        total += r->arenas[w].n;
    gs_raster_destroy(r);
    printf("  default budget: %d of %d tiles recorded, %zu records\n", rec, all, total);

    /* Bytes per record: a header and 8 floats. Budgets for none, about a
     * third and about two thirds of the records (per worker: divided by
     * the thread count). */
    const size_t per = sizeof(uint32_t) + 8 * sizeof(float);
    size_t budgets[] = {1, per * (total / 3 + 1), per * (2 * total / 3 + 1)};
    int saw_mixed = 0;
    for (size_t b = 0; b < sizeof budgets / sizeof budgets[0]; b++)
        for (int t = 1; t <= 3; t++) {
            gs_pool *pool = gs_pool_create(t);
            r = gs_raster_create();
            CHECK(pool && r);
            r->rec_budget = budgets[b] * (size_t)t;
            rt_result o;
            rt_run_with(r, &s, GS_RASTER_FAST, pool, &u, &o);
            CHECK(o.fwd_status == GS_OK && o.bwd_status == GS_OK);
            count_recorded(r, &rec, &filled, &all);
            saw_mixed |= filled > 0 && rec < all;
            char what[96];
            snprintf(what, sizeof what, "budget %zu B/worker, %d thread(s), %d of %d tiles",
                     budgets[b], t, rec, all);
            if (rt_same_bytes(what, &o, &ref))
                printf("  %s: bit-identical\n", what);
            if (b == 0)
                CHECK_MSG(filled == 0, "%s: no records should fit", what);
            rt_result_free(&o);
            gs_raster_destroy(r);
            gs_pool_destroy(pool);
        }
    CHECK_MSG(saw_mixed, "no run recorded only some tiles");

    /* Records switched off (renders no backward follows): no tile keeps
     * any, and the outputs and a backward still give the same bytes. */
    for (int t = 1; t <= 2; t++) {
        gs_pool *pool = gs_pool_create(t);
        r = gs_raster_create();
        CHECK(pool && r);
        gs_raster_set_records(r, 0);
        rt_result o;
        rt_run_with(r, &s, GS_RASTER_FAST, pool, &u, &o);
        CHECK(o.fwd_status == GS_OK && o.bwd_status == GS_OK);
        count_recorded(r, &rec, &filled, &all);
        CHECK_MSG(rec == 0, "records off, %d thread(s): %d of %d tiles recorded", t, rec, all);
        char what[64];
        snprintf(what, sizeof what, "records off, %d thread(s)", t);
        if (rt_same_bytes(what, &o, &ref))
            printf("  %s: bit-identical\n", what);
        rt_result_free(&o);
        gs_raster_destroy(r);
        gs_pool_destroy(pool);
    }
    /* gs_raster_trim between a forward and its backward: the records and
     * the backward scratch go, the backward evaluates every tile again,
     * and the next forward records again; the same bytes throughout. */
    for (int t = 1; t <= 2; t++) {
        gs_pool *pool = gs_pool_create(t);
        r = gs_raster_create();
        CHECK(pool && r);
        rt_result o;
        rt_run_with(r, &s, GS_RASTER_FAST, pool, &u, &o); /* grows everything */
        rt_result_free(&o);
        rt_run_with(r, &s, GS_RASTER_FAST, pool, NULL, &o);
        CHECK(o.fwd_status == GS_OK);
        gs_raster_trim(r);
        count_recorded(r, &rec, &filled, &all);
        size_t kept = r->cap_slots;
        for (int w = 0; w < r->n_arenas; w++)
            kept += r->arenas[w].cap;
        CHECK_MSG(rec == 0 && kept == 0, "trim, %d thread(s): %d tiles recorded, %zu kept", t,
                  rec, kept);
        gs_gaussian_grads gr = {o.g_means, o.g_log_scales, o.g_quats, o.g_opacity,
                                o.g_features};
        gs_error err;
        o.bwd_status = gs_raster_backward(r, pool, u.v_features, u.v_alpha, u.v_depth, &gr,
                                          o.g_background, &err);
        CHECK(o.bwd_status == GS_OK);
        char what[64];
        snprintf(what, sizeof what, "trimmed before the backward, %d thread(s)", t);
        if (rt_same_bytes(what, &o, &ref))
            printf("  %s: bit-identical\n", what);
        rt_result_free(&o);
        rt_run_with(r, &s, GS_RASTER_FAST, pool, &u, &o);
        count_recorded(r, &rec, &filled, &all);
        CHECK_MSG(rec == all, "after trim, %d thread(s): %d of %d tiles recorded", t, rec, all);
        snprintf(what, sizeof what, "a forward after trim, %d thread(s)", t);
        if (rt_same_bytes(what, &o, &ref))
            printf("  %s: bit-identical\n", what);
        rt_result_free(&o);
        gs_raster_destroy(r);
        gs_pool_destroy(pool);
    }
    gs_raster_trim(NULL);
    rt_result_free(&ref);
    rt_upstream_free(&u);
    rt_scene_free(&s);
}

int main(void)
{
    run_scene(1101, 3000, 32, 128, 96, 0);
    run_scene(2202, 1500, 3, 100, 75, 1);
    run_scene(3303, 800, 64, 61, 47, 0);
    GS_TEST_END();
}
