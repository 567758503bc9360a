"""Plot SPHERIC Test 2 runs (Kleefsman et al. 2005, MARIN 3D dam break with a box) against the experiment:
the water heights H1-H4 and the pressure P1 that the in-run probes of configs/validation/spheric_test2_*.yaml
sampled (OUT/probes.csv), over the measurements shipped in simcli/verify/reference_data/.

    python tools/plot_spheric_test2.py SPH=/tmp/v_sph/runs/spheric_test2_sph-L0-... \
        MPM=/tmp/v_mpm/runs/spheric_test2_mpm-L0-... -o docs/img/spheric_test2.png
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from simcli.verify.cases import reference_dir
from simcli.verify.reference import read_table

REF = "kleefsman2005_spheric_test2.csv"  # t, P1, H1, H2, H3, H4


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("runs", nargs="+", help="LABEL=run folder (holding probes.csv)")
    ap.add_argument("-o", "--out", required=True, type=Path)
    a = ap.parse_args()
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    exp = read_table(reference_dir() / REF)
    fig, axes = plt.subplots(5, 1, figsize=(7.5, 11), sharex=True)
    names = ["H1", "H2", "H3", "H4", "P1"]
    for k, name in enumerate(names):
        ax = axes[k]
        col = 1 if name == "P1" else int(name[1]) + 1
        ax.plot(exp[:, 0], exp[:, col], color="0.6", lw=0.8, label="experiment (Kleefsman et al. 2005)")
        for spec in a.runs:
            label, folder = spec.split("=", 1)
            d = np.genfromtxt(Path(folder) / "probes.csv", delimiter=",", names=True)
            v = d[name]
            if name != "P1":
                v = np.where(np.isnan(v), 0.0, v)  # a dry gauge reads 0, as the cases compare it
            ax.plot(d["time"], v, lw=1.0, label=label)
        ax.set_ylabel(f"{name} [{'Pa' if name == 'P1' else 'm'}]")
        ax.grid(alpha=0.3)
    axes[-1].set_xlabel("t [s]")
    axes[-1].set_xlim(0, 6)
    axes[0].legend(fontsize=8, loc="upper left")
    fig.suptitle("SPHERIC Test 2: MARIN dam break with a box, gauges against the experiment", fontsize=10)
    fig.tight_layout()
    a.out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(a.out, dpi=80)
    print(f"wrote {a.out}")


if __name__ == "__main__":
    main()
