/* gazesplatd listeners: sockets passed by systemd (LISTEN_FDS), else a
 * Unix socket (stale files replaced, mode socket_mode) and optionally TCP
 * (loopback unless tcp_allow_remote). */
#define _GNU_SOURCE
#include <arpa/inet.h>
#include <errno.h>
#include <netdb.h>
#include <netinet/in.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <sys/un.h>
#include <unistd.h>

#include "log.h"
#include "daemon.h"

/* ---- listeners ------------------------------------------------------------ */

static int add_listener(gsd_server *s, int fd, int is_tcp, int owned, const char *path)
{
    gsd_listener *l = &s->listeners[s->nlisteners];
    l->srv = s;
    l->fd = fd;
    l->is_tcp = is_tcp;
    l->owned = owned;
    snprintf(l->path, sizeof l->path, "%s", path ? path : "");
    if (ev_add(s->loop, &l->w, fd, EV_READ, s->on_accept, l) != 0)
        return -1;
    s->nlisteners++;
    return 0;
}

static void default_socket_path(char *out, size_t cap)
{
    const char *rt = getenv("RUNTIME_DIRECTORY");
    if (rt && *rt) {
        char first[256];
        snprintf(first, sizeof first, "%s", rt);
        char *colon = strchr(first, ':'); /* several directories: the first */
        if (colon)
            *colon = '\0';
        snprintf(out, cap, "%s/gazesplatd.sock", first);
    } else {
        snprintf(out, cap, "/run/gazesplat/gazesplatd.sock");
    }
}

/* A listening Unix socket at path with file mode `mode`; a stale socket
 * file nobody listens on is replaced. The fd, or -1 with msg. */
static int open_unix(const char *path, int mode, char *msg, size_t cap)
{
    struct sockaddr_un sa;
    memset(&sa, 0, sizeof sa);
    sa.sun_family = AF_UNIX;
    if (strlen(path) >= sizeof sa.sun_path) {
        snprintf(msg, cap, "socket path too long: %s", path);
        return -1;
    }
    memcpy(sa.sun_path, path, strlen(path) + 1);
    int fd = socket(AF_UNIX, SOCK_STREAM | SOCK_NONBLOCK | SOCK_CLOEXEC, 0);
    if (fd < 0) {
        snprintf(msg, cap, "socket: %s", strerror(errno));
        return -1;
    }
    struct stat st;
    if (lstat(path, &st) == 0 && S_ISSOCK(st.st_mode)) {
        int probe = socket(AF_UNIX, SOCK_STREAM | SOCK_CLOEXEC, 0);
        int live = probe >= 0 && connect(probe, (struct sockaddr *)&sa, sizeof sa) == 0;
        if (probe >= 0)
            close(probe);
        if (live) {
            snprintf(msg, cap, "%s: another server is listening", path);
            close(fd);
            return -1;
        }
        unlink(path);
    }
    /* Created with no permissions, then opened to socket_mode. */
    mode_t old = umask(0777);
    int r = bind(fd, (struct sockaddr *)&sa, sizeof sa);
    umask(old);
    if (r != 0 || chmod(path, (mode_t)mode) != 0 || listen(fd, 128) != 0) {
        snprintf(msg, cap, "bind %s: %s", path, strerror(errno));
        close(fd);
        return -1;
    }
    return fd;
}

/* Binds the daemon's Unix socket. */
static int bind_unix(gsd_server *s, const char *path, char *msg, size_t cap)
{
    int fd = open_unix(path, s->cfg.socket_mode, msg, cap);
    if (fd < 0)
        return -1;
    if (add_listener(s, fd, 0, 1, path) != 0) {
        snprintf(msg, cap, "epoll: %s", strerror(errno));
        close(fd);
        return -1;
    }
    LOG_I("listening on unix:%s (mode %04o)", path, (unsigned)s->cfg.socket_mode);
    return 0;
}

static int is_loopback(const struct sockaddr *sa)
{
    if (sa->sa_family == AF_INET)
        return (ntohl(((const struct sockaddr_in *)sa)->sin_addr.s_addr) >> 24) == 127;
    if (sa->sa_family == AF_INET6)
        return IN6_IS_ADDR_LOOPBACK(&((const struct sockaddr_in6 *)sa)->sin6_addr);
    return 0;
}

/* A listening TCP socket on HOST:PORT, loopback unless allow_remote. The
 * fd, or -1 with msg; *remote: the address is not loopback. */
static int open_tcp(const char *hostport, int allow_remote, int *remote, char *msg, size_t cap)
{
    char host[256];
    const char *colon = strrchr(hostport, ':');
    if (!colon || colon == hostport || (size_t)(colon - hostport) >= sizeof host) {
        snprintf(msg, cap, "tcp: want HOST:PORT, got '%s'", hostport);
        return -1;
    }
    snprintf(host, sizeof host, "%.*s", (int)(colon - hostport), hostport);
    if (host[0] == '[' && strlen(host) > 2 && host[strlen(host) - 1] == ']') {
        memmove(host, host + 1, strlen(host));
        host[strlen(host) - 1] = '\0';
    }
    struct addrinfo hints, *res = NULL;
    memset(&hints, 0, sizeof hints);
    hints.ai_socktype = SOCK_STREAM;
    hints.ai_flags = AI_PASSIVE | AI_NUMERICSERV;
    int gr = getaddrinfo(host, colon + 1, &hints, &res);
    if (gr != 0) {
        snprintf(msg, cap, "tcp %s: %s", hostport, gai_strerror(gr));
        return -1;
    }
    int fd = -1;
    *remote = !is_loopback(res->ai_addr);
    if (*remote && !allow_remote) {
        snprintf(msg, cap, "tcp %s is not a loopback address; set tcp_allow_remote = yes "
                 "(and a token) to listen on it", hostport);
    } else {
        fd = socket(res->ai_family, SOCK_STREAM | SOCK_NONBLOCK | SOCK_CLOEXEC, 0);
        int one = 1;
        if (fd >= 0)
            setsockopt(fd, SOL_SOCKET, SO_REUSEADDR, &one, sizeof one);
        if (fd < 0 || bind(fd, res->ai_addr, res->ai_addrlen) != 0 || listen(fd, 128) != 0) {
            snprintf(msg, cap, "tcp %s: %s", hostport, strerror(errno));
            if (fd >= 0)
                close(fd);
            fd = -1;
        }
    }
    freeaddrinfo(res);
    return fd;
}

static int bind_tcp(gsd_server *s, const char *hostport, char *msg, size_t cap)
{
    int remote = 0;
    int fd = open_tcp(hostport, s->cfg.tcp_allow_remote, &remote, msg, cap);
    if (fd < 0)
        return -1;
    if (add_listener(s, fd, 1, 0, NULL) != 0) {
        snprintf(msg, cap, "tcp %s: %s", hostport, strerror(errno));
        close(fd);
        return -1;
    }
    if (remote && !s->cfg.token[0])
        LOG_W("tcp %s reachable from other hosts without a token", hostport);
    LOG_I("listening on tcp:%s%s", hostport, s->cfg.token[0] ? " (token required)" : "");
    return 0;
}

int gsd_listen_open(const char *addr, int mode, int allow_remote, char *msg, size_t cap)
{
    int remote = 0;
    if (!strncmp(addr, "unix:", 5))
        return open_unix(addr + 5, mode, msg, cap);
    return open_tcp(addr, allow_remote, &remote, msg, cap);
}

int gsd_listen_setup(gsd_server *s, char *msg, size_t cap)
{
    char names[GSD_MAX_LISTEN][64];
    int n = gsd_listen_fds(names);
    for (int i = 0; i < n; i++) {
        int fd = GSD_LISTEN_FDS_START + i;
        struct sockaddr_storage ss;
        socklen_t len = sizeof ss;
        if (getsockname(fd, (struct sockaddr *)&ss, &len) != 0) {
            snprintf(msg, cap, "inherited fd %d is not a socket", fd);
            return -1;
        }
        int is_tcp = ss.ss_family == AF_INET || ss.ss_family == AF_INET6;
        if (add_listener(s, fd, is_tcp, 0, NULL) != 0) {
            snprintf(msg, cap, "epoll on inherited fd %d: %s", fd, strerror(errno));
            return -1;
        }
        LOG_I("listening on inherited fd %d (%s%s%s)", fd, is_tcp ? "tcp" : "unix",
              names[i][0] ? ", " : "", names[i]);
    }
    if (n > 0)
        return 0;
    char path[GSD_STR_MAX];
    if (s->cfg.socket[0])
        snprintf(path, sizeof path, "%s", s->cfg.socket);
    else
        default_socket_path(path, sizeof path);
    /* TCP first: a refused address must fail before the socket file exists. */
    if (s->cfg.tcp[0] && bind_tcp(s, s->cfg.tcp, msg, cap) != 0)
        return -1;
    if (strcmp(path, "none") != 0 && bind_unix(s, path, msg, cap) != 0) {
        gsd_listen_close(s);
        return -1;
    }
    if (s->nlisteners == 0) {
        snprintf(msg, cap, "no socket to listen on (socket = none and no tcp)");
        return -1;
    }
    return 0;
}

void gsd_listen_close(gsd_server *s)
{
    for (int i = 0; i < s->nlisteners; i++) {
        gsd_listener *l = &s->listeners[i];
        ev_del(s->loop, &l->w);
        close(l->fd); /* never unlink or shut down an inherited socket */
        if (l->owned && l->path[0])
            unlink(l->path);
    }
    s->nlisteners = 0;
}
