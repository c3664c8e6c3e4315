// OpenCV behind a C interface. Nothing C++ escapes: every entry point
// catches every exception and returns a gs_status. Channel order is swapped
// here with plain loops (no cv::cvtColor, so OpenCV starts no threads).
#include "cv_shim.h"

#include <climits>
#include <cstdlib>
#include <cstring>
#include <new>
#include <vector>

#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>

namespace {

int decode_impl(const unsigned char *buf, size_t len, size_t max_pixels,
                gs_io_image *out, gs_error *err)
{
    if (len > (size_t)INT_MAX)
        return gs_error_set(err, GS_ERR_LIMIT, "image: %zu bytes too large to decode", len);
    const cv::Mat raw(1, (int)len, CV_8UC1, const_cast<unsigned char *>(buf));
    const cv::Mat bgr = cv::imdecode(raw, cv::IMREAD_COLOR);
    if (bgr.empty())
        return gs_error_set(err, GS_ERR_FORMAT, "image: corrupt data (decoder refused it)");
    if (bgr.type() != CV_8UC3 || bgr.dims != 2)
        return gs_error_set(err, GS_ERR_FORMAT, "image: decoder returned type %d", bgr.type());
    const size_t w = (size_t)bgr.cols, h = (size_t)bgr.rows;
    if (w * h > max_pixels)
        return gs_error_set(err, GS_ERR_LIMIT, "image: %zux%zu over the pixel limit", w, h);
    unsigned char *rgb = static_cast<unsigned char *>(std::malloc(w * h * 3));
    if (!rgb)
        return gs_error_set(err, GS_ERR_NOMEM, "image: cannot allocate %zux%zu", w, h);
    for (size_t y = 0; y < h; y++) {
        const unsigned char *s = bgr.ptr<unsigned char>((int)y);
        unsigned char *d = rgb + y * w * 3;
        for (size_t x = 0; x < w; x++) {
            d[3 * x + 0] = s[3 * x + 2];
            d[3 * x + 1] = s[3 * x + 1];
            d[3 * x + 2] = s[3 * x + 0];
        }
    }
    out->width = (int)w;
    out->height = (int)h;
    out->stride = w * 3;
    out->data = rgb;
    return GS_OK;
}

int encode_impl(const gs_io_image *img, gs_io_format format, int quality,
                unsigned char **out, size_t *out_len, gs_error *err)
{
    cv::Mat bgr(img->height, img->width, CV_8UC3);
    for (int y = 0; y < img->height; y++) {
        const unsigned char *s = img->data + (size_t)y * img->stride;
        unsigned char *d = bgr.ptr<unsigned char>(y);
        for (int x = 0; x < img->width; x++) {
            d[3 * x + 0] = s[3 * x + 2];
            d[3 * x + 1] = s[3 * x + 1];
            d[3 * x + 2] = s[3 * x + 0];
        }
    }
    std::vector<int> params;
    const char *ext = ".png";
    if (format == GS_IO_JPEG) {
        ext = ".jpg";
        params = {cv::IMWRITE_JPEG_QUALITY, quality};
    } else {
        params = {cv::IMWRITE_PNG_COMPRESSION, quality};
    }
    std::vector<unsigned char> enc;
    if (!cv::imencode(ext, bgr, enc, params) || enc.empty())
        return gs_error_set(err, GS_ERR_FORMAT, "image: encoder failed");
    unsigned char *buf = static_cast<unsigned char *>(std::malloc(enc.size()));
    if (!buf)
        return gs_error_set(err, GS_ERR_NOMEM, "image: cannot allocate %zu bytes", enc.size());
    std::memcpy(buf, enc.data(), enc.size());
    *out = buf;
    *out_len = enc.size();
    return GS_OK;
}

} // namespace

extern "C" int gs_cv_decode(const unsigned char *buf, size_t len, size_t max_pixels,
                            gs_io_image *out, gs_error *err)
{
    try {
        return decode_impl(buf, len, max_pixels, out, err);
    } catch (const std::bad_alloc &) {
        return gs_error_set(err, GS_ERR_NOMEM, "image: out of memory while decoding");
    } catch (const std::exception &e) {
        return gs_error_set(err, GS_ERR_FORMAT, "image: decoder failed: %.200s", e.what());
    } catch (...) {
        return gs_error_set(err, GS_ERR_FORMAT, "image: decoder failed");
    }
}

extern "C" int gs_cv_encode(const gs_io_image *img, gs_io_format format, int quality,
                            unsigned char **out, size_t *out_len, gs_error *err)
{
    try {
        return encode_impl(img, format, quality, out, out_len, err);
    } catch (const std::bad_alloc &) {
        return gs_error_set(err, GS_ERR_NOMEM, "image: out of memory while encoding");
    } catch (const std::exception &e) {
        return gs_error_set(err, GS_ERR_ARG, "image: encoder failed: %.200s", e.what());
    } catch (...) {
        return gs_error_set(err, GS_ERR_ARG, "image: encoder failed");
    }
}
