/* gazesplat error codes.
 *
 * Every library call that can fail returns an int: GS_OK (0) or a negative
 * gs_status. Calls that can say more take an optional gs_error*, filled with
 * the code and a one-line message for the person reading the log.
 *
 * Lifetimes follow one naming rule across the library: a handle the
 * library allocates (an opaque gs_X *) comes from gs_X_create or gs_X_load
 * and goes with gs_X_destroy (NULL is fine); what a call filled into a
 * struct the caller owns (an image, a sample, a list) goes with gs_X_free,
 * which leaves the struct empty. */
#ifndef GAZESPLAT_ERROR_H
#define GAZESPLAT_ERROR_H

#ifdef __cplusplus
extern "C" {
#endif

typedef enum gs_status {
    GS_OK = 0,
    GS_ERR_ARG = -1,         /* argument out of range or inconsistent */
    GS_ERR_NONFINITE = -2,   /* NaN or Inf in an input */
    GS_ERR_NOMEM = -3,       /* allocation failed */
    GS_ERR_IO = -4,          /* read/write/open failed */
    GS_ERR_FORMAT = -5,      /* malformed or truncated data */
    GS_ERR_LIMIT = -6,       /* a size limit would be exceeded */
    GS_ERR_UNSUPPORTED = -7, /* valid but not supported */
    GS_ERR_STATE = -8,       /* calls in the wrong order */
    GS_ERR_CANCELLED = -9    /* the caller's cancel callback asked to stop */
} gs_status;

typedef struct gs_error {
    int code;
    char msg[256];
} gs_error;

/* Static name of a code, e.g. "non-finite input". Never NULL. */
const char *gs_strerror(int code);

/* Fills *err (if not NULL) and returns code, so callers can write
 * `return gs_error_set(err, GS_ERR_ARG, "width %d < 1", w);` */
int gs_error_set(gs_error *err, int code, const char *fmt, ...)
    __attribute__((format(printf, 3, 4)));

/* Resets *err to GS_OK with an empty message. */
void gs_error_clear(gs_error *err);

#ifdef __cplusplus
}
#endif
#endif
