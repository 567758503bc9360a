"""A stand-in for ``simcli run`` with the same contract on disk and the same exit codes
(run.json, checkpoints/ckpt_*.npz, exit 75 after a checkpoint on SIGUSR1/SIGTERM/SIGINT,
``--resume``), but no physics: each step sleeps FAKE_SIM_STEP_S seconds. Used through
SIMCLI_SWEEP_SIM_CMD so the task logic is tested in well under a second per run.

Also appends one line per start to OUT/trace.txt ("start <step> <threads>"), and fails with
exit 70 at step FAKE_SIM_FAIL_AT (if set) to imitate a numerical failure.
"""

import json
import os
import re
import signal
import sys
import time
from pathlib import Path

from simcli.errors import SceneError
from simcli.scene.loader import load_scene


def main(argv):
    args = argv[1:]
    if args and args[0] == "run":
        args = args[1:]
    scene, out, sets, resume = args[0], None, [], False
    i = 1
    while i < len(args):
        a = args[i]
        if a == "-o":
            out = Path(args[i + 1])
            i += 2
        elif a == "--set":
            sets.append(args[i + 1])
            i += 2
        elif a == "--resume":
            resume = True
            i += 1
        else:
            i += 1
    try:
        loaded = load_scene(scene, sets)
    except SceneError as e:
        print("\n".join(e.lines), file=sys.stderr)
        return 65
    n_steps = loaded.scene.sim.n_steps
    dt = loaded.scene.sim.dt
    got = []
    for s in (signal.SIGUSR1, signal.SIGTERM, signal.SIGINT):
        signal.signal(s, lambda n, f: got.append(signal.Signals(n).name))
    out.mkdir(parents=True, exist_ok=True)
    ck = out / "checkpoints"
    step = 0
    if resume:
        found = sorted(ck.glob("ckpt_*.npz")) if ck.is_dir() else []
        if not found:
            print(f"--resume: no checkpoint in {ck}", file=sys.stderr)
            return 2
        step = int(re.search(r"(\d+)", found[-1].name).group(1))
    threads = os.environ.get("SLURM_CPUS_PER_TASK") or os.environ.get("SIMCLI_THREADS") or ""
    with open(out / "trace.txt", "a") as f:
        f.write(f"start {step} {threads}\n")
    info = {
        "status": "running",
        "exit_code": None,
        "pid": os.getpid(),
        "host": os.uname().nodename,
        "overrides": sets,
        "resumed": resume,
        "steps_done": step,
        "sim_time": step * dt,
        "particles": 10,
        "backend": "fake",
        "timings": {"stepping_s": 0.0},
        "throughput": {"steps_per_s": 1.0},
        "peak_memory_mb": 1.0,
    }

    def write(status, code):
        info.update(
            status=status,
            exit_code=code,
            steps_done=step,
            sim_time=step * dt,
            updated=time.strftime("%Y-%m-%dT%H:%M:%S%z"),
        )
        tmp = out / "run.json.tmp"
        tmp.write_text(json.dumps(info))
        os.replace(tmp, out / "run.json")

    write("running", None)
    step_s = float(os.environ.get("FAKE_SIM_STEP_S", "0.01"))
    fail_at = os.environ.get("FAKE_SIM_FAIL_AT")
    while step < n_steps:
        time.sleep(step_s)
        step += 1
        if fail_at is not None and step == int(fail_at):
            info["error"] = "numerical failure (fake)"
            write("failed", 70)
            return 70
        if got:
            ck.mkdir(exist_ok=True)
            (ck / f"ckpt_{step:08d}.npz").write_bytes(b"fake")
            write("interrupted", 75)
            print(f"{got[0]} received: checkpoint at step {step}", file=sys.stderr)
            return 75
        if step % 5 == 0:
            write("running", None)
    write("done", 0)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
