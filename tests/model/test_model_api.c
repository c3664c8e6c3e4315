/* The public model API on a tiny model trained for a few steps: render,
 * fit, subjects, the face-stream cache, and bad input. */
#define _POSIX_C_SOURCE 200809L /* clock_gettime */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "gazesplat/nn.h"
#include "gazesplat/synth.h"
#include "gazesplat/train.h"
#include "gs_test.h"
#include "model_test_util.h"

/* A fit with these options is refused: GS_ERR_ARG, the subject left as it
 * was, and the message names what was wrong. */
static void check_fit_refused(gs_model_ctx *c, const gs_synth_sample *smp,
                              const gs_fit_options *o, const char *what)
{
    gs_error err = {0, ""};
    gs_subject keep, s;
    memset(&keep, 0x5a, sizeof keep);
    s = keep;
    CHECK(gs_model_fit(c, NULL, smp->rgb, smp->stride, o, &s, NULL, &err) ==
          GS_ERR_ARG);
    CHECK(memcmp(&s, &keep, sizeof keep) == 0);
    CHECK_MSG(strstr(err.msg, what) != NULL, "'%s' not in '%s'", what, err.msg);
}

int main(void)
{
    gs_nn_blas_set_threads(1);
    char path[128];
    tiny_path(path, "test_model_api");
    gs_error err = {0, ""};
    gs_train_report rep;
    gs_model *m = trained_tiny(path, 6, &rep, &err);
    CHECK_MSG(m != NULL, "%s", err.msg);
    CHECK(rep.steps == 6 && isfinite(rep.final_loss));
    gs_model_destroy(m);
    m = NULL;
    CHECK_MSG(gs_model_load(path, &m, &err) == GS_OK, "%s", err.msg);
    gs_model_info info;
    gs_model_get_info(m, &info);
    int S = info.image_size;
    CHECK(S == 128);
    gs_model_ctx *c = gs_model_ctx_create(m);
    CHECK(c != NULL);

    /* A synthetic normalized face to fit. */
    gs_synth_sample smp;
    CHECK(held_out_face(S, 3, &smp, &err) == GS_OK);
    gs_fit_options fo;
    gs_fit_options_default(&fo);
    fo.max_iters = 8;
    fo.known_head = 1;
    memcpy(fo.head_R, smp.labels.head_R, sizeof fo.head_R);
    memcpy(fo.head_t, smp.labels.head_t, sizeof fo.head_t);
    gs_subject sub;
    gs_fit_report fr;
    CHECK_MSG(gs_model_fit(c, NULL, smp.rgb, smp.stride, &fo, &sub, &fr,
                           &err) == GS_OK, "%s", err.msg);
    CHECK(fr.iters >= 1 && isfinite(sub.fit_psnr) && sub.fit_psnr > 5);
    CHECK(fr.loss_last <= fr.loss_first);
    printf("fit: %d iterations, loss %.4f -> %.4f, PSNR %.2f dB\n", fr.iters,
           fr.loss_first, fr.loss_last, sub.fit_psnr);

    /* The fit's rates: 0 means the defaults, bit for bit; another rate
     * changes the fit; rates outside [0, 10] or NaN are refused and leave
     * the subject alone. */
    {
        gs_fit_options fx = fo;
        gs_subject s1, s2, keep;
        fx.lr_code = GS_FIT_LR_CODE_DEFAULT;
        fx.lr_colour = GS_FIT_LR_COLOUR_DEFAULT;
        CHECK(gs_model_fit(c, NULL, smp.rgb, smp.stride, &fx, &s1, NULL,
                           &err) == GS_OK);
        CHECK(memcmp(s1.code, sub.code, sizeof(float) * sub.code_dim) == 0 &&
              memcmp(s1.colour_gain, sub.colour_gain, sizeof s1.colour_gain) == 0);
        fx.lr_code = 0.03;
        fx.lr_colour = 0.005;
        CHECK(gs_model_fit(c, NULL, smp.rgb, smp.stride, &fx, &s2, NULL,
                           &err) == GS_OK);
        CHECK(memcmp(s2.code, sub.code, sizeof(float) * sub.code_dim) != 0);
        const double bad_lr[][2] = {{-0.1, 0}, {0, -1}, {NAN, 0}, {0, NAN},
                                    {11, 0}, {0, INFINITY}};
        for (size_t k = 0; k < sizeof bad_lr / sizeof bad_lr[0]; k++) {
            fx.lr_code = bad_lr[k][0];
            fx.lr_colour = bad_lr[k][1];
            memset(&keep, 0x5a, sizeof keep);
            s2 = keep;
            CHECK(gs_model_fit(c, NULL, smp.rgb, smp.stride, &fx, &s2, NULL,
                               &err) == GS_ERR_ARG);
            CHECK(memcmp(&s2, &keep, sizeof keep) == 0);
        }
        CHECK(strstr(err.msg, "rates") != NULL);
    }

    /* The expression: at a rate that moves the code far each step, the
     * default (free) fit leaves some expression slot outside where
     * training put it; bound_expression keeps every slot inside. */
    {
        gs_fit_options fx = fo;
        fx.lr_code = 1.0;
        fx.code_prior = 0; /* free: no prior either */
        gs_subject sb, sf;
        CHECK(gs_model_fit(c, NULL, smp.rgb, smp.stride, &fx, &sf, NULL,
                           &err) == GS_OK);
        fx.bound_expression = 1;
        CHECK(gs_model_fit(c, NULL, smp.rgb, smp.stride, &fx, &sb, NULL,
                           &err) == GS_OK);
        int id = m->cfg.id_dim, in_b = 1, in_f = 1;
        for (int k = 0; k < GS_MODEL_EXPR_DIM; k++) {
            float vb = sb.code[id + k], vf = sf.code[id + k];
            printf("expression slot %d: bounded %+.3f, free %+.3f (range %g..%g)\n",
                   k, vb, vf, gs_model_expr_lo[k], gs_model_expr_hi[k]);
            in_b &= vb >= gs_model_expr_lo[k] && vb <= gs_model_expr_hi[k];
            in_f &= vf >= gs_model_expr_lo[k] && vf <= gs_model_expr_hi[k];
        }
        CHECK_MSG(in_b, "the bounded fit left the expression's range");
        CHECK_MSG(!in_f, "the free fit stayed inside: the check shows nothing");
    }

    /* The code prior: the sampler's mean and precision over [expression |
     * lights] (test_code_prior: the sampler's to the bit); zero at its mean; a gradient
     * that is the loss's (central differences); about `weight` on average
     * over codes drawn from the sampler. */
    {
        const gs_code_prior p1 = gs_code_prior_table;
        enum { N = GS_CODE_PRIOR_DIM };
        /* expression means of the sampler (identity.c): mouth_open
         * 0.5 E[u^2], smile 0.5 E[u], brow 0, squint 0.5 * 0.7 E[u^2],
         * blink 0.05 E[U(0.3, 1)], pupil 0 */
        const double want[6] = {1.0 / 6, 0.25, 0, 0.35 / 3, 0.0325, 0};
        for (int k = 0; k < 6; k++)
            CHECK_MSG(fabs(p1.mean[k] - want[k]) < 0.02,
                      "expression slot %d: mean %g, want about %g", k,
                      p1.mean[k], want[k]);
        int sym = 1, pos = 1;
        for (int i = 0; i < N; i++) {
            pos &= p1.prec[i * N + i] > 0;
            for (int j = 0; j < N; j++)
                sym &= p1.prec[i * N + j] == p1.prec[j * N + i];
        }
        CHECK(sym && pos);
        double g[N] = {0};
        CHECK(gs_code_prior_eval(&p1, 0.5, p1.mean, g) == 0.0);
        for (int i = 0; i < N; i++)
            CHECK(g[i] == 0.0);
        double x[N], worst = 0;
        for (int i = 0; i < N; i++)
            x[i] = p1.mean[i] + 0.3 * sin(1.7 * i + 0.4);
        memset(g, 0, sizeof g);
        double l0 = gs_code_prior_eval(&p1, 0.5, x, g);
        CHECK(l0 > 0 && isfinite(l0));
        for (int i = 0; i < N; i++) {
            double h = 1e-5, xp[N], xm[N];
            memcpy(xp, x, sizeof x);
            memcpy(xm, x, sizeof x);
            xp[i] += h;
            xm[i] -= h;
            double fd = (gs_code_prior_eval(&p1, 0.5, xp, NULL) -
                         gs_code_prior_eval(&p1, 0.5, xm, NULL)) / (2 * h);
            double e = fabs(fd - g[i]) / fmax(1.0, fabs(g[i]));
            worst = e > worst ? e : worst;
        }
        printf("code prior: loss %.4f at the probe, gradient vs central "
               "differences: worst relative error %.2e\n", l0, worst);
        CHECK(worst < 1e-6);
        /* codes the sampler draws (other scenes than the prior's own
         * 4096) cost at most about the weight each: less, for the ridge
         * takes the light code's three colour-locked directions (and part
         * of the small-variance ones) almost out of the sum */
        gs_train_options to;
        gs_train_options_default(&to);
        gs_synth_gen_config gen;
        gs_train_sample_config(m, &to, &gen);
        double sum = 0;
        for (int k = 0; k < 2000; k++) {
            gs_synth_scene sc;
            gs_synth_camera cam;
            CHECK(gs_synth_gen_scene(&gen, 100000 + (uint64_t)k, &sc, &cam,
                                     &err) == GS_OK);
            /* the slots a training step fills, as --true-code gives them */
            float code[GS_MODEL_MAX_CODE];
            uint8_t fixed[GS_MODEL_MAX_CODE];
            CHECK(gs_model_scene_code(m, &sc, GS_SCENE_CODE_EXPR | GS_SCENE_CODE_LIGHT,
                                      code, fixed, &err) == GS_OK);
            double xv[N];
            for (int i = 0; i < N; i++)
                xv[i] = code[m->cfg.id_dim + i];
            sum += gs_code_prior_eval(&p1, 1.0, xv, NULL);
        }
        printf("code prior: mean loss over 2000 drawn codes %.3f (weight 1)\n",
               sum / 2000);
        CHECK(sum / 2000 > 0.5 && sum / 2000 < 1.05);
    }

    /* The fit with the prior: the default options take the model's weight,
     * which is none here (the same bytes as weight 0), weight 3e-4 fits
     * otherwise; a model naming 3e-4 fits with it by default (the same
     * bytes as asking for it) and still without it when asked for 0; a
     * heavy prior ends nearer the sampler's codes than the free fit at
     * the same (fast) rate; weights outside [0, 10] other than the
     * model's marker, or NaN, are refused and leave the subject alone. */
    {
        const gs_code_prior pr = gs_code_prior_table;
        gs_fit_options fx = fo;
        gs_subject s0, sp, sf;
        CHECK(fo.code_prior == GS_FIT_CODE_PRIOR_MODEL);
        CHECK(m->cfg.fit_code_prior == 0);
        fx.code_prior = 0;
        CHECK(gs_model_fit(c, NULL, smp.rgb, smp.stride, &fx, &s0, NULL,
                           &err) == GS_OK);
        CHECK(memcmp(s0.code, sub.code, sizeof(float) * sub.code_dim) == 0);
        fx.code_prior = 3e-4;
        CHECK(gs_model_fit(c, NULL, smp.rgb, smp.stride, &fx, &s0, NULL,
                           &err) == GS_OK);
        CHECK(memcmp(s0.code, sub.code, sizeof(float) * sub.code_dim) != 0);
        CHECK(gs_model_set_fit_code_prior(m, 3e-4, &err) == GS_OK);
        gs_subject sm, sz;
        fx.code_prior = GS_FIT_CODE_PRIOR_MODEL;
        CHECK(gs_model_fit(c, NULL, smp.rgb, smp.stride, &fx, &sm, NULL,
                           &err) == GS_OK);
        CHECK(memcmp(sm.code, s0.code, sizeof(float) * sub.code_dim) == 0 &&
              memcmp(sm.colour_gain, s0.colour_gain, sizeof sm.colour_gain) == 0 &&
              sm.fit_psnr == s0.fit_psnr);
        fx.code_prior = 0;
        CHECK(gs_model_fit(c, NULL, smp.rgb, smp.stride, &fx, &sz, NULL,
                           &err) == GS_OK);
        CHECK(memcmp(sz.code, sub.code, sizeof(float) * sub.code_dim) == 0);
        /* NULL options: the defaults, so the model's weight */
        gs_fit_options fd;
        gs_fit_options_default(&fd);
        fd.code_prior = 3e-4;
        CHECK(gs_model_fit(c, NULL, smp.rgb, smp.stride, NULL, &sz, NULL,
                           &err) == GS_OK);
        CHECK(gs_model_fit(c, NULL, smp.rgb, smp.stride, &fd, &sm, NULL,
                           &err) == GS_OK);
        CHECK(memcmp(sz.code, sm.code, sizeof(float) * sub.code_dim) == 0);
        CHECK(gs_model_set_fit_code_prior(m, 0, &err) == GS_OK);
        fx.code_prior = 0; /* free */
        fx.lr_code = 1.0;
        CHECK(gs_model_fit(c, NULL, smp.rgb, smp.stride, &fx, &sf, NULL,
                           &err) == GS_OK);
        fx.code_prior = 1.0;
        CHECK_MSG(gs_model_fit(c, NULL, smp.rgb, smp.stride, &fx, &sp, NULL,
                               &err) == GS_OK, "%s", err.msg);
        double xf[GS_CODE_PRIOR_DIM], xp[GS_CODE_PRIOR_DIM];
        for (int i = 0; i < GS_CODE_PRIOR_DIM; i++) {
            xf[i] = sf.code[m->cfg.id_dim + i];
            xp[i] = sp.code[m->cfg.id_dim + i];
        }
        double qf = gs_code_prior_eval(&pr, 1.0, xf, NULL);
        double qp = gs_code_prior_eval(&pr, 1.0, xp, NULL);
        printf("fit at rate 1: prior term %.3f free, %.3f with the prior "
               "(weight 1)\n", qf, qp);
        CHECK(qp < qf);
        const double bad[] = {-0.1, -2.0, 10.5, NAN, INFINITY};
        for (size_t k = 0; k < sizeof bad / sizeof bad[0]; k++) {
            fx.code_prior = bad[k];
            check_fit_refused(c, &smp, &fx, "code prior");
        }
    }

    /* The identity prior: the learned identity codes' Gaussian (mean and
     * covariance over codes.train, a ridge of 1 % of the mean variance).
     * Zero at that mean; a gradient that is the loss's (central
     * differences); over two learned codes, exactly (1 / n) / (1 + 0.01 /
     * n) at weight 1 (their covariance is rank one: d d^T, the codes at
     * mean +- d). A fit at weight 0 is the plain fit's bytes; at a weight
     * it fits otherwise, and a heavy one at a fast rate ends with a lower
     * prior term than the free fit. Refused: weights outside [0, 10] or
     * NaN (the subject left alone), and a model of fewer than 2 training
     * identities. */
    {
        gs_id_prior *ip = NULL;
        CHECK_MSG(gs_id_prior_make(m, &ip, &err) == GS_OK, "%s", err.msg);
        const int n = m->cfg.id_dim, T = m->cfg.n_train_ids;
        const float *codes = m->p.codes;
        CHECK(T == 2 && n >= 2);
        double mean[GS_MODEL_MAX_CODE] = {0}, g[GS_MODEL_MAX_CODE] = {0};
        for (int t = 0; t < T; t++)
            for (int i = 0; i < n; i++)
                mean[i] += codes[(size_t)t * n + i] / (double)T;
        CHECK(gs_id_prior_eval(ip, 0.5, mean, g) == 0.0);
        double x[GS_MODEL_MAX_CODE], xp[GS_MODEL_MAX_CODE], xm[GS_MODEL_MAX_CODE];
        double spread = 0;
        for (int i = 0; i < n; i++) {
            double d = codes[i] - mean[i];
            spread += d * d;
            x[i] = mean[i] + 0.7 * d + 0.01 * sin(1.0 + i);
        }
        memset(g, 0, sizeof g);
        double l0 = gs_id_prior_eval(ip, 0.5, x, g), worst = 0;
        CHECK(l0 > 0);
        for (int i = 0; i < n; i++) {
            memcpy(xp, x, sizeof x);
            memcpy(xm, x, sizeof x);
            double h = 1e-5;
            xp[i] += h, xm[i] -= h;
            double fd = (gs_id_prior_eval(ip, 0.5, xp, NULL) -
                         gs_id_prior_eval(ip, 0.5, xm, NULL)) / (2 * h);
            worst = fmax(worst, fabs(fd - g[i]) / (1e-6 + fabs(fd)));
        }
        double avg = 0;
        for (int t = 0; t < T; t++) {
            double xc[GS_MODEL_MAX_CODE];
            for (int i = 0; i < n; i++)
                xc[i] = codes[(size_t)t * n + i];
            avg += gs_id_prior_eval(ip, 1.0, xc, NULL) / T;
        }
        double want = (1.0 / n) / (1.0 + 0.01 / n);
        printf("identity prior: gradient within %.2e of central differences; "
               "the learned codes' mean term %.6f (want %.6f; their spread %.3g)\n",
               worst, avg, want, sqrt(spread));
        CHECK(worst < 1e-5);
        CHECK_MSG(fabs(avg - want) < 1e-6 * want, "mean term %.9f, want %.9f", avg, want);
        gs_id_prior_free(ip);

        gs_fit_options fx = fo;
        gs_subject s0, s1, sf, sp;
        CHECK(fo.id_prior == 0);
        CHECK(gs_model_fit(c, NULL, smp.rgb, smp.stride, &fx, &s0, NULL, &err) == GS_OK);
        CHECK(memcmp(s0.code, sub.code, sizeof(float) * sub.code_dim) == 0);
        fx.id_prior = 0.3;
        CHECK(gs_model_fit(c, NULL, smp.rgb, smp.stride, &fx, &s1, NULL, &err) == GS_OK);
        CHECK(memcmp(s1.code, sub.code, sizeof(float) * sub.code_dim) != 0);
        CHECK(gs_id_prior_make(m, &ip, &err) == GS_OK);
        fx.lr_code = 1.0;
        fx.id_prior = 0;
        CHECK(gs_model_fit(c, NULL, smp.rgb, smp.stride, &fx, &sf, NULL, &err) == GS_OK);
        fx.id_prior = 10.0;
        CHECK(gs_model_fit(c, NULL, smp.rgb, smp.stride, &fx, &sp, NULL, &err) == GS_OK);
        double xf[GS_MODEL_MAX_CODE], xq[GS_MODEL_MAX_CODE];
        for (int i = 0; i < n; i++)
            xf[i] = sf.code[i], xq[i] = sp.code[i];
        double qf = gs_id_prior_eval(ip, 1.0, xf, NULL), qp = gs_id_prior_eval(ip, 1.0, xq, NULL);
        printf("fit at rate 1: identity prior term %.3f free, %.3f with the prior "
               "(weight 10)\n", qf, qp);
        CHECK(qp < qf);
        gs_id_prior_free(ip);
        const double bad[] = {-0.1, 10.5, NAN, INFINITY};
        for (size_t k = 0; k < sizeof bad / sizeof bad[0]; k++) {
            fx.id_prior = bad[k];
            check_fit_refused(c, &smp, &fx, "identity prior");
        }
        m->cfg.n_train_ids = 1; /* as a model of one training identity */
        fx.id_prior = 0.3;
        check_fit_refused(c, &smp, &fx, "identity");
        m->cfg.n_train_ids = T;
    }

    /* anneal: at a plateau the rates halve and the fit goes on. Up to the
     * first plateau it is the plain fit step for step, so it ends at a loss
     * no higher, later, having halved as often as asked; out of range is
     * refused and leaves the subject alone. */
    {
        gs_fit_options fx = fo;
        fx.max_iters = 200;
        fx.plateau_rel = 0.05; /* a plateau soon, on the tiny model */
        gs_subject s0, s2;
        gs_fit_report r0, r2;
        CHECK(gs_model_fit(c, NULL, smp.rgb, smp.stride, &fx, &s0, &r0, &err) == GS_OK);
        fx.anneal = 2;
        CHECK(gs_model_fit(c, NULL, smp.rgb, smp.stride, &fx, &s2, &r2, &err) == GS_OK);
        printf("anneal: plain %d iterations, loss %.5f; 2 halvings %d iterations "
               "(%d halved), loss %.5f\n", r0.iters, r0.loss_last, r2.iters,
               r2.halvings, r2.loss_last);
        CHECK(r0.stopped_on_plateau && r0.halvings == 0 && r0.iters < 200);
        CHECK(r2.stopped_on_plateau && r2.halvings == 2);
        CHECK(r2.iters >= r0.iters + 40);
        CHECK(r2.loss_first == r0.loss_first && r2.loss_last <= r0.loss_last);
        CHECK(memcmp(s2.code, s0.code, sizeof(float) * s0.code_dim) != 0);
        const int bad[] = {-1, GS_FIT_ANNEAL_MAX + 1};
        for (size_t k = 0; k < sizeof bad / sizeof bad[0]; k++) {
            fx.anneal = bad[k];
            check_fit_refused(c, &smp, &fx, "anneal");
        }
    }

    /* mirror: the fit also fits the input flipped, from the mirrored pose.
     * Fitting the flipped input from the mirrored labels is the same two
     * views the other way round, so with the pose and gaze known it gives
     * the mirrored fit to the bit (the code's light x negated, the colours
     * the same); with them free, the mirrored pose and gaze within
     * rounding, which checks the mirrored view's gradient in every
     * variable. 2 is refused. */
    {
        const int L0 = info.code_dim - 12; /* the lights' slots */
        uint8_t *flip = malloc(3 * (size_t)S * S);
        for (int y = 0; y < S; y++)
            for (int x = 0; x < S; x++)
                memcpy(flip + 3 * ((size_t)y * S + x),
                       smp.rgb + (size_t)y * smp.stride + 3 * (size_t)(S - 1 - x), 3);
        for (int known = 1; known >= 0; known--) {
            gs_fit_options fa = fo, fb;
            fa.max_iters = 12;
            fa.code_prior = 0;
            fa.mirror = 1;
            fa.known_head = known;
            fa.known_gaze = known;
            fa.gaze_pitch = smp.labels.gaze_head_pitch;
            fa.gaze_yaw = smp.labels.gaze_head_yaw;
            fb = fa;
            for (int i = 0; i < 3; i++)
                for (int j = 0; j < 3; j++)
                    fb.head_R[3 * i + j] = (i == 0) != (j == 0) ? -fa.head_R[3 * i + j]
                                                                : fa.head_R[3 * i + j];
            fb.head_t[0] = -fa.head_t[0];
            fb.gaze_yaw = -fa.gaze_yaw;
            float start_m[GS_MODEL_MAX_CODE]; /* the mean code, mirrored */
            for (int k = 0; k < info.code_dim; k++) {
                int lx = k >= L0 && (k - L0) % 3 == 0 && k - L0 < 9;
                start_m[k] = lx ? -m->p.code_mean[k] : m->p.code_mean[k];
            }
            fb.code_start = start_m;
            gs_subject sa, sb;
            gs_fit_report ra, rb;
            CHECK_MSG(gs_model_fit(c, NULL, smp.rgb, smp.stride, &fa, &sa, &ra, &err) == GS_OK,
                      "%s", err.msg);
            CHECK_MSG(gs_model_fit(c, NULL, flip, 3 * (size_t)S, &fb, &sb, &rb, &err) == GS_OK,
                      "%s", err.msg);
            double worst = 0;
            int bits_same = ra.iters == rb.iters && ra.loss_last == rb.loss_last;
            for (int k = 0; k < info.code_dim; k++) {
                int lx = k >= L0 && (k - L0) % 3 == 0 && k - L0 < 9;
                float want = lx ? -sa.code[k] : sa.code[k];
                worst = fmax(worst, fabs((double)sb.code[k] - want));
                bits_same &= memcmp(&sb.code[k], &want, sizeof want) == 0;
            }
            for (int k = 0; k < 3; k++) {
                worst = fmax(worst, fabs(sb.colour_gain[k] - sa.colour_gain[k]));
                worst = fmax(worst, fabs(sb.colour_bias[k] - sa.colour_bias[k]));
                bits_same &= sb.colour_gain[k] == sa.colour_gain[k] &&
                             sb.colour_bias[k] == sa.colour_bias[k];
                for (int j = 0; j < 3; j++) {
                    double sgn = (k == 0) != (j == 0) ? -1 : 1;
                    worst = fmax(worst, fabs(sb.head_R[3 * k + j] - sgn * sa.head_R[3 * k + j]));
                }
                worst = fmax(worst, fabs(sb.head_t[k] - (k == 0 ? -1 : 1) * sa.head_t[k]) / 100);
            }
            worst = fmax(worst, fabs(sb.gaze_pitch - sa.gaze_pitch));
            worst = fmax(worst, fabs(sb.gaze_yaw + sa.gaze_yaw));
            printf("mirror (pose and gaze %s): %d iterations, loss %.5f; the flipped "
                   "input's fit against the mirrored fit: worst %.3g%s\n",
                   known ? "known" : "free", ra.iters, ra.loss_last, worst,
                   bits_same ? ", the same bits" : "");
            if (known)
                CHECK(bits_same);
            else
                CHECK_MSG(worst < 1e-3, "worst %.3g", worst);
            if (!known) { /* the pose and gaze moved: their gradients count */
                CHECK(fabs(sa.gaze_yaw - fa.gaze_yaw) > 1e-4 ||
                      fabs(sa.gaze_pitch - fa.gaze_pitch) > 1e-4);
                CHECK(fabs(sa.head_t[0]) > 1e-3);
            }
        }
        free(flip);
        gs_fit_options fx = fo;
        gs_subject s0, s1;
        CHECK(gs_model_fit(c, NULL, smp.rgb, smp.stride, &fx, &s0, NULL, &err) == GS_OK);
        fx.mirror = 1;
        CHECK(gs_model_fit(c, NULL, smp.rgb, smp.stride, &fx, &s1, NULL, &err) == GS_OK);
        CHECK(memcmp(s1.code, s0.code, sizeof(float) * s0.code_dim) != 0);
        fx.mirror = 2;
        check_fit_refused(c, &smp, &fx, "mirror");
    }

    /* The fit key (gs_model_fit_key) names what the fit depends on and
     * nothing else: the options as the fit reads them (0 for a default,
     * the model's prior weight resolved), the known labels, the mask, the
     * image and the model's parameters and configuration. */
    {
        gs_fit_options k0;
        gs_fit_options_default(&k0);
        const uint64_t base = gs_model_fit_key(m, &k0, smp.rgb, smp.stride);
        CHECK(gs_model_fit_key(m, NULL, smp.rgb, smp.stride) == base);
        gs_fit_options k = k0;
        k.lr_code = GS_FIT_LR_CODE_DEFAULT;
        k.lr_colour = GS_FIT_LR_COLOUR_DEFAULT;
        k.code_prior = 0; /* the model names none */
        k.gaze_pitch = 0.3; /* not known: not read */
        CHECK(gs_model_fit_key(m, &k, smp.rgb, smp.stride) == base);
        int differ = 0, cases = 0;
#define KEY_DIFFERS(stmt)                                                       \
    do {                                                                        \
        k = k0;                                                                 \
        stmt;                                                                   \
        cases++;                                                                \
        differ += gs_model_fit_key(m, &k, smp.rgb, smp.stride) != base;         \
    } while (0)
        KEY_DIFFERS(k.max_iters = 199);
        KEY_DIFFERS(k.lr_code = 0.121);
        KEY_DIFFERS(k.code_prior = 3e-4);
        KEY_DIFFERS(k.id_prior = 3e-3);
        KEY_DIFFERS(k.anneal = 1);
        KEY_DIFFERS(k.mirror = 1);
        KEY_DIFFERS(k.bound_expression = 1);
        KEY_DIFFERS(k.known_gaze = 1);
        KEY_DIFFERS((k.known_head = 1, k.head_t[2] = 600));
        uint8_t mask[128 * 128];
        memset(mask, 255, sizeof mask);
        KEY_DIFFERS(k.mask = mask);
        float cs[GS_MODEL_MAX_CODE] = {0};
        KEY_DIFFERS(k.code_start = cs);
#undef KEY_DIFFERS
        CHECK_MSG(differ == cases, "%d of %d option changes changed the key",
                  differ, cases);
        /* known gaze: its values are read */
        k = k0;
        k.known_gaze = 1;
        const uint64_t kg = gs_model_fit_key(m, &k, smp.rgb, smp.stride);
        k.gaze_yaw = 1e-9;
        CHECK(gs_model_fit_key(m, &k, smp.rgb, smp.stride) != kg);
        /* one pixel's one level */
        smp.rgb[smp.stride * 77 + 3 * 50 + 1] ^= 1;
        CHECK(gs_model_fit_key(m, &k0, smp.rgb, smp.stride) != base);
        smp.rgb[smp.stride * 77 + 3 * 50 + 1] ^= 1;
        CHECK(gs_model_fit_key(m, &k0, smp.rgb, smp.stride) == base);
        /* the model naming a weight: the same key as asking for it */
        k = k0;
        k.code_prior = 3e-4;
        const uint64_t kp = gs_model_fit_key(m, &k, smp.rgb, smp.stride);
        CHECK(gs_model_set_fit_code_prior(m, 3e-4, &err) == GS_OK);
        CHECK(gs_model_fit_key(m, &k0, smp.rgb, smp.stride) == kp);
        CHECK(gs_model_set_fit_code_prior(m, 0, &err) == GS_OK);
        CHECK(gs_model_fit_key(m, &k0, smp.rgb, smp.stride) == base);
        /* another parameter value: another model */
        gs_model *mc = NULL;
        CHECK(gs_model_clone(m, &mc, &err) == GS_OK);
        CHECK(gs_model_fit_key(mc, &k0, smp.rgb, smp.stride) == base);
        mc->params[mc->t[0].offset] += 1e-3f;
        CHECK(gs_model_fit_key(mc, &k0, smp.rgb, smp.stride) != base);
        gs_model_destroy(mc);
    }

    /* Subjects survive encode/decode; bad bytes are refused. */
    uint8_t buf[GS_SUBJECT_ENCODED_MAX];
    size_t n = gs_subject_encode(&sub, buf, sizeof buf);
    CHECK(n > 0 && n <= sizeof buf);
    gs_subject back;
    CHECK(gs_subject_decode(buf, n, &back, &err) == GS_OK);
    CHECK(memcmp(back.code, sub.code, sizeof(float) * sub.code_dim) == 0);
    CHECK(gs_subject_decode(buf, n - 1, &back, &err) == GS_ERR_FORMAT);
    buf[0] ^= 1;
    CHECK(gs_subject_decode(buf, n, &back, &err) == GS_ERR_FORMAT);

    /* A gaze sweep reuses the face stream and renders incrementally; it
     * must equal renders from a fresh context within one 8-bit level (the
     * incremental render is the full one within 1e-5, not bit for bit:
     * with OpenBLAS's generic Prescott kernels one value in this sweep
     * lands on the other side of a rounding step). */
    size_t isz = 3 * (size_t)S * S;
    uint8_t *a = malloc(isz), *b = malloc(isz);
    gs_model_ctx *c2 = gs_model_ctx_create(m);
    int worst = 0;
    for (int k = 0; k < 4; k++) {
        gs_view v = {0};
        v.gaze_pitch = 0.1 * k - 0.15;
        v.gaze_yaw = 0.2 - 0.13 * k;
        CHECK(gs_model_render(c, NULL, &sub, &v, a, 3 * (size_t)S, &err) ==
              GS_OK);
        gs_model_ctx_destroy(c2);
        c2 = gs_model_ctx_create(m);
        CHECK(gs_model_render(c2, NULL, &sub, &v, b, 3 * (size_t)S, &err) ==
              GS_OK);
        for (size_t i = 0; i < isz; i++) {
            int d = abs((int)a[i] - (int)b[i]);
            worst = d > worst ? d : worst;
        }
    }
    CHECK_MSG(worst <= 1, "cached face stream render differs from a fresh one by %d levels",
              worst);
    /* Different gazes give different images. */
    gs_view v0 = {0}, v1 = {0};
    v1.gaze_yaw = 0.5;
    gs_model_render(c, NULL, &sub, &v0, a, 3 * (size_t)S, &err);
    gs_model_render(c, NULL, &sub, &v1, b, 3 * (size_t)S, &err);
    CHECK(memcmp(a, b, isz) != 0);

    /* Bad input. */
    gs_view bad = {0};
    bad.gaze_pitch = 1.2;
    CHECK(gs_model_render(c, NULL, &sub, &bad, a, 3 * (size_t)S, &err) ==
          GS_ERR_ARG);
    bad.gaze_pitch = NAN;
    CHECK(gs_model_render(c, NULL, &sub, &bad, a, 3 * (size_t)S, &err) ==
          GS_ERR_NONFINITE);
    bad.gaze_pitch = 0;
    CHECK(gs_model_render(c, NULL, &sub, &bad, a, 2 * (size_t)S, &err) ==
          GS_ERR_ARG);
    bad.use_head = 1;
    gs_geom_mat3_identity(bad.head_R);
    bad.head_R[0] = 2; /* not a rotation */
    bad.head_t[2] = 600;
    CHECK(gs_model_render(c, NULL, &sub, &bad, a, 3 * (size_t)S, &err) ==
          GS_ERR_ARG);
    gs_subject nan_sub = sub;
    nan_sub.code[0] = NAN;
    CHECK(gs_model_render(c, NULL, &nan_sub, &v0, a, 3 * (size_t)S, &err) ==
          GS_ERR_NONFINITE);
    fo.known_gaze = 1;
    fo.gaze_yaw = 3.0;
    CHECK(gs_model_fit(c, NULL, smp.rgb, smp.stride, &fo, &sub, NULL, &err) ==
          GS_ERR_ARG);

    free(a);
    free(b);
    gs_model_ctx_destroy(c2);
    gs_model_ctx_destroy(c);
    gs_synth_sample_free(&smp);
    gs_model_destroy(m);
    tiny_remove(path);
    GS_TEST_END();
}
