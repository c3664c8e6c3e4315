/* gazesplat eval end to end: a tiny model trained here for seconds, a
 * pairing of 2 inputs x 2 targets, all three methods; the CSV and the
 * summary exist with finite numbers and the run is deterministic; usage
 * errors exit 2. usage: test_eval_cli PATH_TO_GAZESPLAT */
#define _POSIX_C_SOURCE 200809L /* posix_spawn, mkdtemp */

#include <fcntl.h>
#include <math.h>
#include <spawn.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/wait.h>
#include <unistd.h>

#include "gazesplat/gaze.h"
#include "gazesplat/nn.h"
#include "gazesplat/train.h"
#include "gs_test.h"

#include "eval_fixture.h"

static const char *exe;
/* check_csv: the readout columns (26-29, 34) are to be filled
 * (--readout), else empty. */
static int expect_read;
static char dir[] = "eval_test_XXXXXX";

/* Runs gazesplat with args (NULL-terminated), output to dir/log.txt;
 * returns the exit code (-1 when killed). */
static int run(const char *const *args)
{
    const char *argv[32];
    int n = 0;
    argv[n++] = exe;
    while (args[n - 1] && n < 31) {
        argv[n] = args[n - 1];
        n++;
    }
    argv[n] = NULL;
    return ev_spawn(dir, argv);
}

/* Checks the per-pair CSV: rows, methods, statuses and finite metrics.
 * Returns the text with the timing columns (fit_s, render_ms) blanked. */
/* 1 when the summary file md holds every string of the NULL-terminated
 * list, and none of those given with a leading '!'; else 0, and the
 * summary (or its absence) and the first miss are printed. */
static int summary_has(const char *md, ...)
{
    char *sum = ev_slurp(md);
    const char *miss = sum ? NULL : "(no summary)";
    va_list ap;
    va_start(ap, md);
    for (const char *k; sum && !miss && (k = va_arg(ap, const char *));)
        if ((k[0] == '!') == (strstr(sum, k + (k[0] == '!')) != NULL))
            miss = k;
    va_end(ap);
    if (miss)
        fprintf(stderr, "%s: \"%s\" %s\n%s\n", md, miss,
                miss[0] == '!' ? "is there" : "is missing", sum ? sum : "");
    free(sum);
    return miss == NULL;
}

/* Column `col` of every row of `method` in CSV text, ';'-joined into out. */
static void column_of(const char *text, const char *method, int col, char *out,
                      size_t cap)
{
    *out = 0;
    size_t ml = strlen(method);
    for (const char *l = text; l && *l; l = strchr(l, '\n') ? strchr(l, '\n') + 1 : NULL) {
        if (strncmp(l, method, ml) != 0 || l[ml] != ',')
            continue;
        const char *c = l;
        for (int k = 0; k < col && c; k++) {
            c = strpbrk(c, ",\n");
            c = c && *c == ',' ? c + 1 : NULL;
        }
        if (!c)
            continue;
        size_t n = strcspn(c, ",\n"), have = strlen(out);
        if (have + n + 2 < cap)
            snprintf(out + have, cap - have, "%.*s;", (int)n, c);
    }
}

static char *check_csv(const char *path)
{
    char *text = ev_slurp(path);
    CHECK_MSG(text != NULL, "no %s", path);
    if (!text)
        return NULL;
    int rows = 0, bad = 0, methods[3] = {0};
    char *save = NULL, *copy = strdup(text);
    char *out = calloc(strlen(text) + 1, 1);
    for (char *line = strtok_r(copy, "\n", &save); line;
         line = strtok_r(NULL, "\n", &save)) {
        /* Split on commas, keeping empty fields. */
        char *cols[40];
        int nc = 0;
        char *lc = strdup(line);
        for (char *c = lc; c && nc < 40;) {
            cols[nc++] = c;
            c = strchr(c, ',');
            if (c)
                *c++ = 0;
        }
        if (rows++ == 0) {
            CHECK_MSG(strncmp(line, "method,pair,", 12) == 0, "%s", line);
            CHECK_EQ_INT(nc, 35);
        } else {
            methods[0] += strcmp(cols[0], "model") == 0;
            methods[1] += strcmp(cols[0], "warp") == 0;
            methods[2] += strcmp(cols[0], "identity") == 0;
            bad += strcmp(cols[10], "ok") != 0;
            /* Angles (cols 14-19), PSNR, SSIM, id PSNR, id SSIM (20, 21,
             * 24, 25) always; eye metrics unless the eyes are closed. */
            for (int k = 14; k < 26 && nc == 35; k++)
                bad += (*cols[k] == 0 || !isfinite(strtod(cols[k], NULL))) &&
                       k != 22 && k != 23;
            for (int k = 26; k < 30 && nc == 35; k++)
                bad += expect_read ? *cols[k] == 0 ||
                                         !(strtod(cols[k], NULL) >= -180 &&
                                           strtod(cols[k], NULL) <= 180)
                                   : *cols[k] != 0;
            /* The target's true gaze and head pose (30-33): always, and
             * within the evaluation's ranges (gaze +-40, head +-50 deg,
             * head-frame gaze a little wider). */
            for (int k = 30; k < 34 && nc == 35; k++)
                bad += *cols[k] == 0 || !(fabs(strtod(cols[k], NULL)) <= 90.0);
            /* The readout's softness (34): within what was searched. */
            if (nc == 35)
                bad += expect_read ? *cols[34] == 0 ||
                                         !(strtod(cols[34], NULL) >= 0 &&
                                           strtod(cols[34], NULL) <= 2.5)
                                   : *cols[34] != 0;
            /* ... and the read error is the angle from the read gaze to
             * that truth. */
            if (expect_read && nc == 35 && *cols[26] && *cols[28]) {
                double v[2][3], pr[2][2] = {{strtod(cols[28], NULL), strtod(cols[29], NULL)},
                                            {strtod(cols[30], NULL), strtod(cols[31], NULL)}};
                for (int j = 0; j < 2; j++) {
                    const double rad = 3.14159265358979323846 / 180;
                    double pp = pr[j][0] * rad, yy = pr[j][1] * rad;
                    v[j][0] = -cos(pp) * sin(yy);
                    v[j][1] = -sin(pp);
                    v[j][2] = -cos(pp) * cos(yy);
                }
                double d = v[0][0] * v[1][0] + v[0][1] * v[1][1] + v[0][2] * v[1][2];
                double a = acos(d > 1 ? 1 : d < -1 ? -1 : d) * (180 / 3.14159265358979323846);
                bad += !(fabs(a - strtod(cols[26], NULL)) < 0.01);
            }
            if (strcmp(cols[0], "model") == 0)
                bad += !(strtod(cols[11], NULL) > 0) ||
                       !isfinite(strtod(cols[12], NULL));
        }
        /* Keep everything but columns 11 (fit_s) and 13 (render_ms). */
        int col = 0;
        for (const char *p = line; *p; p++) {
            if (*p == ',')
                col++;
            if ((col == 11 || col == 13) && *p != ',')
                continue;
            strncat(out, p, 1);
        }
        strcat(out, "\n");
        free(lc);
    }
    CHECK_EQ_INT(rows, 1 + 4 * 3);
    CHECK(methods[0] == 4 && methods[1] == 4 && methods[2] == 4);
    CHECK_MSG(bad == 0, "%d bad values in %s:\n%s", bad, path, text);
    free(copy);
    free(text);
    return out;
}

static void usage_errors(const char *model, const char *pairs)
{
    const char *none[] = {"eval", NULL};
    CHECK_EQ_INT(run(none), 2);
    const char *bad_method[] = {"eval", "--model", model, "--pairs", pairs,
                                "--out", dir, "--method", "model,nope", NULL};
    CHECK_EQ_INT(run(bad_method), 2);
    const char *dup_method[] = {"eval", "--model", model, "--pairs", pairs,
                                "--out", dir, "--method", "warp,warp", NULL};
    CHECK_EQ_INT(run(dup_method), 2);
    const char *iters0[] = {"eval", "--model", model, "--pairs", pairs,
                            "--out", dir, "--iters", "0", NULL};
    CHECK_EQ_INT(run(iters0), 2);
    const char *mixed[] = {"eval", "--make-pairs", pairs, "--model", model,
                           NULL};
    CHECK_EQ_INT(run(mixed), 2);
    const char *stray[] = {"eval", "--model", model, "--pairs", pairs,
                           "--out", dir, "--targets", "3", NULL};
    CHECK_EQ_INT(run(stray), 2);
    const char *ids0[] = {"eval", "--make-pairs", pairs, "--identities", "0",
                          NULL};
    CHECK_EQ_INT(run(ids0), 2);
    const char *positional[] = {"eval", "extra", NULL};
    CHECK_EQ_INT(run(positional), 2);
    /* Bad values of each of these exit 2. --true-code: a list of expr,
     * light and id, each once; --fit-anneal: 0..8 halvings; --fit-mirror:
     * 0 or 1; --fit-eye-weight: 0..16. */
    static const struct {
        const char *flag, *bad[10];
    } refused[] = {
        {"--true-code", {"nope", "expr,expr", "expr,", ",light", "", "Expr",
                         "id,id", "ids", "identity", NULL}},
        {"--fit-anneal", {"-1", "9", "x", "1.5", "", NULL}},
        {"--fit-mirror", {"2", "-1", "yes", "", NULL}},
        {"--fit-eye-weight", {"-0.1", "16.5", "x", "nan", "", NULL}},
    };
    for (size_t f = 0; f < sizeof refused / sizeof refused[0]; f++)
        for (int i = 0; refused[f].bad[i]; i++) {
            const char *a[] = {"eval", "--model", model, "--pairs", pairs, "--out",
                               dir, refused[f].flag, refused[f].bad[i], NULL};
            CHECK_MSG(run(a) == 2, "%s '%s' accepted", refused[f].flag,
                      refused[f].bad[i]);
        }
    /* --readout-shift: only with --readout, and within [0, 8] px */
    const char *shift_alone[] = {"eval", "--model", model, "--pairs", pairs,
                                 "--out", dir, "--readout-shift", "2", NULL};
    CHECK_EQ_INT(run(shift_alone), 2);
    const char *bad_shift[] = {"eval", "--model", model, "--pairs", pairs,
                               "--out", dir, "--readout", "--readout-shift",
                               "9", NULL};
    CHECK_EQ_INT(run(bad_shift), 2);
    bad_shift[8] = "-1";
    CHECK_EQ_INT(run(bad_shift), 2);
    bad_shift[8] = "nan";
    CHECK_EQ_INT(run(bad_shift), 2);
    /* --readout-soft: only with --readout, and within [0, 2.5] px */
    shift_alone[7] = "--readout-soft";
    CHECK_EQ_INT(run(shift_alone), 2);
    bad_shift[7] = "--readout-soft";
    bad_shift[8] = "3";
    CHECK_EQ_INT(run(bad_shift), 2);
    bad_shift[8] = "-0.5";
    CHECK_EQ_INT(run(bad_shift), 2);
    /* --split: validation and training pairs are written and say so;
     * another split is refused */
    char vpairs[200];
    snprintf(vpairs, sizeof vpairs, "%s/val_pairs.csv", dir);
    const char *split_bad[] = {"eval", "--make-pairs", vpairs, "--split", "training", NULL};
    CHECK_EQ_INT(run(split_bad), 2);
    const char *const split[2][2] = {{"train", "training-split"},
                                     {"validation", "validation-split"}};
    for (int k = 0; k < 2; k++) {
        const char *mk[] = {"eval", "--make-pairs", vpairs, "--split", split[k][0],
                            "--identities", "1", "--inputs", "1", "--targets", "2", NULL};
        CHECK_EQ_INT(run(mk), 0);
        FILE *vf = fopen(vpairs, "r");
        char head[160] = "";
        CHECK_MSG(vf && fgets(head, sizeof head, vf) && strstr(head, split[k][1]),
                  "--split %s: %s", split[k][0], head);
        if (vf)
            fclose(vf);
    }
    /* Render settings: --prune K or P%, --feature-scale in (0, 1] or 2..4. */
    const char *bad_render[][2] = {
        {"--prune", "0"},          {"--prune", "0%"},
        {"--prune", "150%"},       {"--prune", "many"},
        {"--prune", "%"},          {"--feature-scale", "0"},
        {"--feature-scale", "1.5"}, {"--feature-scale", "half"},
        {"--feature-scale", "nan"}, {"--feature-scale", "2.5"},
        {"--feature-scale", "5"},
        {"--transfer-head-weight", "1.5"}, {"--transfer-head-weight", "-0.1"},
        {"--transfer-head-weight", "nan"},
        {"--transfer-eye-weight", "1.5"}, {"--transfer-eye-weight", "-0.1"},
        {"--transfer-eye-weight", "nan"},
        {"--transfer-eye-warp", "-1"}, {"--transfer-eye-warp", "91"},
        {"--transfer-eye-warp", "nan"}, {"--transfer-eye-warp", "wide"},
        {"--transfer-eye-warp-head", "2"}, {"--transfer-eye-warp-head", "on"},
        {"--finetune-outline", "1"}, /* without --finetune N */
        {"--finetune-mirror", "0"},
        {"--feature-scale", "0.1"}, /* 3 of the tiny model's 32 px */
        {"--finetune", "0"},        {"--finetune", "-3"},
        {"--finetune-parts", "face"}, /* without --finetune N */
        {"--finetune-lr", "0.01"},   {"--finetune-eye-weight", "0.5"},
        {"--fit-lr", "0"},          {"--fit-lr", "-0.1"},
        {"--fit-lr", "11"},         {"--fit-lr", "nan"},
        {"--fit-lr", "0.1,0"},      {"--fit-lr", "0.1,"},
        {"--fit-lr", "0.1,0.02,1"}, {"--fit-lr", "fast"},
        {"--code-prior", "-0.001"}, {"--code-prior", "10.5"},
        {"--code-prior", "nan"},    {"--code-prior", "strong"},
        {"--id-prior", "-0.1"},     {"--id-prior", "11"},
        {"--id-prior", "nan"}};
    for (size_t k = 0; k < sizeof bad_render / sizeof bad_render[0]; k++) {
        const char *args[] = {"eval", "--model", model, "--pairs", pairs,
                              "--out", dir, bad_render[k][0],
                              bad_render[k][1], "--limit-inputs", "1",
                              "--iters", "1", NULL};
        int code = run(args);
        CHECK_MSG(code == 2, "%s %s: exit %d", bad_render[k][0],
                  bad_render[k][1], code);
    }
    const char *bad_ft[][2] = {{"--finetune-parts", "face,nose"},
                               {"--finetune-parts", "face,"},
                               {"--finetune-parts", ""},
                               {"--finetune-lr", "0"},
                               {"--finetune-lr", "2"},
                               {"--finetune-lr", "nan"},
                               {"--finetune-eye-weight", "1.5"},
                               {"--finetune-eye-weight", "-1"},
                               {"--finetune-outline", "9"},
                               {"--finetune-mirror", "2"},
                               {"--finetune-outline", "-1"},
                               {"--prune", "50%"}};
    for (size_t k = 0; k < sizeof bad_ft / sizeof bad_ft[0]; k++) {
        const char *args[] = {"eval", "--model", model, "--pairs", pairs,
                              "--out", dir, "--finetune", "2", bad_ft[k][0],
                              bad_ft[k][1], "--limit-inputs", "1",
                              "--iters", "1", NULL};
        int code = run(args);
        CHECK_MSG(code == 2, "--finetune 2 %s %s: exit %d", bad_ft[k][0],
                  bad_ft[k][1], code);
    }
    const char *full_arg[] = {"eval", "--model", model, "--pairs", pairs,
                              "--out", dir, "--full-render", "yes", NULL};
    CHECK_EQ_INT(run(full_arg), 2);
    /* Runtime failures exit 1. */
    char missing[256];
    snprintf(missing, sizeof missing, "%s/missing.csv", dir);
    const char *nopairs[] = {"eval", "--model", model, "--pairs", missing,
                             "--out", dir, NULL};
    CHECK_EQ_INT(run(nopairs), 1);
    const char *nomodel[] = {"eval", "--model", missing, "--pairs", pairs,
                             "--out", dir, NULL};
    CHECK_EQ_INT(run(nomodel), 1);
}

int main(int argc, char **argv)
{
    if (argc != 2) {
        fprintf(stderr, "usage: test_eval_cli PATH_TO_GAZESPLAT\n");
        return 2;
    }
    exe = argv[1];
    CHECK(mkdtemp(dir) != NULL);
    char model[256], pairs[256], out1[256], out2[256], csv[300], md[300];
    snprintf(model, sizeof model, "%s/tiny.safetensors", dir);
    snprintf(pairs, sizeof pairs, "%s/pairs.csv", dir);
    snprintf(out1, sizeof out1, "%s/run1", dir);
    snprintf(out2, sizeof out2, "%s/run2", dir);
    ev_train_tiny(model, 4);
    /* An untrained estimator: random weights still give finite angles. */
    char est[256];
    snprintf(est, sizeof est, "%s/est.safetensors", dir);
    gs_gaze_spec gsp;
    gs_gaze_spec_default(&gsp, GS_GAZE_RESNET);
    gs_gaze_net *net = NULL;
    gs_error err = {0, ""};
    CHECK(gs_gaze_net_create(&gsp, 3, &net, &err) == GS_OK);
    CHECK_MSG(gs_gaze_net_save(net, est, &err) == GS_OK, "%s", err.msg);
    gs_gaze_net_destroy(net);

    const char *mk[] = {"eval", "--make-pairs", pairs, "--identities", "2",
                        "--inputs", "1", "--targets", "2", NULL};
    CHECK_EQ_INT(run(mk), 0);
    usage_errors(model, pairs);

    const char *ev1[] = {"eval", "--model", model, "--pairs", pairs,
                         "--out", out1, "--method", "model,warp,identity",
                         "--iters", "4", "--threads", "2", "--estimator",
                         est, "--save-images", "1", NULL};
    CHECK_EQ_INT(run(ev1), 0);
    char png[320];
    snprintf(png, sizeof png, "%s/images/00000_warp.png", out1);
    CHECK_MSG(access(png, R_OK) == 0, "no %s", png);
    snprintf(png, sizeof png, "%s/images/00001_model.png", out1);
    CHECK_MSG(access(png, R_OK) != 0, "%s: only pair 0 was asked for", png);
    snprintf(csv, sizeof csv, "%s/pairs.csv", out1);
    char *a = check_csv(csv);
    snprintf(md, sizeof md, "%s/summary.md", out1);
    CHECK(summary_has(md, "diverged fits 0, errors 0, non-finite outputs 0",
                      "| warp |", "gaze change 0-15°",
                      "rates 0.12 (code) and 0.02 (colour)", "!nan", "!inf",
                      "!training identities", NULL));
    /* Pairs of training identities run the same way and the summary says
     * they are no held-out figure. */
    char tpairs[256], tout[256], tmd[300];
    snprintf(tpairs, sizeof tpairs, "%s/train_pairs.csv", dir);
    snprintf(tout, sizeof tout, "%s/runt", dir);
    snprintf(tmd, sizeof tmd, "%s/summary.md", tout);
    const char *mkt[] = {"eval", "--make-pairs", tpairs, "--split", "train",
                         "--identities", "2", "--inputs", "1", "--targets", "2", NULL};
    CHECK_EQ_INT(run(mkt), 0);
    const char *evtr[] = {"eval", "--model", model, "--pairs", tpairs,
                          "--out", tout, "--method", "model,oracle", "--iters", "4",
                          "--threads", "2", "--estimator", est, NULL};
    CHECK_EQ_INT(run(evtr), 0);
    CHECK(summary_has(tmd, "**training identities** (`--split train`): faces "
                           "a model trained on 2 or more identities",
                      "diverged fits 0, errors 0, non-finite outputs 0",
                      "| oracle | 4 |",
                      "- oracle: the shared model with each training identity's",
                      NULL));
    /* --true-code id: the fits are given the learned identity codes of
     * these training faces (the model rows change, the oracle's do not)
     * and the summary says so */
    {
        char iout[256], imd[300], csvt[300], csvi[300];
        snprintf(iout, sizeof iout, "%s/runtid", dir);
        snprintf(imd, sizeof imd, "%s/summary.md", iout);
        snprintf(csvt, sizeof csvt, "%s/pairs.csv", tout);
        snprintf(csvi, sizeof csvi, "%s/pairs.csv", iout);
        const char *evid[] = {"eval", "--model", model, "--pairs", tpairs,
                              "--out", iout, "--method", "model,oracle", "--iters", "4",
                              "--threads", "2", "--estimator", est,
                              "--true-code", "id,expr,light", NULL};
        CHECK_EQ_INT(run(evid), 0);
        CHECK(summary_has(imd, "**a diagnostic, not a served figure** (--true-code)",
                          "true expression, lights and identity code (the one "
                          "training learned) and kept them",
                          "diverged fits 0, errors 0, non-finite outputs 0", NULL));
        char *t = ev_slurp(csvt), *u = ev_slurp(csvi);
        char mt[4096], mu[4096], ot[4096], ou[4096];
        column_of(t, "model", 20, mt, sizeof mt);
        column_of(u, "model", 20, mu, sizeof mu);
        column_of(t, "oracle", 20, ot, sizeof ot);
        column_of(u, "oracle", 20, ou, sizeof ou);
        CHECK_MSG(*mt && strcmp(mt, mu) != 0, "--true-code id: model PSNRs %s, %s", mt, mu);
        CHECK_MSG(*ot && strcmp(ot, ou) == 0, "--true-code id: oracle PSNRs %s, %s", ot, ou);
        /* --true-code-start: the same codes only start the fit, which
         * moves them: the model rows differ from the kept run's */
        char sout[256], smd[300], csvs[300];
        snprintf(sout, sizeof sout, "%s/runtstart", dir);
        snprintf(smd, sizeof smd, "%s/summary.md", sout);
        snprintf(csvs, sizeof csvs, "%s/pairs.csv", sout);
        const char *evst[] = {"eval", "--model", model, "--pairs", tpairs,
                              "--out", sout, "--method", "model", "--iters", "4",
                              "--threads", "2", "--estimator", est,
                              "--true-code", "id,expr,light", "--true-code-start",
                              NULL};
        CHECK_EQ_INT(run(evst), 0);
        CHECK(summary_has(smd, "true expression, lights and identity code (the "
                               "one training learned) as their start, and moved "
                               "them as it moved the rest (--true-code-start)",
                          "diverged fits 0, errors 0, non-finite outputs 0", NULL));
        char *st = ev_slurp(csvs), ms[4096];
        column_of(st, "model", 20, ms, sizeof ms);
        CHECK_MSG(*ms && strcmp(ms, mu) != 0 && strcmp(ms, mt) != 0,
                  "--true-code-start: model PSNRs %s against kept %s, plain %s",
                  ms, mu, mt);
        free(st);
        /* --fit-mirror 1, --fit-anneal and --fit-eye-weight: the summary
         * names them and the fits change */
        const char *evmi[] = {"eval", "--model", model, "--pairs", tpairs,
                              "--out", sout, "--method", "model", "--iters", "4",
                              "--threads", "2", "--estimator", est,
                              "--fit-mirror", "1", "--fit-anneal", "1",
                              "--fit-eye-weight", "0.5", NULL};
        CHECK_EQ_INT(run(evmi), 0);
        CHECK(summary_has(smd, ", the rates halved at a plateau up to 1 times (--fit-anneal), "
                               "with the mirrored view (--fit-mirror 1), the "
                               "input's eyes weighted 0.5 (--fit-eye-weight)",
                          "diverged fits 0, errors 0, non-finite outputs 0", NULL));
        st = ev_slurp(csvs);
        column_of(st, "model", 20, ms, sizeof ms);
        CHECK_MSG(*ms && strcmp(ms, mt) != 0, "--fit-mirror 1: model PSNRs %s, plain %s",
                  ms, mt);
        free(st);
        free(t);
        free(u);
        /* without --true-code it has nothing to start from */
        const char *lone[] = {"eval", "--model", model, "--pairs", tpairs,
                              "--out", sout, "--true-code-start", NULL};
        CHECK_EQ_INT(run(lone), 2);
        evid[16] = "id";
        CHECK_EQ_INT(run(evid), 0);
        CHECK(summary_has(imd, "true identity code (the one training learned) and kept it",
                          NULL));
        /* held-out pairs have no learned code */
        evid[4] = pairs;
        CHECK_EQ_INT(run(evid), 2);
    }
    /* The oracle needs training pairs, of identities the model has codes
     * for (the tiny model: 2); so does --true-code id. */
    const char *or_test[] = {"eval", "--model", model, "--pairs", pairs,
                             "--out", tout, "--method", "oracle", NULL};
    CHECK_EQ_INT(run(or_test), 2);
    const char *mkt3[] = {"eval", "--make-pairs", tpairs, "--split", "train",
                          "--identities", "3", "--inputs", "1", "--targets", "1", NULL};
    CHECK_EQ_INT(run(mkt3), 0);
    or_test[4] = tpairs;
    CHECK_EQ_INT(run(or_test), 2);
    const char *id_test[] = {"eval", "--model", model, "--pairs", tpairs, "--out", tout,
                             "--method", "model", "--true-code", "id", NULL};
    CHECK_EQ_INT(run(id_test), 2);
    /* The same thread count gives the same numbers (timings aside). */
    const char *ev2[] = {"eval", "--model", model, "--pairs", pairs,
                         "--out", out2, "--method", "model,warp,identity",
                         "--iters", "4", "--threads", "2", "--estimator",
                         est, NULL};
    CHECK_EQ_INT(run(ev2), 0);
    snprintf(csv, sizeof csv, "%s/pairs.csv", out2);
    char *b = check_csv(csv);
    CHECK_MSG(a && b && strcmp(a, b) == 0, "runs differ:\n%s\n---\n%s", a, b);
    /* Rescoring with the fits of run 2 gives the same numbers again. */
    const char *ev3[] = {"eval", "--model", model, "--pairs", pairs,
                         "--out", out2, "--method", "model,warp,identity",
                         "--iters", "4", "--threads", "2", "--estimator",
                         est, "--reuse-fits", NULL};
    CHECK_EQ_INT(run(ev3), 0);
    char *c = check_csv(csv);
    CHECK_MSG(a && c && strcmp(a, c) == 0, "rescored run differs:\n%s", c);
    free(c);
    snprintf(md, sizeof md, "%s/summary.md", out2);
    CHECK(summary_has(md, "2 fits reused", NULL));
    /* Detail transfer on the same fits: its own rows, all finite. */
    const char *evt[] = {"eval", "--model", model, "--pairs", pairs,
                         "--out", out2, "--method", "model,transfer",
                         "--iters", "4", "--threads", "2", "--estimator",
                         est, "--reuse-fits", NULL};
    CHECK_EQ_INT(run(evt), 0);
    c = ev_slurp(csv);
    CHECK_MSG(c && strstr(c, "\ntransfer,0,") && strstr(c, "\nmodel,0,"),
              "transfer rows:\n%s", c ? c : "");
    free(c);
    CHECK(summary_has(md, "| transfer |",
                      "diverged fits 0, errors 0, non-finite outputs 0",
                      "lights at another head pose: kept in the camera",
                      "smoothed skin residual x 0.5", "eyeball residual x 0.5 once",
                      "exp(-(turn / 20 deg)^2) (--transfer-eye-warp)", "!nan", NULL));
    const char *evth[] = {"eval", "--model", model, "--pairs", pairs,
                          "--out", out2, "--method", "transfer",
                          "--iters", "4", "--threads", "2", "--estimator",
                          est, "--reuse-fits", "--transfer-eye-warp-head", "1", NULL};
    CHECK_EQ_INT(run(evth), 0);
    CHECK(summary_has(md, "| transfer |", "non-finite outputs 0",
                      "the same warp, inside the eye opening the model shows at the "
                      "target's pose (--transfer-eye-warp-head 1)", "!nan", NULL));
    /* the identity prior: fits again (other keys), named in the summary */
    const char *evid[] = {"eval", "--model", model, "--pairs", pairs,
                          "--out", out2, "--method", "model",
                          "--iters", "4", "--threads", "2", "--estimator",
                          est, "--reuse-fits", "--id-prior", "0.5", NULL};
    CHECK_EQ_INT(run(evid), 0);
    CHECK(summary_has(md, "identity prior weight 0.5 (--id-prior)", "!fits reused",
                      "non-finite outputs 0", NULL));
    /* Render settings on run 2's fits: 100 % and scale 1 are the normal
     * path (same numbers); pruned, coarse and full renders stay finite. */
    const char *ev4[] = {"eval", "--model", model, "--pairs", pairs,
                         "--out", out2, "--method", "model,warp,identity",
                         "--iters", "4", "--threads", "2", "--estimator",
                         est, "--reuse-fits", "--prune", "100%",
                         "--feature-scale", "1", NULL};
    CHECK_EQ_INT(run(ev4), 0);
    c = check_csv(csv);
    CHECK_MSG(a && c && strcmp(a, c) == 0, "100 %% / 1.0 differs:\n%s", c);
    free(c);
    const char *ev5[] = {"eval", "--model", model, "--pairs", pairs,
                         "--out", out2, "--method", "model,warp,identity",
                         "--iters", "4", "--threads", "1", "--estimator",
                         est, "--reuse-fits", "--prune", "10%",
                         "--feature-scale", "0.5", "--full-render", NULL};
    CHECK_EQ_INT(run(ev5), 0);
    c = check_csv(csv);
    CHECK_MSG(a && c && strcmp(a, c) != 0, "pruned renders are the same");
    free(c);
    CHECK(summary_has(md, "face Gaussians (10 %), feature scale 0.5, every "
                          "render from scratch",
                      "non-finite outputs 0", NULL));
    const char *ev5s[] = {"eval", "--model", model, "--pairs", pairs,
                          "--out", out2, "--method", "model",
                          "--iters", "4", "--threads", "2", "--estimator",
                          est, "--reuse-fits", "--feature-scale", "2", NULL};
    CHECK_EQ_INT(run(ev5s), 0);
    CHECK(summary_has(md, "face Gaussians (100 %), feature scale 2 "
                          "(supersampled), every render full",
                      "non-finite outputs 0", NULL));
    { /* a supersampled model: its renders at scale 1 are full too */
        char ssm[300];
        snprintf(ssm, sizeof ssm, "%s/tiny-ss2.safetensors", dir);
        gs_model *m = NULL;
        CHECK(gs_model_load(model, &m, &err) == GS_OK);
        CHECK(gs_model_set_supersample(m, 2, &err) == GS_OK);
        CHECK_MSG(gs_model_write(m, ssm, &err) == GS_OK, "%s", err.msg);
        gs_model_destroy(m);
        const char *evss[] = {"eval", "--model", ssm, "--pairs", pairs,
                              "--out", out2, "--method", "model",
                              "--iters", "4", "--threads", "2", "--estimator",
                              est, "--reuse-fits", NULL};
        CHECK_EQ_INT(run(evss), 0);
        CHECK(summary_has(md, "feature scale 1 (the model's own: "
                              "supersampled), every render full",
                          "non-finite outputs 0", NULL));
    }
    { /* a model with the eye at the image's size: incremental, named */
        char edm[300];
        snprintf(edm, sizeof edm, "%s/tiny-ed.safetensors", dir);
        gs_model *m = NULL;
        CHECK(gs_model_load(model, &m, &err) == GS_OK);
        CHECK(gs_model_set_eye_direct(m, 1, &err) == GS_OK);
        CHECK_MSG(gs_model_write(m, edm, &err) == GS_OK, "%s", err.msg);
        gs_model_destroy(m);
        const char *eved[] = {"eval", "--model", edm, "--pairs", pairs,
                              "--out", out2, "--method", "model",
                              "--iters", "4", "--threads", "2", "--estimator",
                              est, "--reuse-fits", NULL};
        CHECK_EQ_INT(run(eved), 0);
        CHECK(summary_has(md, "feature scale 1, incremental where possible",
                          "(config.eye_direct)", "non-finite outputs 0", NULL));
    }
    { /* a model naming a fit prior (gazesplat model): eval fits with it
       * unless told otherwise, the same numbers as --code-prior with the
       * plain model, and the report says whose weight it is; --code-prior
       * 0 gives the plain model's numbers back */
        char pm[300], o3[300], o4[300], o5[300], c3[320], c4[320], c5[320],
            md3[320];
        snprintf(pm, sizeof pm, "%s/tiny-prior.safetensors", dir);
        snprintf(o3, sizeof o3, "%s/run3", dir);
        snprintf(o4, sizeof o4, "%s/run4", dir);
        snprintf(o5, sizeof o5, "%s/run5", dir);
        const char *mk_pm[] = {"model", "--model", model, "--fit-code-prior",
                               "0.5", "--out", pm, NULL};
        CHECK_EQ_INT(run(mk_pm), 0);
        const char *e3[] = {"eval", "--model", pm, "--pairs", pairs,
                            "--out", o3, "--method", "model,warp,identity",
                            "--iters", "4", "--threads", "2", "--estimator",
                            est, NULL};
        const char *e4[] = {"eval", "--model", model, "--pairs", pairs,
                            "--out", o4, "--method", "model,warp,identity",
                            "--iters", "4", "--threads", "2", "--estimator",
                            est, "--code-prior", "0.5", NULL};
        const char *e5[] = {"eval", "--model", pm, "--pairs", pairs,
                            "--out", o5, "--method", "model,warp,identity",
                            "--iters", "4", "--threads", "2", "--estimator",
                            est, "--code-prior", "0", NULL};
        CHECK_EQ_INT(run(e3), 0);
        CHECK_EQ_INT(run(e4), 0);
        CHECK_EQ_INT(run(e5), 0);
        snprintf(c3, sizeof c3, "%s/pairs.csv", o3);
        snprintf(c4, sizeof c4, "%s/pairs.csv", o4);
        snprintf(c5, sizeof c5, "%s/pairs.csv", o5);
        snprintf(md3, sizeof md3, "%s/summary.md", o3);
        char *p3 = check_csv(c3), *p4 = check_csv(c4), *p5 = check_csv(c5);
        CHECK_MSG(p3 && p4 && strcmp(p3, p4) == 0,
                  "the model's prior differs from --code-prior:\n%s\n---\n%s", p3, p4);
        CHECK_MSG(p3 && a && strcmp(p3, a) != 0, "the prior changed nothing");
        CHECK_MSG(p5 && a && strcmp(p5, a) == 0,
                  "--code-prior 0 differs from the plain model:\n%s", p5);
        CHECK(summary_has(md3, "code prior weight 0.5 (the model's)", NULL));
        snprintf(md3, sizeof md3, "%s/summary.md", o4);
        CHECK(summary_has(md3, "code prior weight 0.5 (--code-prior)", NULL));
        snprintf(md3, sizeof md3, "%s/summary.md", o5);
        CHECK(summary_has(md3, "!code prior weight", NULL));
        /* The model's code rate (gazesplat model --fit-code-rate): the
         * fits run at it as at --fit-lr R,0.02 on the plain model, the
         * report says whose rate it is, and --fit-lr 0.12,0.02 gives the
         * plain model's numbers back. */
        {
            char rm[300], o6[300], o7[300], c6[320], c7[320], md6[320];
            snprintf(rm, sizeof rm, "%s/tiny-rate.safetensors", dir);
            snprintf(o6, sizeof o6, "%s/run6", dir);
            snprintf(o7, sizeof o7, "%s/run7", dir);
            const char *mk_rm[] = {"model", "--model", model, "--fit-code-rate",
                                   "0.3", "--out", rm, NULL};
            CHECK_EQ_INT(run(mk_rm), 0);
            const char *e6[20] = {"eval", "--model", rm, "--pairs", pairs,
                                "--out", o6, "--method", "model,warp,identity",
                                "--iters", "4", "--threads", "2", "--estimator",
                                est, NULL};
            const char *e7[] = {"eval", "--model", model, "--pairs", pairs,
                                "--out", o7, "--method", "model,warp,identity",
                                "--iters", "4", "--threads", "2", "--estimator",
                                est, "--fit-lr", "0.3,0.02", NULL};
            CHECK_EQ_INT(run(e6), 0);
            CHECK_EQ_INT(run(e7), 0);
            snprintf(c6, sizeof c6, "%s/pairs.csv", o6);
            snprintf(c7, sizeof c7, "%s/pairs.csv", o7);
            char *p6 = check_csv(c6), *p7 = check_csv(c7);
            CHECK_MSG(p6 && p7 && strcmp(p6, p7) == 0,
                      "the model's rate differs from --fit-lr:\n%s\n---\n%s", p6, p7);
            CHECK_MSG(p6 && a && strcmp(p6, a) != 0, "the rate changed nothing");
            snprintf(md6, sizeof md6, "%s/summary.md", o6);
            CHECK(summary_has(md6, "rates 0.3 (code, the model's) and 0.02 (colour)", NULL));
            snprintf(md6, sizeof md6, "%s/summary.md", o7);
            CHECK(summary_has(md6, "rates 0.3 (code) and 0.02 (colour)", NULL));
            e6[15] = "--fit-lr";
            e6[16] = "0.12,0.02";
            e6[17] = NULL;
            CHECK_EQ_INT(run(e6), 0);
            free(p6);
            p6 = check_csv(c6);
            CHECK_MSG(p6 && a && strcmp(p6, a) == 0,
                      "--fit-lr 0.12,0.02 differs from the plain model:\n%s", p6);
            free(p6);
            free(p7);
        }
        /* Cached fits are keyed by what made them: run 3's (the model's
         * 0.5) serve the plain model at --code-prior 0.5, the same fit,
         * but not the prior model at --code-prior 0, whose fits are made
         * again, with a fresh run's numbers. */
        const char *r4[] = {"eval", "--model", model, "--pairs", pairs,
                            "--out", o3, "--method", "model,warp,identity",
                            "--iters", "4", "--threads", "2", "--estimator",
                            est, "--code-prior", "0.5", "--reuse-fits", NULL};
        CHECK_EQ_INT(run(r4), 0);
        char *q = check_csv(c3);
        CHECK_MSG(q && p4 && strcmp(q, p4) == 0, "reused fits differ:\n%s", q);
        free(q);
        snprintf(md3, sizeof md3, "%s/summary.md", o3);
        CHECK(summary_has(md3, "2 fits reused", "!fitted again", NULL));
        const char *r5[] = {"eval", "--model", pm, "--pairs", pairs,
                            "--out", o3, "--method", "model,warp,identity",
                            "--iters", "4", "--threads", "2", "--estimator",
                            est, "--code-prior", "0", "--reuse-fits", NULL};
        CHECK_EQ_INT(run(r5), 0);
        q = check_csv(c3);
        CHECK_MSG(q && p5 && strcmp(q, p5) == 0,
                  "stale fits were reused:\n%s", q);
        free(q);
        CHECK(summary_has(md3, "2 cached fits were made with another model, "
                               "other fit options or another input",
                          "!fits reused", NULL));
        /* ... and the refitted files serve that setting from then on */
        CHECK_EQ_INT(run(r5), 0);
        CHECK(summary_has(md3, "2 fits reused", "!fitted again", NULL));
        free(p3);
        free(p4);
        free(p5);
    }
    /* Fine-tuned per input on run 2's fits: finite, deterministic, other
     * numbers than without, the input reproduced better. */
    const char *ev6[] = {"eval", "--model", model, "--pairs", pairs,
                         "--out", out2, "--method", "model,warp,identity",
                         "--iters", "4", "--threads", "2", "--estimator",
                         est, "--reuse-fits", "--finetune", "6",
                         "--finetune-eye-weight", "0", NULL};
    CHECK_EQ_INT(run(ev6), 0);
    c = check_csv(csv);
    CHECK_MSG(a && c && strcmp(a, c) != 0, "fine-tuning changed nothing");
    CHECK_EQ_INT(run(ev6), 0);
    char *d = check_csv(csv);
    CHECK_MSG(c && d && strcmp(c, d) == 0, "fine-tuned runs differ");
    free(c);
    free(d);
    char *sum = ev_slurp(md);
    double p0 = NAN, p1 = NAN;
    const char *ft = sum ? strstr(sum, "input PSNR ") : NULL;
    CHECK_MSG(sum && strstr(sum, "fine-tuned per input (--finetune 6, parts "
                                 "face,geometry, rate 0.004, eye weight 0, outline 0 px, mirror on)") &&
                  strstr(sum, "non-finite outputs 0") && ft &&
                  sscanf(ft, "input PSNR %lf -> %lf", &p0, &p1) == 2,
              "%s", sum ? sum : "");
    CHECK_MSG(p1 > p0, "input PSNR %.2f -> %.2f", p0, p1);
    /* --finetune-outline: other numbers, named in the summary */
    const char *ev7[] = {"eval", "--model", model, "--pairs", pairs,
                         "--out", out2, "--method", "model,warp,identity",
                         "--iters", "4", "--threads", "2", "--estimator",
                         est, "--reuse-fits", "--finetune", "6",
                         "--finetune-eye-weight", "0", "--finetune-outline", "2", NULL};
    CHECK_EQ_INT(run(ev7), 0);
    char *e7 = check_csv(csv);
    char *d7 = NULL;
    CHECK_EQ_INT(run(ev6), 0);
    d7 = check_csv(csv);
    CHECK_MSG(e7 && d7 && strcmp(e7, d7) != 0, "--finetune-outline 2 changed nothing");
    free(e7);
    free(d7);
    free(sum);
    CHECK_EQ_INT(run(ev7), 0);
    CHECK(summary_has(md, "eye weight 0, outline 2 px, mirror on)", NULL));
    /* --true-code: the fits are given the inputs' true expression and
     * lights, so they (and the outputs) differ from run 1's; the summary
     * says it is a diagnostic. */
    {
        char out3[256], csv3[300], md3[300];
        snprintf(out3, sizeof out3, "%s/run3", dir);
        snprintf(csv3, sizeof csv3, "%s/pairs.csv", out3);
        snprintf(md3, sizeof md3, "%s/summary.md", out3);
        const char *evtc[] = {"eval", "--model", model, "--pairs", pairs,
                              "--out", out3, "--method", "model,warp,identity",
                              "--iters", "4", "--threads", "2", "--estimator",
                              est, "--true-code", "light,expr", NULL};
        CHECK_EQ_INT(run(evtc), 0);
        char *t = check_csv(csv3);
        CHECK_MSG(t && a && strcmp(t, a) != 0, "--true-code changed nothing");
        free(t);
        CHECK(summary_has(md3, "**a diagnostic, not a served figure** (--true-code)",
                          "true expression and lights and kept them",
                          "non-finite outputs 0", NULL));
        evtc[16] = "expr";
        CHECK_EQ_INT(run(evtc), 0);
        CHECK(summary_has(md3, "true expression and kept it",
                          "!--bound-expression", NULL));
        /* --bound-expression: the fit keeps the expression in its
         * training range, and the summary says so */
        const char *evbe[] = {"eval", "--model", model, "--pairs", pairs,
                              "--out", out3, "--method", "model",
                              "--iters", "4", "--threads", "2",
                              "--bound-expression", NULL};
        CHECK_EQ_INT(run(evbe), 0);
        CHECK(summary_has(md3, "expression kept in its training range "
                               "(--bound-expression)",
                          "!--true-code", "non-finite outputs 0", NULL));
        /* --code-prior: the default is none (the same rows as naming
         * 0, and the summary is silent); a weight fits otherwise and the
         * summary names it */
        const char *evcp[] = {"eval", "--model", model, "--pairs", pairs,
                              "--out", out3, "--method", "model,warp,identity",
                              "--iters", "4", "--threads", "2", "--estimator",
                              est, NULL, NULL, NULL};
        CHECK_EQ_INT(run(evcp), 0);
        char *cp1 = check_csv(csv3);
        CHECK(summary_has(md3, "!--code-prior", "!--bound-expression", NULL));
        evcp[15] = "--code-prior";
        evcp[16] = "0.0003";
        CHECK_EQ_INT(run(evcp), 0);
        char *cp0 = check_csv(csv3);
        CHECK(summary_has(md3, "code prior weight 0.0003 (--code-prior)", NULL));
        CHECK_MSG(cp0 && cp1 && strcmp(cp0, cp1) != 0, "--code-prior 0.0003 changed nothing");
        evcp[16] = "0";
        CHECK_EQ_INT(run(evcp), 0);
        char *cp2 = check_csv(csv3);
        CHECK_MSG(cp1 && cp2 && strcmp(cp1, cp2) == 0,
                  "--code-prior 0 is not the default");
        free(cp0);
        free(cp1);
        free(cp2);
    }
    /* --readout: every output's gaze and the floor read by synthesis,
     * the same for 1 and 2 threads, in the summary's tables. */
    expect_read = 1;
    const char *ev8[] = {"eval", "--model", model, "--pairs", pairs,
                         "--out", out2, "--method", "model,warp,identity",
                         "--iters", "4", "--threads", "2", "--estimator",
                         est, "--reuse-fits", "--readout", NULL};
    CHECK_EQ_INT(run(ev8), 0);
    c = check_csv(csv);
    ev8[12] = "1";
    CHECK_EQ_INT(run(ev8), 0);
    d = check_csv(csv);
    CHECK_MSG(c && d && strcmp(c, d) == 0, "readout: 1 and 2 threads "
              "differ:\n%s\n---\n%s", c, d);
    free(c);
    free(d);
    CHECK(summary_has(md, "read gaze° | read floor° |", "- readout: read gaze°",
                      "shift of up to 4 px", "- readout: gaze only median ",
                      "non-finite outputs 0", NULL));
    /* --readout-shift 0: no alignment, and the summary says so */
    const char *ev9[22] = {"eval", "--model", model, "--pairs", pairs,
                         "--out", out2, "--method", "identity",
                         "--iters", "4", "--threads", "2", "--estimator",
                         est, "--reuse-fits", "--readout", "--readout-shift",
                         "0", NULL};
    CHECK_EQ_INT(run(ev9), 0);
    CHECK(summary_has(md, "shift of up to 0 px", "!--readout-soft", NULL));
    /* --readout-soft: the softness searched, in the summary; every read
     * output carries the level it matched */
    ev9[18] = "4";
    ev9[19] = "--readout-soft";
    ev9[20] = "1.5";
    ev9[21] = NULL;
    CHECK_EQ_INT(run(ev9), 0);
    CHECK(summary_has(md, "shift of up to 4 px", "(`--readout-soft 1.5`)",
                      "non-finite outputs 0", NULL));
    {
        /* identity only: 4 rows, each read, its level the last column */
        char *t = ev_slurp(csv), *save = NULL;
        int rows = 0, soft_ok = 0;
        for (char *line = t ? strtok_r(t, "\n", &save) : NULL; line;
             line = strtok_r(NULL, "\n", &save), rows++) {
            const char *last = strrchr(line, ',');
            double v = last && last[1] ? strtod(last + 1, NULL) : NAN;
            soft_ok += rows > 0 && v >= 0 && v <= 1.5;
        }
        CHECK_MSG(rows == 5 && soft_ok == 4, "read_soft_px: %d of %d rows",
                  soft_ok, rows - 1);
        free(t);
    }
    expect_read = 0;
    free(a);
    free(b);
    char cmd[600];
    snprintf(cmd, sizeof cmd, "rm -rf '%s'", dir);
    if (gs_test_failures == 0 && system(cmd) != 0)
        fprintf(stderr, "could not remove %s\n", dir);
    GS_TEST_END();
}
