/* Thread pool. A job is (fn, ctx, ntasks); tasks are claimed with an
 * atomic counter so a slow worker never holds up the rest, and the caller
 * works as worker 0.
 *
 * Between jobs a worker first spins on the job generation for the pool's
 * spin time, then sleeps on a condition variable; the caller waits for the
 * workers the same way. Waking a sleeping thread costs a system call and,
 * on a virtual machine, the hypervisor's wake-up of a halted virtual CPU
 * (tens of microseconds and more), paid twice per job; the rasterizer and
 * the network run a few jobs per call back to back, so a short spin keeps
 * the threads hot across them. Spinning uses `pause`, and the time it may
 * burn is bounded per job. */
#define _POSIX_C_SOURCE 200809L /* clock_gettime */
#include "gazesplat/clock.h"
#include "gazesplat/pool.h"

#include <pthread.h>
#include <stdatomic.h>
#include <stdlib.h>
#include <time.h>
#include <unistd.h>

#if defined(__x86_64__) || defined(__i386__)
#include <immintrin.h>
#define cpu_relax() _mm_pause()
#else
#define cpu_relax() ((void)0)
#endif

struct gs_pool {
    int nthreads;
    pthread_t *threads;
    pthread_mutex_t call_lock; /* serializes gs_pool_for callers */
    pthread_mutex_t lock;
    pthread_cond_t wake;       /* a new job or shutdown */
    pthread_cond_t done;       /* the last worker left the job */
    atomic_ulong generation;   /* bumped per job (under lock) */
    atomic_int busy;           /* workers still inside the job */
    atomic_int shutdown;
    int sleepers;              /* workers in cond_wait (under lock) */
    int caller_sleeping;       /* the caller in cond_wait on done (under lock) */
    atomic_long spin_ns;       /* spin before sleeping, nanoseconds */
    gs_pool_fn fn;
    void *ctx;
    int ntasks;
    atomic_int next;
};

typedef struct {
    gs_pool *pool;
    int index;
} worker_arg;

/* Spins until cond(p) holds or spin_ns have passed; returns cond(p). The
 * clock is read every 64 pauses. */
#define SPIN_UNTIL(p, cond)                                                           \
    do {                                                                              \
        long spin_ = atomic_load_explicit(&(p)->spin_ns, memory_order_relaxed);      \
        if (spin_ > 0 && !(cond)) {                                                   \
            long long end_ = gs_clock_ns() + spin_;                                   \
            for (unsigned k_ = 1; !(cond); k_++) {                                    \
                cpu_relax();                                                          \
                if (k_ % 64 == 0 && gs_clock_ns() >= end_)                            \
                    break;                                                            \
            }                                                                         \
        }                                                                             \
    } while (0)

static void run_tasks(gs_pool *p, int worker)
{
    for (;;) {
        int t = atomic_fetch_add_explicit(&p->next, 1, memory_order_relaxed);
        if (t >= p->ntasks)
            break;
        p->fn(p->ctx, t, worker);
    }
}

static void *worker_main(void *arg)
{
    worker_arg *wa = arg;
    gs_pool *p = wa->pool;
    int index = wa->index;
    unsigned long seen = 0;
    free(wa);
    for (;;) {
#define NEW_JOB                                                                  \
    (atomic_load_explicit(&p->generation, memory_order_acquire) != seen ||      \
     atomic_load_explicit(&p->shutdown, memory_order_acquire))
        SPIN_UNTIL(p, NEW_JOB);
        if (!NEW_JOB) {
            pthread_mutex_lock(&p->lock);
            p->sleepers++;
            while (!NEW_JOB)
                pthread_cond_wait(&p->wake, &p->lock);
            p->sleepers--;
            pthread_mutex_unlock(&p->lock);
        }
#undef NEW_JOB
        if (atomic_load_explicit(&p->shutdown, memory_order_acquire))
            break;
        seen = atomic_load_explicit(&p->generation, memory_order_acquire);
        run_tasks(p, index);
        if (atomic_fetch_sub_explicit(&p->busy, 1, memory_order_acq_rel) == 1) {
            pthread_mutex_lock(&p->lock);
            if (p->caller_sleeping)
                pthread_cond_signal(&p->done);
            pthread_mutex_unlock(&p->lock);
        }
    }
    return NULL;
}

gs_pool *gs_pool_create(int nthreads)
{
    long cpus = sysconf(_SC_NPROCESSORS_ONLN);
    if (nthreads <= 0)
        nthreads = cpus > 0 ? (int)cpus : 1;
    if (nthreads > GS_POOL_MAX_THREADS)
        nthreads = GS_POOL_MAX_THREADS;
    gs_pool *p = calloc(1, sizeof *p);
    if (!p)
        return NULL;
    p->nthreads = nthreads;
    pthread_mutex_init(&p->call_lock, NULL);
    pthread_mutex_init(&p->lock, NULL);
    pthread_cond_init(&p->wake, NULL);
    pthread_cond_init(&p->done, NULL);
    atomic_init(&p->generation, 0);
    atomic_init(&p->busy, 0);
    atomic_init(&p->shutdown, 0);
    /* More threads than CPUs: a spinning thread would hold a CPU that
     * another of them needs, so they sleep at once. */
    atomic_init(&p->spin_ns, cpus > 0 && nthreads > cpus ? 0 : (long)GS_POOL_DEFAULT_SPIN_US * 1000);
    atomic_init(&p->next, 0);
    if (nthreads > 1) {
        p->threads = calloc((size_t)nthreads - 1, sizeof *p->threads);
        if (!p->threads) {
            gs_pool_destroy(p);
            return NULL;
        }
        for (int i = 1; i < nthreads; i++) {
            worker_arg *wa = malloc(sizeof *wa);
            if (wa) {
                wa->pool = p;
                wa->index = i;
            }
            if (!wa || pthread_create(&p->threads[i - 1], NULL, worker_main, wa) != 0) {
                free(wa);
                p->nthreads = i; /* only threads 1..i-1 exist */
                gs_pool_destroy(p);
                return NULL;
            }
        }
    }
    return p;
}

void gs_pool_destroy(gs_pool *p)
{
    if (!p)
        return;
    pthread_mutex_lock(&p->lock);
    atomic_store_explicit(&p->shutdown, 1, memory_order_release);
    pthread_cond_broadcast(&p->wake);
    pthread_mutex_unlock(&p->lock);
    for (int i = 1; i < p->nthreads; i++)
        pthread_join(p->threads[i - 1], NULL);
    free(p->threads);
    pthread_cond_destroy(&p->done);
    pthread_cond_destroy(&p->wake);
    pthread_mutex_destroy(&p->lock);
    pthread_mutex_destroy(&p->call_lock);
    free(p);
}

int gs_pool_threads(const gs_pool *p)
{
    return p ? p->nthreads : 1;
}

void gs_pool_set_spin_us(gs_pool *p, int us)
{
    if (p)
        atomic_store_explicit(&p->spin_ns, us > 0 ? (long)us * 1000 : 0, memory_order_relaxed);
}

void gs_pool_for(gs_pool *p, int ntasks, gs_pool_fn fn, void *ctx)
{
    if (ntasks <= 0)
        return;
    if (!p || p->nthreads == 1 || ntasks == 1) {
        for (int t = 0; t < ntasks; t++)
            fn(ctx, t, 0);
        return;
    }
    pthread_mutex_lock(&p->call_lock);
    pthread_mutex_lock(&p->lock);
    p->fn = fn;
    p->ctx = ctx;
    p->ntasks = ntasks;
    atomic_store_explicit(&p->next, 0, memory_order_relaxed);
    atomic_store_explicit(&p->busy, p->nthreads - 1, memory_order_relaxed);
    /* The release publishes the job to workers spinning on the generation. */
    atomic_fetch_add_explicit(&p->generation, 1, memory_order_release);
    if (p->sleepers)
        pthread_cond_broadcast(&p->wake);
    pthread_mutex_unlock(&p->lock);

    run_tasks(p, 0);

#define JOB_DONE (atomic_load_explicit(&p->busy, memory_order_acquire) == 0)
    SPIN_UNTIL(p, JOB_DONE);
    if (!JOB_DONE) {
        pthread_mutex_lock(&p->lock);
        p->caller_sleeping = 1;
        while (!JOB_DONE)
            pthread_cond_wait(&p->done, &p->lock);
        p->caller_sleeping = 0;
        pthread_mutex_unlock(&p->lock);
    }
#undef JOB_DONE
    pthread_mutex_unlock(&p->call_lock);
}
