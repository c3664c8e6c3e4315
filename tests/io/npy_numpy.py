"""Cross-check of the C npy code with numpy (run by test_npy_numpy).

usage: npy_numpy.py DIR
Checks the c_*.npy files the C test wrote (values and exact bytes of
np.save), then writes py_*.npy files for the C test to read."""
import io
import sys

import numpy as np


def expected():
    f = (np.arange(24, dtype=np.float32) * 0.5 - 3.0).reshape(2, 3, 4)
    u = (np.arange(60) * 7 % 256).astype(np.uint8).reshape(4, 5, 3)
    return {"c_f32": f, "c_u8": u, "c_scalar": np.float32(2.5), "c_vec": np.arange(7, dtype=np.float32)}


def check_c_files(d):
    bad = 0
    for name, want in expected().items():
        path = f"{d}/{name}.npy"
        got = np.load(path)
        want = np.asarray(want)
        if got.dtype != want.dtype or got.shape != want.shape or not np.array_equal(got, want):
            print(f"{name}: got {got.dtype} {got.shape} {got.ravel()[:5]}, "
                  f"want {want.dtype} {want.shape} {want.ravel()[:5]}")
            bad += 1
        ref = io.BytesIO()
        np.save(ref, want)
        with open(path, "rb") as fh:
            if fh.read() != ref.getvalue():
                print(f"{name}: bytes differ from np.save")
                bad += 1
    return bad


def write_py_files(d):
    f = (np.arange(2 * 3 * 4 * 5, dtype=np.float32) / 8.0 - 4.0).reshape(2, 3, 4, 5)
    np.save(f"{d}/py_f32_4d.npy", f)
    np.save(f"{d}/py_u8_2d.npy", (np.arange(12) * 21 % 256).astype(np.uint8).reshape(3, 4))
    np.save(f"{d}/py_scalar.npy", np.float32(-1.25))
    np.save(f"{d}/py_empty.npy", np.zeros((0, 5), np.float32))
    for version in [(2, 0), (3, 0)]:
        with open(f"{d}/py_v{version[0]}.npy", "wb") as fh:
            np.lib.format.write_array(fh, np.arange(5, dtype=np.float32), version=version)
    # Refused: float64, big-endian, Fortran order, int32, rank 5.
    np.save(f"{d}/py_f64.npy", np.zeros(3))
    np.save(f"{d}/py_be.npy", np.zeros(3, dtype=">f4"))
    np.save(f"{d}/py_fortran.npy", np.asfortranarray(np.zeros((2, 3), np.float32)))
    np.save(f"{d}/py_i32.npy", np.zeros(3, np.int32))
    np.save(f"{d}/py_rank5.npy", np.zeros((1, 1, 1, 1, 2), np.float32))


if __name__ == "__main__":
    bad = check_c_files(sys.argv[1])
    write_py_files(sys.argv[1])
    sys.exit(1 if bad else 0)
