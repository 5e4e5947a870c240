"""Headless software renderer: shaded robot surface, ground grid, task arrow (numpy only).

No display, OpenGL or extra package is needed, so ``render_mode="rgb_array"`` works on CI
machines and clusters. Triangles are rasterised with a z-buffer and flat Lambert shading;
the ground is ray-cast per pixel as a checkerboard; the camera follows the robot.
"""

from __future__ import annotations

import numpy as np

__all__ = ["SoftwareRenderer", "ground_cell"]

_ROBOT_RGB = np.array([0.30, 0.55, 0.85])
_ARROW_RGB = np.array([0.90, 0.25, 0.20])
_SKY_RGB = np.array([0.85, 0.90, 0.95])


class SoftwareRenderer:
    """Renders frames of (positions, faces) with a camera looking at ``target``.

    Parameters
    ----------
    width, height : int
        Image size in pixels.
    distance : float
        Camera distance from the target, m (> 0).
    azimuth, elevation : float
        Camera direction, degrees; the elevation in (-90, 90) (straight above or below, the
        image's horizontal is undefined).
    fov : float
        Vertical field of view, degrees, in (0, 180).
    cell : float
        Side of the ground's checker squares, m; the arrow's lift off the ground and the
        distance over which the ground fades scale with it (see :func:`ground_cell`).
    """

    def __init__(
        self,
        width: int = 480,
        height: int = 360,
        distance: float = 2.0,
        azimuth: float = -60.0,
        elevation: float = 30.0,
        fov: float = 45.0,
        cell: float = 0.1,
    ) -> None:
        if width < 8 or height < 8:
            raise ValueError(f"image must be at least 8 x 8 pixels, got {width} x {height}")
        if not (np.isfinite(cell) and cell > 0):
            raise ValueError(f"cell must be a length > 0 m, got {cell!r}")
        # checked here, not met as a picture: a camera at or behind its target drew a blank
        # frame, a zero field of view raised OverflowError, and a camera straight above or
        # below has no "right" (its view is the cross product of parallel vectors: NaN)
        if not (np.isfinite(distance) and distance > 0):
            raise ValueError(f"distance must be a length > 0 m, got {distance!r}")
        if not (np.isfinite(fov) and 0 < fov < 180):
            raise ValueError(f"fov must be an angle in (0, 180) degrees, got {fov!r}")
        if not np.isfinite(azimuth):
            raise ValueError(f"azimuth must be a finite angle in degrees, got {azimuth!r}")
        if not (np.isfinite(elevation) and -90 < elevation < 90):
            raise ValueError(f"elevation must be an angle in (-90, 90) degrees, got {elevation!r}")
        self.width, self.height = int(width), int(height)
        self.cell = float(cell)
        self.distance, self.azimuth, self.elevation, self.fov = distance, azimuth, elevation, fov
        ys, xs = np.mgrid[0 : self.height, 0 : self.width]
        self._px = xs + 0.5
        self._py = ys + 0.5

    def _camera(self, target: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
        az, el = np.deg2rad(self.azimuth), np.deg2rad(self.elevation)
        back = np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
        eye = target + self.distance * back
        forward = -back
        right = np.cross(forward, [0.0, 0.0, 1.0])
        right /= np.linalg.norm(right)
        up = np.cross(right, forward)
        rot = np.stack([right, up, forward])  # world -> camera rows
        focal = 0.5 * self.height / np.tan(np.deg2rad(self.fov) / 2)
        return eye, rot, focal

    def _project(self, p: np.ndarray, eye, rot, focal) -> tuple[np.ndarray, np.ndarray]:
        c = (p - eye) @ rot.T
        depth = c[:, 2]
        safe = np.maximum(depth, 1e-6)
        u = self.width / 2 + focal * c[:, 0] / safe
        v = self.height / 2 - focal * c[:, 1] / safe
        return np.stack([u, v], axis=1), depth

    def render(
        self,
        positions: np.ndarray,
        faces: np.ndarray,
        target: np.ndarray,
        arrow: np.ndarray | None = None,
        ground: bool = True,
    ) -> np.ndarray:
        """One RGB frame (height, width, 3) uint8."""
        eye, rot, focal = self._camera(np.asarray(target, dtype=float))
        img = np.empty((self.height, self.width, 3))
        img[:] = _SKY_RGB
        zbuf = np.full((self.height, self.width), np.inf)
        if ground:
            self._ground(img, zbuf, eye, rot, focal, target)
        tris = [(positions[faces], _ROBOT_RGB)]
        if arrow is not None:
            tris.append((_arrow_triangles(np.asarray(target, float), np.asarray(arrow, float),
                                          self.distance * 0.5, 0.02 * self.cell),
                         _ARROW_RGB))  # fmt: skip
        for triangles, rgb in tris:
            self._rasterise(img, zbuf, triangles, rgb, eye, rot, focal)
        return (np.clip(img, 0, 1) * 255).astype(np.uint8)

    def _ground(self, img, zbuf, eye, rot, focal, target) -> None:
        dirs = (
            np.stack(
                [
                    (self._px - self.width / 2) / focal,
                    -(self._py - self.height / 2) / focal,
                    np.ones_like(self._px),
                ],
                axis=-1,
            )
            @ rot
        )  # camera -> world
        dz = dirs[..., 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            t = -eye[2] / dz
        hit = (t > 0) & np.isfinite(t)
        pts = eye + t[..., None] * dirs
        cell = self.cell
        checker = (np.floor(pts[..., 0] / cell) + np.floor(pts[..., 1] / cell)) % 2
        line = (np.abs(pts[..., 0] / cell - np.round(pts[..., 0] / cell)) < 0.04) | (
            np.abs(pts[..., 1] / cell - np.round(pts[..., 1] / cell)) < 0.04
        )
        shade = np.where(line, 0.45, np.where(checker > 0, 0.78, 0.70))
        fade = np.exp(-np.hypot(pts[..., 0] - target[0], pts[..., 1] - target[1]) / (60 * cell))
        color = shade[..., None] * fade[..., None] + _SKY_RGB * (1 - fade[..., None])
        # The ground writes no depth: nothing drawn here is below it, and a 2 mm arrow lying on
        # it would lose a depth test to interpolation error.
        img[hit] = color[hit]

    def _rasterise(self, img, zbuf, triangles, rgb, eye, rot, focal) -> None:
        flat = triangles.reshape(-1, 3)
        uv, depth = self._project(flat, eye, rot, focal)
        uv = uv.reshape(-1, 3, 2)
        depth = depth.reshape(-1, 3)
        normal = np.cross(triangles[:, 1] - triangles[:, 0], triangles[:, 2] - triangles[:, 0])
        norm = np.linalg.norm(normal, axis=1)
        ok = (norm > 0) & np.all(depth > 1e-3, axis=1)
        normal[ok] /= norm[ok, None]
        light = np.array([0.3, -0.4, 0.87])
        light /= np.linalg.norm(light)
        lambert = 0.35 + 0.65 * np.abs(normal @ light)
        for k in np.flatnonzero(ok):
            (x0, y0), (x1, y1), (x2, y2) = uv[k]
            xmin = max(int(np.floor(min(x0, x1, x2))), 0)
            xmax = min(int(np.ceil(max(x0, x1, x2))), self.width - 1)
            ymin = max(int(np.floor(min(y0, y1, y2))), 0)
            ymax = min(int(np.ceil(max(y0, y1, y2))), self.height - 1)
            if xmin > xmax or ymin > ymax:
                continue
            area = (x1 - x0) * (y2 - y0) - (x2 - x0) * (y1 - y0)
            if abs(area) < 1e-12:
                continue
            px = self._px[ymin : ymax + 1, xmin : xmax + 1]
            py = self._py[ymin : ymax + 1, xmin : xmax + 1]
            w0 = ((x1 - px) * (y2 - py) - (x2 - px) * (y1 - py)) / area
            w1 = ((x2 - px) * (y0 - py) - (x0 - px) * (y2 - py)) / area
            w2 = 1.0 - w0 - w1
            inside = (w0 >= 0) & (w1 >= 0) & (w2 >= 0)
            if not inside.any():
                continue
            z = w0 * depth[k, 0] + w1 * depth[k, 1] + w2 * depth[k, 2]
            zb = zbuf[ymin : ymax + 1, xmin : xmax + 1]
            draw = inside & (z < zb)
            zb[draw] = z[draw]
            img[ymin : ymax + 1, xmin : xmax + 1][draw] = rgb * lambert[k]


def ground_cell(size: float) -> float:
    """The ground's checker size for a robot ``size`` m long: a power of ten times 0.1 m,
    1.5 to 15 squares a body length (0.1 m for the benchmark robots, 0.15-1.5 m long), so
    that motion shows on the ground at any scale.

    Parameters
    ----------
    size : float
        The robot's largest extent, m.

    Returns
    -------
    float
        The side of a checker square, m.
    """
    return 0.1 * 10.0 ** np.floor(np.log10(size / 0.15))


def _arrow_triangles(
    origin: np.ndarray, direction: np.ndarray, length: float, lift: float
) -> np.ndarray:
    """A flat arrow ``lift`` m above the ground from below ``origin`` along ``direction``."""
    d = np.array([direction[0], direction[1], 0.0])
    d /= max(np.linalg.norm(d), 1e-12)
    side = np.array([-d[1], d[0], 0.0])
    base = np.array([origin[0], origin[1], lift])
    w, head = 0.04 * length, 0.3 * length
    shaft_end = base + (length - head) * d
    tip = base + length * d
    return np.array(
        [
            [base - w * side, base + w * side, shaft_end + w * side],
            [base - w * side, shaft_end + w * side, shaft_end - w * side],
            [shaft_end - 3 * w * side, shaft_end + 3 * w * side, tip],
        ]
    )
