/* The sweep cache (frame_sweep.c): other subjects' renders a context
 * keeps for incremental ones. */
#ifndef GS_MODEL_FRAME_SWEEP_H
#define GS_MODEL_FRAME_SWEEP_H

#include "frame_state.h"

/* a and b have the same code and head pose. */
int gs_frame_same_subject_pose(const gs_frame *a, const gs_frame *b);
void gs_sweep_slot_free(gs_sweep_slot *s);
/* Forgets every kept render (the parameters may change: training). */
void gs_sweep_drop(gs_model_ctx *c);
/* Puts the live render (if any) into a free or the least recently used
 * slot before something overwrites it; with no slot to spare it is lost.
 * Afterwards the live state is not valid. */
void gs_sweep_stash(gs_model_ctx *c);
/* Makes fr's subject and pose the live render state when a slot has it;
 * otherwise stashes the live one. */
void gs_sweep_select(gs_model_ctx *c, const gs_frame *fr);

#endif
