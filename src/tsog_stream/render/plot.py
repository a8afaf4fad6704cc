"""PNG line charts drawn with Pillow alone: PSNR over time (``tsog eval --plot``), and any
labelled series (the benchmarks' rate-distortion curves)."""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Final

import numpy as np
from PIL import Image, ImageDraw, ImageFont

from . import save_png
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
    """The finite values with some room (not below 0 when none is negative); 0-100 when none
    is finite."""
    finite = [v for v in values if math.isfinite(v)]
    if not finite:
        return 0.0, 100.0
    low, high = min(finite), max(finite)
    pad = max(1.0, 0.08 * (high - low))
    step = nice_step(high - low + 2 * pad)
    bottom = math.floor((low - pad) / step) * step
    return (max(bottom, 0.0) if low >= 0 else bottom), math.ceil((high + pad) / step) * step


@dataclass(frozen=True)
class Series:
    """One labelled line of (x, y) points; ``joined=False`` draws dots only (a single peer);
    ``tags`` are written beside the points (e.g. the quality of each)."""

    label: str
    colour: tuple[int, int, int]
    points: Sequence[tuple[float, float]]
    joined: bool = True
    tags: Sequence[str] = ()


class _Frame:
    """Maps (x, y) to pixels inside the plot area."""

    def __init__(self, x: tuple[float, float], y: tuple[float, float]) -> None:
        self.x, self.y = x, y
        left, top, right, bottom = MARGIN
        self.box = (left, top, SIZE[0] - right, SIZE[1] - bottom)

    def px(self, x: float, y: float) -> tuple[float, float]:
        """Pixel of a point; an infinite y sits on the top edge."""
        x0, y0, x1, y1 = self.box
        u = (x - self.x[0]) / (self.x[1] - self.x[0])
        v = 1.0 if math.isinf(y) else (y - self.y[0]) / (self.y[1] - self.y[0])
        return x0 + u * (x1 - x0), y1 - v * (y1 - y0)


def _x_range(values: Sequence[float]) -> tuple[float, float]:
    """The x range shown: the values' span with a little room (one unit around a single x)."""
    low, high = min(values), max(values)
    if high <= low:
        return low - 0.5, high + 0.5
    pad = 0.04 * (high - low)
    return low - pad, high + pad


def _axes(draw: ImageDraw.ImageDraw, frame: _Frame, font: Font, labels: tuple[str, str]) -> None:
    """Grid, tick labels and axis titles."""
    x0, y0, x1, y1 = frame.box
    for y in _ticks(*frame.y):
        _, py = frame.px(frame.x[0], y)
        draw.line([(x0, py), (x1, py)], fill=GRID)
        draw.text((x0 - 6, py), f"{y:g}", fill=INK, font=font, anchor="rm")
    for x in _ticks(*frame.x):
        px, _ = frame.px(x, frame.y[0])
        draw.line([(px, y0), (px, y1)], fill=GRID)
        draw.text((px, y1 + 6), f"{x:g}", fill=INK, font=font, anchor="mt")
    draw.rectangle(frame.box, outline=INK)
    draw.text((x1, SIZE[1] - 8), labels[0], fill=INK, font=font, anchor="rb")  # notes: left
    draw.text((8, (y0 + y1) / 2), labels[1], fill=INK, font=font, anchor="lm")


def _series(draw: ImageDraw.ImageDraw, frame: _Frame, series: Series, font: Font) -> None:
    """One line (when joined) with a dot at every sample, and its tags."""
    pixels = [frame.px(x, y) for x, y in series.points]
    if series.joined and len(pixels) > 1:
        draw.line(pixels, fill=series.colour, width=2)
    radius = 3 if series.joined else 5
    for x, y in pixels:
        draw.ellipse((x - radius, y - radius, x + radius, y + radius), fill=series.colour)
    taken: list[tuple[float, float, float, float]] = []
    for (x, y), tag in zip(pixels, series.tags, strict=False):
        box = draw.textbbox((x + 6, y + 4), tag, font=font, anchor="lt")
        if not any(_overlap(box, other) for other in taken):  # crowded tags: the first shows
            draw.text((x + 6, y + 4), tag, fill=series.colour, font=font, anchor="lt")
            taken.append(box)


def _overlap(a: tuple[float, float, float, float], b: tuple[float, float, float, float]) -> bool:
    """Whether two (left, top, right, bottom) boxes intersect."""
    return a[0] < b[2] and b[0] < a[2] and a[1] < b[3] and b[1] < a[3]


def _legend(draw: ImageDraw.ImageDraw, font: Font, series: Sequence[Series]) -> None:
    """Colour keys above the plot area, right-aligned, on two rows when one is too long."""
    widths = [40 + font.getlength(s.label) + 18 for s in series]
    rows = _legend_rows(widths)
    for (first, stop, width), y in zip(rows, LEGEND_ROWS_Y[len(rows)], strict=True):
        x = SIZE[0] - MARGIN[2] - width
        for entry, step in zip(series[first:stop], widths[first:stop], strict=True):
            draw.line([(x, y), (x + 22, y)], fill=entry.colour, width=3)
            draw.text((x + 28, y), entry.label, fill=INK, font=font, anchor="lm")
            x += step


LEGEND_ROWS_Y: Final = {1: (40,), 2: (31, 48)}
"""Where one or two rows of colour keys sit, between the title and the plot area."""


def _legend_rows(widths: Sequence[float]) -> list[tuple[int, int, float]]:
    """(first, stop, width) of the keys on each row: one row if it fits, else two, the first
    as full as it can be."""
    room = SIZE[0] - MARGIN[2] - 8  # from the left edge, as the y label
    if sum(widths) <= room or len(widths) < 2:
        return [(0, len(widths), sum(widths))]
    cut = 1
    while cut < len(widths) - 1 and sum(widths[: cut + 1]) <= room:
        cut += 1
    return [(0, cut, sum(widths[:cut])), (cut, len(widths), sum(widths[cut:]))]


def line_chart(
    title: str, labels: tuple[str, str], series: Sequence[Series], *, note: str = ""
) -> Image.Image:
    """A chart of ``series`` (drawn in order, the last on top) with x and y axis ``labels``."""
    xs = [x for s in series for x, _ in s.points]
    ys = [y for s in series for _, y in s.points]
    frame = _Frame(_x_range(xs), _y_range(ys))
    image = Image.new("RGB", SIZE, "white")
    draw = ImageDraw.Draw(image)
    font = ImageFont.load_default(size=13)
    draw.text((MARGIN[0], 10), title, fill=INK, font=font)
    _axes(draw, frame, font, labels)
    for entry in series:
        _series(draw, frame, entry, font)
    _legend(draw, font, series)
    if note:
        draw.text((MARGIN[0], SIZE[1] - 8), note, fill=INK, font=font, anchor="lb")
    return image


def psnr_chart(report: EvalReport) -> Image.Image:
    """The chart of ``report``: per time, the mean and the worst PSNR over the views."""
    summaries = report.times()
    mean = [(s.t, s.psnr_mean) for s in summaries]
    worst = [(s.t, s.psnr_worst) for s in summaries]
    names = os.path.basename(report.candidate), os.path.basename(report.reference)
    identical = any(math.isinf(db) for _, db in mean + worst)
    return line_chart(
        f"PSNR over time: {names[0]} vs {names[1]}",
        ("t (s)", "PSNR\n(dB)"),
        [Series("worst view", WORST_COLOUR, worst), Series("mean over views", MEAN_COLOUR, mean)],
        note="top edge = identical (inf)" if identical else "",
    )


def write_png(image: Image.Image, path: str | os.PathLike[str]) -> None:
    """Publish ``image`` atomically as a PNG at ``path``."""
    save_png(np.asarray(image), path)


def write_psnr_plot(report: EvalReport, path: str | os.PathLike[str]) -> None:
    """Draw the chart of ``report`` and publish it atomically as a PNG at ``path``."""
    write_png(psnr_chart(report), path)
