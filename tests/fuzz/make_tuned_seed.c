/* Writes the tuned-block fuzz seeds (run at build time): blocks of the
 * micro model (micro_model.h) for the face part, face + eyes, and every
 * part, each tuned value a little off the base. usage: make_tuned_seed DIR */
#include <stdio.h>
#include <stdlib.h>

#include "micro_model.h"

static int write_block(const gs_model *base, unsigned parts, const char *dir, const char *name)
{
    gs_model *t = NULL;
    gs_error err;
    uint8_t *b = NULL;
    size_t n = 0;
    if (gs_model_clone(base, &t, &err))
        return fprintf(stderr, "%s\n", err.msg), 1;
    for (int i = 0; i < t->ntensors; i++)
        if (gs_model_tensor_part(&t->t[i]) & parts)
            for (size_t k = 0; k < t->t[i].count; k++)
                t->params[t->t[i].offset + k] += 0.01f * (float)(k + 1);
    t->tuned = parts; /* as gs_model_finetune leaves it */
    int rc = gs_model_tuned_encode(t, &b, &n, &err);
    gs_model_destroy(t);
    if (rc)
        return fprintf(stderr, "%s\n", err.msg), 1;
    char path[4096];
    snprintf(path, sizeof path, "%s/%s", dir, name);
    FILE *f = fopen(path, "wb");
    int bad = !f || fwrite(b, 1, n, f) != n;
    if (f && fclose(f))
        bad = 1;
    free(b);
    return bad ? (fprintf(stderr, "cannot write %s\n", path), 1) : 0;
}

int main(int argc, char **argv)
{
    if (argc != 2)
        return fprintf(stderr, "usage: make_tuned_seed DIR\n"), 2;
    gs_model m = {0};
    gs_error err;
    if (micro_model(&m, &err))
        return fprintf(stderr, "%s\n", err.msg), 1;
    int rc = write_block(&m, GS_FT_FACE, argv[1], "face.gsft") ||
             write_block(&m, GS_FT_FACE | GS_FT_EYE, argv[1], "face_eye.gsft") ||
             write_block(&m, 0x1f, argv[1], "all.gsft");
    free(m.params);
    return rc;
}
