/* gazesplat end to end. usage: test_cli PATH_TO_GAZESPLAT errors|render
 * Runs the program with posix_spawn and checks exit codes, stderr
 * messages and the files it writes. The two halves run as two ctest
 * cases: each run of the program costs about 0.1 s of start-up (mostly
 * loading OpenCV's dependencies). */
#define _POSIX_C_SOURCE 200809L /* posix_spawn, mkdtemp */

#include <fcntl.h>
#include <math.h>
#include <spawn.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/wait.h>
#include <unistd.h>

#include "gazesplat/image_io.h"
#include "gazesplat/ply.h"
#include "gs_test.h"

extern char **environ;

static const char *exe;
static char dir[] = "cli_test_XXXXXX";

typedef struct result {
    int status; /* exit code, or -1 when killed */
    char out[4096], err[4096];
} result;

static void slurp(const char *path, char *buf, size_t cap)
{
    FILE *f = fopen(path, "rb");
    size_t n = f ? fread(buf, 1, cap - 1, f) : 0;
    buf[n] = '\0';
    if (f)
        fclose(f);
}

/* Runs gazesplat with args (NULL-terminated). */
static void run(result *r, const char *const *args)
{
    const char *argv[64];
    char outp[256], errp[256];
    int n = 0;
    argv[n++] = exe;
    while (args[n - 1] && n < 63) {
        argv[n] = args[n - 1];
        n++;
    }
    argv[n] = NULL;
    snprintf(outp, sizeof outp, "%s/stdout.txt", dir);
    snprintf(errp, sizeof errp, "%s/stderr.txt", dir);
    posix_spawn_file_actions_t fa;
    posix_spawn_file_actions_init(&fa);
    posix_spawn_file_actions_addopen(&fa, 1, outp, O_WRONLY | O_CREAT | O_TRUNC, 0644);
    posix_spawn_file_actions_addopen(&fa, 2, errp, O_WRONLY | O_CREAT | O_TRUNC, 0644);
    pid_t pid;
    int st = 0;
    r->status = -1;
    if (posix_spawn(&pid, exe, &fa, NULL, (char *const *)argv, environ) == 0 &&
        waitpid(pid, &st, 0) == pid && WIFEXITED(st))
        r->status = WEXITSTATUS(st);
    posix_spawn_file_actions_destroy(&fa);
    slurp(outp, r->out, sizeof r->out);
    slurp(errp, r->err, sizeof r->err);
}

static void path_in(char *buf, size_t cap, const char *name)
{
    snprintf(buf, cap, "%s/%s", dir, name);
}

/* Runs args and checks the exit code and that stdout or stderr contains
 * want (and want2 unless NULL). */
static void expect2(const char *const *args, int status, int on_stderr, const char *want,
                    const char *want2)
{
    result r;
    run(&r, args);
    const char *text = on_stderr ? r.err : r.out;
    char cmd[512] = "";
    for (int i = 0; args[i]; i++)
        snprintf(cmd + strlen(cmd), sizeof cmd - strlen(cmd), "%s ", args[i]);
    CHECK_MSG(r.status == status, "gazesplat %s: exit %d, want %d; stderr: %s", cmd, r.status,
              status, r.err);
    CHECK_MSG(strstr(text, want) != NULL, "gazesplat %s: %s lacks '%s': %s", cmd,
              on_stderr ? "stderr" : "stdout", want, text);
    if (want2)
        CHECK_MSG(strstr(text, want2) != NULL, "gazesplat %s: %s lacks '%s': %s", cmd,
                  on_stderr ? "stderr" : "stdout", want2, text);
}

static void expect(const char *const *args, int status, int on_stderr, const char *want)
{
    expect2(args, status, on_stderr, want, NULL);
}

enum { A_PLY = 2, A_INTR = 4, A_SIZE = 6, A_VIEW = 8, A_OUT = 10 };

static char ply_path[256], png_path[256];

/* A valid render command line; callers change one value. */
static void base_render(const char **a)
{
    static const char *const base[] = {"render", "--ply", ply_path, "--intrinsics",
                                       "300,300,128,128", "--size", "256x256", "--view",
                                       "1,0,0,0,0,1,0,0,0,0,1,4", "--out", png_path, NULL};
    memcpy(a, base, sizeof base);
}

static void test_usage_errors(void)
{
    /* One malformed value per option here; test_cli_args covers the
     * parsers value by value in-process (a run of the program costs
     * about 0.1 s, mostly loading OpenCV's dependencies). */
    static const struct {
        int slot;
        const char *value, *msg;
    } bad[] = {
        {A_SIZE, "0x256", "--size: want WxH, each 1..8192; got '0x256'"},
        {A_SIZE, "9000x10", "--size"},
        {A_INTR, "300,300,128", "--intrinsics: want fx,fy,cx,cy"},
        {A_INTR, "nan,300,128,128", "--intrinsics"},
        {A_INTR, "-300,300,128,128", "--intrinsics"},
        {A_VIEW, "1,0,0,0,0,1,0,0,0,0,1", "--view: want 12 finite"},
        {A_VIEW, "1,0,0,0,0,1,0,0,0,0,inf,4", "--view"},
        {A_OUT, "x.bmp", "--out: want a .npy, .png or .jpg file; got 'x.bmp'"},
    };
    const char *a[24];
    for (size_t i = 0; i < sizeof bad / sizeof bad[0]; i++) {
        base_render(a);
        a[bad[i].slot] = bad[i].value;
        expect2(a, 2, 1, "usage: gazesplat render", bad[i].msg);
    }
    static const char *const extra[][3] = {
        {"--threads", "0", "--threads: want 1..256; got '0'"},
        {"--background", "1,2", "--background: want r,g,b"},
        {"--frobnicate", NULL, "unknown option '--frobnicate'"},
        {"extra", NULL, "unexpected argument 'extra'"},
        {"--size", "256x256", "option --size given twice"},
        {"--scalar=1", NULL, "option --scalar takes no value"},
        {"--threads", NULL, "option --threads needs a value"},
    };
    for (size_t i = 0; i < sizeof extra / sizeof extra[0]; i++) {
        base_render(a);
        a[11] = extra[i][0];
        a[12] = extra[i][1];
        a[13] = NULL;
        expect2(a, 2, 1, "usage: gazesplat render", extra[i][2]);
    }
    base_render(a);
    a[1] = "--scalar"; /* drops --ply */
    a[2] = "--antialiased";
    expect(a, 2, 1, "missing --ply");
    const char *none[] = {NULL}, *bogus[] = {"bogus", NULL}, *render[] = {"render", NULL};
    expect(none, 2, 1, "usage: gazesplat COMMAND");
    expect(bogus, 2, 1, "unknown command 'bogus'");
    expect(render, 2, 1, "missing --ply");
    const char *scene1[] = {"scene", NULL}, *scene2[] = {"scene", "--out", "x.ply", "--seed", "-1", NULL};
    const char *scene3[] = {"scene", "--out", "x.ply", "--seed", "abc", NULL};
    expect(scene1, 2, 1, "usage: gazesplat scene");
    expect(scene2, 2, 1, "--seed: want 0..4294967295; got '-1'");
    expect(scene3, 2, 1, "usage: gazesplat scene");
}

static void test_help(void)
{
    const char *h1[] = {"--help", NULL}, *h2[] = {"help", "render", NULL};
    const char *h3[] = {"help", "nope", NULL}, *h4[] = {"render", "--help", NULL};
    const char *h5[] = {"help", "scene", NULL}, *h6[] = {"-h", NULL}, *h7[] = {"help", NULL};
    expect2(h1, 0, 0, "  render ", " render a 3DGS");
    expect(h2, 0, 0, "usage: gazesplat render --ply FILE");
    expect(h3, 2, 1, "unknown command");
    expect(h4, 0, 0, "--background r,g,b");
    expect(h5, 0, 0, "usage: gazesplat scene --out FILE.ply");
    expect2(h6, 0, 0, "  scene ", " write a procedural");
    expect(h7, 0, 0, "Commands:");
}

static unsigned char *read_all(const char *path, size_t *n)
{
    FILE *f = fopen(path, "rb");
    unsigned char *buf = NULL;
    *n = 0;
    if (f && fseek(f, 0, SEEK_END) == 0) {
        long size = ftell(f);
        rewind(f);
        buf = malloc((size_t)size + 1);
        *n = fread(buf, 1, (size_t)size, f);
    }
    if (f)
        fclose(f);
    return buf;
}

static void write_file(const char *path, const void *data, size_t n)
{
    FILE *f = fopen(path, "wb");
    CHECK(f && fwrite(data, 1, n, f) == n);
    if (f)
        fclose(f);
}

/* A small .ply from a header and n * stride bytes of 0.5f. */
static void write_ply(const char *name, const char *head, size_t nbytes)
{
    char p[256];
    size_t hl = strlen(head);
    unsigned char *b = malloc(hl + nbytes + 1);
    float half = 0.5f;
    memcpy(b, head, hl);
    for (size_t i = 0; i < nbytes; i++)
        b[hl + i] = ((unsigned char *)&half)[i % 4];
    path_in(p, sizeof p, name);
    write_file(p, b, hl + nbytes);
    free(b);
}

#define PROPS(OPA, ROT3)                                                          \
    "property float x\nproperty float y\nproperty float z\nproperty float f_dc_0\n" \
    "property float f_dc_1\nproperty float f_dc_2\nproperty " OPA " opacity\n"      \
    "property float scale_0\nproperty float scale_1\nproperty float scale_2\n"      \
    "property float rot_0\nproperty float rot_1\nproperty float rot_2\n" ROT3 "end_header\n"
#define HEAD(N) "ply\nformat binary_little_endian 1.0\nelement vertex " N "\n"

static void test_runtime_errors(void)
{
    static const struct {
        const char *file, *head;
        size_t bytes;
        const char *msg;
    } cases[] = {
        {"trunc.ply", HEAD("2") PROPS("float", "property float rot_3\n"), 111, "truncated"},
        {"type.ply", HEAD("2") PROPS("double", "property float rot_3\n"), 120,
         "'opacity' has type double, expected float"},
        {"count.ply", HEAD("4000000000") PROPS("float", "property float rot_3\n"), 112,
         "vertex count '4000000000' over the limit"},
        {"missing.ply", HEAD("2") PROPS("float", ""), 104, "missing property 'rot_3'"},
        {"feat1.ply",
         HEAD("1") "property float x\nproperty float y\nproperty float z\nproperty float feat_0\n"
                   "property float opacity\nproperty float scale_0\nproperty float scale_1\n"
                   "property float scale_2\nproperty float rot_0\nproperty float rot_1\n"
                   "property float rot_2\nproperty float rot_3\nend_header\n",
         48, "1 feature channels"},
    };
    const char *a[24];
    char p[256];
    for (size_t i = 0; i < sizeof cases / sizeof cases[0]; i++) {
        write_ply(cases[i].file, cases[i].head, cases[i].bytes);
        path_in(p, sizeof p, cases[i].file);
        base_render(a);
        a[A_PLY] = p;
        expect(a, 1, 1, cases[i].msg);
    }
    path_in(p, sizeof p, "none.ply");
    base_render(a);
    a[A_PLY] = p;
    expect(a, 1, 1, "cannot open");
    base_render(a);
    a[A_OUT] = "no/such/dir/out.png";
    expect(a, 1, 1, "cannot create");
    const char *s[] = {"scene", "--out", "no/such/dir/x.ply", NULL};
    expect(s, 1, 1, "cannot create");
}

static void test_scene(void)
{
    char p2[256], p3[256];
    const char *s1[] = {"scene", "--out", ply_path, "--seed", "7", NULL};
    path_in(p2, sizeof p2, "seed7b.ply");
    path_in(p3, sizeof p3, "seed8.ply");
    const char *s2[] = {"scene", "--out", p2, "--seed", "7", NULL};
    const char *s3[] = {"scene", "--out", p3, "--seed=8", NULL};
    expect(s1, 0, 0, "Gaussians");
    expect(s2, 0, 0, "Gaussians");
    expect(s3, 0, 0, "Gaussians");
    size_t n1, n2, n3;
    unsigned char *b1 = read_all(ply_path, &n1), *b2 = read_all(p2, &n2), *b3 = read_all(p3, &n3);
    CHECK_MSG(n1 > 0 && n1 == n2 && memcmp(b1, b2, n1) == 0, "same seed, different files");
    CHECK_MSG(n1 != n3 || memcmp(b1, b3, n1) != 0, "seeds 7 and 8 give the same file");
    free(b1), free(b2), free(b3);
    gs_ply_scene s;
    gs_error err = {0};
    CHECK_EQ_INT(gs_ply_read(ply_path, NULL, &s, &err), GS_OK);
    CHECK_MSG(s.n >= 1000 && s.n <= 10000, "demo scene has %d Gaussians", s.n);
    CHECK(s.kind == GS_PLY_SH && s.sh_degree == 0 && s.channels == 3);
    gs_ply_free(&s);
}

static float *load_hwc(const char *path)
{
    gs_io_array a;
    gs_error err = {0};
    int rc = gs_io_npy_read(path, 0, &a, &err);
    CHECK_MSG(rc == GS_OK, "%s: %s", path, err.msg);
    if (rc)
        return NULL;
    CHECK(a.dtype == GS_IO_F32 && a.rank == 3 && a.shape[0] == 256 && a.shape[1] == 256 &&
          a.shape[2] == 3);
    if (a.dtype != GS_IO_F32 || gs_io_array_count(&a) != 256 * 256 * 3) {
        gs_io_array_free(&a);
        return NULL;
    }
    return a.data;
}

/* Darkest pixel (sum of RGB) in a 5x5 window around (x, y). */
static float darkest(const float *hwc, int x, int y)
{
    float m = 3;
    for (int j = y - 2; j <= y + 2; j++)
        for (int i = x - 2; i <= x + 2; i++) {
            const float *p = hwc + ((size_t)j * 256 + (size_t)i) * 3;
            m = fminf(m, p[0] + p[1] + p[2]);
        }
    return m;
}

static void check_png_matches(const char *png, const float *hwc)
{
    gs_io_image img;
    gs_error err = {0};
    CHECK_EQ_INT(gs_io_image_read(png, NULL, &img, &err), GS_OK);
    if (!img.data)
        return;
    CHECK(img.width == 256 && img.height == 256);
    size_t bad = 0, lit = 0;
    for (size_t i = 0; i < 256 * 256 * 3; i++) {
        float v = fminf(fmaxf(hwc[i], 0.0f), 1.0f);
        int want = (int)floorf(v * 255.0f + 0.5f);
        bad += img.data[i] != want;
    }
    for (size_t i = 0; i < 256 * 256; i++)
        lit += img.data[3 * i] + img.data[3 * i + 1] + img.data[3 * i + 2] > 12;
    CHECK_MSG(bad == 0, "%zu png values differ from the rounded npy", bad);
    CHECK_MSG(lit > 256 * 256 / 5 && lit < 256 * 256 * 9 / 10, "%zu of 65536 pixels lit", lit);
    const unsigned char *c = img.data + (128 * 256 + 128) * 3, *corner = img.data;
    CHECK_MSG(c[0] > 150 && c[0] > c[1] && c[1] > c[2], "centre (%d,%d,%d) is not skin", c[0], c[1],
              c[2]);
    CHECK(corner[0] == 0 && corner[1] == 0 && corner[2] == 0);
    gs_io_image_free(&img);
}

static void test_render(void)
{
    char npy[256], npy1[256], npys[256], npybg[256], jpg[256];
    const char *a[24];
    path_in(npy, sizeof npy, "render.npy");
    path_in(npy1, sizeof npy1, "render1.npy");
    path_in(npys, sizeof npys, "render_scalar.npy");
    path_in(npybg, sizeof npybg, "render_bg.npy");
    path_in(jpg, sizeof jpg, "render.jpg");
    base_render(a);
    expect(a, 0, 0, "256x256");
    base_render(a);
    a[A_OUT] = npy;
    a[11] = "--threads", a[12] = "2", a[13] = NULL;
    expect(a, 0, 0, "2 threads");
    a[A_OUT] = npy1, a[12] = "1";
    expect(a, 0, 0, "1 threads");
    a[A_OUT] = npys, a[11] = "--scalar", a[12] = NULL;
    expect(a, 0, 0, "scalar");
    a[A_OUT] = npybg, a[11] = "--background", a[12] = "0,0,1";
    expect(a, 0, 0, npybg);
    a[A_OUT] = jpg, a[11] = "--antialiased", a[12] = NULL;
    expect(a, 0, 0, jpg);

    float *f = load_hwc(npy), *f1 = load_hwc(npy1), *fs = load_hwc(npys), *fb = load_hwc(npybg);
    if (f && f1 && fs && fb) {
        CHECK_MSG(memcmp(f, f1, 256 * 256 * 3 * sizeof *f) == 0, "1 and 2 threads differ");
        gs_check_arrays("scalar vs fast", fs, f, 256 * 256 * 3, 1e-5, 0);
        check_png_matches(png_path, f);
        /* Dark pupils where the demo's eyes project, skin between them. */
        CHECK_MSG(darkest(f, 100, 118) < 0.5f && darkest(f, 156, 118) < 0.5f,
                  "no dark pupils: %g %g", darkest(f, 100, 118), darkest(f, 156, 118));
        CHECK(darkest(f, 128, 118) > 1.5f);
        CHECK(fb[0] == 0 && fb[1] == 0 && fb[2] == 1 && f[0] == 0 && f[2] == 0);
    }
    free(f), free(f1), free(fs), free(fb);
    gs_io_image img;
    CHECK_EQ_INT(gs_io_image_read(jpg, NULL, &img, NULL), GS_OK);
    CHECK(img.width == 256 && img.height == 256);
    gs_io_image_free(&img);
}

int main(int argc, char **argv)
{
    if (argc != 3 || (strcmp(argv[2], "errors") != 0 && strcmp(argv[2], "render") != 0)) {
        fprintf(stderr, "usage: %s PATH_TO_GAZESPLAT errors|render\n", argv[0]);
        return 2;
    }
    exe = argv[1];
    if (!mkdtemp(dir)) {
        perror("mkdtemp");
        return 1;
    }
    path_in(ply_path, sizeof ply_path, "demo.ply");
    path_in(png_path, sizeof png_path, "demo.png");
    if (strcmp(argv[2], "errors") == 0) {
        gs_ply_scene one; /* a valid one-Gaussian scene for the base command */
        CHECK_EQ_INT(gs_ply_alloc_sh(&one, 1, 0, 0, NULL), GS_OK);
        one.quats[0] = 1;
        CHECK_EQ_INT(gs_ply_write(ply_path, &one, NULL), GS_OK);
        gs_ply_free(&one);
        test_help();
        test_usage_errors();
        test_runtime_errors();
    } else {
        test_scene();
        test_render();
    }
    char cmd[300];
    snprintf(cmd, sizeof cmd, "rm -rf '%s'", dir);
    if (system(cmd) != 0)
        fprintf(stderr, "could not remove %s\n", dir);
    GS_TEST_END();
}
