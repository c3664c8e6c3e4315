/* gs_pool: a fixed set of worker threads running parallel-for loops.
 *
 * Determinism is the caller's contract: a task must write only to outputs it
 * owns, so results do not depend on which worker ran which task or on the
 * thread count. The pool hands out tasks dynamically (an atomic counter). */
#ifndef GAZESPLAT_POOL_H
#define GAZESPLAT_POOL_H

#ifdef __cplusplus
extern "C" {
#endif

typedef struct gs_pool gs_pool;

/* Largest thread count a pool accepts. */
#define GS_POOL_MAX_THREADS 256

/* Creates a pool of nthreads workers (the calling thread counts as one).
 * nthreads <= 0 means one per online CPU. Returns NULL when out of memory
 * or when threads cannot be started. */
gs_pool *gs_pool_create(int nthreads);
void gs_pool_destroy(gs_pool *pool);

/* Between jobs, workers (and the caller waiting for them) spin for up to
 * this many microseconds before they sleep, so jobs that follow each other
 * closely start without a wake-up (a system call, and on a virtual machine
 * the hypervisor's wake-up of a halted CPU). A pool with more threads than
 * online CPUs starts at 0 (a spinning thread would hold a CPU another one
 * needs). gs_pool_set_spin_us changes it (0: sleep at once, the lowest CPU
 * use when jobs are rare). */
#define GS_POOL_DEFAULT_SPIN_US 200
void gs_pool_set_spin_us(gs_pool *pool, int us);

/* Number of threads, including the caller. A NULL pool has 1. */
int gs_pool_threads(const gs_pool *pool);

/* fn(ctx, task, worker) for task in [0, ntasks); worker in [0, threads).
 * Returns when every task has finished. A NULL pool runs the loop inline.
 * Calls from several threads on one pool are serialized. Not re-entrant:
 * fn must not call gs_pool_for on the same pool. */
typedef void (*gs_pool_fn)(void *ctx, int task, int worker);
void gs_pool_for(gs_pool *pool, int ntasks, gs_pool_fn fn, void *ctx);

#ifdef __cplusplus
}
#endif
#endif
