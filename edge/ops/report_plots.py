"""Pictures of an evaluation report (``radar-edge plot REPORT.json``): accuracy against the truth.

``radar-edge evaluate --json`` writes the report; this draws ``STEM-accuracy.png`` from it:

* lane profile: position RMSE per 50 m range bin (Lim eq. 20); tracked and raw (any detection)
  detection probability per class and range bin against the 99 % line; and, per class, the detection
  probability apart from and while overlapping another vehicle in range, Doppler and beam, with the
  untracked frames split into before the first track, gaps and after the last;
* surveillance profile: the confusion matrix (counts, the ``missed`` column for targets without a
  track) and the detection probability per class.

matplotlib comes from the ``plot`` extra.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from edge.ops.plots import PlotError, require_matplotlib

_DPI = 110
_PD_AIM = 0.99  # the lane profile's acceptance figure for cars within 300 m


def load_report(path: str | Path) -> dict[str, Any]:
    """Read a ``radar-edge evaluate`` report, with a clear error for anything else."""
    p = Path(path)
    try:
        rep = json.loads(p.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise PlotError(f"{p}: no such file") from None
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise PlotError(f"{p}: not a JSON evaluation report ({exc})") from None
    if not isinstance(rep, dict) or not isinstance(rep.get("summary"), dict) or "profile" not in rep:
        raise PlotError(f"{p}: not a radar-edge evaluate report (no 'profile' and 'summary'); "
                        "write one with radar-edge evaluate --scenario NAME --json OUT")
    if rep["profile"] not in ("lane", "surveillance"):
        raise PlotError(f"{p}: no figure for profile {rep['profile']!r} (lane or surveillance reports)")
    return rep


def _bin_key(label: str) -> float:
    return float(label.split("-")[0])


def _title(rep: dict) -> str:
    return f"{rep.get('scenario', '?')} seed {rep.get('seed', '?')}, {rep.get('frames', '?')} frames"


def plot_report(rep: dict[str, Any], out_dir: str | Path, stem: str) -> Path:
    """Draw the report's accuracy figure into ``out_dir/stem-accuracy.png`` and return its path."""
    plt = require_matplotlib()
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    path = out / f"{stem}-accuracy.png"
    fig = _lane_figure(plt, rep) if rep["profile"] == "lane" else _surveillance_figure(plt, rep)
    fig.savefig(path, dpi=_DPI)
    plt.close(fig)
    return path


def _lane_figure(plt, rep: dict):
    s = rep["summary"]
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.6))
    fig.suptitle(f"lane profile accuracy -- {_title(rep)}")

    ax = axes[0]
    rb = s.get("rmse_by_range_m") or {}
    if rb:
        keys = sorted(rb, key=_bin_key)
        x = np.arange(len(keys))
        ax.bar(x, [rb[k] for k in keys], color="tab:blue")
        ax.set_xticks(x, keys, rotation=30)
        for xi, k in zip(x, keys):
            ax.annotate(f"{rb[k]:.2f}", (xi, rb[k]), ha="center", va="bottom", fontsize=8)
    else:
        ax.text(0.5, 0.5, "no tracked frames", ha="center", transform=ax.transAxes)
    mean = s.get("position_rmse_m_mean")
    ax.set_title("position RMSE by range" + (f" (mean over vehicles {mean:.3f} m)" if mean is not None else ""))
    ax.set_xlabel("ground range bin (m)")
    ax.set_ylabel("RMSE (m)")

    ax = axes[1]
    by_cls = s.get("detection_probability_by_class_and_range") or {}
    colors = {}
    for c, bins in sorted(by_cls.items()):
        keys = sorted(bins, key=_bin_key)
        x = [_bin_key(k) + 25.0 for k in keys]
        (line,) = ax.plot(x, [bins[k]["tracked"] for k in keys], "o-", label=f"{c} tracked")
        colors[c] = line.get_color()
        ax.plot(x, [bins[k]["raw"] for k in keys], ":", color=line.get_color(), label=f"{c} raw")
    ax.axhline(_PD_AIM, color="k", lw=0.8, ls="--", label=f"{_PD_AIM:.0%}")
    ax.set_title("detection probability by range and class")
    ax.set_xlabel("ground range (m, bin centre)")
    ax.set_ylabel("probability")
    ax.set_ylim(0.0, 1.02)
    ax.legend(fontsize=7, loc="lower left", ncol=2)

    ax = axes[2]
    ov = s.get("detection_probability_by_overlap") or {}
    ph = s.get("untracked_frames_by_class") or {}
    classes = sorted(set(ov) | set(ph))
    if classes:
        x = np.arange(len(classes))
        sep = [ov.get(c, {}).get("separate") for c in classes]
        olp = [ov.get(c, {}).get("overlapping") for c in classes]
        ax.bar(x - 0.18, [v or 0.0 for v in sep], 0.36, label="separate", color="0.45")
        ax.bar(x + 0.18, [v or 0.0 for v in olp], 0.36, label="overlapping another vehicle", color="0.75")
        labels = []
        for xi, c, a, b in zip(x, classes, sep, olp):
            for dx, v in ((-0.18, a), (0.18, b)):
                if v is not None:
                    ax.annotate(f"{v:.3f}", (xi + dx, v), ha="center", va="bottom", fontsize=7)
            share = ov.get(c, {}).get("overlapping_fraction")
            u = ph.get(c, {})
            labels.append(c + (f"\noverlapping {share:.0%} of frames" if share is not None else "") + (
                f"\nuntracked: {u.get('before_first', 0)} first,\n{u.get('gaps', 0)} gaps, {u.get('after_last', 0)} last"
                if u else ""))
        ax.set_xticks(x, labels, fontsize=7)
        ax.axhline(_PD_AIM, color="k", lw=0.8, ls="--")
    ax.set_ylim(0.0, 1.02)
    ax.set_title("detection probability: separate vs overlapping")
    ax.set_ylabel("probability")
    ax.legend(fontsize=7, loc="lower left")
    fig.tight_layout()
    return fig


def _surveillance_figure(plt, rep: dict):
    s = rep["summary"]
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.6), gridspec_kw={"width_ratios": [1.4, 1]})
    fig.suptitle(f"surveillance profile accuracy -- {_title(rep)}")
    ax = axes[0]
    cm = s.get("confusion_matrix")
    if cm and cm.get("matrix"):
        m = np.asarray(cm["matrix"], dtype=float)
        ax.imshow(m, cmap="Blues")
        for (i, j), v in np.ndenumerate(m):
            ax.text(j, i, f"{int(v)}", ha="center", va="center", color="white" if v > m.max() / 2 else "black")
        ax.set_xticks(range(m.shape[1]), cm["columns"], rotation=30)
        ax.set_yticks(range(m.shape[0]), cm["labels"])
        ax.set_xlabel("predicted")
        ax.set_ylabel("true class")
    else:
        ax.text(0.5, 0.5, "no confusion matrix", ha="center", transform=ax.transAxes)
    acc = s.get("classification_accuracy")
    ax.set_title("confusion matrix" + (f" (accuracy {acc:.2f})" if acc is not None else ""))
    ax = axes[1]
    pc = {k: v for k, v in (s.get("detection_probability_per_class") or {}).items() if v is not None}
    if pc:
        ax.bar(list(pc), list(pc.values()), color="tab:blue")
        ax.set_ylim(0.0, 1.02)
    ax.set_title("detection probability per class")
    fig.tight_layout()
    return fig
