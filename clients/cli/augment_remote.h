/* gazesplat augment --addr: each source's fit and renders through
 * gazesplatd (FIT, then REDIRECT by the subject's key), the same requests
 * `gazesplat client fit` and `client redirect` send. */
#ifndef GS_CLI_AUGMENT_REMOTE_H
#define GS_CLI_AUGMENT_REMOTE_H

#include <stddef.h>
#include <stdint.h>

#include "gazesplat/face.h"

typedef struct gs_client gs_client;

typedef struct aug_remote_fit {
    const uint8_t *image; /* PNG or JPEG bytes */
    size_t len;
    int photo;            /* KIND_PHOTO (the server detects and normalizes) */
    int iters;            /* max_iters (0: the server's) */
    int ft_steps;         /* finetune_steps (0: none) */
    double ft_lr;         /* finetune_lr (0: the server's) */
    int keep_image;       /* for a REDIRECT with transfer by key */
    int known_gaze, known_head;
    double gaze_deg[2], head_deg[2]; /* head frame; normalized camera */
} aug_remote_fit;

typedef struct aug_remote_subject {
    uint8_t key[16];
    double gaze_deg[2], head_deg[2]; /* the fit's: head frame; normalized camera */
    double psnr, ssim, ft_psnr;      /* ft_psnr NaN unless this FIT fine-tuned */
    int cached;                      /* the server knew the subject: nothing ran */
} aug_remote_subject;

typedef struct aug_remote_target {
    double gaze_deg[2];
    int use_head;
    double head_deg[2];
} aug_remote_target;

/* What the calls below return: 0, or one of these with a message. RETRY:
 * the same request may succeed on a new connection (the connection was
 * lost or refused, or the server answered ERR_TIMEOUT,
 * ERR_TOO_MANY_CONNECTIONS, ERR_LOADING, ERR_SHUTTING_DOWN, or
 * ERR_UNKNOWN_SUBJECT, which a new FIT mends); FATAL: it will not (bad
 * arguments, a refused face, a timeout: the server may still be at it). */
enum { AUG_REMOTE_FATAL = -1, AUG_REMOTE_RETRY = -2 };

/* Connects and says HELLO, with route_key (NULL: zero) in its header so a
 * proxy routing on it picks the subject's daemon; *image_size is the
 * server's model's. */
int aug_remote_connect(const char *addr, const char *token, const uint8_t *route_key,
                       gs_client **out, int *image_size, char *server, size_t server_cap,
                       char *msg, size_t cap);
void aug_remote_close(gs_client *c);

/* FIT; BUSY is waited out (its retry hint). Returns 0 or AUG_REMOTE_*. */
int aug_remote_fit_one(gs_client *c, const aug_remote_fit *in, aug_remote_subject *out, char *msg,
                       size_t cap);

/* REDIRECT by key, n targets (sent in groups of the server's
 * max_targets), raw RGB8 of size x size into out + i * rec for target i;
 * q (NULL: not asked for, or n entries): the server's Quality of each image, score NaN
 * where it sent none (face.h, gs_face_quality; the irises' records are
 * left zero). */
int aug_remote_render(gs_client *c, const aug_remote_subject *s, const aug_remote_target *t,
                      size_t n, int transfer, int size, uint8_t *out, size_t rec,
                      gs_face_quality *q, char *msg, size_t cap);

#endif
