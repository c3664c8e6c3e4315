/* .ply reader and writer: byte-exact round trips of every layout, the
 * reference 3DGS layout, any property order with extra properties, and one
 * case per refusal (code and message). */
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "gazesplat/ply.h"
#include "gs_test.h"

typedef struct bytes {
    unsigned char *p;
    size_t n;
} bytes;

/* A header followed by nbytes of data, every float of it 0.5. */
static bytes make_file(const char *head, size_t nbytes)
{
    size_t hl = strlen(head);
    bytes b = {malloc(hl + nbytes + 1), hl + nbytes};
    float half = 0.5f;
    memcpy(b.p, head, hl);
    for (size_t i = 0; i < nbytes; i++)
        b.p[hl + i] = ((const unsigned char *)&half)[i % 4];
    return b;
}

static void fill_scene(gs_ply_scene *s, float seed)
{
    float *arrays[] = {s->means, s->normals, s->log_scales, s->quats, s->opacity_logits,
                       s->f_dc, s->f_rest, s->features};
    size_t widths[] = {3, 3, 3, 4, 1, 3, (size_t)s->n_rest, (size_t)s->channels};
    size_t last = s->kind == GS_PLY_SH ? 7 : 8; /* SH features come from f_dc */
    for (size_t a = 0; a < last; a++) {
        if (!arrays[a] && a != 6)
            continue;
        if (arrays[a])
            for (size_t i = 0; i < widths[a] * (size_t)s->n; i++)
                arrays[a][i] = seed + (float)a * 10.0f + (float)i * 0.37f - (float)(i % 7);
    }
    gs_ply_features_from_sh(s);
}

static void check_same_scene(const gs_ply_scene *a, const gs_ply_scene *b)
{
    CHECK(a->kind == b->kind && a->n == b->n && a->channels == b->channels);
    CHECK(a->sh_degree == b->sh_degree && a->n_rest == b->n_rest);
    CHECK((a->normals == NULL) == (b->normals == NULL));
    size_t n = (size_t)a->n;
    CHECK(memcmp(a->means, b->means, 12 * n) == 0);
    CHECK(memcmp(a->log_scales, b->log_scales, 12 * n) == 0);
    CHECK(memcmp(a->quats, b->quats, 16 * n) == 0);
    CHECK(memcmp(a->opacity_logits, b->opacity_logits, 4 * n) == 0);
    CHECK(memcmp(a->features, b->features, 4 * n * (size_t)a->channels) == 0);
    if (a->normals && b->normals)
        CHECK(memcmp(a->normals, b->normals, 12 * n) == 0);
    if (a->kind == GS_PLY_SH && a->f_dc && b->f_dc)
        CHECK(memcmp(a->f_dc, b->f_dc, 12 * n) == 0);
    if (a->n_rest && a->f_rest && b->f_rest)
        CHECK(memcmp(a->f_rest, b->f_rest, 4 * n * (size_t)a->n_rest) == 0);
}

/* encode -> parse -> same scene -> encode -> same bytes; file too. */
static void round_trip(const gs_ply_scene *s)
{
    void *buf, *buf2;
    size_t len, len2;
    gs_ply_scene r, f;
    gs_error err = {0};
    CHECK_EQ_INT(gs_ply_encode(s, &buf, &len, &err), GS_OK);
    int rc = gs_ply_parse(buf, len, NULL, &r, &err);
    CHECK_MSG(rc == GS_OK, "parse: %s", err.msg);
    if (rc)
        return;
    check_same_scene(s, &r);
    CHECK_EQ_INT(gs_ply_encode(&r, &buf2, &len2, &err), GS_OK);
    CHECK(len == len2 && memcmp(buf, buf2, len) == 0);
    const char *path = "test_ply_tmp.ply";
    CHECK_EQ_INT(gs_ply_write(path, &r, &err), GS_OK);
    CHECK_EQ_INT(gs_ply_read(path, NULL, &f, &err), GS_OK);
    check_same_scene(s, &f);
    FILE *fp = fopen(path, "rb");
    unsigned char *disk = malloc(len + 1);
    size_t got = fp ? fread(disk, 1, len + 1, fp) : 0;
    CHECK(got == len && memcmp(disk, buf, len) == 0);
    if (fp)
        fclose(fp);
    remove(path);
    free(disk);
    free(buf);
    free(buf2);
    gs_ply_free(&r);
    gs_ply_free(&f);
}

static void test_round_trips(void)
{
    gs_ply_scene s;
    for (int deg = 0; deg <= 3; deg++) {
        for (int normals = 0; normals <= 1; normals++) {
            CHECK_EQ_INT(gs_ply_alloc_sh(&s, 5 + deg, deg, normals, NULL), GS_OK);
            CHECK_EQ_INT(s.n_rest, deg == 0 ? 0 : deg == 1 ? 9 : deg == 2 ? 24 : 45);
            fill_scene(&s, (float)deg);
            round_trip(&s);
            gs_ply_free(&s);
        }
    }
    static const int channels[] = {1, 3, 32, GS_RASTER_MAX_CHANNELS};
    for (size_t i = 0; i < 4; i++) {
        CHECK_EQ_INT(gs_ply_alloc_features(&s, 4, channels[i], (int)i % 2, NULL), GS_OK);
        fill_scene(&s, 1.5f);
        round_trip(&s);
        gs_ply_free(&s);
    }
    CHECK_EQ_INT(gs_ply_alloc_sh(&s, 0, 0, 0, NULL), GS_OK);
    round_trip(&s);
    gs_ply_free(&s);
    gs_error err = {0};
    CHECK_EQ_INT(gs_ply_alloc_sh(&s, 1, 4, 0, &err), GS_ERR_ARG);
    CHECK_EQ_INT(gs_ply_alloc_features(&s, 1, GS_RASTER_MAX_CHANNELS + 1, 0, &err), GS_ERR_ARG);
    CHECK_EQ_INT(gs_ply_alloc_features(&s, -1, 3, 0, &err), GS_ERR_ARG);
}

/* The layout the reference 3DGS code writes, header typed out by hand. */
static void test_reference_layout(void)
{
    char head[4096];
    size_t k = (size_t)snprintf(head, sizeof head,
                                "ply\nformat binary_little_endian 1.0\nelement vertex 2\n"
                                "property float x\nproperty float y\nproperty float z\n"
                                "property float nx\nproperty float ny\nproperty float nz\n"
                                "property float f_dc_0\nproperty float f_dc_1\nproperty float f_dc_2\n");
    for (int i = 0; i < 45; i++)
        k += (size_t)snprintf(head + k, sizeof head - k, "property float f_rest_%d\n", i);
    snprintf(head + k, sizeof head - k,
             "property float opacity\nproperty float scale_0\nproperty float scale_1\n"
             "property float scale_2\nproperty float rot_0\nproperty float rot_1\n"
             "property float rot_2\nproperty float rot_3\nend_header\n");
    float rec[2][62];
    for (int v = 0; v < 2; v++)
        for (int i = 0; i < 62; i++)
            rec[v][i] = (float)(v * 100 + i) * 0.01f - 0.3f;
    size_t hl = strlen(head);
    unsigned char *file = malloc(hl + sizeof rec);
    memcpy(file, head, hl);
    memcpy(file + hl, rec, sizeof rec);
    gs_ply_scene s;
    gs_error err = {0};
    CHECK_EQ_INT(gs_ply_parse(file, hl + sizeof rec, NULL, &s, &err), GS_OK);
    CHECK(s.kind == GS_PLY_SH && s.n == 2 && s.channels == 3 && s.sh_degree == 3 && s.normals);
    CHECK(s.means[3] == rec[1][0] && s.means[5] == rec[1][2]);
    CHECK(s.normals[4] == rec[1][4]);
    CHECK(s.f_dc[4] == rec[1][7] && s.f_rest[45 + 44] == rec[1][53]);
    CHECK(s.opacity_logits[1] == rec[1][54]);
    CHECK(s.log_scales[5] == rec[1][57] && s.quats[4] == rec[1][58] && s.quats[7] == rec[1][61]);
    CHECK_CLOSE(s.features[5], 0.28209479177387814 * rec[1][8] + 0.5, 1e-7, 0);
    gs_gaussians g;
    gs_ply_gaussians(&s, &g);
    CHECK(g.n == 2 && g.channels == 3 && g.means == s.means && g.features == s.features &&
          g.quats == s.quats && g.log_scales == s.log_scales &&
          g.opacity_logits == s.opacity_logits);
    void *out;
    size_t len;
    CHECK_EQ_INT(gs_ply_encode(&s, &out, &len, &err), GS_OK);
    CHECK_MSG(len == hl + sizeof rec && memcmp(out, file, len) == 0,
              "re-encoded reference file differs (%zu vs %zu bytes)", len, hl + sizeof rec);
    free(out);
    gs_ply_free(&s);
    free(file);
}

static void put_f(unsigned char **p, float f)
{
    memcpy(*p, &f, 4);
    *p += 4;
}

/* Properties in another order, unknown ones of several types, comments,
 * CRLF lines. */
static void test_any_order(void)
{
    const char *head = "ply\r\nformat binary_little_endian 1.0\r\ncomment made by hand\r\n"
                       "obj_info anything\r\nelement vertex 2\r\n"
                       "property float rot_3\r\nproperty float rot_2\r\nproperty float rot_1\r\n"
                       "property float rot_0\r\nproperty uchar red\r\nproperty float opacity\r\n"
                       "property double extra\r\nproperty float scale_2\r\nproperty float scale_1\r\n"
                       "property float scale_0\r\nproperty float feat_1\r\nproperty float feat_0\r\n"
                       "property int16 s\r\nproperty float z\r\nproperty float y\r\n"
                       "property float32 x\r\nproperty float foo\r\nend_header\r\n";
    /* record: 14 floats (56 bytes) + uchar + int16 + double = 67 bytes */
    unsigned char rec[2][67];
    for (int v = 0; v < 2; v++) {
        unsigned char *p = rec[v];
        double d = NAN; /* unknown properties are not checked */
        for (int i = 0; i < 4; i++)
            put_f(&p, (float)(v * 10 + 3 - i)); /* rot_3..rot_0 */
        *p++ = 200;                                        /* red */
        put_f(&p, (float)v - 2.0f);              /* opacity */
        memcpy(p, &d, 8);
        p += 8;
        for (int i = 0; i < 3; i++)
            put_f(&p, (float)(v * 10 + 6 - i)); /* scale_2..0 */
        for (int i = 0; i < 2; i++)
            put_f(&p, (float)(v * 10 + 8 - i)); /* feat_1, feat_0 */
        *p++ = 1, *p++ = 2;                                /* s */
        for (int i = 0; i < 3; i++)
            put_f(&p, (float)(v * 10 + 12 - i)); /* z, y, x */
        put_f(&p, INFINITY);                     /* foo */
    }
    size_t hl = strlen(head);
    unsigned char *file = malloc(hl + sizeof rec);
    memcpy(file, head, hl);
    memcpy(file + hl, rec, sizeof rec);
    gs_ply_scene s;
    gs_error err = {0};
    int rc = gs_ply_parse(file, hl + sizeof rec, NULL, &s, &err);
    CHECK_MSG(rc == GS_OK, "rc %d: %s", rc, err.msg);
    if (rc == GS_OK) {
        CHECK(s.kind == GS_PLY_FEATURES && s.channels == 2 && s.sh_degree == -1 && !s.f_dc);
        CHECK(!s.normals);
        float want_means[6] = {10, 11, 12, 20, 21, 22}, want_q[8] = {0, 1, 2, 3, 10, 11, 12, 13};
        float want_s[6] = {4, 5, 6, 14, 15, 16}, want_f[4] = {7, 8, 17, 18}, want_o[2] = {-2, -1};
        gs_check_arrays("means", s.means, want_means, 6, 0, 0);
        gs_check_arrays("quats", s.quats, want_q, 8, 0, 0);
        gs_check_arrays("log_scales", s.log_scales, want_s, 6, 0, 0);
        gs_check_arrays("features", s.features, want_f, 4, 0, 0);
        gs_check_arrays("opacity", s.opacity_logits, want_o, 2, 0, 0);
        gs_ply_free(&s);
    }
    free(file);
}

#define FMT "format binary_little_endian 1.0\n"
#define XYZ "property float x\nproperty float y\nproperty float z\n"
#define DC "property float f_dc_0\nproperty float f_dc_1\nproperty float f_dc_2\n"
#define OPA "property float opacity\n"
#define SCL "property float scale_0\nproperty float scale_1\nproperty float scale_2\n"
#define ROT "property float rot_0\nproperty float rot_1\nproperty float rot_2\nproperty float rot_3\n"
#define STD XYZ DC OPA SCL ROT /* 14 floats, 56 bytes */
#define V2 "ply\n" FMT "element vertex 2\n"
#define END "end_header\n"

static void test_refusals(void)
{
    static const struct {
        const char *head;
        size_t data;
        int code;
        const char *msg;
    } cases[] = {
        {V2 STD END, 112, GS_OK, ""},
        {V2 STD END, 111, GS_ERR_FORMAT, "truncated: 2 vertices of 56 bytes need 112 bytes, 111"},
        {V2 STD END, 113, GS_ERR_FORMAT, "1 bytes after the vertex data"},
        {V2 STD END, 0, GS_ERR_FORMAT, "truncated"},
        {"ply\n" FMT "element vertex 4000000000\n" STD END, 112, GS_ERR_LIMIT,
         "vertex count '4000000000' over the limit 10000000"},
        {"ply\n" FMT "element vertex 99999999999999999999999999\n" STD END, 112, GS_ERR_LIMIT,
         "over the limit"},
        {"ply\n" FMT "element vertex 1000\n" STD END, 112, GS_ERR_FORMAT,
         "truncated: 1000 vertices"},
        {"ply\nformat ascii 1.0\nelement vertex 2\n" STD END, 112, GS_ERR_UNSUPPORTED,
         "format 'ascii' not supported"},
        {"ply\nformat binary_big_endian 1.0\nelement vertex 2\n" STD END, 112, GS_ERR_UNSUPPORTED,
         "binary_big_endian"},
        {"ply\nformat binary_little_endian 2.0\nelement vertex 2\n" STD END, 112,
         GS_ERR_UNSUPPORTED, "version"},
        {"ply\nformat binary_middle_endian 1.0\nelement vertex 2\n" STD END, 112, GS_ERR_FORMAT,
         "unknown format"},
        {V2 XYZ DC "property double opacity\n" SCL ROT END, 120, GS_ERR_FORMAT,
         "'opacity' has type double, expected float"},
        {V2 "property uchar x\nproperty float y\nproperty float z\n" DC OPA SCL ROT END, 106,
         GS_ERR_FORMAT, "'x' has type uchar"},
        {V2 XYZ DC SCL ROT END, 104, GS_ERR_FORMAT, "missing property 'opacity'"},
        {V2 XYZ DC OPA SCL "property float rot_0\nproperty float rot_1\nproperty float rot_3\n" END,
         104, GS_ERR_FORMAT, "missing property 'rot_2'"},
        {V2 XYZ OPA SCL ROT END, 88, GS_ERR_FORMAT, "missing property 'f_dc_0' (or 'feat_0')"},
        {V2 XYZ "property float f_dc_0\nproperty float f_dc_2\n" OPA SCL ROT END, 104,
         GS_ERR_FORMAT, "missing property 'f_dc_1'"},
        {V2 STD "property float f_rest_0\nproperty float f_rest_1\nproperty float f_rest_2\n" END,
         136, GS_ERR_FORMAT, "3 f_rest properties (0, 9, 24 or 45 expected)"},
        {V2 STD "property float f_rest_1\n" END, 120, GS_ERR_FORMAT,
         "missing property 'f_rest_0'"},
        {V2 STD "property float f_rest_45\n" END, 120, GS_ERR_UNSUPPORTED, "'f_rest_45' out of range"},
        {V2 XYZ "property float feat_0\nproperty float feat_2\n" OPA SCL ROT END, 104,
         GS_ERR_FORMAT, "missing property 'feat_1'"},
        {V2 XYZ "property float feat_64\n" OPA SCL ROT END, 100, GS_ERR_UNSUPPORTED,
         "'feat_64' out of range"},
        {V2 STD "property float feat_0\n" END, 120, GS_ERR_FORMAT, "both feat_*"},
        {V2 STD "property float f_dc_3\n" END, 120, GS_ERR_FORMAT, "'f_dc_3' out of range"},
        {V2 STD "property list uchar int vertex_indices\n" END, 112, GS_ERR_UNSUPPORTED, "list"},
        {V2 STD "element face 0\n" END, 112, GS_ERR_UNSUPPORTED, "element 'face' not supported"},
        {"ply\n" FMT "element face 2\n" STD END, 112, GS_ERR_UNSUPPORTED, "element 'face'"},
        {"plx\n" FMT "element vertex 2\n" STD END, 112, GS_ERR_FORMAT, "not a PLY file"},
        {"ply extra\n" FMT "element vertex 2\n" STD END, 112, GS_ERR_FORMAT, "not a PLY file"},
        {V2 STD "property float x\n" END, 116, GS_ERR_FORMAT, "property 'x' twice"},
        {"ply\n" FMT STD "element vertex 2\n" END, 112, GS_ERR_FORMAT, "property before element"},
        {"ply\nelement vertex 2\n" FMT STD END, 112, GS_ERR_FORMAT, "bad element line"},
        {"ply\n" FMT FMT "element vertex 2\n" STD END, 112, GS_ERR_FORMAT, "repeated format"},
        {"ply\n" FMT "element vertex 12a\n" STD END, 112, GS_ERR_FORMAT, "bad vertex count '12a'"},
        {"ply\n" FMT "element vertex -2\n" STD END, 112, GS_ERR_FORMAT, "bad vertex count"},
        {"ply\n" FMT "element vertex\n" STD END, 112, GS_ERR_FORMAT, "bad element line"},
        {V2 STD "property half h\n" END, 114, GS_ERR_FORMAT, "unknown property type 'half'"},
        {V2 STD "property float a b\n" END, 116, GS_ERR_FORMAT, "bad property line"},
        {V2 STD "comment a\x01 b\n" END, 112, GS_ERR_FORMAT, "control character"},
        {V2 STD "hello world\n" END, 112, GS_ERR_FORMAT, "unknown header line"},
        {V2 STD "\n" END, 112, GS_ERR_FORMAT, "empty header line"},
        {V2 STD, 112, GS_ERR_FORMAT, "truncated header"},
        {"ply\n" FMT END, 0, GS_ERR_FORMAT, "no vertex element"},
        {V2 STD "property float nx\n" END, 120, GS_ERR_FORMAT, "missing property 'ny'"},
        {V2 STD "property float nz\n" END, 120, GS_ERR_FORMAT, "missing property 'nx'"},
        /* Look-alike names are just unknown properties. */
        {V2 STD "property float scale_01\nproperty float feat_x\nproperty float rot_\n" END, 136,
         GS_OK, ""},
        {"ply\n" FMT "element vertex 0\n" STD END, 0, GS_OK, ""},
        {"ply\r\n" FMT "element vertex 2\r\n" STD "end_header\r\n", 112, GS_OK, ""},
        {"ply\n" FMT "element  vertex\t2\n" STD END, 112, GS_OK, ""},
    };
    for (size_t i = 0; i < sizeof cases / sizeof cases[0]; i++) {
        bytes b = make_file(cases[i].head, cases[i].data);
        gs_ply_scene s;
        gs_error err = {0};
        int rc = gs_ply_parse(b.p, b.n, NULL, &s, &err);
        CHECK_MSG(rc == cases[i].code, "case %zu: rc %d (%s), want %d", i, rc, err.msg,
                  cases[i].code);
        CHECK_MSG(strstr(err.msg, cases[i].msg) != NULL, "case %zu: message '%s' lacks '%s'", i,
                  err.msg, cases[i].msg);
        if (rc == GS_OK)
            gs_ply_free(&s);
        free(b.p);
    }
}

static void test_limits(void)
{
    gs_ply_scene s;
    gs_error err = {0};
    gs_ply_options opt = {1, 0};
    bytes b = make_file(V2 STD END, 112);
    CHECK_EQ_INT(gs_ply_parse(b.p, b.n, &opt, &s, &err), GS_ERR_LIMIT);
    CHECK(strstr(err.msg, "over the limit 1") != NULL);
    opt.max_vertices = -1;
    CHECK_EQ_INT(gs_ply_parse(b.p, b.n, &opt, &s, &err), GS_ERR_ARG);
    free(b.p);
    /* A header over GS_PLY_MAX_HEADER bytes. */
    size_t big = GS_PLY_MAX_HEADER + 100;
    char *head = malloc(big + 1024);
    size_t k = (size_t)sprintf(head, V2);
    while (k < big)
        k += (size_t)sprintf(head + k, "comment padding padding padding padding\n");
    sprintf(head + k, STD END);
    b = make_file(head, 112);
    CHECK_EQ_INT(gs_ply_parse(b.p, b.n, NULL, &s, &err), GS_ERR_LIMIT);
    CHECK(strstr(err.msg, "no end_header in the first 65536 bytes") != NULL);
    free(b.p);
    /* More properties than GS_PLY_MAX_PROPERTIES. */
    k = (size_t)sprintf(head, V2 STD);
    for (int i = 0; i < GS_PLY_MAX_PROPERTIES; i++)
        k += (size_t)sprintf(head + k, "property uchar u%d\n", i);
    sprintf(head + k, END);
    b = make_file(head, 2 * (56 + GS_PLY_MAX_PROPERTIES));
    CHECK_EQ_INT(gs_ply_parse(b.p, b.n, NULL, &s, &err), GS_ERR_LIMIT);
    CHECK(strstr(err.msg, "more than 256 properties") != NULL);
    free(b.p);
    free(head);
    CHECK_EQ_INT(gs_ply_read("no/such/file.ply", NULL, &s, &err), GS_ERR_IO);
    CHECK(strstr(err.msg, "cannot open no/such/file.ply") != NULL);
    CHECK_EQ_INT(gs_ply_read(".", NULL, &s, &err), GS_ERR_IO);
}

static void test_nonfinite(void)
{
    gs_ply_scene s;
    gs_error err = {0};
    gs_ply_options allow = {0, 1};
    bytes b = make_file(V2 STD END, 112);
    float nan = NAN, inf = -INFINITY;
    /* vertex 1, opacity is the 7th float */
    memcpy(b.p + b.n - 56 + 6 * 4, &nan, 4);
    CHECK_EQ_INT(gs_ply_parse(b.p, b.n, NULL, &s, &err), GS_ERR_NONFINITE);
    CHECK_MSG(strstr(err.msg, "vertex 1: 'opacity' is NaN") != NULL, "message '%s'", err.msg);
    CHECK_EQ_INT(gs_ply_parse(b.p, b.n, &allow, &s, &err), GS_OK);
    CHECK(isnan(s.opacity_logits[1]));
    gs_ply_free(&s);
    memcpy(b.p + b.n - 112, &inf, 4);
    CHECK_EQ_INT(gs_ply_parse(b.p, b.n, NULL, &s, &err), GS_ERR_NONFINITE);
    CHECK_MSG(strstr(err.msg, "vertex 0: 'x' is infinite") != NULL, "message '%s'", err.msg);
    /* The file reader applies the same checks. */
    const char *path = "test_ply_nonfinite.ply";
    FILE *f = fopen(path, "wb");
    CHECK(f && fwrite(b.p, 1, b.n, f) == b.n);
    if (f)
        fclose(f);
    CHECK_EQ_INT(gs_ply_read(path, NULL, &s, &err), GS_ERR_NONFINITE);
    CHECK_EQ_INT(gs_ply_read(path, &allow, &s, &err), GS_OK);
    CHECK(isinf(s.means[0]) && isnan(s.opacity_logits[1]));
    gs_ply_free(&s);
    remove(path);
    free(b.p);
}

/* Every prefix is refused; every single-byte change is handled (run under
 * ASan this is a small deterministic fuzz). */
static void test_damage(void)
{
    gs_ply_scene s;
    gs_error err = {0};
    bytes b = make_file(V2 STD END, 112);
    for (size_t n = 0; n < b.n; n++) {
        int rc = gs_ply_parse(b.p, n, NULL, &s, &err);
        CHECK_MSG(rc == GS_ERR_FORMAT, "prefix %zu: rc %d (%s)", n, rc, err.msg);
    }
    static const unsigned char flips[] = {0x01, 0x20, 0x7f, 0x80, 0xff};
    int ok = 0;
    for (size_t i = 0; i < b.n; i++) {
        for (size_t f = 0; f < sizeof flips; f++) {
            b.p[i] ^= flips[f];
            if (gs_ply_parse(b.p, b.n, NULL, &s, &err) == GS_OK) {
                ok++;
                gs_ply_free(&s);
            }
            b.p[i] ^= flips[f];
        }
    }
    CHECK(ok > 0);
    free(b.p);
}

int main(void)
{
    test_round_trips();
    test_reference_layout();
    test_any_order();
    test_refusals();
    test_limits();
    test_nonfinite();
    test_damage();
    GS_TEST_END();
}
