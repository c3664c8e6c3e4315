/* The synthesis readout (gs_eval_gaze_readout), at the eval's 256 px: on
 * a synthetic head it reads the gaze of the scene's own render, follows a
 * render at another gaze (whose lids sit elsewhere: they follow the
 * pitch), is unmoved by a whole-pixel shift of the image (and moved by it
 * without the alignment), moves little under a slight blur, gives the
 * same answer for any thread count, and refuses bad arguments and closed
 * eyes. With the softness search (soft_max_px) a render blurred by sigma
 * 2 px, which the plain readout reads degrees off, reads its own gaze and
 * about its blur, a blurred render at another gaze reads that gaze, and a
 * sharp render reads as sharp. */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "gazesplat/eval.h"
#include "gs_test.h"

#define S 256
#define DEG (3.14159265358979323846 / 180.0)

static void render(const gs_synth_scene *sc, double pitch, double yaw,
                   uint8_t *out)
{
    gs_synth_scene s = *sc;
    s.gaze_pitch = pitch;
    s.gaze_yaw = yaw;
    gs_synth_sample smp = {0};
    CHECK(gs_eval_render_scene(&s, S, 0, 0, NULL, &smp, NULL) == GS_OK);
    for (int y = 0; y < S; y++)
        memcpy(out + (size_t)y * 3 * S, smp.rgb + (size_t)y * smp.stride,
               3 * S);
    gs_synth_sample_free(&smp);
}

/* Gaussian blur of sigma px (radius 3 sigma, edges clamped), in to out. */
static void gauss(const uint8_t *in, uint8_t *out, double sigma)
{
    int R = (int)ceil(3 * sigma);
    float k[32], ks = 0;
    for (int d = -R; d <= R; d++)
        ks += k[d + R] = (float)exp(-0.5 * d * d / (sigma * sigma));
    float *a = malloc(sizeof *a * 6 * S * S), *b = a + 3 * S * S;
    CHECK(a != NULL);
    for (int pass = 0; pass < 2; pass++) {
        const float *src = pass ? b : a;
        float *dst = pass ? a : b;
        if (!pass)
            for (int i = 0; i < 3 * S * S; i++)
                a[i] = in[i];
        for (int y = 0; y < S; y++)
            for (int x = 0; x < S; x++)
                for (int c = 0; c < 3; c++) {
                    float acc = 0;
                    for (int d = -R; d <= R; d++) {
                        int q = (pass ? y : x) + d;
                        q = q < 0 ? 0 : q >= S ? S - 1 : q;
                        acc += k[d + R] *
                               src[3 * (pass ? q * S + x : y * S + q) + c];
                    }
                    dst[3 * (y * S + x) + c] = acc / ks;
                }
    }
    for (int i = 0; i < 3 * S * S; i++)
        out[i] = (uint8_t)(a[i] + 0.5f);
    free(a);
}

static double read_deg(const gs_synth_scene *sc, const uint8_t *img,
                       const gs_eval_readout_options *o, gs_pool *pool,
                       double pitch, double yaw, gs_eval_readout *rd)
{
    gs_error err = {0, ""};
    int rc = gs_eval_gaze_readout(sc, S, 0, 0, img, 3 * S, o, pool, rd, &err);
    CHECK_MSG(rc == GS_OK, "readout: %s", err.msg);
    return rc ? INFINITY : gs_eval_angle_deg(rd->pitch, rd->yaw, pitch, yaw);
}

int main(void)
{
    gs_synth_ranges rg;
    gs_eval_ranges(&rg);
    gs_synth_scene sc;
    gs_synth_scene_random(gs_synth_split_seed(GS_SYNTH_TEST, 2), 11, &rg, &sc);
    sc.expr.blink = 0;
    sc.expr.squint = 0;
    sc.gaze_pitch = -8 * DEG;
    sc.gaze_yaw = 17 * DEG;
    gs_pool *p2 = gs_pool_create(2);
    CHECK(p2 != NULL);
    uint8_t *img = malloc(3 * S * S), *alt = malloc(3 * S * S);
    CHECK(img && alt);
    render(&sc, sc.gaze_pitch, sc.gaze_yaw, img);

    /* Its own render: the scene's gaze, no shift, nearly no residual. */
    gs_eval_readout a, b;
    double e = read_deg(&sc, img, NULL, NULL, sc.gaze_pitch, sc.gaze_yaw, &a);
    CHECK_MSG(e < 0.15, "own render read %.3f deg off", e);
    CHECK(fabs(a.shift[0]) < 0.1 && fabs(a.shift[1]) < 0.1);
    CHECK_MSG(a.rms < 2.0, "own render: residual %.2f levels", a.rms);
    CHECK(a.pixels > 200 && a.renders > 99 + 5);

    /* Any thread count: the same reading. */
    read_deg(&sc, img, NULL, p2, sc.gaze_pitch, sc.gaze_yaw, &b);
    CHECK(a.pitch == b.pitch && a.yaw == b.yaw && a.rms == b.rms &&
          a.shift[0] == b.shift[0] && a.shift[1] == b.shift[1] &&
          a.renders == b.renders);

    /* Moved right by one pixel: the same gaze, the shift found. */
    for (int y = 0; y < S; y++) {
        uint8_t *r = alt + (size_t)y * 3 * S;
        memcpy(r + 3, img + (size_t)y * 3 * S, 3 * (S - 1));
        memcpy(r, r + 3, 3);
    }
    e = read_deg(&sc, alt, NULL, p2, sc.gaze_pitch, sc.gaze_yaw, &b);
    CHECK_MSG(e < 0.15, "shifted render read %.3f deg off", e);
    CHECK_MSG(fabs(b.shift[0] - 1) < 0.1 && fabs(b.shift[1]) < 0.1,
              "shift found (%.3f, %.3f), want (1, 0)", b.shift[0],
              b.shift[1]);
    /* Without the shift search the same image reads a gaze change. */
    gs_eval_readout_options o;
    gs_eval_readout_options_default(&o);
    o.max_shift_px = 0;
    e = read_deg(&sc, alt, &o, p2, sc.gaze_pitch, sc.gaze_yaw, &b);
    CHECK_MSG(e > 1.0, "no shift search: a 1 px shift read %.3f deg off", e);

    /* A render at another gaze (the scene's own stays as it was): that
     * gaze is read, 12 degrees from the scene's. */
    double p1 = sc.gaze_pitch + 6 * DEG, y1 = sc.gaze_yaw - 10 * DEG;
    render(&sc, p1, y1, alt);
    e = read_deg(&sc, alt, NULL, p2, p1, y1, &b);
    CHECK_MSG(e < 0.15, "another gaze read %.3f deg off", e);
    double moved = gs_eval_angle_deg(b.pitch, b.yaw, sc.gaze_pitch,
                                     sc.gaze_yaw);
    CHECK_MSG(fabs(moved - gs_eval_angle_deg(p1, y1, sc.gaze_pitch,
                                             sc.gaze_yaw)) < 0.2,
              "read %.2f deg from the scene's gaze", moved);

    /* A slight blur (3 x 3 binomial) moves the reading little. */
    for (int y = 0; y < S; y++)
        for (int x = 0; x < S; x++)
            for (int c = 0; c < 3; c++) {
                int acc = 0, w = 0;
                for (int dy = -1; dy <= 1; dy++)
                    for (int dx = -1; dx <= 1; dx++) {
                        int xx = x + dx < 0 ? 0 : x + dx >= S ? S - 1 : x + dx;
                        int yy = y + dy < 0 ? 0 : y + dy >= S ? S - 1 : y + dy;
                        int k = (2 - abs(dx)) * (2 - abs(dy));
                        acc += k * img[(size_t)yy * 3 * S + 3 * xx + c];
                        w += k;
                    }
                alt[(size_t)y * 3 * S + 3 * x + c] = (uint8_t)((acc + w / 2) / w);
            }
    e = read_deg(&sc, alt, NULL, p2, sc.gaze_pitch, sc.gaze_yaw, &b);
    CHECK_MSG(e < 1.0, "blurred render read %.3f deg off", e);

    /* The softness search. A sharp render reads as before, and as sharp
     * (the alignment's sub-pixel shift samples it bilinearly: a quarter
     * pixel at most). */
    gs_eval_readout_options so;
    gs_eval_readout_options_default(&so);
    so.soft_max_px = 2.5;
    e = read_deg(&sc, img, &so, p2, sc.gaze_pitch, sc.gaze_yaw, &b);
    CHECK_MSG(e < 0.15 && b.soft_px <= 0.25, "sharp, softness searched: %.3f "
              "deg off, softness %.2f px", e, b.soft_px);
    CHECK(a.soft_px == 0);
    /* Blurred by sigma 2 px: the plain readout is drawn off (0.76 degree
     * here, 4 on average: bench_readout), the softness search reads the
     * gaze and about the blur, for any thread count. */
    gauss(img, alt, 2.0);
    double plain = read_deg(&sc, alt, NULL, p2, sc.gaze_pitch, sc.gaze_yaw,
                            &b);
    e = read_deg(&sc, alt, &so, p2, sc.gaze_pitch, sc.gaze_yaw, &b);
    CHECK_MSG(plain > 0.5 && e < 0.2 && e < plain / 3,
              "blur 2 px read %.3f deg off plain, %.3f searching softness",
              plain, e);
    CHECK_MSG(fabs(b.soft_px - 2.0) <= 0.5, "softness read %.2f px, blur 2",
              b.soft_px);
    gs_eval_readout c1;
    read_deg(&sc, alt, &so, NULL, sc.gaze_pitch, sc.gaze_yaw, &c1);
    CHECK(c1.pitch == b.pitch && c1.yaw == b.yaw && c1.rms == b.rms &&
          c1.soft_px == b.soft_px && c1.renders == b.renders);
    /* A render at another gaze, blurred by 1.5 px: that gaze. */
    render(&sc, p1, y1, img);
    gauss(img, alt, 1.5);
    e = read_deg(&sc, alt, &so, p2, p1, y1, &b);
    CHECK_MSG(e < 0.5, "another gaze, blurred, read %.3f deg off", e);

    /* Bad arguments: a clear error, nothing written. */
    static const double bad[][6] = {
        /* shift, grid, tol, pitch range, yaw range, blur */
        {-1, 10, 0.05, 40, 50, 1}, {9, 10, 0.05, 40, 50, 1},
        {2, 0.5, 0.05, 40, 50, 1}, {2, 10, 0, 40, 50, 1},
        {2, 10, 11, 40, 50, 1},    {2, 10, 0.05, 81, 50, 1},
        {2, 10, 0.05, 40, NAN, 1}, {2, 10, 0.05, 40, 50, -0.5},
        {2, 10, 0.05, 40, 50, 3.5}};
    for (size_t k = 0; k < sizeof bad / sizeof bad[0]; k++) {
        gs_eval_readout_options q = {bad[k][0], bad[k][1], bad[k][2],
                                     bad[k][3], bad[k][4], bad[k][5], 0};
        gs_error err = {0, ""};
        memset(&b, 0x5a, sizeof b);
        CHECK(gs_eval_gaze_readout(&sc, S, 0, 0, img, 3 * S, &q, NULL, &b,
                                   &err) == GS_ERR_ARG);
        CHECK(strstr(err.msg, "options") != NULL);
        CHECK(((const uint8_t *)&b)[0] == 0x5a);
    }
    static const double bad_soft[][2] = {/* blur, softness */
        {1, -0.25}, {1, 2.75}, {1, NAN}, {2.5, 2}};
    for (size_t k = 0; k < sizeof bad_soft / sizeof bad_soft[0]; k++) {
        gs_eval_readout_options q = so;
        q.blur_px = bad_soft[k][0];
        q.soft_max_px = bad_soft[k][1];
        gs_error err = {0, ""};
        CHECK(gs_eval_gaze_readout(&sc, S, 0, 0, img, 3 * S, &q, NULL, &b,
                                   &err) == GS_ERR_ARG);
        CHECK(strstr(err.msg, "options") != NULL);
    }
    gs_error err = {0, ""};
    CHECK(gs_eval_gaze_readout(&sc, S, 0, 0, img, 3 * S - 1, NULL, NULL, &b,
                               &err) == GS_ERR_ARG);
    /* Closed eyes: nothing to read. */
    gs_synth_scene shut = sc;
    shut.expr.blink = 1;
    CHECK(gs_eval_gaze_readout(&shut, S, 0, 0, img, 3 * S, NULL, NULL, &b,
                               &err) == GS_ERR_ARG);
    CHECK(strstr(err.msg, "closed eyes") != NULL);
    CHECK(gs_eval_gaze_readout(&sc, S, 0, 0, NULL, 3 * S, NULL, NULL, &b,
                               &err) == GS_ERR_ARG);
    free(img);
    free(alt);
    gs_pool_destroy(p2);
    GS_TEST_END();
}
