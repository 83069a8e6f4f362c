"""The two charts of a run page as small SVG files: learn-time evaluations, and per-update diagnostics.

Why not matplotlib: a results release of the paper's Table 1 has 1,890 runs, and a user's own
sweeps as many again; a matplotlib PNG cost ~92 ms CPU per learning curve and ~229 ms per
diagnostics figure, minutes of a build for charts that are a few lines each. Here Python computes
the geometry (scales, ticks, one SVG path per series) and ``templates/charts/chart.svg`` lays it
out: about a millisecond per chart, vector (sharp at any zoom), and a few kilobytes. The charts
keep what the PNGs showed: the Monte Carlo and exact metric against steps with the final
evaluation's line; CPO's dual case, accepted line-search step and ``J_c``, or PPO-Lag's passes per
update, Lagrange multiplier and ``J_c``, against the update number.

Numbers are printed with fixed decimals, so the same table gives the same bytes.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np
import pandas as pd

from leaderboard.web.render import TEMPLATES, render

#: The chart template; its text is part of every cached chart's key (an edit redraws them all).
TEMPLATE = "charts/chart.svg"
BLUE, ORANGE, GREEN, PINK, GREY = "#0072B2", "#D55E00", "#009E73", "#CC79A7", "#555555"


@dataclass(frozen=True)
class Tick:
    pos: float  # pixel coordinate along the axis
    label: str


@dataclass(frozen=True)
class Series:
    """One drawn series: ``line`` (a stroked path), ``dots`` (round caps of zero-length segments:
    one path for hundreds of markers, drawn as fast as a line)."""

    kind: str
    d: str
    colour: str
    dash: str = ""
    width: float = 1.4


@dataclass
class Panel:
    """One plot area with its axes, in pixels of the whole chart."""

    x0: float
    y0: float
    x1: float
    y1: float
    title: str = ""
    xlabel: str = ""
    ylabel: str = ""
    xticks: list[Tick] = field(default_factory=list)
    yticks: list[Tick] = field(default_factory=list)
    series: list[Series] = field(default_factory=list)


@dataclass
class Chart:
    width: int
    height: int
    title: str
    panels: list[Panel]
    legend: list[tuple[str, Series]] = field(default_factory=list)  # (label, how it is drawn)
    font_size: float = 11.0


@lru_cache(maxsize=1)
def template_text() -> str:
    """The template's source, for cache keys."""
    return (TEMPLATES / TEMPLATE).read_text(encoding="utf-8")


# ---------------------------------------------------------------------------------------- scales
def nice_ticks(lo: float, hi: float, target: int = 5, integer: bool = False) -> list[float]:
    """Round tick values inside ``[lo, hi]`` (steps 1, 2, 2.5, 5 times a power of ten), about ``target`` of them."""
    if not (math.isfinite(lo) and math.isfinite(hi)) or hi <= lo:
        return [lo] if math.isfinite(lo) else []
    raw = (hi - lo) / max(1, target)
    power = 10.0 ** math.floor(math.log10(raw))
    step = next(m * power for m in (1, 2, 2.5, 5, 10) if m * power >= raw)
    if integer:
        step = max(1.0, math.ceil(step))
    first = math.ceil(lo / step - 1e-9) * step
    count = math.floor((hi - first) / step + 1e-9) + 1
    return [round(first + i * step, 10) for i in range(count)]


def number_label(value: float) -> str:
    """``0``, ``0.25``, ``40k``, ``1.2M``: short labels for tick values."""
    if abs(value) >= 1e6:
        return f"{value / 1e6:g}M"
    if abs(value) >= 1e4:
        return f"{value / 1e3:g}k"
    return f"{value:g}"


@dataclass(frozen=True)
class Scale:
    """A linear map from data ``[lo, hi]`` onto pixels ``[a, b]``."""

    lo: float
    hi: float
    a: float
    b: float

    def __call__(self, value: np.ndarray) -> np.ndarray:
        return self.a + (np.asarray(value, dtype=float) - self.lo) * (self.b - self.a) / (self.hi - self.lo)

    def ticks(self, target: int = 5, integer: bool = False, values: Sequence[float] | None = None) -> list[Tick]:
        chosen = list(values) if values is not None else nice_ticks(self.lo, self.hi, target, integer)
        return [Tick(round(float(self(np.array(v))), 1), number_label(v)) for v in chosen]


def padded(values: np.ndarray, share: float = 0.05) -> tuple[float, float]:
    """The data range with ``share`` of it added at both ends (a single value gets +-0.5)."""
    finite = values[np.isfinite(values)]
    if not len(finite):
        return 0.0, 1.0
    lo, hi = float(finite.min()), float(finite.max())
    if hi == lo:
        return lo - 0.5, hi + 0.5
    pad = (hi - lo) * share
    return lo - pad, hi + pad


def _xy(xs: np.ndarray, ys: np.ndarray) -> list[tuple[float, float] | None]:
    """Pixel points, ``None`` where a value is missing (a line breaks there)."""
    return [(float(x), float(y)) if math.isfinite(x) and math.isfinite(y) else None for x, y in zip(xs, ys)]


def line_path(xs: np.ndarray, ys: np.ndarray) -> str:
    parts: list[str] = []
    pen_up = True
    for point in _xy(xs, ys):
        if point is None:
            pen_up = True
            continue
        parts.append(f"{'M' if pen_up else 'L'}{point[0]:.1f} {point[1]:.1f}")
        pen_up = False
    return "".join(parts)


def dots_path(xs: np.ndarray, ys: np.ndarray) -> str:
    return "".join(f"M{p[0]:.1f} {p[1]:.1f}h0" for p in _xy(xs, ys) if p is not None)


def step_path(xs: np.ndarray, ys: np.ndarray) -> str:
    """Steps changing half-way between points (matplotlib's ``where="mid"``)."""
    points = [p for p in _xy(xs, ys) if p is not None]
    if not points:
        return ""
    parts = [f"M{points[0][0]:.1f} {points[0][1]:.1f}"]
    for (xa, _), (xb, yb) in itertools.pairwise(points):
        parts.append(f"H{(xa + xb) / 2:.1f}V{yb:.1f}")
    parts.append(f"H{points[-1][0]:.1f}")
    return "".join(parts)


def _column(frame: pd.DataFrame, name: str) -> np.ndarray:
    if name not in frame.columns:
        return np.full(len(frame), np.nan)
    return pd.to_numeric(frame[name], errors="coerce").to_numpy(dtype=float)


# ---------------------------------------------------------------------------------------- charts
def learn_chart(learn: pd.DataFrame, final_metric: float | None, title: str, episodes: int | None = None,
                final_episodes: int | None = None) -> Chart:
    """Monte Carlo and exact metric against environment steps, with the final evaluation's line.

    The legend says how many episodes each estimate averages (``episodes``, ``final_episodes``): a
    learn-time 0.95 from 5 episodes above a final 0.441 from 100 read as a bug (issue 45)."""
    data = learn.sort_values("step", kind="stable")
    steps, mc, exact = _column(data, "step"), _column(data, "metric"), _column(data, "exact_metric")
    panel = Panel(58, 48, 540, 262, xlabel="environment steps", ylabel="morality metric")
    sx = Scale(*padded(steps), panel.x0, panel.x1)
    sy = Scale(-0.02, 1.02, panel.y1, panel.y0)
    panel.xticks = sx.ticks(5, integer=True)
    panel.yticks = sy.ticks(values=[0, 0.2, 0.4, 0.6, 0.8, 1.0])
    mc_line = Series("line", line_path(sx(steps), sy(mc)), BLUE)
    panel.series = [mc_line, Series("dots", dots_path(sx(steps), sy(mc)), BLUE, width=5.5)]
    legend = [(f"MC metric ({episodes} episodes each)" if episodes else "MC metric", mc_line)]
    if np.isfinite(exact).any():
        exact_line = Series("line", line_path(sx(steps), sy(exact)), ORANGE, dash="5 3", width=1.2)
        panel.series.append(exact_line)
        legend.append(("exact metric", exact_line))
    if final_metric is not None and math.isfinite(final_metric):
        y = float(sy(np.array(final_metric)))
        final = Series("line", f"M{panel.x0:.1f} {y:.1f}H{panel.x1:.1f}", GREY, dash="1.5 2.5", width=1.0)
        panel.series.append(final)
        legend.append((f"final evaluation ({final_episodes} episodes)" if final_episodes else "final evaluation", final))
    return Chart(552, 300, title, [panel], legend)


def _update_panels(width: int, count: int) -> list[Panel]:
    span = width / count
    return [Panel(round(i * span + 40, 1), 52, round((i + 1) * span - 10, 1), 246, xlabel="update") for i in range(count)]


def updates_chart(updates: pd.DataFrame, title: str) -> Chart:
    """Three panels against the update number: CPO's dual case, accepted step and ``J_c``, or
    PPO-Lag's passes per update (OmniSafe's summed-KL early stop makes it 1), Lagrange multiplier and ``J_c``."""
    data = updates.sort_values("update", kind="stable")
    x = _column(data, "update")
    panels = _update_panels(912, 3)
    scales = [Scale(*padded(x), p.x0, p.x1) for p in panels]
    for panel, sx in zip(panels, scales):
        panel.xticks = sx.ticks(4, integer=True)
    first, second, third = panels
    if "cpo_case" in data.columns and _column(data, "cpo_case").size and np.isfinite(_column(data, "cpo_case")).any():
        cases = _column(data, "cpo_case")
        sy = Scale(-0.5, 4.5, first.y1, first.y0)
        first.yticks = sy.ticks(values=range(5))
        first.series = [Series("dots", dots_path(scales[0](x), sy(cases)), BLUE, width=3.5)]
        first.title = "dual case (0 recovery, 1 feasible recovery)"
        accept = _column(data, "accept_step")
        top = max(20.8, float(np.nanmax(accept)) + 0.8) if np.isfinite(accept).any() else 20.8
        sy = Scale(-0.8, top, second.y1, second.y0)
        second.yticks = sy.ticks(5, integer=True)
        taken = accept > 0
        second.series = [Series("dots", dots_path(scales[1](x[taken]), sy(accept[taken])), GREEN, width=3.5),
                         Series("dots", dots_path(scales[1](x[~taken]), sy(accept[~taken])), ORANGE, width=3.5)]
        share = float(np.mean(taken)) if len(accept) else math.nan
        second.title = f"accepted step (0 = none; {share:.0%} accepted)"
    else:
        passes = _column(data, "passes")
        top = max(2.0, float(np.nanmax(passes)) + 1) if np.isfinite(passes).any() else 2.0
        sy = Scale(0.0, top, first.y1, first.y0)
        first.yticks = sy.ticks(4, integer=True)
        first.series = [Series("line", step_path(scales[0](x), sy(passes)), BLUE, width=1.1)]
        one = float(np.mean(passes == 1)) if len(passes) else math.nan
        first.title = f"passes per update ({one:.0%} stopped after 1)"
        multiplier = _column(data, "lagrange_multiplier")
        sy = Scale(*padded(multiplier), second.y1, second.y0)
        second.yticks = sy.ticks(4)
        second.series = [Series("line", line_path(scales[1](x), sy(multiplier)), GREEN, width=1.2)]
        second.title = "Lagrange multiplier"
    cost = _column(data, "ep_cost")
    sy = Scale(*padded(cost), third.y1, third.y0)
    third.yticks = sy.ticks(4)
    third.series = [Series("line", line_path(scales[2](x), sy(cost)), PINK, width=1.2)]
    third.title = "J_c (mean episode cost used)"
    return Chart(912, 282, title, panels, font_size=10.0)


def chart_svg(chart: Chart) -> str:
    """The chart as a standalone SVG document (an ``<img>`` source)."""
    return render(TEMPLATE, chart=chart)
