/* STATS figures (stats.c), for the STATS reply (server.c) and the
 * Prometheus endpoint (metrics.c). */
#ifndef GSD_STATS_H
#define GSD_STATS_H

#include "daemon.h"

/* Every STATS figure into out (at most cap); returns how many. */
size_t gsd_stats_collect(gsd_server *s, gsd_stat *out, size_t cap);

#endif
