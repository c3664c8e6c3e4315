/* libusb hotplug on a private context and a thread of its own. Devices are
 * only looked at (descriptors), never opened or claimed: uvcvideo keeps the
 * interface and the capture reopens /dev/videoN when told. */
#include <libusb.h>
#include <pthread.h>
#include <stdatomic.h>
#include <stdlib.h>
#include <string.h>

#include "gazesplat/capture.h"

#define USB_CLASS_VIDEO 0x0E
#define EVENT_WAIT_US 100000

struct gs_cap_hotplug {
    libusb_context *ctx;
    libusb_hotplug_callback_handle handle;
    int any_class, filtered;
    gs_cap_hotplug_fn fn;
    void *user;
    pthread_t thread;
    atomic_int stop;
};

/* 1 when the device or one of its interfaces is video class. */
static int is_video(libusb_device *dev, const struct libusb_device_descriptor *d)
{
    if (d->bDeviceClass == USB_CLASS_VIDEO)
        return 1;
    struct libusb_config_descriptor *c = NULL;
    if (libusb_get_active_config_descriptor(dev, &c) != 0 &&
        libusb_get_config_descriptor(dev, 0, &c) != 0)
        return 0;
    int video = 0;
    for (int i = 0; i < c->bNumInterfaces && !video; i++)
        for (int a = 0; a < c->interface[i].num_altsetting && !video; a++)
            video = c->interface[i].altsetting[a].bInterfaceClass == USB_CLASS_VIDEO;
    libusb_free_config_descriptor(c);
    return video;
}

static int LIBUSB_CALL on_hotplug(libusb_context *ctx, libusb_device *dev,
                                  libusb_hotplug_event event, void *user)
{
    (void)ctx;
    gs_cap_hotplug *hp = user;
    struct libusb_device_descriptor d;
    if (libusb_get_device_descriptor(dev, &d) != 0)
        return 0;
    if (!hp->any_class && !hp->filtered && !is_video(dev, &d))
        return 0;
    hp->fn(hp->user,
           event == LIBUSB_HOTPLUG_EVENT_DEVICE_ARRIVED ? GS_CAP_HOTPLUG_ARRIVED
                                                        : GS_CAP_HOTPLUG_LEFT,
           d.idVendor, d.idProduct);
    return 0; /* stay registered */
}

static void *event_thread(void *arg)
{
    gs_cap_hotplug *hp = arg;
    while (!atomic_load(&hp->stop)) {
        struct timeval tv = {0, EVENT_WAIT_US};
        libusb_handle_events_timeout_completed(hp->ctx, &tv, NULL);
    }
    return NULL;
}

int gs_cap_hotplug_start(const gs_cap_usb_id *filter, int any_class, gs_cap_hotplug_fn fn,
                         void *user, gs_cap_hotplug **out, gs_error *err)
{
    if (!fn || !out)
        return gs_error_set(err, GS_ERR_ARG, "hotplug: NULL argument");
    gs_cap_hotplug *hp = calloc(1, sizeof *hp);
    if (!hp)
        return gs_error_set(err, GS_ERR_NOMEM, "hotplug: out of memory");
    hp->fn = fn;
    hp->user = user;
    hp->any_class = any_class;
    hp->filtered = filter != NULL;
    atomic_init(&hp->stop, 0);
    int r = libusb_init(&hp->ctx);
    if (r != 0) {
        free(hp);
        return gs_error_set(err, GS_ERR_UNSUPPORTED, "hotplug: libusb_init: %s",
                            libusb_strerror(r));
    }
    if (!libusb_has_capability(LIBUSB_CAP_HAS_HOTPLUG)) {
        libusb_exit(hp->ctx);
        free(hp);
        return gs_error_set(err, GS_ERR_UNSUPPORTED, "hotplug: libusb has no hotplug here");
    }
    r = libusb_hotplug_register_callback(
        hp->ctx, LIBUSB_HOTPLUG_EVENT_DEVICE_ARRIVED | LIBUSB_HOTPLUG_EVENT_DEVICE_LEFT, 0,
        filter ? filter->vid : LIBUSB_HOTPLUG_MATCH_ANY,
        filter ? filter->pid : LIBUSB_HOTPLUG_MATCH_ANY, LIBUSB_HOTPLUG_MATCH_ANY, on_hotplug,
        hp, &hp->handle);
    if (r == 0 && pthread_create(&hp->thread, NULL, event_thread, hp) != 0) {
        libusb_hotplug_deregister_callback(hp->ctx, hp->handle);
        r = LIBUSB_ERROR_NO_MEM;
    }
    if (r != 0) {
        libusb_exit(hp->ctx);
        free(hp);
        return gs_error_set(err, GS_ERR_IO, "hotplug: %s", libusb_strerror(r));
    }
    *out = hp;
    return GS_OK;
}

void gs_cap_hotplug_stop(gs_cap_hotplug *hp)
{
    if (!hp)
        return;
    atomic_store(&hp->stop, 1);
    libusb_hotplug_deregister_callback(hp->ctx, hp->handle); /* wakes the event wait */
    pthread_join(hp->thread, NULL);
    libusb_exit(hp->ctx);
    free(hp);
}
