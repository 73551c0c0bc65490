"""The session summary of a batch: ``summary.md`` with per-pitch-type averages and spreads, and
its plots (PNG, matplotlib).

Pitches are grouped by ``pitch_type`` (``capture.json``'s ``"pitch_type"``, ``"unknown"`` when
it does not say). For each type and metric: the number of pitches, the mean, the standard
deviation over the pitches (the spread of the session: ``n - 1`` in the denominator, blank with
one pitch), and the mean of the pitches' own 1-sigma (how well each one was measured). The other
kinds get a line of means each, and every failed capture is listed with its reason.
"""

from __future__ import annotations

import io
import math
from pathlib import Path

import numpy as np

from stillcap.files.atomic import write_bytes, write_text

__all__ = ["PITCH_METRICS", "pitch_type_stats", "write_summary"]
_KIND = "kind"

#: The pitch metrics of the summary (column, label).
PITCH_METRICS = (("release_speed_mph", "release speed, mph"), ("spin_rate_rpm", "spin, rpm"),
                 ("spin_efficiency", "spin efficiency"), ("induced_vertical_break_in", "IVB, in"),
                 ("horizontal_break_in", "HB, in"), ("release_extension_ft", "extension, ft"),
                 ("vertical_approach_angle_deg", "VAA, deg"))
_OTHER = {"hand": ("release_speed_mph", "release_horizontal_deg", "release_vertical_deg", "poses"),
          "puppet": ("markers", "markers_missing", "pose_fit_rms_mm", "reproj_error_mean_px"),
          "markers": ("markers", "reproj_error_mean_px", "reproj_error_max_px")}


def _values(rows, col) -> np.ndarray:
    v = [r.get(col) for r in rows]
    return np.array([x if isinstance(x, (int, float)) and not isinstance(x, bool) else np.nan for x in v], float)


def pitch_type_stats(rows: list[dict]) -> dict:
    """``{pitch_type: {metric: (n, mean, std, mean_sigma)}}`` over the rows of pitches analysed
    (``status == "ok"``); NaN where there is nothing to average."""
    ok = [r for r in rows if r.get("kind") == "pitch" and r.get("status") == "ok"]
    out: dict = {}
    for t in sorted({r.get("pitch_type") or "unknown" for r in ok}):
        group = [r for r in ok if (r.get("pitch_type") or "unknown") == t]
        out[t] = {}
        for col, _ in PITCH_METRICS:
            v = _values(group, col)
            s = _values(group, f"{col}_sigma")
            v = v[np.isfinite(v)]
            s = s[np.isfinite(s)]
            out[t][col] = (len(v), float(v.mean()) if len(v) else math.nan,
                           float(v.std(ddof=1)) if len(v) > 1 else math.nan, float(s.mean()) if len(s) else math.nan)
    return out


def _f(v, nd=2) -> str:
    return "" if v is None or not math.isfinite(v) else f"{v:.{nd}f}"


def _png(fig) -> bytes:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110, bbox_inches="tight")
    return buf.getvalue()


def _plots(rows: list[dict], out: Path) -> list[Path]:
    """Movement (HB vs IVB) and speed vs spin per pitch type; one box plot of speed per type."""
    import matplotlib

    matplotlib.use("Agg")  # files only; no display needed on a cluster's client
    import matplotlib.pyplot as plt

    ok = [r for r in rows if r.get("kind") == "pitch" and r.get("status") == "ok"]
    if not ok:
        return []
    types = sorted({r.get("pitch_type") or "unknown" for r in ok})
    paths = []
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.6))
    for t in types:
        g = [r for r in ok if (r.get("pitch_type") or "unknown") == t]
        axes[0].errorbar(_values(g, "horizontal_break_in"), _values(g, "induced_vertical_break_in"),
                         xerr=_values(g, "horizontal_break_in_sigma"), yerr=_values(g, "induced_vertical_break_in_sigma"),
                         fmt="o", ms=5, capsize=2, label=f"{t} ({len(g)})")
        axes[1].errorbar(_values(g, "release_speed_mph"), _values(g, "spin_rate_rpm"),
                         xerr=_values(g, "release_speed_mph_sigma"), yerr=_values(g, "spin_rate_rpm_sigma"),
                         fmt="o", ms=5, capsize=2, label=t)
    axes[0].set(xlabel="horizontal break, in", ylabel="induced vertical break, in",
                title="Movement per pitch type")
    axes[0].axhline(0, color="0.8", lw=0.8)
    axes[0].axvline(0, color="0.8", lw=0.8)
    axes[1].set(xlabel="release speed, mph", ylabel="spin rate, rpm", title="Speed and spin")
    axes[0].legend(fontsize=8)
    fig.tight_layout()
    paths.append(write_bytes(out / "summary_movement.png", _png(fig)))
    plt.close(fig)
    fig, ax = plt.subplots(figsize=(max(4.0, 1.3 * len(types) + 2), 4))
    data = [_values([r for r in ok if (r.get("pitch_type") or "unknown") == t], "release_speed_mph") for t in types]
    ax.boxplot([d[np.isfinite(d)] for d in data], tick_labels=types)
    ax.set(ylabel="release speed, mph", title="Release speed per pitch type")
    fig.tight_layout()
    paths.append(write_bytes(out / "summary_speed.png", _png(fig)))
    plt.close(fig)
    return paths


def write_summary(rows: list[dict], out) -> list[Path]:
    """Write ``summary.md`` (and its plots) for the rows of a results table; the paths written."""
    out = Path(out)
    rows = [r for r in rows if r is not None]
    n_ok = sum(r.get("status") == "ok" for r in rows)
    kinds = sorted({r.get("kind") for r in rows})
    lines = ["# Batch summary", "",
             f"{len(rows)} captures in the table: {n_ok} analysed, {len(rows) - n_ok} failed "
             f"({', '.join(f'{k}: {sum(r.get(_KIND) == k for r in rows)}' for k in kinds)}). "
             "Every row, with all its metrics and their 1-sigma, is in `results.parquet`.", ""]
    stats = pitch_type_stats(rows)
    if stats:
        lines += ["## Pitches per pitch type", "",
                  "Mean ± standard deviation over the pitches of the type (the session's spread); "
                  "in brackets the mean of the pitches' own 1-sigma (how well each was measured).", ""]
        lines.append("| pitch type | n | " + " | ".join(label for _, label in PITCH_METRICS) + " |")
        lines.append("|---|---:|" + "---:|" * len(PITCH_METRICS))
        for t, st in stats.items():
            n = max(v[0] for v in st.values())
            cells = [f"{_f(m)} ± {_f(sd) or '-'} ({_f(sg, 3)})" if v else "" for v, m, sd, sg in st.values()]
            lines.append(f"| {t} | {n} | " + " | ".join(cells) + " |")
        lines.append("")
    for kind, cols in _OTHER.items():
        ok = [r for r in rows if r.get("kind") == kind and r.get("status") == "ok"]
        if ok:
            means = [f"{c} {_f(float(np.nanmean(v)), 3)}" for c in cols
                     if np.isfinite(v := _values(ok, c)).any()]
            lines += [f"## {kind}", "", f"{len(ok)} captures; means: {', '.join(means) or '-'}", ""]
    failed = [r for r in rows if r.get("status") != "ok"]
    if failed:
        lines += ["## Failed captures", "", "| capture | kind | error |", "|---|---|---|"]
        lines += [f"| {r.get('capture')} | {r.get('kind')} | {str(r.get('error') or '').replace('|', '/')} |"
                  for r in failed]
        lines.append("")
    plots = _plots(rows, out)
    if plots:
        lines += ["## Plots", ""] + [f"![{p.stem}]({p.name})" for p in plots] + [""]
    return [*plots, write_text(out / "summary.md", "\n".join(lines))]
