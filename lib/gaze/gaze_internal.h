/* gs_gaze internals: the layer graph, per-thread contexts, the resize. */
#ifndef GS_GAZE_INTERNAL_H
#define GS_GAZE_INTERNAL_H

#include <stddef.h>
#include <stdint.h>

#include "gazesplat/gaze.h"

enum { GZ_CONV3, GZ_CONV1, GZ_RELU, GZ_POOL, GZ_ADD, GZ_LINEAR };
enum { GZ_MAX_OPS = 64, GZ_MAX_BUFS = 64, GZ_MAX_TENSORS = 48 };

/* One layer: reads buffer in (and in2 for GZ_ADD), writes buffer out.
 * C, H, W: the input's shape; OC: output channels (conv) or units
 * (linear, whose input is the flattened C*H*W buffer); wt: index of the
 * weight tensor, the bias is wt + 1 (-1 for parameter-free layers). */
typedef struct gz_op {
    int kind, in, in2, out, C, H, W, OC, wt;
} gz_op;

typedef struct gz_tensor {
    char name[32];
    int ndim;
    int64_t shape[4];
    size_t off, count;
    int fan_in;   /* for He initialisation; 0 for a bias */
} gz_tensor;

typedef struct gz_buf {
    int C, H, W;
    size_t off, len;  /* in the activation array */
} gz_buf;

/* Buffer 0 is the whole face [3,N,N]; buffer 1 the eye band [3,Eh,Ew], the
 * window gz_eye_window of the image (both eyes for head poses within the
 * training range), at twice the face's resolution. */
typedef struct gz_graph {
    int nops, nbufs, ntensors;
    gz_op op[GZ_MAX_OPS];
    gz_buf buf[GZ_MAX_BUFS];
    gz_tensor t[GZ_MAX_TENSORS];
    size_t act_len, nparams, scratch_len;
} gz_graph;

/* Activations of one forward, their gradients and scratch (per thread). */
typedef struct gz_ctx {
    float *act, *dact, *scratch;
    float *tmp;        /* resize rows [3, src_h, N] */
    size_t tmp_cap;
    float *img;        /* uint8 input converted, [3, h, w] */
    size_t img_cap;
    int src_w, src_h, have_forward;
} gz_ctx;

struct gs_gaze_net {
    gs_gaze_spec spec;
    gz_graph g;
    float *params;
    gz_ctx ctx;
};

/* graph.c */
int gz_spec_check(const gs_gaze_spec *s, gs_error *err);
int gz_graph_build(const gs_gaze_spec *s, gz_graph *g, gs_error *err);
void gz_eye_size(int N, int *Eh, int *Ew);
int gz_net_alloc(const gs_gaze_spec *s, gs_gaze_net **out, gs_error *err);

/* net.c */
int gz_ctx_init(gz_ctx *c, const gz_graph *g);
void gz_ctx_free(gz_ctx *c);
int gz_forward(const gz_graph *g, const float *params, gz_ctx *c,
               const float *img, int w, int h, float out[4]);
int gz_backward(const gz_graph *g, const float *params, gz_ctx *c,
                const float dout[4], float *dimg, float *dparams);
/* img[3,h,w] floats from 8-bit RGB (/255) into c->img. */
int gz_ctx_from_rgb(gz_ctx *c, const uint8_t *rgb, int w, int h,
                    size_t stride);

/* resize.c: area (box) resize of a window of [C,h,w] (fractions of the
 * width and height) to [C,Nh,Nw], and its adjoint. tmp: C * h * Nw floats. */
typedef struct gz_window {
    double x0, x1, y0, y1;
} gz_window;
extern const gz_window gz_full_window, gz_eye_window;
void gz_resize_forward(float *out, const float *in, int C, int w, int h,
                       const gz_window *wd, int Nw, int Nh, float *tmp);
void gz_resize_adjoint(float *din, const float *dout, int C, int w, int h,
                       const gz_window *wd, int Nw, int Nh, float *tmp);

#endif
