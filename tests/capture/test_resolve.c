/* Camera choice by USB identity through a fake sysfs tree: two cameras of
 * the same model told apart by serial, the capture node preferred over the
 * metadata node, malformed ids refused; and a capture opened by a usb:
 * spec looks the camera up at every open (plugged in after the start, back
 * as another videoN). */
#define _GNU_SOURCE
#include <limits.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include "gazesplat/capture.h"
#include "gs_test.h"

static char root[PATH_MAX];

static void put(const char *rel, const char *text)
{
    char p[PATH_MAX * 2], cmd[PATH_MAX * 3];
    snprintf(p, sizeof p, "%s/%s", root, rel);
    snprintf(cmd, sizeof cmd, "mkdir -p \"$(dirname '%s')\"", p);
    CHECK(system(cmd) == 0);
    FILE *f = fopen(p, "w");
    CHECK(f != NULL);
    if (f) {
        fprintf(f, "%s\n", text);
        fclose(f);
    }
}

/* /sys/class/video4linux/videoN/device -> the interface dir of usbdev. */
static void node(int n, const char *usbdev, int index)
{
    char rel[256], target[512], link[PATH_MAX * 2], txt[16];
    snprintf(rel, sizeof rel, "class/video4linux/video%d/index", n);
    snprintf(txt, sizeof txt, "%d", index);
    put(rel, txt);
    snprintf(rel, sizeof rel, "devices/pci0000:00/usb1/%s/%s:1.0/uevent", usbdev, usbdev);
    put(rel, "DEVTYPE=usb_interface");
    snprintf(target, sizeof target, "../../../devices/pci0000:00/usb1/%s/%s:1.0", usbdev,
             usbdev);
    snprintf(link, sizeof link, "%s/class/video4linux/video%d/device", root, n);
    CHECK(symlink(target, link) == 0);
}

static void usbdev(const char *name, const char *vid, const char *pid, const char *serial)
{
    char rel[256];
    snprintf(rel, sizeof rel, "devices/pci0000:00/usb1/%s/idVendor", name);
    put(rel, vid);
    snprintf(rel, sizeof rel, "devices/pci0000:00/usb1/%s/idProduct", name);
    put(rel, pid);
    if (serial) {
        snprintf(rel, sizeof rel, "devices/pci0000:00/usb1/%s/serial", name);
        put(rel, serial);
    }
}

static void expect(const char *spec, int code, const char *want)
{
    gs_cap_resolve_opts o = {root, "/devx", 0};
    char path[256] = "";
    gs_error e = {0};
    int r = gs_cap_resolve(spec, &o, path, sizeof path, &e);
    CHECK_MSG(r == code, "%s: code %d (%s), want %d", spec, r, e.msg, code);
    if (want)
        CHECK_MSG(strcmp(path, want) == 0, "%s -> '%s', want '%s'", spec, path, want);
}

/* A capture whose opens are recorded (and fail: no device behind them). */
static char opened[8][256];
static int n_opened;
static int64_t fake_clock;

static int rec_open(void *ctx, const char *path, int flags)
{
    (void)ctx, (void)flags;
    if (n_opened < 8)
        snprintf(opened[n_opened], sizeof opened[0], "%s", path);
    n_opened++;
    return -2; /* ENOENT */
}
static int64_t rec_now(void *ctx)
{
    (void)ctx;
    return fake_clock += 1000000000; /* a second a call: every back-off has passed */
}
static void rec_sleep(void *ctx, int64_t ns)
{
    (void)ctx;
    fake_clock += ns;
}

static void reopen_by_spec(void)
{
    gs_cap_ops ops = {0};
    ops.open = rec_open;
    ops.now_ns = rec_now;
    ops.sleep_ns = rec_sleep;
    gs_cap_resolve_opts o = {root, "/devx", 0};
    gs_cap_config cfg = gs_cap_config_default("usb:abcd:0001");
    cfg.ops = &ops;
    cfg.resolve = &o;
    gs_cap *cap = NULL;
    gs_error e = {0};
    CHECK(gs_cap_create(&cfg, &cap, &e) == GS_OK);
    gs_cap_frame fr;
    /* not plugged in: no open at all, an I/O error naming the spec */
    CHECK(gs_cap_grab(cap, &fr, &e) == GS_ERR_IO);
    CHECK_MSG(n_opened == 0 && strstr(e.msg, "usb:abcd:0001"), "before the camera: %d opens, '%s'",
              n_opened, e.msg);
    /* plugged in as video11: the next open goes there */
    usbdev("1-4", "abcd", "0001", NULL);
    node(11, "1-4", 0);
    gs_cap_kick(cap);
    CHECK(gs_cap_grab(cap, &fr, &e) == GS_ERR_IO);
    CHECK_MSG(n_opened == 1 && strcmp(opened[0], "/devx/video11") == 0, "plugged in: %d opens, '%s'",
              n_opened, n_opened ? opened[0] : "");
    /* unplugged and back as video12 */
    char link[PATH_MAX * 2];
    snprintf(link, sizeof link, "%s/class/video4linux/video11/device", root);
    CHECK(unlink(link) == 0);
    node(12, "1-4", 0);
    gs_cap_kick(cap);
    CHECK(gs_cap_grab(cap, &fr, &e) == GS_ERR_IO);
    CHECK_MSG(n_opened == 2 && strcmp(opened[1], "/devx/video12") == 0, "back as video12: %d opens, '%s'",
              n_opened, n_opened > 1 ? opened[1] : "");
    gs_cap_destroy(cap);
}

int main(void)
{
    snprintf(root, sizeof root, "%s/gs_sysfs_XXXXXX", getenv("TMPDIR") ? getenv("TMPDIR") : "/tmp");
    CHECK(mkdtemp(root) != NULL);
    usbdev("1-1", "046d", "085b", "A1B2");
    usbdev("1-2", "046d", "085b", "C3D4");
    usbdev("1-3", "1bcf", "2c99", NULL);
    node(3, "1-1", 1); /* metadata node of camera A, lower N */
    node(4, "1-1", 0);
    node(1, "1-2", 0);
    node(2, "1-2", 1);
    node(7, "1-3", 0);

    expect("/dev/video5", GS_OK, "/dev/video5");
    expect("usb:046d:085b", GS_OK, "/devx/video1");
    expect("usb:046D:085B:A1B2", GS_OK, "/devx/video4");
    expect("usb:46d:85b:C3D4", GS_OK, "/devx/video1");
    expect("usb:046d:085b:ZZZZ", GS_ERR_IO, NULL);
    expect("usb:1bcf:2c99", GS_OK, "/devx/video7");
    expect("usb:1bcf:2c99:X", GS_ERR_IO, NULL);
    expect("usb:dead:beef", GS_ERR_IO, NULL);
    static const char *bad[] = {"usb:", "usb:046d", "usb:12345:1", "usb:zz:11",
                                "usb:1:2:", "usb::1", "usb:1:"};
    for (size_t i = 0; i < sizeof bad / sizeof bad[0]; i++)
        expect(bad[i], GS_ERR_ARG, NULL);
    gs_cap_usb_id id;
    CHECK_EQ_INT(gs_cap_usb_id_parse("usb:046d:085b:SN 1", &id, NULL), GS_OK);
    CHECK(id.vid == 0x046d && id.pid == 0x085b && strcmp(id.serial, "SN 1") == 0);

    /* Without a video4linux class directory: an I/O error, not a crash. */
    gs_cap_resolve_opts none = {"/nonexistent-sysfs", NULL, 0};
    char path[64];
    CHECK_EQ_INT(gs_cap_resolve("usb:1:2", &none, path, sizeof path, NULL), GS_ERR_IO);

    reopen_by_spec();

    char cmd[PATH_MAX + 16];
    snprintf(cmd, sizeof cmd, "rm -rf '%s'", root);
    CHECK(system(cmd) == 0);
    GS_TEST_END();
}
