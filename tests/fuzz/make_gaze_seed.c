/* Writes the seed corpus of the estimator loader into DIR: the smallest
 * valid estimator of each architecture (run at build time, see
 * CMakeLists.txt, so the seeds follow the format). usage: make_gaze_seed DIR */
#include <stdio.h>

#include "gazesplat/gaze.h"

int main(int argc, char **argv)
{
    if (argc != 2)
        return fprintf(stderr, "usage: make_gaze_seed DIR\n"), 2;
    for (int arch = GS_GAZE_RESNET; arch <= GS_GAZE_VGG; arch++) {
        gs_gaze_spec s;
        gs_gaze_spec_default(&s, arch);
        s.input_size = 32;
        for (int i = 0; i < GS_GAZE_STAGES; i++)
            s.widths[i] = 1;
        s.hidden = 1;
        gs_gaze_net *n = NULL;
        gs_error err = {0, ""};
        char path[4096];
        snprintf(path, sizeof path, "%s/%s.safetensors", argv[1], gs_gaze_arch_name(arch));
        if (gs_gaze_net_create(&s, 1, &n, &err) || gs_gaze_net_save(n, path, &err))
            return fprintf(stderr, "make_gaze_seed: %s\n", err.msg), 1;
        gs_gaze_net_destroy(n);
    }
    return 0;
}
