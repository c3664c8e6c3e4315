/* Shared by the eval command tests: spawning the CLI with its output in a
 * log file, reading a file whole, and training the tiny model they run on.
 * Include after gs_test.h (CHECK) with _POSIX_C_SOURCE 200809L defined. */
#ifndef GS_EVAL_FIXTURE_H
#define GS_EVAL_FIXTURE_H

#include <fcntl.h>
#include <spawn.h>
#include <stdio.h>
#include <stdlib.h>
#include <sys/wait.h>

#include "gazesplat/nn.h"
#include "gazesplat/train.h"

extern char **environ;

/* Runs args[0] with args (NULL-terminated), stdout and stderr to
 * logdir/log.txt; returns the exit code (-1 when killed). A non-zero exit
 * prints the start of the log. */
static inline int ev_spawn(const char *logdir, const char *const *args)
{
    char logp[256];
    snprintf(logp, sizeof logp, "%s/log.txt", logdir);
    posix_spawn_file_actions_t fa;
    posix_spawn_file_actions_init(&fa);
    posix_spawn_file_actions_addopen(&fa, 1, logp, O_WRONLY | O_CREAT | O_TRUNC, 0644);
    posix_spawn_file_actions_adddup2(&fa, 1, 2);
    pid_t pid;
    int st = 0, status = -1;
    if (posix_spawn(&pid, args[0], &fa, NULL, (char *const *)args, environ) == 0 &&
        waitpid(pid, &st, 0) == pid && WIFEXITED(st))
        status = WEXITSTATUS(st);
    posix_spawn_file_actions_destroy(&fa);
    if (status != 0) {
        char buf[2048];
        FILE *f = fopen(logp, "r");
        size_t k = f ? fread(buf, 1, sizeof buf - 1, f) : 0;
        buf[k] = 0;
        if (f)
            fclose(f);
        printf("%s: exit %d: %s", args[0], status, buf);
    }
    return status;
}

/* The file's first MiB as a string (NULL when it cannot be read). */
static inline char *ev_slurp(const char *path)
{
    FILE *f = fopen(path, "rb");
    if (!f)
        return NULL;
    char *buf = malloc(1 << 20);
    size_t n = buf ? fread(buf, 1, (1 << 20) - 1, f) : 0;
    if (buf)
        buf[n] = 0;
    fclose(f);
    return buf;
}

/* The tiny preset with 2 training identities, trained for `steps` steps
 * (seconds) and saved to path. */
static inline void ev_train_tiny(const char *path, int steps)
{
    gs_nn_blas_set_threads(1);
    gs_model_spec spec;
    gs_model_spec_default(&spec);
    spec.preset = "tiny";
    spec.train_identities = 2;
    gs_model *m = NULL;
    gs_error err = {0, ""};
    CHECK(gs_model_new(&spec, 5, &m, &err) == GS_OK);
    gs_train_options to;
    gs_train_options_default(&to);
    to.out_path = path;
    to.steps = steps;
    to.checkpoint_every = 0;
    gs_train_report rep;
    CHECK_MSG(gs_train(m, &to, NULL, &rep, &err) == GS_OK, "%s", err.msg);
    gs_model_destroy(m);
}

#endif
