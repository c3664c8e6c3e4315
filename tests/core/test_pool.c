#include "gazesplat/pool.h"
#include "gs_test.h"

#include <stdatomic.h>
#include <string.h>

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

int main(void)
{
    enum { N = 10007 };
    static int out[N];
    for (int threads = 1; threads <= 4; threads++) {
        gs_pool *p = gs_pool_create(threads);
        CHECK(p != NULL);
        CHECK_EQ_INT(gs_pool_threads(p), threads);
        for (int round = 0; round < 50; round++) {
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
        gs_pool_destroy(p);
    }
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
