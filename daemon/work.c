/* The compute queue: a bounded FIFO of jobs and the worker threads that
 * run them. A full queue is refused at push time (the loop answers BUSY):
 * nothing ever waits on the loop thread. */
#include <stdlib.h>
#include <string.h>

#include "log.h"
#include "daemon.h"
#include "sink.h"

typedef struct worker_arg {
    gsd_server *srv;
    int index;
} worker_arg;

static gsd_job *pop(gsd_work *w)
{
    gsd_job *j = w->head;
    w->head = j->qnext;
    if (!w->head)
        w->tail = NULL;
    w->length--;
    return j;
}

/* How far a worker looks past the head for a REDIRECT of a subject whose
 * render it keeps, and how often the head may be passed over. */
#define PREFER_WINDOW 8

/* The next job for worker wk: with several workers, a REDIRECT of a
 * subject this worker rendered lately (it renders incrementally here)
 * among the first PREFER_WINDOW jobs, unless the head was passed over
 * often enough; otherwise the head. Order within a connection does not
 * matter (replies carry request ids). */
static gsd_job *pop_for(gsd_work *w, const gsd_worker *wk)
{
    if (w->planned < 2 || !wk || w->head->skips >= 2 * w->planned)
        return pop(w);
    gsd_job *prev = w->head;
    for (int k = 1; k < PREFER_WINDOW && prev->qnext; k++, prev = prev->qnext) {
        gsd_job *j = prev->qnext;
        if (!gsd_worker_prefers(wk, j))
            continue;
        prev->qnext = j->qnext;
        if (w->tail == j)
            w->tail = prev;
        w->length--;
        w->head->skips++;
        return j;
    }
    return pop(w);
}

static void *worker_main(void *p)
{
    worker_arg a = *(worker_arg *)p;
    free(p);
    gsd_work *w = &a.srv->work;
    gsd_worker *wk = gsd_worker_create(a.srv, a.index);
    pthread_mutex_lock(&w->mu);
    for (;;) {
        while (!w->head && !w->stopping)
            pthread_cond_wait(&w->cv, &w->mu);
        if (!w->head)
            break; /* stopping with an empty queue */
        gsd_job *j = pop_for(w, wk);
        w->running++;
        w->run_start[a.index] = ev_now_ms();
        w->run_est[a.index] = j->est_ms;
        pthread_mutex_unlock(&w->mu);
        if (wk)
            gsd_worker_run(wk, j);
        else
            gsd_emit_error(j, GAZESPLAT__ERROR_CODE__ERR_INTERNAL, "worker failed to start");
        pthread_mutex_lock(&w->mu);
        w->running--;
        w->run_start[a.index] = 0;
    }
    pthread_mutex_unlock(&w->mu);
    gsd_worker_destroy(wk);
    return NULL;
}

int gsd_work_start(gsd_server *s, int nworkers, int depth)
{
    gsd_work *w = &s->work;
    pthread_mutex_init(&w->mu, NULL);
    pthread_cond_init(&w->cv, NULL);
    w->depth = depth;
    w->planned = nworkers; /* before any worker reads it */
    w->threads = calloc((size_t)nworkers, sizeof *w->threads);
    if (!w->threads)
        return -1;
    for (int i = 0; i < nworkers; i++) {
        worker_arg *a = malloc(sizeof *a);
        if (!a)
            return -1;
        a->srv = s;
        a->index = i;
        if (pthread_create(&w->threads[i], NULL, worker_main, a) != 0) {
            free(a);
            return -1;
        }
        w->nworkers++;
    }
    return 0;
}

int gsd_work_push(gsd_server *s, gsd_job *job)
{
    gsd_work *w = &s->work;
    pthread_mutex_lock(&w->mu);
    int ok = !w->stopping && w->length < w->depth;
    if (ok) {
        job->qnext = NULL;
        if (w->tail)
            w->tail->qnext = job;
        else
            w->head = job;
        w->tail = job;
        w->length++;
        pthread_cond_signal(&w->cv);
    }
    pthread_mutex_unlock(&w->mu);
    return ok ? 0 : -1;
}

void gsd_work_lengths(gsd_server *s, int *length, int *running)
{
    gsd_work *w = &s->work;
    pthread_mutex_lock(&w->mu);
    *length = w->length;
    *running = w->running;
    pthread_mutex_unlock(&w->mu);
}

void gsd_work_backlog(gsd_server *s, int64_t now, double *first, double *total)
{
    gsd_work *w = &s->work;
    double f = -1, t = 0;
    pthread_mutex_lock(&w->mu);
    for (gsd_job *j = w->head; j; j = j->qnext)
        t += j->est_ms;
    for (int i = 0; i < w->nworkers && i < 64; i++) {
        if (!w->run_start[i])
            continue;
        /* A job past its estimate is taken to end within a tenth more. */
        double left = (double)w->run_est[i] - (double)(now - w->run_start[i]);
        if (left < 0.1 * w->run_est[i])
            left = 0.1 * w->run_est[i];
        t += left;
        if (f < 0 || left < f)
            f = left;
    }
    pthread_mutex_unlock(&w->mu);
    *first = f < 0 ? 0 : f;
    *total = t;
}

void gsd_work_set_depth(gsd_server *s, int depth)
{
    pthread_mutex_lock(&s->work.mu);
    s->work.depth = depth;
    pthread_mutex_unlock(&s->work.mu);
}

void gsd_work_stop(gsd_server *s)
{
    gsd_work *w = &s->work;
    if (!w->threads)
        return;
    pthread_mutex_lock(&w->mu);
    w->stopping = 1;
    /* Queued jobs are answered here; running ones see their stop flag. */
    while (w->head) {
        gsd_job *j = pop(w);
        gsd_emit_error(j, GAZESPLAT__ERROR_CODE__ERR_SHUTTING_DOWN, "server stopped");
    }
    pthread_cond_broadcast(&w->cv);
    pthread_mutex_unlock(&w->mu);
    for (int i = 0; i < w->nworkers; i++)
        pthread_join(w->threads[i], NULL);
    free(w->threads);
    w->threads = NULL;
    pthread_mutex_destroy(&w->mu);
    pthread_cond_destroy(&w->cv);
}
