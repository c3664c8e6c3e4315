/* Where a job's results go (sink.c): a struct of callbacks and their
 * context. A job emits its result images one by one and ends with exactly
 * one final result, a success (done) or an error; it never builds frames
 * itself. The server's jobs get the frame sink of out.c (gsd_frame_sink),
 * which packs frames for the job's connection and posts them to the loop;
 * a test can run a job against a sink of its own, with no socket. */
#ifndef GSD_SINK_H
#define GSD_SINK_H

#include <stdint.h>

#include "gs_msg.h"

struct gsd_job;

typedef struct gsd_sink {
    /* One result image of the job (an IMAGE message). Returns 0, or -1
     * when it could not be taken (out of memory): the job then ends with
     * ERR_INTERNAL. */
    int (*image)(void *ctx, struct gsd_job *job, const Gazesplat__ImageResult *m);
    /* The job's final success: a message of the final type (FRAME_FIT_OK
     * with a FitResult, FRAME_DONE or FRAME_SLEEP_OK with a Done). */
    void (*done)(void *ctx, struct gsd_job *job, uint16_t type, const ProtobufCMessage *m);
    /* The job's final error: an ErrorCode and its text (job->refusal
     * holds the FaceRefusal of ERR_FACE_REFUSED). */
    void (*error)(void *ctx, struct gsd_job *job, int code, const char *text);
    void *ctx;
} gsd_sink;

/* What job code calls: each hands its result to job->sink. After a final
 * one (done, error) the job belongs to whoever the sink gave it to, and
 * the caller must not touch it again. */
int gsd_emit_image(struct gsd_job *job, const Gazesplat__ImageResult *m);
void gsd_emit_done(struct gsd_job *job, uint16_t type, const ProtobufCMessage *m);
/* The text is cut at 511 bytes; job->result takes the code (for its log
 * line). */
void gsd_emit_error(struct gsd_job *job, int code, const char *fmt, ...) __attribute__((format(printf, 3, 4)));

#endif
