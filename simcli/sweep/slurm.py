"""The sweep as one Slurm job array: the sbatch script and its submission.

Slurm is the scheduler; this module only writes the script.  Each array element runs
``simcli sweep run SWEEP --task $SLURM_ARRAY_TASK_ID``.  ``--signal=B:USR1@120`` makes Slurm
signal only the batch shell two minutes before the time limit, so the script runs the task in
the background, waits, and forwards USR1/TERM to it; the task checkpoints and exits 75, and
the script then requeues its own array element (``scontrol requeue JOB_TASK``; ``--requeue``
allows it), which resumes from the checkpoint when it starts again.  Logs are appended
(``--open-mode=append``) to one file per element, ``%A_%a``.
"""

from __future__ import annotations

import json
import re
import shlex
import shutil
import subprocess
import time
from dataclasses import dataclass, field
from pathlib import Path

from simcli.sweep.model import index_ranges

SUBMISSIONS = "submissions.json"


@dataclass
class SbatchOptions:
    partition: str | None = None
    time: str | None = None
    cpus_per_task: int | None = None
    gpus_per_task: int | None = None
    max_parallel: int | None = None
    mem: str | None = None
    account: str | None = None
    qos: str | None = None
    job_name: str | None = None
    extra: list[str] = field(default_factory=list)  # more sbatch options, e.g. --constraint=a100
    signal_lead_s: int = 120  # seconds before the time limit at which USR1 is sent


def array_spec(indices: list[int], max_parallel: int | None = None) -> str:
    spec = index_ranges(indices)
    if max_parallel:
        spec += f"%{max_parallel}"
    return spec


def _job_name(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9._-]", "_", text)[:64] or "simcli-sweep"


def sbatch_script(
    *,
    sweep_path: Path,
    workdir: Path,
    python: str,
    log_dir: Path,
    job_name: str,
    indices: list[int],
    opts: SbatchOptions,
) -> str:
    """The text of the sbatch script. Paths should be absolute: the job may start anywhere."""
    q = shlex.quote
    lines = [
        "#!/bin/bash",
        f"#SBATCH --job-name={_job_name(opts.job_name or job_name)}",
        f"#SBATCH --array={array_spec(indices, opts.max_parallel)}",
        f"#SBATCH --output={log_dir}/%x_%A_%a.out",
        "#SBATCH --open-mode=append",
        "#SBATCH --ntasks=1",
        f"#SBATCH --signal=B:USR1@{opts.signal_lead_s}",
        "#SBATCH --requeue",
    ]
    if opts.partition:
        lines.append(f"#SBATCH --partition={opts.partition}")
    if opts.time:
        lines.append(f"#SBATCH --time={opts.time}")
    if opts.cpus_per_task:
        lines.append(f"#SBATCH --cpus-per-task={opts.cpus_per_task}")
    if opts.gpus_per_task:
        lines.append(f"#SBATCH --gpus-per-task={opts.gpus_per_task}")
    if opts.mem:
        lines.append(f"#SBATCH --mem={opts.mem}")
    if opts.account:
        lines.append(f"#SBATCH --account={opts.account}")
    if opts.qos:
        lines.append(f"#SBATCH --qos={opts.qos}")
    for x in opts.extra:
        lines.append(f"#SBATCH {x if x.startswith('-') else '--' + x}")
    lines += [
        "",
        "# Written by `simcli sweep submit`; one array element = one run of the sweep.",
        "set -u",
        f"cd {q(str(workdir))} || exit 74",
        'threads="${SLURM_CPUS_PER_TASK:-1}"',
        'export OMP_NUM_THREADS="$threads" SIMCLI_THREADS="$threads"',
        'task="${SLURM_ARRAY_JOB_ID}_${SLURM_ARRAY_TASK_ID}"',
        (
            'echo "simcli sweep: array element $task on $(hostname), attempt $((${SLURM_RESTART_COUNT:-0} + '
            '1)), $(date -Is)" >&2'
        ),
        "",
        "# Slurm sends USR1 (--signal=B:...) to this shell only: run the task in the background and",
        "# pass the signal on, so it checkpoints and exits 75 before the time limit.",
        f'{q(python)} -m simcli sweep run {q(str(sweep_path))} --task "$SLURM_ARRAY_TASK_ID" --threads '
        '"$threads" &',
        "child=$!",
        "trap 'kill -USR1 \"$child\" 2>/dev/null' USR1",
        "trap 'kill -TERM \"$child\" 2>/dev/null' TERM",
        "trap 'kill -INT \"$child\" 2>/dev/null' INT",
        "# wait returns early (status > 128) when a trapped signal arrives: wait until the task is gone",
        'wait "$child"; code=$?',
        'while kill -0 "$child" 2>/dev/null; do wait "$child"; code=$?; done',
        'wait "$child" 2>/dev/null; last=$?; [ "$last" -ne 127 ] && code=$last',
        "",
        'if [ "$code" -eq 75 ]; then',
        '    echo "simcli sweep: $task interrupted after a checkpoint; requeueing it to resume" >&2',
        '    scontrol requeue "$task" || echo "simcli sweep: requeue of $task failed; resubmit to resume" '
        ">&2",
        "fi",
        'exit "$code"',
        "",
    ]
    return "\n".join(lines)


class SubmitError(Exception):
    pass


def sbatch_available() -> bool:
    return shutil.which("sbatch") is not None


def submit(script: Path) -> str:
    """``sbatch --parsable SCRIPT``; returns the job id."""
    exe = shutil.which("sbatch")
    if exe is None:
        raise SubmitError(
            "sbatch not found: is this a Slurm login node? (use --dry-run to only write the "
            "script, or `simcli sweep run-local` to run the sweep here)"
        )
    try:
        r = subprocess.run(
            [exe, "--parsable", str(script)], capture_output=True, text=True, timeout=120, check=False
        )
    except (OSError, subprocess.TimeoutExpired) as e:
        raise SubmitError(f"sbatch failed: {e}") from None
    if r.returncode != 0:
        raise SubmitError(
            f"sbatch refused the job (exit {r.returncode}): {r.stderr.strip() or r.stdout.strip()}"
        )
    job = r.stdout.strip().split(";")[0]
    if not job:
        raise SubmitError(f"sbatch printed no job id: {r.stdout!r} {r.stderr!r}")
    return job


def record_submission(admin_dir: Path, entry: dict) -> Path:
    path = admin_dir / SUBMISSIONS
    try:
        data = json.loads(path.read_text())
        if not isinstance(data, list):
            data = []
    except (OSError, ValueError):
        data = []
    entry = {"submitted": time.strftime("%Y-%m-%dT%H:%M:%S%z"), **entry}
    data.append(entry)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(data, indent=2) + "\n")
    tmp.replace(path)
    return path


def submissions(admin_dir: Path) -> list[dict]:
    try:
        data = json.loads((admin_dir / SUBMISSIONS).read_text())
    except (OSError, ValueError):
        return []
    return data if isinstance(data, list) else []
