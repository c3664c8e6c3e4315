/* Fine-tuned parameters as a block of their own (docs/model.md, "Serving
 * fine-tuned subjects"): what a subject's gs_model_finetune changed, kept
 * beside its gs_subject and put back into a clone of the shared model
 * when that subject is rendered.
 *
 * Block layout, little-endian:
 *   u32 magic "GSFT", u32 version, u32 parts (GS_FT_*), u32 tensors,
 *   u64 param id of the model it was tuned from,
 *   per tensor: u32 index in the model's table, u32 floats, the floats,
 *   u64 hash of every byte before it. */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "model_internal.h"
#include "frame.h"
#include "fit_internal.h"
#include "hash64.h"

#define TUNED_MAGIC 0x54465347u /* "GSFT" */
#define TUNED_VERSION 1u
#define TUNED_HEAD 24
#define TUNED_ALL_PARTS GS_FT_ALL_PARTS

/* One part of a key: its own hash and length, as one 32-byte block. */
static void hash_part(hash64 *h, const void *p, size_t n)
{
    hash64 s;
    hash_init(&s, 0x706172742d6b6579ULL);
    hash_bytes(&s, p, n);
    uint64_t b[4] = {hash_final(&s), (uint64_t)n, 0, 0};
    hash_bytes(h, b, sizeof b);
}

static uint64_t bits(double x)
{
    uint64_t u;
    memcpy(&u, &x, 8);
    return u;
}

uint64_t gs_model_fit_key(const gs_model *m, const gs_fit_options *opt,
                          const uint8_t *rgb, size_t stride)
{
    gs_fit_options o;
    if (opt)
        o = *opt;
    else
        gs_fit_options_default(&o);
    const gs_model_config *c = &m->cfg;
    const int S = c->image_size, D = gs_model_code_dim(c);
    /* What gs_model_fit makes of the options (fit.c): the defaults that 0
     * stands for, the model's prior weight for GS_FIT_CODE_PRIOR_MODEL,
     * the model's code rate for 0, the known labels only when known.
     * Every field of the configuration but fit_code_prior and
     * fit_code_rate (resolved here) shapes the fit's renders. */
    const uint64_t r[] = {
        gs_model_param_id(m), 1 /* key version */,
        (uint64_t)c->n_face, (uint64_t)c->n_eye_each, (uint64_t)c->feat_dim,
        (uint64_t)c->id_dim, (uint64_t)c->hidden, (uint64_t)c->channels,
        (uint64_t)c->feat_size, (uint64_t)S, (uint64_t)c->guidance,
        (uint64_t)c->guide_source, (uint64_t)c->two_stream,
        (uint64_t)c->eye_rotation, (uint64_t)c->n_train_ids,
        (uint64_t)c->n_lid0, (uint64_t)c->n_lid1, (uint64_t)c->supersample,
        (uint64_t)c->eye_direct, bits(c->template_spacing_mm), bits(c->d_n_mm),
        bits(c->focal),
        (uint64_t)(o.max_iters > 0 ? o.max_iters : 200),
        bits(o.time_budget_s > 0 ? o.time_budget_s : 0),
        bits(o.plateau_rel > 0 ? o.plateau_rel : 1e-3),
        bits(gs_model_fit_code_rate(m, o.lr_code)),
        bits(o.lr_colour > 0 ? o.lr_colour : GS_FIT_LR_COLOUR_DEFAULT),
        (uint64_t)(o.bound_expression != 0),
        bits(o.code_prior == GS_FIT_CODE_PRIOR_MODEL ? c->fit_code_prior
                                                     : o.code_prior),
        (uint64_t)(o.known_gaze != 0), (uint64_t)(o.known_head != 0),
        (uint64_t)(o.code_start != NULL), (uint64_t)(o.code_fixed != NULL),
        (uint64_t)(o.mask != NULL),
    };
    uint64_t known[14]; /* the labels that are known */
    int n = 0;
    if (o.known_gaze) {
        known[n++] = bits(o.gaze_pitch);
        known[n++] = bits(o.gaze_yaw);
    }
    if (o.known_head) {
        for (int k = 0; k < 9; k++)
            known[n++] = bits(o.head_R[k]);
        for (int k = 0; k < 3; k++)
            known[n++] = bits(o.head_t[k]);
    }
    hash64 h;
    hash_init(&h, 0x6669742d6b657931ULL);
    hash_part(&h, r, sizeof r);
    hash_part(&h, known, (size_t)n * sizeof known[0]);
    if (o.code_start)
        hash_part(&h, o.code_start, (size_t)D * sizeof(float));
    if (o.code_fixed)
        hash_part(&h, o.code_fixed, (size_t)D);
    if (o.mask)
        hash_part(&h, o.mask, (size_t)S * S);
    if (o.id_prior != 0) { /* hashed only when set: keys without it stand */
        uint64_t w = bits(o.id_prior);
        hash_part(&h, &w, sizeof w);
    }
    if (o.mirror != 0) { /* likewise */
        uint64_t a = 0x6d6972726f720000ULL | (uint64_t)(uint32_t)o.mirror;
        hash_part(&h, &a, sizeof a);
    }
    if (o.anneal != 0) { /* likewise */
        uint64_t a = 0x616e6e65616c0000ULL | (uint64_t)(uint32_t)o.anneal;
        hash_part(&h, &a, sizeof a);
    }
    for (int y = 0; y < S; y++)
        hash_part(&h, rgb + (size_t)y * stride, 3 * (size_t)S);
    return hash_final(&h);
}

static uint64_t block_hash(const uint8_t *p, size_t n)
{
    hash64 h;
    hash_init(&h, 0x67736674756e6564ULL);
    hash_bytes(&h, p, n);
    return hash_final(&h);
}

static void put32(uint8_t *p, uint32_t v)
{
    memcpy(p, &v, 4);
}

static uint32_t get32(const uint8_t *p)
{
    uint32_t v;
    memcpy(&v, p, 4);
    return v;
}

int gs_model_tuned_encode(const gs_model *m, uint8_t **out, size_t *len, gs_error *err)
{
    if (!m || !out || !len)
        return gs_error_set(err, GS_ERR_ARG, "tuned block: NULL argument");
    if (!m->tuned)
        return gs_error_set(err, GS_ERR_ARG,
                            "tuned block: the model has not been fine-tuned");
    size_t n = TUNED_HEAD + 8;
    uint32_t count = 0;
    for (int i = 0; i < m->ntensors; i++)
        if (gs_model_tensor_part(&m->t[i]) & m->tuned) {
            n += 8 + m->t[i].count * sizeof(float);
            count++;
        }
    uint8_t *b = malloc(n), *p = b;
    if (!b)
        return gs_error_set(err, GS_ERR_NOMEM, "tuned block: out of memory");
    put32(p, TUNED_MAGIC);
    put32(p + 4, TUNED_VERSION);
    put32(p + 8, m->tuned);
    put32(p + 12, count);
    memcpy(p + 16, &m->id, 8);
    p += TUNED_HEAD;
    for (int i = 0; i < m->ntensors; i++) {
        const gs_ptensor *t = &m->t[i];
        if (!(gs_model_tensor_part(t) & m->tuned))
            continue;
        put32(p, (uint32_t)i);
        put32(p + 4, (uint32_t)t->count);
        memcpy(p + 8, m->params + t->offset, t->count * sizeof(float));
        p += 8 + t->count * sizeof(float);
    }
    uint64_t h = block_hash(b, (size_t)(p - b));
    memcpy(p, &h, 8);
    *out = b;
    *len = n;
    return GS_OK;
}

/* Checks a whole block against base; *parts gets its parts. */
static int check_block(const gs_model *base, const uint8_t *buf, size_t len, unsigned *parts,
                       gs_error *err)
{
    if (len < TUNED_HEAD + 8)
        return gs_error_set(err, GS_ERR_FORMAT, "tuned block: %zu bytes, too short", len);
    if (get32(buf) != TUNED_MAGIC)
        return gs_error_set(err, GS_ERR_FORMAT, "tuned block: bad magic");
    if (get32(buf + 4) != TUNED_VERSION)
        return gs_error_set(err, GS_ERR_UNSUPPORTED, "tuned block: version %u (this build reads %u)",
                            get32(buf + 4), TUNED_VERSION);
    uint64_t h;
    memcpy(&h, buf + len - 8, 8);
    if (block_hash(buf, len - 8) != h)
        return gs_error_set(err, GS_ERR_FORMAT,
                            "tuned block: checksum mismatch (truncated or corrupt)");
    unsigned pt = get32(buf + 8);
    uint32_t count = get32(buf + 12);
    uint64_t id;
    memcpy(&id, buf + 16, 8);
    if (!pt || (pt & ~TUNED_ALL_PARTS))
        return gs_error_set(err, GS_ERR_FORMAT, "tuned block: parts 0x%x", pt);
    if (id != base->id)
        return gs_error_set(err, GS_ERR_ARG,
                            "tuned block: tuned from another model (parameter id "
                            "%016llx, this model's %016llx)",
                            (unsigned long long)id, (unsigned long long)base->id);
    /* Exactly the tensors of those parts, in table order. */
    size_t off = TUNED_HEAD, body = len - 8;
    uint32_t seen = 0;
    for (int i = 0; i < base->ntensors; i++) {
        const gs_ptensor *t = &base->t[i];
        if (!(gs_model_tensor_part(t) & pt))
            continue;
        if (seen == count || body - off < 8)
            return gs_error_set(err, GS_ERR_FORMAT, "tuned block: %s missing", t->name);
        uint32_t idx = get32(buf + off), n = get32(buf + off + 4);
        if (idx != (uint32_t)i || n != t->count)
            return gs_error_set(err, GS_ERR_FORMAT,
                                "tuned block: record %u is tensor %u with %u floats; "
                                "expected %s (%d) with %zu",
                                seen, idx, n, t->name, i, t->count);
        off += 8;
        if ((body - off) / sizeof(float) < n)
            return gs_error_set(err, GS_ERR_FORMAT, "tuned block: %s truncated", t->name);
        for (uint32_t k = 0; k < n; k++) {
            float v;
            memcpy(&v, buf + off + (size_t)k * 4, 4);
            if (!isfinite(v))
                return gs_error_set(err, GS_ERR_FORMAT,
                                    "tuned block: %s[%u] is not finite", t->name, k);
        }
        off += (size_t)n * sizeof(float);
        seen++;
    }
    if (seen != count || off != body)
        return gs_error_set(err, GS_ERR_FORMAT,
                            "tuned block: %u records and %zu bytes, expected %u and %zu",
                            count, len, seen, off + 8);
    *parts = pt;
    return GS_OK;
}

int gs_model_tuned_apply(gs_model *dst, const gs_model *base, const uint8_t *buf, size_t len,
                         gs_error *err)
{
    if (!dst || !base || (!buf && len))
        return gs_error_set(err, GS_ERR_ARG, "tuned block: NULL argument");
    if (dst == base)
        return gs_error_set(err, GS_ERR_ARG,
                            "tuned block: apply to a clone (gs_model_clone), never the "
                            "shared model");
    if (base->tuned)
        return gs_error_set(err, GS_ERR_ARG,
                            "tuned block: base is itself fine-tuned; pass the model "
                            "the clones were made from");
    if (!gs_model_same_layout(dst, base))
        return gs_error_set(err, GS_ERR_ARG, "tuned block: dst is not of base's layout");
    unsigned pt = 0;
    if (buf) {
        int rc = check_block(base, buf, len, &pt, err);
        if (rc)
            return rc;
    }
    if (dst->id != base->id) {
        /* Not a clone of base (or copied from elsewhere): start from base. */
        memcpy(dst->params, base->params, base->nparams * sizeof(float));
        dst->tuned = 0;
    }
    /* Tensors dst has tuned that this block does not hold go back to base;
     * the block's own are written over whatever dst has. */
    const uint8_t *p = buf ? buf + TUNED_HEAD : NULL;
    for (int i = 0; i < base->ntensors; i++) {
        const gs_ptensor *t = &base->t[i];
        unsigned part = gs_model_tensor_part(t);
        float *d = dst->params + t->offset;
        if (part & pt) {
            memcpy(d, p + 8, t->count * sizeof(float));
            p += 8 + t->count * sizeof(float);
        } else if (part & dst->tuned) {
            memcpy(d, base->params + t->offset, t->count * sizeof(float));
        }
    }
    dst->id = base->id;
    dst->tuned = pt;
    return GS_OK;
}

uint64_t gs_model_fit_images_key(const gs_model *m, const gs_fit_options *opt,
                                 const gs_fit_image *im, int k)
{
    if (!m || !im || k < 1 || k > GS_FIT_IMAGES_MAX)
        return 0;
    gs_fit_options o;
    if (opt)
        o = *opt;
    else
        gs_fit_options_default(&o);
    /* Each image's key as gs_model_fit_key names it with its own labels
     * and mask; one image is that key, several a hash of theirs in order
     * (a record apart from any one image's, so never a single fit's). */
    uint64_t keys[GS_FIT_IMAGES_MAX + 2] = {0x6d756c74692d6669ULL, (uint64_t)k};
    for (int i = 0; i < k; i++) {
        if (!im[i].rgb)
            return 0;
        gs_fit_options oi;
        gs_fit_options_of_image(&o, &im[i], &oi);
        oi.mask = im[i].mask;
        keys[2 + i] = gs_model_fit_key(m, &oi, im[i].rgb, im[i].stride);
    }
    if (k == 1)
        return keys[2];
    hash64 h;
    hash_init(&h, 0x6669742d6b65796eULL);
    hash_part(&h, keys, (size_t)(k + 2) * sizeof keys[0]);
    return hash_final(&h);
}
