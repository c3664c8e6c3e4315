/* Fuzz target: the gaze estimator loader on arbitrary bytes.
 * Invariants (abort on violation): a refusal carries its code and a
 * message and no net; a net that loads has a valid spec and predicts on a
 * small image, returning GS_OK with finite outputs or GS_ERR_NONFINITE. */
#include <math.h>
#include <stdint.h>
#include <stdlib.h>

#include "gazesplat/gaze.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    gs_gaze_net *n = NULL;
    gs_error err = {0, ""};
    int rc = gs_gaze_net_load_mem(data, size, &n, &err);
    if (rc != GS_OK) {
        if (rc > 0 || err.code != rc || err.msg[0] == '\0' || n)
            abort();
        return 0;
    }
    gs_gaze_spec s;
    gs_gaze_net_spec(n, &s);
    if (!gs_gaze_arch_name(s.arch) || s.input_size < 32 || s.input_size % 16 ||
        gs_gaze_net_param_count(n) == 0)
        abort();
    uint8_t rgb[8 * 8 * 3];
    for (size_t i = 0; i < sizeof rgb; i++)
        rgb[i] = (uint8_t)(i * 37);
    float out[4];
    rc = gs_gaze_net_predict(n, NULL, rgb, 8, 8, 24, out, &err);
    if (rc == GS_OK) {
        for (int k = 0; k < 4; k++)
            if (!isfinite(out[k]))
                abort();
    } else if (rc != GS_ERR_NONFINITE) {
        abort();
    }
    gs_gaze_net_destroy(n);
    return 0;
}
