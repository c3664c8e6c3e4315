/* The real gazesplatd: the compute queue and request life cycle, using
 * the diagnostic SLEEP request (debug_requests = yes) so timings do not
 * depend on a model: BUSY with retry-after under a full queue, CANCEL of
 * running and queued requests, deadlines, per-connection limits, 32
 * clients x 50 requests without lost or mixed-up replies, SIGHUP reload,
 * SIGTERM drain, TCP with a token.
 * usage: test_daemon_jobs PATH_TO_GAZESPLATD */
#define _GNU_SOURCE
#include <netinet/in.h>
#include <poll.h>

#include "daemon_harness.h"

static const char *bin;

static int send_sleep(gs_client *c, uint32_t id, uint32_t ms, uint32_t deadline)
{
    Gazesplat__Sleep m = GAZESPLAT__SLEEP__INIT;
    m.ms = ms;
    m.deadline_ms = deadline;
    return gs_client_send(c, T(SLEEP), NULL, id, &m.base, NULL);
}

static int send_cancel(gs_client *c, uint32_t id, uint32_t target)
{
    Gazesplat__Cancel m = GAZESPLAT__CANCEL__INIT;
    m.request_id = target;
    return gs_client_send(c, T(CANCEL), NULL, id, &m.base, NULL);
}

static void test_busy(const daemon_proc *d)
{
    /* workers 1, queue_depth 2: one running, two queued, the fourth BUSY
     * (sent on a second connection: max_inflight is 3 per connection). */
    gs_client *c = h_hello(d->sock), *c2 = h_hello(d->sock);
    send_sleep(c, 1, 400, 0);
    h_sleep_ms(100);
    send_sleep(c, 2, 50, 0);
    send_sleep(c, 3, 50, 0);
    send_sleep(c2, 4, 50, 0);
    int code;
    uint32_t id;
    ProtobufCMessage *m = NULL;
    int type = h_recv(c2, 3000, &code, &id, &m);
    CHECK_MSG(type == T(BUSY) && id == 4, "first reply type %d id %u, want BUSY for 4", type, id);
    if (type == T(BUSY)) {
        Gazesplat__Busy *b = (Gazesplat__Busy *)m;
        CHECK_MSG(b->retry_after_ms >= 10 && b->queue_length == 2, "retry_after %u queue %u",
                  b->retry_after_ms, b->queue_length);
    }
    if (m)
        protobuf_c_message_free_unpacked(m, NULL);
    for (uint32_t want = 1; want <= 3; want++) {
        type = h_recv(c, 3000, &code, &id, NULL);
        CHECK_MSG(type == T(SLEEP_OK) && id == want, "reply type %d id %u, want SLEEP_OK %u", type, id, want);
    }
    /* The queue drained: accepted again. */
    send_sleep(c2, 5, 0, 0);
    CHECK(h_recv(c2, 3000, &code, &id, NULL) == T(SLEEP_OK) && id == 5);
    gs_client_close(c);
    gs_client_close(c2);
}

/* BUSY hints follow the queued work, not a history of other jobs, and
 * differ between refused clients: after a 1.5 s job, a queue of one
 * 300 ms job running and two of 100 ms queued hints at most its 0.5 s;
 * 15 refused clients are told times spread over that window. */
static void test_busy_hints(const daemon_proc *d)
{
    gs_client *c = h_hello(d->sock);
    int code;
    uint32_t id;
    send_sleep(c, 1, 1500, 0);
    CHECK(h_recv(c, 5000, &code, &id, NULL) == T(SLEEP_OK));
    send_sleep(c, 2, 300, 0);
    h_sleep_ms(30);
    send_sleep(c, 3, 100, 0);
    send_sleep(c, 4, 100, 0);
    enum { N = 15 };
    gs_client *r[N];
    uint32_t hint[N];
    int busy = 0, distinct = 0;
    uint32_t hi = 0;
    for (int i = 0; i < N; i++) {
        r[i] = h_hello(d->sock);
        hint[i] = 0;
        send_sleep(r[i], 1, 10, 0);
        ProtobufCMessage *m = NULL;
        if (h_recv(r[i], 3000, &code, &id, &m) == T(BUSY)) {
            busy++;
            hint[i] = ((Gazesplat__Busy *)m)->retry_after_ms;
            hi = hint[i] > hi ? hint[i] : hi;
        }
        if (m)
            protobuf_c_message_free_unpacked(m, NULL);
    }
    for (int i = 0; i < N; i++) {
        int seen = 0;
        for (int k = 0; k < i; k++)
            seen |= hint[k] == hint[i];
        distinct += !seen;
    }
    printf("busy hints: %d refused, %d distinct values, highest %u ms\n", busy, distinct, hi);
    CHECK_MSG(busy == N, "%d of %d refused", busy, N);
    CHECK_MSG(hi <= 700, "hint %u ms for about 0.5 s of queued work", hi);
    CHECK_MSG(distinct >= 5, "only %d distinct hints among %d refused clients", distinct, N);
    for (uint32_t want = 2; want <= 4; want++)
        CHECK(h_recv(c, 3000, &code, &id, NULL) == T(SLEEP_OK) && id == want);
    for (int i = 0; i < N; i++)
        gs_client_close(r[i]);
    gs_client_close(c);
}

/* The idle timer counts from the last byte either way: a reply that took
 * longer than idle_timeout_ms is not followed by ERR_TIMEOUT. */
static void test_idle_after_long_reply(void)
{
    daemon_proc d;
    memset(&d, 0, sizeof d);
    const char *args[] = {"--set", "debug_requests=yes", "--set", "idle_timeout_ms=1000", NULL};
    CHECK(daemon_start_v(&d, bin, args) == 0);
    gs_client *c = h_hello(d.sock);
    int code;
    uint32_t id;
    send_sleep(c, 1, 1500, 0);
    CHECK(h_recv(c, 5000, &code, &id, NULL) == T(SLEEP_OK));
    h_sleep_ms(200);
    send_sleep(c, 2, 0, 0);
    int type = h_recv(c, 3000, &code, &id, NULL);
    CHECK_MSG(type == T(SLEEP_OK) && id == 2, "after a long reply: type %d code %d", type, code);
    /* Really idle: closed with ERR_TIMEOUT. */
    type = h_recv(c, 5000, &code, &id, NULL);
    CHECK_MSG(type == T(ERROR) && code == E(ERR_TIMEOUT), "idle: type %d code %d", type, code);
    gs_client_close(c);
    CHECK(daemon_stop(&d, SIGTERM, 5000) == 0);
}

static void test_cancel(const daemon_proc *d)
{
    gs_client *c = h_hello(d->sock);
    int code;
    uint32_t id;
    /* Running: stops at its next check. */
    long long t0 = h_now_ms();
    send_sleep(c, 10, 5000, 0);
    h_sleep_ms(100);
    send_cancel(c, 11, 10);
    int type = h_recv(c, 3000, &code, &id, NULL);
    long long dt = h_now_ms() - t0;
    CHECK_MSG(type == T(ERROR) && code == E(ERR_CANCELLED) && id == 10 && dt < 1000,
              "running cancel: type %d code %s id %u after %lld ms", type, gs_msg_error_name(code), id, dt);
    /* Queued: answered CANCELLED when dequeued; the one before it is not. */
    send_sleep(c, 20, 300, 0);
    send_sleep(c, 21, 300, 0);
    send_cancel(c, 22, 21);
    type = h_recv(c, 3000, &code, &id, NULL);
    CHECK_MSG(type == T(SLEEP_OK) && id == 20, "type %d id %u, want SLEEP_OK 20", type, id);
    type = h_recv(c, 3000, &code, &id, NULL);
    CHECK_MSG(type == T(ERROR) && code == E(ERR_CANCELLED) && id == 21, "type %d code %d id %u", type, code, id);
    /* Cancelling an unknown request is silent. */
    send_cancel(c, 23, 999);
    CHECK(h_health_on(c, 24));
    gs_client_close(c);
}

static void test_deadlines(const daemon_proc *d)
{
    gs_client *c = h_hello(d->sock);
    int code;
    uint32_t id;
    long long t0 = h_now_ms();
    send_sleep(c, 30, 3000, 200);
    int type = h_recv(c, 3000, &code, &id, NULL);
    long long dt = h_now_ms() - t0;
    CHECK_MSG(type == T(ERROR) && code == E(ERR_DEADLINE) && id == 30 && dt >= 150 && dt < 1500,
              "running deadline: type %d code %s after %lld ms", type, gs_msg_error_name(code), dt);
    /* Expired while queued: refused at dequeue without running. */
    send_sleep(c, 31, 400, 0);
    send_sleep(c, 32, 10, 100);
    type = h_recv(c, 3000, &code, &id, NULL);
    CHECK(type == T(SLEEP_OK) && id == 31);
    type = h_recv(c, 3000, &code, &id, NULL);
    CHECK_MSG(type == T(ERROR) && code == E(ERR_DEADLINE) && id == 32, "queued deadline: type %d code %d", type, code);
    gs_client_close(c);
}

static void test_conn_limits(const daemon_proc *d)
{
    gs_client *c = h_hello(d->sock);
    int code;
    uint32_t id;
    send_sleep(c, 40, 300, 0);
    send_sleep(c, 40, 10, 0);
    int type = h_recv(c, 3000, &code, &id, NULL);
    CHECK_MSG(type == T(ERROR) && code == E(ERR_DUPLICATE_ID) && id == 40, "duplicate id: type %d code %d", type, code);
    CHECK(h_recv(c, 3000, &code, &id, NULL) == T(SLEEP_OK) && id == 40);
    /* max_inflight 3 (queue_depth 2 + 1 running fit exactly). */
    send_sleep(c, 41, 300, 0);
    h_sleep_ms(100);
    send_sleep(c, 42, 10, 0);
    send_sleep(c, 43, 10, 0);
    send_sleep(c, 44, 10, 0);
    type = h_recv(c, 3000, &code, &id, NULL);
    CHECK_MSG(type == T(ERROR) && code == E(ERR_TOO_MANY_INFLIGHT) && id == 44, "inflight: type %d code %d id %u",
              type, code, id);
    for (int i = 0; i < 3; i++)
        CHECK(h_recv(c, 3000, &code, &id, NULL) == T(SLEEP_OK));
    gs_client_close(c);
}

/* 32 clients x 50 pipelined requests: every reply names an outstanding
 * request of its own connection, has the type that request calls for, and
 * comes exactly once. Replies to different requests may overtake each
 * other (HEALTH is answered by the loop, SLEEP by a worker). */
static int reply_fits(int kind, int type)
{
    return kind == 0 ? type == T(HEALTH_OK)
           : kind == 1 ? type == T(STATS_OK)
                       : type == T(SLEEP_OK) || type == T(BUSY);
}

static void test_many_clients(const daemon_proc *d)
{
    enum { NC = 32, NR = 50 };
    gs_client *cs[NC];
    int sent[NC], got[NC], bad = 0;
    static unsigned char answered[NC][NR];
    memset(answered, 0, sizeof answered);
    for (int i = 0; i < NC; i++) {
        cs[i] = h_hello(d->sock);
        sent[i] = got[i] = 0;
        if (!cs[i])
            bad++;
    }
    CHECK(bad == 0);
    if (bad)
        return;
    long long end = h_now_ms() + 30000;
    int done = 0;
    while (done < NC && h_now_ms() < end) {
        done = 0;
        for (int i = 0; i < NC; i++) {
            while (sent[i] < NR && sent[i] - got[i] < 2) { /* at most 2 outstanding */
                uint32_t rid = (uint32_t)(i * 1000 + sent[i]);
                int kind = sent[i] % 3;
                if (kind == 0) {
                    Gazesplat__HealthRequest r = GAZESPLAT__HEALTH_REQUEST__INIT;
                    gs_client_send(cs[i], T(HEALTH), NULL, rid, &r.base, NULL);
                } else if (kind == 1) {
                    Gazesplat__StatsRequest r = GAZESPLAT__STATS_REQUEST__INIT;
                    gs_client_send(cs[i], T(STATS), NULL, rid, &r.base, NULL);
                } else {
                    send_sleep(cs[i], rid, 0, 0);
                }
                sent[i]++;
            }
            struct pollfd p = {gs_client_fd(cs[i]), POLLIN, 0};
            if (got[i] < NR && poll(&p, 1, 0) > 0) {
                int code;
                uint32_t id = 0;
                int type = h_recv(cs[i], 2000, &code, &id, NULL);
                int k = (int)id - i * 1000;
                int ok = k >= 0 && k < sent[i] && !answered[i][k] && reply_fits(k % 3, type);
                if (ok)
                    answered[i][k] = 1;
                else if (bad++ < 5)
                    fprintf(stderr, "client %d: unexpected reply type %d id %u\n", i, type, id);
                got[i]++;
            }
            done += got[i] == NR;
        }
    }
    CHECK_MSG(done == NC && bad == 0, "%d of %d clients finished, %d bad replies", done, NC, bad);
    for (int i = 0; i < NC; i++)
        gs_client_close(cs[i]);
}

static void write_file(const char *path, const char *text)
{
    FILE *f = fopen(path, "w");
    fputs(text, f);
    fclose(f);
}

static uint32_t hello_queue_depth(const char *addr)
{
    gs_client *c = h_connect(addr);
    Gazesplat__HelloOk *ok = NULL;
    gs_error err;
    uint32_t q = 0;
    if (c && gs_client_hello(c, "t", NULL, 3000, &ok, &err) == GS_OK) {
        q = ok->limits ? ok->limits->queue_depth : 0;
        protobuf_c_message_free_unpacked(&ok->base, NULL);
    }
    gs_client_close(c);
    return q;
}

static void test_reload_and_drain(const daemon_proc *d0)
{
    (void)d0;
    daemon_proc d;
    memset(&d, 0, sizeof d);
    snprintf(d.dir, sizeof d.dir, "/tmp/gsd_test_XXXXXX");
    CHECK(mkdtemp(d.dir) != NULL);
    char conf[128];
    snprintf(conf, sizeof conf, "%s/gazesplatd.conf", d.dir);
    write_file(conf, "queue_depth = 4\ndebug_requests = yes\nlog_level = debug\n");
    const char *args[] = {"-c", conf, "--set", "drain_timeout_ms=5000", NULL};
    CHECK(daemon_start_v(&d, bin, args) == 0);
    CHECK(hello_queue_depth(d.sock) == 4);
    /* SIGHUP re-reads the file; a bad file keeps the old values. */
    write_file(conf, "queue_depth = 9\ndebug_requests = yes\n");
    kill(d.pid, SIGHUP);
    h_sleep_ms(300);
    CHECK_MSG(hello_queue_depth(d.sock) == 9, "queue_depth after SIGHUP: %u", hello_queue_depth(d.sock));
    write_file(conf, "queue_depth = -1\n");
    kill(d.pid, SIGHUP);
    h_sleep_ms(300);
    CHECK(hello_queue_depth(d.sock) == 9);
    CHECK(h_server_answers(d.sock));

    /* SIGTERM: the running request finishes, new work is refused, new
     * connections are not accepted, the daemon exits 0. */
    gs_client *c = h_hello(d.sock);
    int code;
    uint32_t id;
    send_sleep(c, 1, 600, 0);
    h_sleep_ms(100);
    kill(d.pid, SIGTERM);
    h_sleep_ms(100);
    send_sleep(c, 2, 10, 0);
    int type = h_recv(c, 3000, &code, &id, NULL);
    CHECK_MSG(type == T(ERROR) && code == E(ERR_SHUTTING_DOWN) && id == 2, "during drain: type %d code %d", type, code);
    CHECK(h_health_on(c, 3));
    gs_client *late = NULL;
    CHECK(gs_client_connect(d.sock, 500, &late, NULL) != GS_OK);
    type = h_recv(c, 3000, &code, &id, NULL);
    CHECK_MSG(type == T(SLEEP_OK) && id == 1, "in-flight request during drain: type %d id %u", type, id);
    gs_client_close(c);
    int st = daemon_stop(&d, 0, 5000);
    CHECK_MSG(st == 0, "exit status %d after drain", st);
    struct stat sb;
    CHECK_MSG(stat(d.sock, &sb) != 0, "socket %s left behind", d.sock);
    if (gs_test_failures)
        daemon_dump_log(&d);
}

static int free_port(void)
{
    int fd = socket(AF_INET, SOCK_STREAM, 0);
    struct sockaddr_in sa;
    memset(&sa, 0, sizeof sa);
    sa.sin_family = AF_INET;
    sa.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    socklen_t len = sizeof sa;
    bind(fd, (struct sockaddr *)&sa, sizeof sa);
    getsockname(fd, (struct sockaddr *)&sa, &len);
    close(fd);
    return ntohs(sa.sin_port);
}

static int hello_with(const char *addr, const char *token, char *msg, size_t cap)
{
    gs_client *c = h_connect(addr);
    gs_error err;
    gs_error_clear(&err);
    int r = c ? gs_client_hello(c, "t", token, 3000, NULL, &err) : -1;
    snprintf(msg, cap, "%s", err.msg);
    gs_client_close(c);
    return r;
}

static void test_tcp_token(void)
{
    daemon_proc d;
    memset(&d, 0, sizeof d);
    char tcp[64], addr[80], msg[300];
    int port = free_port();
    snprintf(tcp, sizeof tcp, "127.0.0.1:%d", port);
    snprintf(addr, sizeof addr, "tcp:%s", tcp);
    const char *args[] = {"--tcp", tcp, "--set", "token=s3cret-token", NULL};
    CHECK(daemon_start_v(&d, bin, args) == 0);
    CHECK_MSG(hello_with(addr, "s3cret-token", msg, sizeof msg) == GS_OK, "%s", msg);
    CHECK(hello_with(addr, NULL, msg, sizeof msg) != GS_OK && strstr(msg, "ERR_AUTH"));
    CHECK(hello_with(addr, "s3cret-toke", msg, sizeof msg) != GS_OK && strstr(msg, "ERR_AUTH"));
    CHECK(hello_with(addr, "s3cret-token!", msg, sizeof msg) != GS_OK && strstr(msg, "ERR_AUTH"));
    /* The Unix socket relies on its file mode instead. */
    CHECK(hello_with(d.sock, NULL, msg, sizeof msg) == GS_OK);
    struct stat sb;
    CHECK(stat(d.sock, &sb) == 0 && (sb.st_mode & 0777) == 0660);
    CHECK(daemon_stop(&d, SIGTERM, 5000) == 0);

    /* Binding a non-loopback address needs tcp_allow_remote. */
    daemon_proc r;
    memset(&r, 0, sizeof r);
    snprintf(tcp, sizeof tcp, "0.0.0.0:%d", free_port());
    const char *rargs[] = {"--tcp", tcp, NULL};
    CHECK(daemon_start_v(&r, bin, rargs) != 0);
}

int main(int argc, char **argv)
{
    if (argc != 2) {
        fprintf(stderr, "usage: %s GAZESPLATD\n", argv[0]);
        return 2;
    }
    bin = argv[1];
    signal(SIGPIPE, SIG_IGN);
    daemon_proc d;
    memset(&d, 0, sizeof d);
    const char *args[] = {"--set", "workers=1", "--set", "queue_depth=2", "--set", "max_inflight=3",
                          "--set", "debug_requests=yes", "--set", "max_connections=64", NULL};
    if (daemon_start_v(&d, bin, args) != 0) {
        daemon_dump_log(&d);
        return 1;
    }
    test_busy(&d);
    test_busy_hints(&d);
    test_cancel(&d);
    test_deadlines(&d);
    test_conn_limits(&d);
    test_many_clients(&d);
    CHECK(h_server_answers(d.sock));
    CHECK(daemon_stop(&d, SIGTERM, 5000) == 0);
    if (gs_test_failures)
        daemon_dump_log(&d);
    test_reload_and_drain(&d);
    test_tcp_token();
    test_idle_after_long_reply();
    GS_TEST_END();
}
