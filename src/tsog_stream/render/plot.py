"""A PNG chart of PSNR over time (mean and worst view per time), drawn with Pillow alone."""

from __future__ import annotations

import io
import math
import os
from collections.abc import Sequence

from PIL import Image, ImageDraw, ImageFont

from ..io.files import atomic_write_bytes
from .evaluate import EvalReport

SIZE = (800, 420)
MARGIN = (72, 60, 24, 56)
"""Left, top, right, bottom margins of the plot area, pixels."""
MEAN_COLOUR = (31, 119, 180)
WORST_COLOUR = (214, 39, 40)
GRID = (225, 225, 225)
INK = (30, 30, 30)
Font = ImageFont.FreeTypeFont | ImageFont.ImageFont


def nice_step(span: float, ticks: int = 6) -> float:
    """A tick step of 1, 2 or 5 times a power of ten giving about ``ticks`` ticks over ``span``."""
    raw = max(span, 1e-9) / ticks
    power = 10.0 ** math.floor(math.log10(raw))
    return next(m * power for m in (1.0, 2.0, 5.0, 10.0) if m * power >= raw)


def _ticks(low: float, high: float) -> list[float]:
    """Round tick values covering [low, high]."""
    step = nice_step(high - low)
    first = math.ceil(low / step - 1e-9) * step
    count = math.floor((high - first) / step + 1e-9) + 1
    return [round(first + i * step, 10) for i in range(count)]


def _y_range(values: Sequence[float]) -> tuple[float, float]:
    """The dB range shown: the finite values with some room; 0-100 when none is finite."""
    finite = [v for v in values if math.isfinite(v)]
    if not finite:
        return 0.0, 100.0
    low, high = min(finite), max(finite)
    pad = max(1.0, 0.08 * (high - low))
    step = nice_step(high - low + 2 * pad)
    return math.floor((low - pad) / step) * step, math.ceil((high + pad) / step) * step


class _Frame:
    """Maps (t, dB) to pixels inside the plot area."""

    def __init__(self, x: tuple[float, float], y: tuple[float, float]) -> None:
        self.x, self.y = x, y
        left, top, right, bottom = MARGIN
        self.box = (left, top, SIZE[0] - right, SIZE[1] - bottom)

    def px(self, t: float, db: float) -> tuple[float, float]:
        """Pixel of a point; infinite dB sits on the top edge."""
        x0, y0, x1, y1 = self.box
        u = (t - self.x[0]) / (self.x[1] - self.x[0])
        v = 1.0 if math.isinf(db) else (db - self.y[0]) / (self.y[1] - self.y[0])
        return x0 + u * (x1 - x0), y1 - v * (y1 - y0)


def _axes(draw: ImageDraw.ImageDraw, frame: _Frame, font: Font) -> None:
    """Grid, tick labels and axis titles."""
    x0, y0, x1, y1 = frame.box
    for db in _ticks(*frame.y):
        _, y = frame.px(frame.x[0], db)
        draw.line([(x0, y), (x1, y)], fill=GRID)
        draw.text((x0 - 6, y), f"{db:g}", fill=INK, font=font, anchor="rm")
    for t in _ticks(*frame.x):
        x, _ = frame.px(t, frame.y[0])
        draw.line([(x, y0), (x, y1)], fill=GRID)
        draw.text((x, y1 + 6), f"{t:g}", fill=INK, font=font, anchor="mt")
    draw.rectangle(frame.box, outline=INK)
    draw.text(((x0 + x1) / 2, SIZE[1] - 8), "t (s)", fill=INK, font=font, anchor="mb")
    draw.text((8, (y0 + y1) / 2), "PSNR\n(dB)", fill=INK, font=font, anchor="lm")


def _series(
    draw: ImageDraw.ImageDraw,
    frame: _Frame,
    points: Sequence[tuple[float, float]],
    colour: tuple[int, int, int],
) -> None:
    """One line with a dot at every sample."""
    pixels = [frame.px(t, db) for t, db in points]
    if len(pixels) > 1:
        draw.line(pixels, fill=colour, width=2)
    for x, y in pixels:
        draw.ellipse((x - 3, y - 3, x + 3, y + 3), fill=colour)


def _legend(draw: ImageDraw.ImageDraw, font: Font, identical: bool) -> None:
    """Colour keys above the plot area, right-aligned."""
    labels = [("mean over views", MEAN_COLOUR), ("worst view", WORST_COLOUR)]
    x = SIZE[0] - MARGIN[2] - 330
    for text, colour in labels:
        draw.line([(x, 40), (x + 22, 40)], fill=colour, width=3)
        draw.text((x + 28, 40), text, fill=INK, font=font, anchor="lm")
        x += 150
    if identical:
        draw.text(
            (MARGIN[0], SIZE[1] - 8), "top edge = identical (inf)", fill=INK, font=font, anchor="lb"
        )


def psnr_chart(report: EvalReport) -> Image.Image:
    """The chart of ``report``: per time, the mean and the worst PSNR over the views."""
    summaries = report.times()
    mean = [(s.t, s.psnr_mean) for s in summaries]
    worst = [(s.t, s.psnr_worst) for s in summaries]
    ts = [s.t for s in summaries]
    x = (min(ts), max(ts)) if max(ts) > min(ts) else (ts[0] - 0.5, ts[0] + 0.5)
    frame = _Frame(x, _y_range([db for _, db in mean + worst]))
    image = Image.new("RGB", SIZE, "white")
    draw = ImageDraw.Draw(image)
    font = ImageFont.load_default(size=13)
    names = os.path.basename(report.candidate), os.path.basename(report.reference)
    title = f"PSNR over time: {names[0]} vs {names[1]}"
    draw.text((MARGIN[0], 10), title, fill=INK, font=font)
    _axes(draw, frame, font)
    _series(draw, frame, worst, WORST_COLOUR)
    _series(draw, frame, mean, MEAN_COLOUR)
    _legend(draw, font, any(math.isinf(db) for _, db in mean + worst))
    return image


def write_psnr_plot(report: EvalReport, path: str | os.PathLike[str]) -> None:
    """Draw the chart of ``report`` and publish it atomically as a PNG at ``path``."""
    buffer = io.BytesIO()
    psnr_chart(report).save(buffer, format="PNG")
    atomic_write_bytes(path, buffer.getvalue())
