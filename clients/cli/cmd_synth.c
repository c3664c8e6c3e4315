/* gazesplat synth: synthetic heads with exact labels (lib/synth): a
 * dataset directory, a contact sheet, the neutral template. */
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "cli.h"
#include "gazesplat/image_io.h"
#include "gazesplat/synth.h"

static int run_synth(const cli_command *cmd, cli_opt *o);

static const cli_opt synth_opts[] = {
    {"--out", 1, NULL}, {"--count", 1, NULL}, {"--first", 1, NULL}, {"--seed-split", 1, NULL},
    {"--identities", 1, NULL}, {"--seed", 1, NULL}, {"--size", 1, NULL}, {"--rig", 1, NULL},
    {"--supersample", 1, NULL}, {"--no-masks", 0, NULL}, {"--threads", 1, NULL},
    {"--sheet", 1, NULL}, {"--rows", 1, NULL}, {"--template", 1, NULL}, {"--spacing", 1, NULL},
    {"--face-model6", 0, NULL}, {"--kappa", 1, NULL}};

const cli_command cli_synth_command = {
    "synth",
    "render synthetic heads with exact gaze labels (dataset, contact sheet, template)",
    "usage: gazesplat synth [--out DIR] [--sheet FILE.png] [--template FILE.ply]\n"
    "                       [--face-model6] [options]\n"
    "\n"
    "  --out DIR             write a dataset: DIR/images/*.png, DIR/masks/*.png,\n"
    "                        DIR/labels.jsonl and DIR/README.md (all fields)\n"
    "  --count N             images (default 100)\n"
    "  --first N             first generator index (default 0)\n"
    "  --seed-split SPLIT    train | val | test identities (default train);\n"
    "                        their seed ranges never overlap\n"
    "  --identities N        identities drawn from the split (default 100)\n"
    "  --seed N              scene stream seed (default 0)\n"
    "  --size S              square image size, px (default 128)\n"
    "  --rig RIG             normalized (default): normalized face images\n"
    "                        (d_n 680 mm, f_n 1600 px at 512); single: one\n"
    "                        camera at 600 mm; ethx: 18 cameras around the head,\n"
    "                        image i = camera i mod 18 of frame i / 18\n"
    "  --supersample 1|2     samples per pixel edge (default 1)\n"
    "  --kappa SPEC          angle kappa per identity (visual vs optical axis) in\n"
    "                        the --out dataset:\n"
    "                        off (default), literature (horizontal 5.0 +- 1.3,\n"
    "                        vertical 1.5 +- 1.0 deg) or H,HSD,V,VSD in degrees\n"
    "                        (nasal and up positive; normal, truncated at 3 sd);\n"
    "                        the eyeballs render along the optical axes, the\n"
    "                        gaze labels stay the visual axis\n"
    "  --no-masks            skip the mask images\n"
    "  --threads N           worker threads (default: one per CPU)\n"
    "  --sheet FILE.png      contact sheet: --rows identities of the split x a\n"
    "                        3x3 gaze grid, --size px tiles\n"
    "  --rows N              rows of the sheet (default 4)\n"
    "  --template FILE.ply   neutral template for Gaussian initialisation: head\n"
    "                        frame points (mm) with normals, colour and region\n"
    "                        (0 head, 1 face, 2 left eye, 3 right eye) and a\n"
    "                        'landmark' element with the 68 3D landmarks\n"
    "  --spacing MM          template point spacing (default 2)\n"
    "  --face-model6         print the 6-point face model of the mean head (iBUG\n"
    "                        36, 39, 42, 45, 31, 35; head frame, mm) and its\n"
    "                        nose (27-30, 32-34) as the C initialisers of\n"
    "                        gs_geom_face_model6_synth and _nose7_synth\n"
    "\n"
    "Everything is deterministic: the same options give the same bytes.\n",
    .opts = synth_opts,
    .nopts = CLI_NOPTS(synth_opts),
    .run_opts = run_synth,
};

enum {
    O_OUT, O_COUNT, O_FIRST, O_SPLIT, O_IDS, O_SEED, O_SIZE, O_RIG, O_SS,
    O_NOMASKS, O_THREADS, O_SHEET, O_ROWS, O_TEMPLATE, O_SPACING, O_MODEL6, O_KAPPA, O_N
};

static void progress(void *ctx, uint64_t done, uint64_t total)
{
    cli_progress_t *p = ctx;
    double el = cli_now_s() - p->start;
    cli_progress(p, done == total, "gazesplat synth: %llu/%llu images, %.0f s", (unsigned long long)done,
                 (unsigned long long)total, el);
    if (done == total)
        cli_progress_done(p);
}

static void put_f32(FILE *f, float v)
{
    uint32_t u;
    memcpy(&u, &v, 4);
    unsigned char b[4] = {(unsigned char)u, (unsigned char)(u >> 8),
                          (unsigned char)(u >> 16), (unsigned char)(u >> 24)};
    fwrite(b, 1, 4, f);
}

static int write_template_ply(const char *path, const gs_synth_template *t)
{
    FILE *f = fopen(path, "wb");
    if (!f)
        return -1;
    fprintf(f, "ply\nformat binary_little_endian 1.0\n"
               "comment gazesplat synth neutral template: head frame (x toward "
               "the subject's left, y down, z into the head), millimetres\n"
               "comment region: 0 head, 1 face, 2 left eye, 3 right eye\n"
               "element vertex %d\n"
               "property float x\nproperty float y\nproperty float z\n"
               "property float nx\nproperty float ny\nproperty float nz\n"
               "property uchar red\nproperty uchar green\nproperty uchar blue\n"
               "property uchar region\n"
               "element landmark %d\n"
               "property float x\nproperty float y\nproperty float z\n"
               "end_header\n", t->n, GS_SYNTH_LANDMARKS);
    for (int i = 0; i < t->n; i++) {
        for (int k = 0; k < 3; k++)
            put_f32(f, t->xyz[3 * i + k]);
        for (int k = 0; k < 3; k++)
            put_f32(f, t->normal[3 * i + k]);
        unsigned char c[4];
        for (int k = 0; k < 3; k++)
            c[k] = (unsigned char)(t->rgb[3 * i + k] * 255.0f + 0.5f);
        c[3] = t->region[i];
        fwrite(c, 1, 4, f);
    }
    for (int i = 0; i < GS_SYNTH_LANDMARKS; i++)
        for (int k = 0; k < 3; k++)
            put_f32(f, (float)t->landmarks[i][k]);
    int bad = ferror(f);
    bad |= fclose(f) != 0;
    return bad ? -1 : 0;
}

/* Parses the options that shape the generator. */
static int parse_config(const cli_opt *o, gs_synth_gen_config *c, long *count,
                        long *first, long *threads, long *rows, double *spacing)
{
    const cli_command *cmd = &cli_synth_command;
    long v;
    gs_synth_gen_config_default(c);
    if (o[O_COUNT].value && cli_parse_long(o[O_COUNT].value, 1, 100000000L, count))
        return cli_usage_error(cmd, "--count: want 1..100000000; got '%s'", o[O_COUNT].value);
    if (o[O_FIRST].value && cli_parse_long(o[O_FIRST].value, 0, 4000000000L, first))
        return cli_usage_error(cmd, "--first: want 0..4000000000; got '%s'", o[O_FIRST].value);
    if (o[O_SPLIT].value) {
        static const char *const names[3] = {"train", "val", "test"};
        int k = 0;
        while (k < 3 && strcmp(o[O_SPLIT].value, names[k]) != 0)
            k++;
        if (k == 3)
            return cli_usage_error(cmd, "--seed-split: want train, val or test; got '%s'",
                                   o[O_SPLIT].value);
        c->split = (gs_synth_split)k;
    }
    if (o[O_IDS].value) {
        if (cli_parse_long(o[O_IDS].value, 1, 1000000000L, &v))
            return cli_usage_error(cmd, "--identities: want 1..1000000000; got '%s'",
                                   o[O_IDS].value);
        c->identities = (uint64_t)v;
    }
    if (o[O_SEED].value) {
        if (cli_parse_long(o[O_SEED].value, 0, 4294967295L, &v))
            return cli_usage_error(cmd, "--seed: want 0..4294967295; got '%s'", o[O_SEED].value);
        c->seed = (uint64_t)v;
    }
    if (o[O_SIZE].value) {
        if (cli_parse_long(o[O_SIZE].value, 16, 4096, &v))
            return cli_usage_error(cmd, "--size: want 16..4096; got '%s'", o[O_SIZE].value);
        c->size = (int)v;
    }
    if (o[O_RIG].value) {
        static const char *const names[3] = {"single", "ethx", "normalized"};
        int k = 0;
        while (k < 3 && strcmp(o[O_RIG].value, names[k]) != 0)
            k++;
        if (k == 3)
            return cli_usage_error(cmd, "--rig: want single, ethx or normalized; got '%s'",
                                   o[O_RIG].value);
        c->rig = (gs_synth_rig)k;
    }
    if (o[O_SS].value) {
        if (cli_parse_long(o[O_SS].value, 1, 2, &v))
            return cli_usage_error(cmd, "--supersample: want 1 or 2; got '%s'", o[O_SS].value);
        c->supersample = (int)v;
    }
    if (o[O_KAPPA].value && cli_parse_kappa(&cli_synth_command, o[O_KAPPA].value, &c->kappa) != CLI_PARSED)
        return CLI_USAGE;
    if (o[O_THREADS].value && cli_parse_long(o[O_THREADS].value, 1, 256, threads))
        return cli_usage_error(cmd, "--threads: want 1..256; got '%s'", o[O_THREADS].value);
    if (o[O_ROWS].value && cli_parse_long(o[O_ROWS].value, 1, 64, rows))
        return cli_usage_error(cmd, "--rows: want 1..64; got '%s'", o[O_ROWS].value);
    if (o[O_SPACING].value) {
        float s;
        if (cli_parse_floats(o[O_SPACING].value, &s, 1) || !(s >= 0.5f && s <= 20.0f))
            return cli_usage_error(cmd, "--spacing: want 0.5..20 mm; got '%s'",
                                   o[O_SPACING].value);
        *spacing = s;
    }
    return CLI_PARSED;
}

static int do_sheet(const char *path, const gs_synth_gen_config *c, int rows,
                    gs_pool *pool)
{
    uint8_t *rgb;
    int w, h;
    gs_error err = {0, ""};
    int rc = gs_synth_contact_sheet(c->split, rows, c->size, pool, &rgb, &w, &h, &err);
    if (rc != GS_OK)
        return cli_fail(&cli_synth_command, "%s", err.msg);
    gs_io_image img = {w, h, 3 * (size_t)w, rgb};
    rc = gs_io_image_write(path, &img, GS_IO_PNG, 9, &err);
    free(rgb);
    if (rc != GS_OK)
        return cli_fail(&cli_synth_command, "%s", err.msg);
    printf("gazesplat synth: contact sheet %dx%d -> %s\n", w, h, path);
    return CLI_OK;
}

static int do_template(const char *path, double spacing, gs_pool *pool)
{
    gs_synth_template t;
    gs_error err = {0, ""};
    if (gs_synth_template_build(spacing, pool, &t, &err) != GS_OK)
        return cli_fail(&cli_synth_command, "%s", err.msg);
    int rc = write_template_ply(path, &t);
    int n = t.n;
    gs_synth_template_free(&t);
    if (rc != 0)
        return cli_fail(&cli_synth_command, "cannot write %s", path);
    printf("gazesplat synth: template, %d points -> %s\n", n, path);
    return CLI_OK;
}

/* The six points of the mean head's landmarks, as pasted into
 * lib/geom/geom.c (the landmarks do not depend on the point spacing, so a
 * coarse template is enough). */
static int do_face_model6(gs_pool *pool)
{
    static const int ibug[6] = {36, 39, 42, 45, 31, 35};
    gs_synth_template t;
    gs_error err = {0, ""};
    if (gs_synth_template_build(20.0, pool, &t, &err) != GS_OK)
        return cli_fail(&cli_synth_command, "%s", err.msg);
    static const int nose[7] = {27, 28, 29, 30, 32, 33, 34};
    printf("    /* iBUG 36, 39, 42, 45, 31, 35 of the mean synthetic head, mm */\n");
    printf("    static const double m[6][3] = {\n");
    for (int i = 0; i < 6; i++) {
        const double *p = t.landmarks[ibug[i]];
        printf("        {%.4f, %.4f, %.4f}%s\n", p[0], p[1], p[2], i < 5 ? "," : "};");
    }
    printf("    /* iBUG 27, 28, 29, 30, 32, 33, 34 (gs_geom_face_nose7_synth), mm */\n");
    printf("    static const double m[7][3] = {\n");
    for (int i = 0; i < 7; i++) {
        const double *p = t.landmarks[nose[i]];
        printf("        {%.4f, %.4f, %.4f}%s\n", p[0], p[1], p[2], i < 6 ? "," : "};");
    }
    gs_synth_template_free(&t);
    return CLI_OK;
}

_Static_assert(CLI_NOPTS(synth_opts) == O_N, "synth_opts: one entry per option index");

static int run_synth(const cli_command *cmd, cli_opt *o)
{
    int rc = CLI_OK;
    if (!o[O_OUT].value && !o[O_SHEET].value && !o[O_TEMPLATE].value && !o[O_MODEL6].value)
        return cli_usage_error(cmd, "nothing to do: give --out, --sheet, "
                               "--template or --face-model6");
    gs_synth_gen_config c;
    long count = 100, first = 0, threads = 0, rows = 4;
    double spacing = 2.0;
    rc = parse_config(o, &c, &count, &first, &threads, &rows, &spacing);
    if (rc != CLI_PARSED)
        return rc;
    gs_pool *pool = gs_pool_create((int)threads);
    if (!pool)
        return cli_fail(cmd, "cannot start threads");
    if (o[O_OUT].value) {
        cli_progress_t prog;
        cli_progress_start(&prog);
        gs_synth_dataset_opts d = {(uint64_t)first, (uint64_t)count,
                                   !o[O_NOMASKS].value, progress, &prog};
        gs_error err = {0, ""};
        if (gs_synth_dataset_write(o[O_OUT].value, &c, &d, pool, &err) != GS_OK)
            rc = cli_fail(cmd, "%s", err.msg);
        else
            printf("gazesplat synth: %ld images -> %s\n", count, o[O_OUT].value);
    }
    if (rc == CLI_OK && o[O_SHEET].value)
        rc = do_sheet(o[O_SHEET].value, &c, (int)rows, pool);
    if (rc == CLI_OK && o[O_TEMPLATE].value)
        rc = do_template(o[O_TEMPLATE].value, spacing, pool);
    if (rc == CLI_OK && o[O_MODEL6].value)
        rc = do_face_model6(pool);
    gs_pool_destroy(pool);
    return rc;
}
