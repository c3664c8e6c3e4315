/* ev: epoll event loop with one periodic tick and a cross-thread wake-up. */
#define _GNU_SOURCE
#include "ev.h"

#include <errno.h>
#include <stdint.h>
#include <stdlib.h>
#include <sys/epoll.h>
#include <sys/eventfd.h>
#include <time.h>
#include <unistd.h>

#include "gazesplat/clock.h"

#define MAX_EVENTS 64

struct ev_loop {
    int epfd;
    ev_watch wake_watch;
    ev_tick_fn wake_fn;
    void *wake_ctx;
    int tick_ms;
    int64_t next_tick;
    ev_tick_fn tick;
    void *tick_ctx;
    ev_tick_fn after;
    void *after_ctx;
    int stop;
};

int64_t ev_now_ms(void)
{
    return gs_clock_ms();
}

static void on_wake(ev_loop *loop, ev_watch *w, int events)
{
    (void)events;
    uint64_t v;
    while (read(w->fd, &v, sizeof v) > 0) {
    }
    if (loop->wake_fn)
        loop->wake_fn(loop, loop->wake_ctx);
}

ev_loop *ev_create(ev_tick_fn wake_fn, void *ctx)
{
    ev_loop *loop = calloc(1, sizeof *loop);
    if (!loop)
        return NULL;
    loop->epfd = epoll_create1(EPOLL_CLOEXEC);
    int efd = eventfd(0, EFD_CLOEXEC | EFD_NONBLOCK);
    loop->wake_fn = wake_fn;
    loop->wake_ctx = ctx;
    if (loop->epfd < 0 || efd < 0 || ev_add(loop, &loop->wake_watch, efd, EV_READ, on_wake, NULL) != 0) {
        int e = errno;
        if (efd >= 0)
            close(efd);
        if (loop->epfd >= 0)
            close(loop->epfd);
        free(loop);
        errno = e;
        return NULL;
    }
    return loop;
}

void ev_destroy(ev_loop *loop)
{
    if (!loop)
        return;
    close(loop->wake_watch.fd);
    close(loop->epfd);
    free(loop);
}

static uint32_t epoll_mask(int mask)
{
    return (mask & EV_READ ? EPOLLIN | EPOLLRDHUP : 0) | (mask & EV_WRITE ? EPOLLOUT : 0);
}

int ev_add(ev_loop *loop, ev_watch *w, int fd, int mask, ev_fn fn, void *ctx)
{
    w->fd = fd;
    w->mask = mask;
    w->fn = fn;
    w->ctx = ctx;
    struct epoll_event ev = {.events = epoll_mask(mask), .data.ptr = w};
    return epoll_ctl(loop->epfd, EPOLL_CTL_ADD, fd, &ev);
}

int ev_set(ev_loop *loop, ev_watch *w, int mask)
{
    if (w->mask == mask)
        return 0;
    w->mask = mask;
    struct epoll_event ev = {.events = epoll_mask(mask), .data.ptr = w};
    return epoll_ctl(loop->epfd, EPOLL_CTL_MOD, w->fd, &ev);
}

void ev_del(ev_loop *loop, ev_watch *w)
{
    epoll_ctl(loop->epfd, EPOLL_CTL_DEL, w->fd, NULL);
    w->mask = 0;
}

void ev_set_tick(ev_loop *loop, int period_ms, ev_tick_fn tick, void *ctx)
{
    loop->tick_ms = period_ms;
    loop->tick = tick;
    loop->tick_ctx = ctx;
    loop->next_tick = ev_now_ms() + period_ms;
}

void ev_set_after(ev_loop *loop, ev_tick_fn after, void *ctx)
{
    loop->after = after;
    loop->after_ctx = ctx;
}

void ev_wake(ev_loop *loop)
{
    uint64_t one = 1;
    ssize_t r = write(loop->wake_watch.fd, &one, sizeof one);
    (void)r; /* EAGAIN means a wake-up is already pending */
}

void ev_stop(ev_loop *loop)
{
    loop->stop = 1;
}

int ev_run(ev_loop *loop)
{
    struct epoll_event evs[MAX_EVENTS];
    loop->stop = 0;
    while (!loop->stop) {
        int timeout = -1;
        if (loop->tick) {
            int64_t left = loop->next_tick - ev_now_ms();
            timeout = left < 0 ? 0 : (int)left;
        }
        int n = epoll_wait(loop->epfd, evs, MAX_EVENTS, timeout);
        if (n < 0 && errno != EINTR)
            return -1;
        for (int i = 0; i < n && !loop->stop; i++) {
            ev_watch *w = evs[i].data.ptr;
            uint32_t e = evs[i].events;
            /* Hang-ups and errors arrive even when reading is paused. */
            int fired = (e & (EPOLLIN | EPOLLRDHUP) && w->mask & EV_READ ? EV_READ : 0) |
                        (e & EPOLLOUT && w->mask & EV_WRITE ? EV_WRITE : 0) |
                        (e & (EPOLLHUP | EPOLLERR) ? EV_HUP : 0);
            if (fired)
                w->fn(loop, w, fired);
        }
        if (loop->after)
            loop->after(loop, loop->after_ctx);
        if (loop->tick && ev_now_ms() >= loop->next_tick) {
            loop->next_tick = ev_now_ms() + loop->tick_ms;
            loop->tick(loop, loop->tick_ctx);
        }
    }
    return 0;
}
