/* gazesplatd's event loop side (server.c): start, run, stop, the Health
 * state, a reloaded configuration. main.c drives it; no other file calls
 * into it (jobs answer through out.h). */
#ifndef GSD_SERVER_H
#define GSD_SERVER_H

#include "daemon.h"

int gsd_server_init(gsd_server *s, const gsd_config *cfg, char *msg, size_t cap);
int gsd_server_run(gsd_server *s);
void gsd_server_free(gsd_server *s);
/* Health state and its detail text (loop thread); sends READY=1 once. */
void gsd_server_set_state(gsd_server *s, int state, const char *detail);
/* Applies a reloaded configuration (SIGHUP). */
void gsd_server_reconfigure(gsd_server *s, const gsd_config *cfg);

#endif
