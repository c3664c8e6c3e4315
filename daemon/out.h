/* What a job sends back (out.c): the frame sink, which packs its results
 * as frames for its connection and posts them to the loop thread. Every
 * output frame is counted in s->out_total from gsd_out_pack to
 * gsd_out_free, and in its job's out_bytes while o->job is set. */
#ifndef GSD_OUT_H
#define GSD_OUT_H

#include "daemon.h"

/* A frame with header h and message msg; NULL when out of memory. */
gsd_out *gsd_out_pack(gsd_server *s, const gs_frame_header *h, const ProtobufCMessage *msg);
void gsd_out_free(gsd_server *s, gsd_out *o);
/* An ERROR frame answering header h (a protocol error of the loop's). */
gsd_out *gsd_out_error(gsd_server *s, const gs_frame_header *h, int code, const char *text);

/* The server's sink for its jobs (sink.h): each result a frame packed for
 * the job's connection (IMAGE, the final type, ERROR) and handed to the
 * loop through the post queue (thread-safe: workers call it). Out of
 * memory, an IMAGE frame that cannot be packed fails the image callback
 * (the job then ends with ERR_INTERNAL), and a final one is logged and
 * not sent (the request stays unanswered). */
gsd_sink gsd_frame_sink(gsd_server *s);

/* The ErrorCode of a computing step that failed with library status
 * `status` (GS_ERR_*): INVALID_ARGUMENT, CANCELLED or INTERNAL. */
int gsd_status_error(int status);

#endif
