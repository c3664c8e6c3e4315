/* Camera choice by USB identity through a fake sysfs tree: two cameras of
 * the same model told apart by serial, the capture node preferred over the
 * metadata node, malformed ids refused. */
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

    char cmd[PATH_MAX + 16];
    snprintf(cmd, sizeof cmd, "rm -rf '%s'", root);
    CHECK(system(cmd) == 0);
    GS_TEST_END();
}
