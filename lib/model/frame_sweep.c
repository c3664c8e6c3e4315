/* The sweep cache: the render state of the last few subjects a context
 * drew, kept so that a sweep that comes back to a subject redraws only
 * what its targets change (gs_model_ctx_set_sweep_cache). */
#include <stdlib.h>
#include <string.h>

#include "frame_sweep.h"

/* ---- other subjects' renders (the sweep cache) ---- */

int gs_frame_same_subject_pose(const gs_frame *a, const gs_frame *b)
{
    return !memcmp(a->code, b->code, sizeof a->code) &&
           !memcmp(a->head_R, b->head_R, sizeof a->head_R) &&
           !memcmp(a->head_t, b->head_t, sizeof a->head_t);
}

static void swap_f(float **a, float **b)
{
    float *t = *a;
    *a = *b, *b = t;
}

/* Exchanges the live render state with slot s's. */
static void sweep_swap(gs_model_ctx *c, gs_sweep_slot *s)
{
    swap_f(&c->g_mean, &s->g_mean), swap_f(&c->g_scale, &s->g_scale);
    swap_f(&c->g_quat, &s->g_quat), swap_f(&c->g_opac, &s->g_opac);
    swap_f(&c->g_feat, &s->g_feat), swap_f(&c->fmap, &s->fmap);
    swap_f(&c->rgb, &s->rgb), swap_f(&c->gvec, &s->gvec);
    swap_f(&c->eye_base, &s->eye_base);
    swap_f(&c->x_head, &s->x_head), swap_f(&c->q_head, &s->q_head);
    swap_f(&c->rgb_main, &s->rgb_main);
    float code[GS_MODEL_MAX_CODE];
    memcpy(code, c->eye_base_code, sizeof code);
    memcpy(c->eye_base_code, s->eye_base_code, sizeof code);
    memcpy(s->eye_base_code, code, sizeof code);
    int16_t *fb = c->fbox;
    c->fbox = s->fbox, s->fbox = fb;
    uint8_t *r8 = c->rgb8;
    c->rgb8 = s->rgb8, s->rgb8 = r8;
    gs_frame key = c->inc_key;
    c->inc_key = s->key, s->key = key;
    int t = c->inc_valid, r[4];
    c->inc_valid = s->valid, s->valid = t;
    memcpy(r, c->inc_rect, sizeof r), memcpy(c->inc_rect, s->rect, sizeof r);
    memcpy(s->rect, r, sizeof r);
    t = c->rgb8_valid, c->rgb8_valid = s->rgb8_valid, s->rgb8_valid = t;
    t = c->eye_base_valid, c->eye_base_valid = s->eye_base_valid;
    s->eye_base_valid = t;
    float tf[6];
    memcpy(tf, c->rgb8_tf, sizeof tf), memcpy(c->rgb8_tf, s->rgb8_tf, sizeof tf);
    memcpy(s->rgb8_tf, tf, sizeof tf);
    memcpy(r, c->rgb_dirty, sizeof r), memcpy(c->rgb_dirty, s->rgb_dirty, sizeof r);
    memcpy(s->rgb_dirty, r, sizeof r);
    memcpy(r, c->dir_box, sizeof r), memcpy(c->dir_box, s->dir_box, sizeof r);
    memcpy(s->dir_box, r, sizeof r);
    swap_f(&c->anc_fmap, &s->anc_fmap), swap_f(&c->anc_rgb, &s->anc_rgb);
    t = c->anc_valid, c->anc_valid = s->anc_valid, s->anc_valid = t;
    int *cb[] = {c->anc_rect, c->anc_fbox, c->anc_rbox}, *sb[] = {s->anc_rect, s->anc_fbox, s->anc_rbox};
    for (int i = 0; i < 3; i++)
        memcpy(r, cb[i], sizeof r), memcpy(cb[i], sb[i], sizeof r), memcpy(sb[i], r, sizeof r);
    /* the face cache's outputs are not what g_* now holds */
    c->face_valid = 0;
    c->face_map_valid = 0;
}

void gs_sweep_slot_free(gs_sweep_slot *s)
{
    float *f[] = {s->g_mean, s->g_scale, s->g_quat, s->g_opac,
                  s->g_feat, s->fmap, s->rgb, s->gvec, s->eye_base,
                  s->x_head, s->q_head, s->rgb_main, s->anc_fmap, s->anc_rgb};
    for (size_t i = 0; i < sizeof f / sizeof f[0]; i++)
        free(f[i]);
    free(s->fbox);
    free(s->rgb8);
    memset(s, 0, sizeof *s);
}

/* Buffers of the live state's sizes for slot s. */
static int sweep_slot_alloc(const gs_model_ctx *c, gs_sweep_slot *s)
{
    size_t n = (size_t)c->n, fsz = (size_t)c->fs * c->fs,
           isz = (size_t)c->S * c->S;
    int fail = 0;
    s->g_mean = gs_ctx_falloc(n * 3, &fail), s->g_scale = gs_ctx_falloc(n * 3, &fail);
    s->g_quat = gs_ctx_falloc(n * 4, &fail), s->g_opac = gs_ctx_falloc(n, &fail);
    s->g_feat = gs_ctx_falloc(n * c->C, &fail);
    s->fmap = gs_ctx_falloc(fsz * c->C, &fail), s->rgb = gs_ctx_falloc(isz * 3, &fail);
    s->gvec = gs_ctx_falloc((size_t)c->C, &fail);
    s->eye_base = gs_ctx_falloc((size_t)(c->ne ? c->ne : 1) * c->m->p.eye.dims[1], &fail);
    /* the lids turn the face stream's head-frame ones (lid_forward) */
    s->x_head = gs_ctx_falloc(n * 3, &fail);
    s->q_head = gs_ctx_falloc((size_t)(c->nf ? c->nf : 1) * 4, &fail);
    s->fbox = calloc((size_t)(c->nf ? c->nf : 1), 4 * sizeof(int16_t));
    s->rgb8 = malloc(isz * 3);
    if (c->eye_direct) /* the renderer's image under the eye stream's */
        s->rgb_main = gs_ctx_falloc(isz * 3, &fail);
    if (fail || !s->fbox || !s->rgb8) {
        gs_sweep_slot_free(s);
        return GS_ERR_NOMEM;
    }
    return GS_OK;
}

/* Forgets every kept render (the parameters may change: training). */
void gs_sweep_drop(gs_model_ctx *c)
{
    c->inc_valid = 0;
    c->eye_base_valid = 0;
    c->fe_valid = 0;
    if (c->xfer)
        c->xfer_invalidate(c->xfer);
    for (int i = 0; c->slots && i < c->sweep_n - 1; i++)
        c->slots[i].valid = c->slots[i].eye_base_valid = 0;
}

/* Puts the live render (if any) into a free or the least recently used
 * slot before something overwrites it; with no slot to spare it is lost.
 * Afterwards the live state is not valid. */
void gs_sweep_stash(gs_model_ctx *c)
{
    if (!c->inc_valid || c->sweep_n < 2)
        return;
    if (!c->slots) {
        c->slots = calloc((size_t)c->sweep_n - 1, sizeof *c->slots);
        if (!c->slots)
            return;
    }
    gs_sweep_slot *v = NULL;
    for (int i = 0; i < c->sweep_n - 1; i++) {
        gs_sweep_slot *s = &c->slots[i];
        if (!s->valid) {
            v = s;
            break;
        }
        if (!v || s->used < v->used)
            v = s;
    }
    if (!v || (!v->g_mean && sweep_slot_alloc(c, v) != GS_OK))
        return;
    sweep_swap(c, v);
    v->used = ++c->sweep_clock;
    c->inc_valid = 0;
}

/* Makes fr's subject and pose the live render state when a slot has it;
 * otherwise stashes the live one. */
void gs_sweep_select(gs_model_ctx *c, const gs_frame *fr)
{
    for (int i = 0; c->slots && i < c->sweep_n - 1; i++) {
        gs_sweep_slot *s = &c->slots[i];
        if (s->valid && gs_frame_same_subject_pose(&s->key, fr)) {
            sweep_swap(c, s);
            s->used = ++c->sweep_clock;
            return;
        }
    }
    gs_sweep_stash(c);
}

int gs_model_ctx_set_sweep_cache(gs_model_ctx *c, int n, gs_error *err)
{
    if (!c || n < 1 || n > GS_MODEL_MAX_SWEEP_CACHE)
        return gs_error_set(err, GS_ERR_ARG,
                            "sweep cache of %d subjects outside 1..%d", n,
                            GS_MODEL_MAX_SWEEP_CACHE);
    for (int i = 0; c->slots && i < c->sweep_n - 1; i++)
        gs_sweep_slot_free(&c->slots[i]);
    free(c->slots);
    c->slots = NULL;
    c->sweep_n = n;
    c->inc_valid = 0;
    return GS_OK;
}

