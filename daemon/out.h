/* What a job sends back (out.c): its frames, packed for its connection,
 * and the post queue to the loop thread. Every output frame is counted in
 * s->out_total from gsd_out_pack to gsd_out_free, and in its job's
 * out_bytes while o->job is set. */
#ifndef GSD_OUT_H
#define GSD_OUT_H

#include "daemon.h"

/* A frame with header h and message msg; NULL when out of memory. */
gsd_out *gsd_out_pack(gsd_server *s, const gs_frame_header *h, const ProtobufCMessage *msg);
void gsd_out_free(gsd_server *s, gsd_out *o);
/* An ERROR frame answering header h (a protocol error of the loop's). */
gsd_out *gsd_out_error(gsd_server *s, const gs_frame_header *h, int code, const char *text);

/* Thread-safe: hands a frame (from gsd_frame_new) to the loop. */
void gsd_post(gsd_server *s, gsd_out *o);

/* Packs a frame for a job's connection. NULL when out of memory. */
gsd_out *gsd_frame_new(const gsd_job *job, uint16_t type, const ProtobufCMessage *msg);
/* An ERROR frame for a job (final). */
gsd_out *gsd_error_frame(const gsd_job *job, int code, const char *fmt, ...)
    __attribute__((format(printf, 3, 4)));

/* The ErrorCode of a computing step that failed with library status
 * `status` (GS_ERR_*): INVALID_ARGUMENT, CANCELLED or INTERNAL. */
int gsd_status_error(int status);

#endif
