/* gazesplat model: what a model file holds, and the serving settings it
 * names (the fit's code prior and code rate) set in a copy. */
#include <errno.h>
#include <inttypes.h>
#include <stdlib.h>
#include <stdio.h>
#include <string.h>

#include "cli.h"
#include "gazesplat/model.h"
#include "gazesplat/train.h"

static int run_model(const cli_command *cmd, cli_opt *o);

static const cli_opt model_opts[] = {
    {"--model", 1, NULL}, {"--fit-code-prior", 1, NULL}, {"--fit-code-rate", 1, NULL},
    {"--out", 1, NULL}};

const cli_command cli_model_command = {
    "model",
    "show a model file's configuration; set the fit settings it names",
    "usage: gazesplat model --model FILE [--fit-code-prior W]\n"
    "                       [--fit-code-rate R] [--out OUT]\n"
    "\n"
    "  --model FILE        a model file (gazesplat train); loaded and checked\n"
    "                      as the daemon loads it, then described on stdout\n"
    "  --fit-code-prior W  write a copy naming W as the weight of the fit's\n"
    "                      code prior (config.fit_code_prior, 0..10; 0: none),\n"
    "                      the default of every fit made with the model (the\n"
    "                      daemon's, gazesplat fit, redirect, live and eval);\n"
    "                      read as eval's --code-prior reads it, so the model\n"
    "                      fits as `eval --code-prior W` did (docs/model.md,\n"
    "                      \"Fitting\")\n"
    "  --fit-code-rate R   write a copy naming R as the fit's Adam rate for\n"
    "                      the code (config.fit_code_rate, 0..10; 0: none,\n"
    "                      the library's default 0.12), the default of every\n"
    "                      fit made with the model, as eval's --fit-lr R\n"
    "                      (its colour rate stays 0.02)\n"
    "  --out OUT           where the copy goes (written atomically; may be\n"
    "                      FILE itself); the parameters are the same bytes\n",
    .opts = model_opts,
    .nopts = CLI_NOPTS(model_opts),
    .run_opts = run_model,
};

enum { O_MODEL, O_PRIOR, O_RATE, O_OUT, O_N };

static void describe(const char *path, const gs_model *m)
{
    gs_model_info mi;
    gs_model_get_info(m, &mi);
    printf("model: %s\n", path);
    printf("image_size: %d\n", mi.image_size);
    printf("feat_size: %d\n", mi.feat_size);
    printf("supersample: %d\n", mi.supersample);
    printf("eye_direct: %d\n", mi.eye_direct);
    printf("lids: %d\n", gs_model_has_lids(m));
    printf("gaussians_face: %d\n", mi.n_face);
    printf("gaussians_eye: %d\n", mi.n_eye);
    printf("code_dim: %d\n", mi.code_dim);
    printf("train_identities: %d\n", mi.n_train_ids);
    printf("focal_px: %.17g\n", mi.focal);
    printf("distance_mm: %.17g\n", mi.distance_mm);
    printf("param_bytes: %zu\n", mi.param_bytes);
    printf("param_id: %016" PRIx64 "\n", mi.param_id);
    printf("fit_code_prior: %.17g\n", mi.fit_code_prior);
    printf("fit_code_rate: %.17g\n", mi.fit_code_rate);
}

/* --fit-code-rate R, read as a double the way eval's --fit-lr reads its
 * code rate, so that the model fits to the bit as `eval --fit-lr R` did. */
static int parse_rate(const cli_command *cmd, const char *v, double *out)
{
    if (!v)
        return CLI_OK;
    char *end;
    errno = 0;
    double r = strtod(v, &end);
    if (errno || end == v || *end || !(r >= 0.0 && r <= 10.0))
        return cli_usage_error(cmd, "--fit-code-rate: want a rate in [0, 10] "
                                    "(0: the default); got '%s'", v);
    *out = r;
    return CLI_OK;
}

_Static_assert(CLI_NOPTS(model_opts) == O_N, "model_opts: one entry per option index");

static int run_model(const cli_command *cmd, cli_opt *o)
{
    int rc = CLI_OK;
    if (!o[O_MODEL].value)
        return cli_usage_error(cmd, "missing --model");
    const int set = o[O_PRIOR].value || o[O_RATE].value;
    if (set != !!o[O_OUT].value)
        return cli_usage_error(cmd, "--out goes with --fit-code-prior and/or "
                                    "--fit-code-rate");
    double prior = -1.0, rate = -1.0;
    if ((rc = cli_parse_range(cmd, "--fit-code-prior", o[O_PRIOR].value, 0.0, 10.0,
                              "a weight in [0, 10] (0: no prior)", &prior)) ||
        (rc = parse_rate(cmd, o[O_RATE].value, &rate)))
        return rc;
    gs_error err = {0, ""};
    gs_model *m = NULL;
    if (gs_model_load(o[O_MODEL].value, &m, &err))
        return cli_fail(cmd, "%s: %s", o[O_MODEL].value, err.msg);
    if (o[O_OUT].value) {
        if ((o[O_PRIOR].value && gs_model_set_fit_code_prior(m, prior, &err)) ||
            (o[O_RATE].value && gs_model_set_fit_code_rate(m, rate, &err)) ||
            gs_model_write(m, o[O_OUT].value, &err)) {
            gs_model_destroy(m);
            return cli_fail(cmd, "%s: %s", o[O_OUT].value, err.msg);
        }
        describe(o[O_OUT].value, m);
    } else {
        describe(o[O_MODEL].value, m);
    }
    gs_model_destroy(m);
    return CLI_OK;
}
