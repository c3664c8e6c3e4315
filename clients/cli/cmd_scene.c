/* gazesplat scene: writes the procedural demo scene (demo_head.c). */
#include <stdio.h>
#include <string.h>

#include "cli.h"
#include "gazesplat/ply.h"

static int run_scene(const cli_command *cmd, cli_opt *o);

static const cli_opt scene_opts[] = {
    {"--out", 1, NULL}, {"--seed", 1, NULL}};

const cli_command cli_scene_command = {
    "scene",
    "write a procedural demo 3DGS scene (a stylised head) to a .ply",
    "usage: gazesplat scene --out FILE.ply [--seed N]\n"
    "\n"
    "  --out FILE    the .ply to write (SH degree 0, with zero normals)\n"
    "  --seed N      0..4294967295 (default 1): jitter of positions and colours\n"
    "\n"
    "A stylised head of a few thousand Gaussians (skin shell, hair, ears,\n"
    "eyes with iris and pupil, brows, nose, lips, neck), about 1.6 units wide,\n"
    "centred at the world origin and facing -z (x right, y down). The camera\n"
    "of the demo sits 4 units in front of it, looking down +z:\n"
    "  gazesplat render --ply FILE --intrinsics 300,300,128,128 --size 256x256 \\\n"
    "      --view 1,0,0,0,0,1,0,0,0,0,1,4 --out head.png\n",
    .opts = scene_opts,
    .nopts = CLI_NOPTS(scene_opts),
    .run_opts = run_scene,
};

_Static_assert(CLI_NOPTS(scene_opts) == 2, "scene_opts: one entry per option index");

static int run_scene(const cli_command *cmd, cli_opt *o)
{
    long seed = 1;
    gs_ply_scene scene;
    gs_error err = {0, ""};
    int rc = CLI_OK;
    if (!o[0].value)
        return cli_usage_error(cmd, "missing --out");
    if (o[1].value && cli_parse_long(o[1].value, 0, 4294967295L, &seed))
        return cli_usage_error(cmd, "--seed: want 0..4294967295; got '%s'",
                               o[1].value);
    if (cli_demo_head((unsigned long)seed, &scene) != GS_OK)
        return cli_fail(cmd, "out of memory");
    rc = gs_ply_write(o[0].value, &scene, &err);
    if (rc == GS_OK)
        printf("gazesplat scene: %d Gaussians -> %s\n", scene.n, o[0].value);
    gs_ply_free(&scene);
    return rc == GS_OK ? CLI_OK : cli_fail(cmd, "%s", err.msg);
}
