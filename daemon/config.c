/* Table-driven configuration with bounds (after Redis config.c). */
#define _POSIX_C_SOURCE 200809L
#include "config.h"

#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "gazesplat/face.h"
#include "log.h"

enum { T_STR, T_INT, T_OCT, T_BOOL, T_LEVEL, T_REAL };

typedef struct key_def {
    const char *name;
    int type;
    size_t offset;
    double min, max; /* T_INT, T_OCT: [min, max]; T_REAL: a finite value in (min, max] */
    const char *def;
} key_def;

#define OFF(f) offsetof(gsd_config, f)
static const key_def keys[] = {
    {"socket", T_STR, OFF(socket), 0, 0, ""},
    {"socket_mode", T_OCT, OFF(socket_mode), 0, 0777, "0660"},
    {"tcp", T_STR, OFF(tcp), 0, 0, ""},
    {"tcp_allow_remote", T_BOOL, OFF(tcp_allow_remote), 0, 1, "no"},
    {"metrics", T_STR, OFF(metrics), 0, 0, ""},
    {"token", T_STR, OFF(token), 0, 0, ""},
    {"token_file", T_STR, OFF(token_file), 0, 0, ""},
    {"model", T_STR, OFF(model), 0, 0, ""},
    {"state_dir", T_STR, OFF(state_dir), 0, 0, ""},
    {"workers", T_INT, OFF(workers), 1, 64, "1"},
    {"threads", T_INT, OFF(threads), 0, 256, "0"},
    {"queue_depth", T_INT, OFF(queue_depth), 1, 4096, "16"},
    {"sweep_subjects", T_INT, OFF(sweep_subjects), 1, 64, "8"},
    {"max_payload", T_INT, OFF(max_payload), 4096, 256 << 20, "16777216"},
    {"max_targets", T_INT, OFF(max_targets), 1, 1024, "64"},
    {"max_inflight", T_INT, OFF(max_inflight), 1, 1024, "8"},
    {"max_output_kb", T_INT, OFF(max_output_kb), 64, 4 << 20, "65536"},
    {"output_budget_mb", T_INT, OFF(output_budget_mb), 1, 65536, "512"},
    {"max_connections", T_INT, OFF(max_connections), 1, 65536, "1024"},
    {"max_image_side", T_INT, OFF(max_image_side), 16, 16384, "4096"},
    {"max_image_mpix", T_INT, OFF(max_image_mpix), 1, 256, "16"},
    {"header_timeout_ms", T_INT, OFF(header_timeout_ms), 50, 600000, "10000"},
    {"idle_timeout_ms", T_INT, OFF(idle_timeout_ms), 0, 86400000, "300000"},
    {"request_timeout_ms", T_INT, OFF(request_timeout_ms), 10, 3600000, "60000"},
    {"max_deadline_ms", T_INT, OFF(max_deadline_ms), 10, 3600000, "600000"},
    {"drain_timeout_ms", T_INT, OFF(drain_timeout_ms), 0, 3600000, "30000"},
    {"cache_mb", T_INT, OFF(cache_mb), 1, 65536, "256"},
    {"tuned_cache_mb", T_INT, OFF(tuned_cache_mb), 1, 65536, "256"},
    {"input_cache_mb", T_INT, OFF(input_cache_mb), 1, 65536, "64"},
    {"max_finetune_steps", T_INT, OFF(max_finetune_steps), 0, 100000, "1000"},
    {"finetune_lr", T_REAL, OFF(finetune_lr), 0, 1, "0.004"},
    {"tuned_subjects", T_INT, OFF(tuned_subjects), 1, GSD_TUNED_SLOTS_MAX, "2"},
    {"log_level", T_LEVEL, OFF(log_level), 0, 3, "info"},
    {"debug_requests", T_BOOL, OFF(debug_requests), 0, 1, "no"},
    {"photo_input", T_BOOL, OFF(photo_input), 0, 1, "yes"},
    {"face_gate", T_BOOL, OFF(face_gate), 0, 1, "yes"},
    {"face_landmarks", T_STR, OFF(face_landmarks), 0, 0, GS_FACE_SHAPE_MODEL_DEFAULT},
    {"face_cascade", T_STR, OFF(face_cascade), 0, 0, GS_FACE_CASCADE_DEFAULT},
    {"live.device", T_STR, OFF(live_device), 0, 0, ""},
    {"live.output", T_STR, OFF(live_output), 0, 0, ""},
    {"live.width", T_INT, OFF(live_width), 16, 8192, "640"},
    {"live.height", T_INT, OFF(live_height), 16, 8192, "480"},
    {"live.fps", T_INT, OFF(live_fps), 1, 240, "30"},
    {"live.fit_budget_s", T_INT, OFF(live_fit_budget_s), 1, 600, "30"},
};
#define NKEYS (sizeof keys / sizeof keys[0])

static const key_def *find_key(const char *name)
{
    for (size_t i = 0; i < NKEYS; i++)
        if (strcmp(keys[i].name, name) == 0)
            return &keys[i];
    return NULL;
}

static int parse_long(const char *s, int base, long *out)
{
    char *end;
    errno = 0;
    long v = strtol(s, &end, base);
    if (errno || end == s || *end != '\0')
        return -1;
    *out = v;
    return 0;
}

static int set_value(gsd_config *c, const key_def *k, const char *value, char *msg, size_t cap)
{
    void *field = (char *)c + k->offset;
    long v = 0;
    switch (k->type) {
    case T_STR:
        if (strlen(value) >= GSD_STR_MAX) {
            snprintf(msg, cap, "%s: value longer than %d bytes", k->name, GSD_STR_MAX - 1);
            return -1;
        }
        memcpy(field, value, strlen(value) + 1);
        return 0;
    case T_BOOL:
        if (!strcmp(value, "yes") || !strcmp(value, "true") || !strcmp(value, "1"))
            v = 1;
        else if (!strcmp(value, "no") || !strcmp(value, "false") || !strcmp(value, "0"))
            v = 0;
        else {
            snprintf(msg, cap, "%s: want yes or no, got '%s'", k->name, value);
            return -1;
        }
        break;
    case T_REAL: {
        char *end;
        errno = 0;
        double d = strtod(value, &end);
        if (errno || end == value || *end != '\0' || !isfinite(d) || !(d > k->min) || d > k->max) {
            snprintf(msg, cap, "%s: want a number in (%g, %g], got '%s'", k->name, k->min, k->max,
                     value);
            return -1;
        }
        *(double *)field = d;
        return 0;
    }
    case T_LEVEL:
        v = gsd_log_parse_level(value);
        if (v < 0) {
            snprintf(msg, cap, "%s: want error, warn, info or debug, got '%s'", k->name, value);
            return -1;
        }
        break;
    default:
        if (parse_long(value, k->type == T_OCT ? 8 : 10, &v) != 0 || v < k->min || v > k->max) {
            snprintf(msg, cap, k->type == T_OCT ? "%s: want an octal number in [%lo, %lo], got '%s'"
                                                : "%s: want an integer in [%ld, %ld], got '%s'",
                     k->name, (long)k->min, (long)k->max, value);
            return -1;
        }
    }
    *(int *)field = (int)v;
    return 0;
}

void gsd_config_default(gsd_config *c)
{
    char msg[256];
    memset(c, 0, sizeof *c);
    for (size_t i = 0; i < NKEYS; i++)
        set_value(c, &keys[i], keys[i].def, msg, sizeof msg);
}

int gsd_config_set(gsd_config *c, const char *key, const char *value, char *msg, size_t cap)
{
    const key_def *k = find_key(key);
    if (!k) {
        snprintf(msg, cap, "unknown key '%s'", key);
        return -1;
    }
    return set_value(c, k, value, msg, cap);
}

static char *trim(char *s)
{
    while (*s == ' ' || *s == '\t')
        s++;
    size_t n = strlen(s);
    while (n > 0 && (s[n - 1] == ' ' || s[n - 1] == '\t' || s[n - 1] == '\r' || s[n - 1] == '\n'))
        s[--n] = '\0';
    return s;
}

int gsd_config_load(gsd_config *c, const char *path, char *msg, size_t cap)
{
    FILE *f = fopen(path, "r");
    if (!f) {
        snprintf(msg, cap, "%s: %s", path, strerror(errno));
        return -1;
    }
    char line[4096], err[300];
    int lineno = 0, rc = 0;
    while (rc == 0 && fgets(line, sizeof line, f)) {
        lineno++;
        if (!strchr(line, '\n') && !feof(f)) {
            snprintf(msg, cap, "%s:%d: line longer than %zu bytes", path, lineno, sizeof line - 2);
            rc = -1;
            break;
        }
        char *s = trim(line);
        if (*s == '\0' || *s == '#')
            continue;
        char *eq = strchr(s, '=');
        if (!eq) {
            snprintf(msg, cap, "%s:%d: want 'key = value'", path, lineno);
            rc = -1;
            break;
        }
        *eq = '\0';
        if (gsd_config_set(c, trim(s), trim(eq + 1), err, sizeof err) != 0) {
            snprintf(msg, cap, "%s:%d: %s", path, lineno, err);
            rc = -1;
        }
    }
    fclose(f);
    return rc;
}

/* The token file holds the secret on its first line. */
static int read_token_file(gsd_config *c, char *msg, size_t cap)
{
    FILE *f = fopen(c->token_file, "r");
    if (!f) {
        snprintf(msg, cap, "token_file %s: %s", c->token_file, strerror(errno));
        return -1;
    }
    char buf[GSD_STR_MAX];
    int ok = fgets(buf, sizeof buf, f) != NULL;
    fclose(f);
    char *t = ok ? trim(buf) : NULL;
    if (!t || !*t) {
        snprintf(msg, cap, "token_file %s: empty", c->token_file);
        return -1;
    }
    memcpy(c->token, t, strlen(t) + 1);
    return 0;
}

int gsd_config_finish(gsd_config *c, char *msg, size_t cap)
{
    if (c->token_file[0] && read_token_file(c, msg, cap) != 0)
        return -1;
    if (c->max_deadline_ms < c->request_timeout_ms) {
        snprintf(msg, cap, "max_deadline_ms (%d) < request_timeout_ms (%d)", c->max_deadline_ms,
                 c->request_timeout_ms);
        return -1;
    }
    return 0;
}

void gsd_config_print(const gsd_config *c, void *file)
{
    FILE *f = file;
    for (size_t i = 0; i < NKEYS; i++) {
        const key_def *k = &keys[i];
        const void *field = (const char *)c + k->offset;
        if (k->type == T_REAL) { /* the shortest text that reads back the same */
            double d = *(const double *)field;
            char buf[40];
            for (int prec = 6; prec <= 17; prec++) {
                snprintf(buf, sizeof buf, "%.*g", prec, d);
                if (strtod(buf, NULL) == d)
                    break;
            }
            fprintf(f, "%s = %s\n", k->name, buf);
            continue;
        }
        int v = *(const int *)field;
        if (k->type == T_STR)
            fprintf(f, "%s = %s\n", k->name,
                    strcmp(k->name, "token") == 0 && *(const char *)field ? "(set)" : (const char *)field);
        else if (k->type == T_OCT)
            fprintf(f, "%s = %04o\n", k->name, (unsigned)v);
        else if (k->type == T_BOOL)
            fprintf(f, "%s = %s\n", k->name, v ? "yes" : "no");
        else if (k->type == T_LEVEL)
            fprintf(f, "%s = %s\n", k->name, gsd_log_level_name(v));
        else
            fprintf(f, "%s = %d\n", k->name, v);
    }
}
