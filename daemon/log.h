/* Logging to stderr with levels ("<3>" style prefixes that journald reads
 * as priorities when the daemon runs under systemd). Thread-safe: one
 * fprintf per line. */
#ifndef GSD_LOG_H
#define GSD_LOG_H

#include <stddef.h>

enum { LOG_ERR_ = 0, LOG_WARN_ = 1, LOG_INFO_ = 2, LOG_DEBUG_ = 3 };

void gsd_log_set_level(int level);
int gsd_log_level(void);
/* Parses "error", "warn", "info", "debug"; -1 when none. */
int gsd_log_parse_level(const char *s);
const char *gsd_log_level_name(int level);

void gsd_log(int level, const char *fmt, ...) __attribute__((format(printf, 2, 3)));

/* Escapes up to n bytes of untrusted data for a log line (printable ASCII
 * kept, the rest as \xNN) into out (cap bytes, always terminated). */
void gsd_log_escape(const void *data, size_t n, char *out, size_t cap);

#define LOG_E(...) gsd_log(LOG_ERR_, __VA_ARGS__)
#define LOG_W(...) gsd_log(LOG_WARN_, __VA_ARGS__)
#define LOG_I(...) gsd_log(LOG_INFO_, __VA_ARGS__)
#define LOG_D(...) gsd_log(LOG_DEBUG_, __VA_ARGS__)

#endif
