"""Against a real Slurm: a one-node cluster on localhost from Debian's packages (slurmctld,
slurmd, slurm-client; AuthType=auth/none, no munge), a small sweep submitted with
`simcli sweep submit`, one task sent USR1 mid-run (what --signal=B:USR1@120 does before the
time limit) that must checkpoint, exit 75, requeue itself, resume and finish; then every
task's output is checked.

Marked slurm and slow (about a minute), so the default suite leaves it out: run it with
`pytest -m slurm`. Skips with the reason when the Slurm binaries are missing or when not root
(slurmd must be root).
"""

from __future__ import annotations

import csv
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tests.sweep.conftest import ROOT, TINY

BINARIES = ("slurmctld", "slurmd", "sbatch", "scontrol", "squeue", "scancel", "sinfo")
_missing = [b for b in BINARIES if shutil.which(b) is None]

pytestmark = [
    pytest.mark.slurm,
    pytest.mark.slow,  # about a minute: kept out of the default suite; run it with -m slurm
    pytest.mark.skipif(
        bool(_missing),
        reason=f"Slurm binaries missing ({', '.join(_missing)}): "
        "apt-get install -y slurmctld slurmd slurm-client",
    ),
    pytest.mark.skipif(os.geteuid() != 0, reason="starting slurmd needs root"),
    pytest.mark.timeout(300),
]

LONG_STEPS = 150_000  # about 20 s of stepping on one core: long enough to be interrupted mid-run


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _wait(cond, timeout: float, what: str, every: float = 0.5):
    t0 = time.time()
    while time.time() - t0 < timeout:
        got = cond()
        if got:
            return got
        time.sleep(every)
    raise AssertionError(f"timed out after {timeout:.0f} s waiting for {what}")


@pytest.fixture(scope="module")
def slurm(tmp_path_factory):
    """A single-node Slurm controller and daemon on localhost; yields the environment
    (SLURM_CONF) for its client commands. The daemons are stopped by their pids."""
    d = tmp_path_factory.mktemp("slurm")
    host = socket.gethostname().split(".")[0]
    for sub in ("state", "spool", "log"):
        (d / sub).mkdir()
    conf = d / "slurm.conf"
    conf.write_text(f"""\
ClusterName=simclitest
SlurmctldHost={host}(127.0.0.1)
AuthType=auth/none
CredType=cred/none
# a requeued job waits cred_expire seconds before it may start again (default 120)
AuthInfo=cred_expire=5
SlurmUser=root
SlurmdUser=root
SlurmctldPort={_free_port()}
SlurmdPort={_free_port()}
StateSaveLocation={d}/state
SlurmdSpoolDir={d}/spool
SlurmctldPidFile={d}/slurmctld.pid
SlurmdPidFile={d}/slurmd.pid
SlurmctldLogFile={d}/log/slurmctld.log
SlurmdLogFile={d}/log/slurmd.log
MailProg=/bin/true
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
SwitchType=switch/none
MpiDefault=none
ReturnToService=2
SchedulerType=sched/builtin
SchedulerParameters=sched_interval=1
SelectType=select/cons_tres
SelectTypeParameters=CR_CPU
JobCompType=jobcomp/none
AccountingStorageType=accounting_storage/none
JobAcctGatherType=jobacct_gather/none
# four one-CPU slots whatever the machine has
SlurmdParameters=config_overrides
KillWait=5
MinJobAge=600
NodeName={host} NodeAddr=127.0.0.1 CPUs=4 RealMemory=2000 State=UNKNOWN
PartitionName=debug Nodes={host} Default=YES MaxTime=INFINITE State=UP
""")
    env = dict(os.environ, SLURM_CONF=str(conf))
    pids = []
    try:
        subprocess.run(["slurmctld", "-f", str(conf), "-i"], env=env, check=True, timeout=30)
        _wait(lambda: (d / "slurmctld.pid").exists(), 20, "slurmctld to start")
        pids.append(int((d / "slurmctld.pid").read_text()))
        subprocess.run(["slurmd", "-f", str(conf), "-N", host], env=env, check=True, timeout=30)
        _wait(lambda: (d / "slurmd.pid").exists(), 20, "slurmd to start")
        pids.append(int((d / "slurmd.pid").read_text()))

        def idle():
            r = subprocess.run(
                ["sinfo", "-h", "-o", "%T"], env=env, capture_output=True, text=True, check=False
            )
            return r.returncode == 0 and r.stdout.strip() == "idle"

        try:
            _wait(idle, 60, "the node to become idle")
        except AssertionError:
            logs = "\n".join(p.read_text()[-2000:] for p in sorted((d / "log").glob("*.log")))
            raise AssertionError(f"Slurm did not come up:\n{logs}") from None
        yield {"env": env, "dir": d}
    finally:
        _stop(env, pids)


def _stop(env: dict, pids: list[int]) -> None:
    """Cancel every job, let the steps end, shut the daemons down; SIGKILL what is left."""

    def run(*cmd):
        return subprocess.run(cmd, env=env, capture_output=True, text=True, check=False, timeout=30)

    run("scancel", "--user", "root")
    t0 = time.time()
    while time.time() - t0 < 30 and run("squeue", "-h").stdout.strip():
        time.sleep(0.5)
    run("scontrol", "shutdown")
    for pid in pids:
        t0 = time.time()
        while time.time() - t0 < 15:
            try:
                os.kill(pid, 0)
            except ProcessLookupError:
                break
            time.sleep(0.2)
        else:
            try:
                os.kill(pid, signal.SIGKILL)
            except ProcessLookupError:
                pass


def _sim(args, env, cwd, **kw):
    return subprocess.run(
        [sys.executable, "-m", "simcli", *args],
        env=env,
        cwd=cwd,
        capture_output=True,
        text=True,
        check=False,
        **kw,
    )


def _read(p: Path) -> dict | None:
    try:
        return json.loads(p.read_text())
    except (OSError, ValueError):
        return None


def test_sweep_on_slurm_with_a_requeued_task(slurm, tmp_path):
    import h5py

    env = dict(slurm["env"], PYTHONPATH=str(ROOT))
    env.pop("SIMCLI_SWEEP_SIM_CMD", None)
    (tmp_path / "tiny.yaml").write_text(TINY.read_text())
    sweep = tmp_path / "study.yaml"
    sweep.write_text(f"""\
version: 1
base: tiny.yaml
name: "E{{entities.0.material.E}}_n{{sim.steps}}"
grid:
  entities.0.material.E: [1.0e4, 2.0e4]
zip:
  sim.steps: [20, {LONG_STEPS}]
  output.every: [5, {LONG_STEPS // 10}]
output: out/study
""")
    # runs 0 and 2 are short; 1 and 3 are long; run 3 gets interrupted
    r = _sim(["sweep", "expand", str(sweep), "--json"], env, tmp_path)
    runs = json.loads(r.stdout)
    assert [x["name"] for x in runs] == ["E1e4_n20", f"E1e4_n{LONG_STEPS}", "E2e4_n20", f"E2e4_n{LONG_STEPS}"]
    victim = 3
    out = tmp_path / "out" / "study"

    r = _sim(
        ["sweep", "submit", str(sweep), "--cpus-per-task", "1", "--max-parallel", "4", "--time", "10"],
        env,
        tmp_path,
    )
    assert r.returncode == 0, r.stderr
    job = r.stdout.strip()
    assert job.isdigit(), r.stdout
    subs = json.loads((out / "_sweep" / "submissions.json").read_text())
    assert subs[-1]["job_id"] == job and subs[-1]["array"] == "0-3%4"
    script = (out / "_sweep" / "study.sbatch").read_text()
    assert "#SBATCH --signal=B:USR1@120" in script and "#SBATCH --requeue" in script

    # once the long run is stepping, signal its batch shell as Slurm does before the time limit
    run_json = out / runs[victim]["name"] / "run.json"
    _wait(lambda: (_read(run_json) or {}).get("status") == "running", 90, "the long task to start stepping")
    time.sleep(1.5)
    r = subprocess.run(
        ["scancel", "--signal=USR1", "--batch", f"{job}_{victim}"],
        env=env,
        capture_output=True,
        text=True,
        check=False,
    )
    assert r.returncode == 0, r.stderr

    # it checkpoints, exits 75 and requeues itself
    def interrupted():
        d = _read(run_json) or {}
        return d if d.get("status") == "interrupted" else None

    first = _wait(interrupted, 60, "the signalled task to checkpoint and exit 75", every=0.1)
    assert first["exit_code"] == 75 and 0 < first["steps_done"] < LONG_STEPS
    assert (tmp_path / first["checkpoint"]).exists()  # relative to the working directory of the job

    def all_done():
        r = _sim(["sweep", "status", str(sweep), "--json"], env, tmp_path)
        states = json.loads(r.stdout) if r.returncode == 0 else []
        if not states or not all(s["state"] == "done" for s in states):
            return None
        # run.json says done as soon as the simulation exits; the `sweep run` wrapper records the
        # attempt's end a moment later: wait for that too before reading the records
        for x in runs:
            rec = _read(out / x["name"] / "sweep_task.json") or {}
            if not rec.get("attempts") or "exit_code" not in rec["attempts"][-1]:
                return None
        return states

    try:
        states = _wait(all_done, 180, "every task to finish", every=2)
    except AssertionError:
        logs = "\n".join(p.read_text()[-3000:] for p in sorted((out / "_sweep" / "logs").glob("*.out")))
        q = subprocess.run(["squeue"], env=env, capture_output=True, text=True, check=False).stdout
        raise AssertionError(f"not finished; squeue:\n{q}\nlogs:\n{logs}") from None
    assert [s["steps_done"] for s in states] == [20, LONG_STEPS, 20, LONG_STEPS]

    # every task's output: run.json done, every frame in sim.h5, one attempt (or two for the victim)
    for x, s in zip(runs, states):
        d = out / x["name"]
        rj = json.loads((d / "run.json").read_text())
        assert rj["status"] == "done" and rj["exit_code"] == 0
        assert rj["overrides"] == x["set"]
        steps = x["overrides"]["sim.steps"]
        with h5py.File(d / "sim.h5", "r") as f:
            assert list(f["step"][...]) == list(range(0, steps + 1, x["overrides"]["output.every"]))
            pos = f["entities"]["box"]["position"][...]
            assert pos.shape[0] == 11 if steps == LONG_STEPS else pos.shape[0] == 5
        rec = json.loads((d / "sweep_task.json").read_text())
        jobs = [a["slurm_job"] for a in rec["attempts"]]
        assert all(j == f"{job}_{x['index']}" for j in jobs), jobs
        if x["index"] == victim:
            assert [a["exit_code"] for a in rec["attempts"]] == [75, 0]
            assert [a["resume"] for a in rec["attempts"]] == [False, True]
            assert rec["attempts"][1]["slurm_restart_count"] == "1"
            assert rj["resumed"] is True
        else:
            assert [a["exit_code"] for a in rec["attempts"]] == [0], rec["attempts"]

    # the victim's log (appended across the requeue) tells the story
    log = (out / "_sweep" / "logs" / f"simcli-study_{job}_{victim}.out").read_text()
    for needle in (
        "attempt 1",
        "SIGUSR1 received: checkpoint written",
        "interrupted (exit 75)",
        "requeueing it to resume",
        "attempt 2",
        "resuming from ckpt_",
        "done (exit 0)",
    ):
        assert needle in log, f"{needle!r} not in log:\n{log}"
    show = subprocess.run(
        ["scontrol", "show", "job", f"{job}_{victim}"], env=env, capture_output=True, text=True, check=False
    ).stdout
    assert "Restarts=1" in show, show

    # results in one table
    r = _sim(
        ["sweep", "collect", str(sweep), "-m", "measure.com.box.1", "-m", "measure.max_speed.box.max"],
        env,
        tmp_path,
    )
    assert r.returncode == 0, r.stderr
    with open(out / "results.csv") as f:
        rows = list(csv.DictReader(f))
    assert [row["state"] for row in rows] == ["done"] * 4
    assert all(float(row["measure.com.box.1"]) < 0.5 for row in rows)  # every box fell under gravity
    # and a finished task run again is a no-op
    r = _sim(["sweep", "run", str(sweep), "--task", "0"], env, tmp_path)
    assert r.returncode == 0 and "already done" in r.stderr
