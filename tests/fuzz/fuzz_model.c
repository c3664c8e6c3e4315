/* Fuzz target: the model loader on arbitrary bytes.
 * Invariants (abort on violation): a refusal carries its code and a
 * message; a model that loads reports a consistent size and a context can
 * be made for it. */
#include <stdint.h>
#include <stdlib.h>

#include "gazesplat/model.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    gs_model *m = NULL;
    gs_error err = {0, ""};
    int rc = gs_model_load_mem(data, size, &m, &err);
    if (rc != GS_OK) {
        if (rc > 0 || err.code != rc || err.msg[0] == '\0' || m)
            abort();
        return 0;
    }
    gs_model_info info;
    gs_model_get_info(m, &info);
    if (info.image_size != 4 * info.feat_size || info.param_bytes == 0)
        abort();
    gs_model_destroy(m);
    return 0;
}
