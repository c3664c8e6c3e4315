/* gazesplat eval-downstream end to end on a tiny model (trained here for
 * seconds) and a tiny untrained estimator: the CSV has every row with
 * finite errors, k = 0 is the given estimator's error on the test images
 * (recomputed here from the documented scenes), fine-tuning changes it,
 * reruns give the same bytes (1 and 2 threads, fits reused), the summary
 * and the plot are written, usage errors exit 2 and runtime failures 1.
 * usage: test_eval_downstream GAZESPLAT PYTHON PLOT_SCRIPT */
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
#include "gazesplat/nn.h"
#include "gazesplat/train.h"
#include "gs_test.h"

#include "eval_fixture.h"

static char dir[] = "downstream_test_XXXXXX";
enum { IDS = 2, TESTS = 3, MAXK = 2 };

/* The smallest estimator: its error is meaningless, its arithmetic is
 * the shipped one's. */
static void tiny_estimator(const char *path)
{
    gs_gaze_spec s = {GS_GAZE_RESNET, 32, {4, 4, 6, 6}, 8};
    gs_gaze_net *net = NULL;
    gs_error err = {0, ""};
    CHECK(gs_gaze_net_create(&s, 3, &net, &err) == GS_OK);
    CHECK_MSG(gs_gaze_net_save(net, path, &err) == GS_OK, "%s", err.msg);
    gs_gaze_net_destroy(net);
}

/* k = 0 as documented: the estimator on test images POOL..POOL+TESTS-1 of
 * the identity (seed 1), mean angle to the true normalized gaze. */
static double k0_error(const char *model, const char *est, int identity,
                       const gs_synth_kappa *kappa)
{
    gs_model *m = NULL;
    gs_gaze_net *net = NULL;
    gs_error err = {0, ""};
    CHECK(gs_model_load(model, &m, &err) == GS_OK);
    CHECK(gs_gaze_net_load(est, &net, &err) == GS_OK);
    if (!m || !net)
        return NAN;
    gs_model_info mi;
    gs_model_get_info(m, &mi);
    double sum = 0;
    for (int t = 0; t < TESTS; t++) {
        gs_synth_scene sc;
        gs_synth_sample smp = {0};
        float out[4];
        gs_eval_ds_scene(1, identity, GS_EVAL_DS_POOL + t, &sc);
        if (kappa)
            gs_synth_scene_set_kappa(kappa, &sc);
        CHECK(gs_eval_render_scene(&sc, mi.image_size, mi.distance_mm,
                                   mi.focal, NULL, &smp, &err) == GS_OK);
        CHECK(gs_gaze_net_predict(net, NULL, smp.rgb, smp.width, smp.height,
                                  smp.stride, out, &err) == GS_OK);
        sum += gs_eval_angle_deg(out[0], out[1], smp.labels.gaze_norm_pitch,
                                 smp.labels.gaze_norm_yaw);
        gs_synth_sample_free(&smp);
    }
    gs_gaze_net_destroy(net);
    gs_model_destroy(m);
    return sum / TESTS;
}

/* Checks the CSV rows and returns its text. */
static char *check_csv(const char *out, const double *k0)
{
    char path[320];
    snprintf(path, sizeof path, "%s/downstream.csv", out);
    char *text = ev_slurp(path);
    CHECK_MSG(text != NULL, "no %s", path);
    if (!text)
        return NULL;
    const char *head = "identity,identity_seed,k,condition,gaze_err_deg\n";
    CHECK_MSG(strncmp(text, head, strlen(head)) == 0, "header: %.60s", text);
    int rows = 0, changed = 0;
    const char *p = strchr(text, '\n');
    while (p && p[1]) {
        int id, k;
        unsigned long long seed;
        char cond[32];
        double e;
        CHECK_MSG(sscanf(p + 1, "%d,%llu,%d,%31[^,],%lf", &id, &seed, &k,
                         cond, &e) == 5, "bad row %.40s", p + 1);
        int expect_cond = rows % 3, expect_k = (rows / 3) % (MAXK + 1);
        CHECK_EQ_INT(id, rows / (3 * (MAXK + 1)));
        CHECK_EQ_INT(k, expect_k);
        CHECK_MSG(strcmp(cond, gs_eval_ds_condition_name(expect_cond)) == 0,
                  "row %d: %s", rows, cond);
        CHECK(seed == gs_synth_split_seed(GS_SYNTH_TEST, (uint64_t)id));
        CHECK_MSG(isfinite(e) && e >= 0 && e <= 180, "row %d: %g", rows, e);
        if (k == 0 && id < IDS)
            CHECK_MSG(fabs(e - k0[id]) <= 6e-5, "identity %d: k=0 %.6f, "
                      "the estimator as given %.6f", id, e, k0[id]);
        else if (id < IDS)
            changed += fabs(e - k0[id]) > 1e-3;
        rows++;
        p = strchr(p + 1, '\n');
    }
    CHECK_EQ_INT(rows, IDS * (MAXK + 1) * 3);
    CHECK_MSG(changed > 0, "fine-tuning changed no error");
    return text;
}

static void usage_errors(const char *exe, const char *model, const char *est)
{
    const char *none[] = {exe, "eval-downstream", NULL};
    CHECK_EQ_INT(ev_spawn(dir, none), 2);
    const char *bad[][4] = {
        {"--steps", "0"}, {"--max-k", "10"}, {"--max-k", "0"},
        {"--set-size", "5"}, {"--real-fraction", "1.5"}, {"--lr", "0"},
        {"--lr", "x"}, {"--identities", "0"}, {"--threads", "0"},
        {"--test-images", "-1"}, {"--batch", "0"}, {"--iters", "0"},
        {"--seed", "-2"}, {"--bogus", "1"}, {"--fit-lr", "0"},
        {"--fit-lr", "0.1,11"}, {"--fit-lr", "nan"}};
    for (size_t i = 0; i < sizeof bad / sizeof bad[0]; i++) {
        const char *a[] = {exe, "eval-downstream", "--model", model,
                           "--estimator", est, "--out", dir, bad[i][0],
                           bad[i][1], i == 3 ? "--max-k" : NULL, "9", NULL};
        CHECK_MSG(ev_spawn(dir, a) == 2, "%s %s should be a usage error", bad[i][0],
                  bad[i][1]);
    }
    const char *noout[] = {exe, "eval-downstream", "--model", model, NULL};
    CHECK_EQ_INT(ev_spawn(dir, noout), 2);
    const char *positional[] = {exe, "eval-downstream", "extra", NULL};
    CHECK_EQ_INT(ev_spawn(dir, positional), 2);
    char missing[256];
    snprintf(missing, sizeof missing, "%s/missing.safetensors", dir);
    const char *nomodel[] = {exe, "eval-downstream", "--model", missing,
                             "--estimator", est, "--out", dir, NULL};
    CHECK_EQ_INT(ev_spawn(dir, nomodel), 1);
    const char *noest[] = {exe, "eval-downstream", "--model", model,
                           "--estimator", missing, "--out", dir, NULL};
    CHECK_EQ_INT(ev_spawn(dir, noest), 1);
}

/* The cache file format: a file of the run reads as a keyed fit cache
 * (of another key than 0: GS_ERR_STATE), a written one reads back with its
 * key alone, and unkeyed files of the older format are stale, not bad. */
static void fit_cache(const char *out)
{
    gs_subject s, t;
    double secs = -1;
    char path[320];
    snprintf(path, sizeof path, "%s/fits/seed1_00001.bin", out);
    CHECK(gs_eval_fit_cache_read(path, 0, &s, &secs, NULL) == GS_ERR_STATE);
    FILE *f = fopen(path, "rb");
    char magic[8] = {0};
    CHECK(f && fread(magic, 1, 8, f) == 8 && fclose(f) == 0);
    CHECK(memcmp(magic, "GSFITC2\n", 8) == 0);
    memset(&s, 0, sizeof s);
    s.code_dim = 4;
    s.code[2] = 0.25f;
    s.head_R[0] = s.head_R[4] = s.head_R[8] = 1;
    s.fit_psnr = 30;
    snprintf(path, sizeof path, "%s/fits/mine.bin", out);
    const uint64_t key = 0x0123456789abcdefULL;
    CHECK(gs_eval_fit_cache_write(path, key, &s, 1.5, NULL) == GS_OK);
    CHECK(gs_eval_fit_cache_read(path, key, &t, &secs, NULL) == GS_OK);
    CHECK(secs == 1.5 && t.code_dim == 4 && t.code[2] == 0.25f && t.fit_psnr == 30);
    gs_error err = {0, ""};
    CHECK(gs_eval_fit_cache_read(path, key ^ 1, &t, &secs, &err) == GS_ERR_STATE);
    CHECK_MSG(strstr(err.msg, "another model"), "%s", err.msg);
    /* the older format: seconds, then the subject */
    uint8_t buf[8 + GS_SUBJECT_ENCODED_MAX];
    memcpy(buf, &secs, 8);
    size_t n = 8 + gs_subject_encode(&s, buf + 8, sizeof buf - 8);
    f = fopen(path, "wb");
    CHECK(f && fwrite(buf, 1, n, f) == n && fclose(f) == 0);
    CHECK(gs_eval_fit_cache_read(path, key, &t, &secs, &err) == GS_ERR_STATE);
    CHECK_MSG(strstr(err.msg, "older version"), "%s", err.msg);
    snprintf(path, sizeof path, "%s/fits/none.bin", out);
    CHECK(gs_eval_fit_cache_read(path, key, &t, &secs, NULL) == GS_ERR_IO);
    f = fopen(path, "wb");
    CHECK(f && fwrite("12345678garbage", 1, 15, f) == 15 && fclose(f) == 0);
    CHECK(gs_eval_fit_cache_read(path, key, &t, &secs, NULL) == GS_ERR_FORMAT);
    f = fopen(path, "wb");
    CHECK(f && fwrite("GSFITC2\n0123456789abcdefgarbage", 1, 32, f) == 32 &&
          fclose(f) == 0);
    CHECK(gs_eval_fit_cache_read(path, key, &t, &secs, NULL) == GS_ERR_FORMAT);
    /* a failed write leaves nothing behind */
    snprintf(path, sizeof path, "%s/no-such-dir/x.bin", out);
    CHECK(gs_eval_fit_cache_write(path, key, &s, 1.5, NULL) == GS_ERR_IO);
}

/* The rows of a CSV text whose k (third field) is k, in order. */
static char *rows_of_k(const char *csv, int k)
{
    size_t n = strlen(csv);
    char *out = calloc(n + 1, 1);
    const char *p = strchr(csv, '\n');
    while (out && p && p[1]) {
        const char *e = strchr(p + 1, '\n');
        size_t len = e ? (size_t)(e - p) : strlen(p + 1) + 1;
        int id, kk;
        unsigned long long seed;
        if (sscanf(p + 1, "%d,%llu,%d,", &id, &seed, &kk) == 3 && kk == k)
            strncat(out, p + 1, len);
        p = e;
    }
    return out;
}

/* The CSV of a calibration run: only k = 0 and the --ks rows; k = 0 is the
 * estimator on the identity's scenes with its kappa. */
static void check_calibration_csv(const char *out, const double *k0kappa)
{
    char path[320];
    snprintf(path, sizeof path, "%s/downstream.csv", out);
    char *text = ev_slurp(path);
    CHECK_MSG(text != NULL, "no %s", path);
    int rows = 0;
    const char *p = text ? strchr(text, '\n') : NULL;
    while (p && p[1]) {
        int id, k;
        unsigned long long seed;
        char cond[32];
        double e;
        CHECK(sscanf(p + 1, "%d,%llu,%d,%31[^,],%lf", &id, &seed, &k, cond,
                     &e) == 5);
        CHECK_MSG(k == 0 || k == 2, "row %d: k %d is not in --ks 2", rows, k);
        CHECK_MSG(isfinite(e), "row %d: %g", rows, e);
        if (k == 0 && id >= 0 && id < IDS)
            CHECK_MSG(fabs(e - k0kappa[id]) <= 6e-5, "identity %d: k=0 %.6f, "
                      "the estimator on its kappa scenes %.6f", id, e,
                      k0kappa[id]);
        rows++;
        p = strchr(p + 1, '\n');
    }
    CHECK_EQ_INT(rows, IDS * 2 * 3);
    free(text);
}

/* subjects.csv: one row per identity and k run, the identity's kappa
 * (gs_synth_kappa_draw, degrees) and a finite offset, nonzero with
 * --calibrate (the fits found a gaze other than the label). */
static void check_subjects(const char *out, const gs_synth_kappa *kappa)
{
    char path[320];
    snprintf(path, sizeof path, "%s/subjects.csv", out);
    char *text = ev_slurp(path);
    CHECK_MSG(text && strncmp(text, "identity,k,kappa_h_deg,kappa_v_deg,"
                                    "offset_pitch_deg,offset_yaw_deg\n",
                              62) == 0, "%s: %.80s", path, text ? text : "");
    int rows = 0;
    const char *p = text ? strchr(text, '\n') : NULL;
    while (p && p[1]) {
        int id, k;
        double h, v, op, oy, th, tv;
        CHECK(sscanf(p + 1, "%d,%d,%lf,%lf,%lf,%lf", &id, &k, &h, &v, &op,
                     &oy) == 6);
        CHECK_EQ_INT(id, rows);
        CHECK_EQ_INT(k, 2);
        gs_synth_kappa_draw(kappa, gs_synth_split_seed(GS_SYNTH_TEST,
                                                       (uint64_t)id), &th,
                            &tv);
        const double deg = 180.0 / 3.14159265358979323846;
        CHECK_MSG(fabs(h - th * deg) < 1e-4 && fabs(v - tv * deg) < 1e-4,
                  "identity %d: kappa %g %g, drawn %g %g", id, h, v, th * deg,
                  tv * deg);
        CHECK_MSG(isfinite(op) && isfinite(oy) && (op != 0 || oy != 0),
                  "identity %d: offset %g %g", id, op, oy);
        rows++;
        p = strchr(p + 1, '\n');
    }
    CHECK_EQ_INT(rows, IDS);
    free(text);
}

/* The calibration options: kappa scenes, a subject from the k images, the
 * fitted offset, --ks and --first-identity. */
static int run_cal(const char *exe, const char *model, const char *est,
                   const char *out, const char *threads, const char *extra)
{
    const char *a[] = {exe, "eval-downstream", "--model", model,
                       "--estimator", est, "--out", out, "--identities", "2",
                       "--test-images", "3", "--set-size", "10", "--max-k",
                       "2", "--steps", "3", "--batch", "4", "--lr", "1e-3",
                       "--iters", "2", "--threads", threads, "--kappa",
                       "literature", "--subject-from-k", "--ks", "2", extra,
                       NULL};
    return ev_spawn(dir, a);
}

static void calibration(const char *exe, const char *model, const char *est,
                        const char *legacy_csv)
{
    {
        gs_eval_ds_options o;
        gs_error e = {0, ""};
        gs_eval_ds_options_default(&o);
        o.max_k = 3;
        o.ks = 1u << 3 | 1u << 1;
        CHECK(gs_eval_ds_options_check(&o, &e) == GS_OK);
        o.ks = 1u << 4;
        CHECK(gs_eval_ds_options_check(&o, &e) == GS_ERR_ARG &&
              strstr(e.msg, "ks"));
        o.ks = 1u;
        CHECK(gs_eval_ds_options_check(&o, &e) == GS_ERR_ARG);
        o.ks = 0;
        gs_synth_kappa_literature(&o.kappa);
        CHECK(gs_eval_ds_options_check(&o, &e) == GS_OK);
        o.kappa.h_mean_deg = 20;
        CHECK(gs_eval_ds_options_check(&o, &e) == GS_ERR_ARG);
    }
    const char *bad[][2] = {{"--ks", "0"}, {"--ks", "3"}, {"--ks", "1,,2"},
                            {"--ks", "x"}, {"--kappa", "bogus"},
                            {"--kappa", "20,1,1,1"},
                            {"--first-identity", "-1"}};
    for (size_t i = 0; i < sizeof bad / sizeof bad[0]; i++) {
        const char *a[] = {exe, "eval-downstream", "--model", model,
                           "--estimator", est, "--out", dir, "--max-k", "2",
                           bad[i][0], bad[i][1], NULL};
        CHECK_MSG(ev_spawn(dir, a) == 2, "%s %s should be a usage error",
                  bad[i][0], bad[i][1]);
    }
    gs_synth_kappa kappa;
    gs_synth_kappa_literature(&kappa);
    double k0[IDS];
    for (int i = 0; i < IDS; i++)
        k0[i] = k0_error(model, est, i, &kappa);
    char c1[256], c2[256], c3[256], c4[256];
    snprintf(c1, sizeof c1, "%s/cal1", dir);
    snprintf(c2, sizeof c2, "%s/cal2", dir);
    snprintf(c3, sizeof c3, "%s/cal3", dir);
    snprintf(c4, sizeof c4, "%s/cal4", dir);
    CHECK_EQ_INT(run_cal(exe, model, est, c1, "2", "--calibrate"), 0);
    CHECK_EQ_INT(run_cal(exe, model, est, c2, "1", "--calibrate"), 0);
    check_calibration_csv(c1, k0);
    check_subjects(c1, &kappa);
    const char *files[] = {"downstream.csv", "subjects.csv"};
    for (int f = 0; f < 2; f++) {
        char pa[320], pb[320];
        snprintf(pa, sizeof pa, "%s/%s", c1, files[f]);
        snprintf(pb, sizeof pb, "%s/%s", c2, files[f]);
        char *a = ev_slurp(pa), *b = ev_slurp(pb);
        CHECK_MSG(a && b && strcmp(a, b) == 0, "%s: 1 and 2 threads differ",
                  files[f]);
        free(a);
        free(b);
    }
    /* Without --calibrate the renders aim at the targets themselves: the
     * model's rows change, the real and warp rows do not. */
    CHECK_EQ_INT(run_cal(exe, model, est, c3, "2", NULL), 0);
    char pa[320], pb[320];
    snprintf(pa, sizeof pa, "%s/downstream.csv", c1);
    snprintf(pb, sizeof pb, "%s/downstream.csv", c3);
    char *a = ev_slurp(pa), *b = ev_slurp(pb);
    CHECK_MSG(a && b && strcmp(a, b) != 0, "--calibrate changed nothing");
    free(a);
    free(b);
    /* A subject from k = 1 images without kappa is the legacy subject of
     * real image 1, and the first set_size - 1 images are the same: the
     * k = 1 rows equal the legacy run's. --first-identity 1 gives
     * identity 1's rows. */
    const char *one[] = {exe, "eval-downstream", "--model", model,
                         "--estimator", est, "--out", c4, "--identities", "1",
                         "--first-identity", "1", "--test-images", "3",
                         "--set-size", "10", "--max-k", "2", "--steps", "3",
                         "--batch", "4", "--lr", "1e-3", "--iters", "2",
                         "--subject-from-k", "--ks", "1", NULL};
    CHECK_EQ_INT(ev_spawn(dir, one), 0);
    snprintf(pb, sizeof pb, "%s/downstream.csv", c4);
    b = ev_slurp(pb);
    char *want = rows_of_k(legacy_csv, 1), *got = b ? rows_of_k(b, 1) : NULL;
    const char *id1 = want ? strstr(want, "\n1,") : NULL;
    CHECK_MSG(got && id1 && strcmp(got, id1 + 1) == 0,
              "k = 1 from 1 image, identity 1:\n%s\nlegacy:\n%s",
              got ? got : "", want ? want : "");
    free(b);
    free(want);
    free(got);
}

static int run_ds(const char *exe, const char *model, const char *est,
                  const char *out, const char *threads, int reuse)
{
    const char *a[] = {exe, "eval-downstream", "--model", model,
                       "--estimator", est, "--out", out, "--identities", "2",
                       "--test-images", "3", "--set-size", "10", "--max-k",
                       "2", "--steps", "3", "--batch", "4", "--lr", "1e-3",
                       "--iters", "2", "--threads", threads,
                       reuse ? "--reuse-fits" : NULL, NULL};
    return ev_spawn(dir, a);
}

int main(int argc, char **argv)
{
    if (argc != 4) {
        fprintf(stderr, "usage: test_eval_downstream GAZESPLAT PYTHON "
                        "PLOT_SCRIPT\n");
        return 2;
    }
    const char *exe = argv[1];
    CHECK(mkdtemp(dir) != NULL);
    /* The library refuses fit rates outside [0, 10] (0: the defaults). */
    {
        gs_eval_ds_options o;
        gs_error e = {0, ""};
        gs_eval_ds_options_default(&o);
        CHECK(gs_eval_ds_options_check(&o, &e) == GS_OK);
        o.fit_lr_code = -0.1;
        CHECK(gs_eval_ds_options_check(&o, &e) == GS_ERR_ARG &&
              strstr(e.msg, "fit rates"));
        o.fit_lr_code = 0.12;
        o.fit_lr_colour = NAN;
        CHECK(gs_eval_ds_options_check(&o, &e) == GS_ERR_ARG);
    }
    char model[256], est[256], out1[256], out2[256], md[320], png[320];
    snprintf(model, sizeof model, "%s/tiny.safetensors", dir);
    snprintf(est, sizeof est, "%s/est.safetensors", dir);
    snprintf(out1, sizeof out1, "%s/run1", dir);
    snprintf(out2, sizeof out2, "%s/run2", dir);
    ev_train_tiny(model, 2);
    tiny_estimator(est);
    usage_errors(exe, model, est);

    double k0[IDS];
    for (int i = 0; i < IDS; i++)
        k0[i] = k0_error(model, est, i, NULL);
    CHECK_EQ_INT(run_ds(exe, model, est, out1, "2", 0), 0);
    char *a = check_csv(out1, k0);
    snprintf(md, sizeof md, "%s/downstream.md", out1);
    char *sum = ev_slurp(md);
    if (!sum)
        sum = strdup("(none)");
    CHECK_MSG(strstr(sum, "| k | real only | real + ours | real + warp |") &&
                  strstr(sum, "Failed identities: 0.") &&
                  strstr(sum, "gazesplat eval-downstream --model") &&
                  strstr(sum, "rates 0.12 (code) and 0.02 (colour)") &&
                  !strstr(sum, "nan"),
              "summary:\n%s", sum);
    free(sum);
    fit_cache(out1);

    /* Determinism: another thread count, then the fits reused. */
    CHECK_EQ_INT(run_ds(exe, model, est, out2, "1", 0), 0);
    char *b = check_csv(out2, k0);
    CHECK_MSG(a && b && strcmp(a, b) == 0, "1 and 2 threads differ:\n%s\n"
              "---\n%s", a, b);
    free(b);
    CHECK_EQ_INT(run_ds(exe, model, est, out2, "2", 1), 0);
    b = check_csv(out2, k0);
    CHECK_MSG(a && b && strcmp(a, b) == 0, "fits reused differ:\n%s", b);
    snprintf(md, sizeof md, "%s/downstream.md", out2);
    sum = ev_slurp(md);
    CHECK_MSG(sum && strstr(sum, "2 reused"), "%s", sum ? sum : "");
    free(sum);
    calibration(exe, model, est, a);
    free(a);
    free(b);

    /* The plot script on the first run's CSV. */
    const char *plot[] = {argv[2], argv[3], out1, NULL};
    CHECK_EQ_INT(ev_spawn(dir, plot), 0);
    snprintf(png, sizeof png, "%s/downstream.png", out1);
    struct stat st;
    CHECK_MSG(stat(png, &st) == 0 && st.st_size > 1000, "no plot %s", png);

    char cmd[600];
    snprintf(cmd, sizeof cmd, "rm -rf '%s'", dir);
    if (gs_test_failures == 0 && system(cmd) != 0)
        fprintf(stderr, "could not remove %s\n", dir);
    GS_TEST_END();
}
