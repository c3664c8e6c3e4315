/* Writes the smallest valid model file (the fuzz seed of the model
 * loader): tests/fuzz/corpus/model/micro.safetensors. Build and run it by
 * hand after a change of the model format:
 *   cc -Ilib/include -Ilib/model tests/fuzz/make_model_seed.c \
 *      build/lib/libgazesplat.a -lopenblas -lm -lpthread -lstdc++ ... */
#include <stdio.h>
#include <stdlib.h>

#include "model_internal.h"

int main(int argc, char **argv)
{
    gs_model_config c;
    gs_model_config_default(&c);
    c.n_face = 2;
    c.n_eye_each = 1;
    c.feat_dim = 1;
    c.id_dim = 1;
    c.hidden = 2;
    c.channels = 3;
    c.feat_size = 8;
    c.image_size = 32;
    c.n_train_ids = 1;
    gs_model m = {0};
    gs_error err;
    if (gs_model_layout(&c, &m, &err))
        return fprintf(stderr, "%s\n", err.msg), 1;
    m.params = calloc(m.nparams, sizeof(float));
    gs_model_bind(&m, m.params, &m.p);
    for (size_t i = 0; i < m.nparams; i++)
        m.params[i] = 0.25f;
    if (gs_model_save(&m, argc > 1 ? argv[1] : "micro.safetensors", &err))
        return fprintf(stderr, "%s\n", err.msg), 1;
    free(m.params);
    return 0;
}
