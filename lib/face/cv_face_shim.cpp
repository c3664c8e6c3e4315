// OpenCV behind a C interface for lib/face: cascade detection (objdetect),
// solvePnP (calib3d) and warpPerspective (imgproc). Every entry point
// catches every exception and returns a gs_status.
#include "cv_face_shim.h"

#include <cstdlib>
#include <new>
#include <vector>

#include <opencv2/calib3d.hpp>
#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>
#include <opencv2/objdetect.hpp>

struct gs_cvf_cascade {
    cv::CascadeClassifier cc;
};

namespace {

// Wraps an RGB gs_io_image without copying (3 channels, its stride).
cv::Mat wrap(const gs_io_image *img)
{
    return cv::Mat(img->height, img->width, CV_8UC3, img->data, img->stride);
}

// Grey with integer BT.601 weights, a plain loop (no OpenCV threads).
cv::Mat grey_of(const gs_io_image *img)
{
    cv::Mat g(img->height, img->width, CV_8UC1);
    for (int y = 0; y < img->height; y++) {
        const unsigned char *s = img->data + (size_t)y * img->stride;
        unsigned char *d = g.ptr<unsigned char>(y);
        for (int x = 0; x < img->width; x++)
            d[x] = (unsigned char)((77 * s[3 * x] + 150 * s[3 * x + 1] + 29 * s[3 * x + 2] + 128) >> 8);
    }
    return g;
}

int fail_exc(gs_error *err, const char *what)
{
    try {
        throw;
    } catch (const std::bad_alloc &) {
        return gs_error_set(err, GS_ERR_NOMEM, "%s: out of memory", what);
    } catch (const std::exception &e) {
        return gs_error_set(err, GS_ERR_ARG, "%s: OpenCV: %.200s", what, e.what());
    } catch (...) {
        return gs_error_set(err, GS_ERR_ARG, "%s: OpenCV failed", what);
    }
}

} // namespace

extern "C" int gs_cvf_cascade_load(const char *path, gs_cvf_cascade **out, gs_error *err)
{
    try {
        gs_cvf_cascade *c = new gs_cvf_cascade;
        if (!c->cc.load(path) || c->cc.empty()) {
            delete c;
            return gs_error_set(err, GS_ERR_IO, "face detector: cannot load cascade %.200s", path);
        }
        *out = c;
        return GS_OK;
    } catch (...) {
        return fail_exc(err, "face detector");
    }
}

extern "C" void gs_cvf_cascade_free(gs_cvf_cascade *c)
{
    delete c;
}

extern "C" int gs_cvf_detect(gs_cvf_cascade *c, const gs_io_image *img, double scale_factor,
                             int min_neighbors, int min_size, int **rects, int *n, gs_error *err)
{
    try {
        cv::Mat g = grey_of(img);
        cv::equalizeHist(g, g);
        std::vector<cv::Rect> found;
        c->cc.detectMultiScale(g, found, scale_factor, min_neighbors, 0,
                               cv::Size(min_size, min_size));
        int *r = nullptr;
        if (!found.empty()) {
            r = static_cast<int *>(std::malloc(found.size() * 4 * sizeof(int)));
            if (!r)
                return gs_error_set(err, GS_ERR_NOMEM, "face detector: out of memory");
            for (size_t i = 0; i < found.size(); i++) {
                r[4 * i] = found[i].x;
                r[4 * i + 1] = found[i].y;
                r[4 * i + 2] = found[i].width;
                r[4 * i + 3] = found[i].height;
            }
        }
        *rects = r;
        *n = (int)found.size();
        return GS_OK;
    } catch (...) {
        return fail_exc(err, "face detector");
    }
}

extern "C" int gs_cvf_solve_pnp(const double (*obj)[3], const double (*img)[2], int n,
                                const double k[9], double rvec[3], double tvec[3], gs_error *err)
{
    try {
        std::vector<cv::Point3d> o;
        std::vector<cv::Point2d> p;
        for (int i = 0; i < n; i++) {
            o.emplace_back(obj[i][0], obj[i][1], obj[i][2]);
            p.emplace_back(img[i][0], img[i][1]);
        }
        cv::Mat km(3, 3, CV_64F, const_cast<double *>(k));
        cv::Mat r, t;
        if (!cv::solvePnP(o, p, km, cv::noArray(), r, t, false, cv::SOLVEPNP_EPNP))
            return gs_error_set(err, GS_ERR_ARG, "head pose: EPnP found no solution");
        if (!cv::solvePnP(o, p, km, cv::noArray(), r, t, true, cv::SOLVEPNP_ITERATIVE))
            return gs_error_set(err, GS_ERR_ARG, "head pose: refinement failed");
        for (int i = 0; i < 3; i++) {
            rvec[i] = r.at<double>(i);
            tvec[i] = t.at<double>(i);
        }
        return GS_OK;
    } catch (...) {
        return fail_exc(err, "head pose");
    }
}

extern "C" int gs_cvf_warp(const gs_io_image *src, gs_io_image *dst, const double m[9],
                           gs_error *err)
{
    try {
        cv::Mat mm(3, 3, CV_64F, const_cast<double *>(m));
        cv::Mat d = wrap(dst);
        cv::warpPerspective(wrap(src), d, mm, d.size(), cv::INTER_LINEAR | cv::WARP_INVERSE_MAP,
                            cv::BORDER_CONSTANT, cv::Scalar(0, 0, 0));
        return GS_OK;
    } catch (...) {
        return fail_exc(err, "warp");
    }
}
