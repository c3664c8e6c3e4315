/* The photo path's first half, shared by gazesplat redirect and gazesplat
 * augment: detection, landmarks, head pose in the synthetic head frame,
 * normalization to the model's camera, the face mask and the fit options
 * that follow from them. */
#ifndef GS_CLI_PHOTO_PREP_H
#define GS_CLI_PHOTO_PREP_H

#include <stdint.h>

#include "gazesplat/face.h"
#include "gazesplat/image_io.h"
#include "gazesplat/model.h"

typedef struct cli_photo_face {
    gs_face_result res; /* the analysis (landmarks, pose, normalization) */
    gs_io_image norm;   /* the normalized face, image_size^2 */
    uint8_t *mask_n;    /* its face mask, image_size^2 bytes */
    gs_face_gate gate;  /* the gate's measures (when asked for) */
} cli_photo_face;

/* Face `index` (largest first) of photo, normalized to the model's camera
 * (info), with its face mask; with `gate`, through the face gate too. On
 * failure everything is freed and err says why (GS_ERR_NOMEM: "out of
 * memory"); out->gate.refusal says whether the gate refused the face
 * (GS_FACE_REFUSED_NO_FACE when none was found). */
int cli_photo_normalize(gs_face_detector *det, const gs_face_shape_model *sp,
                        const gs_io_image *photo, int index, const gs_model_info *info,
                        int gate, cli_photo_face *out, gs_error *err);

/* The face gate on a normalized face given as such: GS_OK, or
 * GS_ERR_ARG "face refused (NAME): reason" with g->refusal set, or the
 * gate's own error (g->refusal GS_FACE_USABLE). */
int cli_gate_normalized(const gs_io_image *face, gs_face_gate *g, gs_error *err);

/* The fit's options for it: defaults, the mask, max_iters and the
 * landmarks' head pose rotated into the normalized camera. */
void cli_photo_fit_options(const cli_photo_face *p, int iters, gs_fit_options *o);

void cli_photo_face_free(cli_photo_face *p);

#endif
