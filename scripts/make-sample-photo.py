#!/usr/bin/python3
"""Makes samples/astronaut.jpg, the photo the demo redirects: the head and
shoulders of scikit-image's astronaut image (Eileen Collins, NASA; public
domain), cropped to 288 x 288 px around the face and scaled to 512 x 512,
JPEG quality 90. Needs Debian's python3-skimage and python3-pil.
usage: scripts/make-sample-photo.py [OUT]"""
import os
import sys

from PIL import Image
from skimage import data

# (left, top, right, bottom) in the 512 x 512 original: the face sits near
# x 175..275, y 60..180; the crop keeps the hair and the collar.
CROP = (80, 0, 368, 288)
SIZE = 512


def main():
    here = os.path.dirname(os.path.abspath(__file__))
    out = sys.argv[1] if len(sys.argv) > 1 else os.path.join(here, "..", "samples", "astronaut.jpg")
    img = Image.fromarray(data.astronaut()).crop(CROP).resize((SIZE, SIZE), Image.LANCZOS)
    img.save(out, "JPEG", quality=90, optimize=True)
    print("wrote %s (%d bytes)" % (out, os.path.getsize(out)))


if __name__ == "__main__":
    main()
