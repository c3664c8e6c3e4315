/* gazesplat: command-line front end. Looks the subcommand up in a table;
 * each subcommand lives in its own file and parses its own options. */
#include <stdio.h>
#include <string.h>

#include "cli.h"
#include "gazesplat/nn.h"

static const cli_command *const commands[] = {
    &cli_face_command,
    &cli_client_command,
    &cli_render_command,
    &cli_scene_command,
    &cli_synth_command,
    &cli_train_command,
    &cli_fit_command,
    &cli_redirect_command,
    &cli_augment_command,
    &cli_live_command,
    &cli_train_estimator_command,
    &cli_estimate_command,
    &cli_eval_estimator_command,
    &cli_eval_command,
    &cli_eval_downstream_command,
    &cli_eval_range_command,
    &cli_eval_photos_command,
    &cli_check_labels_command,
    &cli_model_command,
};
#define NCOMMANDS (int)(sizeof commands / sizeof commands[0])

static void overview(FILE *f)
{
    fputs("usage: gazesplat COMMAND [OPTIONS]\n"
          "       gazesplat help COMMAND\n"
          "       gazesplat --version\n\n"
          "Commands:\n", f);
    for (int i = 0; i < NCOMMANDS; i++)
        fprintf(f, "  %-8s %s\n", commands[i]->name, commands[i]->summary);
    fputs("\nExit status: 0 success, 1 failure, 2 bad usage.\n", f);
}

static const cli_command *lookup(const char *name)
{
    for (int i = 0; i < NCOMMANDS; i++)
        if (strcmp(commands[i]->name, name) == 0)
            return commands[i];
    return NULL;
}

static int help(int argc, char **argv)
{
    if (argc == 2) {
        overview(stdout);
        return CLI_OK;
    }
    const cli_command *c = argc == 3 ? lookup(argv[2]) : NULL;
    if (!c) {
        fprintf(stderr, "gazesplat help: %s\n", argc == 3 ? "unknown command" : "one command name");
        overview(stderr);
        return CLI_USAGE;
    }
    fputs(c->usage, stdout);
    return CLI_OK;
}

int main(int argc, char **argv)
{
    /* May run the program again with OpenBLAS's AVX kernels selected (nn.h). */
    gs_nn_blas_select_kernels(argv);
    /* One OpenBLAS thread for every command (nn.h): they parallelise with
     * gs_pool, and OpenBLAS's own threads would fight the pool. */
    gs_nn_blas_set_threads(1);
    if (argc < 2) {
        overview(stderr);
        return CLI_USAGE;
    }
    if (strcmp(argv[1], "--version") == 0 || strcmp(argv[1], "version") == 0) {
        printf("gazesplat %s\n", GS_VERSION);
        return CLI_OK;
    }
    if (strcmp(argv[1], "--help") == 0 || strcmp(argv[1], "-h") == 0) {
        overview(stdout);
        return CLI_OK;
    }
    if (strcmp(argv[1], "help") == 0)
        return help(argc, argv);
    const cli_command *c = lookup(argv[1]);
    if (!c) {
        fprintf(stderr, "gazesplat: unknown command '%s'\n", argv[1]);
        overview(stderr);
        return CLI_USAGE;
    }
    return cli_run(c, argc - 1, argv + 1);
}
