/* ev: the daemon's event loop, a thin layer over epoll (after Redis ae.c).
 *
 * A watch is a struct the caller owns (usually embedded in a connection):
 * its fd, the events of interest and a callback. The loop never allocates
 * per watch. One periodic tick drives every timeout (header, idle,
 * deadlines, watchdog, cache flush), so there is no timer heap.
 *
 * Single-threaded: every call except ev_wake is made from the loop thread.
 * ev_wake may be called from any thread (worker completions) and makes the
 * loop run its wake callback. */
#ifndef GS_EV_H
#define GS_EV_H

#include <stdint.h>

enum { EV_READ = 1, EV_WRITE = 2, EV_HUP = 4 };

typedef struct ev_loop ev_loop;
typedef struct ev_watch ev_watch;

/* Called with the events that fired: EV_READ, EV_WRITE (when in the
 * mask) and EV_HUP (hang-up or error, always reported, even while reading
 * is paused, so the owner always sees a dead peer). */
typedef void (*ev_fn)(ev_loop *loop, ev_watch *w, int events);
typedef void (*ev_tick_fn)(ev_loop *loop, void *ctx);

struct ev_watch {
    int fd;
    int mask;      /* current interest, EV_READ | EV_WRITE */
    ev_fn fn;
    void *ctx;
};

/* Creates a loop; wake_fn(loop, ctx) runs in the loop thread after any
 * ev_wake. Returns NULL on failure (errno set). */
ev_loop *ev_create(ev_tick_fn wake_fn, void *ctx);
void ev_destroy(ev_loop *loop);

/* Starts watching w->fd for mask. Returns 0 or -1 (errno). */
int ev_add(ev_loop *loop, ev_watch *w, int fd, int mask, ev_fn fn, void *ctx);
/* Changes the interest; a no-op when unchanged. */
int ev_set(ev_loop *loop, ev_watch *w, int mask);
/* Stops watching (before closing the fd). */
void ev_del(ev_loop *loop, ev_watch *w);

/* tick(loop, ctx) every period_ms (approximately; never early by more
 * than a millisecond). */
void ev_set_tick(ev_loop *loop, int period_ms, ev_tick_fn tick, void *ctx);

/* after(loop, ctx) once after each batch of events: the place to free
 * what callbacks closed (a watch must stay valid until the batch ends). */
void ev_set_after(ev_loop *loop, ev_tick_fn after, void *ctx);

/* Thread-safe: makes the loop call its wake callback soon. */
void ev_wake(ev_loop *loop);

/* Runs until ev_stop. Returns 0, or -1 if epoll_wait failed. */
int ev_run(ev_loop *loop);
void ev_stop(ev_loop *loop);

/* Monotonic milliseconds. */
int64_t ev_now_ms(void);

#endif
