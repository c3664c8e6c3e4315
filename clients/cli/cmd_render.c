/* gazesplat render: a .ply scene through the rasterizer to .npy or an
 * image. The rasterizer writes channel planes (C x H x W); outputs are
 * interleaved H x W x 3 RGB, taken from channels 0..2. */
#define _POSIX_C_SOURCE 200809L /* clock_gettime */

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "gazesplat/clock.h"
#include "cli.h"
#include "gazesplat/image_io.h"
#include "gazesplat/ply.h"
#include "gazesplat/pool.h"
#include "gazesplat/raster.h"

static int run_render(const cli_command *cmd, cli_opt *o);

static const cli_opt render_opts[] = {
    {"--ply", 1, NULL}, {"--intrinsics", 1, NULL}, {"--size", 1, NULL}, {"--view", 1, NULL},
    {"--out", 1, NULL}, {"--threads", 1, NULL}, {"--scalar", 0, NULL}, {"--antialiased", 0, NULL},
    {"--background", 1, NULL}};

const cli_command cli_render_command = {
    "render",
    "render a 3DGS .ply scene to .npy, .png or .jpg",
    "usage: gazesplat render --ply FILE --intrinsics fx,fy,cx,cy --size WxH\n"
    "           --view r00,r01,r02,t0,r10,r11,r12,t1,r20,r21,r22,t2\n"
    "           --out FILE.npy|FILE.png|FILE.jpg [--threads N] [--scalar]\n"
    "           [--antialiased] [--background r,g,b]\n"
    "\n"
    "  --ply FILE           3DGS scene (binary little-endian .ply)\n"
    "  --intrinsics LIST    focal lengths and principal point, pixels (fx, fy > 0)\n"
    "  --size WxH           image size, 1..8192 each\n"
    "  --view LIST          world-to-camera [R | t], 3x4, row-major; camera\n"
    "                       frame x right, y down, z forward\n"
    "  --out FILE           .npy: H x W x 3 float32 RGB; .png/.jpg: 8-bit RGB,\n"
    "                       clamped to [0, 1] and rounded\n"
    "  --threads N          worker threads, 1..256 (default: one per CPU); the\n"
    "                       result is the same for any N\n"
    "  --scalar             use the scalar reference rasterizer (one thread)\n"
    "  --antialiased        compensate opacity for the 0.3 px screen blur\n"
    "  --background r,g,b   background colour (default 0,0,0)\n"
    "\n"
    "Colours are the degree-0 SH colour (0.2821 f_dc + 0.5); for feature\n"
    "scenes, channels 0..2.\n",
    .opts = render_opts,
    .nopts = CLI_NOPTS(render_opts),
    .run_opts = run_render,
};

enum { OUT_NPY = 1, OUT_PNG, OUT_JPEG };

typedef struct render_args {
    const char *ply, *out;
    int out_kind;
    gs_camera cam;
    int threads; /* 0: one per CPU */
    gs_raster_options ropt;
    float bg[3];
} render_args;

enum { O_PLY, O_INTR, O_SIZE, O_VIEW, O_OUT, O_THREADS, O_SCALAR, O_AA, O_BG, O_COUNT };

static int out_kind_of(const char *path)
{
    const char *dot = strrchr(path, '.');
    if (dot && strcmp(dot, ".npy") == 0)
        return OUT_NPY;
    int f = gs_io_format_from_path(path);
    return f == GS_IO_PNG ? OUT_PNG : f == GS_IO_JPEG ? OUT_JPEG : 0;
}

/* Converts the parsed option strings; CLI_PARSED or a usage error. */
static int convert_args(const cli_opt *o, render_args *a)
{
    const cli_command *cmd = &cli_render_command;
    static const char *const required[] = {"--ply", "--intrinsics", "--size", "--view", "--out"};
    float intr[4];
    long threads = 0;
    for (int i = 0; i < 5; i++)
        if (!o[i].value)
            return cli_usage_error(cmd, "missing %s", required[i]);
    a->ply = o[O_PLY].value;
    a->out = o[O_OUT].value;
    if (cli_parse_floats(o[O_INTR].value, intr, 4) || intr[0] <= 0 || intr[1] <= 0)
        return cli_usage_error(cmd, "--intrinsics: want fx,fy,cx,cy, finite, fx and fy > 0; got '%s'",
                               o[O_INTR].value);
    a->cam.fx = intr[0], a->cam.fy = intr[1], a->cam.cx = intr[2], a->cam.cy = intr[3];
    if (cli_parse_size(o[O_SIZE].value, GS_RASTER_MAX_SIZE, &a->cam.width, &a->cam.height))
        return cli_usage_error(cmd, "--size: want WxH, each 1..%d; got '%s'", GS_RASTER_MAX_SIZE,
                               o[O_SIZE].value);
    if (cli_parse_floats(o[O_VIEW].value, a->cam.viewmat, 12))
        return cli_usage_error(cmd, "--view: want 12 finite comma-separated numbers; got '%s'",
                               o[O_VIEW].value);
    if (!(a->out_kind = out_kind_of(a->out)))
        return cli_usage_error(cmd, "--out: want a .npy, .png or .jpg file; got '%s'", a->out);
    if (o[O_THREADS].value && cli_parse_long(o[O_THREADS].value, 1, GS_POOL_MAX_THREADS, &threads))
        return cli_usage_error(cmd, "--threads: want 1..%d; got '%s'", GS_POOL_MAX_THREADS,
                               o[O_THREADS].value);
    a->threads = (int)threads;
    a->ropt.path = o[O_SCALAR].value ? GS_RASTER_SCALAR : GS_RASTER_FAST;
    a->ropt.antialiased = o[O_AA].value != NULL;
    if (o[O_BG].value && cli_parse_floats(o[O_BG].value, a->bg, 3))
        return cli_usage_error(cmd, "--background: want r,g,b, finite; got '%s'", o[O_BG].value);
    return CLI_PARSED;
}

/* H x W x 3 float32 from channels 0..2 of the C x H x W planes. */
static int write_npy(const char *path, const float *planes, int w, int h, gs_error *err)
{
    size_t hw = (size_t)w * (size_t)h, shape[3] = {(size_t)h, (size_t)w, 3};
    float *hwc = malloc(hw * 3 * sizeof *hwc);
    if (!hwc)
        return gs_error_set(err, GS_ERR_NOMEM, "out of memory");
    for (size_t i = 0; i < hw; i++)
        for (size_t c = 0; c < 3; c++)
            hwc[3 * i + c] = planes[c * hw + i];
    int rc = gs_io_npy_write(path, GS_IO_F32, 3, shape, hwc, err);
    free(hwc);
    return rc;
}

/* 8-bit RGB: each value clamped to [0, 1], times 255, rounded half up. */
static int write_image(const char *path, int format, const float *planes, int w, int h,
                       gs_error *err)
{
    size_t hw = (size_t)w * (size_t)h;
    gs_io_image img = {w, h, 3 * (size_t)w, malloc(hw * 3)};
    if (!img.data)
        return gs_error_set(err, GS_ERR_NOMEM, "out of memory");
    for (size_t i = 0; i < hw; i++)
        for (size_t c = 0; c < 3; c++) {
            float v = fminf(fmaxf(planes[c * hw + i], 0.0f), 1.0f);
            img.data[3 * i + c] = (unsigned char)floorf(v * 255.0f + 0.5f);
        }
    int rc = gs_io_image_write(path, &img, (gs_io_format)format, 0, err);
    free(img.data);
    return rc;
}

/* Background planes (C x H x W): bg in channels 0..2, zero elsewhere. */
static float *background_planes(const float bg[3], int channels, size_t hw)
{
    float *p = calloc((size_t)channels * hw, sizeof *p);
    for (int c = 0; p && c < 3; c++)
        for (size_t i = 0; i < hw; i++)
            p[(size_t)c * hw + i] = bg[c];
    return p;
}

typedef struct render_bufs {
    float *features, *alpha, *bg;
    gs_raster *r;
    gs_pool *pool;
} render_bufs;

static void free_bufs(render_bufs *b)
{
    free(b->features);
    free(b->alpha);
    free(b->bg);
    gs_raster_destroy(b->r);
    gs_pool_destroy(b->pool);
}

static int render_scene(const render_args *a, const gs_ply_scene *scene, gs_error *err)
{
    const cli_command *cmd = &cli_render_command;
    size_t hw = (size_t)a->cam.width * (size_t)a->cam.height;
    int use_bg = a->bg[0] != 0 || a->bg[1] != 0 || a->bg[2] != 0;
    render_bufs b = {0};
    b.features = malloc((size_t)scene->channels * hw * sizeof(float));
    b.alpha = malloc(hw * sizeof(float));
    b.bg = use_bg ? background_planes(a->bg, scene->channels, hw) : NULL;
    b.r = gs_raster_create();
    if (a->ropt.path == GS_RASTER_FAST && a->threads != 1)
        b.pool = gs_pool_create(a->threads);
    if (!b.features || !b.alpha || (use_bg && !b.bg) || !b.r) {
        free_bufs(&b);
        return cli_fail(cmd, "out of memory for a %dx%d render", a->cam.width, a->cam.height);
    }
    gs_gaussians g;
    gs_ply_gaussians(scene, &g);
    double t0 = (1e3 * gs_clock_s());
    int rc = gs_raster_forward(b.r, b.pool, &a->cam, &g, b.bg, &a->ropt, b.features, b.alpha,
                               NULL, err);
    double ms = (1e3 * gs_clock_s()) - t0;
    int nthreads = b.pool ? gs_pool_threads(b.pool) : 1;
    if (!rc)
        rc = a->out_kind == OUT_NPY ? write_npy(a->out, b.features, a->cam.width, a->cam.height, err)
             : write_image(a->out, a->out_kind == OUT_PNG ? GS_IO_PNG : GS_IO_JPEG, b.features,
                           a->cam.width, a->cam.height, err);
    free_bufs(&b);
    if (rc)
        return cli_fail(cmd, "%s", err->msg);
    printf("gazesplat render: %d Gaussians, %dx%d, %.1f ms (%s, %d threads) -> %s\n", scene->n,
           a->cam.width, a->cam.height, ms, a->ropt.path == GS_RASTER_SCALAR ? "scalar" : "fast",
           nthreads, a->out);
    return CLI_OK;
}

_Static_assert(CLI_NOPTS(render_opts) == O_COUNT, "render_opts: one entry per option index");

static int run_render(const cli_command *cmd, cli_opt *o)
{
    render_args a;
    gs_ply_scene scene;
    gs_error err = {0, ""};
    memset(&a, 0, sizeof a);
    int rc = convert_args(o, &a);
    if (rc != CLI_PARSED)
        return rc;
    if (gs_ply_read(a.ply, NULL, &scene, &err) != GS_OK)
        return cli_fail(cmd, "%s", err.msg);
    if (scene.channels < 3) {
        int channels = scene.channels;
        gs_ply_free(&scene);
        return cli_fail(cmd, "%s has %d feature channels; RGB needs 3", a.ply,
                        channels);
    }
    rc = render_scene(&a, &scene, &err);
    gs_ply_free(&scene);
    return rc;
}
