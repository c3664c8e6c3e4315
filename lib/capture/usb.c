/* Camera choice by USB identity: "usb:VID:PID[:SERIAL]" -> /dev/videoN,
 * through sysfs (videoN/device is the USB interface; its parent directory
 * is the USB device with idVendor, idProduct and serial), cross-checked
 * with libusb's enumeration when libusb can run here. Nothing is opened or
 * claimed. */
#define _GNU_SOURCE
#include <ctype.h>
#include <dirent.h>
#include <errno.h>
#include <libusb.h>
#include <limits.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "gazesplat/capture.h"

static int parse_hex16(const char *s, size_t n, uint16_t *out)
{
    if (n < 1 || n > 4)
        return -1;
    unsigned v = 0;
    for (size_t i = 0; i < n; i++) {
        if (!isxdigit((unsigned char)s[i]))
            return -1;
        v = v * 16 + (unsigned)(isdigit((unsigned char)s[i]) ? s[i] - '0'
                                                              : tolower((unsigned char)s[i]) - 'a' + 10);
    }
    *out = (uint16_t)v;
    return 0;
}

int gs_cap_usb_id_parse(const char *spec, gs_cap_usb_id *id, gs_error *err)
{
    if (!spec || !id || strncmp(spec, "usb:", 4) != 0)
        return gs_error_set(err, GS_ERR_ARG, "camera id: expected usb:VID:PID[:SERIAL]");
    gs_cap_usb_id r = {0};
    const char *v = spec + 4, *c1 = strchr(v, ':');
    const char *p = c1 ? c1 + 1 : NULL, *c2 = p ? strchr(p, ':') : NULL;
    size_t plen = p ? (c2 ? (size_t)(c2 - p) : strlen(p)) : 0;
    if (!c1 || parse_hex16(v, (size_t)(c1 - v), &r.vid) || parse_hex16(p, plen, &r.pid))
        return gs_error_set(err, GS_ERR_ARG, "camera id '%s': VID and PID are 1-4 hex digits",
                            spec);
    if (c2) {
        size_t slen = strlen(c2 + 1);
        if (slen == 0 || slen >= sizeof r.serial)
            return gs_error_set(err, GS_ERR_ARG, "camera id '%s': serial empty or too long",
                                spec);
        memcpy(r.serial, c2 + 1, slen + 1);
    }
    *id = r;
    return GS_OK;
}

/* First line of a sysfs attribute, newline stripped. 0 or -1. */
static int read_attr(const char *dir, const char *name, char *buf, size_t n)
{
    char path[PATH_MAX];
    if (snprintf(path, sizeof path, "%s/%s", dir, name) >= (int)sizeof path)
        return -1;
    FILE *f = fopen(path, "r");
    if (!f)
        return -1;
    char *ok = fgets(buf, (int)n, f);
    fclose(f);
    if (!ok)
        return -1;
    buf[strcspn(buf, "\r\n")] = '\0';
    return 0;
}

static int read_hex_attr(const char *dir, const char *name, uint16_t *out)
{
    char b[16];
    return read_attr(dir, name, b, sizeof b) ? -1 : parse_hex16(b, strlen(b), out);
}

/* libusb's view: sysfs names ("1-1.4") of the devices with this vid:pid.
 * Returns the count, or -1 when libusb cannot enumerate here. */
#define MAX_USB_NAMES 32
static int libusb_names(const gs_cap_usb_id *id, char names[][32])
{
    libusb_context *ctx = NULL;
    if (libusb_init(&ctx) != 0)
        return -1;
    libusb_device **list = NULL;
    ssize_t n = libusb_get_device_list(ctx, &list);
    int count = n < 0 ? -1 : 0;
    for (ssize_t i = 0; i < n && count < MAX_USB_NAMES; i++) {
        struct libusb_device_descriptor d;
        uint8_t ports[8];
        if (libusb_get_device_descriptor(list[i], &d) != 0 || d.idVendor != id->vid ||
            d.idProduct != id->pid)
            continue;
        int np = libusb_get_port_numbers(list[i], ports, (int)sizeof ports);
        if (np <= 0)
            continue;
        char *s = names[count];
        int len = snprintf(s, 32, "%u-%u", libusb_get_bus_number(list[i]), ports[0]);
        for (int k = 1; k < np && len > 0 && len < 28; k++)
            len += snprintf(s + len, (size_t)(32 - len), ".%u", ports[k]);
        count++;
    }
    if (n >= 0)
        libusb_free_device_list(list, 1);
    libusb_exit(ctx);
    return count;
}

typedef struct match {
    int found;
    int index;  /* the node's sysfs index: 0 is the capture node */
    int num;    /* N of videoN */
} match;

/* Checks /sys/class/video4linux/<name> against id; updates *best. */
static void check_node(const char *classdir, const char *name, const gs_cap_usb_id *id,
                       char names[][32], int nnames, match *best)
{
    char node[PATH_MAX], link[PATH_MAX], iface[PATH_MAX];
    int num;
    if (sscanf(name, "video%d", &num) != 1 || num < 0)
        return;
    if (snprintf(node, sizeof node, "%s/%s", classdir, name) >= (int)sizeof node ||
        snprintf(link, sizeof link, "%s/device", node) >= (int)sizeof link ||
        !realpath(link, iface))
        return;
    char *slash = strrchr(iface, '/');
    if (!slash || slash == iface)
        return;
    *slash = '\0'; /* the USB device directory */
    uint16_t vid, pid;
    if (read_hex_attr(iface, "idVendor", &vid) || read_hex_attr(iface, "idProduct", &pid) ||
        vid != id->vid || pid != id->pid)
        return;
    char serial[sizeof id->serial];
    if (id->serial[0] &&
        (read_attr(iface, "serial", serial, sizeof serial) || strcmp(serial, id->serial) != 0))
        return;
    if (nnames > 0) {
        const char *base = strrchr(iface, '/') + 1;
        int listed = 0;
        for (int i = 0; i < nnames && !listed; i++)
            listed = strcmp(names[i], base) == 0;
        if (!listed)
            return;
    }
    char ib[16];
    int index = read_attr(node, "index", ib, sizeof ib) ? 0 : atoi(ib);
    if (!best->found || index < best->index || (index == best->index && num < best->num))
        *best = (match){1, index, num};
}

int gs_cap_resolve(const char *spec, const gs_cap_resolve_opts *opts, char *path,
                   size_t path_len, gs_error *err)
{
    if (!spec || !path || path_len == 0)
        return gs_error_set(err, GS_ERR_ARG, "camera: NULL argument");
    if (strncmp(spec, "usb:", 4) != 0) {
        if (strlen(spec) >= path_len)
            return gs_error_set(err, GS_ERR_LIMIT, "camera: path too long");
        strcpy(path, spec);
        return GS_OK;
    }
    gs_cap_usb_id id;
    int r = gs_cap_usb_id_parse(spec, &id, err);
    if (r != GS_OK)
        return r;
    const char *sys = opts && opts->sysfs_root ? opts->sysfs_root : "/sys";
    const char *dev = opts && opts->dev_root ? opts->dev_root : "/dev";
    char names[MAX_USB_NAMES][32];
    int nnames = opts && opts->use_libusb ? libusb_names(&id, names) : -1;
    char classdir[PATH_MAX];
    if (snprintf(classdir, sizeof classdir, "%s/class/video4linux", sys) >= (int)sizeof classdir)
        return gs_error_set(err, GS_ERR_LIMIT, "camera: sysfs path too long");
    DIR *d = opendir(classdir);
    if (!d)
        return gs_error_set(err, GS_ERR_IO, "camera: %s: %s", classdir, strerror(errno));
    match best = {0};
    for (struct dirent *e; (e = readdir(d));)
        check_node(classdir, e->d_name, &id, names, nnames, &best);
    closedir(d);
    if (!best.found)
        return gs_error_set(err, GS_ERR_IO, "camera: no video device for %s", spec);
    if (snprintf(path, path_len, "%s/video%d", dev, best.num) >= (int)path_len)
        return gs_error_set(err, GS_ERR_LIMIT, "camera: path too long");
    return GS_OK;
}
