"""`simcli plot OUT`: a run's time series on one page.

run.json holds one summary per run (no per-frame records), so the per-frame curves come from sim.h5 (max
and mean speed, kinetic energy, highest point of each entity, collider forces where written) and from
OUT/probes.csv where the scene has probes; run.json's substeps, throughput and wall times are printed
beside them."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .data import open_run, read_probes, read_run_json, series
from .draw import PALETTE, _mpl


def _summary(info: dict) -> str:
    if not info:
        return "no run.json"
    lines = [f"status: {info.get('status')}  exit {info.get('exit_code')}"]
    lines.append(f"steps: {info.get('steps_done')}   sim time: {info.get('sim_time')} s")
    sub = info.get("substeps") or {}
    if sub:
        lines.append(
            f"substeps/step: min {sub.get('min')}  mean {_f(sub.get('mean'))}  max {sub.get('max')}"
            + ("  (auto)" if sub.get("auto") else "")
        )
        if sub.get("dt_min_s") is not None:
            lines.append(f"substep dt: {_f(sub.get('dt_min_s'))} .. {_f(sub.get('dt_max_s'))} s")
    thr = info.get("throughput") or {}
    for k, v in thr.items():
        if isinstance(v, (int, float)) and v:
            lines.append(f"{k.replace('_', ' ')}: {_f(v)}")
    tim = info.get("timings") or {}
    for k in ("compile_s", "stepping_s", "output_s", "time_to_first_step_s"):
        if k in tim:
            lines.append(f"{k[:-2].replace('_', ' ')}: {_f(tim[k])} s")
    if info.get("peak_memory_mb"):
        lines.append(f"peak memory: {info['peak_memory_mb']} MB   backend: {info.get('backend')}")
    for w in (info.get("warnings") or [])[:4]:
        lines.append(f"warning: {str(w)[:80]}")
    return "\n".join(lines)


def _f(v) -> str:
    if v is None:
        return "-"
    v = float(v)
    return f"{v:.4g}" if abs(v) < 1e5 else f"{v:.3e}"


def plot_run(out, path) -> Path:
    _m, plt = _mpl()
    out = Path(out)
    run = open_run(out)
    t = run.times
    ser = series(run)
    probes = read_probes(out)
    info = read_run_json(out)
    panels = [("max_speed", "max speed [m/s]"), ("mean_speed", "mean speed [m/s]")]
    has_ke = any("kinetic_energy" in s for s in ser.values())
    panels.append(
        ("kinetic_energy", "kinetic energy [J]")
        if has_ke
        else ("kinetic_energy_per_kg", "kinetic energy / mass [J/kg]")
    )
    panels.append(("top", "highest point (last axis) [m]"))
    if any("force" in s for s in ser.values()):
        panels.append(("force", "collider force [N]"))
    n_probe = 0
    if probes is not None:
        n_probe = min(len(probes[0]) - 1, 6)
    n = len(panels) + (1 if n_probe else 0) + 1
    cols = 2
    rows = (n + 1) // 2
    fig, axes = plt.subplots(rows, cols, figsize=(10, 2.6 * rows), dpi=100, squeeze=False)
    axes = axes.ravel()
    i = 0
    for key, label in panels:
        ax = axes[i]
        drawn = False
        for j, (name, s) in enumerate(ser.items()):
            if key not in s:
                continue
            y = s[key]
            if y.ndim == 2:
                for c in range(y.shape[1]):
                    ax.plot(t[: len(y)], y[:, c], lw=1.2, label=f"{name} {'xyz'[c]}")
            else:
                ax.plot(t[: len(y)], y, lw=1.4, color=PALETTE[j % len(PALETTE)], label=name)
            drawn = True
        if not drawn:
            continue
        ax.set_ylabel(label, fontsize=8)
        ax.set_xlabel("t [s]", fontsize=8)
        ax.tick_params(labelsize=7)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
        if key.startswith("kinetic") and np.nanmax([s.get(key, np.zeros(1)).max() for s in ser.values()]) > 0:
            ax.set_yscale("symlog", linthresh=1e-6)
        i += 1
    if n_probe:
        ax = axes[i]
        head, data = probes
        for c in range(1, n_probe + 1):
            ax.plot(data[:, 0], data[:, c], lw=1.2, label=head[c])
        ax.set_xlabel(head[0], fontsize=8)
        ax.set_ylabel("probes (probes.csv)", fontsize=8)
        ax.tick_params(labelsize=7)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
        i += 1
    ax = axes[i]
    ax.axis("off")
    ax.text(
        0, 1, _summary(info), va="top", ha="left", family="monospace", fontsize=7.5, transform=ax.transAxes
    )
    for a in axes[i + 1 :]:
        a.axis("off")
    fig.suptitle(f"{run.name}: {run.n_frames} frames, t = {t[-1] if len(t) else 0:.3g} s", fontsize=10)
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, format="png")
    plt.close(fig)
    return path
