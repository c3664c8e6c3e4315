/* gazesplatd: request validation, run on the loop thread before a request
 * is queued, so bad requests are answered at once and never reach a
 * worker. Each check returns 0 or an ErrorCode with a message. */
#include <math.h>
#include <stdio.h>
#include <string.h>

#include "daemon.h"
#include "gazesplat/model.h"

#define E(x) GAZESPLAT__ERROR_CODE__##x

/* ---- request validation ---------------------------------------------------- */

static uint32_t be16(const uint8_t *p) { return (uint32_t)p[0] << 8 | p[1]; }
static uint32_t be32(const uint8_t *p) { return be16(p) << 16 | be16(p + 2); }

/* A JPEG's size from its first SOF marker (walking the marker segments
 * from SOI; entropy-coded data is never reached before a SOF). */
static int probe_jpeg(const uint8_t *p, size_t n, uint32_t *w, uint32_t *h)
{
    size_t i = 2;
    while (i + 4 <= n) {
        if (p[i] != 0xFF)
            return -1;
        uint8_t m = p[i + 1];
        if (m == 0xFF || m == 0x01 || (m >= 0xD0 && m <= 0xD8)) { /* fill, TEM, RSTn, SOI */
            i += m == 0xFF ? 1 : 2;
            continue;
        }
        if (m == 0xDA || m == 0xD9) /* scan or end before any frame header */
            return -1;
        if (m >= 0xC0 && m <= 0xCF && m != 0xC4 && m != 0xC8 && m != 0xCC) {
            if (i + 9 > n) /* FF Cn, length, precision, height, width */
                return -1;
            *h = be16(p + i + 5);
            *w = be16(p + i + 7);
            return 0;
        }
        i += 2 + be16(p + i + 2);
    }
    return -1;
}

int gsd_image_probe(const uint8_t *p, size_t n, uint32_t *w, uint32_t *h)
{
    if (n >= 24 && memcmp(p, "\x89PNG\r\n\x1a\n", 8) == 0 && memcmp(p + 12, "IHDR", 4) == 0) {
        *w = be32(p + 16);
        *h = be32(p + 20);
        return 0;
    }
    if (n >= 4 && p[0] == 0xFF && p[1] == 0xD8 && p[2] == 0xFF)
        return probe_jpeg(p, n, w, h);
    return -1;
}

int gsd_utf8_valid(const char *str, size_t n)
{
    const uint8_t *p = (const uint8_t *)str;
    size_t i = 0;
    while (i < n) {
        uint8_t b = p[i];
        if (b < 0x80) {
            i++;
            continue;
        }
        /* Lead byte: length and the least code point of that length
         * (less is an overlong form). C0, C1 and F5..FF never lead. */
        size_t len = b >= 0xC2 && b <= 0xDF ? 2 : b >= 0xE0 && b <= 0xEF ? 3
                   : b >= 0xF0 && b <= 0xF4 ? 4 : 0;
        if (len == 0)
            return 0;
        static const uint32_t lead_mask[5] = {0, 0, 0x1F, 0x0F, 0x07};
        static const uint32_t least[5] = {0, 0, 0x80, 0x800, 0x10000};
        uint32_t cp = b & lead_mask[len];
        if (n - i < len)
            return 0;
        for (size_t k = 1; k < len; k++) {
            if ((p[i + k] & 0xC0) != 0x80)
                return 0;
            cp = cp << 6 | (p[i + k] & 0x3F);
        }
        if (cp < least[len] || cp > 0x10FFFF || (cp >= 0xD800 && cp <= 0xDFFF))
            return 0;
        i += len;
    }
    return 1;
}

static int has_png_signature(const uint8_t *p, size_t n)
{
    return n >= 8 && memcmp(p, "\x89PNG\r\n\x1a\n", 8) == 0;
}

static int has_jpeg_signature(const uint8_t *p, size_t n)
{
    return n >= 3 && p[0] == 0xFF && p[1] == 0xD8 && p[2] == 0xFF;
}

int gsd_check_image(const gsd_server *s, const Gazesplat__Image *img, char *msg, size_t cap)
{
    /* Until the face models are loaded (state 0) the server-state check
     * answers ERR_LOADING. */
    if (img->kind == GAZESPLAT__IMAGE_KIND__KIND_PHOTO && atomic_load(&s->photo_state) < 0) {
        snprintf(msg, cap, "photo input unavailable: %s; send a normalized face (kind NORMALIZED_FACE)",
                 s->photo_msg);
        return E(ERR_PHOTO_UNSUPPORTED);
    }
    if (img->kind != GAZESPLAT__IMAGE_KIND__KIND_NORMALIZED_FACE && img->kind != GAZESPLAT__IMAGE_KIND__KIND_PHOTO) {
        snprintf(msg, cap, "unknown image kind %d", (int)img->kind);
        return E(ERR_INVALID_ARGUMENT);
    }
    /* An unknown enum value is a field out of range; ERR_BAD_IMAGE is for
     * data that does not decode as the format named. */
    if (img->format != GAZESPLAT__IMAGE_FORMAT__FORMAT_PNG &&
        img->format != GAZESPLAT__IMAGE_FORMAT__FORMAT_JPEG &&
        img->format != GAZESPLAT__IMAGE_FORMAT__FORMAT_RAW_RGB8) {
        if (img->format == GAZESPLAT__IMAGE_FORMAT__FORMAT_NONE)
            snprintf(msg, cap, "image format not given (FORMAT_NONE); want PNG, JPEG or RAW_RGB8");
        else
            snprintf(msg, cap, "unknown image format %d; want PNG, JPEG or RAW_RGB8", (int)img->format);
        return E(ERR_INVALID_ARGUMENT);
    }
    if (img->data.len == 0) {
        snprintf(msg, cap, "empty image data");
        return E(ERR_BAD_IMAGE);
    }
    size_t side = (size_t)s->cfg.max_image_side, mpix = (size_t)s->cfg.max_image_mpix << 20;
    switch (img->format) {
    case GAZESPLAT__IMAGE_FORMAT__FORMAT_PNG:
    case GAZESPLAT__IMAGE_FORMAT__FORMAT_JPEG: {
        /* A decompression bomb is refused here, on the loop thread, from
         * the size its header declares; the decoder checks again. */
        uint32_t w, h;
        if (gsd_image_probe(img->data.data, img->data.len, &w, &h) == 0 &&
            (w > side || h > side || (size_t)w * h > mpix)) {
            snprintf(msg, cap, "image header declares %ux%u, over %zu per side or %zu pixels", w, h,
                     side, mpix);
            return E(ERR_IMAGE_TOO_LARGE);
        }
        /* The format named must be the data's: PNG bytes labelled JPEG (or
         * the reverse) are refused, not decoded as what they turn out to be. */
        int png = has_png_signature(img->data.data, img->data.len);
        int jpeg = has_jpeg_signature(img->data.data, img->data.len);
        int want_png = img->format == GAZESPLAT__IMAGE_FORMAT__FORMAT_PNG;
        if (want_png ? !png : !jpeg) {
            snprintf(msg, cap, "format says %s but the data %s", want_png ? "PNG" : "JPEG",
                     png ? "is PNG" : jpeg ? "is JPEG" : "has neither signature");
            return E(ERR_BAD_IMAGE);
        }
        return 0;
    }
    case GAZESPLAT__IMAGE_FORMAT__FORMAT_RAW_RGB8:
        if (img->width == 0 || img->height == 0 || img->width > side || img->height > side ||
            (size_t)img->width * img->height > mpix) {
            snprintf(msg, cap, "raw image %ux%u outside 1..%zu per side, %zu pixels", img->width,
                     img->height, side, mpix);
            return img->width == 0 || img->height == 0 ? E(ERR_BAD_IMAGE) : E(ERR_IMAGE_TOO_LARGE);
        }
        if (img->stride < 3u * img->width ||
            img->data.len < (size_t)img->stride * (img->height - 1) + 3u * img->width) {
            snprintf(msg, cap, "raw image %ux%u stride %u needs %zu bytes, got %zu", img->width,
                     img->height, img->stride, (size_t)img->stride * (img->height - 1) + 3u * img->width,
                     img->data.len);
            return E(ERR_BAD_IMAGE);
        }
        return 0;
    default: /* refused above */
        return E(ERR_INVALID_ARGUMENT);
    }
}

/* A target's gaze and head (either NULL when absent) against the target
 * table (gazesplat/model.h, inclusive limits): what names the target in
 * the message. The renderer checks the same table, so a target passed
 * here is never refused once its job has started. */
static int check_target(const Gazesplat__Angles *gaze, const Gazesplat__Angles *head,
                        const char *what, char *msg, size_t cap)
{
    double g[2] = {gaze ? gaze->pitch_deg : 0, gaze ? gaze->yaw_deg : 0};
    double h[2] = {head ? head->pitch_deg : 0, head ? head->yaw_deg : 0};
    gs_error err;
    gs_error_clear(&err);
    if (gs_model_check_target(gaze ? g : NULL, head ? h : NULL, &err) != GS_OK) {
        snprintf(msg, cap, "%s%s", what, err.msg);
        return E(ERR_INVALID_ARGUMENT);
    }
    return 0;
}

int gsd_check_deadline(const gsd_server *s, uint32_t ms, char *msg, size_t cap)
{
    if (ms > (uint32_t)s->cfg.max_deadline_ms) {
        snprintf(msg, cap, "deadline %u ms over max_deadline_ms %d", ms, s->cfg.max_deadline_ms);
        return E(ERR_INVALID_ARGUMENT);
    }
    return 0;
}

static int check_intrinsics(const Gazesplat__Intrinsics *k, char *msg, size_t cap)
{
    if (k && (!isfinite(k->fx) || !isfinite(k->fy) || !isfinite(k->cx) || !isfinite(k->cy) ||
              k->fx <= 0 || k->fy <= 0)) {
        snprintf(msg, cap, "intrinsics need finite values and fx, fy > 0");
        return E(ERR_INVALID_ARGUMENT);
    }
    return 0;
}

/* finetune_steps / finetune_parts / finetune_outline_px of FIT and
 * REDIRECT. */
static int check_finetune(const gsd_server *s, uint32_t steps, const char *parts,
                          uint32_t outline, int no_mirror, double lr, char *msg, size_t cap)
{
    int has_parts = parts && parts[0];
    if ((has_parts || outline || no_mirror || lr != 0) && !steps) {
        snprintf(msg, cap, "%s without finetune_steps",
                 has_parts ? "finetune_parts"
                 : outline ? "finetune_outline_px"
                 : no_mirror ? "finetune_no_mirror" : "finetune_lr");
        return E(ERR_INVALID_ARGUMENT);
    }
    if (outline > 8) {
        snprintf(msg, cap, "finetune_outline_px %u over 8", outline);
        return E(ERR_INVALID_ARGUMENT);
    }
    if (!isfinite(lr) || lr < 0 || lr > 1) { /* 0: the server's finetune_lr */
        snprintf(msg, cap, "finetune_lr %g out of (0, 1]", lr);
        return E(ERR_INVALID_ARGUMENT);
    }
    if (!steps)
        return 0;
    if (s->cfg.max_finetune_steps == 0) {
        snprintf(msg, cap, "fine-tuning is off on this server (max_finetune_steps = 0)");
        return E(ERR_INVALID_ARGUMENT);
    }
    if (steps > (uint32_t)s->cfg.max_finetune_steps) {
        snprintf(msg, cap, "finetune_steps %u over max_finetune_steps %d", steps,
                 s->cfg.max_finetune_steps);
        return E(ERR_INVALID_ARGUMENT);
    }
    unsigned bits;
    gs_error err;
    gs_error_clear(&err);
    if (has_parts && gs_finetune_parts_parse(parts, &bits, &err) != GS_OK) {
        snprintf(msg, cap, "%s", err.msg);
        return E(ERR_INVALID_ARGUMENT);
    }
    return 0;
}

/* An image's declared size (RAW fields, or the PNG/JPEG header); -1 when
 * the header says none (the decoder then explains). */
static int declared_size(const Gazesplat__Image *img, uint32_t *w, uint32_t *h)
{
    if (img->format == GAZESPLAT__IMAGE_FORMAT__FORMAT_RAW_RGB8) {
        *w = img->width;
        *h = img->height;
        return 0;
    }
    return gsd_image_probe(img->data.data, img->data.len, w, h);
}

/* FitRequest.more_images: at most GSD_FIT_IMAGES_MAX images in all, each
 * valid with valid labels, all of image 0's kind, normalized faces all of
 * one size. The message names the image (0: FitRequest.image). */
static int check_more_images(const gsd_server *s, const Gazesplat__FitRequest *r, char *msg,
                             size_t cap)
{
    if (r->n_more_images + 1 > GSD_FIT_IMAGES_MAX) {
        snprintf(msg, cap, "too many images: %zu, want 1..%d of one person",
                 r->n_more_images + 1, GSD_FIT_IMAGES_MAX);
        return E(ERR_INVALID_ARGUMENT);
    }
    uint32_t w0 = 0, h0 = 0;
    int have0 = r->n_more_images && declared_size(r->image, &w0, &h0) == 0;
    for (size_t i = 0; i < r->n_more_images; i++) {
        const Gazesplat__FitImage *f = r->more_images[i];
        char what[48], sub[300];
        int e;
        snprintf(what, sizeof what, "image %zu: ", i + 1);
        if (!f->image) {
            snprintf(msg, cap, "image %zu has no image", i + 1);
            return E(ERR_INVALID_ARGUMENT);
        }
        if ((e = gsd_check_image(s, f->image, sub, sizeof sub)) != 0 ||
            (e = check_intrinsics(f->intrinsics, sub, sizeof sub)) != 0) {
            snprintf(msg, cap, "%s%s", what, sub);
            return e;
        }
        if ((e = check_target(f->gaze, f->head, what, msg, cap)) != 0)
            return e;
        if (f->image->kind != r->image->kind) {
            snprintf(msg, cap, "image %zu is a %s and image 0 a %s: the images of one FIT are "
                     "all photos or all normalized faces", i + 1,
                     f->image->kind == GAZESPLAT__IMAGE_KIND__KIND_PHOTO ? "photo" : "normalized face",
                     r->image->kind == GAZESPLAT__IMAGE_KIND__KIND_PHOTO ? "photo" : "normalized face");
            return E(ERR_INVALID_ARGUMENT);
        }
        uint32_t w, h;
        if (r->image->kind == GAZESPLAT__IMAGE_KIND__KIND_NORMALIZED_FACE && have0 &&
            declared_size(f->image, &w, &h) == 0 && (w != w0 || h != h0)) {
            snprintf(msg, cap, "images of different sizes: image %zu is %ux%u, image 0 %ux%u "
                     "(normalized faces of one model are all its size)", i + 1, w, h, w0, h0);
            return E(ERR_INVALID_ARGUMENT);
        }
    }
    return 0;
}

int gsd_check_fit(const gsd_server *s, const Gazesplat__FitRequest *r, char *msg, size_t cap)
{
    int e;
    if (!r->image) {
        snprintf(msg, cap, "FIT without an image");
        return E(ERR_INVALID_ARGUMENT);
    }
    if ((e = gsd_check_image(s, r->image, msg, cap)) != 0 ||
        (e = check_target(r->gaze, r->head, r->n_more_images ? "image 0: FIT label: " : "FIT label: ",
                          msg, cap)) != 0)
        return e;
    if ((e = check_intrinsics(r->intrinsics, msg, cap)) != 0)
        return e;
    if ((e = check_more_images(s, r, msg, cap)) != 0)
        return e;
    if (r->max_iters > 100000) {
        snprintf(msg, cap, "max_iters %u over 100000", r->max_iters);
        return E(ERR_INVALID_ARGUMENT);
    }
    if ((e = check_finetune(s, r->finetune_steps, r->finetune_parts, r->finetune_outline_px,
                              r->finetune_no_mirror, r->finetune_lr, msg, cap)) != 0)
        return e;
    return gsd_check_deadline(s, r->deadline_ms, msg, cap);
}

static int key_is_zero(const uint8_t *key)
{
    for (int i = 0; i < GS_FRAME_KEY_SIZE; i++)
        if (key[i])
            return 0;
    return 1;
}

int gsd_check_redirect(const gsd_server *s, const gs_frame_header *h,
                          const Gazesplat__RedirectRequest *r, char *msg, size_t cap)
{
    int e;
    if (r->n_targets == 0 || r->n_targets > (size_t)s->cfg.max_targets) {
        snprintf(msg, cap, "%zu targets, want 1..%d", r->n_targets, s->cfg.max_targets);
        return E(ERR_INVALID_ARGUMENT);
    }
    /* Every target, before the job is queued. */
    for (size_t i = 0; i < r->n_targets; i++) {
        char what[48];
        if (!r->targets[i]->gaze) {
            snprintf(msg, cap, "target %zu has no gaze", i);
            return E(ERR_INVALID_ARGUMENT);
        }
        snprintf(what, sizeof what, "target %zu: ", i);
        if ((e = check_target(r->targets[i]->gaze, r->targets[i]->head, what, msg, cap)))
            return e;
    }
    if (r->image && (e = gsd_check_image(s, r->image, msg, cap)) != 0)
        return e;
    if (!r->image && key_is_zero(h->key)) {
        snprintf(msg, cap, "REDIRECT needs a subject key in the header or an inline image");
        return E(ERR_INVALID_ARGUMENT);
    }
    if (r->max_iters > 100000) {
        snprintf(msg, cap, "max_iters %u over 100000", r->max_iters);
        return E(ERR_INVALID_ARGUMENT);
    }
    if (!r->image && (r->finetune_steps || r->finetune_outline_px || r->finetune_no_mirror ||
                      r->finetune_lr != 0 ||
                      (r->finetune_parts && r->finetune_parts[0]))) {
        snprintf(msg, cap, "finetune_steps go with an inline image (a fitted subject keeps "
                           "its own fine-tuning)");
        return E(ERR_INVALID_ARGUMENT);
    }
    if ((e = check_finetune(s, r->finetune_steps, r->finetune_parts, r->finetune_outline_px,
                              r->finetune_no_mirror, r->finetune_lr, msg, cap)) != 0)
        return e;
    if ((e = check_intrinsics(r->intrinsics, msg, cap)) != 0)
        return e;
    if (!isfinite(r->min_quality) || r->min_quality < 0 || r->min_quality > 1) {
        snprintf(msg, cap, "min_quality %g out of [0, 1]", r->min_quality);
        return E(ERR_INVALID_ARGUMENT);
    }
    if (r->output_format > GAZESPLAT__IMAGE_FORMAT__FORMAT_RAW_RGB8 || r->jpeg_quality > 100) {
        snprintf(msg, cap, "output format %d / jpeg quality %u out of range", (int)r->output_format,
                 r->jpeg_quality);
        return E(ERR_INVALID_ARGUMENT);
    }
    if (r->output_mode == GAZESPLAT__OUTPUT_MODE__OUTPUT_PASTE_BACK &&
        (!r->image || r->image->kind != GAZESPLAT__IMAGE_KIND__KIND_PHOTO)) {
        snprintf(msg, cap, "PASTE_BACK needs the photo in the request (image of kind PHOTO)");
        return E(ERR_INVALID_ARGUMENT);
    }
    if (r->output_mode != GAZESPLAT__OUTPUT_MODE__OUTPUT_NORMALIZED &&
        r->output_mode != GAZESPLAT__OUTPUT_MODE__OUTPUT_PASTE_BACK) {
        snprintf(msg, cap, "unknown output mode %d", (int)r->output_mode);
        return E(ERR_INVALID_ARGUMENT);
    }
    return gsd_check_deadline(s, r->deadline_ms, msg, cap);
}
