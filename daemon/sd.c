/* sd_notify and sd_listen_fds, implemented over plain sockets. */
#define _GNU_SOURCE
#include "sd.h"

#include <errno.h>
#include <fcntl.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <sys/un.h>
#include <unistd.h>

int gsd_notify(const char *state)
{
    const char *path = getenv("NOTIFY_SOCKET");
    if (!path || !*path)
        return 0;
    struct sockaddr_un sa;
    memset(&sa, 0, sizeof sa);
    sa.sun_family = AF_UNIX;
    size_t n = strlen(path);
    if ((path[0] != '/' && path[0] != '@') || n >= sizeof sa.sun_path)
        return -1;
    memcpy(sa.sun_path, path, n);
    if (path[0] == '@')
        sa.sun_path[0] = '\0'; /* abstract namespace */
    socklen_t len = (socklen_t)(offsetof(struct sockaddr_un, sun_path) + n);
    int fd = socket(AF_UNIX, SOCK_DGRAM | SOCK_CLOEXEC, 0);
    if (fd < 0)
        return -1;
    ssize_t r = sendto(fd, state, strlen(state), MSG_NOSIGNAL, (struct sockaddr *)&sa, len);
    close(fd);
    return r == (ssize_t)strlen(state) ? 1 : -1;
}

int gsd_notifyf(const char *fmt, ...)
{
    char buf[1024];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(buf, sizeof buf, fmt, ap);
    va_end(ap);
    return gsd_notify(buf);
}

static int parse_ulong(const char *s, unsigned long long *out)
{
    if (!s || !*s)
        return -1;
    char *end;
    errno = 0;
    unsigned long long v = strtoull(s, &end, 10);
    if (errno || *end)
        return -1;
    *out = v;
    return 0;
}

uint64_t gsd_watchdog_usec(void)
{
    unsigned long long usec, pid;
    if (parse_ulong(getenv("WATCHDOG_USEC"), &usec) != 0 || usec == 0)
        return 0;
    if (getenv("WATCHDOG_PID") &&
        (parse_ulong(getenv("WATCHDOG_PID"), &pid) != 0 || pid != (unsigned long long)getpid()))
        return 0;
    return usec;
}

int gsd_listen_fds(char names[GSD_MAX_LISTEN][64])
{
    unsigned long long pid, n;
    int count = 0;
    for (int i = 0; i < GSD_MAX_LISTEN; i++)
        names[i][0] = '\0';
    if (parse_ulong(getenv("LISTEN_PID"), &pid) == 0 && pid == (unsigned long long)getpid() &&
        parse_ulong(getenv("LISTEN_FDS"), &n) == 0 && n > 0 && n <= GSD_MAX_LISTEN) {
        count = (int)n;
        const char *fdnames = getenv("LISTEN_FDNAMES");
        for (int i = 0; i < count; i++) {
            int fd = GSD_LISTEN_FDS_START + i;
            fcntl(fd, F_SETFD, FD_CLOEXEC);
            fcntl(fd, F_SETFL, fcntl(fd, F_GETFL) | O_NONBLOCK);
            if (fdnames) {
                const char *colon = strchr(fdnames, ':');
                size_t len = colon ? (size_t)(colon - fdnames) : strlen(fdnames);
                snprintf(names[i], 64, "%.*s", (int)len, fdnames);
                fdnames = colon ? colon + 1 : NULL;
            }
        }
    }
    unsetenv("LISTEN_PID");
    unsetenv("LISTEN_FDS");
    unsetenv("LISTEN_FDNAMES");
    return count;
}
