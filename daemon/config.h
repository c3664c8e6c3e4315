/* gazesplatd configuration: one table of keys (config.c) read from a
 * "key = value" file and from --set key=value flags, every value checked
 * against its bounds. daemon/README.md lists the keys. */
#ifndef GSD_CONFIG_H
#define GSD_CONFIG_H

#include <stddef.h>

#define GSD_STR_MAX 512

/* Most fine-tuned subjects a worker holds (a model clone each). */
#define GSD_TUNED_SLOTS_MAX 16
/* A kept FIT input (keep_image): an 8-byte header and a square RGB image of
 * the model's size, at most 1024 px. */
#define GSD_INPUT_MAX_BLOB (8 + 3 * 1024 * 1024)

typedef struct gsd_config {
    char socket[GSD_STR_MAX];     /* Unix socket path; "" = default */
    int socket_mode;              /* octal, default 0660 */
    char tcp[GSD_STR_MAX];        /* "HOST:PORT", "" = no TCP */
    int tcp_allow_remote;         /* bind a non-loopback address */
    char token[GSD_STR_MAX];      /* shared secret ("" = none) */
    char token_file[GSD_STR_MAX]; /* read the token from this file */
    char model[GSD_STR_MAX];      /* model file */
    char state_dir[GSD_STR_MAX];  /* subject cache; "" = $STATE_DIRECTORY or none */
    int workers, threads, queue_depth;
    int sweep_subjects;           /* renders kept per worker for gaze sweeps */
    int max_payload, max_targets, max_inflight, max_output_kb, max_connections;
    int output_budget_mb;         /* unsent output of all connections */
    char metrics[GSD_STR_MAX];    /* Prometheus endpoint: HOST:PORT or unix:PATH; "" = none */
    int max_image_side, max_image_mpix;
    int header_timeout_ms, idle_timeout_ms, request_timeout_ms, max_deadline_ms;
    int drain_timeout_ms;
    int cache_mb;
    int tuned_cache_mb;      /* fine-tuned parameter blocks */
    int input_cache_mb;      /* kept FIT inputs (keep_image) */
    int max_finetune_steps;  /* per FIT; 0: fine-tuning refused */
    double finetune_lr;      /* Adam's base rate when a request gives none */
    int tuned_subjects;      /* fine-tuned subjects each worker holds ready */
    int log_level;
    int debug_requests;
    int photo_input;                  /* accept KIND_PHOTO (needs the two below) */
    int face_gate;                    /* refuse faces gs_face_gate refuses */
    char face_landmarks[GSD_STR_MAX]; /* dlib 68-point shape predictor */
    char face_cascade[GSD_STR_MAX];   /* OpenCV face cascade */
    /* live eye contact hosted by the daemon (live.c); "" device = off */
    char live_device[GSD_STR_MAX];    /* /dev/videoN or usb:VID:PID[:SERIAL] */
    char live_output[GSD_STR_MAX];    /* v4l2loopback device, "" = none */
    int live_width, live_height, live_fps;
    int live_fit_budget_s;            /* longest background fit */
} gsd_config;

void gsd_config_default(gsd_config *c);

/* Sets one key from text; returns 0, or -1 with a message in msg. */
int gsd_config_set(gsd_config *c, const char *key, const char *value, char *msg, size_t cap);

/* Reads a file of "key = value" lines ('#' comments). Returns 0, or -1
 * with "PATH:LINE: problem" in msg. */
int gsd_config_load(gsd_config *c, const char *path, char *msg, size_t cap);

/* Checks relations between keys and reads token_file. 0 or -1 + msg. */
int gsd_config_finish(gsd_config *c, char *msg, size_t cap);

/* Writes every key with its value, "key = value" lines. */
void gsd_config_print(const gsd_config *c, void *file);

#endif
