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
    /* a real-valued key: a finite number in (0, 1], the last good value kept */
    CHECK(c.finetune_lr == 0.004);
    CHECK(gsd_config_set(&c, "finetune_lr", "0.002", msg, sizeof msg) == 0 && c.finetune_lr == 0.002);
    CHECK(gsd_config_set(&c, "finetune_lr", "1e-3", msg, sizeof msg) == 0 && c.finetune_lr == 1e-3);
    CHECK(gsd_config_set(&c, "finetune_lr", "1", msg, sizeof msg) == 0 && c.finetune_lr == 1.0);
    const char *bad_lr[] = {"0", "-0.001", "1.5", "nan", "inf", "0.01x", "", "x", "1e999"};
    for (size_t i = 0; i < sizeof bad_lr / sizeof bad_lr[0]; i++) {
        CHECK_MSG(gsd_config_set(&c, "finetune_lr", bad_lr[i], msg, sizeof msg) == -1 &&
                      strstr(msg, "finetune_lr: want a number in (0, 1]"),
                  "'%s': %s", bad_lr[i], msg);
        CHECK(c.finetune_lr == 1.0);
    }
    /* printed values read back as they were */
    CHECK(gsd_config_set(&c, "finetune_lr", "0.0012345678901234567", msg, sizeof msg) == 0);
    {
        double want = c.finetune_lr;
        char *buf = NULL;
        size_t len = 0;
        FILE *mf = open_memstream(&buf, &len);
        gsd_config_print(&c, mf);
        fclose(mf);
        CHECK(strstr(buf, "finetune_lr = 0.0012345678901234567\n") != NULL);
        gsd_config c2; /* the whole printed configuration loads back */
        gsd_config_default(&c2);
        CHECK_MSG(load_text(&c2, buf, msg, sizeof msg) == 0, "%s", msg);
        CHECK(c2.finetune_lr == want && c2.workers == c.workers);
        free(buf);
        gsd_config_default(&c2);
        mf = open_memstream(&buf, &len);
        gsd_config_print(&c2, mf);
        fclose(mf);
        CHECK(strstr(buf, "\nfinetune_lr = 0.004\n") != NULL);
        free(buf);
    }
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
