/* gazesplat face: a photo through lib/face: face boxes, 68 landmarks, head
 * pose, and the normalized face crop. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "cli.h"
#include "gazesplat/face.h"
#include "gazesplat/image_io.h"

static int run_face(const cli_command *cmd, cli_opt *o);

static const cli_opt face_opts[] = {
    {"--image", 1, NULL}, {"--index", 1, NULL}, {"--box", 1, NULL}, {"--out-norm", 1, NULL},
    {"--out-mask", 1, NULL}, {"--size", 1, NULL}, {"--focal", 1, NULL}, {"--cascade", 1, NULL},
    {"--model", 1, NULL}, {"--min-size", 1, NULL}, {"--min-neighbors", 1, NULL},
    {"--list", 0, NULL}, {"--json", 0, NULL}, {"--pose-model", 1, NULL}};

const cli_command cli_face_command = {
    "face",
    "find faces in a photo: boxes, 68 landmarks, head pose, normalized crop",
    "usage: gazesplat face --image FILE [--index I] [--out-norm FILE.png]\n"
    "                      [--json] [options]\n"
    "\n"
    "  --image FILE         photo (PNG or JPEG)\n"
    "  --index I            which face, largest first (default 0)\n"
    "  --box L,T,R,B        use this face box (dlib convention, inclusive)\n"
    "                       instead of the detector\n"
    "  --out-norm FILE      write the normalized face (PNG or JPEG)\n"
    "  --out-mask FILE      write the face mask of the normalized face (PNG)\n"
    "  --size N             normalized image side, 16..4096 (default 512)\n"
    "  --focal F            camera focal length in pixels (default: the\n"
    "                       photo's longer side), principal point at the centre\n"
    "  --cascade FILE       OpenCV cascade XML (default: Debian's\n"
    "                       haarcascade_frontalface_alt2.xml)\n"
    "  --model FILE         dlib 68-point shape predictor (default: Debian's\n"
    "                       libdlib-data file)\n"
    "  --min-size PX        smallest face the cascade looks for (default:\n"
    "                       1/16 of the photo's shorter side, at least 24)\n"
    "  --min-neighbors N    cascade votes a face needs (default 5)\n"
    "  --pose-model M       generic (default): the common 6-point face model;\n"
    "                       synth: the mean synthetic head, whose head frame\n"
    "                       the trained models use (as `gazesplat redirect`)\n"
    "  --list               only list the faces found (boxes)\n"
    "  --json               print one JSON object instead of text\n"
    "\n"
    "Angles are degrees in the ETH-XGaze convention (pitch > 0 up, yaw > 0\n"
    "toward image-left); the head translation is the face centre, mm.\n"
    "The landmark model was trained on iBUG 300-W: no commercial use.\n",
    .opts = face_opts,
    .nopts = CLI_NOPTS(face_opts),
    .run_opts = run_face,
};

enum {
    O_IMAGE, O_INDEX, O_BOX, O_NORM, O_MASK, O_SIZE, O_FOCAL, O_CASCADE, O_MODEL, O_MINSIZE,
    O_MINNB, O_LIST, O_JSON, O_POSE, O_N
};

#define MAX_LIST 64
#define CLI_LIST 100 /* internal: stop after listing */
#define DEG(x) ((x) * 57.29577951308232)

typedef struct face_run {
    gs_io_image img;
    gs_face_detection det[MAX_LIST];
    int n_det;
    gs_face_result res;
} face_run;

static int parse_opts(const cli_opt *o, gs_face_opts *fo)
{
    const cli_command *cmd = &cli_face_command;
    long v;
    gs_face_opts_default(fo);
    if (!o[O_IMAGE].value)
        return cli_usage_error(cmd, "missing --image");
    if (o[O_INDEX].value) {
        if (cli_parse_long(o[O_INDEX].value, 0, MAX_LIST - 1, &v))
            return cli_usage_error(cmd, "--index: want 0..%d; got '%s'", MAX_LIST - 1,
                                   o[O_INDEX].value);
        fo->index = (int)v;
    }
    if (o[O_BOX].value) {
        float b[4];
        if (cli_parse_floats(o[O_BOX].value, b, 4) || b[2] <= b[0] || b[3] <= b[1])
            return cli_usage_error(cmd, "--box: want L,T,R,B with R > L, B > T; got '%s'",
                                   o[O_BOX].value);
        fo->use_box = 1;
        fo->box = (gs_face_box){(int)lroundf(b[0]), (int)lroundf(b[1]), (int)lroundf(b[2]),
                                (int)lroundf(b[3])};
    }
    if (o[O_SIZE].value) {
        if (cli_parse_long(o[O_SIZE].value, 16, 4096, &v))
            return cli_usage_error(cmd, "--size: want 16..4096; got '%s'", o[O_SIZE].value);
        fo->norm_size = (int)v;
    }
    if (o[O_FOCAL].value) {
        float f;
        if (cli_parse_floats(o[O_FOCAL].value, &f, 1) || !(f > 0))
            return cli_usage_error(cmd, "--focal: want a positive number; got '%s'",
                                   o[O_FOCAL].value);
        fo->use_k = 1; /* the centre is filled once the photo's size is known */
        fo->k[0] = fo->k[4] = f;
    }
    if (o[O_MINSIZE].value) {
        if (cli_parse_long(o[O_MINSIZE].value, 8, 100000, &v))
            return cli_usage_error(cmd, "--min-size: want 8..100000; got '%s'",
                                   o[O_MINSIZE].value);
        fo->detect.min_size = (int)v;
    }
    if (o[O_POSE].value) {
        if (!strcmp(o[O_POSE].value, "generic"))
            fo->pose_model = GS_FACE_POSE_GENERIC;
        else if (!strcmp(o[O_POSE].value, "synth"))
            fo->pose_model = GS_FACE_POSE_SYNTH;
        else
            return cli_usage_error(cmd, "--pose-model: want generic or synth; got '%s'",
                                   o[O_POSE].value);
    }
    if (o[O_MINNB].value) {
        if (cli_parse_long(o[O_MINNB].value, 0, 100, &v))
            return cli_usage_error(cmd, "--min-neighbors: want 0..100; got '%s'",
                                   o[O_MINNB].value);
        fo->detect.min_neighbors = (int)v;
    }
    return CLI_PARSED;
}

static void print_list(const face_run *r, int json)
{
    if (json)
        printf("{\"width\":%d,\"height\":%d,\"faces\":[", r->img.width, r->img.height);
    else
        printf("image %dx%d: %d face%s\n", r->img.width, r->img.height, r->n_det,
               r->n_det == 1 ? "" : "s");
    for (int i = 0; i < r->n_det && i < MAX_LIST; i++) {
        const gs_face_box b = r->det[i].box, c = r->det[i].cascade;
        if (json)
            printf("%s{\"box\":[%d,%d,%d,%d],\"cascade\":[%d,%d,%d,%d]}", i ? "," : "", b.left,
                   b.top, b.right, b.bottom, c.left, c.top, c.right, c.bottom);
        else
            printf("  face %d: box %d,%d,%d,%d (cascade %d,%d,%d,%d)\n", i, b.left, b.top,
                   b.right, b.bottom, c.left, c.top, c.right, c.bottom);
    }
    if (json)
        printf("]}\n");
}

static void print_text(const face_run *r)
{
    const gs_face_result *s = &r->res;
    printf("image %dx%d: %d face%s\n", s->image_width, s->image_height, r->n_det,
           r->n_det == 1 ? "" : "s");
    for (int i = 0; i < r->n_det && i < MAX_LIST; i++)
        printf("  face %d: box %d,%d,%d,%d (cascade %d,%d,%d,%d)\n", i, r->det[i].box.left,
               r->det[i].box.top, r->det[i].box.right, r->det[i].box.bottom,
               r->det[i].cascade.left, r->det[i].cascade.top, r->det[i].cascade.right,
               r->det[i].cascade.bottom);
    printf("box %d,%d,%d,%d\nlandmarks", s->box.left, s->box.top, s->box.right, s->box.bottom);
    for (int i = 0; i < GS_FACE_LANDMARKS; i++)
        printf("%s%d,%d", i % 8 ? " " : "\n  ", s->pts[i][0], s->pts[i][1]);
    printf("\nhead pitch %.2f yaw %.2f deg (normalized camera: %.2f, %.2f)\n",
           DEG(s->pose.pitch), DEG(s->pose.yaw), DEG(s->head_pitch_n), DEG(s->head_yaw_n));
    printf("face centre %.1f, %.1f, %.1f mm; reprojection %.2f px; focal %.1f px\n",
           s->pose.t[0], s->pose.t[1], s->pose.t[2], s->pose.rms_px, s->k[0]);
}

static void print_box(const char *name, gs_face_box b)
{
    printf("\"%s\":[%d,%d,%d,%d]", name, b.left, b.top, b.right, b.bottom);
}

static void print_json(const face_run *r)
{
    const gs_face_result *s = &r->res;
    printf("{\"width\":%d,\"height\":%d,\"faces\":[", s->image_width, s->image_height);
    for (int i = 0; i < r->n_det && i < MAX_LIST; i++) {
        printf("%s{", i ? "," : "");
        print_box("box", r->det[i].box);
        putchar(',');
        print_box("cascade", r->det[i].cascade);
        putchar('}');
    }
    printf("],");
    print_box("box", s->box);
    printf(",\"landmarks\":[");
    for (int i = 0; i < GS_FACE_LANDMARKS; i++)
        printf("%s[%d,%d]", i ? "," : "", s->pts[i][0], s->pts[i][1]);
    printf("],\"k\":[");
    for (int i = 0; i < 9; i++)
        printf("%s%.17g", i ? "," : "", s->k[i]);
    printf("],\"head_rvec\":[%.17g,%.17g,%.17g],\"head_t_mm\":[%.17g,%.17g,%.17g],"
           "\"head_pitch_deg\":%.6f,\"head_yaw_deg\":%.6f,\"reprojection_px\":%.4f,",
           s->pose.rvec[0], s->pose.rvec[1], s->pose.rvec[2], s->pose.t[0], s->pose.t[1],
           s->pose.t[2], DEG(s->pose.pitch), DEG(s->pose.yaw), s->pose.rms_px);
    printf("\"norm\":{\"size\":%d,\"focal\":%.17g,\"distance_mm\":%.17g,\"W\":[", s->norm.width,
           s->norm.f_n, s->norm.d_n_mm);
    for (int i = 0; i < 9; i++)
        printf("%s%.17g", i ? "," : "", s->norm.W[i]);
    printf("],\"head_pitch_deg\":%.6f,\"head_yaw_deg\":%.6f}}\n", DEG(s->head_pitch_n),
           DEG(s->head_yaw_n));
}

static int write_outputs(const cli_opt *o, face_run *r)
{
    const cli_command *cmd = &cli_face_command;
    gs_error err = {0, ""};
    if (o[O_NORM].value) {
        int fmt = gs_io_format_from_path(o[O_NORM].value);
        gs_io_image n;
        if (gs_face_normalize_image(&r->img, &r->res.norm, &n, &err) != GS_OK)
            return cli_fail(cmd, "%s", err.msg);
        int rc = gs_io_image_write(o[O_NORM].value, &n, fmt ? fmt : GS_IO_PNG, 0, &err);
        gs_io_image_free(&n);
        if (rc != GS_OK)
            return cli_fail(cmd, "%s", err.msg);
    }
    if (o[O_MASK].value) {
        int s = r->res.norm.width;
        gs_io_image m = {s, s, 3 * (size_t)s, malloc((size_t)s * s * 3)};
        uint8_t *a = malloc((size_t)s * s);
        int rc = m.data && a ? GS_OK : GS_ERR_NOMEM;
        if (!rc)
            rc = gs_face_mask((const double(*)[2])r->res.uv_n, GS_FACE_MASK_FACE, 0, s / 64.0,
                              s, s, a, &err);
        if (!rc) {
            for (size_t i = 0; i < (size_t)s * s; i++)
                m.data[3 * i] = m.data[3 * i + 1] = m.data[3 * i + 2] = a[i];
            rc = gs_io_image_write(o[O_MASK].value, &m, GS_IO_PNG, 0, &err);
        }
        free(a);
        free(m.data);
        if (rc != GS_OK)
            return cli_fail(cmd, "%s", rc == GS_ERR_NOMEM ? "out of memory" : err.msg);
    }
    return CLI_OK;
}

static int analyze(const cli_opt *o, gs_face_opts *fo, face_run *r)
{
    const cli_command *cmd = &cli_face_command;
    gs_error err = {0, ""};
    gs_face_detector *det = NULL;
    gs_face_shape_model *sp = NULL;
    if (fo->use_k) {
        fo->k[2] = r->img.width * 0.5;
        fo->k[5] = r->img.height * 0.5;
        fo->k[8] = 1;
    }
    int rc = CLI_OK;
    if (!fo->use_box) {
        if (gs_face_detector_load(o[O_CASCADE].value, &det, &err) != GS_OK ||
            gs_face_detect(det, &r->img, &fo->detect, r->det, MAX_LIST, &r->n_det, &err) != GS_OK)
            rc = cli_fail(cmd, "%s", err.msg);
        else if (o[O_LIST].value)
            rc = CLI_LIST;
        else if (r->n_det == 0)
            rc = cli_fail(cmd, "no face found in %s", o[O_IMAGE].value);
        else if (fo->index >= r->n_det)
            rc = cli_fail(cmd, "--index %d but %d face%s found", fo->index, r->n_det,
                          r->n_det == 1 ? "" : "s");
        else {
            fo->use_box = 1;
            fo->box = r->det[fo->index].box;
        }
    }
    if (rc == CLI_OK && gs_face_shape_model_load(o[O_MODEL].value, &sp, &err) != GS_OK)
        rc = cli_fail(cmd, "%s", err.msg);
    if (rc == CLI_OK && gs_face_analyze(NULL, sp, &r->img, fo, &r->res, &err) != GS_OK)
        rc = cli_fail(cmd, "%s", err.msg);
    gs_face_shape_model_destroy(sp);
    gs_face_detector_destroy(det);
    return rc;
}

_Static_assert(CLI_NOPTS(face_opts) == O_N, "face_opts: one entry per option index");

static int run_face(const cli_command *cmd, cli_opt *o)
{
    int rc = CLI_OK;
    gs_face_opts fo;
    rc = parse_opts(o, &fo);
    if (rc != CLI_PARSED)
        return rc;
    face_run *r = calloc(1, sizeof *r);
    if (!r)
        return cli_fail(cmd, "out of memory");
    gs_error err = {0, ""};
    if (gs_io_image_read(o[O_IMAGE].value, NULL, &r->img, &err) != GS_OK) {
        free(r);
        return cli_fail(cmd, "%s", err.msg);
    }
    if (o[O_LIST].value && fo.use_box) {
        gs_io_image_free(&r->img);
        free(r);
        return cli_usage_error(cmd, "--list needs the detector, not --box");
    }
    rc = analyze(o, &fo, r);
    if (rc == CLI_LIST) {
        print_list(r, o[O_JSON].value != NULL);
        rc = CLI_OK;
        gs_io_image_free(&r->img);
        free(r);
        return rc;
    }
    if (rc == CLI_OK)
        rc = write_outputs(o, r);
    if (rc == CLI_OK) {
        if (o[O_JSON].value)
            print_json(r);
        else
            print_text(r);
    }
    gs_io_image_free(&r->img);
    free(r);
    return rc;
}
