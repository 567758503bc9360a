"""One task of a sweep, and its state on disk.

A task runs ``simcli run BASE -o OUTPUT/NAME --set KEY=VALUE ...`` as a child process (a task
that is killed cannot take its driver with it), so that what runs on a cluster node is exactly
what a user runs by hand.  Running a task again is safe:

- finished (``run.json`` says done): nothing to do, exit 0;
- interrupted or killed with a checkpoint of the same scene: ``--resume`` from it;
- otherwise (never started, failed, no checkpoint, or the scene changed): a fresh start,
  after removing checkpoints that belong to another scene.

SIGUSR1, SIGTERM and SIGINT received by the driver are forwarded to the simulation, which
finishes its step, writes a checkpoint and exits 75; the driver exits with the child's code.
The child runs in its own session (a terminal's Ctrl-C reaches it once, through the driver)
and is sent SIGTERM if the driver dies.

``SIMCLI_SWEEP_SIM_CMD`` replaces ``python -m simcli run`` by another command (the tests use
a stand-in simulator); it is split like a shell command line.
"""

from __future__ import annotations

import ctypes
import fcntl
import json
import os
import platform
import shlex
import shutil
import signal
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

from simcli.errors import (
    EXIT_INTERRUPTED,
    EXIT_INVALID_SCENE,
    EXIT_NUMERICAL,
    EXIT_OK,
    EXIT_OTHER,
    EXIT_OUTPUT,
)
from simcli.sweep.model import LoadedSweep, Run

SIM_CMD_ENV = "SIMCLI_SWEEP_SIM_CMD"
TASK_FILE = "sweep_task.json"
LOCK_FILE = ".sweep.lock"
STALE_S = 900.0  # a running run.json not rewritten for this long is probably dead
FORWARDED = (signal.SIGUSR1, signal.SIGTERM, signal.SIGINT)
_PR_SET_PDEATHSIG = 1


def _log(msg: str) -> None:
    print(f"simcli sweep: {msg}", file=sys.stderr, flush=True)


def sim_command() -> list[str]:
    env = os.environ.get(SIM_CMD_ENV)
    if env:
        return shlex.split(env)
    return [sys.executable, "-m", "simcli", "run"]


def read_json(path: Path) -> dict | None:
    try:
        d = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return d if isinstance(d, dict) else None


def write_json(path: Path, data: dict) -> None:
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(data, indent=2, default=str) + "\n", encoding="utf-8")
    os.replace(tmp, path)


def checkpoints(out: Path) -> list[Path]:
    d = out / "checkpoints"
    return sorted(d.glob("ckpt_*.npz")) if d.is_dir() else []


def _plain(params: dict) -> dict:
    """Values as they read back from JSON, so recorded and current values compare equal."""
    return json.loads(json.dumps(params, default=str))


def _child_setup() -> None:  # pragma: no cover - runs in the child between fork and exec
    # the simulation gets SIGTERM (checkpoint, exit 75) if its driver dies
    try:
        ctypes.CDLL(None, use_errno=True).prctl(_PR_SET_PDEATHSIG, signal.SIGTERM, 0, 0, 0)
    except Exception:  # noqa: BLE001, S110 - best effort: not Linux, no libc
        pass


def _slurm_id() -> str | None:
    a, t = os.environ.get("SLURM_ARRAY_JOB_ID"), os.environ.get("SLURM_ARRAY_TASK_ID")
    if a and t:
        return f"{a}_{t}"
    return os.environ.get("SLURM_JOB_ID")


class _Forwarder:
    """Signal handlers that pass SIGUSR1/SIGTERM/SIGINT on to the child process (exactly once
    each, also when one arrives before the child exists)."""

    def __init__(self, signals=FORWARDED):
        self.signals = signals
        self.received: list[int] = []
        self._pending: list[int] = []
        self._pids: list[int] = []
        self._old: dict = {}

    def _handler(self, signum, frame):
        self.received.append(signum)
        if not self._pids:
            self._pending.append(signum)
        for pid in self._pids:
            _kill(pid, signum)

    def install(self):
        for s in self.signals:
            self._old[s] = signal.signal(s, self._handler)
        return self

    def add(self, pid: int) -> None:
        self._pids.append(pid)
        while self._pending:
            _kill(pid, self._pending.pop(0))

    def remove(self, pid: int) -> None:
        if pid in self._pids:
            self._pids.remove(pid)

    def restore(self):
        for s, h in self._old.items():
            signal.signal(s, h)


def _kill(pid: int, sig: int) -> None:
    try:
        os.kill(pid, sig)
    except ProcessLookupError:
        pass


# -------------------------------------------------------------------- one task


def run_task(ls: LoadedSweep, index: int, threads: int | None = None, quiet: bool = False) -> int:
    """Run, resume or skip run ``index``; returns the exit code of the contract."""
    run = ls.runs[index]
    out = ls.run_dir(run)
    tag = f"task {index} '{run.name}'"
    try:
        out.mkdir(parents=True, exist_ok=True)
        lock = open(out / LOCK_FILE, "a+")  # noqa: SIM115 - held until the task ends
    except OSError as e:
        _log(f"{tag}: cannot write to {out}: {e.strerror or e}")
        return EXIT_OUTPUT
    try:
        try:
            fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            _log(
                f"{tag}: already running (another `simcli sweep run` holds {out / LOCK_FILE}); nothing to do"
            )
            return EXIT_OTHER
        return _run_locked(ls, run, out, tag, threads, quiet)
    finally:
        lock.close()


def _run_locked(ls: LoadedSweep, run: Run, out: Path, tag: str, threads: int | None, quiet: bool) -> int:
    fp = ls.run_fingerprint(run)
    params = _plain(run.params)
    rec = read_json(out / TASK_FILE) or {}
    rj = read_json(out / "run.json")
    status = rj.get("status") if rj else None
    ckpts = checkpoints(out)
    if rec.get("params") not in (None, params) and (rj is not None or ckpts):
        diff = (
            ", ".join(
                f"{k}: {rec['params'].get(k)!r} there, {v!r} now"
                for k, v in params.items()
                if rec["params"].get(k) != v
            )
            or "other keys varied"
        )
        _log(
            f"{tag}: {out} holds a run with other values ({diff}): the sweep file changed. Remove {out} "
            f"(or give the sweep another output folder) to run it again"
        )
        return EXIT_OTHER
    if status == "done" and rj.get("exit_code") == EXIT_OK:
        if rec.get("fingerprint") not in (None, fp):
            _log(
                f"{tag}: warning: the base scene changed since this run finished; remove {out} to run it "
                "again"
            )
        _log(
            f"{tag}: already done ({rj.get('steps_done', '?')} steps, t = {rj.get('sim_time', '?')} s); "
            f"nothing to do"
        )
        return EXIT_OK
    resume = bool(ckpts)
    why_fresh = None
    if ckpts and rec.get("fingerprint") != fp:
        resume, why_fresh = False, "its checkpoints belong to another version of the scene"
    elif ckpts and status == "failed" and rj.get("exit_code") in (EXIT_INVALID_SCENE, EXIT_NUMERICAL):
        resume, why_fresh = False, f"the last attempt failed (exit {rj.get('exit_code')})"
    if ckpts and not resume:
        _log(f"{tag}: starting over: {why_fresh}")
        shutil.rmtree(out / "checkpoints", ignore_errors=True)

    attempt = {
        "started": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
        "host": platform.node(),
        "pid": os.getpid(),
        "resume": resume,
        "slurm_job": _slurm_id(),
        "slurm_restart_count": os.environ.get("SLURM_RESTART_COUNT"),
    }
    rec.update(
        sweep=str(ls.path.resolve()),
        index=run.index,
        name=run.name,
        base=str(ls.base_path.resolve()),
        params=params,
        fingerprint=fp,
    )
    rec["attempts"] = (rec.get("attempts") or [])[-49:] + [attempt]
    try:
        write_json(out / TASK_FILE, rec)
    except OSError as e:
        _log(f"{tag}: cannot write {out / TASK_FILE}: {e.strerror or e}")
        return EXIT_OUTPUT

    cmd = sim_command() + [str(ls.base_path), "-o", str(out)]
    for s in run.set_args():
        cmd += ["--set", s]
    if resume:
        cmd.append("--resume")
    else:  # a fresh start replaces what an earlier attempt left (simcli run refuses that without it)
        cmd.append("--overwrite")
    if quiet:
        cmd.append("--quiet")
    env = dict(os.environ)
    if threads is not None:
        env["SIMCLI_THREADS"] = str(threads)
        env.pop("SLURM_CPUS_PER_TASK", None)  # it would take precedence over SIMCLI_THREADS
    where = f" on {attempt['host']}" + (f", Slurm job {attempt['slurm_job']}" if attempt["slurm_job"] else "")
    _log(f"{tag}: {'resuming from ' + ckpts[-1].name if resume else 'starting'}{where} -> {out}")

    fwd = _Forwarder().install()
    try:
        try:
            proc = subprocess.Popen(cmd, env=env, start_new_session=True, preexec_fn=_child_setup)  # noqa: PLW1509 - single-threaded
        except OSError as e:
            _log(f"{tag}: cannot start {cmd[0]}: {e}")
            return EXIT_OTHER
        fwd.add(proc.pid)
        code = proc.wait()
    finally:
        fwd.restore()
    code = _settle(out, code, fwd.received, tag)
    attempt.update(ended=time.strftime("%Y-%m-%dT%H:%M:%S%z"), exit_code=code)
    try:
        write_json(out / TASK_FILE, rec)
    except OSError:
        pass
    _log(f"{tag}: {describe_exit(code)}")
    return code


def _settle(out: Path, code: int, received: list[int], tag: str) -> int:
    """Map a child killed by a signal to the contract's codes and make run.json say what happened
    (a killed process cannot write it itself)."""
    rj = read_json(out / "run.json")
    status = rj.get("status") if rj else None
    if code < 0:
        sig = signal.Signals(-code).name
        if received:
            # interrupted before it could install its handlers or write a checkpoint: safe to rerun
            code, new, err = (
                EXIT_INTERRUPTED,
                "interrupted",
                f"stopped by {sig} before a checkpoint was written",
            )
        else:
            code, new, err = (
                128 - code,
                "failed",
                f"killed by {sig}" + (" (out of memory?)" if sig == "SIGKILL" else ""),
            )
        if status in (None, "starting", "running"):
            d = dict(rj or {})
            d.update(status=new, exit_code=code, error=err, updated=time.strftime("%Y-%m-%dT%H:%M:%S%z"))
            try:
                write_json(out / "run.json", d)
            except OSError:
                pass
    elif status in ("starting", "running"):
        d = dict(rj)
        d.update(
            status="done" if code == 0 else ("interrupted" if code == EXIT_INTERRUPTED else "failed"),
            exit_code=code,
            updated=time.strftime("%Y-%m-%dT%H:%M:%S%z"),
        )
        d.setdefault("error", f"the simulation exited {code} without updating run.json")
        try:
            write_json(out / "run.json", d)
        except OSError:
            pass
    return code


def describe_exit(code: int) -> str:
    return {
        EXIT_OK: "done (exit 0)",
        EXIT_INTERRUPTED: "interrupted (exit 75): checkpoint written; running the task again resumes it",
        EXIT_INVALID_SCENE: "invalid scene (exit 65)",
        EXIT_NUMERICAL: "numerical failure (exit 70)",
        EXIT_OUTPUT: "output error (exit 74)",
    }.get(code, f"failed (exit {code})")


# ---------------------------------------------------------------- task state


@dataclass
class TaskState:
    index: int
    name: str
    state: str  # pending | starting | running | done | failed | interrupted | stale
    exit_code: int | None = None
    steps_done: int | None = None
    n_steps: int | None = None
    sim_time: float | None = None
    updated: str | None = None
    job: str | None = None
    detail: str = ""
    extra: dict = field(default_factory=dict)

    def as_dict(self) -> dict:
        return {
            k: getattr(self, k)
            for k in (
                "index",
                "name",
                "state",
                "exit_code",
                "steps_done",
                "n_steps",
                "sim_time",
                "updated",
                "job",
                "detail",
            )
        }


def _pid_alive(pid) -> bool:
    try:
        os.kill(int(pid), 0)
    except ProcessLookupError:
        return False
    except (PermissionError, TypeError, ValueError):
        return True
    return True


def task_state(ls: LoadedSweep, run: Run, n_steps: int | None = None) -> TaskState:
    """What run.json (and the task record) say about a run; no Slurm accounting needed."""
    out = ls.run_dir(run)
    st = TaskState(index=run.index, name=run.name, state="pending", n_steps=n_steps)
    rec = read_json(out / TASK_FILE) or {}
    attempts = rec.get("attempts") or []
    if attempts:
        st.job = attempts[-1].get("slurm_job")
    rj = read_json(out / "run.json")
    if rj is None:
        if attempts and "ended" not in attempts[-1]:
            st.state = "starting"
        return st
    if rec.get("params") not in (None, _plain(run.params)):
        st.state = "stale"
        st.detail = f"{out} holds a run with other values (the sweep file changed)"
        return st
    status = rj.get("status", "?")
    st.exit_code = rj.get("exit_code")
    st.steps_done = rj.get("steps_done")
    st.sim_time = rj.get("sim_time")
    st.updated = rj.get("updated")
    st.state = {"killed": "failed"}.get(status, status)
    if status == "failed":
        st.detail = str(rj.get("error", ""))[:200]
    elif status == "interrupted":
        ck = checkpoints(out)
        st.detail = f"checkpoint {ck[-1].name}" if ck else "no checkpoint: restarts from the beginning"
    elif status in ("starting", "running"):
        host, pid = rj.get("host"), rj.get("pid")
        try:
            age = time.time() - (out / "run.json").stat().st_mtime
        except OSError:
            age = 0.0
        if host == platform.node() and pid is not None and not _pid_alive(pid):
            st.state = "failed"
            st.detail = f"process {pid} on {host} is gone without a final status (killed?)"
        elif age > STALE_S:
            st.detail = f"no update for {age / 60:.0f} min: the task may have been killed"
    return st


def sweep_states(ls: LoadedSweep) -> list[TaskState]:
    from simcli.errors import SceneError
    from simcli.sweep.model import load_run_scene

    states = []
    for run in ls.runs:
        try:
            n = load_run_scene(ls, run, check=False).scene.sim.n_steps
        except SceneError:
            n = None
        states.append(task_state(ls, run, n))
    return states


# ------------------------------------------------------------------ run-local


def run_local(
    ls: LoadedSweep, indices: list[int], jobs: int, threads: int | None = None, quiet: bool = False
) -> int:
    """Run tasks as local processes, ``jobs`` at a time, each through ``simcli sweep run``
    (the code path of a Slurm task); logs go to OUTPUT/_sweep/logs/local_<index>.log."""
    log_dir = ls.admin_dir / "logs"
    try:
        log_dir.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        _log(f"cannot create {log_dir}: {e.strerror or e}")
        return EXIT_OUTPUT
    if threads is None:
        cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
        threads = max(1, cores // max(1, jobs))
    queue = list(indices)
    running: dict[int, tuple[subprocess.Popen, object]] = {}
    results: dict[int, int] = {}
    fwd = _Forwarder().install()
    _log(f"{len(queue)} task(s), {jobs} at a time, {threads} thread(s) each; logs in {log_dir}")
    try:
        while running or (queue and not fwd.received):
            while queue and len(running) < jobs and not fwd.received:
                i = queue.pop(0)
                run = ls.runs[i]
                logf = open(log_dir / f"local_{i}.log", "ab")  # noqa: SIM115 - closed when the task ends
                cmd = [
                    sys.executable,
                    "-m",
                    "simcli",
                    "sweep",
                    "run",
                    str(ls.path),
                    "--task",
                    str(i),
                    "--threads",
                    str(threads),
                ] + (["--quiet"] if quiet else [])
                p = subprocess.Popen(
                    cmd,
                    stdout=logf,
                    stderr=subprocess.STDOUT,
                    stdin=subprocess.DEVNULL,
                    start_new_session=True,
                    preexec_fn=_child_setup,
                )  # noqa: PLW1509 - single-threaded
                running[i] = (p, logf)
                fwd.add(p.pid)
                _log(f"task {i} '{run.name}': started (log {log_dir / f'local_{i}.log'})")
            time.sleep(0.1)
            for i, (p, logf) in list(running.items()):
                code = p.poll()
                if code is None:
                    continue
                logf.close()
                fwd.remove(p.pid)
                del running[i]
                results[i] = code
                _log(f"task {i} '{ls.runs[i].name}': {describe_exit(code)}")
    finally:
        fwd.restore()
        for p, logf in running.values():
            logf.close()
    not_started = [i for i in indices if i not in results]
    ok = sum(1 for c in results.values() if c == EXIT_OK)
    bad = {i: c for i, c in results.items() if c not in (EXIT_OK, EXIT_INTERRUPTED)}
    interrupted = [i for i, c in results.items() if c == EXIT_INTERRUPTED]
    parts = [f"{ok} done"]
    if interrupted:
        parts.append(f"{len(interrupted)} interrupted")
    if bad:
        parts.append(f"{len(bad)} failed ({', '.join(f'{i}: exit {c}' for i, c in sorted(bad.items()))})")
    if not_started:
        parts.append(f"{len(not_started)} not started")
    _log("summary: " + ", ".join(parts) + ("; run it again to resume" if interrupted or not_started else ""))
    if bad:
        return EXIT_OTHER
    if interrupted or not_started:
        return EXIT_INTERRUPTED
    return EXIT_OK


# -------------------------------------------------------------------- results

DEFAULT_METRICS = [
    "steps_done",
    "sim_time",
    "particles",
    "backend",
    "timings.startup_s",
    "timings.stepping_s",
    "throughput.steps_per_s",
    "throughput.particle_substeps_per_s",
    "peak_memory_mb",
]
REDUCTIONS = ("final", "max", "min", "mean")
METRIC_HELP = (
    "a dotted path into run.json (throughput.steps_per_s), or measure.<quantity>.<entity>[.<axis>]"
    "[.final|max|min|mean]: a verification measurement of sim.h5 (simcli.verify.measure: com, "
    "min_coord, max_speed, kinetic_energy, ...), reduced over the frames (default: the last frame), or "
    "probe.<name>[.x|y|z][.final|max|min|mean]: a probe's column of probes.csv"
)


def _dig(d, dotted: str):
    cur = d
    for p in dotted.split("."):
        if isinstance(cur, dict) and p in cur:
            cur = cur[p]
        elif isinstance(cur, list) and p.lstrip("-").isdigit() and -len(cur) <= int(p) < len(cur):
            cur = cur[int(p)]
        else:
            return False, None
    return True, cur


def parse_measure(metric: str) -> tuple[str, str, int | None, str]:
    """'measure.com.jelly.1.max' -> ('com', 'jelly', 1, 'max'). Raises ValueError."""
    parts = metric.split(".")
    if len(parts) < 3 or parts[0] != "measure":
        raise ValueError(
            f"'{metric}': expected measure.<quantity>.<entity>[.<axis>][.{'|'.join(REDUCTIONS)}]"
        )
    quantity, entity, axis, reduce = parts[1], parts[2], None, "final"
    for p in parts[3:]:
        if p.isdigit():
            axis = int(p)
        elif p in REDUCTIONS:
            reduce = p
        else:
            raise ValueError(
                f"'{metric}': '{p}' is neither an axis (0, 1, 2) nor one of {', '.join(REDUCTIONS)}"
            )
    return quantity, entity, axis, reduce


def measure_value(out: Path, metric: str) -> float:
    """A verification measurement (simcli.verify.measure) of OUT/sim.h5, reduced to one number."""
    import numpy as np

    from simcli.verify.measure import run_measurement

    quantity, entity, axis, reduce = parse_measure(metric)
    _, v = run_measurement(out / "sim.h5", quantity, entity, axis, {})
    if len(v) == 0:
        raise ValueError("no frames")
    return float({"final": lambda a: a[-1], "max": np.max, "min": np.min, "mean": np.mean}[reduce](v))


def collect_rows(ls: LoadedSweep, metrics: list[str]) -> tuple[list[str], list[list], list[str]]:
    """(header, rows, warnings): index, name, state, exit code, the varied values, the default
    run.json metrics, then ``metrics``, one row per run (empty cells where a value is missing)."""
    from simcli.probes import collect as probe_cols  # probe.<name>[.<comp>].<reduction> (OUT/probes.csv)

    keys = list(ls.runs[0].params) if ls.runs else []
    auto = probe_cols.columns(ls.run_dir(r) for r in ls.runs)  # every probe is picked up unasked
    columns = list(dict.fromkeys(DEFAULT_METRICS + list(metrics) + auto))
    notes: list[str] = []
    for m in metrics:
        if m.startswith("measure.") or m.startswith("probe."):
            try:
                (parse_measure if m.startswith("measure.") else probe_cols.parse)(m)
            except ValueError as e:
                notes.append(str(e))
    found: set[str] = set()
    failed: dict[str, str] = {}
    rows = []
    for run in ls.runs:
        out = ls.run_dir(run)
        st = task_state(ls, run)
        rj = read_json(out / "run.json") or {}
        row = [run.index, run.name, st.state, st.exit_code]
        row += [
            json.dumps(run.params[k]) if isinstance(run.params[k], (list, dict)) else run.params[k]
            for k in keys
        ]
        for m in columns:
            v = None
            if m.startswith("measure."):
                if (out / "sim.h5").exists():
                    try:
                        v = measure_value(out, m)
                    except Exception as e:  # noqa: BLE001 - a missing entity, an unknown quantity, a damaged file
                        failed.setdefault(m, f"{type(e).__name__}: {e}")
            elif m.startswith("probe."):
                try:
                    v = probe_cols.value(out, m)
                except (KeyError, ValueError, OSError) as e:
                    failed.setdefault(m, f"{type(e).__name__}: {e}")
            else:
                _, v = _dig(rj, m)
                if isinstance(v, (list, dict)):
                    v = json.dumps(v)
            if v is not None:
                found.add(m)
            row.append(v)
        rows.append(row)
    for m in metrics:
        if m not in found and any(r[2] == "done" for r in rows):
            why = failed.get(m)
            notes.append(
                f"metric '{m}' has no value in any run"
                + (f" ({why})" if why else f"; a metric is {METRIC_HELP}")
            )
    return ["index", "name", "state", "exit_code"] + keys + columns, rows, notes


def write_csv(stream, header: list[str], rows: list[list]) -> None:
    import csv

    w = csv.writer(stream)
    w.writerow(header)
    for r in rows:
        w.writerow(["" if v is None else v for v in r])
