/* Expression-guided neural renderer (internal to lib/model).
 *
 * Turns a rasterized feature map x [C, H, W] and a latent code tau [D] into
 * an RGB image [3, 4H, 4W] in [0, 1]: two upsampling blocks of 1x1
 * convolutions (GazeGaussian / GazeNeRF), each followed by the expression
 * guidance, where tau attends over the pixels of the block's features.
 * docs/model.md ("Renderer") has the diagram, the parameter names and the
 * cost per pixel.
 *
 * Conventions are those of gazesplat/nn.h (llm.c style): CHW float32,
 * forward writes, backward ADDS into every gradient it is given, nothing
 * allocates, every call returns GS_OK or a negative gs_status (GS_ERR_ARG
 * for NULLs, bad sizes, short buffers, an invalid config; GS_ERR_LIMIT for
 * sizes whose arithmetic would overflow).
 *
 * Threads: forward and backward run their passes on an optional gs_pool
 * (NULL: the calling thread), split by a partition that depends on the
 * sizes only, so the result is the same bytes for any pool, provided
 * OpenBLAS runs one thread (gs_nn_blas_set_threads(1), see nn.h). The pool
 * must not be running another gs_pool_for at the same time (pool.h).
 *
 * All parameters live in ONE float array; gs_renderer_bind carves the named
 * pointers out of it (and out of a gradient array of the same layout), and
 * gs_renderer_layout describes each tensor (name, shape, offset) for the
 * model file. */
#ifndef GS_MODEL_RENDERER_H
#define GS_MODEL_RENDERER_H

#include <stddef.h>
#include <stdint.h>

#include "gazesplat/error.h"
#include "gazesplat/pool.h"

/* Expression guidance after each block (u [C,HW] -> g [C,HW]), with
 *   s = wk^T tau / sqrt(D)                 [C]   (wk [D,C])
 *   att = softmax_p(u_p . s)                [HW]  (over all pixels)
 *   a = wv (sum_p att_p u_p) + bv           [C]   (wv [C,C], bv [C])
 * NONE:           g = u (the "plain renderer" ablation; no guide tensors).
 * ADDITIVE:       g_p = u_p + a (the released GazeGaussian code; the key
 *                 bias of that code cancels in the softmax and is omitted).
 * MULTIPLICATIVE: g_p = u_p + u_p * a, elementwise (paper Eq. 9,
 *                 z' = z + z . Attn(q = tau, k = z, v = z)). */
/* Where the guidance vector comes from (for ADDITIVE and MULTIPLICATIVE):
 * BLOCK: as above, each block's vector from attention over that block's
 *        own u (the released GazeGaussian code). The vector depends on
 *        every pixel, so a change anywhere changes the whole image.
 * SOURCE: ONE vector a from attention of tau over a separate source map
 *        src [C, H, W] (the model passes its face stream's feature map),
 *        applied in both blocks. The renderer is then local given a: a
 *        feature pixel influences only output pixels near it, which makes
 *        exact incremental renders of gaze changes possible (the face stream
 *        does not depend on the gaze). */
typedef enum gs_renderer_guide_source {
    GS_GUIDE_SRC_BLOCK = 0,
    GS_GUIDE_SRC_SOURCE = 1
} gs_renderer_guide_source;

typedef enum gs_renderer_guidance {
    GS_GUIDE_NONE = 0,
    GS_GUIDE_ADDITIVE = 1,
    GS_GUIDE_MULTIPLICATIVE = 2
} gs_renderer_guidance;

#define GS_RENDERER_BLOCKS 2
#define GS_RENDERER_MAX_CHANNELS 256
#define GS_RENDERER_MAX_CODE 256
#define GS_RENDERER_MAX_SIDE 2048 /* feature map H, W; the image is 4x */

typedef struct gs_renderer_config {
    int channels; /* C, feature channels (32); the blocks are C->2C->4C */
    int code_dim; /* D, 1..GS_RENDERER_MAX_CODE */
    int guidance; /* gs_renderer_guidance */
    int blocks;   /* must be GS_RENDERER_BLOCKS */
    int guide_source; /* gs_renderer_guide_source */
} gs_renderer_config;

/* Output pixels (at 4x) that a change of feature pixel (i, j) can reach lie
 * within GS_RENDERER_REACH feature pixels of it (i.e. 4 (i +- REACH)), when
 * the guidance source is SOURCE or there is no guidance: the only spatial
 * operators are the 3x3 blurs, the bilinear 2x upsamplings and the pixel
 * shuffles (test_renderer checks the bound on impulses). */
#define GS_RENDERER_REACH 2
/* The same in output pixels: a change of feature pixel (i, j) reaches
 * output rows (and columns) 4 i - 6 .. 4 i + 9 and no further, the bilinear
 * upsamplings and the blurs of the RGB path adding 1 + 1 pixels at 2x and
 * 1 + 1 at 4x. Conversely an output pixel of a crop at least this far from
 * the crop's cut edges equals the full render's. */
#define GS_RENDERER_REACH_PX 6

/* GS_OK, or GS_ERR_ARG with a message naming the bad field. */
int gs_renderer_config_validate(const gs_renderer_config *cfg, gs_error *err);

/* ---- Parameters --------------------------------------------------------- */

typedef struct gs_renderer_conv {
    float *w; /* [out, in] */
    float *b; /* [out] */
} gs_renderer_conv;

typedef struct gs_renderer_params {
    gs_renderer_conv rgb0; /* C -> 3 on the input features */
    struct {
        gs_renderer_conv a;   /* C -> 2C */
        gs_renderer_conv b;   /* 2C -> 4C */
        gs_renderer_conv c;   /* C -> C, after the shuffle and blur */
        gs_renderer_conv rgb; /* C -> 3 */
    } block[GS_RENDERER_BLOCKS];
    /* Guidance, shared by both blocks; NULL for GS_GUIDE_NONE. */
    float *key_w;   /* [D, C] */
    float *value_w; /* [C, C] */
    float *value_b; /* [C] */
} gs_renderer_params;

#define GS_RENDERER_MAX_TENSORS 21
#define GS_RENDERER_NAME_MAX 48

/* One named tensor of the parameter array, in file order. */
typedef struct gs_renderer_tensor {
    char name[GS_RENDERER_NAME_MAX]; /* "renderer.block0.conv_a.weight" */
    int rank;                        /* 2 for weights, 1 for biases */
    int shape[2];                    /* [out, in] or [out] (shape[1] = 1) */
    size_t offset;                   /* floats from the start of the array */
    size_t count;                    /* floats */
} gs_renderer_tensor;

/* Number of floats of the parameter array; 0 for an invalid config. */
size_t gs_renderer_param_count(const gs_renderer_config *cfg);

/* Fills table[0 .. *count) (cap >= GS_RENDERER_MAX_TENSORS is always
 * enough); the tensors tile the array in order, without gaps. */
int gs_renderer_layout(const gs_renderer_config *cfg,
                       gs_renderer_tensor *table, int cap, int *count);

/* Points *p into base[n] (n >= gs_renderer_param_count). Works for the
 * parameters and for a gradient array alike. */
int gs_renderer_bind(const gs_renderer_config *cfg, float *base, size_t n,
                     gs_renderer_params *p);

/* Deterministic initialisation of base[n] from seed (same seed, same
 * bytes): PyTorch's default Conv2d bounds, weights and biases uniform in
 * +-1/sqrt(fan_in); the guidance value wv and bv are zero so the guidance
 * starts as the identity (see renderer.c). */
int gs_renderer_init(const gs_renderer_config *cfg, float *base, size_t n,
                     uint64_t seed);

/* ---- Forward and backward ------------------------------------------------ */

/* Floats of the activation buffer for an H x W feature map (everything the
 * backward needs, plus its scratch); 0 for invalid sizes or config. */
size_t gs_renderer_act_size(const gs_renderer_config *cfg, int H, int W);
/* Floats a forward needs when no backward follows (renders): the blocks'
 * maps share two ping-pong buffers, about a third of gs_renderer_act_size
 * (24 MB against 72 MB at 64^2, C = 32, D = 144). Every forward below takes a
 * buffer of either size: at least gs_renderer_act_size keeps what the
 * backward reads; a smaller one (at least this) keeps nothing, and no
 * backward may use it. The output is the same bytes either way. */
size_t gs_renderer_fwd_size(const gs_renderer_config *cfg, int H, int W);

/* out_rgb[3, 4H, 4W] in [0,1] from x[C, H, W] and tau[D] (tau may be NULL
 * for GS_GUIDE_NONE). acts[acts_len] receives the saved activations. */
int gs_renderer_forward(const gs_renderer_config *cfg,
                        const gs_renderer_params *p, const float *x,
                        const float *tau, int H, int W, float *acts,
                        size_t acts_len, float *out_rgb, gs_pool *pool);

/* With a guidance source (SOURCE): the same, the vector from src [C,H,W]
 * (NULL: x itself). Other configs ignore src. */
int gs_renderer_forward_src(const gs_renderer_config *cfg,
                            const gs_renderer_params *p, const float *x,
                            const float *tau, const float *src, int H, int W,
                            float *acts, size_t acts_len, float *out_rgb,
                            gs_pool *pool);

/* The guidance vector a [C] of src [C,H,W] (SOURCE configs only): what
 * gs_renderer_forward_src computes before the blocks. acts as for a
 * forward of that size. */
int gs_renderer_guide_vector(const gs_renderer_config *cfg,
                             const gs_renderer_params *p, const float *src,
                             const float *tau, int H, int W, float *acts,
                             size_t acts_len, float *a, gs_pool *pool);

/* Forward with a given guidance vector a [C] (SOURCE configs; NONE ignores
 * a): renders any crop of a feature map exactly as the full map would,
 * away from the crop's cut edges (GS_RENDERER_REACH). No backward. */
int gs_renderer_forward_vec(const gs_renderer_config *cfg,
                            const gs_renderer_params *p, const float *x,
                            const float *a, int H, int W, float *acts,
                            size_t acts_len, float *out_rgb, gs_pool *pool);

/* Gradients from dout_rgb[3, 4H, 4W], with acts as left by the forward of
 * the same x, tau, H, W (its scratch part is overwritten; the saved part is
 * not, so backward may run again). ADDS into dparams (bound to a gradient
 * array with gs_renderer_bind; NULL: no weight gradients, the input
 * gradients alone, the same bits), dx[C, H, W]
 * and dtau[D] (both may be NULL). */
int gs_renderer_backward(const gs_renderer_config *cfg,
                         const gs_renderer_params *p, float *acts,
                         size_t acts_len, const float *x, const float *tau,
                         const float *dout_rgb, int H, int W,
                         const gs_renderer_params *dparams, float *dx,
                         float *dtau, gs_pool *pool);

/* Backward of gs_renderer_forward_src: also adds into dsrc [C,H,W] (may be
 * NULL; when src was NULL the source gradient goes to dx). */
int gs_renderer_backward_src(const gs_renderer_config *cfg,
                             const gs_renderer_params *p, float *acts,
                             size_t acts_len, const float *x,
                             const float *tau, const float *src,
                             const float *dout_rgb, int H, int W,
                             const gs_renderer_params *dparams, float *dx,
                             float *dsrc, float *dtau, gs_pool *pool);

#endif
