/* The synthesis readout: which way does the eyeball in an image point? On
 * synthetic heads everything of the target scene but the gaze is known,
 * so the gaze an image shows can be read by rendering that scene at
 * candidate gazes and keeping the one whose eyeballs match the image best
 * (analysis by synthesis).
 *
 * Two stages, both over the eye boxes only (a box per eye about its
 * eyeball centre's projection):
 *  1. Alignment. The scene at its own gaze (the reference) is rendered
 *     once; the image's 2D shift t is the one that best matches it on the
 *     boxes' still pixels: those no gaze changes (probe renders at the
 *     corners of the gaze range mark the eyeballs and the lids, which
 *     follow the pitch): corners, skin, brow edge. A face placed a pixel
 *     off is then not read as a gaze change, and neither moves the lids.
 *  2. Gaze. Candidates are compared with the shifted image on the pixels
 *     where the reference shows eyeball only: the gaze is read from the
 *     iris and sclera inside the true eye opening, not from the lids
 *     around it (the synthetic lids follow the gaze's pitch; a redirected
 *     image's lids may not). Candidates keep their lids: rendered with
 *     the lids pulled back (gs_synth_render_opts.open_lids) the eyeball
 *     loses the lids' shading, and the true target itself read 2-4.5
 *     degrees off.
 * Image and candidates are blurred alike first (blur_px), which makes the
 * match less sensitive to a slightly soft image.
 *
 * Softness (soft_max_px > 0). A redirection's eyes are softer than the
 * renderer's, and a soft eye matches a sharp render of the wrong gaze
 * better than one of its own: the true target blurred by sigma 1.5 px reads
 * 2.3 degrees off, by 2 px 4 degrees, through a 64-pixel map 9.9
 * (bench_readout). So each candidate is also compared blurred further, by
 * sqrt(blur_px^2 + s^2) for s = 0, 0.25, ... soft_max_px (Gaussians
 * compose so: that is the candidate as an image of softness s would show
 * it, after the image's own blur_px), and keeps the level that matches
 * best; the alignment likewise keeps the level whose reference its still
 * pixels match best (a sharp reference drags a blurred image's shift by
 * up to a pixel: several degrees of pitch). The levels are searched by
 * descent from the alignment's level (the grid) or the search centre's
 * (its neighbours). Sharp images read as before; the blurred targets read
 * within 0.15 degree on average.
 *
 * Cost: each candidate renders only the boxes' tiles; the candidates of a
 * search step are rendered in parallel, one per pool task, and reduced in
 * candidate order (deterministic for any thread count). */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "eval_internal.h"
#include "gazesplat/eval.h"

#define RD_PI 3.14159265358979323846
#define RD_DEG (RD_PI / 180.0)
/* Eye box of one eye: the eyeball centre's projection +- these many
 * projected eyeball radii (both corners and the lids). */
#define RD_HALF_W 1.7
#define RD_HALF_H 1.2
/* Coarse shift grid step (px); a parabola through it refines. */
#define RD_SHIFT_STEP 0.25
/* Starts of the gaze pattern search taken from the coarse grid. */
#define RD_STARTS 2
#define RD_MAX_CAND 128
/* Largest blur radius: 3 sigma for sigma up to 3 px. */
#define RD_MAX_R 9
/* Candidates stay within +-80 degrees of pitch and yaw. */
#define RD_LIMIT (80 * RD_DEG)
/* A pixel no probe gaze changes by more than this (summed RGB levels,
 * blurred) is still: the alignment uses those. */
#define RD_STILL 3.0f
/* Fewer still pixels than this: no alignment (the shift stays 0). */
#define RD_MIN_STILL 16
/* Two gazes closer than this (radians) in pitch and yaw are the same. */
#define RD_SAME 1e-9
/* Step of the image softness levels tried (soft_max_px), px. */
#define RD_SOFT_STEP 0.25
#define RD_MAX_SOFT 11

void gs_eval_readout_options_default(gs_eval_readout_options *o)
{
    o->max_shift_px = 4.0;
    o->blur_px = 1.0;
    o->grid_deg = 10.0;
    o->tol_deg = 0.05;
    o->pitch_range_deg = 40.0;
    o->yaw_range_deg = 50.0;
    o->soft_max_px = 0.0;
}

typedef struct rd_ctx {
    gs_synth_scene scene;       /* the target; its gaze is overwritten */
    gs_synth_camera cam;        /* the scene's normalized camera */
    int size;
    int nsoft;                  /* softness levels (1: only the blur) */
    int R[RD_MAX_SOFT];         /* level j's blur radius (px), 0: none */
    float ker[RD_MAX_SOFT][2 * RD_MAX_R + 1]; /* level 0: blur_px alone,
                                   level j: sqrt(blur_px^2 + (j step)^2) */
    int x0, y0, w, h;           /* bounding box of the eye boxes */
    uint8_t *inbox;             /* w * h: inside an eye box */
    int ex, ey, ew, eh;         /* box rendered: the bounding box + R + 1 */
    float *bimg;                /* the image, blurred, over the box
                                   (bx, by, bw, bh): the bounding box +
                                   R + the shift range + 1 */
    int bx, by, bw, bh;
    int n;                      /* eyeball pixels of the reference */
    int *idx;                   /* their indices in the bounding box */
    float *img;                 /* the image there, shifted by t, n * 3 */
    double t[2];
    int workers;
    gs_synth_sample *smp;       /* per worker */
    float *ebuf;                /* per worker, 2 * ew * eh * 3: the render,
                                   its rows blurred */
    int nh;                     /* rendered-box pixels whose row blur the
                                   eyeball pixels' column blur reads (any
                                   level) */
    int *hidx;                  /* their indices in the rendered box */
    /* the batch being evaluated */
    int nc;
    double g[RD_MAX_CAND][2];   /* pitch, yaw (radians) */
    double e[RD_MAX_CAND];      /* energy (mean square, 8-bit levels), the
                                   least over the softness levels */
    int lv[RD_MAX_CAND];        /* the level that gave it */
    int lv0;                    /* the batch's start level (the descent's) */
    int align_lv;               /* the level the alignment matched at */
    int rc[RD_MAX_CAND];
    gs_error err[RD_MAX_CAND];
    int renders;
    /* every gaze evaluated so far: pitch, yaw, energy, level */
    double (*memo)[4];
    int nmemo, memo_cap;
} rd_ctx;

/* The blurred image at (u, v) = pixel (x, y) + shift, bilinear. */
static void sample_at(const rd_ctx *c, int x, int y, double tx, double ty,
                      float out[3])
{
    double u = x + tx, v = y + ty;
    int xi = (int)floor(u), yi = (int)floor(v);
    double ax = u - xi, ay = v - yi;
    const float *p = c->bimg + 3 * ((size_t)(yi - c->by) * c->bw + (xi - c->bx));
    const float *q = p + 3 * (size_t)c->bw;
    for (int ch = 0; ch < 3; ch++)
        out[ch] = (float)((1 - ay) * ((1 - ax) * p[ch] + ax * p[3 + ch]) +
                          ay * ((1 - ax) * q[ch] + ax * q[3 + ch]));
}

/* One pass of blur level lv along x (dx 1) or y (dx 0) of a w x h RGB
 * float image, in to out, edges clamped. */
static void blur_pass(const rd_ctx *c, int lv, const float *in, float *out,
                      int w, int h, int dx)
{
    int R = c->R[lv], len = dx ? w : h;
    const float *ker = c->ker[lv];
    for (int y = 0; y < h; y++)
        for (int x = 0; x < w; x++) {
            int at = dx ? x : y;
            for (int ch = 0; ch < 3; ch++) {
                float a = 0;
                for (int d = -R; d <= R; d++) {
                    int q = at + d < 0 ? 0 : at + d >= len ? len - 1 : at + d;
                    size_t i = dx ? (size_t)y * w + q : (size_t)q * w + x;
                    a += ker[d + R] * in[3 * i + ch];
                }
                out[3 * ((size_t)y * w + x) + ch] = a;
            }
        }
}

/* Separable blur (level lv) of a w x h RGB float image in place (tmp: its
 * size). */
static void blur_rgb(const rd_ctx *c, int lv, float *img, float *tmp, int w,
                     int h)
{
    if (!c->R[lv])
        return;
    blur_pass(c, lv, img, tmp, w, h, 1);
    blur_pass(c, lv, tmp, img, w, h, 0);
}

/* Renders `sc` over the rendered box into sample s and its RGB (white
 * outside the head, as the targets are), not blurred, into eb
 * (ew * eh * 3 floats). */
static int render_raw(const rd_ctx *c, const gs_synth_scene *sc,
                      gs_synth_sample *s, float *eb, gs_error *err)
{
    gs_synth_render_opts o = {.supersample = 1,
                              .region = {c->ex, c->ey, c->ex + c->ew,
                                         c->ey + c->eh}};
    int rc = gs_synth_render(sc, &c->cam, &o, NULL, s, err);
    if (rc)
        return rc;
    const uint8_t *head = gs_synth_sample_mask(s, GS_SYNTH_MASK_HEAD);
    for (int y = 0; y < c->eh; y++)
        for (int x = 0; x < c->ew; x++) {
            size_t i = (size_t)(c->ey + y) * c->size + (c->ex + x);
            const uint8_t *p = s->rgb + (size_t)(c->ey + y) * s->stride +
                               3 * (size_t)(c->ex + x);
            for (int ch = 0; ch < 3; ch++)
                eb[3 * ((size_t)y * c->ew + x) + ch] = head[i] ? p[ch] : 255.0f;
        }
    return GS_OK;
}

/* render_raw, then the image's own blur (level 0) in place (eb: 2 * ew *
 * eh * 3 floats, the second half scratch). */
static int render_box(const rd_ctx *c, const gs_synth_scene *sc,
                      gs_synth_sample *s, float *eb, gs_error *err)
{
    int rc = render_raw(c, sc, s, eb, err);
    if (!rc)
        blur_rgb(c, 0, eb, eb + 3 * (size_t)c->ew * c->eh, c->ew, c->eh);
    return rc;
}

/* The energy (mean square, 8-bit levels) of a candidate's render raw at
 * softness level lv against the shifted image, over the eyeball pixels.
 * The blur is blur_rgb's, sum for sum, computed only where the eyeball
 * pixels need it: the row pass at c->hidx (into hb), the column pass at
 * the eyeball pixels. */
static double level_energy(const rd_ctx *c, int lv, const float *raw,
                           float *hb)
{
    int R = c->R[lv];
    const float *ker = c->ker[lv];
    for (int i = 0; R && i < c->nh; i++) {
        int at = c->hidx[i], x = at % c->ew, row = at - x;
        for (int ch = 0; ch < 3; ch++) {
            float a = 0;
            for (int d = -R; d <= R; d++) {
                int q = x + d < 0 ? 0 : x + d >= c->ew ? c->ew - 1 : x + d;
                a += ker[d + R] * raw[3 * (size_t)(row + q) + ch];
            }
            hb[3 * (size_t)at + ch] = a;
        }
    }
    double s = 0;
    for (int k = 0; k < c->n; k++) {
        int x = c->x0 + c->idx[k] % c->w - c->ex;
        int y = c->y0 + c->idx[k] / c->w - c->ey;
        for (int ch = 0; ch < 3; ch++) {
            float r = 0;
            if (!R)
                r = raw[3 * ((size_t)y * c->ew + x) + ch];
            for (int d = -R; R && d <= R; d++) {
                int q = y + d < 0 ? 0 : y + d >= c->eh ? c->eh - 1 : y + d;
                r += ker[d + R] * hb[3 * ((size_t)q * c->ew + x) + ch];
            }
            double dd = (double)c->img[3 * k + ch] - r;
            s += dd * dd;
        }
    }
    return s / (3.0 * c->n);
}

/* One candidate gaze: render once, then find its best softness level by
 * descent from the batch's start level c->lv0 (a level up, else a level
 * down, then on while the energy falls): the match against blur is
 * unimodal in practice, and bench_readout's table came out the same to
 * the digit as with a scan of every level. The least energy found is the
 * candidate's. */
static void eval_candidate(void *vctx, int task, int worker)
{
    rd_ctx *c = vctx;
    gs_synth_scene sc = c->scene;
    sc.gaze_pitch = c->g[task][0];
    sc.gaze_yaw = c->g[task][1];
    size_t ne = 3 * (size_t)c->ew * c->eh;
    float *raw = c->ebuf + (size_t)worker * 2 * ne, *hb = raw + ne;
    c->e[task] = INFINITY;
    c->lv[task] = 0;
    c->rc[task] = render_raw(c, &sc, &c->smp[worker], raw, &c->err[task]);
    if (c->rc[task])
        return;
    int lv = c->lv0, dir = 0;
    double e = level_energy(c, lv, raw, hb);
    for (int d = 1; !dir && d >= -1; d -= 2)
        if (lv + d >= 0 && lv + d < c->nsoft) {
            double e1 = level_energy(c, lv + d, raw, hb);
            if (e1 < e) {
                e = e1;
                lv += d;
                dir = d;
            }
        }
    while (dir && lv + dir >= 0 && lv + dir < c->nsoft) {
        double e1 = level_energy(c, lv + dir, raw, hb);
        if (!(e1 < e))
            break;
        e = e1;
        lv += dir;
    }
    c->e[task] = e;
    c->lv[task] = lv;
}

/* Evaluates the batch c->g[0..nc); returns the first render error. */
static int run_batch(rd_ctx *c, gs_pool *pool, gs_error *err)
{
    gs_pool_for(pool, c->nc, eval_candidate, c);
    c->renders += c->nc;
    for (int i = 0; i < c->nc; i++)
        if (c->rc[i]) {
            if (err)
                *err = c->err[i];
            return c->rc[i];
        }
    return GS_OK;
}

/* The energies of the gazes pts[0..n) (n <= RD_MAX_CAND) into e[]. Each
 * gaze is rendered once per reading: the search's neighbourhoods overlap
 * after a move, and its moves return to grid points, so a gaze met
 * before takes its remembered energy. */
static int eval_points(rd_ctx *c, gs_pool *pool, double (*pts)[2], int n,
                       double *e, int *lvs, gs_error *err)
{
    int slot[RD_MAX_CAND];
    c->nc = 0;
    for (int k = 0; k < n; k++) {
        slot[k] = -1;
        e[k] = NAN;
        for (int m = 0; m < c->nmemo && isnan(e[k]); m++)
            if (fabs(c->memo[m][0] - pts[k][0]) < RD_SAME &&
                fabs(c->memo[m][1] - pts[k][1]) < RD_SAME) {
                e[k] = c->memo[m][2];
                lvs[k] = (int)c->memo[m][3];
            }
        if (isnan(e[k])) {
            slot[k] = c->nc;
            c->g[c->nc][0] = pts[k][0];
            c->g[c->nc][1] = pts[k][1];
            c->nc++;
        }
    }
    if (!c->nc)
        return GS_OK;
    int rc = run_batch(c, pool, err);
    if (rc)
        return rc;
    if (c->nmemo + c->nc > c->memo_cap) {
        int cap = 2 * (c->nmemo + c->nc);
        double(*m)[4] = realloc(c->memo, sizeof *m * (size_t)cap);
        if (!m)
            return gs_error_set(err, GS_ERR_NOMEM, "gaze readout: out of "
                                "memory");
        c->memo = m;
        c->memo_cap = cap;
    }
    for (int k = 0; k < n; k++)
        if (slot[k] >= 0) {
            e[k] = c->e[slot[k]];
            lvs[k] = c->lv[slot[k]];
            double *m = c->memo[c->nmemo++];
            m[0] = pts[k][0];
            m[1] = pts[k][1];
            m[2] = e[k];
            m[3] = c->lv[slot[k]];
        }
    return GS_OK;
}

/* The eye boxes, inside the image by the shift range plus one pixel (for
 * the bilinear taps), and their bounding box. */
static int make_boxes(rd_ctx *c, const gs_synth_labels *l, double smax,
                      gs_error *err)
{
    double lo = smax + 1, hi = c->size - smax - 2;
    double box[2][4];
    int nbox = 0;
    double bx0 = INFINITY, by0 = INFINITY, bx1 = -INFINITY, by1 = -INFINITY;
    for (int e = 0; e < 2; e++) {
        double z = l->eye_centre[e][2];
        if (!(z > 0))
            continue;
        double r = l->K[0] * l->eyeball_radius_mm / z;
        double x0 = fmax(lo, l->eye_centre_uv[e][0] - RD_HALF_W * r);
        double x1 = fmin(hi, l->eye_centre_uv[e][0] + RD_HALF_W * r);
        double y0 = fmax(lo, l->eye_centre_uv[e][1] - RD_HALF_H * r);
        double y1 = fmin(hi, l->eye_centre_uv[e][1] + RD_HALF_H * r);
        if (!(x1 - x0 >= 2 && y1 - y0 >= 2))
            continue;
        double *b = box[nbox++];
        b[0] = x0;
        b[1] = y0;
        b[2] = x1;
        b[3] = y1;
        bx0 = fmin(bx0, x0);
        by0 = fmin(by0, y0);
        bx1 = fmax(bx1, x1);
        by1 = fmax(by1, y1);
    }
    if (!nbox)
        return gs_error_set(err, GS_ERR_ARG, "gaze readout: no eye inside "
                            "the image");
    c->x0 = (int)floor(bx0);
    c->y0 = (int)floor(by0);
    c->w = (int)ceil(bx1) - c->x0;
    c->h = (int)ceil(by1) - c->y0;
    c->inbox = calloc((size_t)c->w * c->h, 1);
    c->idx = malloc(sizeof *c->idx * (size_t)c->w * c->h);
    if (!c->inbox || !c->idx)
        return gs_error_set(err, GS_ERR_NOMEM, "gaze readout: out of memory");
    /* Pixel (x, y) covers [x, x + 1): those whose centre is inside. */
    for (int y = 0; y < c->h; y++)
        for (int x = 0; x < c->w; x++) {
            double u = c->x0 + x + 0.5, v = c->y0 + y + 0.5;
            for (int b = 0; b < nbox; b++)
                c->inbox[y * c->w + x] |= u >= box[b][0] && u <= box[b][2] &&
                                          v >= box[b][1] && v <= box[b][3];
        }
    return GS_OK;
}

/* Offset (in steps) of the minimum of the parabola through a, b, c at
 * -1, 0, 1; 0 when it is not convex. */
static double parabola_min(double a, double b, double c)
{
    double den = a - 2 * b + c;
    return den > 0 ? 0.5 * (a - c) / den : 0;
}

/* Stage 1: the shift of the image that best matches the reference (eb,
 * the rendered box) on the boxes' still pixels (eye[] 0: neither eyeball
 * nor changed by a probe gaze, with a pixel's margin): a grid of
 * step (RD_SHIFT_STEP), then a parabola per axis through the best's
 * neighbours. The grid's least energy (sum of squares) goes to *energy, 0
 * when there is nothing to align. */
static int align(rd_ctx *c, const float *eb, const uint8_t *eye,
                 double smax, double step, double *energy, gs_error *err)
{
    int ns = 1 + 2 * (int)lround(smax / step);
    int nsk = 0, rc = GS_OK;
    int *sk = malloc(sizeof *sk * (size_t)c->w * c->h);
    double *eg = malloc(sizeof *eg * (size_t)ns * ns);
    c->t[0] = c->t[1] = 0;
    *energy = 0;
    if (!sk || !eg) {
        rc = gs_error_set(err, GS_ERR_NOMEM, "gaze readout: out of memory");
        goto done;
    }
    if (ns == 1)
        goto done;
    for (int y = 0; y < c->h; y++)
        for (int x = 0; x < c->w; x++) {
            int near_eye = 0;
            for (int dy = -1; dy <= 1; dy++)
                for (int dx = -1; dx <= 1; dx++) {
                    int xx = c->x0 + x + dx, yy = c->y0 + y + dy;
                    near_eye |= eye[(size_t)yy * c->size + xx] != 0;
                }
            if (c->inbox[y * c->w + x] && !near_eye)
                sk[nsk++] = y * c->w + x;
        }
    if (nsk < RD_MIN_STILL)
        goto done; /* nothing to align on: no shift */
    int bi = 0;
    for (int i = 0; i < ns * ns; i++) {
        double tx = (i % ns) * step - smax;
        double ty = (i / ns) * step - smax;
        double s = 0;
        for (int k = 0; k < nsk; k++) {
            int x = c->x0 + sk[k] % c->w, y = c->y0 + sk[k] / c->w;
            float v[3];
            sample_at(c, x, y, tx, ty, v);
            const float *r = eb + 3 * ((size_t)(y - c->ey) * c->ew + (x - c->ex));
            for (int ch = 0; ch < 3; ch++)
                s += ((double)v[ch] - r[ch]) * ((double)v[ch] - r[ch]);
        }
        eg[i] = s;
        if (eg[i] < eg[bi])
            bi = i;
        if (s < *energy || i == 0)
            *energy = s;
    }
    int bx = bi % ns, by = bi / ns;
    double d[2] = {0, 0};
    if (bx > 0 && bx < ns - 1)
        d[0] = parabola_min(eg[bi - 1], eg[bi], eg[bi + 1]);
    if (by > 0 && by < ns - 1)
        d[1] = parabola_min(eg[bi - ns], eg[bi], eg[bi + ns]);
    c->t[0] = (bx + d[0]) * step - smax;
    c->t[1] = (by + d[1]) * step - smax;
done:
    free(sk);
    free(eg);
    return rc;
}

static void rd_free(rd_ctx *c)
{
    if (c->smp)
        for (int i = 0; i < c->workers; i++)
            gs_synth_sample_free(&c->smp[i]);
    free(c->smp);
    free(c->ebuf);
    free(c->hidx);
    free(c->bimg);
    free(c->img);
    free(c->idx);
    free(c->inbox);
    free(c->memo);
}

/* The blur levels: level j blurs by sqrt(blur_px^2 + (j RD_SOFT_STEP)^2),
 * the image's blur after a softness of j RD_SOFT_STEP (Gaussians compose
 * so). Returns the largest kernel radius. */
static int setup_levels(rd_ctx *c, const gs_eval_readout_options *o)
{
    c->nsoft = 1 + (int)floor(o->soft_max_px / RD_SOFT_STEP + 1e-9);
    int Rmax = 0;
    for (int lv = 0; lv < c->nsoft; lv++) {
        double sg = lv ? sqrt(o->blur_px * o->blur_px +
                              (lv * RD_SOFT_STEP) * (lv * RD_SOFT_STEP))
                       : o->blur_px; /* level 0: the plain readout's, exactly */
        int R = sg > 0 ? (int)ceil(3 * sg - (lv ? 1e-9 : 0)) : 0;
        R = c->R[lv] = R > RD_MAX_R ? RD_MAX_R : R;
        Rmax = R > Rmax ? R : Rmax;
        double ks = 0;
        for (int d = -R; d <= R; d++)
            ks += c->ker[lv][d + R] =
                (float)exp(-0.5 * d * d / (sg * sg + 1e-30));
        for (int d = 0; d <= 2 * R; d++)
            c->ker[lv][d] = (float)(c->ker[lv][d] / ks);
    }
    return Rmax;
}

/* The rendered and image boxes, the buffers, and the image's box blurred
 * at level 0. */
static int setup_buffers(rd_ctx *c, int size, double smax, int Rmax, const uint8_t *rgb,
                         size_t stride, gs_pool *pool, gs_error *err)
{
    int rc;
    /* Rendered: the bounding box + the largest R (+ 1 for the eyeball's
     * dilation); the image's: + its own R + the shift range + 1 more. */
    int m = Rmax + 1;
    c->ex = c->x0 - m < 0 ? 0 : c->x0 - m;
    c->ey = c->y0 - m < 0 ? 0 : c->y0 - m;
    c->ew = (c->x0 + c->w + m > size ? size : c->x0 + c->w + m) - c->ex;
    c->eh = (c->y0 + c->h + m > size ? size : c->y0 + c->h + m) - c->ey;
    m = c->R[0] + (int)ceil(smax) + 1;
    c->bx = c->x0 - m < 0 ? 0 : c->x0 - m;
    c->by = c->y0 - m < 0 ? 0 : c->y0 - m;
    c->bw = (c->x0 + c->w + m > size ? size : c->x0 + c->w + m) - c->bx;
    c->bh = (c->y0 + c->h + m > size ? size : c->y0 + c->h + m) - c->by;
    c->workers = gs_pool_threads(pool);
    size_t nb = 3 * (size_t)c->bw * c->bh;
    c->bimg = malloc(sizeof *c->bimg * 2 * nb);
    c->ebuf = malloc(sizeof *c->ebuf * 6 * (size_t)c->ew * c->eh * c->workers);
    c->smp = calloc((size_t)c->workers, sizeof *c->smp);
    c->img = malloc(sizeof *c->img * 3 * (size_t)c->w * c->h);
    if (!c->bimg || !c->ebuf || !c->smp || !c->img)
        return gs_error_set(err, GS_ERR_NOMEM, "gaze readout: out of memory");
    for (int i = 0; i < c->workers; i++)
        if ((rc = gs_synth_sample_alloc(&c->smp[i], size, size, err)))
            return rc;
    for (int y = 0; y < c->bh; y++)
        for (int x = 0; x < c->bw; x++)
            for (int ch = 0; ch < 3; ch++)
                c->bimg[3 * ((size_t)y * c->bw + x) + ch] =
                    rgb[(size_t)(c->by + y) * stride + 3 * (size_t)(c->bx + x) + ch];
    blur_rgb(c, 0, c->bimg, c->bimg + nb, c->bw, c->bh);
    return GS_OK;
}

/* eye (size^2): 1 on the reference's eyeball pixels; 2 where any gaze
 * changes the render (the eyeballs and the lids, which follow the pitch),
 * which the alignment leaves out. ref holds the reference's box. */
static int mark_eye(rd_ctx *c, const gs_synth_scene *scene, gs_synth_sample *s, int size,
                    uint8_t *eye, float *ref, gs_error *err)
{
    int rc = GS_OK;
    size_t ne = 3 * (size_t)c->ew * c->eh;
    const uint8_t *ml = gs_synth_sample_mask(s, GS_SYNTH_MASK_LEFT_EYE);
    const uint8_t *mr = gs_synth_sample_mask(s, GS_SYNTH_MASK_RIGHT_EYE);
    for (int y = c->ey; y < c->ey + c->eh; y++)
        for (int x = c->ex; x < c->ex + c->ew; x++) {
            size_t i = (size_t)y * size + x;
            eye[i] = ml[i] || mr[i];
        }
    /* Pixels any gaze changes (the eyeballs and the lids, which follow
     * the pitch) are no help for the alignment: probe renders at the
     * corners of the gaze range mark them (2 in eye[]). */
    float *pb = ref + ne;
    memcpy(ref, c->ebuf, sizeof *ref * ne);
    static const double probe[4][2] = {{-30, 0}, {30, 0}, {0, -45}, {0, 45}};
    for (int k = 0; !rc && k < 4; k++) {
        gs_synth_scene ps = *scene;
        ps.gaze_pitch = probe[k][0] * RD_DEG;
        ps.gaze_yaw = probe[k][1] * RD_DEG;
        if ((rc = render_box(c, &ps, s, pb, err)))
            break;
        for (int y = 0; y < c->eh; y++)
            for (int x = 0; x < c->ew; x++) {
                size_t i = (size_t)y * c->ew + x;
                float d = fabsf(pb[3 * i] - ref[3 * i]) +
                          fabsf(pb[3 * i + 1] - ref[3 * i + 1]) +
                          fabsf(pb[3 * i + 2] - ref[3 * i + 2]);
                uint8_t *mk = &eye[(size_t)(c->ey + y) * size + c->ex + x];
                if (d > RD_STILL && !*mk)
                    *mk = 2;
            }
    }
    return rc;
}

/* The alignment: on the blur level whose reference the still pixels match
 * best (a soft image aligns on a soft reference), then at RD_SHIFT_STEP.
 * ref: 6 boxes of scratch, the reference's first. */
static int setup_align(rd_ctx *c, const gs_synth_scene *scene, gs_synth_sample *s,
                       const uint8_t *eye, float *ref, double smax, gs_error *err)
{
    int rc = GS_OK;
    size_t ne = 3 * (size_t)c->ew * c->eh;
    double ebest = INFINITY, e;
    /* A soft image aligns on a soft reference: the level whose reference
     * the still pixels match best on a shift grid of about 1 px is aligned
     * on (a sharp reference drags a blurred image's shift by up to a
     * pixel, several degrees of pitch). */
    c->align_lv = 0;
    if (!rc && c->nsoft > 1) {
        float *raw = ref + 3 * ne, *lb = raw + ne;
        /* about 1 px, dividing the range exactly (the image's buffer ends
         * at the range) */
        double cstep = smax > 0 ? smax / ceil(smax) : 1.0;
        rc = render_raw(c, scene, s, raw, err);
        for (int lv = 0; !rc && lv < c->nsoft; lv++) {
            memcpy(lb, raw, sizeof *lb * ne);
            blur_rgb(c, lv, lb, lb + ne, c->ew, c->eh);
            if (!(rc = align(c, lb, eye, smax, cstep, &e, err)) &&
                e < ebest) {
                ebest = e;
                c->align_lv = lv;
            }
        }
        if (!rc && c->align_lv) {
            memcpy(ref, raw, sizeof *ref * ne);
            blur_rgb(c, c->align_lv, ref, lb, c->ew, c->eh);
        }
    }
    if (!rc)
        rc = align(c, ref, eye, smax, RD_SHIFT_STEP, &e, err);
    return rc;
}

/* The eyeball pixels the readout compares (those the gaze alone moves),
 * sampled from the aligned image, and the row blur their column blur
 * reads. */
static int setup_pixels(rd_ctx *c, const uint8_t *eye, int size, int Rmax, gs_error *err)
{
    c->n = 0;
    for (int y = 0; y < c->h; y++)
        for (int x = 0; x < c->w; x++)
            if (c->inbox[y * c->w + x] &&
                eye[(size_t)(c->y0 + y) * size + c->x0 + x] == 1) {
                sample_at(c, c->x0 + x, c->y0 + y, c->t[0], c->t[1],
                          c->img + 3 * (size_t)c->n);
                c->idx[c->n++] = y * c->w + x;
            }
    if (!c->n)
        return gs_error_set(err, GS_ERR_ARG, "gaze readout: no eyeball "
                            "visible in the scene (closed eyes)");
    /* The row blur the eyeball pixels' column blur reads: their columns,
     * Rmax rows either way (clamped as the blur clamps). */
    uint8_t *need = calloc((size_t)c->ew * c->eh, 1);
    c->hidx = malloc(sizeof *c->hidx * (size_t)c->ew * c->eh);
    if (!need || !c->hidx) {
        free(need);
        return gs_error_set(err, GS_ERR_NOMEM, "gaze readout: out of memory");
    }
    for (int k = 0; k < c->n; k++) {
        int x = c->x0 + c->idx[k] % c->w - c->ex;
        int y = c->y0 + c->idx[k] / c->w - c->ey;
        for (int d = -Rmax; d <= Rmax; d++) {
            int q = y + d < 0 ? 0 : y + d >= c->eh ? c->eh - 1 : y + d;
            need[(size_t)q * c->ew + x] = 1;
        }
    }
    c->nh = 0;
    for (int i = 0; i < c->ew * c->eh; i++)
        if (need[i])
            c->hidx[c->nh++] = i;
    free(need);
    return GS_OK;
}

/* Boxes, blur, buffers, the reference, the alignment and the eyeball
 * pixels of the shifted image. */
static int setup(rd_ctx *c, const gs_synth_scene *scene, int size,
                 double d_n_mm, double f_n, const uint8_t *rgb, size_t stride,
                 const gs_eval_readout_options *o, gs_pool *pool,
                 gs_error *err)
{
    c->scene = *scene;
    c->size = size;
    double smax = floor(o->max_shift_px / RD_SHIFT_STEP) * RD_SHIFT_STEP;
    gs_synth_labels lab;
    int rc = gs_eval_scene_camera(scene, size, d_n_mm, f_n, &c->cam, err);
    if (!rc)
        rc = gs_synth_labels_compute(scene, &c->cam, &lab, err);
    if (!rc)
        rc = make_boxes(c, &lab, smax, err);
    if (rc)
        return rc;
    int Rmax = setup_levels(c, o);
    if ((rc = setup_buffers(c, size, smax, Rmax, rgb, stride, pool, err)))
        return rc;
    /* The reference: the scene at its own gaze, lids as they are. */
    gs_synth_sample *s = &c->smp[0];
    if ((rc = render_box(c, scene, s, c->ebuf, err)))
        return rc;
    size_t ne = 3 * (size_t)c->ew * c->eh;
    uint8_t *eye = calloc((size_t)size * size, 1);
    float *ref = malloc(sizeof *ref * 6 * ne);
    if (!eye || !ref) {
        free(eye);
        free(ref);
        return gs_error_set(err, GS_ERR_NOMEM, "gaze readout: out of memory");
    }
    rc = mark_eye(c, scene, s, size, eye, ref, err);
    if (!rc)
        rc = setup_align(c, scene, s, eye, ref, smax, err);
    free(ref);
    if (!rc)
        rc = setup_pixels(c, eye, size, Rmax, err);
    free(eye);
    return rc;
}

/* 1 when the readout's options are in their documented ranges. */
static int options_ok(const gs_eval_readout_options *o)
{
    return o->max_shift_px >= 0 && o->max_shift_px <= 8 && o->grid_deg >= 1 && o->grid_deg <= 45 &&
           o->blur_px >= 0 && o->blur_px <= RD_MAX_R / 3.0 && o->tol_deg >= 0.01 &&
           o->tol_deg <= o->grid_deg / 2 && o->pitch_range_deg >= 0 && o->pitch_range_deg <= 80 &&
           o->yaw_range_deg >= 0 && o->yaw_range_deg <= 80 && o->soft_max_px >= 0 &&
           o->soft_max_px <= 2.5 &&
           o->blur_px * o->blur_px + o->soft_max_px * o->soft_max_px <=
               (RD_MAX_R / 3.0) * (RD_MAX_R / 3.0);
}

/* The starts: grid[k][3] = 1 at the grid's local minima (no lower
 * neighbour among its 8), 0 elsewhere; (2 np + 1) rows of `row`. */
static void mark_minima(double (*grid)[5], int np, int row, int ng)
{
    for (int k = 0; k < ng; k++) {
        int i = k / row, j = k % row, local = 1;
        for (int d = 0; d < 9 && local; d++) {
            int ii = i + d / 3 - 1, jj = j + d % 3 - 1;
            if (d != 4 && ii >= 0 && ii <= 2 * np && jj >= 0 && jj < row &&
                grid[ii * row + jj][2] < grid[k][2])
                local = 0;
        }
        grid[k][3] = local;
    }
}

int gs_eval_gaze_readout(const gs_synth_scene *scene, int size, double d_n_mm,
                         double f_n, const uint8_t *rgb, size_t stride,
                         const gs_eval_readout_options *opts, gs_pool *pool,
                         gs_eval_readout *out, gs_error *err)
{
    gs_eval_readout_options o;
    if (opts)
        o = *opts;
    else
        gs_eval_readout_options_default(&o);
    if (!scene || !rgb || !out || size < 16 || size > 8192 ||
        stride < 3 * (size_t)size)
        return gs_error_set(err, GS_ERR_ARG, "gaze readout: bad arguments");
    if (!options_ok(&o))
        return gs_error_set(err, GS_ERR_ARG, "gaze readout: options out of "
                            "range");
    rd_ctx *c = calloc(1, sizeof *c);
    if (!c)
        return gs_error_set(err, GS_ERR_NOMEM, "gaze readout: out of memory");
    int rc = setup(c, scene, size, d_n_mm, f_n, rgb, stride, &o, pool, err);
    /* Coarse grid over the ranges, centred on 0, in batches. */
    int np = (int)floor(o.pitch_range_deg / o.grid_deg + 1e-9);
    int ny = (int)floor(o.yaw_range_deg / o.grid_deg + 1e-9);
    int row = 2 * ny + 1, ng = (2 * np + 1) * row;
    double(*grid)[5] = rc ? NULL : malloc(sizeof *grid * (size_t)ng);
    if (!rc && !grid)
        rc = gs_error_set(err, GS_ERR_NOMEM, "gaze readout: out of memory");
    double pts[RD_MAX_CAND][2], e_pts[RD_MAX_CAND];
    int l_pts[RD_MAX_CAND];
    c->lv0 = c->align_lv;
    for (int k0 = 0; !rc && k0 < ng; k0 += RD_MAX_CAND) {
        int n = ng - k0 < RD_MAX_CAND ? ng - k0 : RD_MAX_CAND;
        for (int k = 0; k < n; k++) {
            pts[k][0] = ((k0 + k) / row - np) * o.grid_deg * RD_DEG;
            pts[k][1] = ((k0 + k) % row - ny) * o.grid_deg * RD_DEG;
        }
        rc = eval_points(c, pool, pts, n, e_pts, l_pts, err);
        for (int k = 0; !rc && k < n; k++) {
            grid[k0 + k][0] = pts[k][0];
            grid[k0 + k][1] = pts[k][1];
            grid[k0 + k][2] = e_pts[k];
            grid[k0 + k][4] = l_pts[k];
        }
    }
    if (!rc)
        mark_minima(grid, np, row, ng);
    /* Pattern search (8 neighbours, the step halved when none is lower)
     * from each start; the lowest energy reached wins. */
    double best_e = INFINITY, best_g[2] = {0, 0};
    int best_l = 0;
    for (int s = 0; !rc && s < RD_STARTS; s++) {
        int bi = -1;
        for (int k = 0; k < ng; k++)
            if (grid[k][3] != 0 && (bi < 0 || grid[k][2] < grid[bi][2]))
                bi = k;
        if (bi < 0)
            break;
        grid[bi][3] = 0;
        double g[2] = {grid[bi][0], grid[bi][1]}, e = grid[bi][2];
        int gl = (int)grid[bi][4];
        for (double st = o.grid_deg / 2 * RD_DEG;
             !rc && st >= o.tol_deg * RD_DEG * (1 - 1e-9); st /= 2) {
            for (int moves = 0; !rc && moves < 64; moves++) {
                int n = 0;
                for (int d = 0; d < 9; d++) {
                    double p = g[0] + (d / 3 - 1) * st;
                    double y = g[1] + (d % 3 - 1) * st;
                    if (d == 4 || fabs(p) > RD_LIMIT || fabs(y) > RD_LIMIT)
                        continue;
                    pts[n][0] = p;
                    pts[n][1] = y;
                    n++;
                }
                c->lv0 = gl; /* the neighbours start at the centre's level */
                rc = eval_points(c, pool, pts, n, e_pts, l_pts, err);
                int bk = -1;
                for (int k = 0; !rc && k < n; k++)
                    if (e_pts[k] < e && (bk < 0 || e_pts[k] < e_pts[bk]))
                        bk = k;
                if (bk < 0)
                    break;
                e = e_pts[bk];
                gl = l_pts[bk];
                g[0] = pts[bk][0];
                g[1] = pts[bk][1];
            }
        }
        if (e < best_e) {
            best_e = e;
            best_g[0] = g[0];
            best_g[1] = g[1];
            best_l = gl;
        }
    }
    free(grid);
    if (!rc && !isfinite(best_e))
        rc = gs_error_set(err, GS_ERR_NONFINITE, "gaze readout: no finite "
                          "match");
    if (!rc) {
        out->pitch = best_g[0];
        out->yaw = best_g[1];
        out->shift[0] = c->t[0];
        out->shift[1] = c->t[1];
        out->rms = sqrt(best_e);
        out->renders = c->renders + 5 + (c->nsoft > 1); /* + the reference
                                     (twice when softness is searched) and
                                     4 probes */
        out->pixels = c->n;
        out->soft_px = best_l * RD_SOFT_STEP;
    }
    rd_free(c);
    free(c);
    return rc;
}
