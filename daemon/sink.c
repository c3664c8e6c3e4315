/* A job's results through its sink (sink.h). */
#include "sink.h"

#include <stdarg.h>
#include <stdio.h>

#include "daemon.h"

int gsd_emit_image(gsd_job *job, const Gazesplat__ImageResult *m)
{
    return job->sink.image(job->sink.ctx, job, m);
}

void gsd_emit_done(gsd_job *job, uint16_t type, const ProtobufCMessage *m)
{
    job->sink.done(job->sink.ctx, job, type, m);
}

void gsd_emit_error(gsd_job *job, int code, const char *fmt, ...)
{
    char text[512];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(text, sizeof text, fmt, ap);
    va_end(ap);
    job->result = code; /* for its log line */
    job->sink.error(job->sink.ctx, job, code, text);
}
