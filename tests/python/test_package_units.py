"""The package gazesplat without a daemon (the built copy on PYTHONPATH):
exceptions pickle with their fields and keep their code through PyTorch's
DataLoader re-raise; the frame header and request messages (and clear
errors for bad arguments); addresses; the angle conventions of
gazesplat.geometry on known cases; a REDIRECT left early against a scripted
server (CANCEL sent, its frames drained, the next request answered); and
the unbuilt source tree's import error saying what to do.
usage: test_package_units.py CLIENTS_PYTHON_SRC"""
import math
import os
import pickle
import socket
import subprocess
import sys
import tempfile
import threading

import gazesplat
from gazesplat import Busy, Client, GazesplatError, ProtocolError, geometry, pb
from gazesplat import protocol as P

FT = pb.FrameType
failures = 0
count = 0


def check(cond, what):
    global failures, count
    count += 1
    if not cond:
        failures += 1
        print("CHECK failed:", what, flush=True)


def raises(exc, fn, text=""):
    try:
        fn()
    except exc as e:
        check(text in str(e), "%s lacks %r" % (e, text))
        return e
    except Exception as e:  # noqa: BLE001
        check(False, "raised %r, want %s" % (e, exc.__name__))
        return None
    check(False, "no %s" % exc.__name__)
    return None


def test_errors():
    e = GazesplatError(pb.ERR_UNKNOWN_SUBJECT, "no subject", 12)
    check((e.code, e.name, e.message, e.request_id) == (18, "ERR_UNKNOWN_SUBJECT", "no subject", 12), repr(e))
    for x in (e, GazesplatError(1234, "future code"), Busy(100, 3, 4), ProtocolError("bad magic")):
        y = pickle.loads(pickle.dumps(x))
        check(type(y) is type(x) and str(y) == str(x) and vars(y) == vars(x), "pickle %r -> %r" % (x, y))
    check(GazesplatError(1234).name == "1234", "an unknown code keeps its number")
    old = GazesplatError(pb.Error(code=pb.ERR_DEADLINE, message="late", request_id=3))
    check(old.code == pb.ERR_DEADLINE and old.request_id == 3, "from an Error message %r" % old)
    b = Busy(pb.Busy(retry_after_ms=70, queue_length=2))
    check(b.retry_after_ms == 70 and b.queue_length == 2, "from a Busy message %r" % b)
    try:
        from torch._utils import ExceptionWrapper
    except ImportError:
        print("no torch: DataLoader re-raise not checked")
        return
    for x in (e, Busy(100, 3, 4)):
        try:
            raise x
        except Exception:
            w = pickle.loads(pickle.dumps(ExceptionWrapper(sys.exc_info(), where="in DataLoader worker process 1")))
        try:
            w.reraise()
        except type(x) as y:
            check(getattr(y, "code", None) == getattr(x, "code", None) and
                  getattr(y, "retry_after_ms", None) == getattr(x, "retry_after_ms", None) and
                  "worker process 1" in str(y), "re-raised %r" % y)


def test_protocol():
    frame = P.pack_frame(FT.FRAME_CANCEL, pb.Cancel(request_id=7), 8)
    check(frame.hex() == "47415a4501000c000200000000000000000000000000000000000000080000000807",
          "CANCEL of 7 as PROTOCOL.md shows it: %s" % frame.hex())
    check(P.unpack_header(frame[:32]) == (FT.FRAME_CANCEL, 2, 8, b"\0" * 16), "header")
    raises(ProtocolError, lambda: P.unpack_header(b"GAZX" + frame[4:32]), "bad magic")
    raises(ProtocolError, lambda: P.unpack_header(frame[:6] + b"\x63\x00" + frame[8:32]), "unknown frame type 99")
    raises(ValueError, lambda: P.pack_frame(FT.FRAME_FIT, None, 1, b"short"), "16 bytes")
    check(P.parse_addr("tcp:[::1]:7000") == ("tcp", ("::1", 7000)) and P.parse_addr("unix:/a/b") == ("unix", "/a/b")
          and P.parse_addr("/a/b") == ("unix", "/a/b"), "addresses")
    raises(ValueError, lambda: P.parse_addr("tcp:host"), "tcp:HOST:PORT")
    raises(ValueError, lambda: P.image_message(b"GIF89a"), "neither PNG nor JPEG")
    raises(ValueError, lambda: P.redirect_request([(0, 0)]), "exactly one of subject and image")
    raises(ValueError, lambda: P.redirect_request([(0, 0)], subject=b"k" * 16, fmt="gif"), "fmt is one of")
    raises(ValueError, lambda: P.redirect_request([(0, 0)], subject=b"k" * 16, head_deg=[None, None]), "one head pose")
    raises(ValueError, lambda: P.redirect_request([(0, 0, 0)], subject=b"k" * 16), "(pitch, yaw)")
    r = P.redirect_request([(10, -5), (0, 0)], subject=b"k" * 16, head_deg=[None, (3, 4)], fmt="raw")
    check(len(r.targets) == 2 and not r.targets[0].HasField("head") and r.targets[1].head.yaw_deg == 4
          and r.output_format == pb.FORMAT_RAW_RGB8, "redirect request %s" % r)
    png = b"\x89PNG\r\n\x1a\n" + b"\0" * 16
    one = P.fit_request(png, gaze_deg=(5, 0))
    check(one.SerializeToString() == P.fit_request(png, gaze_deg=(5, 0), more_images=[]).SerializeToString()
          and len(one.more_images) == 0, "one image: the request of before")
    f = P.fit_request(png, gaze_deg=(5, 0), photo=True, more_images=[png, (png, None, (3, -4)), (png, (1, 2))])
    check(len(f.more_images) == 3 and not f.more_images[0].HasField("gaze")
          and f.more_images[1].head.yaw_deg == -4 and not f.more_images[1].HasField("gaze")
          and f.more_images[2].gaze.pitch_deg == 1 and f.more_images[2].image.kind == pb.KIND_PHOTO,
          "further images with their labels: %s" % f.more_images)
    raises(ValueError, lambda: P.fit_request(png, more_images=[png] * 16), "at most 16 images")
    raises(ValueError, lambda: P.fit_request(png, more_images=[(png, None, None, None)]), "a tuple of 4")
    try:
        import numpy as np
        m = P.image_message(np.zeros((4, 5, 3), np.uint8))
        check(m.width == 5 and m.height == 4 and m.stride == 15 and len(m.data) == 60, "raw image")
        raises(ValueError, lambda: P.image_message(np.zeros((4, 5), np.uint8)), "HxWx3 uint8")
    except ImportError:
        pass


def test_geometry():
    h2c, c2h = geometry.gaze_head_to_camera, geometry.gaze_camera_to_head

    def near(a, b):
        return all(abs(x - y) < 1e-9 for x, y in zip(a, b))

    check(near(h2c((0, 0), (0, 30)), (0, 30)) and near(h2c((0, 0), (-20, 0)), (-20, 0)), "out of the face")
    check(near(h2c((0, -30), (0, 30)), (0, 0)), "eyes against the head: at the camera")
    check(near(h2c((12, 0), (0, 0)), (12, 0)), "frontal head: frames agree")
    check(near(c2h(h2c((10, -20), (15, 25)), (15, 25)), (10, -20)), "round trip")
    g = geometry.pitchyaw_to_vec(math.radians(10), math.radians(20))
    check(near(geometry.vec_to_pitchyaw(g), (math.radians(10), math.radians(20))) and g[2] < 0 and g[0] < 0 and g[1] < 0,
          "vector %s: up and toward image-left look -y and -x" % (g,))
    raises(ValueError, lambda: geometry.vec_to_pitchyaw((0, 0, 0)), "zero")
    r = geometry.head_rotation(math.radians(20), math.radians(30))
    z = [r[i][2] for i in range(3)]  # R e_z: into the head
    check(abs(math.degrees(math.asin(z[1])) - 20) < 1e-9 and abs(math.degrees(math.atan2(z[0], z[2])) - 30) < 1e-9,
          "head angles of R_head are those of its z-axis (geom.h)")


def scripted_server(path, script):
    """Accepts one connection and answers HELLO, then runs script(conn)."""
    srv = socket.socket(socket.AF_UNIX)
    srv.bind(path)
    srv.listen(1)

    def read_frame(conn, buf):
        while len(buf) < 32:
            buf += conn.recv(65536)
        ftype, n, rid, _ = P.unpack_header(bytes(buf[:32]))
        while len(buf) < 32 + n:
            buf += conn.recv(65536)
        msg = P.MESSAGES[ftype].FromString(bytes(buf[32:32 + n]))
        del buf[:32 + n]
        return ftype, rid, msg

    def run():
        conn, _ = srv.accept()
        buf = bytearray()
        ftype, rid, _ = read_frame(conn, buf)
        conn.sendall(P.pack_frame(FT.FRAME_HELLO_OK, pb.HelloOk(version=1, image_size=8), rid))
        script(conn, lambda: read_frame(conn, buf))
        conn.close()
        srv.close()

    th = threading.Thread(target=run, daemon=True)
    th.start()
    return th


def test_early_stop():
    seen = []

    def script(conn, read):
        ftype, rid, _ = read()  # REDIRECT of 3 targets
        conn.sendall(P.pack_frame(FT.FRAME_IMAGE, pb.ImageResult(index=0), rid))
        f2, _, cancel = read()  # the client stopped after one image
        seen.append((f2, cancel.request_id == rid))
        conn.sendall(P.pack_frame(FT.FRAME_IMAGE, pb.ImageResult(index=1), rid))
        conn.sendall(P.pack_frame(FT.FRAME_ERROR, pb.Error(code=pb.ERR_CANCELLED, request_id=rid), rid))
        ftype, rid2, _ = read()
        seen.append(ftype)
        conn.sendall(P.pack_frame(FT.FRAME_HEALTH_OK, pb.Health(state=pb.Health.READY), rid2))

    path = os.path.join(tempfile.mkdtemp(prefix="gs_units_"), "s")
    th = scripted_server(path, script)
    with Client("unix:" + path, timeout=10) as c:
        for r in c.redirect([(0, 0)] * 3, subject=b"k" * 16):
            break
        del r
        h = c.health()
    th.join(10)
    check(seen == [(FT.FRAME_CANCEL, True), FT.FRAME_HEALTH] and h.state == pb.Health.READY,
          "early stop: CANCEL, drained, next request answered: %s" % seen)


def test_aio():
    """AsyncClient against a scripted server: a reply later than the
    timeout raises TimeoutError and cancels that request (its late frames
    are dropped), a REDIRECT left early is cancelled and drained, and the
    connection answers the next requests."""
    import asyncio
    import contextlib
    from gazesplat.aio import AsyncClient
    seen = []

    def script(conn, read):
        ftype, slow, _ = read()                  # HEALTH: answered too late
        f, _, cancel = read()                    # its CANCEL
        seen.append((f, cancel.request_id == slow))
        conn.sendall(P.pack_frame(FT.FRAME_HEALTH_OK, pb.Health(), slow))
        ftype, rid, _ = read()                   # REDIRECT
        conn.sendall(P.pack_frame(FT.FRAME_IMAGE, pb.ImageResult(index=0), rid))
        f, _, cancel = read()
        seen.append((f, cancel.request_id == rid))
        conn.sendall(P.pack_frame(FT.FRAME_IMAGE, pb.ImageResult(index=1), rid))
        conn.sendall(P.pack_frame(FT.FRAME_ERROR, pb.Error(code=pb.ERR_CANCELLED, request_id=rid), rid))
        ftype, rid, _ = read()
        conn.sendall(P.pack_frame(FT.FRAME_HEALTH_OK, pb.Health(state=pb.Health.READY), rid))

    async def client(path):
        async with AsyncClient("unix:" + path, timeout=0.3) as c:
            try:
                await c.health()
                check(False, "aio: no timeout")
            except asyncio.TimeoutError:
                pass
            c.timeout = 10
            async with contextlib.aclosing(c.redirect([(0, 0)] * 3, subject=b"k" * 16)) as it:
                async for r in it:
                    check(r.index == 0, "aio: first image")
                    break
            check(not c._pending, "aio: nothing in flight after the early exit: %s" % list(c._pending))
            h = await c.health()
            return h.state

    path = os.path.join(tempfile.mkdtemp(prefix="gs_units_"), "s")
    th = scripted_server(path, script)
    state = asyncio.run(client(path))
    th.join(10)
    check(seen == [(FT.FRAME_CANCEL, True)] * 2 and state == pb.Health.READY,
          "aio: timeout and early exit cancel; the next request is answered: %s %s" % (seen, state))


def test_unbuilt(src):
    """The source tree alone (no generated messages): a clear ImportError."""
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    r = subprocess.run([sys.executable, "-c", "import gazesplat"], cwd=src, env=env, capture_output=True, text=True)
    check(r.returncode != 0 and "gazesplat_pb2 is missing" in r.stderr and "protoc" in r.stderr,
          "unbuilt import: %s" % r.stderr[-600:])


def main():
    check(gazesplat.__version__[0].isdigit(), "version %s" % gazesplat.__version__)
    test_errors()
    test_protocol()
    test_geometry()
    test_early_stop()
    test_aio()
    test_unbuilt(sys.argv[1])
    print("%d checks, %d failed" % (count, failures))
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
