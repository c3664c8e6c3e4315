/* The target ranges (gazesplat/model.h): one table, inclusive limits,
 * used by every check of a gaze or head target. */
#include <math.h>

#include "model_internal.h"

const gs_target_range gs_target_ranges[GS_TARGET_NFIELDS] = {
    [GS_TARGET_GAZE_PITCH] = {"gaze pitch", -GS_MODEL_MAX_GAZE_PITCH_DEG,
                              GS_MODEL_MAX_GAZE_PITCH_DEG, "deg"},
    [GS_TARGET_GAZE_YAW] = {"gaze yaw", -GS_MODEL_MAX_GAZE_YAW_DEG,
                            GS_MODEL_MAX_GAZE_YAW_DEG, "deg"},
    [GS_TARGET_HEAD_PITCH] = {"head pitch", -GS_MODEL_MAX_HEAD_PITCH_DEG,
                              GS_MODEL_MAX_HEAD_PITCH_DEG, "deg"},
    [GS_TARGET_HEAD_YAW] = {"head yaw", -GS_MODEL_MAX_HEAD_YAW_DEG,
                            GS_MODEL_MAX_HEAD_YAW_DEG, "deg"},
};

int gs_model_check_range_slack(gs_target_field f, double v, double slack,
                               gs_error *err)
{
    if ((unsigned)f >= GS_TARGET_NFIELDS)
        return gs_error_set(err, GS_ERR_ARG, "target field %d unknown", (int)f);
    const gs_target_range *r = &gs_target_ranges[f];
    if (!isfinite(v))
        return gs_error_set(err, GS_ERR_NONFINITE, "%s %g %s not finite",
                            r->name, v, r->unit);
    /* %.12g: a value just past a limit does not print as the limit. */
    if (!(v >= r->lo - slack && v <= r->hi + slack))
        return gs_error_set(err, GS_ERR_ARG,
                            "%s %.12g %s outside [%g, %g] %s (inclusive)",
                            r->name, v, r->unit, r->lo, r->hi, r->unit);
    return GS_OK;
}

int gs_model_check_range(gs_target_field f, double v, gs_error *err)
{
    return gs_model_check_range_slack(f, v, 0.0, err);
}

int gs_model_check_target(const double gaze_deg[2], const double head_deg[2],
                          gs_error *err)
{
    int rc = GS_OK;
    if (gaze_deg && !rc)
        rc = gs_model_check_range(GS_TARGET_GAZE_PITCH, gaze_deg[0], err);
    if (gaze_deg && !rc)
        rc = gs_model_check_range(GS_TARGET_GAZE_YAW, gaze_deg[1], err);
    if (head_deg && !rc)
        rc = gs_model_check_range(GS_TARGET_HEAD_PITCH, head_deg[0], err);
    if (head_deg && !rc)
        rc = gs_model_check_range(GS_TARGET_HEAD_YAW, head_deg[1], err);
    return rc;
}
