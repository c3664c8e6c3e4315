/* gs_cap: live video. V4L2 capture with newest-frame semantics and
 * reconnects, v4l2loopback output, camera choice by USB identity, libusb
 * hotplug, the eye-contact policy and the capture -> processing -> output
 * pipeline.
 *
 * Every device call goes through a gs_cap_ops table (open, close, ioctl,
 * mmap, munmap, poll, write, and the clock), so tests drive the capture code
 * with a fake device and a fake clock; gs_cap_ops_system() is the real one.
 *
 * Pixels at the API are 8-bit RGB interleaved (see image_io.h). YUYV <-> RGB
 * uses BT.601 limited range ("studio swing", what webcams and v4l2loopback
 * consumers assume): Y in [16, 235], Cb/Cr in [16, 240],
 *   R = 1.164 (Y-16) + 1.596 (Cr-128)
 *   G = 1.164 (Y-16) - 0.392 (Cb-128) - 0.813 (Cr-128)
 *   B = 1.164 (Y-16) + 2.017 (Cb-128)
 * in 16-bit fixed point, rounded and clamped. RGB -> YUYV averages the two
 * pixels of a pair for chroma.
 *
 * Errors: GS_OK or a negative gs_status; a gs_error says what happened. A
 * lost device is GS_ERR_IO, never fatal: the next gs_cap_grab reopens it. */
#ifndef GAZESPLAT_CAPTURE_H
#define GAZESPLAT_CAPTURE_H

#include <poll.h>
#include <stddef.h>
#include <stdint.h>
#include <sys/types.h>

#include "gazesplat/error.h"

#ifdef __cplusplus
extern "C" {
#endif

/* ---- device operations ---------------------------------------------------- */

/* Every call returns >= 0 on success or -errno, never touches errno's
 * meaning for the caller; mmap returns NULL on failure (with *err_no set). */
typedef struct gs_cap_ops {
    void *ctx;
    int (*open)(void *ctx, const char *path, int flags);
    int (*close)(void *ctx, int fd);
    int (*ioctl)(void *ctx, int fd, unsigned long request, void *arg);
    void *(*mmap)(void *ctx, int fd, size_t len, off_t offset, int *err_no);
    int (*munmap)(void *ctx, void *addr, size_t len);
    int (*poll)(void *ctx, struct pollfd *fds, nfds_t nfds, int timeout_ms);
    ssize_t (*write)(void *ctx, int fd, const void *buf, size_t len);
    int64_t (*now_ns)(void *ctx);           /* CLOCK_MONOTONIC */
    void (*sleep_ns)(void *ctx, int64_t ns);
} gs_cap_ops;

/* The kernel's calls and CLOCK_MONOTONIC. A static table (ctx NULL). */
const gs_cap_ops *gs_cap_ops_system(void);

/* ---- pixel conversion ----------------------------------------------------- */

/* YUYV (Y0 U Y1 V per pixel pair, row stride src_stride bytes) to RGB
 * (dst_stride bytes per row). width must be even. */
void gs_cap_yuyv_to_rgb(const uint8_t *src, size_t src_stride, int width, int height,
                        uint8_t *dst, size_t dst_stride);

/* RGB to YUYV; width must be even. */
void gs_cap_rgb_to_yuyv(const uint8_t *src, size_t src_stride, int width, int height,
                        uint8_t *dst, size_t dst_stride);

/* 1 when buf looks like a whole JPEG: starts with FFD8 and ends with FFD9
 * (trailing zero padding, which some cameras add, is allowed). */
int gs_cap_mjpeg_complete(const uint8_t *buf, size_t len);

/* ---- capture -------------------------------------------------------------- */

typedef enum gs_cap_pixfmt {
    GS_CAP_PIX_AUTO = 0,  /* YUYV, else MJPEG */
    GS_CAP_PIX_YUYV = 1,
    GS_CAP_PIX_MJPEG = 2
} gs_cap_pixfmt;

#define GS_CAP_MAX_BUFFERS 16
#define GS_CAP_MAX_SIDE 8192

typedef struct gs_cap_config {
    const char *path;        /* /dev/videoN, or usb:VID:PID[:SERIAL] looked up
                                at every open (gs_cap_resolve; copied) */
    int width, height;       /* requested; the driver may adjust */
    int fps;                 /* requested; 0 keeps the driver's rate */
    gs_cap_pixfmt pixfmt;
    int nbuffers;            /* mmap buffers, 2..GS_CAP_MAX_BUFFERS (0: 4) */
    int timeout_ms;          /* no frame this long = device lost (0: 1000) */
    int backoff_min_ms;      /* first reopen delay (0: 100) */
    int backoff_max_ms;      /* delay doubles up to this (0: 1000) */
    const gs_cap_ops *ops;   /* NULL: gs_cap_ops_system() */
    /* Where a usb: path is looked up (copied; its strings must outlive the
     * capture). NULL: the system's /sys and /dev, with libusb's names. */
    const struct gs_cap_resolve_opts *resolve;
} gs_cap_config;

/* A config with the defaults above for path, 640x480 at 30 fps, AUTO. */
gs_cap_config gs_cap_config_default(const char *path);

/* What the device agreed to, read back from S_FMT and S_PARM. */
typedef struct gs_cap_format {
    int width, height;
    gs_cap_pixfmt pixfmt;
    size_t bytesperline, sizeimage;
    int fps_num, fps_den;    /* frames per second = num / den; 0/0 unknown */
    int nbuffers;
} gs_cap_format;

/* One decoded frame; rgb is owned by the gs_cap and valid until the next
 * gs_cap_grab or gs_cap_destroy. */
typedef struct gs_cap_frame {
    int width, height;
    size_t stride;           /* 3 * width */
    const uint8_t *rgb;
    uint32_t sequence;       /* the driver's frame counter */
    int64_t t_capture_ns;    /* driver timestamp (monotonic), else t_dequeue */
    int64_t t_dequeue_ns;    /* when we took it from the driver */
    int skipped;             /* frames dropped before this one (stale + bad + gaps) */
} gs_cap_frame;

typedef struct gs_cap_stats {
    uint64_t frames;         /* delivered by gs_cap_grab */
    uint64_t stale;          /* good frames skipped because a newer one was ready */
    uint64_t bad;            /* error flag, too short, MJPEG without markers, undecodable */
    uint64_t gaps;           /* sequence numbers the driver skipped */
    uint64_t opens;          /* successful (re)opens */
    uint64_t failures;       /* device lost, open failed, timeouts */
    uint64_t first_frame_ns; /* latest successful open: from the start of the open to
                              * its first delivered frame (the driver's share of a
                              * recovery; the back-off wait comes before it) */
} gs_cap_stats;

typedef struct gs_cap gs_cap;

/* Checks cfg and allocates; opens nothing (the first grab does). */
int gs_cap_create(const gs_cap_config *cfg, gs_cap **out, gs_error *err);
void gs_cap_destroy(gs_cap *cap);

/* Waits up to the config's timeout for the newest frame. When the device is
 * closed it is (re)opened once its back-off delay has passed, with format
 * and fps applied again. Every ioctl error, a poll timeout or a bad open
 * closes the device and returns GS_ERR_IO; the back-off then doubles from
 * backoff_min_ms to backoff_max_ms and resets after a good frame. Returns
 * GS_OK with *frame filled. */
int gs_cap_grab(gs_cap *cap, gs_cap_frame *frame, gs_error *err);

/* Asks the next grab to reopen now, skipping the back-off (a hotplug
 * arrival). Safe to call from any thread. */
void gs_cap_kick(gs_cap *cap);

/* 1 while the device is open and streaming. */
int gs_cap_is_open(const gs_cap *cap);

/* The format in use (or last in use); GS_ERR_STATE before the first open. */
int gs_cap_get_format(const gs_cap *cap, gs_cap_format *fmt);

void gs_cap_get_stats(const gs_cap *cap, gs_cap_stats *stats);

/* Closes the device (stream off, unmap, release the buffers). The next grab
 * reopens it immediately. */
void gs_cap_close(gs_cap *cap);

/* ---- v4l2loopback output -------------------------------------------------- */

/* A writer on a V4L2 OUTPUT device (v4l2loopback): YUYV, even width, set
 * with S_FMT on the OUTPUT type, frames handed over with write(). The
 * format given at create is kept for the writer's life and re-applied on
 * every reopen: a frame of another size (a camera back at another
 * resolution) is letterboxed into it, so readers never see the format
 * change. A write error closes the device; the next write reopens it after
 * a delay. */
typedef struct gs_cap_out gs_cap_out;

int gs_cap_out_create(const char *path, int width, int height, int fps,
                      const gs_cap_ops *ops, gs_cap_out **out, gs_error *err);
void gs_cap_out_destroy(gs_cap_out *o);

/* Converts an RGB frame to YUYV and writes it. A frame of another size is
 * scaled into the output's format (aspect kept, black bars). */
int gs_cap_out_write(gs_cap_out *o, const uint8_t *rgb, size_t stride, int width,
                     int height, gs_error *err);

/* Writes the "no video" frame (dark grey, "NO VIDEO" in light grey) in the
 * output's format: the pipeline sends it while the camera is gone so that
 * video-call apps keep a live stream. */
int gs_cap_out_write_placeholder(gs_cap_out *o, gs_error *err);

/* Draws the placeholder into an RGB image of any size. */
void gs_cap_placeholder_rgb(uint8_t *rgb, size_t stride, int width, int height);

/* The output's format (fixed at create). */
void gs_cap_out_size(const gs_cap_out *o, int *width, int *height);

/* ---- choosing a camera ---------------------------------------------------- */

typedef struct gs_cap_usb_id {
    uint16_t vid, pid;
    char serial[128];        /* "" matches any */
} gs_cap_usb_id;

/* Parses "usb:VID:PID[:SERIAL]" (hex ids). GS_ERR_ARG when malformed. */
int gs_cap_usb_id_parse(const char *spec, gs_cap_usb_id *id, gs_error *err);

/* Where to look: sysfs_root (NULL: "/sys") and dev_root (NULL: "/dev") let
 * tests point at a fake tree. use_libusb: also enumerate with libusb and
 * keep only devices it lists (skipped when libusb cannot start). */
typedef struct gs_cap_resolve_opts { /* gs_cap_resolve */
    const char *sysfs_root;
    const char *dev_root;
    int use_libusb;
} gs_cap_resolve_opts;

/* Turns a camera spec into a device path: a path is returned as it is;
 * "usb:VID:PID[:SERIAL]" is looked up in <sysfs>/class/video4linux/videoN:
 * videoN/device is the USB interface, its parent holds idVendor, idProduct
 * and serial. Of the matching nodes the one with the lowest `index` (the
 * capture node, not the metadata node) and then the lowest N wins.
 * GS_ERR_IO when no camera matches. */
int gs_cap_resolve(const char *spec, const gs_cap_resolve_opts *opts, char *path,
                   size_t path_len, gs_error *err);

/* ---- libusb hotplug ------------------------------------------------------- */

/* Watches USB arrivals and departures on a thread of its own (a private
 * libusb context; the interface is never claimed, so the kernel's uvcvideo
 * keeps streaming). Without a filter id only devices with a video-class
 * interface (0x0E) are reported; any_class reports every device (tests). */
typedef struct gs_cap_hotplug gs_cap_hotplug;

typedef enum gs_cap_hotplug_event {
    GS_CAP_HOTPLUG_ARRIVED = 1,
    GS_CAP_HOTPLUG_LEFT = 2
} gs_cap_hotplug_event;

typedef void (*gs_cap_hotplug_fn)(void *user, gs_cap_hotplug_event ev, uint16_t vid,
                                  uint16_t pid);

/* filter NULL: every video-class device (or every device with any_class).
 * GS_ERR_UNSUPPORTED when libusb has no hotplug support here. */
int gs_cap_hotplug_start(const gs_cap_usb_id *filter, int any_class, gs_cap_hotplug_fn fn,
                         void *user, gs_cap_hotplug **out, gs_error *err);
void gs_cap_hotplug_stop(gs_cap_hotplug *hp);

/* ---- eye-contact policy --------------------------------------------------- */

/* How strongly to redirect the eyes toward the camera, from the tracked
 * gaze and head pose. Each measured angle gives a factor that is 1 up to
 * its low threshold, 0 from its high threshold, linear between (looking or
 * turned away fades the correction out); the target weight is strength
 * times the smallest factor, 0 without a face or when off. The weight
 * follows the target with an exponential time constant smooth_s. During a
 * blink (eye openness below blink_openness) the weight and the gaze are
 * held, for at most blink_hold_max_s; longer closed eyes fade out. */
typedef struct gs_cap_policy_config {
    int enabled;               /* 0: off (fades to 0) */
    float strength;            /* 0..1 */
    float gaze_low_deg, gaze_high_deg;             /* 20, 30 (pitch and yaw) */
    float head_pitch_low_deg, head_pitch_high_deg; /* 15, 25 */
    float head_yaw_low_deg, head_yaw_high_deg;     /* 25, 30 */
    float smooth_s;            /* 0.1; 0 = no smoothing */
    float blink_openness;      /* 0.2 */
    float blink_hold_max_s;    /* 0.5 */
} gs_cap_policy_config;

gs_cap_policy_config gs_cap_policy_config_default(void);

/* Sets one field by name ("enabled" takes yes/no/true/false/on/off/1/0;
 * the others a number), without the range check. GS_ERR_ARG for an
 * unknown key or an unparsable value. */
int gs_cap_policy_config_set(gs_cap_policy_config *c, const char *key, const char *value,
                             gs_error *err);
/* Applies "k=v,k=v,..." and checks the result; *c is changed only when
 * every setting parsed and the whole config passed the check. */
int gs_cap_policy_config_parse(gs_cap_policy_config *c, const char *list, gs_error *err);

/* Ranges: strength in [0,1]; 0 <= low < high <= 90 for each pair;
 * smooth_s in [0, 10]; blink_openness in [0,1]; blink_hold_max_s in [0, 10]. */
int gs_cap_policy_config_check(const gs_cap_policy_config *c, gs_error *err);

/* One frame's measurements (radians, geom.h conventions). */
typedef struct gs_cap_policy_input {
    int face;                  /* 0: no face found */
    float gaze_pitch, gaze_yaw;
    float head_pitch, head_yaw;
    float openness;            /* eye openness 0 (closed) .. 1 */
    float dt_s;                /* seconds since the previous frame */
} gs_cap_policy_input;

typedef struct gs_cap_policy_output {
    float weight;              /* 0 (natural gaze) .. 1 (full correction) */
    float gaze_pitch, gaze_yaw;/* smoothed gaze to correct from (radians) */
    int held;                  /* 1 while a blink holds the previous values */
} gs_cap_policy_output;

typedef struct gs_cap_policy gs_cap_policy;

int gs_cap_policy_create(const gs_cap_policy_config *cfg, gs_cap_policy **out,
                         gs_error *err);
void gs_cap_policy_destroy(gs_cap_policy *p);

/* Replaces the configuration; takes effect at the next update. Safe to call
 * from any thread while another updates. */
int gs_cap_policy_set(gs_cap_policy *p, const gs_cap_policy_config *cfg, gs_error *err);
void gs_cap_policy_get(gs_cap_policy *p, gs_cap_policy_config *cfg);

/* Advances the policy by one frame. Call from one thread. */
void gs_cap_policy_update(gs_cap_policy *p, const gs_cap_policy_input *in,
                          gs_cap_policy_output *out);

/* ---- pipeline ------------------------------------------------------------- */

/* A processing stage, run on its own thread on each frame in place (RGB).
 * The eye-contact stage plugs in here; gs_cap_stage_passthrough() leaves
 * frames as they are. */
typedef struct gs_cap_stage {
    void *ctx;
    int (*process)(void *ctx, uint8_t *rgb, size_t stride, int width, int height,
                   int64_t t_capture_ns, gs_error *err);
} gs_cap_stage;

gs_cap_stage gs_cap_stage_passthrough(void);

/* Frame events for the program (logging). Called from pipeline threads. */
typedef enum gs_cap_pipe_event {
    GS_CAP_EV_STREAMING = 1,   /* capture (re)opened and delivering */
    GS_CAP_EV_LOST = 2,        /* capture failed; reopening */
    GS_CAP_EV_OUT_ERROR = 3,   /* output write failed */
    GS_CAP_EV_STAGE_ERROR = 4  /* processing failed; frame passed through */
} gs_cap_pipe_event;

typedef void (*gs_cap_pipe_log_fn)(void *user, gs_cap_pipe_event ev, const char *msg);

typedef struct gs_cap_pipe_config {
    gs_cap *cap;               /* borrowed */
    gs_cap_stage stage;
    gs_cap_out *out;           /* borrowed; NULL discards frames (benchmarks) */
    int ring;                  /* slots per ring, 1..8 (0: 2) */
    const gs_cap_ops *clock;   /* now_ns for latencies, the capture's clock (NULL: system) */
    gs_cap_pipe_log_fn log;    /* may be NULL */
    void *log_user;
    int placeholder_ms;        /* no frame this long: the output gets the "no
                                  video" frame, 10 per second (0: 500; < 0: never) */
} gs_cap_pipe_config;

/* Latency percentiles in milliseconds over the last GS_CAP_PIPE_WINDOW frames. */
#define GS_CAP_PIPE_WINDOW 1024
typedef struct gs_cap_latency {
    double p50_ms, p99_ms, max_ms;
} gs_cap_latency;

typedef struct gs_cap_pipe_stats {
    uint64_t in, out;          /* frames captured, frames written */
    uint64_t ring_drops;       /* overwritten in a ring: a later stage was slower */
    uint64_t placeholders;     /* "no video" frames written while the camera was gone */
    gs_cap_stats cap;
    gs_cap_latency capture;    /* driver timestamp -> frame in the first ring */
    gs_cap_latency process;    /* taken by the stage -> stage done */
    gs_cap_latency output;     /* taken by the output -> written */
    gs_cap_latency total;      /* driver timestamp -> written */
} gs_cap_pipe_stats;

typedef struct gs_cap_pipe gs_cap_pipe;

/* Starts the capture, processing and output threads. The rings keep the
 * newest frames: a full ring drops its oldest frame, so a slow stage never
 * builds up latency. */
int gs_cap_pipe_start(const gs_cap_pipe_config *cfg, gs_cap_pipe **out, gs_error *err);

/* Stops and joins the threads (within about one capture timeout). */
void gs_cap_pipe_stop(gs_cap_pipe *p);

void gs_cap_pipe_get_stats(gs_cap_pipe *p, gs_cap_pipe_stats *stats);

#ifdef __cplusplus
}
#endif
#endif
