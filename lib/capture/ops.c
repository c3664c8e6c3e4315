/* The device operations of the real kernel, behind gs_cap_ops. */
#define _GNU_SOURCE
#include <errno.h>
#include <fcntl.h>
#include <sys/ioctl.h>
#include <sys/mman.h>
#include <time.h>
#include <unistd.h>

#include "gazesplat/capture.h"
#include "gazesplat/clock.h"

static int sys_open(void *ctx, const char *path, int flags)
{
    (void)ctx;
    int fd = open(path, flags | O_CLOEXEC);
    return fd < 0 ? -errno : fd;
}

static int sys_close(void *ctx, int fd)
{
    (void)ctx;
    return close(fd) < 0 ? -errno : 0;
}

static int sys_ioctl(void *ctx, int fd, unsigned long request, void *arg)
{
    (void)ctx;
    return ioctl(fd, request, arg) < 0 ? -errno : 0;
}

static void *sys_mmap(void *ctx, int fd, size_t len, off_t offset, int *err_no)
{
    (void)ctx;
    void *p = mmap(NULL, len, PROT_READ | PROT_WRITE, MAP_SHARED, fd, offset);
    if (p == MAP_FAILED) {
        *err_no = errno;
        return NULL;
    }
    return p;
}

static int sys_munmap(void *ctx, void *addr, size_t len)
{
    (void)ctx;
    return munmap(addr, len) < 0 ? -errno : 0;
}

static int sys_poll(void *ctx, struct pollfd *fds, nfds_t nfds, int timeout_ms)
{
    (void)ctx;
    int n = poll(fds, nfds, timeout_ms);
    return n < 0 ? -errno : n;
}

static ssize_t sys_write(void *ctx, int fd, const void *buf, size_t len)
{
    (void)ctx;
    ssize_t n = write(fd, buf, len);
    return n < 0 ? -errno : n;
}

static int64_t sys_now_ns(void *ctx)
{
    (void)ctx;
    return gs_clock_ns();
}

static void sys_sleep_ns(void *ctx, int64_t ns)
{
    (void)ctx;
    if (ns <= 0)
        return;
    struct timespec ts = {(time_t)(ns / 1000000000), (long)(ns % 1000000000)};
    while (nanosleep(&ts, &ts) < 0 && errno == EINTR) {
    }
}

static const gs_cap_ops system_ops = {
    NULL, sys_open, sys_close, sys_ioctl, sys_mmap, sys_munmap,
    sys_poll, sys_write, sys_now_ns, sys_sleep_ns,
};

const gs_cap_ops *gs_cap_ops_system(void)
{
    return &system_ops;
}
