"""Offscreen pictures of a scan with registered templates drawn in place (PNG, no display).

The scan's points are splatted into the camera image (nearest depth wins, shaded by depth); the
registered templates are ray cast from the same camera (``DepthCamera``) and drawn over the scan
where they are in front of it, each template in its own colour with Lambert shading.
"""
from __future__ import annotations

import struct
import zlib

import numpy as np

from .simulation import KINECT_NFOV, CameraIntrinsics, DepthCamera

__all__ = ["render_registrations", "write_png", "TEMPLATE_COLOURS"]

TEMPLATE_COLOURS = {
    "gate_valve": (230, 80, 60), "ball_valve": (60, 160, 230), "quarter_turn_valve": (250, 190, 40),
    "emergency_stop": (220, 40, 140), "grab_handle": (70, 200, 90)}
_FALLBACK = [(160, 110, 230), (40, 200, 200), (240, 130, 40), (150, 150, 150)]


def write_png(path: str, rgb: np.ndarray) -> None:
    """Write an (H, W, 3) uint8 image as an 8-bit RGB PNG."""
    img = np.ascontiguousarray(rgb, dtype=np.uint8)
    h, w = img.shape[:2]
    raw = b"".join(b"\x00" + img[r].tobytes() for r in range(h))     # filter 0 per row

    def chunk(tag: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + tag + data + \
            struct.pack(">I", zlib.crc32(tag + data) & 0xFFFFFFFF)
    png = b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0)) + \
        chunk(b"IDAT", zlib.compress(raw, 6)) + chunk(b"IEND", b"")
    with open(path, "wb") as handle:
        handle.write(png)


def render_registrations(points: np.ndarray, registrations, library,
                         intrinsics: CameraIntrinsics = KINECT_NFOV) -> np.ndarray:
    """(H, W, 3) uint8 picture of ``points`` (N, 3, camera optical frame) with each
    ``(template name, T_scene_model[, joints, scale])`` of ``registrations`` drawn in place (an
    articulated template at its joint values and scale)."""
    H, W = intrinsics.height, intrinsics.width
    img = np.full((H, W, 3), 24, dtype=float)
    pts = np.asarray(points, dtype=float)
    pts = pts[np.all(np.isfinite(pts), axis=1) & (pts[:, 2] > 0.05)]
    scan_depth = np.full(H * W, np.inf)
    if len(pts):
        u = np.round(pts[:, 0] / pts[:, 2] * intrinsics.fx + intrinsics.cx).astype(int)
        v = np.round(pts[:, 1] / pts[:, 2] * intrinsics.fy + intrinsics.cy).astype(int)
        ok = (u >= 0) & (u < W) & (v >= 0) & (v < H)
        np.minimum.at(scan_depth, v[ok] * W + u[ok], pts[ok, 2])
        seen = np.isfinite(scan_depth)
        d = scan_depth[seen]
        lo, hi = np.percentile(d, 2), np.percentile(d, 98)
        grey = 200 - 140 * np.clip((d - lo) / max(hi - lo, 1e-6), 0, 1)
        flat = img.reshape(-1, 3)
        flat[seen] = grey[:, None]
    regs = list(registrations)
    if regs:
        camera = DepthCamera(intrinsics)
        meshes = []
        for name, T, *extra in regs:
            tpl = library[name]
            joints = extra[0] if len(extra) > 0 else {}
            scale = extra[1] if len(extra) > 1 else 1.0
            meshes.append((tpl.mesh_at(tpl.joint_value(joints or {}), float(scale)),
                           np.asarray(T, dtype=float)))
        hit, labels, normals = camera.render(meshes, None, return_normals=True)
        depth = hit[..., 2].reshape(-1)
        labels = labels.reshape(-1)
        rays = camera.ray_directions.reshape(-1, 3)
        rays = rays / np.linalg.norm(rays, axis=1, keepdims=True)
        shade = 0.35 + 0.65 * np.abs(np.einsum("ni,ni->n", normals.reshape(-1, 3), rays))
        in_front = (labels >= 0) & ~(scan_depth < depth - 0.01)
        flat = img.reshape(-1, 3)
        for k, (name, *_) in enumerate(regs):
            sel = in_front & (labels == k)
            colour = np.array(TEMPLATE_COLOURS.get(name, _FALLBACK[k % len(_FALLBACK)]), float)
            flat[sel] = 0.25 * flat[sel] + 0.75 * colour * shade[sel, None]
    return np.clip(img, 0, 255).astype(np.uint8)
