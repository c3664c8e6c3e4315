// dlib as the reference for the face tests (built only with the tests,
// linked with Debian's libdlib). Reads a binary PPM (P6) so that dlib sees
// exactly the pixels our decoder produced.
//
//   dlib_ref landmarks MODEL IMAGE.ppm N L T R B ... [IMAGE.ppm N ...]
//       68 lines "x y" per box (N boxes per image): dlib::shape_predictor's
//       points; the model is read once
//   dlib_ref hog IMAGE.ppm [UPSAMPLE]
//       one line "L T R B" per face of dlib's HOG frontal face detector
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <iostream>
#include <string>

#include <dlib/image_processing.h>
#include <dlib/image_processing/frontal_face_detector.h>
#include <dlib/image_transforms.h>

namespace {

bool read_ppm(const char *path, dlib::array2d<dlib::rgb_pixel> &img)
{
    std::ifstream f(path, std::ios::binary);
    std::string magic;
    long w = 0, h = 0, maxv = 0;
    f >> magic >> w >> h >> maxv;
    if (!f || magic != "P6" || w < 1 || h < 1 || maxv != 255)
        return false;
    f.get();
    img.set_size(h, w);
    for (long y = 0; y < h; y++)
        for (long x = 0; x < w; x++) {
            unsigned char p[3];
            if (!f.read(reinterpret_cast<char *>(p), 3))
                return false;
            img[y][x] = dlib::rgb_pixel(p[0], p[1], p[2]);
        }
    return true;
}

int landmarks(int argc, char **argv)
{
    if (argc < 5)
        return 2;
    dlib::shape_predictor sp;
    dlib::deserialize(argv[2]) >> sp;
    int i = 3;
    while (i + 1 < argc) {
        dlib::array2d<dlib::rgb_pixel> img;
        if (!read_ppm(argv[i], img))
            return 1;
        const int n = atoi(argv[i + 1]);
        i += 2;
        if (n < 0 || i + 4 * n > argc)
            return 2;
        for (int b = 0; b < n; b++, i += 4) {
            dlib::rectangle r(atol(argv[i]), atol(argv[i + 1]), atol(argv[i + 2]),
                              atol(argv[i + 3]));
            dlib::full_object_detection d = sp(img, r);
            for (unsigned long k = 0; k < d.num_parts(); k++)
                std::printf("%ld %ld\n", d.part(k).x(), d.part(k).y());
        }
    }
    return i == argc ? 0 : 2;
}

int hog(int argc, char **argv)
{
    if (argc < 3)
        return 2;
    dlib::array2d<dlib::rgb_pixel> img;
    if (!read_ppm(argv[2], img))
        return 1;
    int up = argc > 3 ? atoi(argv[3]) : 1;
    for (int i = 0; i < up; i++)
        dlib::pyramid_up(img);
    dlib::frontal_face_detector det = dlib::get_frontal_face_detector();
    dlib::pyramid_down<2> pyr;
    for (const dlib::rectangle &d : det(img)) {
        // Back to the original image, as dlib's Python API does it.
        const dlib::rectangle r = pyr.rect_down(d, (unsigned)up);
        std::printf("%ld %ld %ld %ld\n", r.left(), r.top(), r.right(), r.bottom());
    }
    return 0;
}

} // namespace

int main(int argc, char **argv)
{
    try {
        if (argc > 1 && !std::strcmp(argv[1], "landmarks"))
            return landmarks(argc, argv);
        if (argc > 1 && !std::strcmp(argv[1], "hog"))
            return hog(argc, argv);
    } catch (const std::exception &e) {
        std::fprintf(stderr, "dlib_ref: %s\n", e.what());
        return 1;
    }
    std::fprintf(stderr, "usage: dlib_ref landmarks MODEL IMAGE.ppm L T R B ... | hog IMAGE.ppm [UP]\n");
    return 2;
}
