/* gazesplat fit / redirect: fit a subject to a normalized face image and
 * render it at other gazes. (Photos go through face detection and
 * normalization first; see docs/face.md.) */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

#include "cli.h"
#include "gazesplat/redirect.h"
#include "gazesplat/face.h"
#include "gazesplat/geom.h"
#include "gazesplat/image_io.h"
#include "gazesplat/nn.h"
#include "gazesplat/model.h"

static int run_fit(const cli_command *cmd, cli_opt *o);
static int run_redirect(const cli_command *cmd, cli_opt *o);

static const cli_opt fit_opts[] = {
    {"--model", 1, NULL}, {"--image", 1, NULL}, {"--mask", 1, NULL}, {"--gaze-deg", 1, NULL},
    {"--iters", 1, NULL}, {"--time", 1, NULL}, {"--out", 1, NULL}, {"--finetune", 1, NULL},
    {"--finetune-parts", 1, NULL}, {"--finetune-lr", 1, NULL}, {"--finetune-plateau", 1, NULL},
    {"--finetune-outline", 1, NULL}, {"--finetune-mirror", 1, NULL}, {"--no-gate", 0, NULL},
    {"--head-deg", 1, NULL}, {"--ref", 1, NULL}};

const cli_command cli_fit_command = {
    "fit",
    "fit a subject (latent code, head pose, gaze, colour) to a face image",
    "usage: gazesplat fit --model M --image FACE.png[,FACE2.png...] --out SUBJECT.bin\n"
    "                     [--mask M[,M2...]] [--gaze-deg P,Y[;P,Y...]]\n"
    "                     [--head-deg P,Y[;P,Y...]] [--ref I] [--iters N] [--time S]\n"
    "                     [--finetune N [--finetune-parts LIST]\n"
    "                      [--finetune-lr X] [--finetune-plateau R]\n"
    "                      [--finetune-outline PX] [--finetune-mirror 0|1]]\n"
    "\n"
    "  --model FILE     a model file (gazesplat train)\n"
    "  --image LIST     a normalized face image (PNG/JPEG) of the model's\n"
    "                   image size: face centre at the image centre, the\n"
    "                   model's normalized camera (docs/model.md); or up to\n"
    "                   16 of one person, comma-separated, fitted as one\n"
    "                   subject: one identity (and one fine-tuning), each\n"
    "                   image its own expression, lights, gaze and head pose\n"
    "                   (docs/subjects.md)\n"
    "  --mask LIST      optional grey images, one per image: weight of each\n"
    "                   pixel (face region), same size\n"
    "  --gaze-deg LIST  the images' gaze (head frame, degrees; pitch in\n"
    "                   [-50, 50], yaw in [-60, 60], inclusive) if known,\n"
    "                   one P,Y per image separated by ';', '-' for one not\n"
    "                   known; an unknown gaze is estimated with the fit\n"
    "  --head-deg LIST  the images' head pose (normalized camera, degrees,\n"
    "                   each in [-70, 70]) if known, as --gaze-deg; an\n"
    "                   unknown one is estimated with the fit\n"
    "  --ref I          the image (0: the first) whose expression, lights,\n"
    "                   head pose and gaze the subject file keeps; its\n"
    "                   identity (and the fine-tuning) is all the images'\n"
    "  --iters N        iteration cap (200); --time S: time budget\n"
    "  --finetune N     then fine-tune a copy of the model on the image for N\n"
    "                   Adam steps (gs_model_finetune; the paper's last step)\n"
    "                   and store the tuned tensors with the subject\n"
    "  --finetune-parts LIST  what is tuned, comma-separated: face (face\n"
    "                   Gaussians' colour and features), eye, renderer, mlp,\n"
    "                   geometry, face-geometry (the face stream's alone);\n"
    "                   default face,geometry\n"
    "  --finetune-lr X  Adam's base rate (default 0.004, the daemon's)\n"
    "  --finetune-plateau R  stop fine-tuning when the loss improved by less\n"
    "                   than the fraction R over 20 steps (default: never)\n"
    "                   (--time S bounds the fit and the fine-tuning together)\n"
    "  --finetune-outline PX  colours learn nothing within PX feature pixels\n"
    "                   (0..8, default 0) of the model's outline, only the\n"
    "                   geometry: fewer background-coloured patches at other\n"
    "                   head poses (2 with --finetune-mirror 0; docs/model.md)\n"
    "  --finetune-mirror 0|1  also fit the input mirrored left to right, from\n"
    "                   the mirrored pose (1, the default: the side the input\n"
    "                   hides takes the other side's look); 0: the input alone\n"
    "  --no-gate        fit whatever the image holds; by default a face the\n"
    "                   gate refuses (a flat or noise image) exits 3\n"
    "  --out FILE       the fitted subject (binary, gs_subject_encode),\n"
    "                   followed by the tuned block with --finetune\n"
    "                   (gs_model_tuned_encode; 3.4 MB for the default parts at cpu)\n"
    "Prints the fit quality and the estimated labels. The fit's code prior\n"
    "is the one the model file names (gazesplat model; docs/model.md).\n",
    .opts = fit_opts,
    .nopts = CLI_NOPTS(fit_opts),
    .run_opts = run_fit,
};

static const cli_opt redirect_opts[] = {
    {"--model", 1, NULL}, {"--subject", 1, NULL}, {"--image", 1, NULL}, {"--gaze-deg", 1, NULL},
    {"--out", 1, NULL}, {"--head-deg", 1, NULL}, {"--index", 1, NULL}, {"--out-norm", 0, NULL},
    {"--iters", 1, NULL}, {"--finetune", 1, NULL}, {"--finetune-parts", 1, NULL},
    {"--finetune-lr", 1, NULL}, {"--finetune-plateau", 1, NULL}, {"--transfer", 0, NULL},
    {"--light-on-head", 0, NULL}, {"--transfer-head-weight", 1, NULL},
    {"--transfer-eye-weight", 1, NULL}, {"--finetune-outline", 1, NULL},
    {"--finetune-mirror", 1, NULL}, {"--transfer-eye-warp", 1, NULL}, {"--no-gate", 0, NULL},
    {"--ref", 1, NULL}, {"--image-gaze-deg", 1, NULL}, {"--image-head-deg", 1, NULL}};

const cli_command cli_redirect_command = {
    "redirect",
    "render a fitted subject (or a face image, fitted first) at new gazes",
    "usage: gazesplat redirect --model M (--subject S.bin | --image IMG[,IMG2...])\n"
    "                          --gaze-deg \"P,Y;P,Y;...\" --out DIR\n"
    "                          [--head-deg P,Y [--light-on-head]] [--index I]\n"
    "                          [--out-norm] [--transfer-head-weight W]\n"
    "                          [--transfer-eye-weight W]\n"
    "                          [--transfer-eye-warp DEG]\n"
    "                          [--iters N] [--transfer] [--finetune N\n"
    "                          [--finetune-parts LIST] [--finetune-lr X]\n"
    "                          [--finetune-plateau R] [--finetune-outline PX]\n"
    "                          [--finetune-mirror 0|1]] [--ref I]\n"
    "                          [--image-gaze-deg LIST] [--image-head-deg LIST]\n"
    "\n"
    "  --image IMG      a normalized face of the model's size, fitted first;\n"
    "                   or any photo: its face (--index I, largest first) is\n"
    "                   detected, normalized, fitted, redirected and pasted\n"
    "                   back into the photo's eye regions (full-size output;\n"
    "                   --out-norm also writes the normalized crops). Up to\n"
    "                   16 images of one person, comma-separated (all faces\n"
    "                   or all photos), are fitted as one subject (one\n"
    "                   identity, one fine-tuning; docs/subjects.md) and the\n"
    "                   targets rendered from image --ref's expression,\n"
    "                   lights and head pose (and pasted back into it)\n"
    "  --ref I          (with --image) the image rendered from, 0 (the first)\n"
    "                   by default\n"
    "  --image-gaze-deg LIST  (with --image) the images' known gaze, one P,Y\n"
    "                   per image separated by ';', '-' where unknown\n"
    "  --image-head-deg LIST  (with normalized faces) their known head pose,\n"
    "                   as --image-gaze-deg\n"
    "  --gaze-deg LIST  targets, head frame, degrees (pitch > 0 looks up,\n"
    "                   yaw > 0 toward image-left), separated by ';';\n"
    "                   pitch in [-50, 50], yaw in [-60, 60], inclusive\n"
    "  --subject S.bin  a subject from gazesplat fit; one written with\n"
    "                   --finetune renders with its tuned tensors\n"
    "  --iters N        fit iteration cap (200)\n"
    "  --finetune N     (with --image) fine-tune a copy of the model on the\n"
    "                   face after the fit, as gazesplat fit does\n"
    "  --transfer       detail transfer: add back what the fit could not\n"
    "                   reproduce (the input's residual against the model,\n"
    "                   carried through the model's geometry; the eyeballs\n"
    "                   turn with the gaze). Needs the input: --image, or\n"
    "                   --subject with --image naming the face it was\n"
    "                   fitted to\n"
    "  --head-deg P,Y   render with this head pose instead of the subject's\n"
    "                   (pitch and yaw in [-70, 70], inclusive);\n"
    "                   the lights stay where they are in the camera, so\n"
    "                   the shading changes as the head turns\n"
    "  --light-on-head  (with --head-deg) keep the fitted light on the head\n"
    "                   instead: the shading turns with it\n"
    "  --transfer-head-weight W  (with --transfer and --head-deg) weight of\n"
    "                   the smoothed skin residual carried to the new head\n"
    "                   pose, 0..1 (0.5; 0 = the model's render there)\n"
    "  --transfer-eye-weight W  (with --transfer) weight of the eyeball\n"
    "                   residual once the eye has turned a few degrees from\n"
    "                   the input's gaze, 0..1 (0.5; all of it at the\n"
    "                   input's own gaze, reached smoothly)\n"
    "  --transfer-eye-warp DEG  (with --transfer) at the input's head pose\n"
    "                   the input's eyeball pixels, turned with the eye\n"
    "                   inside its opening, weighted exp(-(turn / DEG)^2);\n"
    "                   0..90 (20; 0 = off)\n"
    "  --no-gate        redirect whatever the image holds; by default a face\n"
    "                   the gate refuses exits 3 with the reason: no face,\n"
    "                   eyes under 16 px wide or closed, head beyond the\n"
    "                   trained range (yaw 60, pitch 40 deg), the face cut\n"
    "                   by the border, a flat or noise image (docs/face.md)\n"
    "  --out DIR        writes DIR/000.png, 001.png, ... (created if needed)\n",
    .opts = redirect_opts,
    .nopts = CLI_NOPTS(redirect_opts),
    .run_opts = run_redirect,
};

#define DEG (3.14159265358979323846 / 180.0)

static int load_model(const cli_command *cmd, const char *path, gs_model **m)
{
    gs_error err = {0, ""};
    if (gs_model_load(path, m, &err))
        return cli_fail(cmd, "%s: %s", path, err.msg);
    return CLI_OK;
}

/* Progress of a fit or a fine-tune: the library polls its cancel
 * callback once per iteration; this one never cancels, it counts and
 * reports (cli_progress: in place on a terminal, a line every 10 s
 * elsewhere). */
typedef struct iter_progress {
    cli_progress_t p;
    const char *cmd, *what;
    int n, total;
} iter_progress;

static int report_iteration(void *arg)
{
    iter_progress *ip = arg;
    ip->n++;
    cli_progress(&ip->p, 0, "gazesplat %s: %s, iteration %d of at most %d, %.1f s", ip->cmd, ip->what,
                 ip->n, ip->total, cli_now_s() - ip->p.start);
    return 0;
}

static void iter_progress_start(iter_progress *ip, const char *cmd, const char *what, int total)
{
    cli_progress_start(&ip->p);
    ip->cmd = cmd;
    ip->what = what;
    ip->n = 0;
    ip->total = total;
}

/* After a fit: a copy of m fine-tuned on the n fitted images (ft->iters
 * steps; one set of tuned parameters over the n pairs), reported on
 * stderr. */
static int finetune_copy(const cli_command *cmd, gs_model *m, gs_pool *pool, int n,
                         const gs_subject *subs, const gs_fit_image *im,
                         const gs_finetune_options *ft, gs_model **tuned)
{
    gs_error err = {0, ""};
    gs_finetune_options fo = *ft;
    gs_finetune_report r;
    char parts[64];
    iter_progress ip;
    iter_progress_start(&ip, cmd->name, "fine-tuning", fo.iters > 0 ? fo.iters : 50);
    fo.cancel = report_iteration;
    fo.cancel_arg = &ip;
    *tuned = NULL;
    int frc = gs_redirect_finetune(tuned, m, pool, subs, im, n, &fo, &r, &err);
    cli_progress_done(&ip.p);
    if (frc)
        return cli_fail(cmd, "finetune: %s", err.msg);
    fprintf(stderr,
            "gazesplat %s: fine-tuned %s (%zu floats) for %d steps in %.2f s%s: "
            "PSNR %.2f -> %.2f dB%s\n",
            cmd->name, gs_finetune_parts_name(fo.parts ? fo.parts : GS_FT_DEFAULT, parts,
                                         sizeof parts),
            r.params_tuned, r.iters, r.seconds,
            r.stopped_on_plateau ? " (plateau)" : r.stopped_on_time ? " (time)" : "",
            r.psnr_first, r.psnr_best, n > 1 ? " (mean over the images)" : "");
    return CLI_OK;
}

/* The images one subject is fitted from (--image A,B,... of gazesplat fit
 * and redirect): paths, masks and labels per image, and the image whose
 * expression, lights and head pose the subject keeps (--ref). */
typedef struct fit_inputs {
    int n, ref;
    char *buf, *mask_buf; /* the lists' copies */
    const char *image[GS_FIT_IMAGES_MAX], *mask[GS_FIT_IMAGES_MAX];
    int known_gaze[GS_FIT_IMAGES_MAX], known_head[GS_FIT_IMAGES_MAX];
    double gaze[GS_FIT_IMAGES_MAX][2], head[GS_FIT_IMAGES_MAX][2]; /* degrees */
} fit_inputs;

static void fit_inputs_free(fit_inputs *fi)
{
    free(fi->buf);
    free(fi->mask_buf);
    memset(fi, 0, sizeof *fi);
}

/* Parses the lists (masks, gaze, head and ref may be NULL); every item is
 * checked before any work. */
static int fit_inputs_parse(const cli_command *cmd, const char *images, const char *masks,
                            const char *gaze, const char *head, const char *ref,
                            const char *gaze_flag, const char *head_flag, fit_inputs *fi)
{
    memset(fi, 0, sizeof *fi);
    int rc = cli_split_paths(cmd, "--image", images, GS_FIT_IMAGES_MAX, &fi->buf, fi->image, &fi->n);
    int nm = 0;
    if (!rc && masks &&
        !(rc = cli_split_paths(cmd, "--mask", masks, GS_FIT_IMAGES_MAX, &fi->mask_buf, fi->mask, &nm)) &&
        nm != fi->n)
        rc = cli_usage_error(cmd, "--mask: %d masks for %d images: one per image", nm, fi->n);
    if (!rc && gaze)
        rc = cli_parse_image_labels(cmd, gaze_flag, gaze, 0, fi->n, fi->gaze, fi->known_gaze);
    if (!rc && head)
        rc = cli_parse_image_labels(cmd, head_flag, head, 1, fi->n, fi->head, fi->known_head);
    long r = 0;
    if (!rc && ref && cli_parse_long(ref, 0, fi->n - 1, &r))
        rc = cli_usage_error(cmd, "--ref: want 0..%d, an index into --image", fi->n - 1);
    fi->ref = (int)r;
    if (rc)
        fit_inputs_free(fi);
    return rc;
}

/* Reads image i (and its mask) of fi: a normalized face of the model's
 * size (in->norm), through the gate when asked; *w: its weights or NULL. */
static int read_face(const cli_command *cmd, const gs_model_info *info, const fit_inputs *fi, int i,
                     int gate, gs_redirect_input *in, uint8_t **w)
{
    const char *image = fi->image[i], *mask = fi->mask[i];
    gs_io_image mk = {0}, face = {0};
    gs_error err = {0, ""};
    *w = NULL;
    memset(in, 0, sizeof *in);
    if (gs_io_image_read(image, NULL, &face, &err))
        return cli_fail(cmd, "%s: %s", image, err.msg);
    int rc = CLI_OK;
    if (gs_redirect_input_face(info, &face, gate, in, &err)) {
        cli_fail(cmd, "%s: %s", image, err.msg);
        rc = in->gate.refusal != GS_FACE_USABLE ? CLI_REFUSED : CLI_FAIL;
    }
    const gs_io_image *img = &in->norm;
    if (!rc && mask) {
        if (gs_io_image_read(mask, NULL, &mk, &err))
            rc = cli_fail(cmd, "%s: %s", mask, err.msg);
        else if (mk.width != img->width || mk.height != img->height)
            rc = cli_fail(cmd, "mask size differs from the image");
        else if (!(*w = malloc((size_t)img->width * img->height)))
            rc = cli_fail(cmd, "out of memory");
        for (int y = 0; !rc && y < img->height; y++)
            for (int x = 0; x < img->width; x++)
                (*w)[(size_t)y * img->width + x] = mk.data[(size_t)y * mk.stride + 3 * x];
    }
    gs_io_image_free(&mk);
    return rc;
}

/* Fits one subject to fi's images (one identity; each image its own
 * expression, lights, gaze and head); *sub is image fi->ref's. With
 * ft->iters > 0 also fine-tunes a copy of m on them (*tuned, NULL
 * otherwise). */
static int fit_image(const cli_command *cmd, gs_model *m, gs_pool *pool, const fit_inputs *fi,
                     long iters, double budget, const gs_finetune_options *ft, int gate,
                     gs_subject *sub, gs_model **tuned)
{
    double t_start = cli_now_s();
    *tuned = NULL;
    gs_model_info info;
    gs_model_get_info(m, &info);
    const int n = fi->n;
    gs_redirect_input img[GS_FIT_IMAGES_MAX];
    uint8_t *w[GS_FIT_IMAGES_MAX] = {0};
    gs_fit_image im[GS_FIT_IMAGES_MAX];
    gs_subject subs[GS_FIT_IMAGES_MAX];
    memset(img, 0, sizeof img);
    int rc = CLI_OK;
    for (int i = 0; !rc && i < n; i++) {
        rc = read_face(cmd, &info, fi, i, gate, &img[i], &w[i]);
        gs_fit_image_from_options(&im[i], img[i].norm.data, img[i].norm.stride, NULL);
        im[i].mask = w[i];
        if (fi->known_gaze[i]) { /* degrees, checked by the parser */
            im[i].known_gaze = 1;
            im[i].gaze_pitch = fi->gaze[i][0] * DEG;
            im[i].gaze_yaw = fi->gaze[i][1] * DEG;
        }
        if (fi->known_head[i]) { /* the face centre on the camera's axis */
            im[i].known_head = 1;
            gs_geom_rot_from_pitchyaw(fi->head[i][0] * DEG, fi->head[i][1] * DEG, 0, im[i].head_R);
            im[i].head_t[2] = info.distance_mm;
        }
    }
    gs_fit_options o;
    gs_fit_options_default(&o);
    o.max_iters = (int)iters;
    o.time_budget_s = budget;
    iter_progress ip;
    iter_progress_start(&ip, cmd->name, "fit", o.max_iters > 0 ? o.max_iters : 200);
    o.cancel = report_iteration;
    o.cancel_arg = &ip;
    gs_error err = {0, ""};
    if (!rc) {
        gs_model_ctx *c = gs_model_ctx_create(m);
        gs_fit_report r;
        int frc = c ? gs_model_fit_images(c, pool, im, n, &o, subs, &r, &err) : GS_ERR_NOMEM;
        cli_progress_done(&ip.p);
        if (!c)
            rc = cli_fail(cmd, "out of memory");
        else if (frc)
            rc = cli_fail(cmd, "fit: %s", err.msg);
        else
            *sub = subs[fi->ref];
        if (!rc && n > 1)
            fprintf(stderr, "gazesplat %s: fit %d images, %d iterations in %.2f s%s; "
                    "the subject is image %d's\n", cmd->name, n, r.iters, r.seconds,
                    r.stopped_on_plateau ? " (plateau)" : "", fi->ref);
        for (int i = 0; !rc && i < n; i++)
            if (n == 1)
                fprintf(stderr,
                        "gazesplat %s: fit %d iterations in %.2f s%s: PSNR %.2f "
                        "dB, SSIM %.4f; gaze %.1f,%.1f deg\n",
                        cmd->name, r.iters, r.seconds,
                        r.stopped_on_plateau ? " (plateau)" : "", sub->fit_psnr,
                        sub->fit_ssim, sub->gaze_pitch / DEG,
                        sub->gaze_yaw / DEG);
            else
                fprintf(stderr, "gazesplat %s: image %d (%s): PSNR %.2f dB, SSIM %.4f; "
                        "gaze %.1f,%.1f deg\n", cmd->name, i, fi->image[i], subs[i].fit_psnr,
                        subs[i].fit_ssim, subs[i].gaze_pitch / DEG, subs[i].gaze_yaw / DEG);
        gs_model_ctx_destroy(c);
    }
    if (!rc && ft->iters > 0) {
        /* --time bounds the fit and the fine-tuning together. */
        gs_finetune_options f2 = *ft;
        if (budget > 0) {
            f2.time_budget_s = budget - (cli_now_s() - t_start);
            f2.time_budget_s = f2.time_budget_s > 1e-3 ? f2.time_budget_s : 1e-3;
        }
        rc = finetune_copy(cmd, m, pool, n, subs, im, &f2, tuned);
    }
    for (int i = 0; i < n; i++) {
        free(w[i]);
        gs_redirect_input_free(&img[i]);
    }
    return rc;
}

_Static_assert(CLI_NOPTS(fit_opts) == 16, "fit_opts: one entry per option index");

static int run_fit(const cli_command *cmd, cli_opt *o)
{
    int rc = CLI_OK;
    if (!o[0].value || !o[1].value || !o[6].value)
        return cli_usage_error(cmd, "--model, --image and --out are needed");
    long iters = GS_REDIRECT_FIT_ITERS;
    float budget = 0;
    if (o[4].value && cli_parse_long(o[4].value, 1, 100000, &iters))
        return cli_usage_error(cmd, "--iters: want 1..100000");
    if (o[5].value && (cli_parse_floats(o[5].value, &budget, 1) ||
                       !(budget > 0 && budget < 1e5)))
        return cli_usage_error(cmd, "--time: want seconds > 0");
    gs_finetune_options ft;
    if ((rc = cli_parse_finetune(cmd, o[7].value, o[8].value, o[9].value, o[10].value,
                                 o[11].value, o[12].value, &ft)))
        return rc;
    fit_inputs fi;
    if ((rc = fit_inputs_parse(cmd, o[1].value, o[2].value, o[3].value, o[14].value, o[15].value,
                               "--gaze-deg", "--head-deg", &fi)))
        return rc;
    gs_model *m = NULL;
    if ((rc = load_model(cmd, o[0].value, &m))) {
        fit_inputs_free(&fi);
        return rc;
    }
    gs_pool *pool = gs_pool_create(2);
    gs_subject sub;
    gs_model *tuned = NULL;
    rc = fit_image(cmd, m, pool, &fi, iters, budget, &ft, !o[13].value, &sub, &tuned);
    fit_inputs_free(&fi);
    uint8_t *blk = NULL;
    size_t blen = 0;
    gs_error err = {0, ""};
    if (!rc && tuned && gs_model_tuned_encode(tuned, &blk, &blen, &err))
        rc = cli_fail(cmd, "finetune: %s", err.msg);
    if (!rc) {
        /* The subject, then the tuned block when there is one; written to
         * a temporary name and renamed, so a failure leaves no half file. */
        uint8_t buf[GS_SUBJECT_ENCODED_MAX];
        size_t n = gs_subject_encode(&sub, buf, sizeof buf);
        char tmp[4096];
        snprintf(tmp, sizeof tmp, "%s.tmp", o[6].value);
        FILE *f = fopen(tmp, "wb");
        int bad = !f || fwrite(buf, 1, n, f) != n || (blk && fwrite(blk, 1, blen, f) != blen);
        if (f && fclose(f))
            bad = 1;
        if (bad || rename(tmp, o[6].value)) {
            remove(tmp);
            rc = cli_fail(cmd, "cannot write %s", o[6].value);
        }
    }
    free(blk);
    gs_model_destroy(tuned);
    gs_pool_destroy(pool);
    gs_model_destroy(m);
    return rc;
}

/* mkdir -p of one level: an existing directory is fine. */
static int make_dir(const char *path)
{
    struct stat st;
    return mkdir(path, 0777) == 0 ||
           (stat(path, &st) == 0 && S_ISDIR(st.st_mode));
}

/* A subject file: the encoded subject, then (gazesplat fit --finetune)
 * a tuned block, which *tuned gets: a clone of m with it applied. */
#define MAX_SUBJECT_FILE ((size_t)1 << 30)
static int read_subject(const cli_command *cmd, const char *path, gs_model *m,
                        gs_subject *s, gs_model **tuned)
{
    *tuned = NULL;
    uint8_t *buf = NULL;
    size_t n = 0;
    if (cli_read_file(path, MAX_SUBJECT_FILE, &buf, &n))
        return cli_fail(cmd, "cannot read %s (missing, empty or over 1 GiB)", path);
    /* A subject, then maybe a tuned block; decode explains a bad header. */
    size_t slen = gs_subject_encoded_len(buf, n);
    if (slen == 0 || slen > n)
        slen = n;
    gs_error err = {0, ""};
    int rc = CLI_OK;
    if (gs_subject_decode(buf, slen, s, &err))
        rc = cli_fail(cmd, "%s: %s", path, err.msg);
    else if (n > slen) {
        if (gs_model_clone(m, tuned, &err) ||
            gs_model_tuned_apply(*tuned, m, buf + slen, n - slen, &err)) {
            rc = cli_fail(cmd, "%s: %s", path, err.msg);
            gs_model_destroy(*tuned);
            *tuned = NULL;
        } else {
            gs_model_info ti;
            char parts[64];
            gs_model_get_info(*tuned, &ti);
            fprintf(stderr, "gazesplat %s: %s: fine-tuned %s\n", cmd->name, path,
                    gs_finetune_parts_name(ti.tuned_parts, parts, sizeof parts));
        }
    }
    free(buf);
    return rc;
}

/* The photo path: detect -> landmarks -> pose -> normalize -> fit ->
 * render each target -> paste the eye regions back into the photo. With
 * several photos of one person (fi->n > 1) each is normalized and they
 * are fitted as one subject (one identity, one fine-tuning); the targets
 * are rendered from photo fi->ref's subject and pasted back into it. */
static int redirect_photo(const cli_command *cmd, gs_model *m, gs_pool *pool,
                          const fit_inputs *fi, int index, int iters,
                          const gs_finetune_options *ft, double tg[][2],
                          int nt, const char *dir, int out_norm, int transfer, int gate)
{
    gs_model *tuned = NULL;
    gs_model_info info;
    gs_model_get_info(m, &info);
    int S = info.image_size;
    const int n = fi->n, ref = fi->ref;
    gs_error err = {0, ""};
    gs_io_image face = {S, S, 3 * (size_t)S, NULL};
    gs_redirect_input in[GS_FIT_IMAGES_MAX];
    gs_redirect_paste_state ps;
    memset(in, 0, sizeof in);
    memset(&ps, 0, sizeof ps);
    gs_face_detector *det = NULL;
    gs_face_shape_model *sp = NULL;
    gs_model_ctx *c = NULL;
    gs_fit_image im[GS_FIT_IMAGES_MAX];
    gs_subject subs[GS_FIT_IMAGES_MAX];
    int rc = CLI_OK;
    if (gs_face_detector_load(NULL, &det, &err) || gs_face_shape_model_load(NULL, &sp, &err)) {
        rc = cli_fail(cmd, "%s", err.msg);
        goto done;
    }
    gs_redirect_photo_opts po;
    gs_redirect_photo_opts_default(&po);
    po.index = index;
    po.gate = gate;
    for (int i = 0; i < n; i++) {
        const char *path = fi->image[i];
        gs_io_image photo = {0};
        if (gs_io_image_read(path, NULL, &photo, &err) ||
            gs_redirect_input_photo(det, sp, &info, &photo, &po, &in[i], &err)) {
            gs_io_image_free(&photo);
            rc = cli_fail(cmd, "%s: %s", path, err.msg);
            if (in[i].gate.refusal != GS_FACE_USABLE)
                rc = CLI_REFUSED;
            goto done;
        }
        gs_fit_options oi;
        gs_redirect_fit_options(&in[i], &oi);
        oi.max_iters = iters;
        gs_fit_image_from_options(&im[i], in[i].norm.data, in[i].norm.stride, &oi);
        if (fi->known_gaze[i]) {
            im[i].known_gaze = 1;
            im[i].gaze_pitch = fi->gaze[i][0] * DEG;
            im[i].gaze_yaw = fi->gaze[i][1] * DEG;
        }
    }
    const gs_redirect_input *r0 = &in[ref];
    face.data = malloc(face.stride * (size_t)S);
    c = gs_model_ctx_create(m);
    if (!face.data || !c) {
        rc = cli_fail(cmd, "out of memory");
        goto done;
    }
    gs_fit_options o;
    gs_fit_options_default(&o);
    o.max_iters = iters;
    gs_fit_report r;
    if (gs_model_fit_images(c, pool, im, n, &o, subs, &r, &err)) {
        rc = cli_fail(cmd, "fit: %s", err.msg);
        goto done;
    }
    const gs_subject sub = subs[ref];
    if (n > 1)
        fprintf(stderr, "gazesplat redirect: %d photos fitted as one subject, %d iterations; "
                "rendering from photo %d (%s)\n", n, r.iters, ref, fi->image[ref]);
    fprintf(stderr, "gazesplat redirect: face %d of %d, head %.1f,%.1f deg; "
            "fit %d iterations, PSNR %.2f dB; gaze %.1f,%.1f deg\n",
            index, r0->face.n_faces, r0->face.head_pitch_n / DEG, r0->face.head_yaw_n / DEG,
            r.iters, sub.fit_psnr, sub.gaze_pitch / DEG, sub.gaze_yaw / DEG);
    if (ft->iters > 0) { /* render with the tuned copy from here on */
        if ((rc = finetune_copy(cmd, m, pool, n, subs, im, ft, &tuned)))
            goto done;
        gs_model_ctx_destroy(c);
        if (!(c = gs_model_ctx_create(tuned))) {
            rc = cli_fail(cmd, "out of memory");
            goto done;
        }
    }
    gs_xfer_eyes eyes = gs_redirect_eyes(r0);
    for (int k = 0; k < nt && !rc; k++) {
        gs_view v = {0};
        v.gaze_pitch = tg[k][0];
        v.gaze_yaw = tg[k][1];
        char out[4096];
        if (gs_redirect_render(c, pool, &sub, transfer ? r0->norm.data : NULL, r0->norm.stride,
                               &eyes, &v,
                               face.data, face.stride, &err)) {
            rc = cli_fail(cmd, "target %d: %s", k, err.msg);
            break;
        }
        if (out_norm) {
            snprintf(out, sizeof out, "%s/norm_%03d.png", dir, k);
            if (gs_io_image_write(out, &face, GS_IO_PNG, 0, &err))
                rc = cli_fail(cmd, "%s: %s", out, err.msg);
        }
        snprintf(out, sizeof out, "%s/%03d.png", dir, k);
        if (gs_redirect_paste(r0, &ps, 0, &face, &err) ||
            gs_io_image_write(out, &ps.out, GS_IO_PNG, 0, &err))
            rc = cli_fail(cmd, "%s: %s", out, err.msg);
    }
    if (!rc)
        printf("gazesplat redirect: %d images -> %s\n", nt, dir);
done:
    gs_model_ctx_destroy(c);
    gs_model_destroy(tuned);
    free(face.data);
    gs_redirect_paste_free(&ps);
    for (int i = 0; i < n; i++)
        gs_redirect_input_free(&in[i]);
    gs_face_detector_destroy(det);
    gs_face_shape_model_destroy(sp);
    return rc;
}

_Static_assert(CLI_NOPTS(redirect_opts) == 24, "redirect_opts: one entry per option index");

static int run_redirect(const cli_command *cmd, cli_opt *o)
{
    int rc = CLI_OK;
    int transfer = o[13].value != NULL;
    if (!o[0].value || !o[3].value || !o[4].value || (!o[1].value && !o[2].value) ||
        (o[1].value && o[2].value && !transfer))
        return cli_usage_error(cmd, "--model, --gaze-deg, --out and one of "
                                    "--subject / --image are needed (both only "
                                    "with --transfer)");
    if (transfer && !o[2].value)
        return cli_usage_error(cmd, "--transfer needs the input face: --image");
    if (o[14].value && !o[5].value)
        return cli_usage_error(cmd, "--light-on-head goes with --head-deg");
    double head_w = GS_XFER_HEAD_WEIGHT_DEFAULT, eye_w = GS_XFER_EYE_WEIGHT_DEFAULT;
    if (o[15].value && (!transfer || !o[5].value))
        return cli_usage_error(cmd, "--transfer-head-weight goes with --transfer "
                                    "and --head-deg");
    double warp_deg = GS_XFER_EYE_WARP_DEG_DEFAULT;
    if (o[16].value && !transfer)
        return cli_usage_error(cmd, "--transfer-eye-weight goes with --transfer");
    if (o[19].value && !transfer)
        return cli_usage_error(cmd, "--transfer-eye-warp goes with --transfer");
    if ((rc = cli_parse_unit(cmd, "--transfer-head-weight", o[15].value, &head_w)) ||
        (rc = cli_parse_unit(cmd, "--transfer-eye-weight", o[16].value, &eye_w)) ||
        (rc = cli_parse_range(cmd, "--transfer-eye-warp", o[19].value, 0.0, 90.0,
                              CLI_WARP_WANT, &warp_deg)))
        return rc;
    /* Parse and check every target (the target table, gazesplat/model.h)
     * before any work. */
    enum { MAXT = 256 };
    double tg[MAXT][2], head[1][2] = {{0, 0}};
    int nt = 0, nh = 0;
    if ((rc = cli_parse_angles(cmd, "--gaze-deg", o[3].value, 1, 0, tg, MAXT, &nt)) ||
        (o[5].value && (rc = cli_parse_angles(cmd, "--head-deg", o[5].value, 0, 1, head, 1, &nh))))
        return rc;
    for (int k = 0; k < nt; k++) {
        tg[k][0] *= DEG;
        tg[k][1] *= DEG;
    }
    gs_finetune_options ft;
    if ((rc = cli_parse_finetune(cmd, o[9].value, o[10].value, o[11].value, o[12].value,
                                 o[17].value, o[18].value, &ft)))
        return rc;
    if (ft.iters > 0 && o[1].value)
        return cli_usage_error(cmd, "--finetune goes with --image (a subject file "
                                    "carries its own fine-tuning)");
    if ((o[21].value || o[22].value || o[23].value) && (!o[2].value || o[1].value))
        return cli_usage_error(cmd, "--ref, --image-gaze-deg and --image-head-deg go with "
                                    "--image (the faces fitted here)");
    fit_inputs fi;
    memset(&fi, 0, sizeof fi);
    if (o[2].value && (rc = fit_inputs_parse(cmd, o[2].value, NULL, o[22].value, o[23].value,
                                             o[21].value, "--image-gaze-deg",
                                             "--image-head-deg", &fi)))
        return rc;
    if (o[1].value && fi.n > 1) {
        fit_inputs_free(&fi);
        return cli_usage_error(cmd, "--transfer with --subject takes the one face it was "
                                    "fitted to: --image FACE");
    }
    gs_model *m = NULL;
    if ((rc = load_model(cmd, o[0].value, &m))) {
        fit_inputs_free(&fi);
        return rc;
    }
    gs_pool *pool = gs_pool_create(2);
    long index = 0, iters = GS_REDIRECT_FIT_ITERS;
    if ((o[6].value && cli_parse_long(o[6].value, 0, 1000, &index)) ||
        (o[8].value && cli_parse_long(o[8].value, 1, 100000, &iters))) {
        gs_pool_destroy(pool);
        gs_model_destroy(m);
        fit_inputs_free(&fi);
        return cli_usage_error(cmd, "--index: want 0..1000; --iters: 1..1e5");
    }
    if (o[2].value && !o[1].value) {
        /* A photo unless it is already a normalized face of the model's
         * size. */
        gs_model_info mi;
        gs_model_get_info(m, &mi);
        int photo = 1, photos = 0;
        for (int i = 0; i < fi.n; i++) {
            gs_io_image probe = {0};
            gs_error perr = {0, ""};
            int p = 1;
            if (gs_io_image_read(fi.image[i], NULL, &probe, &perr) == GS_OK)
                p = probe.width != mi.image_size ||
                    probe.height != mi.image_size || o[6].value;
            gs_io_image_free(&probe);
            photos += p;
            photo = i == 0 ? p : photo;
        }
        const char *bad = NULL;
        if (photos != 0 && photos != fi.n)
            bad = "--image: the images of one subject are all photos or all "
                  "normalized faces of the model's size";
        else if (photo && o[5].value)
            bad = "--head-deg needs a normalized face of the model's size; a "
                  "photo keeps its head pose (only the gaze changes)";
        else if (photo && o[23].value)
            bad = "--image-head-deg goes with normalized faces; a photo's head "
                  "pose comes from its landmarks";
        if (bad) {
            gs_pool_destroy(pool);
            gs_model_destroy(m);
            fit_inputs_free(&fi);
            return cli_usage_error(cmd, "%s", bad);
        }
        if (photo) {
            if (!make_dir(o[4].value))
                rc = cli_fail(cmd, "cannot create %s", o[4].value);
            else
                rc = redirect_photo(cmd, m, pool, &fi, (int)index,
                                    (int)iters, &ft, tg, nt, o[4].value,
                                    o[7].value != NULL, transfer, !o[20].value);
            gs_pool_destroy(pool);
            gs_model_destroy(m);
            fit_inputs_free(&fi);
            return rc;
        }
    }
    gs_subject sub;
    gs_model *tuned = NULL;
    rc = o[1].value ? read_subject(cmd, o[1].value, m, &sub, &tuned)
                    : fit_image(cmd, m, pool, &fi, iters, 0, &ft, !o[20].value, &sub, &tuned);
    /* --transfer: from the face the subject renders from (--ref's) */
    const char *input_path = fi.n ? fi.image[fi.ref] : NULL;
    if (!rc && !make_dir(o[4].value))
        rc = cli_fail(cmd, "cannot create %s", o[4].value);
    gs_model_info info;
    gs_model_get_info(m, &info);
    gs_model_ctx *c = rc ? NULL : gs_model_ctx_create(tuned ? tuned : m);
    if (!rc && !c)
        rc = cli_fail(cmd, "out of memory");
    if (!rc && (o[15].value || o[16].value || o[19].value)) {
        gs_model_render_options ro;
        gs_model_render_options_default(&ro);
        ro.transfer_head_weight = head_w;
        ro.transfer_eye_weight = eye_w;
        ro.transfer_eye_warp_deg = warp_deg;
        gs_error err = {0, ""};
        if (gs_model_ctx_set_render_options(c, &ro, &err))
            rc = cli_fail(cmd, "transfer weights: %s", err.msg);
    }
    gs_io_image img = {info.image_size, info.image_size,
                       3 * (size_t)info.image_size, NULL};
    img.data = malloc(img.stride * (size_t)img.height);
    gs_io_image input = {0}; /* --transfer: the face the subject was fitted to */
    if (!rc && transfer) {
        gs_error err = {0, ""};
        if (gs_io_image_read(input_path, NULL, &input, &err))
            rc = cli_fail(cmd, "%s: %s", input_path, err.msg);
        else if (input.width != info.image_size || input.height != info.image_size)
            rc = cli_fail(cmd, "%s: %dx%d, the subject's face is %dx%d", input_path,
                          input.width, input.height, info.image_size, info.image_size);
    }
    for (int k = 0; !rc && k < nt; k++) {
        gs_view v = {0};
        v.gaze_pitch = tg[k][0];
        v.gaze_yaw = tg[k][1];
        if (o[5].value) {
            v.use_head = 1;
            v.light_on_head = o[14].value != NULL;
            /* Head angles as geom.h defines them (z-axis of R). */
            gs_geom_rot_from_pitchyaw(head[0][0] * DEG, head[0][1] * DEG, 0,
                                      v.head_R);
            memcpy(v.head_t, sub.head_t, sizeof v.head_t);
        }
        gs_error err = {0, ""};
        char path[4096];
        snprintf(path, sizeof path, "%s/%03d.png", o[4].value, k);
        if (gs_redirect_render(c, pool, &sub, transfer ? input.data : NULL, input.stride, NULL, &v,
                          img.data, img.stride, &err) ||
            gs_io_image_write(path, &img, GS_IO_PNG, 0, &err))
            rc = cli_fail(cmd, "target %d: %s", k, err.msg);
    }
    if (!rc)
        printf("gazesplat redirect: %d images -> %s\n", nt, o[4].value);
    free(img.data);
    gs_io_image_free(&input);
    gs_model_ctx_destroy(c);
    gs_model_destroy(tuned);
    gs_pool_destroy(pool);
    gs_model_destroy(m);
    fit_inputs_free(&fi);
    return rc;
}
