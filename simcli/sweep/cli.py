"""``simcli sweep ...``: parameter studies from one sweep file, locally or on Slurm.

Human messages go to stderr; stdout carries the result of ``expand``, ``status`` (tables, or
JSON with ``--json``) and ``submit --dry-run`` (the script).
"""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path

import click

from simcli.errors import EXIT_INVALID_SCENE, EXIT_OTHER, EXIT_OUTPUT, SceneError


def _err(msg: str) -> None:
    click.echo(msg, err=True)


def _load(path: Path):
    from simcli.sweep.model import load_sweep

    try:
        return load_sweep(path)
    except SceneError as e:
        for line in e.lines:
            _err(line)
        sys.exit(EXIT_INVALID_SCENE)


def _load_valid(path: Path):
    """The sweep, after checking every expanded scene: on any problem, print them all and exit."""
    from simcli.sweep.model import validate_runs

    ls = _load(path)
    lines = validate_runs(ls)
    for line in lines:
        _err(line)
    if lines:
        sys.exit(EXIT_INVALID_SCENE)
    return ls


def _indices(ls, tasks: str | None) -> list[int]:
    from simcli.sweep.model import parse_indices

    if tasks is None:
        return [r.index for r in ls.runs]
    try:
        return parse_indices(tasks, len(ls.runs))
    except ValueError as e:
        raise click.BadParameter(str(e), param_hint="--tasks") from None


def _table(rows: list[list[str]]) -> str:
    widths = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
    return "\n".join("  ".join(c.ljust(w) for c, w in zip(r, widths)).rstrip() for r in rows)


SWEEP_ARG = click.argument(
    "sweep_file", metavar="SWEEP.yaml", type=click.Path(dir_okay=False, path_type=Path)
)


@click.group(context_settings={"help_option_names": ["-h", "--help"]})
def sweep() -> None:
    """Parameter studies: one base scene, keys varied over a grid and/or zipped lists, one run
    per combination; run locally (run-local) or as a Slurm job array (submit)."""


@sweep.command()
@SWEEP_ARG
@click.option("--json", "as_json", is_flag=True, help="Machine-readable output.")
def expand(sweep_file: Path, as_json: bool) -> None:
    """List the runs: index, name, output folder and the values each one sets."""
    from simcli.sweep.model import name_value_text

    ls = _load(sweep_file)
    if as_json:
        click.echo(
            json.dumps(
                [
                    {
                        "index": r.index,
                        "name": r.name,
                        "out": str(ls.run_dir(r)),
                        "overrides": r.params,
                        "set": r.set_args(),
                    }
                    for r in ls.runs
                ],
                indent=2,
            )
        )
        return
    keys = list(ls.runs[0].params) if ls.runs else []
    rows = [["INDEX", "NAME"] + keys]
    for r in ls.runs:
        rows.append([str(r.index), r.name] + [name_value_text(r.params[k]) for k in keys])
    click.echo(_table(rows))
    _err(f"{len(ls.runs)} run(s) of {ls.base_path}, output in {ls.output_dir}/<name>/")


@sweep.command()
@SWEEP_ARG
@click.option("--quiet", "-q", is_flag=True, help="Print errors only.")
def validate(sweep_file: Path, quiet: bool) -> None:
    """Check the sweep file and every expanded scene, without starting any solver."""
    ls = _load_valid(sweep_file)
    if not quiet:
        _err(f"{sweep_file}: ok ({len(ls.runs)} runs of {ls.base_path})")


@sweep.command()
@SWEEP_ARG
@click.option(
    "--task",
    "task",
    type=int,
    default=None,
    help="Run index (see `sweep expand`); default $SLURM_ARRAY_TASK_ID.",
)
@click.option(
    "--threads",
    type=click.IntRange(min=1),
    default=None,
    help="CPU threads of the simulation (default: $SLURM_CPUS_PER_TASK, else every core).",
)
@click.option("--quiet", "-q", is_flag=True, help="No progress output from the simulation.")
def run(sweep_file: Path, task: int | None, threads: int | None, quiet: bool) -> None:
    """Run one task into OUTPUT/<name>/: a no-op when it is done, a resume when it was interrupted.

    Exits with the simulation's code (75: interrupted after a checkpoint, safe to run again)."""
    from simcli.sweep.tasks import run_task

    if task is None:
        env = os.environ.get("SLURM_ARRAY_TASK_ID")
        if env is None:
            raise click.UsageError("give --task N (or run inside a Slurm job array: $SLURM_ARRAY_TASK_ID)")
        try:
            task = int(env)
        except ValueError:
            raise click.UsageError(f"SLURM_ARRAY_TASK_ID is not an integer: {env!r}") from None
    ls = _load(sweep_file)
    if not 0 <= task < len(ls.runs):
        raise click.BadParameter(
            f"task {task} does not exist: the sweep has {len(ls.runs)} runs (0-{len(ls.runs) - 1})",
            param_hint="--task",
        )
    sys.exit(run_task(ls, task, threads=threads, quiet=quiet))


@sweep.command("run-local")
@SWEEP_ARG
@click.option(
    "-j",
    "--jobs",
    type=click.IntRange(min=1),
    default=1,
    show_default=True,
    help="Tasks running at the same time.",
)
@click.option("--tasks", default=None, metavar="LIST", help="Only these runs, e.g. 0-3,7 (default: all).")
@click.option(
    "--threads",
    type=click.IntRange(min=1),
    default=None,
    help="CPU threads per task (default: the cores divided by -j).",
)
@click.option("--quiet", "-q", is_flag=True, help="No progress lines in the task logs.")
def run_local(sweep_file: Path, jobs: int, tasks: str | None, threads: int | None, quiet: bool) -> None:
    """Run the sweep's tasks as local processes, J at a time (each one as `sweep run --task N`).

    Ctrl-C interrupts every running task after a checkpoint; running the command again resumes."""
    from simcli.sweep.tasks import run_local as _run_local

    ls = _load_valid(sweep_file)
    sys.exit(_run_local(ls, _indices(ls, tasks), jobs, threads=threads, quiet=quiet))


@sweep.command()
@SWEEP_ARG
@click.option("--partition", "-p", default=None, help="Slurm partition.")
@click.option(
    "--time", "-t", "time_limit", default=None, help="Time limit per task (Slurm syntax, e.g. 4:00:00)."
)
@click.option(
    "--cpus-per-task",
    "-c",
    type=click.IntRange(min=1),
    default=None,
    help="CPU cores per task; the simulation uses as many threads.",
)
@click.option("--gpus-per-task", type=click.IntRange(min=0), default=None, help="GPUs per task.")
@click.option(
    "--max-parallel",
    "-K",
    type=click.IntRange(min=1),
    default=None,
    help="At most K tasks running at once (--array=...%K).",
)
@click.option("--mem", default=None, help="Memory per task (Slurm syntax, e.g. 8G).")
@click.option("--account", "-A", default=None, help="Slurm account.")
@click.option("--qos", default=None, help="Slurm QOS.")
@click.option("--tasks", default=None, metavar="LIST", help="Only these runs, e.g. 0-3,7 (default: all).")
@click.option(
    "--sbatch-option",
    "extra",
    multiple=True,
    metavar="OPT",
    help="Another sbatch option for the script, e.g. --constraint=a100. Repeatable.",
)
@click.option("--dry-run", is_flag=True, help="Write and print the script, do not submit it.")
def submit(
    sweep_file: Path,
    partition,
    time_limit,
    cpus_per_task,
    gpus_per_task,
    max_parallel,
    mem,
    account,
    qos,
    tasks,
    extra,
    dry_run,
) -> None:
    """Submit the sweep as one Slurm job array (one element per run; preemption-safe).

    Writes OUTPUT/_sweep/<sweep>.sbatch, submits it with sbatch and records the job id in
    OUTPUT/_sweep/submissions.json. A task stopped by its time limit or by preemption
    checkpoints, exits 75 and is requeued; it resumes from its checkpoint."""
    from simcli.sweep.slurm import SbatchOptions, SubmitError, array_spec, record_submission, sbatch_script
    from simcli.sweep.slurm import submit as _submit

    ls = _load_valid(sweep_file)
    indices = _indices(ls, tasks)
    opts = SbatchOptions(
        partition=partition,
        time=time_limit,
        cpus_per_task=cpus_per_task,
        gpus_per_task=gpus_per_task,
        max_parallel=max_parallel,
        mem=mem,
        account=account,
        qos=qos,
        extra=list(extra),
    )
    admin = ls.admin_dir.resolve()
    log_dir = admin / "logs"
    text = sbatch_script(
        sweep_path=ls.path.resolve(),
        workdir=Path.cwd(),
        python=sys.executable,
        log_dir=log_dir,
        job_name=f"simcli-{ls.label}",
        indices=indices,
        opts=opts,
    )
    script = admin / f"{ls.label}.sbatch"
    try:
        log_dir.mkdir(parents=True, exist_ok=True)  # Slurm does not create the log folder
        script.write_text(text)
    except OSError as e:
        _err(f"cannot write {script}: {e.strerror or e}")
        sys.exit(EXIT_OUTPUT)
    if dry_run:
        click.echo(text, nl=False)
        _err(f"wrote {script} ({len(indices)} tasks); not submitted (--dry-run)")
        return
    try:
        job = _submit(script)
    except SubmitError as e:
        _err(f"simcli sweep: {e}")
        sys.exit(EXIT_OTHER)
    path = record_submission(
        admin,
        {
            "job_id": job,
            "array": array_spec(indices, max_parallel),
            "script": str(script),
            "sweep": str(ls.path.resolve()),
            "workdir": str(Path.cwd()),
            "n_tasks": len(indices),
        },
    )
    _err(f"submitted job array {job} ({len(indices)} tasks of {ls.path}); recorded in {path}")
    _err(f"  follow it:   simcli sweep status {sweep_file}    (and squeue -j {job})")
    _err(f"  logs:        {log_dir}/simcli-{ls.label}_{job}_<task>.out")
    _err(f"  results:     simcli sweep collect {sweep_file}")
    click.echo(job)


@sweep.command()
@SWEEP_ARG
@click.option("--json", "as_json", is_flag=True, help="Machine-readable output.")
def status(sweep_file: Path, as_json: bool) -> None:
    """Each task's state from its run.json (no Slurm accounting needed): pending, starting,
    running, done, failed (exit code), interrupted (resumes when run again)."""
    from simcli.sweep.slurm import submissions
    from simcli.sweep.tasks import sweep_states

    ls = _load(sweep_file)
    states = sweep_states(ls)
    if as_json:
        click.echo(json.dumps([s.as_dict() for s in states], indent=2))
        return
    rows = [["INDEX", "NAME", "STATE", "EXIT", "STEPS", "SIM_TIME", "JOB", "DETAIL"]]
    for s in states:
        steps = (
            ""
            if s.steps_done is None
            else (f"{s.steps_done}/{s.n_steps}" if s.n_steps else str(s.steps_done))
        )
        if s.steps_done is not None and s.n_steps and s.state not in ("done",):
            steps += f" ({100.0 * s.steps_done / s.n_steps:.0f}%)"
        rows.append(
            [
                str(s.index),
                s.name,
                s.state,
                "" if s.exit_code is None else str(s.exit_code),
                steps,
                "" if s.sim_time is None else f"{s.sim_time:.4g}",
                s.job or "",
                s.detail,
            ]
        )
    click.echo(_table(rows))
    counts: dict[str, int] = {}
    for s in states:
        counts[s.state] = counts.get(s.state, 0) + 1
    summary = ", ".join(f"{n} {k}" for k, n in sorted(counts.items()))
    subs = submissions(ls.admin_dir)
    tail = f"; last submission: job {subs[-1]['job_id']} at {subs[-1]['submitted']}" if subs else ""
    _err(f"{len(states)} runs: {summary}{tail}")


@sweep.command()
@SWEEP_ARG
@click.option(
    "-o",
    "--out",
    "out",
    default=None,
    metavar="CSV",
    help="Where to write the table (default OUTPUT/results.csv; '-' for stdout).",
)
@click.option(
    "--metric",
    "-m",
    "metrics",
    multiple=True,
    metavar="PATH",
    help="Another column: a dotted path into run.json (throughput.steps_per_s) or "
    "measure.<quantity>.<entity>[.<axis>][.final|max|min|mean] (a verification measurement of "
    "sim.h5, e.g. measure.com.jelly.1) or probe.<name>[.x|y|z][.final|max|min|mean] (a probe's column of "
    "probes.csv; every probe is collected unasked). Repeatable; adds to the sweep file's metrics.",
)
def collect(sweep_file: Path, out: str | None, metrics: tuple[str, ...]) -> None:
    """One CSV row per run: index, name, state, every varied value, and the chosen metrics."""
    from simcli.sweep.tasks import collect_rows, write_csv

    ls = _load(sweep_file)
    header, rows, notes = collect_rows(ls, list(ls.sweep.metrics) + list(metrics))
    for n in notes:
        _err(f"simcli sweep: warning: {n}")
    if out == "-":
        write_csv(sys.stdout, header, rows)
        return
    path = Path(out) if out else ls.output_dir / "results.csv"
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with open(path, "w", newline="", encoding="utf-8") as f:
            write_csv(f, header, rows)
    except OSError as e:
        _err(f"cannot write {path}: {e.strerror or e}")
        sys.exit(EXIT_OUTPUT)
    done = sum(1 for r in rows if r[2] == "done")
    _err(f"wrote {path}: {len(rows)} runs ({done} done), {len(header)} columns")
