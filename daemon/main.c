/* gazesplatd: command line, configuration, signals, run. */
#define _GNU_SOURCE
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#ifdef __GLIBC__
#include <malloc.h>
#endif

#include "gazesplat/nn.h"

#include "config.h"
#include "log.h"
#include "server.h"

static const char usage[] =
    "usage: gazesplatd [options]\n"
    "\n"
    "  -c, --config FILE     configuration file (key = value lines, daemon/README.md)\n"
    "  --socket PATH         Unix socket (default $RUNTIME_DIRECTORY/gazesplatd.sock,\n"
    "                        else /run/gazesplat/gazesplatd.sock; 'none' for TCP only)\n"
    "  --tcp HOST:PORT       also listen on TCP (loopback unless tcp_allow_remote)\n"
    "  --model FILE          model file\n"
    "  --state-dir DIR       subject cache directory (default $STATE_DIRECTORY)\n"
    "  --log-level LEVEL     error, warn, info (default) or debug\n"
    "  --set KEY=VALUE       any configuration key (repeatable)\n"
    "  --check-config        print the effective configuration and exit\n"
    "  --version, --help\n"
    "\n"
    "Flags override the file. SIGHUP re-reads the file (then the flags) and\n"
    "reloads the model; SIGTERM drains and exits. Sockets passed by systemd\n"
    "(LISTEN_FDS) are used instead of binding.\n";

typedef struct app {
    int argc;
    char **argv;
    const char *config_path;
} app;

/* Flags that are shorthands for keys. */
static const struct {
    const char *flag, *key;
} shorthands[] = {
    {"--socket", "socket"}, {"--tcp", "tcp"}, {"--model", "model"},
    {"--state-dir", "state_dir"}, {"--log-level", "log_level"},
};

/* Builds the configuration: defaults, file, flags. 0, -1 error, 1 exit ok. */
static int build_config(app *a, gsd_config *cfg, int *check_only)
{
    char msg[600];
    gsd_config_default(cfg);
    a->config_path = NULL;
    for (int i = 1; i < a->argc; i++)
        if ((!strcmp(a->argv[i], "-c") || !strcmp(a->argv[i], "--config")) && i + 1 < a->argc)
            a->config_path = a->argv[++i];
    if (a->config_path && gsd_config_load(cfg, a->config_path, msg, sizeof msg) != 0) {
        fprintf(stderr, "gazesplatd: %s\n", msg);
        return -1;
    }
    for (int i = 1; i < a->argc; i++) {
        const char *f = a->argv[i];
        if (!strcmp(f, "-c") || !strcmp(f, "--config")) {
            if (++i >= a->argc)
                goto missing;
            continue;
        }
        if (!strcmp(f, "--check-config")) {
            *check_only = 1;
            continue;
        }
        if (!strcmp(f, "--help") || !strcmp(f, "-h")) {
            fputs(usage, stdout);
            return 1;
        }
        if (!strcmp(f, "--version")) {
            puts("gazesplatd " GSD_VERSION);
            return 1;
        }
        const char *key = NULL;
        for (size_t k = 0; k < sizeof shorthands / sizeof shorthands[0]; k++)
            if (!strcmp(f, shorthands[k].flag))
                key = shorthands[k].key;
        if (!key && strcmp(f, "--set") != 0) {
            fprintf(stderr, "gazesplatd: unknown option '%s'\n%s", f, usage);
            return -1;
        }
        if (++i >= a->argc)
            goto missing;
        const char *value = a->argv[i];
        char kbuf[64];
        if (!key) {
            const char *eq = strchr(value, '=');
            if (!eq || eq == value || (size_t)(eq - value) >= sizeof kbuf) {
                fprintf(stderr, "gazesplatd: --set wants KEY=VALUE, got '%s'\n", value);
                return -1;
            }
            snprintf(kbuf, sizeof kbuf, "%.*s", (int)(eq - value), value);
            key = kbuf;
            value = eq + 1;
        }
        if (gsd_config_set(cfg, key, value, msg, sizeof msg) != 0) {
            fprintf(stderr, "gazesplatd: %s: %s\n", f, msg);
            return -1;
        }
    }
    if (gsd_config_finish(cfg, msg, sizeof msg) != 0) {
        fprintf(stderr, "gazesplatd: %s\n", msg);
        return -1;
    }
    return 0;
missing:
    fprintf(stderr, "gazesplatd: %s needs a value\n", a->argv[a->argc - 1]);
    return -1;
}

static void on_sighup(gsd_server *s)
{
    app *a = s->app;
    gsd_config cfg;
    int check = 0;
    if (build_config(a, &cfg, &check) != 0) {
        LOG_E("reload: configuration rejected; keeping the current one");
        return;
    }
    gsd_server_reconfigure(s, &cfg);
}

int main(int argc, char **argv)
{
    /* Before anything is opened: may run the program again with OpenBLAS's
     * AVX kernels selected (nn.h); on failure it goes on with the slow ones. */
    gs_nn_blas_select_kernels(argv);
    /* One OpenBLAS thread, as nn.h asks of programs: the workers' pools
     * parallelise over fixed partitions (bit-identical for any thread
     * count), and OpenBLAS's own threads would fight them for the cores
     * (the FIT measured 4.6x slower on 2 cores without this). */
    gs_nn_blas_set_threads(1);
#ifdef __GLIBC__
    /* Buffers of 1 MiB and more (a fit's gradients and activations, a
     * fine-tune's context: docs in daemon/README.md, "Memory") get pages
     * of their own, returned when freed. glibc otherwise raises this
     * threshold to the size of the largest such buffer freed (up to 32
     * MiB), after which the next fit's buffers come from the arenas and
     * stay there; measured 10 to 14 MB less RSS with fine-tuned subjects,
     * with no change in the images per second of REDIRECTs. */
    mallopt(M_MMAP_THRESHOLD, 1 << 20);
#endif
    app a = {argc, argv, NULL};
    gsd_config cfg;
    int check = 0;
    int r = build_config(&a, &cfg, &check);
    if (r != 0)
        return r > 0 ? 0 : 2;
    if (check) {
        gsd_config_print(&cfg, stdout);
        return 0;
    }
    gsd_log_set_level(cfg.log_level);
    signal(SIGPIPE, SIG_IGN); /* writes use MSG_NOSIGNAL or writev: EPIPE, not death */

    static gsd_server srv; /* large; lives for the whole program */
    char msg[600];
    if (gsd_server_init(&srv, &cfg, msg, sizeof msg) != 0) {
        LOG_E("%s", msg);
        gsd_notifyf("STATUS=failed: %s", msg);
        return 1;
    }
    srv.app = &a;
    srv.on_sighup = on_sighup;
    LOG_I("gazesplatd %s: %d workers x %d pool threads, OpenBLAS %d thread(s) (%s), queue %d, "
          "max_connections %d, state %s",
          GSD_VERSION, cfg.workers, gsd_pool_threads(&cfg), gs_nn_blas_threads(), gs_nn_blas_core(),
          cfg.queue_depth, srv.cfg.max_connections, srv.state_dir[0] ? srv.state_dir : "(none)");
    r = gsd_server_run(&srv);
    gsd_server_free(&srv);
    LOG_I("stopped");
    return r == 0 ? 0 : 1;
}
