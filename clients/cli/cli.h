/* gazesplat command-line tool: shared declarations.
 *
 * Exit codes: 0 success, 1 runtime failure (message on stderr), 2 bad
 * usage (message and the command's usage on stderr). */
#ifndef GS_CLI_H
#define GS_CLI_H

#include <stddef.h>
#include <stdint.h>

/* Exit statuses: CLI_REFUSED, the face gate refused the input (face.h);
 * CLI_OUTLIERS, check-labels found more outliers than allowed. */
enum { CLI_OK = 0, CLI_FAIL = 1, CLI_USAGE = 2, CLI_REFUSED = 3, CLI_OUTLIERS = 4 };

/* An option of a command: "--name VALUE", "--name=VALUE", or a flag. */
typedef struct cli_opt {
    const char *name;   /* with the dashes */
    int takes_value;
    const char *value;  /* NULL until seen; "" for a seen flag */
} cli_opt;

/* One subcommand. Most name their options (opts, nopts) and a run_opts:
 * cli_run parses argv against a copy of opts, answers --help/-h with the
 * usage on stdout (exit 0) and a bad option with a usage error (exit 2),
 * and hands run_opts the filled copy. A command that reads its own argv
 * (client: a verb first) gives run instead, which gets argv[0] = the
 * command name. */
typedef struct cli_command cli_command;
struct cli_command {
    const char *name;
    const char *summary; /* one line for the command list */
    const char *usage;   /* full help text, first line "usage: gazesplat ..." */
    int (*run)(int argc, char **argv);
    const cli_opt *opts;
    int nopts;
    int (*run_opts)(const cli_command *cmd, cli_opt *o);
};

/* The entries of an option table (an array, not a pointer). */
#define CLI_NOPTS(t) ((int)(sizeof(t) / sizeof((t)[0])))

/* The most options one command takes (augment: 29). */
enum { CLI_OPTS_MAX = 64 };

/* Runs cmd on argv (argv[0] = the command name) as its definition says
 * (above); returns the exit status. */
int cli_run(const cli_command *cmd, int argc, char **argv);

/* The command line cli_run ran ("gazesplat NAME ARG..." as given, cut at
 * cap), for a command's report; "gazesplat" outside cli_run. */
void cli_command_line(char *buf, size_t cap);

/* The subcommands, defined in their own files. */
extern const cli_command cli_face_command;
extern const cli_command cli_client_command;
extern const cli_command cli_render_command;
extern const cli_command cli_scene_command;
extern const cli_command cli_synth_command;
extern const cli_command cli_train_command;
extern const cli_command cli_fit_command;
extern const cli_command cli_redirect_command;
extern const cli_command cli_live_command;
extern const cli_command cli_train_estimator_command;
extern const cli_command cli_estimate_command;
extern const cli_command cli_eval_estimator_command;
extern const cli_command cli_eval_command;
extern const cli_command cli_eval_downstream_command;
extern const cli_command cli_eval_range_command;
extern const cli_command cli_model_command;
extern const cli_command cli_augment_command;
extern const cli_command cli_eval_photos_command;
extern const cli_command cli_check_labels_command;

/* CLI_HELP is no exit status (every command turns it into CLI_OK); it is
 * negative so that it can never be read as one (CLI_REFUSED is 3). */
enum { CLI_PARSED = 0, CLI_HELP = -1 };

/* A macro's value as a string literal (a default option value). */
#define CLI_STR_(x) #x
#define CLI_STR(x) CLI_STR_(x)

/* Fills opts from argv[1..]. Returns CLI_PARSED, CLI_HELP for --help/-h,
 * or CLI_USAGE after printing the problem and the usage to stderr. Unknown
 * options, missing values, repeats and positional arguments are errors. */
int cli_parse(const cli_command *cmd, int argc, char **argv, cli_opt *opts, int nopts);

/* Prints "gazesplat NAME: <message>" and the usage to stderr; returns
 * CLI_USAGE. */
int cli_usage_error(const cli_command *cmd, const char *fmt, ...)
    __attribute__((format(printf, 2, 3)));

/* Prints "gazesplat NAME: <message>" to stderr; returns CLI_FAIL. */
int cli_fail(const cli_command *cmd, const char *fmt, ...)
    __attribute__((format(printf, 2, 3)));

/* Exactly n comma-separated finite floats. Returns 0 or -1. */
int cli_parse_floats(const char *s, float *out, int n);

/* Target angles, degrees: one "P,Y" (list 0) or "P,Y;P,Y;..." (list 1,
 * 1..max pairs) into out[0..*n-1], each pair a gaze (head 0) or a head
 * pose (head 1) checked against the target table (gazesplat/model.h,
 * inclusive ranges) before any work. Each number is a plain decimal
 * (digits, sign, point, exponent). Refused, as a usage error naming flag:
 * an empty list or item, a missing or extra number, trailing junk, NaN,
 * Inf, overflow, a value outside its range (the message names the field
 * and the range). Returns CLI_OK or CLI_USAGE (reported). */
int cli_parse_angles(const cli_command *cmd, const char *flag, const char *s, int list, int head,
                     double (*out)[2], int max, int *n);

/* The labels of n images, one item each separated by ';': "P,Y" degrees
 * (checked as cli_parse_angles does) or "-" for an image without that
 * label; known[i] says which. n = 1 takes one "P,Y" as before. A wrong
 * count of items is a usage error naming flag. Returns CLI_OK or
 * CLI_USAGE (reported). */
int cli_parse_image_labels(const cli_command *cmd, const char *flag, const char *s, int head,
                           int n, double (*out)[2], int *known);
/* A comma-separated list of at most max paths: *buf (malloc'd, free it)
 * holds them, out[] points into it. An empty list or item is a usage
 * error naming flag. Returns CLI_OK or CLI_USAGE (reported). */
int cli_split_paths(const cli_command *cmd, const char *flag, const char *s, int max, char **buf,
                    const char **out, int *n);

/* A decimal integer in [lo, hi]. Returns 0 or -1. */
int cli_parse_long(const char *s, long lo, long hi, long *out);

/* --fit-lr's "CODE[,COLOUR]": each in (0, 10] (doubles, as given); COLOUR
 * defaults to CODE / 6, the defaults' ratio. Returns 0 or -1. */
int cli_parse_fit_lr(const char *s, double *code, double *colour);
/* --kappa off | literature | H,HSD,V,VSD (degrees) into *k; CLI_PARSED,
 * or a usage error of cmd naming the option. */
struct gs_synth_kappa;
int cli_parse_kappa(const cli_command *cmd, const char *v,
                    struct gs_synth_kappa *k);

/* A rate: a finite decimal number in (0, hi], read as a double (so 0.004
 * on the command line is the 0.004 a protocol field or a config key
 * holds). Returns 0 or -1. */
int cli_parse_rate(const char *s, double hi, double *out);

/* "WxH", each in [1, max]. Returns 0 or -1. */
int cli_parse_size(const char *s, int max, int *w, int *h);

/* A number in [0, 1] from flag's value into *out (unchanged when value is
 * NULL). Returns CLI_OK or CLI_USAGE (reported). */
int cli_parse_unit(const cli_command *cmd, const char *flag, const char *value, double *out);
/* A number in [lo, hi] from flag's value into *out (unchanged when value
 * is NULL); refused with "FLAG: want WANT; got 'VALUE'". Returns CLI_OK or
 * CLI_USAGE (reported). */
int cli_parse_range(const cli_command *cmd, const char *flag, const char *value, double lo,
                    double hi, const char *want, double *out);
/* --transfer-eye-warp's range, as cli_parse_range's WANT */
#define CLI_WARP_WANT "degrees in [0, 90] (0: off)"

/* --finetune N, --finetune-parts LIST, --finetune-lr X, --finetune-plateau
 * R, --finetune-outline PX, --finetune-mirror 0|1 (any may be NULL) into
 * fo: fo->iters 0 when N
 * is absent. The others without N are a usage error. Returns CLI_OK or
 * CLI_USAGE (reported). */
struct gs_finetune_options;
int cli_parse_finetune(const cli_command *cmd, const char *n, const char *parts, const char *lr,
                       const char *plateau, const char *outline, const char *mirror,
                       struct gs_finetune_options *fo);

/* CLOCK_MONOTONIC in seconds. */
double cli_now_s(void);

/* Progress on stderr. On a terminal one line is rewritten in place (as
 * often as it is called, at most 10 times a second); anywhere else (a log
 * file, a pipe, journald) each report is a line of its own, at most one
 * every 10 s, and never a carriage return; `force` reports now whatever
 * the rate. cli_progress_done ends it: on a terminal the line is cleared
 * for what reports the result. */
typedef struct cli_progress_t {
    int tty, drawn;
    double last, start;
} cli_progress_t;
void cli_progress_start(cli_progress_t *p);
void cli_progress(cli_progress_t *p, int force, const char *fmt, ...) __attribute__((format(printf, 3, 4)));
void cli_progress_done(cli_progress_t *p);

/* Reads a regular file of 1..max bytes whole into *out (malloc'd).
 * Returns 0, or -1 (missing, empty, too large, unreadable; *out NULL). */
int cli_read_file(const char *path, size_t max, uint8_t **out, size_t *len);
/* Writes all n bytes to fd (EINTR retried; a write of 0 is ENOSPC).
 * Returns 0 or -1 with errno. */
int cli_write_all(int fd, const void *p, size_t n);
/* fsync of a file or directory by path: 0 or -1 with errno. */
int cli_fsync_path(const char *path);

/* A shipped model file by name (e.g. the gaze estimator
 * "gaze-resnet.safetensors"): the one in the models folder of the current
 * directory (a source tree), else the installed copy in the models folder
 * of the package's data directory (GS_CLI_DATADIR), else the relative path
 * (so that the error names it). The returned string is static. */
const char *cli_shipped_model(const char *name);

/* Demo scene (demo_head.c): a stylised head, see cmd_scene.c. */
struct gs_ply_scene;
int cli_demo_head(unsigned long seed, struct gs_ply_scene *out);

#endif
