"""Heads-up display for recorded videos: text panel and a scale bar in metres.

Drawn onto an rgb frame (H, W, 3) uint8 with numpy only, after the snake is
rendered (:mod:`snake_env.envs.rendering` is left unchanged): a dark panel in
the top-left corner with one line per entry (e.g. time, forward speed,
distance, episode return), and a white bar with its length in metres in the
bottom-left corner. Text uses a built-in 5x7 bitmap font (upper case, digits
and a little punctuation; lower case is drawn as upper case), scaled by an
integer factor, so no font files or imaging libraries are needed.

:func:`hud_boxes` gives the rectangles the HUD may touch: a frame with a HUD
equals the plain frame everywhere outside them.
"""

from __future__ import annotations

import math

import numpy as np

# The classic 5x7 LCD font: five column bytes per character, bit 0 = top row.
_COLUMNS = {
    "0": (0x3E, 0x51, 0x49, 0x45, 0x3E), "1": (0x00, 0x42, 0x7F, 0x40, 0x00), "2": (0x42, 0x61, 0x51, 0x49, 0x46),
    "3": (0x21, 0x41, 0x45, 0x4B, 0x31), "4": (0x18, 0x14, 0x12, 0x7F, 0x10), "5": (0x27, 0x45, 0x45, 0x45, 0x39),
    "6": (0x3C, 0x4A, 0x49, 0x49, 0x30), "7": (0x01, 0x71, 0x09, 0x05, 0x03), "8": (0x36, 0x49, 0x49, 0x49, 0x36),
    "9": (0x06, 0x49, 0x49, 0x29, 0x1E), "A": (0x7E, 0x11, 0x11, 0x11, 0x7E), "B": (0x7F, 0x49, 0x49, 0x49, 0x36),
    "C": (0x3E, 0x41, 0x41, 0x41, 0x22), "D": (0x7F, 0x41, 0x41, 0x22, 0x1C), "E": (0x7F, 0x49, 0x49, 0x49, 0x41),
    "F": (0x7F, 0x09, 0x09, 0x09, 0x01), "G": (0x3E, 0x41, 0x49, 0x49, 0x7A), "H": (0x7F, 0x08, 0x08, 0x08, 0x7F),
    "I": (0x00, 0x41, 0x7F, 0x41, 0x00), "J": (0x20, 0x40, 0x41, 0x3F, 0x01), "K": (0x7F, 0x08, 0x14, 0x22, 0x41),
    "L": (0x7F, 0x40, 0x40, 0x40, 0x40), "M": (0x7F, 0x02, 0x0C, 0x02, 0x7F), "N": (0x7F, 0x04, 0x08, 0x10, 0x7F),
    "O": (0x3E, 0x41, 0x41, 0x41, 0x3E), "P": (0x7F, 0x09, 0x09, 0x09, 0x06), "Q": (0x3E, 0x41, 0x51, 0x21, 0x5E),
    "R": (0x7F, 0x09, 0x19, 0x29, 0x46), "S": (0x46, 0x49, 0x49, 0x49, 0x31), "T": (0x01, 0x01, 0x7F, 0x01, 0x01),
    "U": (0x3F, 0x40, 0x40, 0x40, 0x3F), "V": (0x1F, 0x20, 0x40, 0x20, 0x1F), "W": (0x3F, 0x40, 0x38, 0x40, 0x3F),
    "X": (0x63, 0x14, 0x08, 0x14, 0x63), "Y": (0x07, 0x08, 0x70, 0x08, 0x07), "Z": (0x61, 0x51, 0x49, 0x45, 0x43),
    ".": (0x00, 0x60, 0x60, 0x00, 0x00), ",": (0x00, 0x50, 0x30, 0x00, 0x00), "-": (0x08, 0x08, 0x08, 0x08, 0x08),
    ":": (0x00, 0x36, 0x36, 0x00, 0x00), "/": (0x20, 0x10, 0x08, 0x04, 0x02), "+": (0x08, 0x08, 0x3E, 0x08, 0x08),
    "=": (0x14, 0x14, 0x14, 0x14, 0x14), "%": (0x23, 0x13, 0x08, 0x64, 0x62), "(": (0x00, 0x1C, 0x22, 0x41, 0x00),
    ")": (0x00, 0x41, 0x22, 0x1C, 0x00), "_": (0x40, 0x40, 0x40, 0x40, 0x40), " ": (0, 0, 0, 0, 0),
}
_ROWS, _COLS = 7, 5
_FONT = {char: np.array([[(col >> row) & 1 for col in cols] for row in range(_ROWS)], bool)
         for char, cols in _COLUMNS.items()}
_UNKNOWN = np.ones((_ROWS, _COLS), bool)

TEXT = np.array([255, 255, 255], np.float32)
PANEL = np.array([20, 24, 30], np.float32)
PANEL_ALPHA = 0.6


def text_size(text: str, scale: int = 2) -> tuple[int, int]:
    """(height, width) in pixels of one line of text."""
    return _ROWS * scale, max(len(text) * (_COLS + 1) * scale - scale, 0)


def draw_text(frame: np.ndarray, text: str, row: int, col: int, scale: int = 2, color=TEXT) -> None:
    """Write ``text`` in place into ``frame`` (H, W, 3) with its top-left corner at (row, col)."""
    color = np.asarray(color, frame.dtype)
    H, W, _ = frame.shape
    for k, char in enumerate(text.upper()):
        glyph = _FONT.get(char, _UNKNOWN)
        if char == " ":
            continue
        mask = np.kron(glyph, np.ones((scale, scale), bool))
        r0, c0 = row, col + k * (_COLS + 1) * scale
        r1, c1 = min(r0 + mask.shape[0], H), min(c0 + mask.shape[1], W)
        if r0 >= H or c0 >= W or r1 <= 0 or c1 <= 0:
            continue
        sub = mask[max(-r0, 0): r1 - r0, max(-c0, 0): c1 - c0]
        frame[max(r0, 0):r1, max(c0, 0):c1][sub] = color


def nice_length(max_metres: float) -> float:
    """The largest 1-2-5 length (m) not above ``max_metres``."""
    if not max_metres > 0 or not math.isfinite(max_metres):
        raise ValueError(f"max_metres must be a positive finite length, got {max_metres!r}")
    base = 10.0 ** math.floor(math.log10(max_metres))
    return max(k * base for k in (1, 2, 5) if k * base <= max_metres * (1 + 1e-12))


def format_metres(length: float) -> str:
    return f"{length:g} M" if length >= 0.01 else f"{length * 1000:g} MM"


def _layout(shape, lines, pixels_per_metre, scale):
    H, W = shape[:2]
    pad = 3 * scale
    line_h = (_ROWS + 3) * scale
    boxes = {}
    if lines:
        width = max(text_size(line, scale)[1] for line in lines)
        boxes["panel"] = (0, 0, min(2 * pad + len(lines) * line_h - 3 * scale, H), min(2 * pad + width, W))
    if pixels_per_metre:
        length = nice_length(0.25 * W / pixels_per_metre)
        bar_px = max(int(round(length * pixels_per_metre)), 1)
        label = format_metres(length)
        label_w = text_size(label, scale)[1]
        height = 2 * pad + _ROWS * scale + 2 * scale + 3 * scale
        top = H - height
        boxes["scale"] = (max(top, 0), 0, H, min(2 * pad + max(bar_px, label_w), W))
        boxes["_bar"] = (length, bar_px, label, top + pad, pad)
    return boxes


def hud_boxes(shape, lines, pixels_per_metre=None, scale: int = 2) -> list[tuple[int, int, int, int]]:
    """Rectangles (row0, col0, row1, col1), end-exclusive, that :func:`draw_hud` may change."""
    return [box for key, box in _layout(shape, lines, pixels_per_metre, scale).items() if not key.startswith("_")]


def draw_hud(frame: np.ndarray, lines, pixels_per_metre=None, scale: int = 2) -> np.ndarray:
    """A copy of ``frame`` with the text ``lines`` in a panel (top left) and, given the
    camera's ``pixels_per_metre``, a scale bar in metres (bottom left)."""
    out = np.array(frame, dtype=np.float32, copy=True)
    layout = _layout(out.shape, list(lines), pixels_per_metre, scale)
    pad = 3 * scale
    line_h = (_ROWS + 3) * scale
    for key in ("panel", "scale"):
        if key in layout:
            r0, c0, r1, c1 = layout[key]
            out[r0:r1, c0:c1] += PANEL_ALPHA * (PANEL - out[r0:r1, c0:c1])
    for k, line in enumerate(lines):
        draw_text(out, line, pad + k * line_h, pad, scale)
    if "_bar" in layout:
        length, bar_px, label, top, left = layout["_bar"]
        draw_text(out, label, top, left, scale)
        bar_row = top + _ROWS * scale + 2 * scale
        out[bar_row:bar_row + 2 * scale, left:left + bar_px] = TEXT
        out[bar_row - scale:bar_row + 3 * scale, left:left + scale] = TEXT  # end ticks
        out[bar_row - scale:bar_row + 3 * scale, left + bar_px - scale:left + bar_px] = TEXT
    return np.clip(np.rint(out), 0, 255).astype(np.uint8)


def episode_lines(time_s: float, speed: float, distance: float, episode_return: float, label: str | None = None,
                  gait: dict | None = None):
    """The HUD lines of a locomotion episode: time (s), forward speed (m/s), distance from the origin (m), return;
    with ``gait`` (the metrics of ``snake_env.train.gait_metrics`` so far) also the dominant joint frequency (Hz),
    the peak joint rate (rad/s), the torque sign-flip share, the mean actuator power (W) and the share of
    wheel-steps the env flags in ``wheel_slip`` (outside the friction cone; on sliding wheels, sliding), or,
    where the env flags none (unlimited grip), outside the reference cone."""
    lines = [label.upper()] if label else []
    lines += [f"TIME   {time_s:7.2f} S", f"SPEED  {speed:+7.2f} M/S", f"DIST   {distance:7.2f} M",
              f"RETURN {episode_return:+7.1f}"]
    if gait:
        def value(key, spec):
            number = gait.get(key)
            return "N/A" if number is None or not math.isfinite(number) else format(number, spec)

        flagged = gait.get("wheel_slip_share")
        slip = "wheel_slip_share" if flagged is not None and math.isfinite(flagged) else "outside_friction_cone_share"
        lines += [f"GAIT   {value('dominant_joint_frequency', '7.2f')} HZ",
                  f"RATE   {value('peak_joint_rate', '7.1f')} RAD/S",
                  f"FLIPS  {value('torque_sign_flip_share', '7.0%')}",
                  f"POWER  {value('mean_power', '7.1f')} W",
                  f"SLIP   {value(slip, '7.0%')}"]
    return lines
