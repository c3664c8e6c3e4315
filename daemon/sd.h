/* systemd integration without libsystemd: sd_notify(3) over the
 * $NOTIFY_SOCKET datagram socket and sd_listen_fds(3) semantics. */
#ifndef GSD_SD_H
#define GSD_SD_H

#include <stdint.h>

#define GSD_LISTEN_FDS_START 3
#define GSD_MAX_LISTEN 16

/* Sends one notification ("READY=1\nSTATUS=..."). Returns 1 when sent, 0
 * when $NOTIFY_SOCKET is unset, -1 on error. */
int gsd_notify(const char *state);
/* printf-style convenience. */
int gsd_notifyf(const char *fmt, ...) __attribute__((format(printf, 1, 2)));

/* The watchdog interval in microseconds from $WATCHDOG_USEC (checked
 * against $WATCHDOG_PID when set); 0 when disabled. */
uint64_t gsd_watchdog_usec(void);

/* Sockets passed by the service manager: checks $LISTEN_PID against our
 * pid, returns the count n (fds 3 .. 3+n-1, made close-on-exec and
 * non-blocking), 0 when not activated. The names from $LISTEN_FDNAMES are
 * copied into names[i] ("" when absent). Unsets the variables so children
 * do not inherit them. */
int gsd_listen_fds(char names[GSD_MAX_LISTEN][64]);

#endif
