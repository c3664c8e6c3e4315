/* The served model (model_ref.c): loaded in a background thread, swapped in
 * by the loop, held by reference while a worker or the live stage uses it
 * (the functions the other files call are in daemon.h). */
#ifndef GSD_MODEL_REF_H
#define GSD_MODEL_REF_H

#include "daemon.h"
#include "gazesplat/model.h"

struct gsd_model {
    gs_model *m;
    gs_model_info info;
    int image_size;
    char id[33];
    char path[GSD_STR_MAX];
    atomic_int refs;
};

/* The current model with one more reference (NULL when none). */
gsd_model *gsd_model_acquire(gsd_server *s);
/* Drops a reference; the last one frees the model. NULL is fine. */
void gsd_model_unref(gsd_model *m);

#endif
