"""One task: run, idempotent rerun, resume after an interruption, fresh start after a failure
or a scene change; run-local, status and collect. The simulation is the stand-in
tests/sweep/fake_sim.py (same files and exit codes as `simcli run`, no physics)."""

from __future__ import annotations

import csv
import fcntl
import json
import signal
import subprocess
import sys
import time

import pytest
from click.testing import CliRunner

from simcli.cli import cli
from simcli.sweep.model import load_sweep
from simcli.sweep.tasks import LOCK_FILE, TASK_FILE, _settle, run_task, sweep_states

SWEEP = """\
base: tiny.yaml
output: out
name: "n{sim.steps}"
grid:
  sim.steps: [{steps}, 6]
"""


@pytest.fixture
def sweep(make_sweep, tmp_path, monkeypatch, fake_sim):
    monkeypatch.chdir(tmp_path)

    def make(steps=8, text=SWEEP):
        return make_sweep(text.replace("{steps}", str(steps)))

    return make


def _rj(path):
    return json.loads((path / "run.json").read_text())


def _trace(path):
    return (path / "trace.txt").read_text().split("\n")[:-1]


def _wait_for(cond, timeout=20.0):
    t = time.time()
    while time.time() - t < timeout:
        if cond():
            return True
        time.sleep(0.05)
    return False


def test_task_runs_and_rerun_is_a_no_op(sweep, tmp_path, capfd):
    ls = load_sweep(sweep())
    assert run_task(ls, 0) == 0
    out = tmp_path / "out" / "n8"
    assert _rj(out)["status"] == "done" and _rj(out)["steps_done"] == 8
    rec = json.loads((out / TASK_FILE).read_text())
    assert rec["params"] == {"sim.steps": 8} and rec["index"] == 0 and len(rec["attempts"]) == 1
    assert rec["attempts"][0]["exit_code"] == 0 and rec["attempts"][0]["resume"] is False
    # the overrides reach `simcli run` as --set arguments
    assert _rj(out)["overrides"] == ["sim.steps=8"]
    mtime = (out / "run.json").stat().st_mtime_ns
    assert run_task(ls, 0) == 0
    assert "already done (8 steps" in capfd.readouterr().err
    assert _trace(out) == ["start 0 "]  # started once
    assert (out / "run.json").stat().st_mtime_ns == mtime
    assert len(json.loads((out / TASK_FILE).read_text())["attempts"]) == 1


@pytest.mark.parametrize("sig", [signal.SIGUSR1, signal.SIGTERM])
def test_signal_checkpoints_then_rerun_resumes(sweep, tmp_path, monkeypatch, sig):
    p_sweep = sweep(steps=2000)
    monkeypatch.setenv("FAKE_SIM_STEP_S", "0.01")
    out = tmp_path / "out" / "n2000"
    p = subprocess.Popen(
        [sys.executable, "-m", "simcli", "sweep", "run", str(p_sweep), "--task", "0"],
        stderr=subprocess.PIPE,
        text=True,
    )
    assert _wait_for(lambda: (out / "run.json").exists() and _rj(out)["status"] == "running")
    time.sleep(0.1)
    p.send_signal(sig)  # to the driver: it forwards to the simulation
    _, err = p.communicate(timeout=20)
    assert p.returncode == 75, err
    assert "interrupted (exit 75)" in err
    rj = _rj(out)
    assert rj["status"] == "interrupted" and 0 < rj["steps_done"] < 2000
    ls = load_sweep(p_sweep)
    st = sweep_states(ls)[0]
    assert st.state == "interrupted" and st.detail.startswith("checkpoint ckpt_") and st.n_steps == 2000
    monkeypatch.setenv("FAKE_SIM_STEP_S", "0.0005")
    assert run_task(ls, 0) == 0
    assert _trace(out) == ["start 0 ", f"start {rj['steps_done']} "]
    rec = json.loads((out / TASK_FILE).read_text())
    assert [a["resume"] for a in rec["attempts"]] == [False, True]
    assert [a["exit_code"] for a in rec["attempts"]] == [75, 0]
    assert _rj(out)["status"] == "done" and _rj(out)["steps_done"] == 2000


def test_failed_task_starts_over(sweep, tmp_path, monkeypatch):
    ls = load_sweep(sweep())
    out = tmp_path / "out" / "n8"
    monkeypatch.setenv("FAKE_SIM_FAIL_AT", "3")
    assert run_task(ls, 0) == 70
    assert _rj(out)["status"] == "failed"
    (out / "checkpoints").mkdir()
    (out / "checkpoints" / "ckpt_00000002.npz").write_bytes(b"x")  # from before the failure
    st = sweep_states(ls)[0]
    assert (st.state, st.exit_code) == ("failed", 70) and "numerical failure" in st.detail
    monkeypatch.delenv("FAKE_SIM_FAIL_AT")
    assert run_task(ls, 0) == 0
    assert _trace(out) == ["start 0 ", "start 0 "]  # not resumed: the failure would repeat
    assert not (out / "checkpoints").exists()


def test_checkpoint_of_another_scene_is_not_resumed(sweep, tmp_path, capfd):
    p = sweep()
    ls = load_sweep(p)
    out = tmp_path / "out" / "n8"
    out.mkdir(parents=True)
    (out / "checkpoints").mkdir()
    (out / "checkpoints" / "ckpt_00000004.npz").write_bytes(b"x")
    (out / "run.json").write_text(json.dumps({"status": "interrupted", "exit_code": 75, "steps_done": 4}))
    (out / TASK_FILE).write_text(
        json.dumps({"params": {"sim.steps": 8}, "fingerprint": "from-an-older-base"})
    )
    assert run_task(ls, 0) == 0
    assert "starting over: its checkpoints belong to another version of the scene" in capfd.readouterr().err
    assert _trace(out) == ["start 0 "]


def test_output_of_other_values_is_left_alone(sweep, tmp_path, capfd):
    ls = load_sweep(sweep(text="base: tiny.yaml\noutput: out\ngrid: {sim.steps: [4, 6]}\n"))
    assert run_task(ls, 0) == 0
    # the same index (and default name) now means other values
    ls2 = load_sweep(sweep(text="base: tiny.yaml\noutput: out\ngrid: {sim.steps: [5, 6]}\n"))
    assert run_task(ls2, 0) == 1
    assert "holds a run with other values (sim.steps: 4 there, 5 now)" in capfd.readouterr().err
    assert sweep_states(ls2)[0].state == "stale"
    assert _rj(tmp_path / "out" / "0")["steps_done"] == 4


def test_a_running_task_is_not_started_twice(sweep, tmp_path, capfd):
    ls = load_sweep(sweep())
    out = tmp_path / "out" / "n8"
    out.mkdir(parents=True)
    with open(out / LOCK_FILE, "a") as f:
        fcntl.flock(f, fcntl.LOCK_EX)
        assert run_task(ls, 0) == 1
    assert "already running" in capfd.readouterr().err
    assert not (out / "run.json").exists()


def test_a_child_killed_by_a_signal_is_recorded(tmp_path):
    (tmp_path / "run.json").write_text(json.dumps({"status": "running", "steps_done": 3}))
    assert _settle(tmp_path, -signal.SIGKILL, [], "t") == 137
    assert _rj(tmp_path)["status"] == "failed" and "SIGKILL" in _rj(tmp_path)["error"]
    (tmp_path / "run.json").write_text(json.dumps({"status": "starting"}))
    # stopped by a signal we forwarded, before its handlers were in place: safe to rerun
    assert _settle(tmp_path, -signal.SIGUSR1, [signal.SIGUSR1], "t") == 75
    assert _rj(tmp_path)["status"] == "interrupted"


def test_run_task_index_from_slurm_env(sweep, tmp_path, monkeypatch):
    p = sweep()
    r = CliRunner().invoke(cli, ["sweep", "run", str(p)])
    assert r.exit_code == 2 and "SLURM_ARRAY_TASK_ID" in r.output
    r = CliRunner().invoke(cli, ["sweep", "run", str(p), "--task", "5"])
    assert r.exit_code == 2 and "task 5 does not exist" in r.output
    monkeypatch.setenv("SLURM_ARRAY_TASK_ID", "1")
    monkeypatch.setenv("SLURM_CPUS_PER_TASK", "2")
    r = CliRunner().invoke(cli, ["sweep", "run", str(p)])
    assert r.exit_code == 0, r.output
    assert _rj(tmp_path / "out" / "n6")["status"] == "done"
    assert _trace(tmp_path / "out" / "n6") == ["start 0 2"]


def test_run_local_status_and_collect(sweep, tmp_path):
    import h5py
    import numpy as np

    p = sweep(
        text='base: tiny.yaml\noutput: out\nname: "s{sim.steps}_E{entities.0.material.E}"\n'
        "grid: {sim.steps: [4, 6]}\nzip: {entities.0.material.E: [1.0e4, 2.0e4]}\n"
        "metrics: [throughput.steps_per_s]\n"
    )
    r = CliRunner().invoke(cli, ["sweep", "run-local", str(p), "-j", "2", "--tasks", "0-2"])
    assert r.exit_code == 0, r.output
    assert "summary: 3 done" in r.stderr
    assert (tmp_path / "out" / "_sweep" / "logs" / "local_0.log").exists()
    r = CliRunner().invoke(cli, ["sweep", "status", str(p), "--json"])
    states = json.loads(r.stdout)
    assert [s["state"] for s in states] == ["done", "done", "done", "pending"]
    assert states[0]["steps_done"] == 4 and states[0]["n_steps"] == 4
    r = CliRunner().invoke(cli, ["sweep", "status", str(p)])
    assert "4 runs: 3 done, 1 pending" in r.stderr and "s6_E2e4" in r.stdout
    # frames for one run, measured with the verification measurements
    run0 = tmp_path / "out" / "s4_E1e4"
    with h5py.File(run0 / "sim.h5", "w") as f:
        f["time"] = np.array([0.0, 0.1])
        g = f.create_group("entities/box")
        g["position"] = np.array([[[0.0, 0.0], [1.0, 1.0]], [[0.0, 1.0], [2.0, 1.0]]])
        g["velocity"] = np.array([[[0.0, 0.0], [6.0, 8.0]], [[3.0, 4.0], [0.0, 1.0]]])
    r = CliRunner().invoke(
        cli,
        [
            "sweep",
            "collect",
            str(p),
            "-m",
            "measure.com.box.0",
            "-m",
            "measure.max_speed.box.max",
            "-m",
            "measure.max_speed.box",
        ],
    )
    assert r.exit_code == 0, r.output
    with open(tmp_path / "out" / "results.csv") as f:
        rows = list(csv.DictReader(f))
    assert [row["name"] for row in rows] == ["s4_E1e4", "s4_E2e4", "s6_E1e4", "s6_E2e4"]
    assert [row["state"] for row in rows] == ["done", "done", "done", "pending"]
    assert rows[1]["sim.steps"] == "4" and rows[1]["entities.0.material.E"] == "20000.0"
    assert rows[2]["steps_done"] == "6" and rows[3]["steps_done"] == ""
    assert rows[0]["throughput.steps_per_s"] == "1.0"
    assert rows[0]["measure.com.box.0"] == "1.0"  # last frame
    assert rows[0]["measure.max_speed.box.max"] == "10.0" and rows[0]["measure.max_speed.box"] == "5.0"
    assert rows[1]["measure.com.box.0"] == ""  # no sim.h5 there
    r = CliRunner().invoke(cli, ["sweep", "collect", str(p), "-o", "-", "-m", "measure.com.nobody.0"])
    assert "metric 'measure.com.nobody.0' has no value in any run (KeyError" in r.stderr
    r = CliRunner().invoke(cli, ["sweep", "collect", str(p), "-o", "-"])
    assert r.stdout.splitlines()[0].startswith(
        "index,name,state,exit_code,sim.steps,entities.0.material.E,steps_done"
    )


def test_run_local_reports_failures(sweep, monkeypatch):
    p = sweep()
    monkeypatch.setenv("FAKE_SIM_FAIL_AT", "5")  # n8 fails at step 5, n6 too
    r = CliRunner().invoke(cli, ["sweep", "run-local", str(p), "-j", "2"])
    assert r.exit_code == 1
    assert "summary: 0 done, 2 failed (0: exit 70, 1: exit 70)" in r.stderr


def test_run_local_ctrl_c_interrupts_tasks_and_a_rerun_resumes(sweep, tmp_path, monkeypatch):
    p = sweep(steps=3000)
    monkeypatch.setenv("FAKE_SIM_STEP_S", "0.01")
    proc = subprocess.Popen(
        [sys.executable, "-m", "simcli", "sweep", "run-local", str(p), "-j", "1"],
        stderr=subprocess.PIPE,
        text=True,
    )
    out = tmp_path / "out" / "n3000"
    assert _wait_for(lambda: (out / "run.json").exists() and _rj(out)["status"] == "running")
    time.sleep(0.1)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=20)
    assert proc.returncode == 75, err
    assert "1 interrupted, 1 not started; run it again to resume" in err
    assert _rj(out)["status"] == "interrupted"
    monkeypatch.setenv("FAKE_SIM_STEP_S", "0.0002")
    r = CliRunner().invoke(cli, ["sweep", "run-local", str(p), "-j", "2"])
    assert r.exit_code == 0, r.output
    assert _trace(out)[1].startswith("start ") and _trace(out)[1] != "start 0 "
