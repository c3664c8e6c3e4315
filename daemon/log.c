/* Leveled logging to stderr. */
#include "log.h"

#include <stdarg.h>
#include <stdatomic.h>
#include <stdio.h>
#include <string.h>

/* The daemon's one log threshold: a program-level setting, not library state. */
static atomic_int log_level = LOG_INFO_;

static const char *const names[] = {"error", "warn", "info", "debug"};
/* syslog priorities: err 3, warning 4, info 6, debug 7 */
static const int prio[] = {3, 4, 6, 7};

void gsd_log_set_level(int level)
{
    atomic_store(&log_level, level);
}

int gsd_log_level(void)
{
    return atomic_load(&log_level);
}

int gsd_log_parse_level(const char *s)
{
    for (int i = 0; i < 4; i++)
        if (strcmp(s, names[i]) == 0)
            return i;
    return -1;
}

const char *gsd_log_level_name(int level)
{
    return level >= 0 && level < 4 ? names[level] : "?";
}

void gsd_log(int level, const char *fmt, ...)
{
    if (level > atomic_load(&log_level))
        return;
    char line[1024];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(line, sizeof line, fmt, ap);
    va_end(ap);
    fprintf(stderr, "<%d>gazesplatd: %s: %s\n", prio[level], names[level], line);
}

void gsd_log_escape(const void *data, size_t n, char *out, size_t cap)
{
    const unsigned char *p = data;
    size_t o = 0;
    for (size_t i = 0; i < n && o + 5 < cap; i++) {
        if (p[i] >= 0x20 && p[i] < 0x7f && p[i] != '\\')
            out[o++] = (char)p[i];
        else
            o += (size_t)snprintf(out + o, cap - o, "\\x%02x", p[i]);
    }
    if (cap)
        out[o < cap ? o : cap - 1] = '\0';
}
