/* Fuzz target: the .ply reader on arbitrary bytes.
 * Invariants checked (abort on violation): a failure carries its code and
 * a message; a success re-encodes, parses back and re-encodes to the same
 * bytes. Non-finite values are retried with allow_nonfinite so the
 * writer sees them too. */
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "gazesplat/ply.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

static void check_round_trip(const gs_ply_scene *s, const gs_ply_options *opt)
{
    void *a = NULL, *b = NULL;
    size_t la = 0, lb = 0;
    gs_ply_scene t;
    if (gs_ply_encode(s, &a, &la, NULL) != GS_OK)
        abort();
    if (gs_ply_parse(a, la, opt, &t, NULL) != GS_OK)
        abort();
    if (gs_ply_encode(&t, &b, &lb, NULL) != GS_OK)
        abort();
    if (la != lb || memcmp(a, b, la) != 0)
        abort();
    gs_ply_free(&t);
    free(a);
    free(b);
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    gs_ply_options opt = {100000, 0}; /* keeps allocations small */
    gs_ply_scene s;
    gs_error err = {0, ""};
    int rc = gs_ply_parse(data, size, &opt, &s, &err);
    if (rc == GS_ERR_NONFINITE) {
        opt.allow_nonfinite = 1;
        rc = gs_ply_parse(data, size, &opt, &s, &err);
    }
    if (rc != GS_OK) {
        if (rc > 0 || err.code != rc || err.msg[0] == '\0')
            abort();
        return 0;
    }
    check_round_trip(&s, &opt);
    gs_ply_free(&s);
    return 0;
}
