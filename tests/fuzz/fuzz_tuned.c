/* Fuzz target: tuned blocks (gs_model_tuned_apply) on arbitrary bytes,
 * against the micro model (micro_model.h; the seeds are its blocks).
 * Invariants (abort on violation): a refusal carries its code and a
 * message and leaves the clone's parameters untouched; an accepted block
 * leaves only finite parameters, and putting the base back (NULL block)
 * restores every byte. */
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "micro_model.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

static gs_model base;
static gs_model *clone_m;
static float *snap;

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    gs_error err = {0, ""};
    if (!clone_m) {
        if (micro_model(&base, &err) || gs_model_clone(&base, &clone_m, &err))
            abort();
        snap = malloc(base.nparams * sizeof(float));
        if (!snap)
            abort();
    }
    memcpy(snap, clone_m->params, base.nparams * sizeof(float));
    int rc = gs_model_tuned_apply(clone_m, &base, size ? data : (const uint8_t *)"", size, &err);
    if (rc != GS_OK) {
        if (rc > 0 || err.code != rc || err.msg[0] == '\0' ||
            memcmp(snap, clone_m->params, base.nparams * sizeof(float)))
            abort();
        return 0;
    }
    for (size_t i = 0; i < base.nparams; i++)
        if (!isfinite(clone_m->params[i]))
            abort();
    if (gs_model_tuned_apply(clone_m, &base, NULL, 0, &err) != GS_OK ||
        memcmp(base.params, clone_m->params, base.nparams * sizeof(float)))
        abort();
    return 0;
}
