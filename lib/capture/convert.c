/* YUYV <-> RGB, BT.601 limited range, 16-bit fixed point (coefficients in
 * capture.h), and the MJPEG completeness check. */
#include "gazesplat/capture.h"

static inline uint8_t clamp8(int v)
{
    return (uint8_t)(v < 0 ? 0 : v > 255 ? 255 : v);
}

/* Coefficients times 65536. */
enum {
    K_Y = 76309,    /* 255/219 */
    K_RV = 104597,  /* 1.596 */
    K_GU = 25675,   /* 0.392 */
    K_GV = 53279,   /* 0.813 */
    K_BU = 132201   /* 2.017 */
};

/* src: height x width/2 pairs of (Y0 U Y1 V); dst: height x width x 3. */
void gs_cap_yuyv_to_rgb(const uint8_t *src, size_t src_stride, int width, int height,
                        uint8_t *dst, size_t dst_stride)
{
    for (int y = 0; y < height; y++) {
        const uint8_t *s = src + (size_t)y * src_stride;
        uint8_t *d = dst + (size_t)y * dst_stride;
        for (int x = 0; x + 1 < width; x += 2, s += 4, d += 6) {
            int u = s[1] - 128, v = s[3] - 128;
            int r = K_RV * v + 32768, g = -K_GU * u - K_GV * v + 32768, b = K_BU * u + 32768;
            int y0 = K_Y * (s[0] - 16), y1 = K_Y * (s[2] - 16);
            d[0] = clamp8((y0 + r) >> 16);
            d[1] = clamp8((y0 + g) >> 16);
            d[2] = clamp8((y0 + b) >> 16);
            d[3] = clamp8((y1 + r) >> 16);
            d[4] = clamp8((y1 + g) >> 16);
            d[5] = clamp8((y1 + b) >> 16);
        }
    }
}

/* Y = 16 + (65.481 R + 128.553 G + 24.966 B) / 255, chroma from the pair's
 * summed RGB (hence the shift by 17). Every intermediate stays positive. */
static inline uint8_t luma(int r, int g, int b)
{
    return (uint8_t)(((16 << 16) + 32768 + 16829 * r + 33039 * g + 6416 * b) >> 16);
}

void gs_cap_rgb_to_yuyv(const uint8_t *src, size_t src_stride, int width, int height,
                        uint8_t *dst, size_t dst_stride)
{
    for (int y = 0; y < height; y++) {
        const uint8_t *s = src + (size_t)y * src_stride;
        uint8_t *d = dst + (size_t)y * dst_stride;
        for (int x = 0; x + 1 < width; x += 2, s += 6, d += 4) {
            int r2 = s[0] + s[3], g2 = s[1] + s[4], b2 = s[2] + s[5];
            d[0] = luma(s[0], s[1], s[2]);
            d[1] = clamp8(((128 << 17) + 65536 - 9714 * r2 - 19071 * g2 + 28784 * b2) >> 17);
            d[2] = luma(s[3], s[4], s[5]);
            d[3] = clamp8(((128 << 17) + 65536 + 28784 * r2 - 24103 * g2 - 4681 * b2) >> 17);
        }
    }
}

int gs_cap_mjpeg_complete(const uint8_t *buf, size_t len)
{
    if (len < 4 || buf[0] != 0xFF || buf[1] != 0xD8)
        return 0;
    while (len > 4 && buf[len - 1] == 0)
        len--;
    return buf[len - 2] == 0xFF && buf[len - 1] == 0xD9;
}
