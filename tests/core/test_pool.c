#define _POSIX_C_SOURCE 200809L /* nanosleep */
#include "gazesplat/pool.h"
#include "gs_test.h"

#include <pthread.h>
#include <stdatomic.h>
#include <string.h>
#include <time.h>

typedef struct {
    int *out;
    atomic_int calls;
    int max_worker;
    int threads;
} ctx_t;

static void square(void *vctx, int task, int worker)
{
    ctx_t *c = vctx;
    c->out[task] = task * task;
    if (worker < 0 || worker >= c->threads)
        c->max_worker = worker;
    atomic_fetch_add(&c->calls, 1);
}

static void nap_us(long us)
{
    struct timespec ts = {0, us * 1000};
    nanosleep(&ts, NULL);
}

/* Several threads calling gs_pool_for on one pool: the calls are
 * serialized and each sees all of its own tasks done. */
typedef struct {
    gs_pool *pool;
    int bad;
} caller_arg;

static void *caller(void *varg)
{
    caller_arg *a = varg;
    enum { M = 777 };
    int out[M];
    for (int round = 0; round < 100; round++) {
        ctx_t c = {out, 0, 0, gs_pool_threads(a->pool)};
        memset(out, 0xff, sizeof out);
        int n = (round * 37) % M + 1;
        gs_pool_for(a->pool, n, square, &c);
        for (int i = 0; i < n; i++)
            a->bad += out[i] != i * i;
        a->bad += atomic_load(&c.calls) != n;
    }
    return NULL;
}

int main(void)
{
    enum { N = 10007 };
    static int out[N];
    /* Spin times: sleep at once, the default, and long enough that the
     * workers do not sleep between these jobs; naps between some jobs, so
     * both the spinning and the sleeping hand-over are taken. */
    const int spins[] = {0, GS_POOL_DEFAULT_SPIN_US, 20000};
    for (int threads = 1; threads <= 4; threads++) {
        for (int sp = 0; sp < 3; sp++) {
            gs_pool *p = gs_pool_create(threads);
            CHECK(p != NULL);
            CHECK_EQ_INT(gs_pool_threads(p), threads);
            gs_pool_set_spin_us(p, spins[sp]);
            for (int round = 0; round < 50; round++) {
                if (round % 7 == 3)
                    nap_us(round % 2 ? 50 : 500);
                ctx_t c = {out, 0, 0, threads};
                memset(out, 0xff, sizeof out);
                int n = round == 0 ? 0 : (round * 197) % N + 1;
                gs_pool_for(p, n, square, &c);
                CHECK_EQ_INT(atomic_load(&c.calls), n);
                CHECK_EQ_INT(c.max_worker, 0);
                int bad = 0;
                for (int i = 0; i < n; i++)
                    bad += out[i] != i * i;
                CHECK_EQ_INT(bad, 0);
            }
            gs_pool_destroy(p); /* with the long spin, workers are still spinning */
        }
    }
    for (int sp = 0; sp < 3; sp++) {
        gs_pool *p = gs_pool_create(2);
        gs_pool_set_spin_us(p, spins[sp]);
        caller_arg a[3] = {{p, 0}, {p, 0}, {p, 0}};
        pthread_t th[3];
        for (int k = 0; k < 3; k++)
            CHECK(pthread_create(&th[k], NULL, caller, &a[k]) == 0);
        for (int k = 0; k < 3; k++) {
            pthread_join(th[k], NULL);
            CHECK_EQ_INT(a[k].bad, 0);
        }
        gs_pool_destroy(p);
    }
    gs_pool_set_spin_us(NULL, 10); /* a NULL pool is ignored */
    /* NULL pool runs inline with one thread. */
    ctx_t c = {out, 0, 0, 1};
    gs_pool_for(NULL, 10, square, &c);
    CHECK_EQ_INT(atomic_load(&c.calls), 10);
    CHECK_EQ_INT(gs_pool_threads(NULL), 1);
    gs_pool *p = gs_pool_create(0);
    CHECK(p != NULL && gs_pool_threads(p) >= 1);
    gs_pool_destroy(p);
    gs_pool_destroy(NULL);
    GS_TEST_END();
}
