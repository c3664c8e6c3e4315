#include "gazesplat/error.h"
#include "gs_test.h"

#include <string.h>

int main(void)
{
    gs_error e;
    gs_error_clear(&e);
    CHECK_EQ_INT(e.code, GS_OK);
    CHECK(e.msg[0] == '\0');
    CHECK_EQ_INT(gs_error_set(&e, GS_ERR_FORMAT, "bad %s at %d", "header", 7), GS_ERR_FORMAT);
    CHECK_EQ_INT(e.code, GS_ERR_FORMAT);
    CHECK(strcmp(e.msg, "bad header at 7") == 0);
    CHECK_EQ_INT(gs_error_set(NULL, GS_ERR_IO, "x"), GS_ERR_IO);
    for (int c = GS_ERR_CANCELLED; c <= 0; c++)
        CHECK(strcmp(gs_strerror(c), "unknown error") != 0);
    CHECK(strcmp(gs_strerror(12345), "unknown error") == 0);
    /* Messages longer than the buffer are cut, never overflow. */
    char big[1000];
    memset(big, 'x', sizeof big - 1);
    big[sizeof big - 1] = '\0';
    gs_error_set(&e, GS_ERR_ARG, "%s", big);
    CHECK(strlen(e.msg) == sizeof e.msg - 1);
    GS_TEST_END();
}
