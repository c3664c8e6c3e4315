"""Gaze and head-pose angles, the conventions of lib/geom
(gazesplat/geom.h), in plain Python.

Angles are (pitch, yaw), ETH-XGaze signs: pitch > 0 looks up, yaw > 0
looks toward image-left. A unit gaze vector g (camera axes: x right, y
down, z forward) has

    pitch = asin(-g_y), yaw = atan2(-g_x, -g_z)
    g = (-cos p sin y, -sin p, -cos p cos y)

so (0, 0) looks straight back at the camera.

The head pose (pitch, yaw) of a normalized face is its rotation R_head =
Ry(yaw) Rx(-pitch) (no roll: normalization removes it), which maps the head
frame to the normalized camera; a REDIRECT target's gaze is in the head
frame. The same gaze in the normalized camera frame is R_head g_head
(gazesplat/geom.h; lib/synth labels: gaze_cam = head_R gaze_head), and back
g_head = R_head^T g_cam. A gaze straight out of the face, (0, 0) in the
head frame, is the head pose itself in the camera frame.
"""
from __future__ import annotations

import math
from typing import List, Sequence, Tuple

__all__ = ["pitchyaw_to_vec", "vec_to_pitchyaw", "head_rotation", "gaze_head_to_camera",
           "gaze_camera_to_head", "Vec3", "Mat3"]

Vec3 = Tuple[float, float, float]
Mat3 = List[List[float]]


def pitchyaw_to_vec(pitch: float, yaw: float) -> Vec3:
    """Unit gaze vector of (pitch, yaw) radians."""
    return (-math.cos(pitch) * math.sin(yaw), -math.sin(pitch), -math.cos(pitch) * math.cos(yaw))


def vec_to_pitchyaw(g: Sequence[float]) -> Tuple[float, float]:
    """(pitch, yaw) radians of a non-zero gaze vector."""
    n = math.sqrt(sum(c * c for c in g))
    if not n > 0 or not math.isfinite(n):
        raise ValueError("gaze vector %r is zero or not finite" % (tuple(g),))
    x, y, z = (c / n for c in g)
    return math.asin(max(-1.0, min(1.0, -y))), math.atan2(-x, -z)


def _mul(a: Mat3, b: Mat3) -> Mat3:
    return [[sum(a[i][k] * b[k][j] for k in range(3)) for j in range(3)] for i in range(3)]


def head_rotation(pitch: float, yaw: float, roll: float = 0.0) -> Mat3:
    """R_head = Ry(yaw) Rx(-pitch) Rz(roll), rows (gs_geom_rot_from_pitchyaw),
    for head angles in radians. A normalized face has no roll."""
    cy, sy = math.cos(yaw), math.sin(yaw)
    cp, sp = math.cos(-pitch), math.sin(-pitch)
    cr, sr = math.cos(roll), math.sin(roll)
    ry = [[cy, 0.0, sy], [0.0, 1.0, 0.0], [-sy, 0.0, cy]]
    rx = [[1.0, 0.0, 0.0], [0.0, cp, -sp], [0.0, sp, cp]]
    rz = [[cr, -sr, 0.0], [sr, cr, 0.0], [0.0, 0.0, 1.0]]
    return _mul(_mul(ry, rx), rz)


def _apply(r: Mat3, v: Sequence[float], transpose: bool = False) -> Vec3:
    if transpose:
        return (r[0][0] * v[0] + r[1][0] * v[1] + r[2][0] * v[2],
                r[0][1] * v[0] + r[1][1] * v[1] + r[2][1] * v[2],
                r[0][2] * v[0] + r[1][2] * v[1] + r[2][2] * v[2])
    return (r[0][0] * v[0] + r[0][1] * v[1] + r[0][2] * v[2],
            r[1][0] * v[0] + r[1][1] * v[1] + r[1][2] * v[2],
            r[2][0] * v[0] + r[2][1] * v[1] + r[2][2] * v[2])


def gaze_head_to_camera(gaze_deg: Sequence[float], head_deg: Sequence[float],
                        roll_deg: float = 0.0) -> Tuple[float, float]:
    """A head-frame gaze (pitch, yaw degrees) of a face whose head pose is
    head_deg (pitch, yaw degrees, normalized camera) as the gaze in the
    normalized camera frame, degrees. roll_deg: for a camera frame with
    head roll (lib/synth's camera labels); 0 for a normalized face."""
    r = head_rotation(math.radians(head_deg[0]), math.radians(head_deg[1]), math.radians(roll_deg))
    g = _apply(r, pitchyaw_to_vec(math.radians(gaze_deg[0]), math.radians(gaze_deg[1])))
    p, y = vec_to_pitchyaw(g)
    return math.degrees(p), math.degrees(y)


def gaze_camera_to_head(gaze_deg: Sequence[float], head_deg: Sequence[float],
                        roll_deg: float = 0.0) -> Tuple[float, float]:
    """The inverse of gaze_head_to_camera."""
    r = head_rotation(math.radians(head_deg[0]), math.radians(head_deg[1]), math.radians(roll_deg))
    g = _apply(r, pitchyaw_to_vec(math.radians(gaze_deg[0]), math.radians(gaze_deg[1])), transpose=True)
    p, y = vec_to_pitchyaw(g)
    return math.degrees(p), math.degrees(y)
