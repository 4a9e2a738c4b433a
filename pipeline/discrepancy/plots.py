"""Residual and trajectory plots (PNG) and the rerun recording of a workflow result."""

from __future__ import annotations

import io
import math
from pathlib import Path

import numpy as np
from scipy.stats import chi2

from pipeline.discrepancy.workflow import Result
from pipeline.atomic import write_bytes
from pipeline.viz import record_clip


def safe_file_name(name: str) -> str:
    """``name`` usable as a file name or recording path part: every character but letters,
    digits and ``-_.`` replaced by ``_`` (``"clip"`` for an empty name)."""
    return "".join(ch if ch.isalnum() or ch in "-_." else "_" for ch in name) or "clip"


_PHASE_COLOURS = {"flight": "#ffffff", "contact": "#d62728", "sliding": "#ff7f0e", "rolling": "#2ca02c", "rest": "#7f7f7f"}


def plot_residuals(result: Result, path: str | Path, max_clips: int = 8) -> Path:
    """PNG: per clip, position residual norm (mm) over time for the base model (before) and
    the extended model (after), the flagging threshold, and the measured motion phase as a
    colour band."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    clips = result.clips[:max_clips]
    fig = Figure(figsize=(9, 2.2 * len(clips) + 0.6), dpi=100)
    FigureCanvasAgg(fig)
    axes = fig.subplots(len(clips), 1, squeeze=False)[:, 0]
    label = " + ".join(n["effect"] for n in result.named) or "nothing named"
    for c, (ax, clip) in enumerate(zip(axes, clips)):
        for i, tr in enumerate(clip.tracks):
            idx = np.searchsorted(clip.times, tr.t)
            e0 = np.linalg.norm((result.base_qpos[c][idx, i, :3] - tr.pos)[:, tr.axes], axis=1) * 1e3
            e1 = np.linalg.norm((result.final_qpos[c][idx, i, :3] - tr.pos)[:, tr.axes], axis=1) * 1e3
            ax.plot(tr.t, e0, color="#d62728", lw=1.2, label=f"{tr.object}: base" if c == 0 else None)
            ax.plot(tr.t, e1, color="#1f77b4", lw=1.2, label=f"{tr.object}: + {label}" if c == 0 else None)
            w, dof = min(result.config.segment_window, len(tr.t)), int(tr.axes.sum())
            thr = result.noise[c].position * math.sqrt(chi2.isf(result.config.segment_p, w * dof) / w) * 1e3
            ax.axhline(thr, color="k", ls="--", lw=0.8,
                       label=f"noise threshold (RMS over {w} samples)" if c == 0 and i == 0 else None)
            top = max(float(np.max(e0)), thr) * 1.1
            ph = result.phases[c][i]
            for k in range(len(tr.t)):
                t1 = tr.t[k + 1] if k + 1 < len(tr.t) else tr.t[k] + (tr.t[k] - tr.t[k - 1])
                ax.axvspan(tr.t[k], t1, ymin=0, ymax=0.04, color=_PHASE_COLOURS[ph[k]], lw=0)
            ax.set_ylim(0, top)
        ax.set_title(f"{clip.name}", fontsize=9)
        ax.set_ylabel("|residual| (mm)")
        ax.grid(alpha=0.3)
    axes[-1].set_xlabel("t (s)   band: phase (white flight, red contact, orange sliding, green rolling, grey rest)")
    fig.legend(loc="upper right", fontsize=8)
    fig.tight_layout(rect=(0, 0, 1, 0.97))
    buf = io.BytesIO()
    fig.savefig(buf, format="png")
    return write_bytes(path, buf.getvalue())


def plot_trajectories(result: Result, path: str | Path, max_clips: int = 8) -> Path:
    """PNG: measured positions (dots) against the base and extended models (lines), one row
    per clip, one column per observed coordinate."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    clips = result.clips[:max_clips]
    fig = Figure(figsize=(10, 2.2 * len(clips) + 0.6), dpi=100)
    FigureCanvasAgg(fig)
    axes = fig.subplots(len(clips), 3, squeeze=False)
    for c, clip in enumerate(clips):
        for i, tr in enumerate(clip.tracks):
            for a, name in enumerate("xyz"):
                ax = axes[c, a]
                if not tr.axes[a]:
                    ax.text(0.5, 0.5, "not observed", ha="center", transform=ax.transAxes)
                    continue
                ax.plot(tr.t, tr.pos[:, a], ".", ms=3, color="k", label="measured" if c == a == 0 else None)
                ax.plot(clip.times, result.base_qpos[c][:, i, a], color="#d62728", lw=1, label="base" if c == a == 0 else None)
                ax.plot(clip.times, result.final_qpos[c][:, i, a], color="#1f77b4", lw=1,
                        label="extended" if c == a == 0 else None)
                ax.set_ylabel(f"{name} (m)")
                ax.grid(alpha=0.3)
        axes[c, 0].set_title(clip.name, fontsize=9, loc="left")
    for a in range(3):
        axes[-1, a].set_xlabel("t (s)")
    fig.legend(loc="upper right", fontsize=8)
    fig.tight_layout(rect=(0, 0, 1, 0.97))
    buf = io.BytesIO()
    fig.savefig(buf, format="png")
    return write_bytes(path, buf.getvalue())


def record(result: Result, path: str | Path) -> Path:
    """Rerun recording: every clip's objects as measured, as the base model and as the
    extended model fits them (clips side by side, 1 m apart along y), on a common frame
    timeline, with residual norms as scalars (``metrics/<clip>/base|extended``, m)."""
    T = max(len(c.times) for c in result.clips)
    objs, pos, quat, scalars = [], [], [], {}
    for c, clip in enumerate(result.clips):
        offset = np.array([0.0, 1.0 * c, 0.0])
        for i, tr in enumerate(clip.tracks):
            idx = np.searchsorted(clip.times, tr.t)
            meas_q = tr.quat if tr.quat is not None else result.base_qpos[c][idx, i, 3:]
            for kind, p, q in (("measured", tr.pos, meas_q),
                               ("base", result.base_qpos[c][idx, i, :3], result.base_qpos[c][idx, i, 3:]),
                               ("extended", result.final_qpos[c][idx, i, :3], result.final_qpos[c][idx, i, 3:])):
                pad = T - len(p)
                pp = np.concatenate([p, np.repeat(p[-1:], pad, 0)]) + offset
                qq = np.concatenate([q, np.repeat(q[-1:], pad, 0)])
                objs.append({"name": f"{safe_file_name(clip.name)}/{tr.object}/{kind}", "shape": tr.spec.shape,
                             "size": tr.spec.size})
                pos.append(pp)
                quat.append(qq)
            for kind, q in (("base", result.base_qpos[c]), ("extended", result.final_qpos[c])):
                e = np.linalg.norm((q[idx, i, :3] - tr.pos)[:, tr.axes], axis=1)
                scalars[f"{safe_file_name(clip.name)}/{tr.object}/{kind}"] = np.concatenate(
                    [e, np.full(T - len(e), np.nan)])
    return record_clip(path, positions=np.stack(pos, 1), quaternions=np.stack(quat, 1), objects=objs,
                       scalars=scalars, fps=float(result.clips[0].fps), app_id="dynamics_discrepancy")
