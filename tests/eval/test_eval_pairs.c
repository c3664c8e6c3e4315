/* The pairing: deterministic, bins as documented, classes covered, the
 * file round-trips and a file from another generator is refused. */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "gazesplat/eval.h"
#include "gs_test.h"

static void bins(void)
{
    CHECK_EQ_INT(gs_eval_angle_bin(0), GS_EVAL_BIN_0_15);
    CHECK_EQ_INT(gs_eval_angle_bin(14.999), GS_EVAL_BIN_0_15);
    CHECK_EQ_INT(gs_eval_angle_bin(15), GS_EVAL_BIN_15_30);
    CHECK_EQ_INT(gs_eval_angle_bin(29.9), GS_EVAL_BIN_15_30);
    CHECK_EQ_INT(gs_eval_angle_bin(30), GS_EVAL_BIN_30_50);
    CHECK_EQ_INT(gs_eval_angle_bin(49.9), GS_EVAL_BIN_30_50);
    CHECK_EQ_INT(gs_eval_angle_bin(50), GS_EVAL_BIN_OVER_50);
    CHECK(strcmp(gs_eval_bin_name(GS_EVAL_BIN_15_30), "15-30") == 0);
    gs_synth_expression ex;
    gs_synth_expression_neutral(&ex);
    CHECK(!gs_eval_expr_narrowed(&ex));
    ex.squint = 0.4f;
    CHECK(gs_eval_expr_narrowed(&ex));
    ex.squint = 0;
    ex.blink = 0.5f;
    CHECK(gs_eval_expr_narrowed(&ex));
    gs_synth_scene s;
    gs_synth_scene_default(&s, 600);
    CHECK(!gs_eval_scene_harsh(&s)); /* frontal-ish key, ambient 0.33 */
    s.ambient[0] = s.ambient[1] = s.ambient[2] = 0.1f;
    s.light[0].dir[0] = -0.8f;
    CHECK(gs_eval_scene_harsh(&s));
    CHECK_CLOSE(gs_eval_angle_deg(0, 0, 0, 0.5), 28.6479, 1e-3, 0);
    CHECK_CLOSE(gs_eval_angle_deg(0.3, 0, 0, 0), 17.1887, 1e-3, 0);
}

static void schedule(const gs_eval_pairs *ps, const gs_eval_pairs_spec *sp)
{
    int nar = 0, harsh = 0, headbin[GS_EVAL_BINS] = {0}, bad = 0;
    CHECK_EQ_INT(ps->n, sp->identities * sp->inputs * sp->targets);
    for (int q = 0; q < ps->n; q++) {
        const gs_eval_pair *p = &ps->p[q];
        int j = q % sp->targets, in = q / sp->targets;
        int k = in % sp->identities, i = in / sp->identities;
        int c = (i + 2 * k) % 10;
        bad += p->input != in || p->identity != k;
        bad += gs_synth_seed_split(p->identity_seed) != GS_SYNTH_TEST;
        bad += gs_eval_angle_bin(p->gaze_change_deg) != j % 3;
        bad += p->head_change != j % 2;
        bad += p->narrowed != (c == 3) || p->harsh != (c == 4);
        if (!p->head_change)
            bad += gs_eval_angle_bin(p->head_deg) != c % 3;
        bad += !(p->head_deg < 50);
        if (j == 0) {
            nar += p->narrowed;
            harsh += p->harsh;
            headbin[gs_eval_angle_bin(p->head_deg)]++;
        }
        if (!p->head_change)
            bad += p->head_change_deg > 1e-6;
    }
    CHECK_MSG(bad == 0, "%d schedule violations", bad);
    /* The first two inputs of every identity already hold every class. */
    int seen[10] = {0}, nseen = 0;
    for (int q = 0; q < 2 * sp->identities * sp->targets; q += sp->targets) {
        int in = q / sp->targets;
        int c = (in / sp->identities + 2 * (in % sp->identities)) % 10;
        nseen += !seen[c];
        seen[c] = 1;
    }
    CHECK_EQ_INT(nseen, 10);
    CHECK(nar > 0 && harsh > 0);
    CHECK(headbin[0] > 0 && headbin[1] > 0 && headbin[2] > 0);
}

/* ps with pair `at` replaced by `other` (of another split), written to
 * path, reads back as a format error that says the splits are mixed; ps
 * is left as it was and path removed. */
static void mixed_refused(const char *path, gs_eval_pairs *ps, int at,
                          const gs_eval_pair *other)
{
    gs_error err = {0, ""};
    gs_eval_pairs r = {0, NULL};
    gs_eval_pair keep = ps->p[at];
    ps->p[at] = *other;
    FILE *f = fopen(path, "w");
    CHECK(f && gs_eval_pairs_write(f, ps, &err) == GS_OK);
    if (f)
        fclose(f);
    ps->p[at] = keep;
    f = fopen(path, "r");
    CHECK(f && gs_eval_pairs_read(f, &r, &err) == GS_ERR_FORMAT);
    CHECK_MSG(strstr(err.msg, "mixed") != NULL, "%s", err.msg);
    if (f)
        fclose(f);
    gs_eval_pairs_free(&r);
    remove(path);
}

int main(void)
{
    bins();
    gs_eval_pairs_spec sp;
    gs_eval_pairs_spec_default(&sp);
    CHECK(sp.identities == 15 && sp.inputs == 10 && sp.targets == 10);
    sp.identities = 5;
    sp.inputs = 4;
    sp.targets = 6;
    gs_eval_pairs a, b;
    gs_error err = {0, ""};
    CHECK_MSG(gs_eval_pairs_make(&sp, &a, &err) == GS_OK, "%s", err.msg);
    CHECK(gs_eval_pairs_make(&sp, &b, &err) == GS_OK);
    CHECK(a.n == b.n && memcmp(a.p, b.p, sizeof *a.p * (size_t)a.n) == 0);
    schedule(&a, &sp);

    /* Round trip through the file. */
    char path[64];
    snprintf(path, sizeof path, "eval_pairs_%d.csv", (int)getpid());
    FILE *f = fopen(path, "w");
    CHECK(f && gs_eval_pairs_write(f, &a, &err) == GS_OK);
    fclose(f);
    gs_eval_pairs r;
    f = fopen(path, "r");
    CHECK_MSG(gs_eval_pairs_read(f, &r, &err) == GS_OK, "%s", err.msg);
    fclose(f);
    CHECK_EQ_INT(r.n, a.n);
    int same = r.n == a.n;
    for (int i = 0; same && i < r.n; i++)
        same = r.p[i].input_scene == a.p[i].input_scene &&
               r.p[i].target_scene == a.p[i].target_scene &&
               r.p[i].head_change == a.p[i].head_change;
    CHECK(same);
    gs_eval_pairs_free(&r);

    /* A changed seed no longer matches its derived columns. */
    f = fopen(path, "w");
    gs_eval_pair keep = a.p[3];
    a.p[3].target_scene += 1;
    gs_eval_pairs_write(f, &a, &err);
    fclose(f);
    a.p[3] = keep;
    f = fopen(path, "r");
    CHECK(gs_eval_pairs_read(f, &r, &err) == GS_ERR_FORMAT);
    CHECK_MSG(strstr(err.msg, "line 6") != NULL, "%s", err.msg);
    fclose(f);
    /* A bad header, and an empty file. */
    f = fopen(path, "w");
    fputs("pair,input\n0,0\n", f);
    fclose(f);
    f = fopen(path, "r");
    CHECK(gs_eval_pairs_read(f, &r, &err) == GS_ERR_FORMAT);
    fclose(f);
    f = fopen(path, "w");
    fclose(f);
    f = fopen(path, "r");
    CHECK(gs_eval_pairs_read(f, &r, &err) == GS_ERR_FORMAT);
    fclose(f);
    remove(path);

    /* Scenes of a pair: the target keeps everything but gaze (and head). */
    gs_synth_scene in, tg;
    gs_eval_pair_scenes(&a.p[0], &in, &tg);
    CHECK(a.p[0].head_change == 0);
    CHECK(memcmp(in.head_R, tg.head_R, sizeof in.head_R) == 0);
    CHECK(memcmp(&in.expr, &tg.expr, sizeof in.expr) == 0);
    CHECK(memcmp(in.light, tg.light, sizeof in.light) == 0);
    gs_eval_pair_scenes(&a.p[1], &in, &tg);
    CHECK(a.p[1].head_change == 1);
    CHECK(memcmp(in.head_R, tg.head_R, sizeof in.head_R) != 0);

    /* Validation identities: the same schedule on other identities; a
     * file of them reads back; a file mixing the splits is refused. The
     * training identities (the seen-identity diagnostic) likewise, and a
     * split out of range is refused. */
    gs_eval_pairs v;
    sp.split = GS_SYNTH_VAL;
    CHECK_MSG(gs_eval_pairs_make(&sp, &v, &err) == GS_OK, "%s", err.msg);
    int val = v.n == a.n, disjoint = 1;
    for (int i = 0; val && i < v.n; i++) {
        val = gs_synth_seed_split(v.p[i].identity_seed) == GS_SYNTH_VAL;
        disjoint &= v.p[i].identity_seed != a.p[i].identity_seed;
    }
    CHECK_MSG(val && disjoint, "validation pairs: %d, disjoint from test: %d", val, disjoint);
    f = fopen(path, "w");
    CHECK(f && gs_eval_pairs_write(f, &v, &err) == GS_OK);
    fclose(f);
    f = fopen(path, "r");
    CHECK_MSG(gs_eval_pairs_read(f, &r, &err) == GS_OK && r.n == v.n, "%s", err.msg);
    fclose(f);
    gs_eval_pairs_free(&r);
    mixed_refused(path, &v, v.n - 1, &a.p[a.n - 1]); /* a test pair last */
    gs_eval_pairs_free(&v);
    gs_eval_pairs t;
    sp.split = GS_SYNTH_TRAIN;
    CHECK_MSG(gs_eval_pairs_make(&sp, &t, &err) == GS_OK, "%s", err.msg);
    int train = t.n == a.n;
    for (int i = 0; train && i < t.n; i++)
        train = gs_synth_seed_split(t.p[i].identity_seed) == GS_SYNTH_TRAIN &&
                t.p[i].identity_seed ==
                    gs_synth_split_seed(GS_SYNTH_TRAIN, (uint64_t)t.p[i].identity) &&
                t.p[i].input_scene == a.p[i].input_scene;
    CHECK_MSG(train, "training pairs: the same schedule on training identities");
    f = fopen(path, "w");
    CHECK(f && gs_eval_pairs_write(f, &t, &err) == GS_OK);
    fclose(f);
    f = fopen(path, "r");
    char first[200] = "";
    CHECK(fgets(first, sizeof first, f) && strstr(first, "training-split"));
    rewind(f);
    CHECK_MSG(gs_eval_pairs_read(f, &r, &err) == GS_OK && r.n == t.n, "%s", err.msg);
    fclose(f);
    int tsame = r.n == t.n;
    for (int i = 0; tsame && i < r.n; i++)
        tsame = r.p[i].identity_seed == t.p[i].identity_seed &&
                r.p[i].target_scene == t.p[i].target_scene;
    CHECK(tsame);
    gs_eval_pairs_free(&r);
    mixed_refused(path, &t, 0, &a.p[0]); /* a test pair first */
    gs_eval_pairs_free(&t);
    sp.split = (gs_synth_split)3;
    CHECK(gs_eval_pairs_make(&sp, &r, &err) == GS_ERR_ARG);
    sp.split = GS_SYNTH_TEST;

    sp.targets = 0;
    CHECK(gs_eval_pairs_make(&sp, &r, &err) == GS_ERR_ARG);
    gs_eval_pairs_free(&a);
    gs_eval_pairs_free(&b);
    GS_TEST_END();
}
