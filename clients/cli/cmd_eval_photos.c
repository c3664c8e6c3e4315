/* gazesplat eval-photos: the real-photo report (docs/photos/report.md).
 * Every face of the given photos through the gate, then, for those it
 * passes, the served fit and a 5 x 5 gaze grid in two modes (the model's
 * render, detail transfer), each image measured against the input by
 * gs_face_quality_measure: the gaze its irises show against the gaze asked
 * for (gain and cross-talk by least squares, sign agreement), the iris
 * colour (CIELAB delta E), the eye regions' speckle, and whether the face
 * detector still finds the face. */
#define _POSIX_C_SOURCE 200809L
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "cli.h"
#include "gazesplat/redirect.h"
#include "gazesplat/face.h"
#include "gazesplat/geom.h"
#include "gazesplat/model.h"
#include "gazesplat/pool.h"

#define DEG (3.14159265358979323846 / 180.0)
#define NT 25

static const double grid_pitch[5] = {20, 10, 0, -10, -20};
static const double grid_yaw[5] = {25, 15, 0, -15, -25};

static int run_eval_photos(const cli_command *cmd, cli_opt *o);

static const cli_opt eval_photos_opts[] = {
    {"--model", 1, NULL}, {"--photos", 1, NULL}, {"--out-json", 1, NULL}, {"--iters", 1, NULL},
    {"--finetune", 1, NULL}, {"--no-gate", 0, NULL}};

const cli_command cli_eval_photos_command = {
    "eval-photos",
    "report how redirected real faces look and carry their gaze (gate, gain, colour, speckle)",
    "usage: gazesplat eval-photos --model M --photos FILE[,FILE...] [--out-json FILE]\n"
    "                             [--iters N] [--finetune N] [--no-gate]\n"
    "\n"
    "  --photos LIST    photos (PNG/JPEG), comma-separated; every face the\n"
    "                   detector finds in each is one row\n"
    "  --model M        the model (the served setting: the fit to its plateau,\n"
    "                   at most --iters N (200), --finetune N steps (15) at\n"
    "                   0.004 with the mirrored view)\n"
    "  --no-gate        also measure the faces the gate refuses\n"
    "  --out-json FILE  every face's and image's measures as JSON\n"
    "\n"
    "Targets: head-frame gaze changes of pitch +20..-20 by yaw +25..-25 from\n"
    "the fitted gaze of the face (25 images), in two modes: plain (the\n"
    "model's render) and transfer (detail transfer with the eyeball warp),\n"
    "measured on the normalized face. Prints one markdown row per face and\n"
    "mode: fit time, the gate, gain (measured over commanded change, least\n"
    "squares) and cross-talk per axis, sign agreement for changes of 10 deg\n"
    "and more, iris delta E, speckle over the input's, the share of images\n"
    "the detector still finds a face in, and the mean and lowest quality\n"
    "score (docs/face.md, \"Redirect quality\").\n",
    .opts = eval_photos_opts,
    .nopts = CLI_NOPTS(eval_photos_opts),
    .run_opts = run_eval_photos,
};

typedef struct mode_stats {
    int n;              /* images with both irises measured (at least one eye) */
    double gain[2], cross[2]; /* gain pitch, yaw; cross: pitch from yaw, yaw from pitch */
    double sign;        /* fraction agreeing, over components >= 10 deg */
    double delta_e, artifact, detected, score_mean, score_min;
} mode_stats;

/* Least squares of y on [a, b, 1] over n points: coefficients of a and b. */
static void fit2(const double *a, const double *b, const double *y, int n, double *ca, double *cb)
{
    double m[3][4] = {{0}};
    for (int i = 0; i < n; i++) {
        double x[3] = {a[i], b[i], 1};
        for (int r = 0; r < 3; r++) {
            for (int c = 0; c < 3; c++)
                m[r][c] += x[r] * x[c];
            m[r][3] += x[r] * y[i];
        }
    }
    for (int c = 0; c < 3; c++) { /* Gauss-Jordan, partial pivoting */
        int p = c;
        for (int r = c + 1; r < 3; r++)
            if (fabs(m[r][c]) > fabs(m[p][c]))
                p = r;
        for (int k = 0; k < 4; k++) {
            double t = m[c][k];
            m[c][k] = m[p][k];
            m[p][k] = t;
        }
        if (fabs(m[c][c]) < 1e-12) {
            *ca = *cb = NAN;
            return;
        }
        for (int r = 0; r < 3; r++)
            if (r != c) {
                double f = m[r][c] / m[c][c];
                for (int k = c; k < 4; k++)
                    m[r][k] -= f * m[c][k];
            }
    }
    *ca = m[0][3] / m[0][0];
    *cb = m[1][3] / m[1][1];
}

typedef struct face_eval {
    const char *photo;
    int index;
    gs_face_gate gate;
    double fit_s, ft_s, fit_psnr;
    int evaluated;
    mode_stats mode[2];
    gs_face_quality q[2][NT];
} face_eval;

static int detect_any(gs_face_detector *det, const uint8_t *rgb, int S)
{
    gs_io_image im = {S, S, 3 * (size_t)S, (uint8_t *)rgb};
    gs_face_detect_opts o;
    gs_face_detect_opts_default(&o);
    o.min_size = S / 4;
    gs_face_detection d[4];
    int n = 0;
    return gs_face_detect(det, &im, &o, d, 4, &n, NULL) == GS_OK && n > 0;
}

static void stats_of(const gs_face_quality *q, const int *det, mode_stats *m)
{
    double cp[NT], cy[NT], mp[NT], my[NT];
    int n = 0, agree = 0, asked = 0;
    double de = 0, art = 0, sc = 0, smin = 1, dets = 0;
    for (int t = 0; t < NT; t++) {
        art += q[t].artifact;
        sc += q[t].score;
        smin = fmin(smin, q[t].score);
        dets += det[t];
        if (!q[t].eyes)
            continue;
        cp[n] = q[t].commanded[0] / DEG;
        cy[n] = q[t].commanded[1] / DEG;
        mp[n] = q[t].measured[0] / DEG;
        my[n] = q[t].measured[1] / DEG;
        de += q[t].delta_e;
        for (int a = 0; a < 2; a++) {
            double c = a ? cy[n] : cp[n], v = a ? my[n] : mp[n];
            if (fabs(c) >= 10) {
                asked++;
                agree += (c > 0) == (v > 0);
            }
        }
        n++;
    }
    memset(m, 0, sizeof *m);
    m->n = n;
    m->artifact = art / NT;
    m->score_mean = sc / NT;
    m->score_min = smin;
    m->detected = dets / NT;
    m->delta_e = n ? de / n : NAN;
    m->sign = asked ? (double)agree / asked : NAN;
    if (n >= 6) {
        fit2(cp, cy, mp, n, &m->gain[0], &m->cross[0]);
        fit2(cy, cp, my, n, &m->gain[1], &m->cross[1]);
    } else {
        m->gain[0] = m->gain[1] = m->cross[0] = m->cross[1] = NAN;
    }
}

/* Face po->index of photo as a redirect input, from a copy of the photo
 * (the photo's other faces come next). */
static int photo_input(gs_face_detector *det, const gs_face_shape_model *sp,
                       const gs_model_info *info, const gs_io_image *photo,
                       const gs_redirect_photo_opts *po, gs_redirect_input *in, gs_error *err)
{
    gs_io_image copy = *photo;
    size_t bytes = photo->stride * (size_t)photo->height;
    memset(in, 0, sizeof *in);
    if (!(copy.data = malloc(bytes)))
        return gs_error_set(err, GS_ERR_NOMEM, "out of memory");
    memcpy(copy.data, photo->data, bytes);
    return gs_redirect_input_photo(det, sp, info, &copy, po, in, err);
}

/* The face's fit and both modes' 25 images, measured. */
static int eval_face(const cli_command *cmd, gs_model *m, gs_pool *pool, gs_face_detector *det,
                     const gs_face_shape_model *sp,
                     const gs_redirect_input *pf, long iters, const gs_finetune_options *ft,
                     face_eval *fe)
{
    gs_model_info info;
    gs_model_get_info(m, &info);
    int S = info.image_size, rc = CLI_OK;
    gs_error err = {0, ""};
    gs_fit_options o;
    gs_redirect_fit_options(pf, &o);
    o.max_iters = (int)iters;
    gs_subject sub;
    gs_fit_report fr;
    gs_model *tuned = NULL;
    gs_face_quality_ref *qref = NULL;
    gs_model_ctx *c = gs_model_ctx_create(m);
    uint8_t *out = malloc((size_t)S * S * 3);
    if (!c || !out) {
        rc = cli_fail(cmd, "out of memory");
        goto done;
    }
    double t0 = cli_now_s();
    if (gs_model_fit(c, pool, pf->norm.data, pf->norm.stride, &o, &sub, &fr, &err)) {
        rc = cli_fail(cmd, "%s face %d: fit: %s", fe->photo, fe->index, err.msg);
        goto done;
    }
    fe->fit_s = cli_now_s() - t0;
    fe->fit_psnr = sub.fit_psnr;
    if (ft->iters > 0) {
        gs_fit_image im;
        gs_fit_image_from_options(&im, pf->norm.data, pf->norm.stride, NULL);
        im.mask = pf->mask;
        gs_finetune_report r;
        t0 = cli_now_s();
        if (gs_redirect_finetune(&tuned, m, pool, &sub, &im, 1, ft, &r, &err)) {
            rc = cli_fail(cmd, "%s face %d: finetune: %s", fe->photo, fe->index, err.msg);
            goto done;
        }
        fe->ft_s = cli_now_s() - t0;
        gs_model_ctx_destroy(c);
        if (!(c = gs_model_ctx_create(tuned))) {
            rc = cli_fail(cmd, "out of memory");
            goto done;
        }
    }
    gs_face_quality_opts qo;
    gs_face_quality_opts_default(&qo);
    qo.px_per_mm = info.focal / info.distance_mm;
    qo.shape = sp;
    if (gs_face_quality_ref_create(&pf->norm, (const double(*)[2])pf->face.uv_n, &qo, &qref, &err)) {
        rc = cli_fail(cmd, "%s face %d: quality: %s", fe->photo, fe->index, err.msg);
        goto done;
    }
    gs_io_image oi = {S, S, 3 * (size_t)S, out};
    gs_xfer_eyes eyes = gs_redirect_eyes(pf);
    for (int mode = 0; mode < 2 && !rc; mode++) {
        int dets[NT];
        for (int t = 0; t < NT; t++) {
            gs_view v;
            memset(&v, 0, sizeof v);
            double dp = grid_pitch[t / 5] * DEG, dy = grid_yaw[t % 5] * DEG;
            v.gaze_pitch = fmax(-50 * DEG, fmin(50 * DEG, sub.gaze_pitch + dp));
            v.gaze_yaw = fmax(-60 * DEG, fmin(60 * DEG, sub.gaze_yaw + dy));
            int r = gs_redirect_render(c, pool, &sub, mode ? pf->norm.data : NULL, pf->norm.stride, &eyes,
                                       &v, out, oi.stride, &err);
            if (!r)
                r = gs_face_quality_measure(qref, &oi, sub.head_R, v.gaze_pitch - sub.gaze_pitch,
                                            v.gaze_yaw - sub.gaze_yaw, &fe->q[mode][t], &err);
            if (r) {
                rc = cli_fail(cmd, "%s face %d: %s", fe->photo, fe->index, err.msg);
                break;
            }
            dets[t] = detect_any(det, out, S);
        }
        if (!rc)
            stats_of(fe->q[mode], dets, &fe->mode[mode]);
    }
    fe->evaluated = !rc;
done:
    gs_face_quality_ref_destroy(qref);
    free(out);
    gs_model_ctx_destroy(c);
    gs_model_destroy(tuned);
    return rc;
}

/* A number with `prec` decimals (a sign with plus) for JSON (`none`
 * "null" when not finite) or the table ("-"). */
static const char *num(char *buf, size_t cap, int prec, int plus, double v, const char *none)
{
    if (!isfinite(v))
        return none;
    if (plus)
        snprintf(buf, cap, "%+.*f", prec, v);
    else
        snprintf(buf, cap, "%.*f", prec, v);
    return buf;
}

static void print_row(const face_eval *fe)
{
    static const char *const names[2] = {"plain", "transfer"};
    const char *base = strrchr(fe->photo, '/');
    base = base ? base + 1 : fe->photo;
    if (!fe->evaluated) {
        printf("| %s | %d | refused: %s | | | | | | | | | |\n", base, fe->index,
               gs_face_refusal_name(fe->gate.refusal));
        return;
    }
    for (int k = 0; k < 2; k++) {
        const mode_stats *m = &fe->mode[k];
        char b[8][32];
        printf("| %s | %d | %s%s | %.1f + %.1f s | %d/25 | %s / %s | %s / %s | %s | %s | %.2f | %.0f %% | "
               "%.2f (%.2f) |\n",
               base, fe->index, names[k], fe->gate.refusal ? " (gate off)" : "", fe->fit_s, fe->ft_s,
               m->n, num(b[0], 32, 2, 0, m->gain[1], "-"), num(b[1], 32, 2, 0, m->gain[0], "-"),
               num(b[2], 32, 2, 1, m->cross[1], "-"), num(b[3], 32, 2, 1, m->cross[0], "-"),
               num(b[4], 32, 0, 0, 100 * m->sign, "-"), num(b[5], 32, 1, 0, m->delta_e, "-"),
               m->artifact, 100 * m->detected, m->score_mean, m->score_min);
    }
}

static void json_face(FILE *f, const face_eval *fe, int first)
{
    fprintf(f, "%s{\"photo\":\"%s\",\"face\":%d,\"gate\":\"%s\",\"eye_px\":[%.2f,%.2f],"
               "\"eye_open\":[%.3f,%.3f],\"head_deg\":[%.2f,%.2f]",
            first ? "" : ",\n", fe->photo, fe->index, gs_face_refusal_name(fe->gate.refusal),
            fe->gate.eye_px[0], fe->gate.eye_px[1], fe->gate.eye_open[0], fe->gate.eye_open[1],
            fe->gate.head_pitch_deg, fe->gate.head_yaw_deg);
    if (fe->evaluated) {
        fprintf(f, ",\"fit_s\":%.3f,\"finetune_s\":%.3f,\"fit_psnr\":%.2f,\"modes\":[", fe->fit_s,
                fe->ft_s, fe->fit_psnr);
        for (int k = 0; k < 2; k++) {
            const mode_stats *m = &fe->mode[k];
            char b[8][32];
            fprintf(f, "%s{\"mode\":\"%s\",\"measured\":%d,\"gain_yaw\":%s,\"gain_pitch\":%s,"
                       "\"cross_yaw_from_pitch\":%s,\"cross_pitch_from_yaw\":%s,\"sign\":%s,"
                       "\"delta_e\":%s,\"artifact\":%.4f,\"detected\":%.3f,\"score_mean\":%.4f,"
                       "\"score_min\":%.4f,\"images\":[",
                    k ? "," : "", k ? "transfer" : "plain", m->n,
                    num(b[0], 32, 4, 0, m->gain[1], "null"), num(b[1], 32, 4, 0, m->gain[0], "null"),
                    num(b[2], 32, 4, 0, m->cross[1], "null"), num(b[3], 32, 4, 0, m->cross[0], "null"),
                    num(b[4], 32, 4, 0, m->sign, "null"), num(b[5], 32, 3, 0, m->delta_e, "null"),
                    m->artifact, m->detected, m->score_mean, m->score_min);
            for (int t = 0; t < NT; t++) {
                const gs_face_quality *q = &fe->q[k][t];
                fprintf(f, "%s{\"asked_deg\":[%.2f,%.2f],\"seen_deg\":[%s,%s],\"eyes\":%d,"
                           "\"delta_e\":%s,\"artifact\":%.3f,\"score\":%.4f}",
                        t ? "," : "", q->commanded[0] / DEG, q->commanded[1] / DEG,
                        num(b[0], 32, 2, 0, q->measured[0] / DEG, "null"),
                        num(b[1], 32, 2, 0, q->measured[1] / DEG, "null"), q->eyes,
                        num(b[2], 32, 2, 0, q->delta_e, "null"), q->artifact, q->score);
            }
            fprintf(f, "]}");
        }
        fprintf(f, "]");
    }
    fprintf(f, "}");
}

_Static_assert(CLI_NOPTS(eval_photos_opts) == 6, "eval_photos_opts: one entry per option index");

static int run_eval_photos(const cli_command *cmd, cli_opt *o)
{
    int rc = CLI_OK;
    if (!o[0].value || !o[1].value)
        return cli_usage_error(cmd, "--model and --photos are needed");
    long iters = GS_REDIRECT_FIT_ITERS;
    if (o[3].value && cli_parse_long(o[3].value, 1, 100000, &iters))
        return cli_usage_error(cmd, "--iters: want 1..100000; got '%s'", o[3].value);
    gs_finetune_options ft;
    const char *ftn = o[4].value ? o[4].value : CLI_STR(GS_REDIRECT_FINETUNE_STEPS);
    if (!strcmp(ftn, "0")) {
        gs_finetune_options_default(&ft);
        ft.iters = 0;
    } else if ((rc = cli_parse_finetune(cmd, ftn, NULL, NULL, NULL, NULL, NULL, &ft)))
        return rc;
    gs_error err = {0, ""};
    gs_model *m = NULL;
    gs_face_detector *det = NULL;
    gs_face_shape_model *sp = NULL;
    if (gs_model_load(o[0].value, &m, &err))
        return cli_fail(cmd, "%s: %s", o[0].value, err.msg);
    if (gs_face_detector_load(NULL, &det, &err) || gs_face_shape_model_load(NULL, &sp, &err)) {
        gs_model_destroy(m);
        gs_face_detector_destroy(det);
        return cli_fail(cmd, "face models: %s", err.msg);
    }
    gs_model_info info;
    gs_model_get_info(m, &info);
    gs_pool *pool = gs_pool_create(2);
    FILE *jf = NULL;
    if (o[2].value && !(jf = fopen(o[2].value, "w")))
        rc = cli_fail(cmd, "cannot write %s", o[2].value);
    if (jf)
        fprintf(jf, "{\"faces\":[\n");
    printf("| photo | face | mode | fit + fine-tune | measured | gain yaw / pitch | cross-talk "
           "yaw / pitch | sign %% | iris dE | speckle | detected | score (min) |\n"
           "|---|---|---|---|---|---|---|---|---|---|---|---|\n");
    char *list = strdup(o[1].value);
    int nfaces = 0, passed = 0;
    face_eval *fe = calloc(1, sizeof *fe);
    for (char *save = NULL, *path = strtok_r(list, ",", &save); !rc && path;
         path = strtok_r(NULL, ",", &save)) {
        gs_io_image photo = {0};
        if (gs_io_image_read(path, NULL, &photo, &err)) {
            rc = cli_fail(cmd, "%s: %s", path, err.msg);
            break;
        }
        gs_face_detection d[64];
        int n = 0;
        gs_face_detect_opts dopt;
        gs_face_detect_opts_default(&dopt);
        if (gs_face_detect(det, &photo, &dopt, d, 64, &n, &err))
            rc = cli_fail(cmd, "%s: %s", path, err.msg);
        for (int i = 0; i < n && !rc; i++) {
            gs_redirect_input pf;
            memset(fe, 0, sizeof *fe);
            fe->photo = path;
            fe->index = i;
            gs_redirect_photo_opts po;
            gs_redirect_photo_opts_default(&po);
            po.index = i;
            int r = photo_input(det, sp, &info, &photo, &po, &pf, &err);
            fe->gate = pf.gate;
            if (r && fe->gate.refusal != GS_FACE_USABLE && o[5].value &&
                fe->gate.refusal != GS_FACE_REFUSED_NO_FACE) {
                po.gate = 0;
                r = photo_input(det, sp, &info, &photo, &po, &pf, &err);
                pf.gate = fe->gate;
            }
            nfaces++;
            if (!r && pf.red_eye_px > 0)
                fprintf(stderr, "gazesplat %s: %s face %d: red-eye repaired (%d px)\n",
                        cmd->name, path, i, pf.red_eye_px);
            if (!r) {
                passed += fe->gate.refusal == GS_FACE_USABLE;
                rc = eval_face(cmd, m, pool, det, sp, &pf, iters, &ft, fe);
                gs_redirect_input_free(&pf);
            } else if (fe->gate.refusal == GS_FACE_USABLE) {
                rc = cli_fail(cmd, "%s face %d: %s", path, i, err.msg);
            }
            print_row(fe);
            fflush(stdout);
            if (jf)
                json_face(jf, fe, nfaces == 1);
        }
        gs_io_image_free(&photo);
    }
    printf("\n%d faces, %d passed the gate\n", nfaces, passed);
    if (jf) {
        fprintf(jf, "\n]}\n");
        if (fclose(jf) && !rc)
            rc = cli_fail(cmd, "cannot write %s", o[2].value);
    }
    free(fe);
    free(list);
    gs_pool_destroy(pool);
    gs_face_detector_destroy(det);
    gs_face_shape_model_destroy(sp);
    gs_model_destroy(m);
    return rc;
}
