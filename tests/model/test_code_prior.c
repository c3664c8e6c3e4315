/* The fit's code prior as served (lib/model/prior_table.c) is the one the
 * training sampler gives (gs_train_code_prior, 4096 scenes), to the bit,
 * for models of other identities and image sizes: a model's fit draws no
 * scenes, and a change to the sampler fails here until the table is
 * written again:
 *     test_code_prior --print > lib/model/prior_table.c */
#include <stdio.h>
#include <string.h>

#include "../../lib/model/model_internal.h"
#include "gs_test.h"
#include "model_test_util.h"

static void print_table(const gs_code_prior *p)
{
    enum { N = GS_CODE_PRIOR_DIM };
    printf("/* The fit's code prior (prior.c): the mean and precision of the code's\n"
           " * [expression | lights] slots over the training sampler's scenes, as\n"
           " * gs_train_code_prior (lib/train/prior.c) computes them. Written by\n"
           " * test_code_prior --print, which checks them against it. */\n"
           "#include \"model_internal.h\"\n\n");
    printf("const gs_code_prior gs_code_prior_table = {\n    .mean = {\n");
    for (int i = 0; i < N; i++)
        printf("%s%.17g,%s", i % 4 ? " " : "        ", p->mean[i],
               i % 4 == 3 || i == N - 1 ? "\n" : "");
    printf("    },\n    .prec = {\n");
    for (int i = 0; i < N * N; i++)
        printf("%s%.17g,%s", i % 4 ? " " : "        ", p->prec[i],
               i % 4 == 3 || i == N * N - 1 ? "\n" : "");
    printf("    },\n};\n");
}

int main(int argc, char **argv)
{
    gs_error err = {0, ""};
    gs_model *m = tiny_model(GS_GUIDE_ADDITIVE, 1);
    CHECK(m != NULL);
    if (!m)
        GS_TEST_END();
    gs_code_prior want, got;
    const gs_code_prior *table = &gs_code_prior_table;
    CHECK_MSG(gs_train_code_prior(m, &want, &err) == GS_OK, "%s", err.msg);
    if (argc == 2 && !strcmp(argv[1], "--print")) {
        print_table(&want);
        gs_model_destroy(m);
        return 0;
    }
    CHECK_MSG(!memcmp(&want, table, sizeof want),
              "lib/model/prior_table.c is not the sampler's prior (mean[0] %.17g against %.17g): "
              "write it again with test_code_prior --print", table->mean[0], want.mean[0]);
    gs_model_destroy(m);
    /* Other identities and image sizes: the same scenes' expressions and
     * lights, so the same prior. */
    const int ids[] = {64, 320}, sizes[] = {128, 256};
    for (int a = 0; a < 2; a++)
        for (int b = 0; b < 2; b++) {
            gs_model_config cfg;
            tiny_config(&cfg);
            cfg.n_train_ids = ids[a];
            cfg.image_size = sizes[b];
            cfg.feat_size = sizes[b] / 4;
            cfg.focal = 1600.0 * sizes[b] / 512;
            m = NULL;
            CHECK_MSG(gs_model_create(&cfg, 1, &m, &err) == GS_OK, "%s", err.msg);
            if (!m)
                continue;
            CHECK_MSG(gs_train_code_prior(m, &got, &err) == GS_OK, "%s", err.msg);
            CHECK_MSG(!memcmp(&want, &got, sizeof want),
                      "%d identities at %d px: another prior (mean[0] %.17g against %.17g)",
                      ids[a], sizes[b], got.mean[0], want.mean[0]);
            gs_model_destroy(m);
        }
    printf("code prior: the table is the sampler's, for 3, 64 and 320 identities at 128 and 256 px\n");
    GS_TEST_END();
}
