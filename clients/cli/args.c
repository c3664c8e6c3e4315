/* Option parsing and strict number parsing for the subcommands, and the
 * small helpers several of them share. */
#define _POSIX_C_SOURCE 200809L /* clock_gettime */
#include <errno.h>
#include <fcntl.h>
#include <float.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <time.h>
#include <unistd.h>

#include "cli.h"
#include "gazesplat/clock.h"
#include "gazesplat/model.h"
#include "gazesplat/synth.h"

static void vreport(const cli_command *cmd, const char *fmt, va_list ap)
{
    fprintf(stderr, "gazesplat %s: ", cmd->name);
    vfprintf(stderr, fmt, ap);
    fputc('\n', stderr);
}

int cli_usage_error(const cli_command *cmd, const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    vreport(cmd, fmt, ap);
    va_end(ap);
    fputs(cmd->usage, stderr);
    return CLI_USAGE;
}

int cli_fail(const cli_command *cmd, const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    vreport(cmd, fmt, ap);
    va_end(ap);
    return CLI_FAIL;
}

static cli_opt *find_opt(cli_opt *opts, int nopts, const char *arg, size_t len)
{
    for (int i = 0; i < nopts; i++)
        if (strlen(opts[i].name) == len && strncmp(opts[i].name, arg, len) == 0)
            return &opts[i];
    return NULL;
}

int cli_parse(const cli_command *cmd, int argc, char **argv, cli_opt *opts, int nopts)
{
    for (int i = 1; i < argc; i++) {
        const char *arg = argv[i];
        if (strcmp(arg, "--help") == 0 || strcmp(arg, "-h") == 0)
            return CLI_HELP;
        if (strncmp(arg, "--", 2) != 0)
            return cli_usage_error(cmd, "unexpected argument '%s'", arg);
        const char *eq = strchr(arg, '=');
        size_t len = eq ? (size_t)(eq - arg) : strlen(arg);
        cli_opt *o = find_opt(opts, nopts, arg, len);
        if (!o)
            return cli_usage_error(cmd, "unknown option '%.*s'", (int)len, arg);
        if (o->value)
            return cli_usage_error(cmd, "option %s given twice", o->name);
        if (!o->takes_value) {
            if (eq)
                return cli_usage_error(cmd, "option %s takes no value", o->name);
            o->value = "";
        } else if (eq) {
            o->value = eq + 1;
        } else if (i + 1 < argc) {
            o->value = argv[++i];
        } else {
            return cli_usage_error(cmd, "option %s needs a value", o->name);
        }
    }
    return CLI_PARSED;
}

/* cli_run's argv, for cli_command_line: the one command a process runs. */
static int run_argc;
static char **run_argv;

void cli_command_line(char *buf, size_t cap)
{
    size_t n = (size_t)snprintf(buf, cap, "gazesplat");
    for (int i = 0; i < run_argc && n < cap; i++)
        n += (size_t)snprintf(buf + n, cap - n, " %s", run_argv[i]);
}

int cli_run(const cli_command *cmd, int argc, char **argv)
{
    run_argc = argc;
    run_argv = argv;
    if (!cmd->run_opts)
        return cmd->run(argc, argv);
    cli_opt o[CLI_OPTS_MAX];
    if (cmd->nopts < 0 || cmd->nopts > CLI_OPTS_MAX) {
        fprintf(stderr, "gazesplat %s: %d options, more than the %d a command may have\n",
                cmd->name, cmd->nopts, CLI_OPTS_MAX);
        return CLI_FAIL;
    }
    memcpy(o, cmd->opts, (size_t)cmd->nopts * sizeof o[0]);
    int rc = cli_parse(cmd, argc, argv, o, cmd->nopts);
    if (rc == CLI_HELP) {
        fputs(cmd->usage, stdout);
        return CLI_OK;
    }
    if (rc != CLI_PARSED)
        return rc;
    return cmd->run_opts(cmd, o);
}

/* One float from s up to a comma or the end; *end is set past it. */
static int parse_one_float(const char *s, float *out, const char **end)
{
    char *e;
    if (*s == '\0' || *s == ',' || *s == ' ' || *s == '\t')
        return -1;
    errno = 0;
    double v = strtod(s, &e);
    if (e == s || (*e != ',' && *e != '\0') || !isfinite(v) || fabs(v) > FLT_MAX)
        return -1;
    *out = (float)v;
    *end = e;
    return 0;
}

int cli_parse_floats(const char *s, float *out, int n)
{
    for (int i = 0; i < n; i++) {
        if (parse_one_float(s, &out[i], &s) != 0)
            return -1;
        if (i + 1 < n) {
            if (*s != ',')
                return -1;
            s++;
        }
    }
    return *s == '\0' ? 0 : -1;
}

/* One decimal number of the len bytes at s: digits, sign, point and
 * exponent only (no blanks, hex, nan or inf), all of it, finite. */
static int parse_decimal(const char *s, size_t len, double *out)
{
    char buf[64], *e;
    if (len == 0 || len >= sizeof buf || strspn(s, "0123456789+-.eE") < len)
        return -1;
    memcpy(buf, s, len);
    buf[len] = '\0';
    errno = 0;
    double v = strtod(buf, &e);
    if (e != buf + len || !isfinite(v))
        return -1;
    *out = v;
    return 0;
}

int cli_parse_angles(const cli_command *cmd, const char *flag, const char *s, int list, int head,
                     double (*out)[2], int max, int *n)
{
    const char *want = list ? "\"P,Y;P,Y;...\" degrees" : "P,Y degrees";
    *n = 0;
    if (!s || !*s)
        return cli_usage_error(cmd, "%s: empty; want %s", flag, want);
    for (;;) {
        size_t len = list ? strcspn(s, ";") : strlen(s);
        size_t comma = strcspn(s, ",");
        if (*n == max)
            return cli_usage_error(cmd, "%s: more than %d targets", flag, max);
        if (len == 0)
            return cli_usage_error(cmd, "%s: empty item %d; want %s", flag, *n, want);
        double *v = out[*n];
        if (comma >= len || parse_decimal(s, comma, &v[0]) ||
            parse_decimal(s + comma + 1, len - comma - 1, &v[1]))
            return cli_usage_error(cmd, "%s: bad item %d '%.*s': want %s, finite decimal numbers",
                                   flag, *n, (int)(len < 64 ? len : 64), s, want);
        gs_error err = {0, ""};
        if (gs_model_check_target(head ? NULL : v, head ? v : NULL, &err) != GS_OK)
            return list ? cli_usage_error(cmd, "%s: item %d: %s", flag, *n, err.msg)
                        : cli_usage_error(cmd, "%s: %s", flag, err.msg);
        ++*n;
        s += len;
        if (!*s)
            return CLI_OK;
        s++; /* past the ';': an item must follow */
        if (!*s)
            return cli_usage_error(cmd, "%s: empty item %d; want %s", flag, *n, want);
    }
}

int cli_parse_image_labels(const cli_command *cmd, const char *flag, const char *s, int head,
                           int n, double (*out)[2], int *known)
{
    if (!s || !*s)
        return cli_usage_error(cmd, "%s: empty", flag);
    int i = 0;
    for (const char *p = s;; i++) {
        size_t len = strcspn(p, ";");
        if (i == n)
            return cli_usage_error(cmd, "%s: more than %d items, one per image", flag, n);
        char item[128];
        if (len == 0 || len >= sizeof item)
            return cli_usage_error(cmd, "%s: item %d is empty or too long", flag, i);
        memcpy(item, p, len);
        item[len] = 0;
        known[i] = strcmp(item, "-") != 0;
        int got = 0, rc;
        if (known[i] && (rc = cli_parse_angles(cmd, flag, item, 0, head, &out[i], 1, &got)))
            return rc;
        p += len;
        if (!*p)
            break;
        p++;
    }
    if (i + 1 != n)
        return cli_usage_error(cmd, "%s: %d items for %d images: one per image, '-' where "
                               "unknown", flag, i + 1, n);
    return CLI_OK;
}

int cli_split_paths(const cli_command *cmd, const char *flag, const char *s, int max, char **buf,
                    const char **out, int *n)
{
    *n = 0;
    *buf = NULL;
    if (!s || !*s)
        return cli_usage_error(cmd, "%s: empty list", flag);
    size_t len = strlen(s);
    char *b = malloc(len + 1);
    if (!b)
        return cli_fail(cmd, "out of memory");
    memcpy(b, s, len + 1);
    for (char *p = b;;) {
        char *c = strchr(p, ',');
        if (c)
            *c = 0;
        if (!*p || *n == max) {
            int empty = !*p;
            free(b);
            return empty ? cli_usage_error(cmd, "%s: empty item %d", flag, *n)
                         : cli_usage_error(cmd, "%s: more than %d images", flag, max);
        }
        out[(*n)++] = p;
        if (!c)
            break;
        p = c + 1;
    }
    *buf = b;
    return CLI_OK;
}

int cli_parse_long(const char *s, long lo, long hi, long *out)
{
    char *e;
    if (!s || !((*s >= '0' && *s <= '9') || *s == '-'))
        return -1;
    errno = 0;
    long v = strtol(s, &e, 10);
    if (errno || e == s || *e != '\0' || v < lo || v > hi)
        return -1;
    *out = v;
    return 0;
}

int cli_parse_size(const char *s, int max, int *w, int *h)
{
    char buf[32];
    const char *x = strpbrk(s, "xX");
    long vw, vh;
    if (!x || (size_t)(x - s) >= sizeof buf)
        return -1;
    memcpy(buf, s, (size_t)(x - s));
    buf[x - s] = '\0';
    if (cli_parse_long(buf, 1, max, &vw) != 0 || cli_parse_long(x + 1, 1, max, &vh) != 0)
        return -1;
    *w = (int)vw;
    *h = (int)vh;
    return 0;
}

int cli_parse_range(const cli_command *cmd, const char *flag, const char *value, double lo,
                    double hi, const char *want, double *out)
{
    float x;
    if (!value)
        return CLI_OK;
    if (cli_parse_floats(value, &x, 1) || !(x >= lo && x <= hi))
        return cli_usage_error(cmd, "%s: want %s; got '%s'", flag, want, value);
    *out = x;
    return CLI_OK;
}

int cli_parse_unit(const cli_command *cmd, const char *flag, const char *value, double *out)
{
    return cli_parse_range(cmd, flag, value, 0.0, 1.0, "a number in [0, 1]", out);
}

int cli_parse_finetune(const cli_command *cmd, const char *n, const char *parts, const char *lr,
                       const char *plateau, const char *outline, const char *mirror,
                       gs_finetune_options *fo)
{
    gs_finetune_options_default(fo);
    fo->iters = 0;
    fo->lr = GS_FINETUNE_LR_SERVED; /* the daemon's: one default everywhere */
    if (n) {
        long v;
        if (cli_parse_long(n, 1, 100000, &v))
            return cli_usage_error(cmd, "--finetune: want 1..100000 steps");
        fo->iters = (int)v;
    }
    if (parts && gs_finetune_parts_parse(parts, &fo->parts, NULL))
        return cli_usage_error(cmd, "--finetune-parts: want a list of face, eye, renderer, "
                               "mlp, geometry, face-geometry; got '%s'", parts);
    if (lr && cli_parse_rate(lr, 1.0, &fo->lr))
        return cli_usage_error(cmd, "--finetune-lr: want a rate in (0, 1]");
    if (plateau) {
        float x;
        if (cli_parse_floats(plateau, &x, 1) || !(x > 0 && x < 1))
            return cli_usage_error(cmd, "--finetune-plateau: want a fraction in (0, 1)");
        fo->plateau_rel = x;
    }
    if (outline) {
        long v;
        if (cli_parse_long(outline, 0, 8, &v))
            return cli_usage_error(cmd, "--finetune-outline: want 0..8 feature pixels");
        fo->outline_px = (int)v;
    }
    if (mirror) {
        long v;
        if (cli_parse_long(mirror, 0, 1, &v))
            return cli_usage_error(cmd, "--finetune-mirror: want 0 or 1");
        fo->mirror = (int)v;
    }
    if ((parts || lr || plateau || outline || mirror) && !n)
        return cli_usage_error(cmd, "--finetune-parts, --finetune-lr, --finetune-plateau, "
                               "--finetune-outline and --finetune-mirror go with --finetune N");
    return CLI_OK;
}

double cli_now_s(void)
{
    return gs_clock_s();
}

void cli_progress_start(cli_progress_t *p)
{
    p->tty = isatty(STDERR_FILENO);
    p->drawn = 0;
    p->start = cli_now_s();
    p->last = -1e9;
}

void cli_progress(cli_progress_t *p, int force, const char *fmt, ...)
{
    double now = cli_now_s();
    if (!force && now - p->last < (p->tty ? 0.1 : 10.0))
        return;
    p->last = now;
    va_list ap;
    va_start(ap, fmt);
    if (p->tty)
        fputs("\r\033[K", stderr); /* back to the line's start, and clear it */
    vfprintf(stderr, fmt, ap);
    if (!p->tty)
        fputc('\n', stderr);
    va_end(ap);
    fflush(stderr);
    p->drawn = 1;
}

void cli_progress_done(cli_progress_t *p)
{
    if (p->tty && p->drawn) /* the line goes: what follows reports the result */
        fputs("\r\033[K", stderr);
    p->drawn = 0;
}

int cli_write_all(int fd, const void *p, size_t n)
{
    const char *b = p;
    while (n) {
        ssize_t w = write(fd, b, n);
        if (w < 0 && errno == EINTR)
            continue;
        if (w <= 0) {
            if (w == 0)
                errno = ENOSPC;
            return -1;
        }
        b += w;
        n -= (size_t)w;
    }
    return 0;
}

int cli_fsync_path(const char *path)
{
    int fd = open(path, O_RDONLY);
    if (fd < 0)
        return -1;
    int r = fsync(fd);
    int e = errno;
    close(fd);
    errno = e;
    return r;
}

#ifndef GS_CLI_DATADIR /* the gazesplat_cli target names the install's */
#define GS_CLI_DATADIR "/usr/share/gazesplat"
#endif

const char *cli_shipped_model(const char *name)
{
    static char path[4][512];
    static int next;
    char *p = path[next++ % 4];
    snprintf(p, sizeof path[0], "models/%s", name);
    if (access(p, R_OK) == 0)
        return p;
    char inst[512];
    snprintf(inst, sizeof inst, "%s/models/%s", GS_CLI_DATADIR, name);
    if (access(inst, R_OK) == 0)
        snprintf(p, sizeof path[0], "%s", inst);
    return p;
}

int cli_read_file(const char *path, size_t max, uint8_t **out, size_t *len)
{
    *out = NULL;
    FILE *f = fopen(path, "rb");
    struct stat st;
    if (!f || fstat(fileno(f), &st) != 0 || st.st_size <= 0 || (uint64_t)st.st_size > max) {
        if (f)
            fclose(f);
        return -1;
    }
    *len = (size_t)st.st_size;
    *out = malloc(*len);
    int ok = *out && fread(*out, 1, *len, f) == *len;
    fclose(f);
    if (!ok) {
        free(*out);
        *out = NULL;
    }
    return ok ? 0 : -1;
}

int cli_parse_rate(const char *s, double hi, double *out)
{
    char *end;
    errno = 0;
    double v = strtod(s, &end);
    if (errno || end == s || *end || !(v > 0 && v <= hi))
        return -1;
    *out = v;
    return 0;
}

int cli_parse_fit_lr(const char *s, double *code, double *colour)
{
    char *end;
    double v[2];
    errno = 0;
    v[0] = strtod(s, &end);
    int two = *end == ',';
    if (two)
        v[1] = strtod(end + 1, &end);
    else
        v[1] = v[0] / 6.0;
    if (errno || end == s || *end || !(v[0] > 0 && v[0] <= 10) ||
        !(v[1] > 0 && v[1] <= 10))
        return -1;
    *code = v[0];
    *colour = v[1];
    return 0;
}

/* --kappa off | literature | H,HSD,V,VSD (degrees). */
int cli_parse_kappa(const cli_command *cmd, const char *v, gs_synth_kappa *k)
{
    memset(k, 0, sizeof *k);
    if (!strcmp(v, "off"))
        return CLI_PARSED;
    if (!strcmp(v, "literature")) {
        gs_synth_kappa_literature(k);
        return CLI_PARSED;
    }
    double f[4];
    const char *p = v;
    int n = 0;
    while (n < 4) {
        char *e;
        f[n] = strtod(p, &e);
        if (e == p || !isfinite(f[n]) || strspn(p, "0123456789+-.eE") < (size_t)(e - p))
            break;
        n++;
        p = e;
        if (n < 4 && *p++ != ',')
            break;
    }
    if (n < 4 || *p != '\0')
        return cli_usage_error(cmd, "--kappa: want off, literature or H,HSD,V,VSD "
                               "(four numbers, degrees); got '%s'", v);
    k->enabled = 1;
    k->h_mean_deg = f[0];
    k->h_sd_deg = f[1];
    k->v_mean_deg = f[2];
    k->v_sd_deg = f[3];
    gs_error err = {0, ""};
    if (gs_synth_kappa_check(k, &err) != GS_OK)
        return cli_usage_error(cmd, "--kappa: %s", err.msg);
    return CLI_PARSED;
}
