/* STATS and the metrics endpoint's figures (stats.h): the counters by name
 * and the levels read at the moment of asking. */
#include "stats.h"

#include <stddef.h>

#include "gazesplat/nn.h"

#define CTR(f) {#f, offsetof(gsd_counters, f)}
static const struct {
    const char *name;
    size_t off;
} counter_names[] = {
    CTR(conn_accepted), CTR(conn_rejected), CTR(conn_closed), CTR(frames_in), CTR(frames_out),
    CTR(bytes_in), CTR(bytes_out), CTR(protocol_errors), CTR(request_errors), CTR(timeouts),
    CTR(req_hello), CTR(req_health), CTR(req_stats), CTR(req_fit), CTR(req_redirect),
    CTR(req_cancel), CTR(req_sleep), CTR(busy), CTR(cancelled), CTR(deadline_exceeded),
    CTR(fits), CTR(fits_cached), CTR(images_out), CTR(images_dropped), CTR(jobs_done), CTR(renders_full),
    CTR(renders_incremental), CTR(model_loads),
    CTR(model_load_failures), CTR(reloads), CTR(cache_saves), CTR(cache_save_failures),
    CTR(finetunes), CTR(tuned_swaps), CTR(tuned_saves), CTR(tuned_save_failures),
    CTR(renders_transfer), CTR(input_saves), CTR(input_save_failures), CTR(output_waits),
};
#define NCOUNTERS (sizeof counter_names / sizeof counter_names[0])

size_t gsd_stats_collect(gsd_server *s, gsd_stat *out, size_t cap)
{
    size_t n = 0;
    for (size_t i = 0; i < NCOUNTERS && n < cap; i++, n++)
        out[n] = (gsd_stat){counter_names[i].name,
                            atomic_load((atomic_ullong *)((char *)&s->ctr + counter_names[i].off)), 0};
    int qlen, running;
    gsd_work_lengths(s, &qlen, &running);
    gsd_cache_stats cst, tst, ist;
    gsd_cache_stats_get(s->cache, &cst);
    gsd_cache_stats_get(s->tuned, &tst);
    gsd_cache_stats_get(s->inputs, &ist);
    /* gauge 1: a level now; 0: a count that only grows */
    const gsd_stat extra[] = {
        {"connections_open", (uint64_t)s->nconns, 1}, {"queue_length", (uint64_t)qlen, 1},
        {"jobs_running", (uint64_t)running, 1}, {"cache_entries", cst.entries, 1},
        {"cache_bytes", cst.bytes, 1}, {"cache_budget", cst.budget, 1}, {"cache_hits", cst.hits, 0},
        {"cache_misses", cst.misses, 0}, {"cache_evictions", cst.evictions, 0},
        {"tuned_entries", tst.entries, 1}, {"tuned_bytes", tst.bytes, 1},
        {"tuned_evictions", tst.evictions, 0}, {"input_entries", ist.entries, 1},
        {"input_bytes", ist.bytes, 1}, {"input_evictions", ist.evictions, 0},
        {"state", (uint64_t)atomic_load(&s->state), 1},
        {"uptime_ms", (uint64_t)(ev_now_ms() - s->started_ms), 1},
        {"job_ms_avg", (uint64_t)s->job_ms_avg, 1},
        {"output_bytes", (uint64_t)atomic_load(&s->out_total), 1},
        {"output_budget", (uint64_t)atomic_load(&s->out_budget), 1},
        {"pool_threads", (uint64_t)gsd_pool_threads(&s->cfg), 1},
        {"blas_threads", (uint64_t)gs_nn_blas_threads(), 1},
        {"max_connections", (uint64_t)s->cfg.max_connections, 1}, /* in force: fits the fd limit */
    };
    for (size_t i = 0; i < sizeof extra / sizeof extra[0] && n < cap; i++, n++)
        out[n] = extra[i];
    return n;
}

