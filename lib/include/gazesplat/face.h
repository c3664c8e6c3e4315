/* gs_face: real faces. A photo in, the normalized face the model fits out,
 * and the redirected face pasted back into the photo.
 *
 *   detect      OpenCV cascade (Debian opencv-data) -> face boxes, mapped to
 *               the box convention of dlib's HOG detector, largest first
 *   landmarks   68 iBUG points by our own implementation of dlib's ensemble
 *               of regression trees (Kazemi & Sullivan 2014), reading dlib's
 *               shape_predictor_68_face_landmarks.dat; identical to dlib's
 *               own points for the same box
 *   pose        solvePnP (EPnP, then Levenberg-Marquardt) of a 6-point face
 *               model of geom.h (generic or the synthetic mean head); t is
 *               the face centre
 *   normalize   gs_geom_normalize + a perspective warp (and its inverse)
 *   masks       face and eye regions from the landmarks, at any size
 *   paste-back  a redirected normalized face blended into the photo through
 *               a feathered mask, in the photo's own pixels
 *
 * Frames, units and pixel conventions are those of geom.h: millimetres,
 * radians, OpenCV camera frame, pixel centres at +0.5. Boxes are the one
 * exception: they are dlib rectangles (integer, inclusive corners, pixel
 * centres at integers), because the landmark model was trained on them.
 *
 * The 68-point model was trained on the iBUG 300-W data set, whose owners
 * ask that it not be used commercially.
 *
 * Images are gs_io_image (8-bit RGB). Every call returns GS_OK or a negative
 * gs_status and fills the optional gs_error. A photo without a usable face
 * is GS_ERR_ARG with a message that says why (no face, face too small,
 * landmarks outside the image). Models are read-only after loading and may
 * be shared by threads; a detector may not (OpenCV's cascade is not
 * re-entrant): one per thread. */
#ifndef GAZESPLAT_FACE_H
#define GAZESPLAT_FACE_H

#include <stddef.h>
#include <stdint.h>

#include "gazesplat/error.h"
#include "gazesplat/geom.h"
#include "gazesplat/image_io.h"

#ifdef __cplusplus
extern "C" {
#endif

#define GS_FACE_LANDMARKS 68
/* Faces whose box is narrower than this are refused ("too small"): the
 * landmark model was trained on faces of about 80 px and above. */
#define GS_FACE_MIN_BOX 40
/* Model file of Debian's libdlib-data. */
#define GS_FACE_SHAPE_MODEL_DEFAULT "/usr/share/dlib/shape_predictor_68_face_landmarks.dat"
/* Cascade of Debian's opencv-data (chosen on the test photos, docs/face.md). */
#define GS_FACE_CASCADE_DEFAULT \
    "/usr/share/opencv4/haarcascades/haarcascade_frontalface_alt2.xml"

/* A dlib rectangle: inclusive integer corners, width = right - left + 1. */
typedef struct gs_face_box {
    int left, top, right, bottom;
} gs_face_box;

/* ---- landmarks: ensemble of regression trees ---- */

typedef struct gs_face_shape_model gs_face_shape_model;

/* Parses a dlib shape_predictor serialization held in memory (the data is
 * copied). Refuses truncated, corrupt and inconsistent data with
 * GS_ERR_FORMAT, shapes this implementation does not handle (trees of
 * different depths, more than 256 parts) with GS_ERR_UNSUPPORTED, and sizes
 * over 1 GiB with GS_ERR_LIMIT. Destroy with gs_face_shape_model_destroy. */
int gs_face_shape_model_parse(const void *buf, size_t len,
                              gs_face_shape_model **out, gs_error *err);
/* Same, from a file; NULL path: GS_FACE_SHAPE_MODEL_DEFAULT. The 99 MB
 * model takes a few hundred ms: load it once per process. */
int gs_face_shape_model_load(const char *path, gs_face_shape_model **out,
                             gs_error *err);
void gs_face_shape_model_destroy(gs_face_shape_model *m);
/* Number of landmarks the model predicts (68 for dlib's model). */
int gs_face_shape_model_parts(const gs_face_shape_model *m);

/* Runs the predictor on `box`. pts (n_parts x 2, may be NULL) receives
 * dlib's integer points (pixel centres at integers, exactly what
 * dlib::shape_predictor returns); uv (n_parts x 2, may be NULL) the same
 * points before rounding, in geom.h pixels (+0.5). Boxes need not lie
 * inside the image (pixels outside read as 0, as in dlib). GS_ERR_ARG for
 * an empty box or image. */
int gs_face_shape_predict(const gs_face_shape_model *m,
                          const gs_io_image *img, gs_face_box box, int *pts,
                          double *uv, gs_error *err);

/* ---- detection ---- */

typedef struct gs_face_detector gs_face_detector;

/* Loads an OpenCV cascade XML; NULL path: GS_FACE_CASCADE_DEFAULT. */
int gs_face_detector_load(const char *path, gs_face_detector **out,
                          gs_error *err);
void gs_face_detector_destroy(gs_face_detector *d);

typedef struct gs_face_detect_opts {
    double scale_factor;  /* pyramid step, > 1 (default 1.1) */
    int min_neighbors;    /* cascade vote (default 5) */
    int min_size;         /* smallest face, px; 0 (default): 1/16 of the
                             image's shorter side, at least 24 */
} gs_face_detect_opts;
void gs_face_detect_opts_default(gs_face_detect_opts *o);

typedef struct gs_face_detection {
    gs_face_box box;      /* in dlib's HOG box convention (the fit below) */
    gs_face_box cascade;  /* the cascade's own box */
} gs_face_detection;

/* Finds faces, largest first (ties: top, then left). Writes up to `cap`
 * detections and the number found (possibly more than cap) to *n. opts may
 * be NULL (defaults). */
int gs_face_detect(gs_face_detector *d, const gs_io_image *img,
                   const gs_face_detect_opts *opts, gs_face_detection *out,
                   int cap, int *n, gs_error *err);

/* The fixed box affine from a cascade box (x, y, w, h; OpenCV pixels) to
 * dlib's HOG convention: centre shifted by (GS_FACE_BOX_DX, GS_FACE_BOX_DY)
 * times w, side scaled by GS_FACE_BOX_SCALE. Fitted on the test photos by
 * scripts/fit-face-box.py; see docs/face.md. */
#define GS_FACE_BOX_SCALE 0.9405
#define GS_FACE_BOX_DX (-0.0094)
#define GS_FACE_BOX_DY 0.0542
gs_face_box gs_face_box_from_cascade(int x, int y, int w, int h);

/* ---- head pose ---- */

/* Default intrinsics for a w x h photo when the caller has none: focal
 * length = the longer side in pixels (about a 53 degree field across it,
 * typical of webcams and phone cameras), principal point at the centre,
 * no distortion. */
void gs_face_default_intrinsics(int width, int height, double k[9]);

/* Which 6-point face model the pose is solved against. The two head frames
 * differ by about 12 deg of pitch, and their shapes differ too (the
 * synthetic head's nose wings stand 21 mm in front of its inner eye
 * corners, the generic model's 7 mm): on the mean synthetic head the
 * generic model errs by 14 deg on average (docs/face.md). Pick the model
 * whose frame the consumer of the pose uses:
 *   GENERIC  gs_geom_face_model6, the widely used generic model: head angles
 *            comparable with other tools (the default of gs_face_opts).
 *   SYNTH    gs_geom_face_model6_synth and gs_geom_face_nose7_synth, 13
 *            points of the mean synthetic head of lib/synth: the head
 *            frame the synthetic labels, and so every model trained on
 *            them, use (`gazesplat redirect`, the daemon's photo input).
 *            The nose bridge makes its tilt well-conditioned. */
typedef enum gs_face_pose_model {
    GS_FACE_POSE_GENERIC = 0,
    GS_FACE_POSE_SYNTH = 1
} gs_face_pose_model;

/* The model's six points (iBUG 36, 39, 42, 45, 31, 35), head frame, mm.
 * GS_ERR_ARG for an unknown model. */
int gs_face_model6(gs_face_pose_model model, double out[6][3]);

typedef struct gs_face_pose {
    double R[9];        /* head to camera rotation (geom.h head frame) */
    double rvec[3];     /* the same, axis-angle */
    double t[3];        /* face centre, camera frame, mm: X = R X_head + t */
    double pitch, yaw;  /* head angles (gs_geom_head_pitchyaw), radians */
    double rms_px;      /* reprojection error, px, of the points solved
                           from (6; 13 for SYNTH) */
} gs_face_pose;

/* Head pose from the 68 landmarks (uv, geom.h pixels) and intrinsics k:
 * solvePnP of the generic 6-point model (iBUG 36, 39, 42, 45, 31, 35)
 * centred on its face centre, EPnP then iterative Levenberg-Marquardt. GS_ERR_ARG when
 * the solution puts the face behind the camera. */
int gs_face_head_pose(const double uv[][2], const double k[9],
                      gs_face_pose *out, gs_error *err);
/* The same against either model (gs_face_head_pose is GENERIC). */
int gs_face_head_pose_model(const double uv[][2], const double k[9],
                            gs_face_pose_model model, gs_face_pose *out,
                            gs_error *err);

/* ---- the whole analysis ---- */

typedef struct gs_face_opts {
    int index;              /* which detection, largest first (default 0) */
    int use_box;            /* 1: skip detection and use `box` */
    gs_face_box box;
    int use_k;              /* 1: camera intrinsics `k`; 0: the default */
    double k[9];
    gs_face_pose_model pose_model; /* default GS_FACE_POSE_GENERIC */
    int norm_size;          /* normalized image side (default 512) */
    double norm_distance_mm; /* d_n (default GS_GEOM_NORM_DISTANCE_MM) */
    double norm_focal;      /* f_n (default gs_geom_norm_focal(norm_size)) */
    gs_face_detect_opts detect;
} gs_face_opts;
void gs_face_opts_default(gs_face_opts *o);

/* Everything a redirect needs to fit the normalized face and paste the
 * result back. */
typedef struct gs_face_result {
    int image_width, image_height;
    int n_faces;                    /* detections (0 when use_box) */
    gs_face_box box;                /* the face used */
    int pts[GS_FACE_LANDMARKS][2];  /* dlib's integer landmarks */
    double uv[GS_FACE_LANDMARKS][2];     /* landmarks, geom.h pixels */
    double uv_n[GS_FACE_LANDMARKS][2];   /* the same in the normalized image */
    double k[9];                    /* intrinsics used */
    gs_face_pose pose;              /* in the photo's camera */
    gs_geom_norm norm;              /* normalization of this face */
    double head_pitch_n, head_yaw_n; /* head angles in the normalized camera */
} gs_face_result;

/* Photo -> detection -> landmarks -> head pose -> normalization. `det` may
 * be NULL when opts->use_box. Errors (GS_ERR_ARG): no face, index past the
 * faces found, box narrower than GS_FACE_MIN_BOX, a landmark outside the
 * image. */
int gs_face_analyze(gs_face_detector *det, const gs_face_shape_model *sp,
                    const gs_io_image *img, const gs_face_opts *opts,
                    gs_face_result *out, gs_error *err);

/* The same from 68 landmarks found by other means (iBUG order, geom.h
 * pixels of a width x height photo): head pose and normalization, as
 * gs_face_analyze does after its own landmarks. `box` becomes the
 * landmarks' bounding box; opts->index, use_box and detect are unused.
 * GS_ERR_ARG for a landmark outside the photo, GS_ERR_NONFINITE for NaN. */
int gs_face_analyze_landmarks(const double uv[][2], int width, int height,
                              const gs_face_opts *opts, gs_face_result *out,
                              gs_error *err);

/* ---- warps ---- */

/* The normalized face: img warped by n->W into a new n->width x
 * n->height image (bilinear, black outside). Free with gs_io_image_free. */
int gs_face_normalize_image(const gs_io_image *img, const gs_geom_norm *n,
                            gs_io_image *out, gs_error *err);
/* The inverse: a normalized image warped by n->W_inv back into a new
 * width x height image in the photo's pixels. */
int gs_face_denormalize_image(const gs_io_image *norm_img,
                              const gs_geom_norm *n, int width, int height,
                              gs_io_image *out, gs_error *err);

/* ---- masks ---- */

typedef enum gs_face_mask_kind {
    GS_FACE_MASK_FACE = 0,       /* hull of jaw (0-16) and brows (17-26),
                                    the brows raised by 10% of the face
                                    height to take in the forehead's lower
                                    part; eyes included */
    GS_FACE_MASK_FACE_NO_EYES = 1, /* FACE minus both eye masks */
    GS_FACE_MASK_EYES = 2,       /* both eye polygons (36-41, 42-47) */
    GS_FACE_MASK_RIGHT_EYE = 3,  /* 36-41, the subject's right (image left) */
    GS_FACE_MASK_LEFT_EYE = 4,   /* 42-47 */
    GS_FACE_MASK_EYE_OPENINGS = 5 /* both eye polygons as the landmarks
                                     draw them (not grown): where the
                                     eyeball shows between the lids */
} gs_face_mask_kind;

/* Rasterizes a mask into `mask` (width x height bytes, row-major): the
 * polygon grown by `dilate` pixels (eye polygons but EYE_OPENINGS also by 30% of
 * the eye width so lids and a margin of skin move with the eye), with a
 * linear ramp `feather` pixels wide centred on its edge (0: hard edge).
 * Values 0..255. uv: the 68 landmarks in the mask's own pixels (geom.h;
 * result.uv for the photo, result.uv_n for the normalized image). */
int gs_face_mask(const double uv[][2], gs_face_mask_kind kind, double dilate,
                 double feather, int width, int height, uint8_t *mask,
                 gs_error *err);

/* ---- paste-back ---- */

/* Blends a redirected normalized face into `photo` in place: each photo
 * pixel p gets mask(p) * face(W p) + (1 - mask(p)) * photo(p), the face
 * sampled bilinearly at W p (geom.h pixels). `mask` is in the photo's
 * pixels (photo->width x photo->height), e.g. gs_face_mask of kind FACE or
 * EYES on result.uv with some feathering; pixels where it is 0, and those
 * whose W p falls outside the normalized face, are left alone. */
int gs_face_paste_back(gs_io_image *photo, const gs_io_image *norm_face,
                       const gs_geom_norm *n, const uint8_t *mask,
                       gs_error *err);

/* The mask every photo path pastes with (the daemon, gazesplat redirect):
 * the EYES polygons (whole_face: FACE) of r->uv grown by 2 px, with a ramp
 * of 4 % of the face box's width (at least 2 px), so the seam is as soft on
 * a large face as on a small one. mask: r->image_width x r->image_height. */
int gs_face_paste_mask(const gs_face_result *r, int whole_face, uint8_t *mask,
                       gs_error *err);

/* ---- the gate: can this face be redirected well? ----
 *
 * Checked before any fit. A refusal is a normal result (GS_OK with
 * `refusal` set and `reason` in words), so callers can report it and go
 * on: the CLI exits 3, the daemon answers ERR_FACE_REFUSED, augment lists
 * the source as refused. Thresholds and why (docs/face.md, "The gate"):
 *
 *   at border     more than max_outside of the face lies outside the photo
 *   head pose     the head (normalized camera) beyond the range the
 *                 shipped models were trained on (lib/synth's scenes: yaw
 *                 +-60, pitch +-40 degrees)
 *   small eyes    an eye narrower than min_eye_px (corner to corner, in
 *                 the photo): its iris is a few pixels and the fit cannot
 *                 see where it looks
 *   eyes closed   an eye's opening (eye aspect ratio: the two lid
 *                 distances over twice the width) under min_eye_open; or
 *                 no iris located in either eye (gs_face_iris_locate in
 *                 the normalized face) where the fits that ran found a
 *                 sclera-iris contrast under min_iris_contrast: the
 *                 landmark model draws open contours on some closed eyes
 *   flat          the face region's luma has no contrast (black, white or
 *                 grey frames)
 *   noise         the face region is pixel noise: its mean neighbour
 *                 difference over its standard deviation (about 1.13 for
 *                 independent pixels, 0.09-0.21 on faces) over max_roughness
 *
 * They are checked in the order of the enum below (flat and noise first:
 * on a frame that is no face the landmarks mean nothing).
 * A normalized face given as such has no landmarks: only flat and noise
 * apply to it. */
typedef enum gs_face_refusal {
    GS_FACE_USABLE = 0,
    GS_FACE_REFUSED_NO_FACE = 1,     /* gs_face_analyze found none (callers) */
    GS_FACE_REFUSED_FLAT = 2,
    GS_FACE_REFUSED_NOISE = 3,
    GS_FACE_REFUSED_AT_BORDER = 4,
    GS_FACE_REFUSED_HEAD_POSE = 5,
    GS_FACE_REFUSED_SMALL_EYES = 6,
    GS_FACE_REFUSED_EYES_CLOSED = 7
} gs_face_refusal;
#define GS_FACE_REFUSAL_COUNT 8

typedef struct gs_face_gate_opts {
    double min_eye_px;          /* default 16 */
    double min_eye_open;        /* default 0.13 */
    double max_head_yaw_deg;    /* default 60 */
    double max_head_pitch_deg;  /* default 40 */
    double max_outside;         /* default 0.05 */
    double min_contrast;        /* luma standard deviation, default 5 */
    double max_roughness;       /* default 0.5 */
    double min_iris_contrast;   /* grey levels, default 15; 0: off */
} gs_face_gate_opts;
void gs_face_gate_opts_default(gs_face_gate_opts *o);

typedef struct gs_face_gate {
    gs_face_refusal refusal;    /* the first check that failed, in the
                                   enum's order; every measure below is
                                   filled either way */
    double eye_px[2];           /* eye widths in the photo (36-39, 42-45);
                                   0 for a normalized face */
    double eye_open[2];         /* eye aspect ratios; 0 likewise */
    int irises;                 /* eyes whose iris is located (status OK)
                                   in the normalized face; 0 likewise */
    double iris_contrast;       /* the larger sclera-iris contrast of the
                                   two eyes' fits; NaN when neither fitted
                                   (and for a normalized face) */
    double head_pitch_deg, head_yaw_deg; /* normalized camera; 0 likewise */
    double outside;             /* fraction of the face outside the photo */
    double contrast, roughness; /* of the normalized face's centre */
    char reason[192];           /* "" when usable */
} gs_face_gate;

/* Stable lower-case names ("usable", "no_face", "flat", "noise",
 * "at_border", "head_pose", "small_eyes", "eyes_closed"); NULL for a value
 * outside the enum. */
const char *gs_face_refusal_name(gs_face_refusal r);

/* A photo's face: `r` from gs_face_analyze and `norm_face`, the photo
 * normalized by r->norm (gs_face_normalize_image). opts may be NULL. */
int gs_face_gate_photo(const gs_face_result *r, const gs_io_image *norm_face,
                       const gs_face_gate_opts *opts, gs_face_gate *out,
                       gs_error *err);
/* The same with the two eyes' irises already located by the caller
 * (gs_face_iris_locate on norm_face inside r->uv_n's eye contours, 36-41
 * then 42-47, at the normalized camera's scale: what the gate would find
 * itself), so that they are not located twice; NULL: the gate locates
 * them. */
struct gs_face_iris;
int gs_face_gate_photo_irises(const gs_face_result *r, const gs_io_image *norm_face,
                              const struct gs_face_iris *iris,
                              const gs_face_gate_opts *opts, gs_face_gate *out,
                              gs_error *err);
/* A normalized face given as such (flat and noise only). */
int gs_face_gate_normalized(const gs_io_image *norm_face,
                            const gs_face_gate_opts *opts, gs_face_gate *out,
                            gs_error *err);

/* ---- iris ---- */

/* Why an eye has no iris result. Not an error: the call returns GS_OK and
 * says so in gs_face_iris.status (a quality gate refuses on it). */
typedef enum gs_face_iris_status {
    GS_FACE_IRIS_OK = 0,
    GS_FACE_IRIS_TOO_SMALL = 1, /* corner distance under min_eye_width_px */
    GS_FACE_IRIS_CLOSED = 2,    /* contour opening under min_opening */
    GS_FACE_IRIS_NO_EDGE = 3,   /* too little limbus edge, too low a contrast
                                   or a fit that does not hold together */
    GS_FACE_IRIS_PARTIAL = 4    /* no pupil stands out and the limbus is not
                                   seen on both sides over a vertical span
                                   of its arc (the iris in a corner or under
                                   the lids): the centre is filled but rests
                                   on the radius prior */
} gs_face_iris_status;

typedef struct gs_face_iris_opts {
    double min_eye_width_px;  /* default 10 */
    double min_opening;       /* height / width of the contour; default 0.12 */
    double radius_min_px;     /* iris radius searched, px; both 0 (default): */
    double radius_max_px;     /*   0.14 to 0.62 eye widths (head yaw narrows
                                   the eye, not the iris). At a known scale
                                   set it with gs_face_iris_opts_scale
                                   (5.6 to 8.2 px at 256 px normalized
                                   faces): much better (docs/face.md) */
    double min_visible;       /* fraction of the limbus with edge support;
                                 default 0.08 */
    double min_contrast;      /* limbus step, grey levels; default 8 */
} gs_face_iris_opts;
void gs_face_iris_opts_default(gs_face_iris_opts *o);
/* Sets the radius range for a known scale at the eye, px per mm: human
 * irises measure 10.7-13 mm across, so GS_FACE_IRIS_RADIUS_MIN_MM to
 * _MAX_MM times px_per_mm. A normalized face: f_n / d_n (800 / 680 at
 * 256 px); a photo with a pose: the focal length over |pose.t|. */
#define GS_FACE_IRIS_RADIUS_MIN_MM 4.8
#define GS_FACE_IRIS_RADIUS_MAX_MM 7.0
void gs_face_iris_opts_scale(gs_face_iris_opts *o, double px_per_mm);

typedef struct gs_face_iris {
    gs_face_iris_status status;
    /* Filled when status is OK or PARTIAL (else NaN or 0): */
    double centre[2];      /* iris centre, image pixels (geom.h, +0.5): the
                              centre of the fitted limbus ellipse (pupil
                              and iris concentric) */
    double pupil_centre[2]; /* the pupil detector's own centre, NaN when no
                               pupil stands out */
    double radius;         /* limbus radius (major semi-axis), px */
    double pupil_radius;   /* px; 0 when no pupil stands out of the iris */
    double pupil_contrast; /* pupil - iris grey: < 0 dark, > 0 bright
                              (red-eye) */
    double contrast;       /* sclera - iris grey at the centre (grey of
                              (2G + B) / 3, 0..255) */
    double residual;       /* robust rms misfit of the eye model, grey */
    double centre_sd_px;   /* standard error of the centre from the fit
                              (largest axis), px */
    double visible;        /* fraction of 64 points of the limbus ellipse
                              inside the contour with the grey stepping up
                              across them */
    double confidence;     /* 0..1: visible, contrast over residual, and
                              the centre's error against the radius */
    double lab[3];         /* mean CIELAB (D65) of the iris ring inside the
                              contour, glints left out */
    int lab_pixels;        /* pixels averaged for lab */
    /* Always filled: */
    double eye_width;      /* corner distance |p3 - p0|, px */
    double opening;        /* contour height / width: (|p1 p5| + |p2 p4|)
                              / 2 across the corner line over the width;
                              negative when the lids cross */
} gs_face_iris;

/* Locates the iris of one eye: img (RGB) and its 6 iBUG contour points
 * (36-41 or 42-47, in that order, geom.h pixels). The grey of the
 * contour's opening (lids and lashes left out, glints opened away) is fitted
 * by a pupil disc inside a concentric iris disc on a shaded sclera, both
 * one ellipse shape, sub-pixel edges, levels by least squares, geometry by
 * damped Gauss-Newton; started from the best-fitting iris disc on a grid
 * and again from the pupil a detector finds (docs/face.md, "Iris
 * localizer"). Deterministic; two allocations. opts may be NULL
 * (defaults). Errors: GS_ERR_ARG for
 * NULL pointers, a bad image, a contour point outside the image, or a
 * degenerate contour (corners under 1 px apart, points farther than 3 eye
 * widths apart); GS_ERR_NONFINITE for a non-finite point or option. An eye
 * too small, closed or without iris edges is GS_OK with out->status
 * saying which. */
int gs_face_iris_locate(const gs_io_image *img, const double eye_uv[6][2],
                        const gs_face_iris_opts *opts, gs_face_iris *out,
                        gs_error *err);

/* Repairs red-eye in img (RGB, changed in place) at the 68 landmarks uv
 * (geom.h pixels): in each eye the iris localizer finds (px_per_mm as in
 * gs_face_iris_opts_scale; 0: the default radius range), when at least 30 %
 * of the pupil disc is red (R over 1.35 times and 40 levels above both G
 * and B) and a smaller share, under 50 %, of the iris ring around it,
 * every red pixel in the eye's contour within 1.35 pupil radii gets
 * R = (G + B) / 2. Other pixels, and eyes without red-eye, keep their
 * bytes. *fixed_px (may be NULL): the pixels changed. Errors: GS_ERR_ARG
 * for a bad image or landmarks, as gs_face_iris_locate. docs/face.md,
 * "Red-eye". */
int gs_face_red_eye_fix(gs_io_image *img, const double uv[GS_FACE_LANDMARKS][2],
                        double px_per_mm, int *fixed_px, gs_error *err);

/* Gaze of an eye from its iris centre: the eyeball model calibrated on the
 * synthetic heads (docs/face.md, "Calibration"): the iris centre sits
 * GS_FACE_IRIS_ROT_X_MM / _Y_MM in front of the eyeball centre, which sits
 * at a fixed head-frame offset from the midpoint of the eye corners; the
 * corner distance in the image sets the scale. eye: 0 = the subject's
 * right eye (36-41, image left in a frontal view), 1 = the left (42-47).
 * head_R: head to camera rotation in the image's camera (the normalized
 * camera for a normalized face, e.g. gs_geom_norm_rot of the pose), NULL
 * for a frontal head. Writes the head-frame gaze (radians, ETH-XGaze
 * convention of geom.h). GS_ERR_ARG for a bad eye index or contour. */
#define GS_FACE_IRIS_ROT_X_MM 10.298
#define GS_FACE_IRIS_ROT_Y_MM 10.205
#define GS_FACE_IRIS_EYE_OFFSET_MM {-0.501, -0.265, 0.067}
int gs_face_iris_gaze(int eye, const double eye_uv[6][2],
                      const double iris_uv[2], const double head_R[9],
                      double *pitch, double *yaw, gs_error *err);

/* The gaze change between two images of the same eye (before -> after):
 * gs_face_iris_gaze of each, after minus before, radians. Head shifts and
 * scale changes between the images cancel through the corners. */
int gs_face_iris_gaze_change(int eye, const double eye_uv0[6][2],
                             const double iris_uv0[2],
                             const double eye_uv1[6][2],
                             const double iris_uv1[2], const double head_R[9],
                             double *dpitch, double *dyaw, gs_error *err);

/* ---- redirect quality ----
 *
 * How well one redirected image carries the gaze it was asked for,
 * measured against its input without the model (docs/face.md, "Redirect
 * quality"): both images' irises (gs_face_iris_locate inside the input's
 * eye contours, the output's moved with its lids when the options carry
 * the landmark model) give the measured gaze change (gs_face_iris_gaze_change),
 * compared with the commanded one; the iris colour (CIELAB delta E of the
 * two irises); and the eye regions' fine-scale energy (the mean absolute
 * difference of the luma from its 3 x 3 mean over both eye masks) over the
 * input's, which speckle and doubled lids raise. `score` in [0, 1] is the
 * product of one factor per measure, each 1 within its tolerance and
 * falling as a Gaussian past it; an output whose irises vanished where the
 * input showed them scores 0. */
typedef struct gs_face_quality_opts {
    double gaze_tol_deg;   /* gaze error allowed, at least (default 10) */
    double gaze_tol_frac;  /* ... or this fraction of the change asked (0.5) */
    double max_delta_e;    /* iris colour change allowed (15) */
    double max_artifact;   /* eye speckle over the input's allowed (1.6) */
    double px_per_mm;      /* the scale at the eyes for the iris search
                              (gs_face_iris_opts_scale); 0: unknown */
    /* The landmark model, for normalized faces (NULL: none). With it the
     * output's iris is searched inside the input's eye contours moved by
     * the change the model sees between the two images (both from the box
     * of gs_face_normalized_landmarks), so that lids which follow the gaze
     * are read as the output has them; the gaze change is still read in
     * the input's eye frame. Without it, inside the input's contours:
     * that reads the pitch of exact synthetic redirects, whose lids
     * follow the gaze, with a gain of 0.67 (docs/face.md). A reference
     * keeps the pointer: the model must outlive it. */
    const gs_face_shape_model *shape;
} gs_face_quality_opts;
void gs_face_quality_opts_default(gs_face_quality_opts *o);

typedef struct gs_face_quality {
    double score;          /* 0..1 */
    int eyes;              /* eyes with an iris in both images (0..2) */
    double commanded[2];   /* gaze change asked (pitch, yaw), radians */
    double measured[2];    /* the irises' change, mean of the eyes; NaN
                              when eyes is 0 */
    double gaze_error_deg; /* |measured - commanded|; NaN likewise */
    double delta_e;        /* iris CIELAB delta E; NaN likewise */
    double artifact;       /* eye fine-scale energy, output over input */
    gs_face_iris iris[2][2]; /* [eye][input, output] */
    char reason[160];      /* the largest penalty in words, "" if none */
} gs_face_quality;

/* The 68 landmarks of a normalized face given as such (no photo, so no
 * detection): the landmark model started from the box a face takes at the
 * normalized camera (0.16-0.84 of the width, 0.19-0.86 of the height:
 * where the cascade finds the synthetic test faces at 256 px). On exact
 * synthetic labels the eye points land 3.4 px off on average at 256 px
 * (test_face_quality). uv: geom.h pixels of img. */
int gs_face_normalized_landmarks(const gs_face_shape_model *sp, const gs_io_image *img,
                                 double uv[][2], gs_error *err);

/* input and output: the same-sized images (the normalized face and its
 * render, or the photo and its pasted-back result); uv: the input's 68
 * landmarks in their pixels; head_R: the head rotation in their camera
 * (NULL: frontal); cmd_pitch, cmd_yaw: the head-frame gaze change asked,
 * radians. */
int gs_face_redirect_quality(const gs_io_image *input, const gs_io_image *output,
                             const double uv[][2], const double head_R[9],
                             double cmd_pitch, double cmd_yaw,
                             const gs_face_quality_opts *opts,
                             gs_face_quality *out, gs_error *err);

/* The same in two steps for many images of one input: the reference (the
 * input's irises, eye mask and speckle, found once; the input itself is
 * not kept), then one measure per image. */
typedef struct gs_face_quality_ref gs_face_quality_ref;
int gs_face_quality_ref_create(const gs_io_image *input, const double uv[][2],
                               const gs_face_quality_opts *opts,
                               gs_face_quality_ref **out, gs_error *err);
void gs_face_quality_ref_destroy(gs_face_quality_ref *r);
int gs_face_quality_measure(const gs_face_quality_ref *r, const gs_io_image *output,
                            const double head_R[9], double cmd_pitch, double cmd_yaw,
                            gs_face_quality *out, gs_error *err);

#ifdef __cplusplus
}
#endif
#endif
