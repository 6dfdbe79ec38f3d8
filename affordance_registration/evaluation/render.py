# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
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

__all__ = ["render_registrations", "render_verdict", "write_png", "TEMPLATE_COLOURS"]

TEMPLATE_COLOURS = {
    "gate_valve": (230, 80, 60),
    "ball_valve": (60, 160, 230),
    "quarter_turn_valve": (250, 190, 40),
    "emergency_stop": (220, 40, 140),
    "grab_handle": (70, 200, 90),
}
_FALLBACK = [(160, 110, 230), (40, 200, 200), (240, 130, 40), (150, 150, 150)]


def write_png(path: str, rgb: np.ndarray) -> None:
    """Write an (H, W, 3) uint8 image as an 8-bit RGB PNG."""
    img = np.ascontiguousarray(rgb, dtype=np.uint8)
    h, w = img.shape[:2]
    raw = b"".join(b"\x00" + img[r].tobytes() for r in range(h))  # filter 0 per row

    def chunk(tag: bytes, data: bytes) -> bytes:
        return (
            struct.pack(">I", len(data))
            + tag
            + data
            + struct.pack(">I", zlib.crc32(tag + data) & 0xFFFFFFFF)
        )

    png = (
        b"\x89PNG\r\n\x1a\n"
        + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0))
        + chunk(b"IDAT", zlib.compress(raw, 6))
        + chunk(b"IEND", b"")
    )
    with open(path, "wb") as handle:
        handle.write(png)


def render_registrations(
    points: np.ndarray, registrations, library, intrinsics: CameraIntrinsics = KINECT_NFOV
) -> np.ndarray:
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
            meshes.append(
                (
                    tpl.mesh_at(tpl.joint_value(joints or {}), float(scale)),
                    np.asarray(T, dtype=float),
                )
            )
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


PASS_COLOUR, FAIL_COLOUR, TRUTH_COLOUR = (90, 230, 110), (255, 80, 70), (255, 255, 255)


def _outline(labels: np.ndarray) -> np.ndarray:
    """(H, W) bool: pixels of a labelled region (label >= 0) next to a pixel of another label."""
    edge = np.zeros(labels.shape, bool)
    for axis in (0, 1):
        diff = np.diff(labels, axis=axis) != 0
        pad = [(0, 0), (0, 0)]
        pad[axis] = (0, 1)
        edge |= np.pad(diff, pad) & (labels >= 0)
        pad[axis] = (1, 0)
        edge |= np.pad(diff, pad) & (labels >= 0)
    return edge


def render_verdict(
    points: np.ndarray, registrations, truths, library, intrinsics: CameraIntrinsics = KINECT_NFOV
) -> np.ndarray:
    """(H, W, 3) uint8: :func:`render_registrations` of the registered fits, the outline of each
    true object drawn over it (white), and a label at every registration: its template name and
    PASS or FAIL with why.

    ``registrations``: dicts with ``template``, ``pose`` (4x4), ``joints``, ``scale``, ``ok``
    (bool) and ``why`` (text); ``truths``: (template, T_scene_model, joints, scale) of the true
    objects, camera optical frame."""
    from PIL import Image, ImageDraw, ImageFont  # local: only pictures need it

    regs = list(registrations)
    img = render_registrations(
        points,
        [
            (
                r["template"],
                np.asarray(r["pose"], float),
                r.get("joints") or {},
                r.get("scale", 1.0),
            )
            for r in regs
        ],
        library,
        intrinsics,
    )
    truths = list(truths)
    if truths:
        meshes = [
            (
                library[name].mesh_at(library[name].joint_value(joints or {}), float(scale)),
                np.asarray(T, float),
            )
            for name, T, joints, scale in truths
        ]
        _, labels = DepthCamera(intrinsics).render(meshes, None)
        edge = _outline(labels)
        img[edge] = TRUTH_COLOUR
    # zoom into the scanned part of the image so the labels can be read
    seen = np.argwhere(np.any(img != 24, axis=-1))
    (r0, c0), (r1, c1) = (
        (seen.min(axis=0), seen.max(axis=0))
        if len(seen)
        else ((0, 0), (img.shape[0] - 1, img.shape[1] - 1))
    )
    r0, c0 = max(r0 - 12, 0), max(c0 - 12, 0)
    r1, c1 = min(r1 + 12, img.shape[0] - 1), min(c1 + 12, img.shape[1] - 1)
    k = int(np.clip(1000 // max(c1 - c0 + 1, 1), 1, 3))
    crop = np.repeat(np.repeat(img[r0 : r1 + 1, c0 : c1 + 1], k, axis=0), k, axis=1)
    picture = Image.fromarray(np.ascontiguousarray(crop))
    draw = ImageDraw.Draw(picture)
    font = ImageFont.load_default(size=15)
    W, H = picture.size
    placed: list[tuple] = []
    for r in regs:
        tpl = library[r["template"]]
        T = np.asarray(r["pose"], float)
        c = T[:3, :3] @ tpl.centroid + T[:3, 3]
        if c[2] <= 0.05:
            continue
        u = (intrinsics.fx * c[0] / c[2] + intrinsics.cx - c0) * k
        v = (intrinsics.fy * c[1] / c[2] + intrinsics.cy - r0) * k
        text = f"{r['template']}  " + ("PASS" if r["ok"] else f"FAIL: {r['why']}")
        colour = PASS_COLOUR if r["ok"] else FAIL_COLOUR
        x0, y0, x1, y1 = draw.textbbox((0, 0), text, font=font)
        w, h = x1 - x0 + 6, y1 - y0 + 6
        x = int(np.clip(u - w / 2, 0, max(W - w, 0)))
        y = int(np.clip(v - 0.05 * k * intrinsics.fy / c[2] - h, 24, max(H - h, 24)))
        for _ in range(20):  # move down past labels already placed
            hit = [b for b in placed if x < b[2] and b[0] < x + w and y < b[3] and b[1] < y + h]
            if not hit:
                break
            y = max(b[3] for b in hit) + 1
        placed.append((x, y, x + w, y + h))
        draw.line((u, v, x + w / 2, y + h / 2), fill=colour, width=1)
        draw.rectangle((x, y, x + w, y + h), fill=(0, 0, 0), outline=colour)
        draw.text((x + 3, y + 3 - y0), text, fill=colour, font=font)
    passed = sum(bool(r["ok"]) for r in regs)
    summary = f"{passed}/{len(regs)} PASS - filled: registered fit, white outline: truth"
    draw.rectangle((0, 0, W, 21), fill=(0, 0, 0))
    draw.text(
        (6, 3),
        summary,
        fill=PASS_COLOUR if passed == len(regs) and regs else FAIL_COLOUR,
        font=font,
    )
    return np.asarray(picture, dtype=np.uint8)
