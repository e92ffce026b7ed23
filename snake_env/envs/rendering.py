"""Top-view rendering of the snake with numpy only (headless, no display needed).

Shapes are rasterized as anti-aliased capsules: for every pixel in a shape's
bounding box the distance to the capsule's axis segment gives the coverage.
The camera follows the whole snake's centre of mass; a fixed world grid (and
the x axis drawn darker) makes the motion visible, the CM trail shows the path.
The "human" window uses pygame, imported only when a window is opened.
"""

from __future__ import annotations

import math

import numpy as np

BACKGROUND = np.array([246, 244, 238], np.float32)
GRID = np.array([222, 219, 210], np.float32)
AXIS = np.array([170, 166, 156], np.float32)
TRAIL = np.array([70, 130, 200], np.float32)
LINK_TAIL = np.array([46, 139, 87], np.float32)  # link 1
LINK_FRONT = np.array([154, 205, 50], np.float32)  # link n
LINK1_MARK = np.array([200, 60, 50], np.float32)
WHEEL = np.array([40, 40, 46], np.float32)
JOINT = np.array([30, 60, 40], np.float32)
OVERLAY = np.array([220, 120, 30], np.float32)  # task overlays: goal, path, command arrow


def _capsule(canvas, p0, p1, radius, color):
    """Blend a capsule (segment p0-p1 in pixels, half-width ``radius`` px) into canvas (H, W, 3) float32."""
    H, W, _ = canvas.shape
    r = radius + 1.0
    x_lo = max(int(math.floor(min(p0[0], p1[0]) - r)), 0)
    x_hi = min(int(math.ceil(max(p0[0], p1[0]) + r)) + 1, W)
    y_lo = max(int(math.floor(min(p0[1], p1[1]) - r)), 0)
    y_hi = min(int(math.ceil(max(p0[1], p1[1]) + r)) + 1, H)
    if x_lo >= x_hi or y_lo >= y_hi:
        return
    xs = np.arange(x_lo, x_hi, dtype=np.float32) + 0.5
    ys = np.arange(y_lo, y_hi, dtype=np.float32)[:, None] + 0.5
    dx, dy = p1[0] - p0[0], p1[1] - p0[1]
    length2 = dx * dx + dy * dy
    if length2 > 0.0:
        t = np.clip(((xs - p0[0]) * dx + (ys - p0[1]) * dy) / length2, 0.0, 1.0)
    else:
        t = np.zeros((1, 1), np.float32)
    ex = xs - (p0[0] + t * dx)
    ey = ys - (p0[1] + t * dy)
    alpha = np.clip(radius + 0.5 - np.sqrt(ex * ex + ey * ey), 0.0, 1.0)[..., None]
    patch = canvas[y_lo:y_hi, x_lo:x_hi]
    patch += alpha * (color - patch)


def _polyline(canvas, points, color, thickness=1):
    """Draw a polyline (K, 2) in pixels by dense sampling (vectorized; for the trail)."""
    if len(points) < 2:
        return
    H, W, _ = canvas.shape
    seg = np.diff(points, axis=0)
    steps = np.maximum(np.ceil(np.hypot(seg[:, 0], seg[:, 1]) * 2.0).astype(int), 1)
    idx = np.repeat(np.arange(len(seg)), steps)
    frac = (np.arange(steps.sum()) - np.repeat(np.cumsum(steps) - steps, steps)) / np.repeat(steps, steps)
    pts = points[idx] + seg[idx] * frac[:, None]
    cols = np.floor(pts[:, 0]).astype(int)
    rows = np.floor(pts[:, 1]).astype(int)
    for dr in range(-(thickness // 2), thickness - thickness // 2):
        for dc in range(-(thickness // 2), thickness - thickness // 2):
            r, c = rows + dr, cols + dc
            ok = (r >= 0) & (r < H) & (c >= 0) & (c < W)
            canvas[r[ok], c[ok]] = color


class SnakeRenderer:
    """Draws q = (theta_1..theta_n, x, y) (eq. 1) as an (H, W, 3) uint8 top view.

    Args:
        width, height: frame size (pixels).
        half_length: per-link half-lengths h_k (m), shape (n,).
    """

    def __init__(self, width: int, height: int, half_length):
        self.width = int(width)
        self.height = int(height)
        self.half_length = np.asarray(half_length, np.float64)
        n = self.half_length.shape[0]
        total = 2.0 * float(self.half_length.sum())  # snake length (m)
        self.view = max(1.2, 1.6 * total)  # metres across the shorter image side
        self.scale = min(self.width, self.height) / self.view  # pixels per metre
        raw = self.view / 8.0  # aim at about 8 grid cells across (m)
        base = 10.0 ** math.floor(math.log10(raw))
        self.grid_step = max(k * base for k in (1, 2, 5) if k * base <= raw)  # m, a 1-2-5 spacing
        link_width = 0.18 * float(np.mean(2.0 * self.half_length))  # m, drawn body width
        self.body_radius = max(1.5, 0.5 * link_width * self.scale)
        self.wheel_radius = max(1.0, 0.55 * self.body_radius)  # half the tyre width (px)
        self.wheel_half = max(2.0, 0.45 * float(np.mean(self.half_length)) * self.scale)  # half the tyre length (px)
        self.colors = [LINK_TAIL + (LINK_FRONT - LINK_TAIL) * (k / max(n - 1, 1)) for k in range(n)]

    def to_pixels(self, xy, center):
        """World (m) -> pixel (col, row) with the camera at ``center``; y points up."""
        xy = np.asarray(xy, np.float64)
        col = self.width / 2.0 + (xy[..., 0] - center[0]) * self.scale
        row = self.height / 2.0 - (xy[..., 1] - center[1]) * self.scale
        return np.stack([col, row], axis=-1)

    def _grid(self, canvas, center):
        half_w = self.width / 2.0 / self.scale
        half_h = self.height / 2.0 / self.scale
        g = self.grid_step
        for x in np.arange(math.floor((center[0] - half_w) / g) * g, center[0] + half_w + g, g):
            col = int(round(self.width / 2.0 + (x - center[0]) * self.scale))
            if 0 <= col < self.width:
                canvas[:, col] = AXIS if abs(x) < 1e-9 else GRID
        for y in np.arange(math.floor((center[1] - half_h) / g) * g, center[1] + half_h + g, g):
            row = int(round(self.height / 2.0 - (y - center[1]) * self.scale))
            if 0 <= row < self.height:
                canvas[row, :] = AXIS if abs(y) < 1e-9 else GRID

    def _overlay(self, canvas, overlay, center):
        """Task overlays in world coordinates (m): ("polyline", (K, 2)), ("point", (2,)) or
        ("arrow", (start (2,), end (2,)))."""
        for kind, data in overlay:
            if kind == "polyline":
                _polyline(canvas, self.to_pixels(data, center), OVERLAY, thickness=2)
            elif kind == "point":
                p = self.to_pixels(data, center)
                _capsule(canvas, p, p, max(3.0, 0.05 * self.scale), OVERLAY)
            elif kind == "arrow":
                start, end = (self.to_pixels(v, center) for v in data)
                _capsule(canvas, start, end, 1.5, OVERLAY)
                _capsule(canvas, end, end, 4.0, OVERLAY)
            else:
                raise ValueError(f"overlay kind must be one of ['polyline', 'point', 'arrow'], got {kind!r}")

    def draw(self, q, trail=None, overlay=None) -> np.ndarray:
        """Frame of state q; ``trail`` (K, 2) holds past CM positions (m), the last one the camera centre;
        ``overlay`` is a task's list of (kind, data) drawn under the snake (see :meth:`_overlay`)."""
        q = np.asarray(q, np.float64)
        n = self.half_length.shape[0]
        theta = q[:n]
        e = np.stack([np.cos(theta), np.sin(theta)], axis=-1)
        h = self.half_length
        # link CMs: CM_{k+1} = CM_k + h_k e_k + h_{k+1} e_{k+1} (eq. 3)
        steps = e[:-1] * h[:-1, None] + e[1:] * h[1:, None]
        cms = q[n:n + 2] + np.concatenate([np.zeros((1, 2)), np.cumsum(steps, axis=0)])
        if trail is not None and len(trail):
            trail = np.asarray(trail, np.float64).reshape(-1, 2)
            center = trail[-1]
        else:
            center = cms.mean(axis=0)
        canvas = np.empty((self.height, self.width, 3), np.float32)
        canvas[:] = BACKGROUND
        self._grid(canvas, center)
        if trail is not None and len(trail) > 1:
            _polyline(canvas, self.to_pixels(trail, center), TRAIL, thickness=3)
        if overlay:
            self._overlay(canvas, overlay, center)
        ends0 = self.to_pixels(cms - e * h[:, None], center)
        ends1 = self.to_pixels(cms + e * h[:, None], center)
        mids = self.to_pixels(cms, center)
        # wheels under the body: a pair per link, across the link at its CM, rolling along e_k
        normal = np.stack([e[:, 1], e[:, 0]], axis=-1)  # perpendicular in pixel coords (row axis flipped)
        along = np.stack([e[:, 0], -e[:, 1]], axis=-1)
        offset = 1.2 * self.body_radius + self.wheel_radius
        for k in range(n):
            for side in (-1.0, 1.0):
                c = mids[k] + side * offset * normal[k]
                _capsule(canvas, c - self.wheel_half * along[k], c + self.wheel_half * along[k], self.wheel_radius, WHEEL)
        for k in range(n):
            _capsule(canvas, ends0[k], ends1[k], self.body_radius, self.colors[k])
        for k in range(n - 1):
            _capsule(canvas, ends1[k], ends1[k], 0.55 * self.body_radius, JOINT)
        _capsule(canvas, mids[0], mids[0], 0.6 * self.body_radius, LINK1_MARK)  # link 1: (x, y) of eq. 1
        return canvas.astype(np.uint8)


class HumanWindow:
    """A pygame window showing rgb frames at ``fps`` (pygame imported here only)."""

    def __init__(self, width: int, height: int, fps: int):
        try:
            import pygame
        except ImportError as exc:
            raise ImportError('render_mode="human" needs pygame: pip install "snake_env[human]"') from exc
        self._pygame = pygame
        pygame.display.init()  # display only: pygame.init() would also open audio devices
        self.screen = pygame.display.set_mode((width, height))
        pygame.display.set_caption("snake_env")
        self.clock = pygame.time.Clock()
        self.fps = fps

    def show(self, frame: np.ndarray) -> None:
        pygame = self._pygame
        pygame.event.pump()
        surface = pygame.surfarray.make_surface(np.ascontiguousarray(frame.swapaxes(0, 1)))
        self.screen.blit(surface, (0, 0))
        pygame.display.flip()
        self.clock.tick(self.fps)

    def close(self) -> None:
        self._pygame.display.quit()
        self._pygame.quit()
