/* gazesplat eval-range end to end on a tiny model (trained here for
 * seconds) and a few training steps: one CSV row per test image with every
 * condition's error finite, the flag "inside the source range" as the
 * test scenes say, the same bytes for 1 and 2 threads, the set sizes in the
 * summary, the estimators written and loadable, usage errors exit 2 and
 * runtime failures 1. The library refuses options outside their ranges.
 * usage: test_eval_range GAZESPLAT */
#define _POSIX_C_SOURCE 200809L /* posix_spawn, mkdtemp */

#include <fcntl.h>
#include <math.h>
#include <spawn.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include "gazesplat/eval.h"
#include "gazesplat/gaze.h"
#include "gazesplat/train.h"
#include "gs_test.h"

#include "eval_fixture.h"

static char dir[] = "range_test_XXXXXX";
enum { SOURCES = 2, PER_SOURCE = 2, TARGETS = 3, TESTS = 2, PER_TEST = 3 };

static int run(const char *exe, const char *model, const char *out,
               const char *threads, int save)
{
    const char *a[] = {exe, "eval-range", "--model", model, "--out", out,
                       "--sources", "2", "--per-source", "2", "--targets", "3",
                       "--tests", "2", "--per-test", "3", "--steps", "3",
                       "--batch", "4", "--iters", "2", "--threads", threads,
                       save ? "--save-estimators" : NULL, NULL};
    return ev_spawn(dir, a);
}

static void options(void)
{
    gs_eval_range_options o;
    gs_error e = {0, ""};
    gs_eval_range_options_default(&o);
    CHECK(gs_eval_range_options_check(&o, &e) == GS_OK);
    o.src_gaze_yaw = o.gaze_yaw + 0.01; /* the source must lie inside */
    CHECK(gs_eval_range_options_check(&o, &e) == GS_ERR_ARG &&
          strstr(e.msg, "inside"));
    gs_eval_range_options_default(&o);
    o.head_yaw = 1.0; /* 57 deg: beyond the model's range */
    CHECK(gs_eval_range_options_check(&o, &e) == GS_ERR_ARG);
    gs_eval_range_options_default(&o);
    o.gaze_pitch = NAN;
    CHECK(gs_eval_range_options_check(&o, &e) == GS_ERR_ARG);
    gs_eval_range_options_default(&o);
    o.lr = 0;
    CHECK(gs_eval_range_options_check(&o, &e) == GS_ERR_ARG);
    CHECK(strcmp(gs_eval_range_condition_name(GS_EVAL_RANGE_WARP),
                 "source+warp") == 0);
    CHECK(strcmp(gs_eval_range_condition_name(9), "?") == 0);
}

static void usage_errors(const char *exe, const char *model)
{
    const char *bad[][2] = {{"--sources", "0"}, {"--targets", "x"},
                            {"--lr", "1"},      {"--lr", "nan"},
                            {"--steps", "-3"},  {"--threads", "0"},
                            {"--bogus", "1"},   {"--per-test", "1001"}};
    for (size_t i = 0; i < sizeof bad / sizeof bad[0]; i++) {
        const char *a[] = {exe, "eval-range", "--model", model, "--out", dir,
                           bad[i][0], bad[i][1], NULL};
        CHECK_MSG(ev_spawn(dir, a) == 2, "%s %s should be a usage error",
                  bad[i][0], bad[i][1]);
    }
    const char *noout[] = {exe, "eval-range", "--model", model, NULL};
    CHECK_EQ_INT(ev_spawn(dir, noout), 2);
    char missing[256];
    snprintf(missing, sizeof missing, "%s/missing.safetensors", dir);
    const char *nomodel[] = {exe, "eval-range", "--model", missing, "--out",
                             dir, NULL};
    CHECK_EQ_INT(ev_spawn(dir, nomodel), 1);
}

/* The rows: identity-major, finite errors, the in-range flag. */
static void check_csv(const char *text)
{
    const char *head = "identity,index,gaze_pitch_deg,gaze_yaw_deg,"
                       "head_pitch_deg,head_yaw_deg,in_source_range,"
                       "err_source,err_source+ours,err_source+ours-gaze,"
                       "err_source+warp\n";
    CHECK_MSG(text && strncmp(text, head, strlen(head)) == 0, "header: %.80s",
              text ? text : "");
    int rows = 0, differ = 0;
    const char *p = text ? strchr(text, '\n') : NULL;
    while (p && p[1]) {
        int id, ix, in;
        double gp, gy, hp, hy, e[4];
        CHECK_MSG(sscanf(p + 1, "%d,%d,%lf,%lf,%lf,%lf,%d,%lf,%lf,%lf,%lf",
                         &id, &ix, &gp, &gy, &hp, &hy, &in, &e[0], &e[1],
                         &e[2], &e[3]) == 11, "bad row %.60s", p + 1);
        CHECK_EQ_INT(id, rows / PER_TEST);
        CHECK_EQ_INT(ix, rows % PER_TEST);
        for (int c = 0; c < 4; c++)
            CHECK_MSG(isfinite(e[c]) && e[c] >= 0 && e[c] <= 180, "row %d: %g",
                      rows, e[c]);
        differ += e[1] != e[0] || e[3] != e[0];
        /* the test scenes: gaze within +-30/+-40 (normalized labels stay
         * near the head-frame gaze), head within +-20/+-30 */
        CHECK_MSG(fabs(gp) < 45 && fabs(gy) < 55 && fabs(hp) < 30 &&
                  fabs(hy) < 40, "row %d: gaze %g %g head %g %g", rows, gp,
                  gy, hp, hy);
        CHECK(in == 0 || in == 1);
        rows++;
        p = strchr(p + 1, '\n');
    }
    CHECK_EQ_INT(rows, TESTS * PER_TEST);
    CHECK_MSG(differ > 0, "every condition trained the same estimator");
}

int main(int argc, char **argv)
{
    if (argc != 2) {
        fprintf(stderr, "usage: test_eval_range GAZESPLAT\n");
        return 2;
    }
    const char *exe = argv[1];
    CHECK(mkdtemp(dir) != NULL);
    options();
    char model[256], out1[256], out2[256], path[320];
    snprintf(model, sizeof model, "%s/tiny.safetensors", dir);
    snprintf(out1, sizeof out1, "%s/run1", dir);
    snprintf(out2, sizeof out2, "%s/run2", dir);
    ev_train_tiny(model, 2);
    usage_errors(exe, model);

    CHECK_EQ_INT(run(exe, model, out1, "2", 1), 0);
    CHECK_EQ_INT(run(exe, model, out2, "1", 0), 0);
    snprintf(path, sizeof path, "%s/range.csv", out1);
    char *a = ev_slurp(path);
    snprintf(path, sizeof path, "%s/range.csv", out2);
    char *b = ev_slurp(path);
    check_csv(a);
    CHECK_MSG(a && b && strcmp(a, b) == 0, "1 and 2 threads differ:\n%s\n---\n%s",
              a ? a : "", b ? b : "");
    free(a);
    free(b);
    snprintf(path, sizeof path, "%s/range.md", out1);
    char *md = ev_slurp(path);
    CHECK_MSG(md && strstr(md, "| source | 4 |") &&
                  strstr(md, "| source+ours | 10 |") &&
                  strstr(md, "| source+warp | 10 |") &&
                  strstr(md, "gazesplat eval-range --model"),
              "summary:\n%s", md ? md : "");
    free(md);
    for (int c = 0; c < GS_EVAL_RANGE_CONDITIONS; c++) {
        snprintf(path, sizeof path, "%s/%s.safetensors", out1,
                 gs_eval_range_condition_name(c));
        gs_gaze_net *n = NULL;
        gs_error err = {0, ""};
        CHECK_MSG(gs_gaze_net_load(path, &n, &err) == GS_OK, "%s: %s", path,
                  err.msg);
        gs_gaze_net_destroy(n);
    }
    snprintf(path, sizeof path, "%s/source.safetensors", out2);
    struct stat st;
    CHECK_MSG(stat(path, &st) != 0, "estimators written without --save-estimators");

    char cmd[600];
    snprintf(cmd, sizeof cmd, "rm -rf '%s'", dir);
    if (gs_test_failures == 0 && system(cmd) != 0)
        fprintf(stderr, "could not remove %s\n", dir);
    GS_TEST_END();
}
