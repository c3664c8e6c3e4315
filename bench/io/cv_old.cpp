// The OpenCV imgcodecs path lib/io used before it called libjpeg and
// libpng itself (cv::imdecode with IMREAD_COLOR, cv::imencode), kept here
// only so bench_image can hold the two side by side: same pixels, same
// bytes, speed. Only this benchmark links imgcodecs.
#include "cv_old.h"

#include <climits>
#include <cstdlib>
#include <cstring>
#include <vector>

#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>

extern "C" int cvold_decode(const unsigned char *buf, size_t len, gs_io_image *out)
{
    try {
        if (len > (size_t)INT_MAX)
            return -1;
        const cv::Mat raw(1, (int)len, CV_8UC1, const_cast<unsigned char *>(buf));
        const cv::Mat bgr = cv::imdecode(raw, cv::IMREAD_COLOR);
        if (bgr.empty() || bgr.type() != CV_8UC3)
            return -1;
        const size_t w = (size_t)bgr.cols, h = (size_t)bgr.rows;
        unsigned char *rgb = static_cast<unsigned char *>(std::malloc(w * h * 3));
        if (!rgb)
            return -1;
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
        return 0;
    } catch (...) {
        return -1;
    }
}

extern "C" int cvold_encode(const gs_io_image *img, gs_io_format format, int quality,
                            unsigned char **out, size_t *out_len)
{
    try {
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
        if (format == GS_IO_JPEG)
            params = {cv::IMWRITE_JPEG_QUALITY, quality};
        else
            params = {cv::IMWRITE_PNG_COMPRESSION, quality};
        std::vector<unsigned char> enc;
        if (!cv::imencode(format == GS_IO_JPEG ? ".jpg" : ".png", bgr, enc, params))
            return -1;
        unsigned char *b = static_cast<unsigned char *>(std::malloc(enc.size()));
        if (!b)
            return -1;
        std::memcpy(b, enc.data(), enc.size());
        *out = b;
        *out_len = enc.size();
        return 0;
    } catch (...) {
        return -1;
    }
}
