/* Scalar reference compositing: one pixel at a time over its tile's list,
 * exactly as raster.h documents. Single-threaded, plain expf. The fast path
 * is measured and tested against this one. */
#include <math.h>
#include <string.h>

#include "raster_internal.h"

typedef struct {
    float dx, dy, sigma, vis, alpha; /* vis = exp(-sigma) */
} splat_eval;

/* Returns 1 when Gaussian i contributes alpha >= 1/255 at pixel (px, py). */
static int eval_splat(const gs_proj *P, uint32_t i, float px, float py, splat_eval *e)
{
    const float *q = P->conic + 3 * i;
    e->dx = P->mean2d[2 * i] - px;
    e->dy = P->mean2d[2 * i + 1] - py;
    e->sigma = 0.5f * (q[0] * e->dx * e->dx + q[2] * e->dy * e->dy) + q[1] * e->dx * e->dy;
    if (e->sigma < 0.0f)
        return 0;
    e->vis = expf(-e->sigma);
    e->alpha = fminf(GS_RASTER_MAX_ALPHA, P->opacity[i] * e->vis);
    return e->alpha >= GS_RASTER_MIN_ALPHA;
}

void gs_raster_scalar_forward(gs_raster *r, const float *bg, float *out_f, float *out_alpha,
                              float *out_depth)
{
    const int W = r->cam.width, H = r->cam.height, C = r->g.channels;
    const size_t HW = (size_t)W * (size_t)H;
    const gs_proj *P = &r->proj;
    float acc[GS_RASTER_MAX_CHANNELS];
    size_t contributions = 0;
    for (int y = 0; y < H; y++)
        for (int x = 0; x < W; x++) {
            int t = (y / GS_RASTER_TILE) * r->tiles_x + x / GS_RASTER_TILE;
            uint32_t s = r->tile_off[t], e = r->tile_off[t + 1], last = 0;
            float px = (float)x + 0.5f, py = (float)y + 0.5f, T = 1.0f, depth = 0.0f;
            memset(acc, 0, (size_t)C * sizeof *acc);
            for (uint32_t k = s; k < e; k++) {
                uint32_t i = r->isect[k];
                splat_eval ev;
                if (!eval_splat(P, i, px, py, &ev))
                    continue;
                float next_T = T * (1.0f - ev.alpha);
                if (next_T <= GS_RASTER_T_EPS)
                    break;
                float w = ev.alpha * T;
                const float *f = r->g.features + (size_t)i * C;
                for (int ch = 0; ch < C; ch++)
                    acc[ch] += f[ch] * w;
                depth += P->depth[i] * w;
                T = next_T;
                last = k - s + 1;
                contributions++;
            }
            size_t pix = (size_t)y * W + x;
            for (int ch = 0; ch < C; ch++)
                out_f[ch * HW + pix] = acc[ch] + (bg ? T * bg[ch * HW + pix] : 0.0f);
            out_alpha[pix] = 1.0f - T;
            if (out_depth)
                out_depth[pix] = depth;
            r->t_final[pix] = T;
            r->last[pix] = last;
        }
    r->contributions = contributions;
}

void gs_raster_scalar_backward(gs_raster *r, const float *v_f, const float *v_alpha,
                               const float *v_depth, float *v_features, float *v_bg)
{
    const int W = r->cam.width, H = r->cam.height, C = r->g.channels;
    const size_t HW = (size_t)W * (size_t)H;
    const gs_proj *P = &r->proj;
    gs_proj_grad *G = &r->pgrad;
    const float *bg = r->background;
    float buf[GS_RASTER_MAX_CHANNELS], vpix[GS_RASTER_MAX_CHANNELS];
    for (int y = 0; y < H; y++)
        for (int x = 0; x < W; x++) {
            size_t pix = (size_t)y * W + x;
            int t = (y / GS_RASTER_TILE) * r->tiles_x + x / GS_RASTER_TILE;
            uint32_t s = r->tile_off[t];
            float px = (float)x + 0.5f, py = (float)y + 0.5f;
            const float T_final = r->t_final[pix];
            float T = T_final, buf_d = 0.0f, bg_dot = 0.0f;
            for (int ch = 0; ch < C; ch++) {
                vpix[ch] = v_f[ch * HW + pix];
                buf[ch] = 0.0f;
                if (bg)
                    bg_dot += bg[ch * HW + pix] * vpix[ch];
                if (v_bg)
                    v_bg[ch * HW + pix] += T_final * vpix[ch];
            }
            float vA = v_alpha ? v_alpha[pix] : 0.0f, vD = v_depth ? v_depth[pix] : 0.0f;
            for (uint32_t k = s + r->last[pix]; k-- > s;) {
                uint32_t i = r->isect[k];
                splat_eval ev;
                if (!eval_splat(P, i, px, py, &ev))
                    continue;
                float ra = 1.0f / fmaxf(1.0f - ev.alpha, GS_RASTER_ONE_MINUS_ALPHA_FLOOR);
                T *= ra;
                float fac = ev.alpha * T, z = P->depth[i];
                const float *f = r->g.features + (size_t)i * C;
                float va = 0.0f;
                for (int ch = 0; ch < C; ch++) {
                    va += (f[ch] * T - buf[ch] * ra) * vpix[ch];
                    buf[ch] += f[ch] * fac;
                    if (v_features)
                        v_features[(size_t)i * C + ch] += fac * vpix[ch];
                }
                va += T_final * ra * (vA - bg_dot) + vD * (z * T - buf_d * ra);
                buf_d += z * fac;
                G->depth[i] += fac * vD;
                if (P->opacity[i] * ev.vis <= GS_RASTER_MAX_ALPHA) {
                    float v_sigma = -ev.alpha * va;
                    const float *q = P->conic + 3 * i;
                    G->conic[3 * i] += 0.5f * v_sigma * ev.dx * ev.dx;
                    G->conic[3 * i + 1] += v_sigma * ev.dx * ev.dy;
                    G->conic[3 * i + 2] += 0.5f * v_sigma * ev.dy * ev.dy;
                    G->mean2d[2 * i] += v_sigma * (q[0] * ev.dx + q[1] * ev.dy);
                    G->mean2d[2 * i + 1] += v_sigma * (q[1] * ev.dx + q[2] * ev.dy);
                    G->opacity[i] += ev.vis * va;
                }
            }
        }
}
