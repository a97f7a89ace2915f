"""Inline SVG plots for the HTML report: lines, scatter and polar plots, no plotting library.

Every function returns one ``<svg>`` element as text. Axes are linear (``svg_lines`` may plot
log10 of y); series are ``{name: (xs, ys)}`` and take their colour from :data:`COLOURS` by name.
"""

from __future__ import annotations

import html
import math

import numpy as np

COLOURS = {"reference": "#222222", "analytic": "#d95f02", "neural": "#1b9e77", "reference sampler": "#7570b3",
           "analytic sampler": "#e7298a", "neural sampler": "#1b9e77"}


def _ticks(lo: float, hi: float, n: int = 5) -> list[float]:
    return [lo + (hi - lo) * i / (n - 1) for i in range(n)]


def _axes(w, h, m, xr, yr, xlabel, ylabel, xfmt, yfmt) -> list[str]:
    out = [f'<rect x="{m}" y="{m // 2}" width="{w - 1.5 * m}" height="{h - 1.5 * m}" fill="none" stroke="#999"/>']
    for t in _ticks(*xr):
        x = m + (t - xr[0]) / (xr[1] - xr[0] or 1) * (w - 1.5 * m)
        out.append(f'<text x="{x:.1f}" y="{h - m + 16}" font-size="10" text-anchor="middle">{xfmt(t)}</text>')
    for t in _ticks(*yr):
        y = h - m - (t - yr[0]) / (yr[1] - yr[0] or 1) * (h - 1.5 * m)
        out.append(f'<text x="{m - 4}" y="{y + 3:.1f}" font-size="10" text-anchor="end">{yfmt(t)}</text>')
    out.append(f'<text x="{w / 2}" y="{h - 6}" font-size="12" text-anchor="middle">{html.escape(xlabel)}</text>')
    out.append(f'<text x="12" y="{h / 2}" font-size="12" text-anchor="middle" '
               f'transform="rotate(-90 12 {h / 2})">{html.escape(ylabel)}</text>')
    return out


def svg_lines(series: dict, xlabel: str, ylabel: str, logy: bool = False, w: int = 520, h: int = 320) -> str:
    """Line plot of ``{name: (xs, ys)}``; ``logy`` plots log10(y) (y clamped to 1e-12)."""
    m = 60
    tf = (lambda v: math.log10(max(v, 1e-12))) if logy else float
    pts = {k: [(float(x), tf(y)) for x, y in zip(*v) if math.isfinite(float(y))] for k, v in series.items()}
    allp = [p for v in pts.values() for p in v] or [(0.0, 0.0), (1.0, 1.0)]
    xr = (min(p[0] for p in allp), max(p[0] for p in allp))
    yr = (min(p[1] for p in allp), max(p[1] for p in allp))
    yr = yr if yr[1] > yr[0] else (yr[0] - 0.5, yr[1] + 0.5)
    xr = xr if xr[1] > xr[0] else (xr[0] - 0.5, xr[1] + 0.5)
    out = _axes(w, h, m, xr, yr, xlabel, ylabel, lambda t: f"{t:.0f}",
                (lambda t: f"{10 ** t:.2g}") if logy else (lambda t: f"{t:.3g}"))
    palette = ["#1b9e77", "#d95f02", "#7570b3", "#e7298a", "#66a61e", "#e6ab02"]
    for i, (name, p) in enumerate(pts.items()):
        c = COLOURS.get(name, palette[i % len(palette)])
        xy = " ".join(f"{m + (x - xr[0]) / (xr[1] - xr[0]) * (w - 1.5 * m):.1f},"
                      f"{h - m - (y - yr[0]) / (yr[1] - yr[0]) * (h - 1.5 * m):.1f}" for x, y in p)
        out.append(f'<polyline points="{xy}" fill="none" stroke="{c}" stroke-width="1.5"/>')
        out.append(f'<text x="{w - m}" y="{m // 2 + 14 + 14 * i}" font-size="11" fill="{c}" '
                   f'text-anchor="end">{html.escape(name)}</text>')
    return f'<svg xmlns="http://www.w3.org/2000/svg" width="{w}" height="{h}">{"".join(out)}</svg>'


def svg_scatter(points: list, xlabel: str, ylabel: str, w: int = 520, h: int = 320) -> str:
    """Labelled points ``[(name, x, y)]`` with x on a log10 axis (x > 0)."""
    m = 60
    lx = [math.log10(max(x, 1e-12)) for _, x, _ in points]
    xr = (math.floor(min(lx)), math.ceil(max(lx)) if max(lx) > math.floor(min(lx)) else math.floor(min(lx)) + 1)
    yr = (0.0, max(max(y for _, _, y in points) * 1.15, 1e-3))
    out = _axes(w, h, m, xr, yr, xlabel, ylabel, lambda t: f"1e{t:.1f}", lambda t: f"{t:.3f}")
    for (name, _, y), x in zip(points, lx):
        px = m + (x - xr[0]) / (xr[1] - xr[0]) * (w - 1.5 * m)
        py = h - m - (y - yr[0]) / (yr[1] - yr[0]) * (h - 1.5 * m)
        c = COLOURS.get(name, "#333")
        out.append(f'<circle cx="{px:.1f}" cy="{py:.1f}" r="5" fill="{c}"/>')
        out.append(f'<text x="{px + 7:.1f}" y="{py - 7:.1f}" font-size="11" fill="{c}">{html.escape(name)}</text>')
    return f'<svg xmlns="http://www.w3.org/2000/svg" width="{w}" height="{h}">{"".join(out)}</svg>'


def svg_polar(series: dict, title: str, w: int = 420, eps: float = 1e-2) -> str:
    """Upper half-plane polar plot of ``{name: (theta [rad from the normal, signed], value >= 0)}``;
    radius log1p(value/eps) normalised to the largest over all series."""
    h = w // 2 + 40
    cx, cy, r0 = w / 2, w / 2 + 10, w / 2 - 20
    top = max([float(np.log1p(np.max(v) / eps)) for _, v in series.values()] + [1e-6])
    out = [f'<text x="{cx}" y="14" font-size="12" text-anchor="middle">{html.escape(title)}</text>']
    for f in (0.25, 0.5, 0.75, 1.0):
        out.append(f'<path d="M {cx - r0 * f} {cy} A {r0 * f} {r0 * f} 0 0 1 {cx + r0 * f} {cy}" fill="none" '
                   f'stroke="#ddd"/>')
    out.append(f'<line x1="{cx - r0}" y1="{cy}" x2="{cx + r0}" y2="{cy}" stroke="#999"/>')
    out.append(f'<line x1="{cx}" y1="{cy}" x2="{cx}" y2="{cy - r0}" stroke="#ddd"/>')
    for i, (name, (theta, v)) in enumerate(series.items()):
        r = np.log1p(np.clip(np.nan_to_num(v), 0, None) / eps) / top * r0
        xy = " ".join(f"{cx + rr * math.sin(t):.1f},{cy - rr * math.cos(t):.1f}" for t, rr in zip(theta, r))
        c = COLOURS.get(name, "#333")
        out.append(f'<polyline points="{xy}" fill="none" stroke="{c}" stroke-width="1.5"/>')
        out.append(f'<text x="8" y="{30 + 14 * i}" font-size="11" fill="{c}">{html.escape(name)}</text>')
    return f'<svg xmlns="http://www.w3.org/2000/svg" width="{w}" height="{h}">{"".join(out)}</svg>'


# ----------------------------------------------------------------------------- measurements
