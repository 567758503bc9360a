"""The generated sbatch script: golden text, shell syntax, and its signal/requeue logic run
under plain bash with a stand-in `scontrol` (no Slurm needed)."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from simcli.sweep.slurm import SbatchOptions, array_spec, sbatch_script
from tests.sweep.conftest import HERE

GOLDEN = HERE / "golden" / "sweep.sbatch"


def _golden_text() -> str:
    opts = SbatchOptions(
        partition="gpu",
        time="02:00:00",
        cpus_per_task=8,
        gpus_per_task=1,
        max_parallel=4,
        mem="16G",
        extra=["--constraint=a100"],
    )
    return sbatch_script(
        sweep_path=Path("/data/study/sweeps/jelly.yaml"),
        workdir=Path("/data/study"),
        python="/opt/simcli/.venv/bin/python",
        log_dir=Path("/data/study/out/jelly/_sweep/logs"),
        job_name="simcli-jelly",
        indices=list(range(8)),
        opts=opts,
    )


def test_sbatch_script_matches_golden_file():
    text = _golden_text()
    if os.environ.get("UPDATE_GOLDEN"):
        GOLDEN.write_text(text)
    assert text == GOLDEN.read_text(), "sbatch text changed: check it, then rerun with UPDATE_GOLDEN=1"


def test_sbatch_script_essentials():
    text = _golden_text()
    for line in (
        "#SBATCH --array=0-7%4",
        "#SBATCH --signal=B:USR1@120",
        "#SBATCH --requeue",
        "#SBATCH --open-mode=append",
        "#SBATCH --cpus-per-task=8",
        "#SBATCH --gpus-per-task=1",
        "#SBATCH --partition=gpu",
        "#SBATCH --time=02:00:00",
        "#SBATCH --output=/data/study/out/jelly/_sweep/logs/%x_%A_%a.out",
        'threads="${SLURM_CPUS_PER_TASK:-1}"',
        'scontrol requeue "$task"',
    ):
        assert line in text.splitlines() or line in text, line
    r = subprocess.run(["bash", "-n"], input=text, text=True, capture_output=True, check=False)
    assert r.returncode == 0, r.stderr
    # optional lines are left out when not asked for
    bare = sbatch_script(
        sweep_path=Path("/s.yaml"),
        workdir=Path("/"),
        python="python",
        log_dir=Path("/l"),
        job_name="j",
        indices=[0, 1, 2, 5],
        opts=SbatchOptions(),
    )
    assert "#SBATCH --array=0-2,5\n" in bare
    assert "--partition" not in bare and "--time" not in bare and "--gpus-per-task" not in bare


def test_array_spec():
    assert array_spec(list(range(10))) == "0-9"
    assert array_spec([0, 1, 3], 2) == "0-1,3%2"


def _wait_for(cond, timeout=20.0):
    t = time.time()
    while time.time() - t < timeout:
        if cond():
            return True
        time.sleep(0.05)
    return False


@pytest.mark.skipif(shutil.which("bash") is None, reason="needs bash")
def test_script_forwards_usr1_and_requeues_itself(tmp_path, make_sweep, fake_sim, monkeypatch):
    """USR1 to the batch shell (what --signal=B:USR1 does) reaches the simulation, which
    checkpoints and exits 75; the script then runs `scontrol requeue JOB_TASK`. The requeued
    start resumes from the checkpoint and finishes."""
    monkeypatch.setenv("FAKE_SIM_STEP_S", "0.02")
    sweep = make_sweep('base: tiny.yaml\noutput: out\ngrid: {sim.steps: [400, 5]}\nname: "s{sim.steps}"\n')
    bindir = tmp_path / "bin"
    bindir.mkdir()
    calls = tmp_path / "scontrol_calls.txt"
    (bindir / "scontrol").write_text(f'#!/bin/sh\necho "$@" >> {calls}\n')
    (bindir / "scontrol").chmod(0o755)
    script = tmp_path / "job.sbatch"
    script.write_text(
        sbatch_script(
            sweep_path=sweep,
            workdir=tmp_path,
            python=sys.executable,
            log_dir=tmp_path / "logs",
            job_name="t",
            indices=[0, 1],
            opts=SbatchOptions(),
        )
    )
    env = dict(
        os.environ,
        PATH=f"{bindir}{os.pathsep}{os.environ['PATH']}",
        SLURM_ARRAY_JOB_ID="77",
        SLURM_ARRAY_TASK_ID="0",
        SLURM_JOB_ID="78",
        SLURM_CPUS_PER_TASK="3",
    )
    out = tmp_path / "out" / "s400"
    p = subprocess.Popen(
        ["bash", str(script)], env=env, cwd="/", stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True
    )
    assert _wait_for(lambda: (out / "run.json").exists() and '"running"' in (out / "run.json").read_text())
    time.sleep(0.2)
    p.send_signal(signal.SIGUSR1)
    log, _ = p.communicate(timeout=30)
    assert p.returncode == 75, log
    assert calls.read_text().split() == ["requeue", "77_0"], log
    rj = json.loads((out / "run.json").read_text())
    assert rj["status"] == "interrupted" and rj["exit_code"] == 75 and 0 < rj["steps_done"] < 400
    ckpts = list((out / "checkpoints").glob("ckpt_*.npz"))
    assert len(ckpts) == 1
    # the requeued element starts the same script again: it resumes and finishes
    env.update(SLURM_RESTART_COUNT="1", FAKE_SIM_STEP_S="0.001")
    r = subprocess.run(
        ["bash", str(script)], env=env, cwd="/", capture_output=True, text=True, timeout=60, check=False
    )
    assert r.returncode == 0, r.stderr
    trace = (out / "trace.txt").read_text().split("\n")
    # threads come from SLURM_CPUS_PER_TASK; the second start resumes at the checkpoint's step
    assert trace[0] == "start 0 3" and trace[1] == f"start {rj['steps_done']} 3", trace
    assert json.loads((out / "run.json").read_text())["status"] == "done"
    assert calls.read_text().split() == ["requeue", "77_0"]  # no second requeue
    assert "attempt 2" in r.stderr
