/* Writes the smallest valid model file (the fuzz seed of the model
 * loader): tests/fuzz/corpus/model/micro.safetensors. Build and run it by
 * hand after a change of the model format:
 *   cc -Ilib/include -Ilib/model tests/fuzz/make_model_seed.c \
 *      build/lib/libgazesplat.a -lopenblas -lm -lpthread -lstdc++ ... */
#include <stdio.h>
#include <stdlib.h>

#include "micro_model.h"

int main(int argc, char **argv)
{
    gs_model m = {0};
    gs_error err;
    if (micro_model(&m, &err))
        return fprintf(stderr, "%s\n", err.msg), 1;
    if (gs_model_save(&m, argc > 1 ? argv[1] : "micro.safetensors", &err))
        return fprintf(stderr, "%s\n", err.msg), 1;
    free(m.params);
    return 0;
}
