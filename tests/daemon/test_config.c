/* Daemon configuration: defaults, bounds, file syntax, frame of errors. */
#define _POSIX_C_SOURCE 200809L
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "config.h"
#include "gs_test.h"

static int load_text(gsd_config *c, const char *text, char *msg, size_t cap)
{
    char path[] = "/tmp/gs_config_XXXXXX";
    int fd = mkstemp(path);
    FILE *f = fdopen(fd, "w");
    fputs(text, f);
    fclose(f);
    int r = gsd_config_load(c, path, msg, cap);
    unlink(path);
    return r;
}

int main(void)
{
    gsd_config c;
    char msg[600];
    gsd_config_default(&c);
    CHECK(c.socket_mode == 0660 && c.workers == 1 && c.queue_depth == 16);
    CHECK(c.max_payload == 16 << 20 && c.header_timeout_ms == 10000 && c.log_level == 2);

    CHECK(gsd_config_set(&c, "workers", "4", msg, sizeof msg) == 0 && c.workers == 4);
    CHECK(gsd_config_set(&c, "workers", "0", msg, sizeof msg) == -1 && strstr(msg, "[1, 64]"));
    CHECK(gsd_config_set(&c, "workers", "65", msg, sizeof msg) == -1);
    CHECK(gsd_config_set(&c, "workers", "3x", msg, sizeof msg) == -1);
    CHECK(gsd_config_set(&c, "workers", "", msg, sizeof msg) == -1);
    CHECK(gsd_config_set(&c, "workers", "99999999999999999999", msg, sizeof msg) == -1);
    CHECK(c.workers == 4);
    CHECK(gsd_config_set(&c, "socket_mode", "0600", msg, sizeof msg) == 0 && c.socket_mode == 0600);
    CHECK(gsd_config_set(&c, "socket_mode", "0800", msg, sizeof msg) == -1);
    CHECK(gsd_config_set(&c, "debug_requests", "yes", msg, sizeof msg) == 0 && c.debug_requests);
    CHECK(gsd_config_set(&c, "debug_requests", "maybe", msg, sizeof msg) == -1);
    CHECK(gsd_config_set(&c, "log_level", "debug", msg, sizeof msg) == 0 && c.log_level == 3);
    CHECK(gsd_config_set(&c, "log_level", "loud", msg, sizeof msg) == -1);
    CHECK(gsd_config_set(&c, "nope", "1", msg, sizeof msg) == -1 && strstr(msg, "unknown key"));
    char longv[GSD_STR_MAX + 10];
    memset(longv, 'a', sizeof longv - 1);
    longv[sizeof longv - 1] = '\0';
    CHECK(gsd_config_set(&c, "model", longv, msg, sizeof msg) == -1);

    gsd_config_default(&c);
    CHECK_MSG(load_text(&c, "# comment\n\n  model = /m.gsm  \nqueue_depth=3\r\ntcp = 127.0.0.1:7000\n",
                        msg, sizeof msg) == 0, "%s", msg);
    CHECK(strcmp(c.model, "/m.gsm") == 0 && c.queue_depth == 3 && strcmp(c.tcp, "127.0.0.1:7000") == 0);
    CHECK(load_text(&c, "workers = 2\nqueue_depth = 0\n", msg, sizeof msg) == -1);
    CHECK_MSG(strstr(msg, ":2: queue_depth") != NULL, "%s", msg);
    CHECK(load_text(&c, "just words\n", msg, sizeof msg) == -1 && strstr(msg, ":1:"));
    CHECK(gsd_config_load(&c, "/nonexistent/gazesplatd.conf", msg, sizeof msg) == -1);

    gsd_config_default(&c);
    c.request_timeout_ms = 5000;
    c.max_deadline_ms = 1000;
    CHECK(gsd_config_finish(&c, msg, sizeof msg) == -1);
    GS_TEST_END();
}
