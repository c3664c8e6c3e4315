/* gs_live: the eye-contact stage of `gazesplat live` (sources in
 * lib/capture/live_*.c, see docs/live.md).
 *
 *   tracking    face box and 68 landmarks seeded from the previous frame's
 *               landmarks; the detector runs only to (re)acquire a face and,
 *               every few frames, on a crop around it to confirm it is still
 *               a face; head pose (PnP) and eye openness (eye aspect ratio)
 *   subject     a background fit of the model on the first good frames, on
 *               a worker thread (pass-through until it is ready); a refit
 *               when the landmark-shape signature says the person changed
 *   eyes        the worker renders the subject's eyes looking into the
 *               camera (asynchronously, always on the newest target); each
 *               frame warps the latest rendered eyes onto its own eye
 *               corners with a similarity transform and blends them through
 *               feathered eye masks, weighted by the policy (capture.h)
 *
 * The model sits behind a small engine interface (fit, render) and the face
 * models behind a tracking interface (detect, landmarks), so tests drive the
 * stage with fakes; gs_live_engine_model and gs_live_track_ops_face are the
 * real ones. Pixels are 8-bit RGB; angles radians (geom.h conventions). */
#ifndef GAZESPLAT_LIVE_H
#define GAZESPLAT_LIVE_H

#include <stddef.h>
#include <stdint.h>

#include "gazesplat/capture.h"
#include "gazesplat/error.h"
#include "gazesplat/face.h"
#include "gazesplat/image_io.h"
#include "gazesplat/model.h"
#include "gazesplat/pool.h"

#ifdef __cplusplus
extern "C" {
#endif

/* ---- tracking ---------------------------------------------------------- */

typedef struct gs_live_track_ops {
    void *ctx;
    /* The largest face in img: *found 1 and *box (dlib convention), or
     * *found 0. min_size: smallest face side worth reporting, px. */
    int (*detect)(void *ctx, const gs_io_image *img, int min_size, gs_face_box *box,
                  int *found, gs_error *err);
    /* 68 landmarks (geom.h pixels) for a box. */
    int (*landmarks)(void *ctx, const gs_io_image *img, gs_face_box box, double uv[][2],
                     gs_error *err);
} gs_live_track_ops;

/* The real models: an OpenCV cascade and dlib's 68-point predictor, both
 * borrowed. Fill a gs_live_face_models and point the ops at it. */
typedef struct gs_live_face_models {
    gs_face_detector *det;
    const gs_face_shape_model *sp;
} gs_live_face_models;
gs_live_track_ops gs_live_track_ops_face(gs_live_face_models *m);

typedef struct gs_live_track_config {
    int verify_every;  /* frames between confirming detections on a crop (0: never; 15) */
    double max_jump;   /* lost when the landmarks' box moves or scales by more than
                          this fraction of its side in one frame (0.5) */
    int min_box;       /* smallest face box side, px (GS_FACE_MIN_BOX) */
} gs_live_track_config;
gs_live_track_config gs_live_track_config_default(void);

typedef struct gs_live_track_state {
    int face;              /* 1: a face is tracked in this frame */
    int detected;          /* 1: the full detector ran this frame (acquire/loss) */
    uint64_t track_id;     /* changes each time a face is acquired after a loss */
    gs_face_box box;       /* the box the landmarks were predicted in */
    double uv[GS_FACE_LANDMARKS][2];
    gs_face_pose pose;     /* head pose in the camera (needs k) */
    double openness;       /* mean of both eyes, 0 closed .. 1 open */
} gs_live_track_state;

typedef struct gs_live_track gs_live_track;

int gs_live_track_create(const gs_live_track_config *cfg, const gs_live_track_ops *ops,
                         gs_live_track **out, gs_error *err);
void gs_live_track_destroy(gs_live_track *t);
/* Tracks one frame. k: intrinsics for the head pose. A frame without a
 * face is GS_OK with st->face 0; errors are the ops' failures. */
int gs_live_track_update(gs_live_track *t, const gs_io_image *img, const double k[9],
                         gs_live_track_state *st, gs_error *err);

/* Box for the next frame from the current landmarks, using the offset and
 * scale between the detector's box and its landmarks measured at the last
 * detection (exposed for tests). */
gs_face_box gs_live_track_seed_box(const gs_live_track *t, const double uv[][2]);

/* Eye openness from the 68 landmarks: the eye aspect ratio
 * (|p2-p6| + |p3-p5|) / (2 |p1-p4|) of each eye, mapped linearly from
 * 0.10 (closed) .. 0.30 (open) to 0..1 and averaged over both eyes. */
double gs_live_eye_openness(const double uv[][2]);

/* The gaze (head frame) that looks from the eyes into the camera origin,
 * for head pose R, t (camera frame, mm): the mean over both eyes of
 * R^T normalize(-(R e + t)), e the eye centre of geom.h's 6-point model. */
int gs_live_camera_gaze(const double R[9], const double t[3], double *pitch, double *yaw);

/* ---- patch warp ----------------------------------------------------------- */

/* Similarity (rotation, uniform scale, translation) mapping dst0 -> src0 and
 * dst1 -> src1: src = [a -b; b a] dst + [tx ty], m = {a, b, tx, ty}.
 * GS_ERR_ARG when dst0 == dst1. */
int gs_live_similarity(const double dst0[2], const double dst1[2], const double src0[2],
                       const double src1[2], double m[4]);

/* Blends patch into frame through mask: for each frame pixel p (centre
 * x+0.5, y+0.5) in box [x0,x1) x [y0,y1) with mask value w (mask has the
 * box's size, one byte per pixel), frame = frame + alpha w/255 (patch(m p)
 * - frame), patch sampled bilinearly (geom.h pixels); pixels whose m p falls
 * outside the patch are left alone. */
void gs_live_blend_patch(uint8_t *frame, size_t stride, int width, int height, int x0, int y0,
                         int x1, int y1, const uint8_t *mask, const uint8_t *patch,
                         size_t patch_stride, int patch_w, int patch_h, const double m[4],
                         float alpha);

/* ---- engine: what the stage needs from the model ------------------------- */

/* A fitted subject plus where its eye corners (iBUG 36, 39, 42, 45) land in
 * its renders (normalized pixels). */
typedef struct gs_live_subject {
    gs_subject subject;
    double corners_n[4][2];
} gs_live_subject;

typedef struct gs_live_engine {
    void *ctx;
    int image_size;        /* renders are image_size^2 RGB */
    /* Fits a subject to the face of st in frame (k: intrinsics). Runs on
     * the stage's worker thread. */
    int (*fit)(void *ctx, const gs_io_image *frame, const gs_live_track_state *st,
               const double k[9], gs_live_subject *out, gs_error *err);
    /* Renders the subject at its fitted head pose with gaze (pitch, yaw),
     * head frame, into rgb (image_size^2, stride 3 image_size). */
    int (*render)(void *ctx, const gs_live_subject *s, double pitch, double yaw, uint8_t *rgb,
                  gs_error *err);
} gs_live_engine;

/* The real engine on a loaded model: one gs_model_ctx (the stage has one
 * worker) and an optional pool (NULL: serial). fit_budget_s bounds a fit
 * (0: 30 s). Free with gs_live_engine_model_free. */
int gs_live_engine_model(const gs_model *m, gs_pool *pool, double fit_budget_s,
                         gs_live_engine *out, gs_error *err);
void gs_live_engine_model_free(gs_live_engine *e);

/* ---- the stage ------------------------------------------------------------ */

typedef struct gs_live_config {
    int use_k;                 /* 1: intrinsics k; 0: gs_face_default_intrinsics */
    double k[9];
    gs_live_track_config track;
    int fit_after;             /* good frames before the first fit (5) */
    float fit_head_max_deg;    /* a good frame: head pitch and yaw within this (15) */
    float stale_full_s;        /* a patch whose gaze is off the current target
                                  blends fully up to this age (0.15 s) ... */
    float stale_max_s;         /* ... and not at all from this age (0.5 s) */
    float stale_gaze_deg;      /* the patch counts as current within this (1.0) */
    float feather_px;          /* eye mask feathering (3) */
    float change_tol;          /* person change: a shape ratio off by this
                                  fraction (0.12) ... */
    float change_s;            /* ... for this long (1.0 s) triggers a refit */
} gs_live_config;
gs_live_config gs_live_config_default(void);

typedef struct gs_live_status {
    uint64_t frames, faces, detections, losses;
    uint64_t fits, fit_failures, renders, refits;
    int face;                  /* tracked in the last frame */
    int subject_ready;         /* a fitted subject exists */
    int fitting;               /* a fit is running */
    float weight;              /* blend weight used on the last frame, 0..1 */
    float policy_weight;       /* the policy's output */
    float head_pitch, head_yaw;    /* last frame, radians */
    float target_pitch, target_yaw;/* gaze into the camera, head frame */
    float patch_age_s;         /* how old the blended patch was (-1: none) */
    float openness;
    double last_fit_s;         /* seconds the last fit took */
} gs_live_status;

typedef struct gs_live_stage gs_live_stage;

/* policy is borrowed (its settings may change at any time from any thread);
 * engine and ops are copied (their ctx borrowed). Starts the worker. */
int gs_live_stage_create(const gs_live_config *cfg, const gs_live_track_ops *ops,
                         const gs_live_engine *engine, gs_cap_policy *policy,
                         gs_live_stage **out, gs_error *err);
/* Stops the worker (a running fit finishes first). */
void gs_live_stage_destroy(gs_live_stage *s);

/* Processes one frame in place (the gs_cap_stage callback). */
int gs_live_stage_process(gs_live_stage *s, uint8_t *rgb, size_t stride, int width, int height,
                          int64_t t_capture_ns, gs_error *err);
gs_cap_stage gs_live_stage_as_cap(gs_live_stage *s);

/* Thread-safe snapshot. */
void gs_live_stage_get_status(gs_live_stage *s, gs_live_status *st);
/* Drops the subject and fits again on the next good frames. */
void gs_live_stage_refit(gs_live_stage *s);

#ifdef __cplusplus
}
#endif
#endif
