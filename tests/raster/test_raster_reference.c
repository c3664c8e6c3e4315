/* Compares gs_raster_forward/backward on both paths with the float64
 * PyTorch reference written by raster_reference.py (llm.c style).
 *
 * Tolerances (stated here, printed per array):
 *   images: features and alpha |diff| <= 1e-5 + 1e-5 |ref|,
 *           depth (sum of weight x z, z ~ 3..6) <= 2e-5 + 1e-5 |ref|;
 *   gradients: |diff| <= GRAD_ATOL x max|ref| + GRAD_RTOL |ref|, with
 *           gsplat's boundary band: entries below 1e-5 max|ref| may fail
 *           in at most 0.1% of the entries of an array.
 *   stats: contributing (pixel, Gaussian) pairs exact on both paths;
 *          visible Gaussians and (tile, Gaussian) pairs exact on the
 *          scalar path, at most the reference's on the fast path (it also
 *          culls tiles and Gaussians that cannot reach alpha 1/255).
 * The scenes are nudged off every discrete threshold by the script, so
 * float32 rounding flips no decision; any band use is reported. */
#include "rt_util.h"

#define GRAD_ATOL 1e-4
#define GRAD_RTOL 1e-3
#define BAND 1e-5
#define BAND_FRAC 1e-3

typedef struct rt_tensor {
    char name[64];
    int ndim;
    size_t dims[4];
    size_t count;
    float *data;
} rt_tensor;

typedef struct rt_file {
    int version, nscenes, ntensors;
    rt_tensor *t;
} rt_file;

static int read_u32(FILE *fp, uint32_t *v)
{
    unsigned char b[4];
    if (fread(b, 1, 4, fp) != 4)
        return -1;
    *v = (uint32_t)b[0] | (uint32_t)b[1] << 8 | (uint32_t)b[2] << 16 |
         (uint32_t)b[3] << 24;
    return 0;
}

static int read_tensor(FILE *fp, rt_tensor *t)
{
    uint32_t len, ndim, d;
    if (read_u32(fp, &len) || len == 0 || len >= sizeof t->name ||
        fread(t->name, 1, len, fp) != len)
        return -1;
    t->name[len] = 0;
    if (read_u32(fp, &ndim) || ndim > 4)
        return -1;
    t->ndim = (int)ndim;
    t->count = 1;
    for (uint32_t k = 0; k < ndim; k++) {
        if (read_u32(fp, &d) || d == 0 || d > (1u << 24))
            return -1;
        t->dims[k] = d;
        t->count *= d;
    }
    if (t->count > ((size_t)1 << 26))
        return -1;
    t->data = rt_alloc(t->count, sizeof(float));
    for (size_t i = 0; i < t->count; i++) {
        uint32_t u;
        if (read_u32(fp, &u))
            return -1;
        memcpy(&t->data[i], &u, 4);
    }
    return 0;
}

static int load_file(const char *path, rt_file *f)
{
    memset(f, 0, sizeof *f);
    FILE *fp = fopen(path, "rb");
    if (!fp) {
        fprintf(stderr, "cannot open %s (run raster_reference.py first)\n", path);
        return -1;
    }
    char magic[8];
    uint32_t ver, ns, nt;
    int ok = fread(magic, 1, 8, fp) == 8 && memcmp(magic, "GSRASTRF", 8) == 0 &&
             !read_u32(fp, &ver) && !read_u32(fp, &ns) && !read_u32(fp, &nt) &&
             ver == 1 && ns >= 1 && ns < 100 && nt < 10000;
    if (ok) {
        f->version = (int)ver;
        f->nscenes = (int)ns;
        f->t = rt_alloc(nt, sizeof *f->t);
        for (uint32_t i = 0; ok && i < nt; i++) {
            ok = read_tensor(fp, &f->t[i]) == 0;
            f->ntensors = (int)i + 1;
        }
    }
    fclose(fp);
    if (!ok)
        fprintf(stderr, "%s: bad or truncated reference file\n", path);
    return ok ? 0 : -1;
}

static void free_file(rt_file *f)
{
    for (int i = 0; i < f->ntensors; i++)
        free(f->t[i].data);
    free(f->t);
}

/* Tensor s<scene>.<field>, or NULL (printing why) if absent or if its
 * element count is not count (count 0: any). */
static const rt_tensor *get(const rt_file *f, int scene, const char *field,
                            size_t count)
{
    char name[64];
    snprintf(name, sizeof name, "s%d.%s", scene, field);
    for (int i = 0; i < f->ntensors; i++) {
        if (strcmp(f->t[i].name, name) != 0)
            continue;
        if (count && f->t[i].count != count) {
            fprintf(stderr, "%s: %zu values, want %zu\n", name, f->t[i].count, count);
            return NULL;
        }
        return &f->t[i];
    }
    return NULL;
}

/* Data of a tensor that must exist (a failed check otherwise). */
static const float *need(const rt_file *f, int scene, const char *field, size_t count)
{
    const rt_tensor *t = get(f, scene, field, count);
    CHECK_MSG(t != NULL, "s%d.%s missing or misshaped in the reference file",
              scene, field);
    return t ? t->data : NULL;
}

/* Builds the scene (arrays borrowed from the file). */
static int scene_from_file(const rt_file *f, int k, rt_scene *s, rt_upstream *u)
{
    const rt_tensor *cam = get(f, k, "camera", 6), *vm = get(f, k, "viewmat", 12);
    const rt_tensor *opt = get(f, k, "options", 2), *m = get(f, k, "means", 0);
    const rt_tensor *ft = get(f, k, "features", 0);
    if (!cam || !vm || !opt || !m || !ft || m->ndim != 2 || ft->ndim != 2)
        return -1;
    int n = (int)m->dims[0], C = (int)ft->dims[1];
    int W = (int)cam->data[4], H = (int)cam->data[5];
    size_t np = (size_t)W * (size_t)H;
    memset(s, 0, sizeof *s);
    s->cam = (gs_camera){cam->data[0], cam->data[1], cam->data[2], cam->data[3], W, H, {0}};
    memcpy(s->cam.viewmat, vm->data, sizeof s->cam.viewmat);
    s->antialiased = opt->data[0] != 0.0f;
    const rt_tensor *ls = get(f, k, "log_scales", (size_t)n * 3);
    const rt_tensor *q = get(f, k, "quats", (size_t)n * 4);
    const rt_tensor *o = get(f, k, "opacity_logits", (size_t)n);
    const rt_tensor *vf = get(f, k, "v_features", np * C);
    const rt_tensor *va = get(f, k, "v_alpha", np), *vd = get(f, k, "v_depth", np);
    if (!ls || !q || !o || !vf || !va || !vd)
        return -1;
    s->g = (gs_gaussians){n, C, m->data, ls->data, q->data, o->data, ft->data};
    if (opt->data[1] != 0.0f) {
        const rt_tensor *bg = get(f, k, "background", np * C);
        if (!bg)
            return -1;
        s->background = bg->data;
    }
    *u = (rt_upstream){vf->data, va->data, vd->data};
    return 0;
}

static void check_scene(const rt_file *f, int k, gs_raster_path path, gs_pool *pool)
{
    rt_scene s;
    rt_upstream u;
    if (scene_from_file(f, k, &s, &u) != 0) {
        CHECK_MSG(0, "scene %d incomplete in the reference file", k);
        return;
    }
    int n = s.g.n, C = s.g.channels;
    size_t np = (size_t)s.cam.width * s.cam.height;
    printf("  scene %d, %s path: %dx%d C=%d N=%d%s%s\n", k, rt_path_name(path),
           s.cam.width, s.cam.height, C, n, s.antialiased ? " antialiased" : "",
           s.background ? " background" : "");
    rt_result o;
    rt_run(&s, path, pool, &u, &o);
    CHECK_EQ_INT(o.fwd_status, GS_OK);
    CHECK_EQ_INT(o.bwd_status, GS_OK);
    const float *rf = need(f, k, "out_features", np * C);
    const float *ra = need(f, k, "out_alpha", np), *rd = need(f, k, "out_depth", np);
    const float *st = need(f, k, "stats", 3);
    if (o.fwd_status == GS_OK && rf && ra && rd && st) {
        rt_compare_image("features", o.features, rf, np * C, 1e-5, 1e-5);
        rt_compare_image("alpha", o.alpha, ra, np, 1e-5, 1e-5);
        rt_compare_image("depth", o.depth, rd, np, 2e-5, 1e-5);
        printf("    stats: visible %d (ref %.0f), intersections %zu (ref %.0f), "
               "contributions %zu (ref %.0f)\n", o.stats.visible, st[0],
               o.stats.intersections, st[1], o.stats.contributions, st[2]);
        CHECK_EQ_INT(o.stats.contributions, (long long)st[2]);
        if (path == GS_RASTER_SCALAR) {
            CHECK_EQ_INT(o.stats.visible, (int)st[0]);
            CHECK_EQ_INT(o.stats.intersections, (long long)st[1]);
        } else {
            CHECK(o.stats.visible <= (int)st[0]);
            CHECK(o.stats.intersections <= (size_t)st[1]);
        }
    }
    if (o.bwd_status == GS_OK) {
        struct {
            const char *name;
            const float *got;
            size_t count;
        } g[] = {{"grad_means", o.g_means, (size_t)n * 3},
                 {"grad_log_scales", o.g_log_scales, (size_t)n * 3},
                 {"grad_quats", o.g_quats, (size_t)n * 4},
                 {"grad_opacity_logits", o.g_opacity, (size_t)n},
                 {"grad_features", o.g_features, (size_t)n * C},
                 {"grad_background", o.g_background, np * C}};
        for (size_t i = 0; i < sizeof g / sizeof g[0]; i++) {
            const rt_tensor *ref = get(f, k, g[i].name, g[i].count);
            if (!ref) {
                CHECK_MSG(i == 5 && !s.background, "%s missing", g[i].name);
                continue;
            }
            rt_compare_grad(g[i].name + 5, g[i].got, ref->data, g[i].count,
                            GRAD_ATOL, GRAD_RTOL, BAND, BAND_FRAC);
        }
    }
    rt_result_free(&o);
}

int main(int argc, char **argv)
{
    if (argc != 2) {
        fprintf(stderr, "usage: %s raster_reference.bin\n", argv[0]);
        return 2;
    }
    rt_file f;
    if (load_file(argv[1], &f) != 0)
        return 1;
    printf("reference file: version %d, %d scenes, %d tensors\n", f.version,
           f.nscenes, f.ntensors);
    CHECK(f.nscenes >= 4);
    gs_pool *pool = gs_pool_create(2);
    CHECK(pool != NULL);
    for (int k = 0; k < f.nscenes; k++) {
        check_scene(&f, k, GS_RASTER_SCALAR, NULL);
        check_scene(&f, k, GS_RASTER_FAST, pool);
    }
    gs_pool_destroy(pool);
    free_file(&f);
    GS_TEST_END();
}
