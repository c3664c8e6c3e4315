#include "gazesplat/error.h"

#include <stdarg.h>
#include <stdio.h>

const char *gs_strerror(int code)
{
    switch (code) {
    case GS_OK: return "ok";
    case GS_ERR_ARG: return "invalid argument";
    case GS_ERR_NONFINITE: return "non-finite input";
    case GS_ERR_NOMEM: return "out of memory";
    case GS_ERR_IO: return "i/o error";
    case GS_ERR_FORMAT: return "malformed data";
    case GS_ERR_LIMIT: return "limit exceeded";
    case GS_ERR_UNSUPPORTED: return "unsupported";
    case GS_ERR_STATE: return "wrong call order";
    case GS_ERR_CANCELLED: return "cancelled";
    default: return "unknown error";
    }
}

int gs_error_set(gs_error *err, int code, const char *fmt, ...)
{
    if (err) {
        va_list ap;
        err->code = code;
        va_start(ap, fmt);
        vsnprintf(err->msg, sizeof err->msg, fmt, ap);
        va_end(ap);
    }
    return code;
}

void gs_error_clear(gs_error *err)
{
    if (err) {
        err->code = GS_OK;
        err->msg[0] = '\0';
    }
}
