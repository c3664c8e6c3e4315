/* gs_client: blocking client over a Unix or TCP socket. */
#define _POSIX_C_SOURCE 200809L
#include "gs_client.h"

#include <errno.h>
#include <netdb.h>
#include <poll.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <sys/un.h>
#include <unistd.h>

#include <blake2.h>

#include "gazesplat/clock.h"

struct gs_client {
    int fd;
    uint16_t version;
    gs_frame_parser parser;
    uint8_t route_key[GS_FRAME_KEY_SIZE];
};

static int reply_type_ok(uint16_t type)
{
    return gs_msg_is_reply(type);
}

static int connect_unix(const char *path, gs_error *err)
{
    struct sockaddr_un sa;
    memset(&sa, 0, sizeof sa);
    sa.sun_family = AF_UNIX;
    if (strlen(path) >= sizeof sa.sun_path)
        return gs_error_set(err, GS_ERR_ARG, "socket path too long: %s", path);
    memcpy(sa.sun_path, path, strlen(path) + 1);
    int fd = socket(AF_UNIX, SOCK_STREAM | SOCK_CLOEXEC, 0);
    if (fd < 0)
        return gs_error_set(err, GS_ERR_IO, "socket: %s", strerror(errno));
    if (connect(fd, (struct sockaddr *)&sa, sizeof sa) != 0) {
        int e = errno;
        close(fd);
        return gs_error_set(err, GS_ERR_IO, "connect %s: %s", path, strerror(e));
    }
    return fd;
}

static int connect_tcp(const char *hostport, gs_error *err)
{
    char host[256];
    const char *colon = strrchr(hostport, ':');
    if (!colon || colon == hostport || (size_t)(colon - hostport) >= sizeof host)
        return gs_error_set(err, GS_ERR_ARG, "want tcp:HOST:PORT, got tcp:%s", hostport);
    memcpy(host, hostport, (size_t)(colon - hostport));
    host[colon - hostport] = '\0';
    if (host[0] == '[' && host[strlen(host) - 1] == ']') {
        memmove(host, host + 1, strlen(host));
        host[strlen(host) - 1] = '\0';
    }
    struct addrinfo hints, *res = NULL;
    memset(&hints, 0, sizeof hints);
    hints.ai_socktype = SOCK_STREAM;
    int r = getaddrinfo(host, colon + 1, &hints, &res);
    if (r != 0)
        return gs_error_set(err, GS_ERR_IO, "resolve %s: %s", hostport, gai_strerror(r));
    int fd = -1, e = 0;
    for (struct addrinfo *a = res; a && fd < 0; a = a->ai_next) {
        fd = socket(a->ai_family, a->ai_socktype | SOCK_CLOEXEC, a->ai_protocol);
        if (fd >= 0 && connect(fd, a->ai_addr, a->ai_addrlen) != 0) {
            e = errno;
            close(fd);
            fd = -1;
        }
    }
    freeaddrinfo(res);
    if (fd < 0)
        return gs_error_set(err, GS_ERR_IO, "connect %s: %s", hostport, strerror(e));
    return fd;
}

int gs_client_connect(const char *addr, int timeout_ms, gs_client **out, gs_error *err)
{
    (void)timeout_ms; /* connect on a local socket does not block for long */
    int fd;
    if (strncmp(addr, "tcp:", 4) == 0)
        fd = connect_tcp(addr + 4, err);
    else
        fd = connect_unix(strncmp(addr, "unix:", 5) == 0 ? addr + 5 : addr, err);
    if (fd < 0)
        return fd;
    gs_client *c = calloc(1, sizeof *c);
    if (!c) {
        close(fd);
        return gs_error_set(err, GS_ERR_NOMEM, "out of memory");
    }
    c->fd = fd;
    c->version = GS_PROTO_VERSION_MIN;
    gs_frame_limits lim = {GS_FRAME_HARD_MAX_PAYLOAD, GS_PROTO_VERSION_MIN, GS_PROTO_VERSION_MAX,
                           reply_type_ok};
    gs_frame_parser_init(&c->parser, &lim);
    *out = c;
    return GS_OK;
}

void gs_client_close(gs_client *c)
{
    if (!c)
        return;
    close(c->fd);
    gs_frame_parser_free(&c->parser);
    free(c);
}

int gs_client_fd(const gs_client *c)
{
    return c->fd;
}

void gs_client_set_version(gs_client *c, uint16_t version)
{
    c->version = version;
}

int gs_client_send_raw(gs_client *c, const void *buf, size_t len, gs_error *err)
{
    const uint8_t *p = buf;
    while (len > 0) {
        ssize_t n = send(c->fd, p, len, MSG_NOSIGNAL);
        if (n < 0 && errno == EINTR)
            continue;
        if (n < 0)
            return gs_error_set(err, GS_ERR_IO, "send: %s", strerror(errno));
        p += n;
        len -= (size_t)n;
    }
    return GS_OK;
}

int gs_client_send(gs_client *c, uint16_t type, const uint8_t key[GS_FRAME_KEY_SIZE],
                   uint32_t request_id, const ProtobufCMessage *msg, gs_error *err)
{
    gs_frame_header h;
    memset(&h, 0, sizeof h);
    h.version = c->version;
    h.type = type;
    h.request_id = request_id;
    if (key)
        memcpy(h.key, key, GS_FRAME_KEY_SIZE);
    uint8_t *buf;
    size_t len;
    if (gs_msg_pack(&h, msg, GS_FRAME_HARD_MAX_PAYLOAD, &buf, &len) != 0)
        return gs_error_set(err, GS_ERR_LIMIT, "message too large or out of memory");
    int r = gs_client_send_raw(c, buf, len, err);
    free(buf);
    return r;
}

void gs_client_frame_free(gs_client_frame *f)
{
    if (f->msg)
        protobuf_c_message_free_unpacked(f->msg, NULL);
    f->msg = NULL;
}

/* Reads until the parser has a frame or the deadline passes. */
static int read_frame(gs_client *c, long long deadline, gs_error *err)
{
    for (;;) {
        uint8_t *dst;
        size_t want;
        gs_frame_parser_want(&c->parser, &dst, &want);
        if (want == 0)
            break;
        int left = (int)(deadline - gs_clock_ms());
        struct pollfd pfd = {c->fd, POLLIN, 0};
        int pr = left > 0 ? poll(&pfd, 1, left) : 0;
        if (pr < 0 && errno == EINTR)
            continue;
        if (pr <= 0)
            return gs_error_set(err, GS_ERR_IO, "timeout");
        ssize_t n = recv(c->fd, dst, want, 0);
        if (n < 0 && (errno == EINTR || errno == EAGAIN))
            continue;
        if (n < 0)
            return gs_error_set(err, GS_ERR_IO, "recv: %s", strerror(errno));
        if (n == 0)
            return gs_error_set(err, GS_ERR_IO, "closed");
        int r = gs_frame_parser_advance(&c->parser, (size_t)n);
        if (r < 0)
            return gs_error_set(err, GS_ERR_FORMAT, "server frame: %s", gs_frame_strerror(r));
        if (r == GS_FRAME_READY)
            break;
    }
    return GS_OK;
}

int gs_client_recv(gs_client *c, int timeout_ms, gs_client_frame *f, gs_error *err)
{
    f->msg = NULL;
    int r = read_frame(c, gs_clock_ms() + timeout_ms, err);
    if (r != GS_OK)
        return r;
    f->header = *gs_frame_parser_header(&c->parser);
    f->msg = gs_msg_unpack(f->header.type, gs_frame_parser_payload(&c->parser),
                           f->header.payload_len);
    uint16_t type = f->header.type;
    gs_frame_parser_next(&c->parser);
    if (!f->msg)
        return gs_error_set(err, GS_ERR_FORMAT, "server sent a malformed %s payload",
                            gs_msg_type_name(type));
    return GS_OK;
}

int gs_client_call(gs_client *c, uint16_t type, const uint8_t key[GS_FRAME_KEY_SIZE],
                   uint32_t request_id, const ProtobufCMessage *msg, int timeout_ms,
                   gs_client_frame *reply, gs_error *err)
{
    int r = gs_client_send(c, type, key, request_id, msg, err);
    return r != GS_OK ? r : gs_client_recv(c, timeout_ms, reply, err);
}

void gs_client_set_route_key(gs_client *c, const uint8_t key[GS_FRAME_KEY_SIZE])
{
    memcpy(c->route_key, key, GS_FRAME_KEY_SIZE);
}

void gs_client_route_key(const void *image, size_t len, const void *settings,
                         size_t settings_len, uint8_t out[GS_FRAME_KEY_SIZE])
{
    static const uint8_t tag[] = "gazesplat-route-key-c1";
    uint8_t n[8];
    for (int i = 0; i < 8; i++)
        n[i] = (uint8_t)((uint64_t)len >> (8 * i));
    blake2b_state st;
    blake2b_init(&st, GS_FRAME_KEY_SIZE);
    blake2b_update(&st, tag, sizeof tag);
    blake2b_update(&st, n, sizeof n);
    blake2b_update(&st, image, len);
    if (settings && settings_len)
        blake2b_update(&st, settings, settings_len);
    blake2b_final(&st, out, GS_FRAME_KEY_SIZE);
}

int gs_client_hello(gs_client *c, const char *client_name, const char *token, int timeout_ms,
                    Gazesplat__HelloOk **ok, gs_error *err)
{
    Gazesplat__Hello hello = GAZESPLAT__HELLO__INIT;
    hello.min_version = GS_PROTO_VERSION_MIN;
    hello.max_version = GS_PROTO_VERSION_MAX;
    hello.client_name = (char *)(client_name ? client_name : "gs_client");
    if (token) {
        hello.token.data = (uint8_t *)token;
        hello.token.len = strlen(token);
    }
    gs_client_frame f;
    int r = gs_client_call(c, GAZESPLAT__FRAME_TYPE__FRAME_HELLO, c->route_key, 0, &hello.base,
                           timeout_ms, &f, err);
    if (r != GS_OK)
        return r;
    if (f.header.type == GAZESPLAT__FRAME_TYPE__FRAME_ERROR) {
        const Gazesplat__Error *e = (const Gazesplat__Error *)f.msg;
        r = gs_error_set(err, GS_ERR_STATE, "%s: %s", gs_msg_error_name(e->code), e->message);
        gs_client_frame_free(&f);
        return r;
    }
    if (f.header.type != GAZESPLAT__FRAME_TYPE__FRAME_HELLO_OK) {
        r = gs_error_set(err, GS_ERR_FORMAT, "HELLO answered by %s",
                         gs_msg_type_name(f.header.type));
        gs_client_frame_free(&f);
        return r;
    }
    Gazesplat__HelloOk *h = (Gazesplat__HelloOk *)f.msg;
    c->version = (uint16_t)h->version;
    if (ok)
        *ok = h;
    else
        gs_client_frame_free(&f);
    return GS_OK;
}
