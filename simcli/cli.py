"""Command line: click commands, nothing else. Human logs go to stderr; stdout carries only
machine-readable output (``schema``, ``--json``)."""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import click

from simcli import __version__
from simcli.errors import EXIT_INVALID_SCENE, EXIT_OK, EXIT_OUTPUT, EXIT_USAGE, SceneError
from simcli.progress import plural

_T0 = time.perf_counter()


def _err(msg: str) -> None:
    click.echo(msg, err=True)


@click.group(context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="simcli")
def cli() -> None:
    """simcli: configuration-driven batch simulator for non-rigid physics."""


@cli.command()
@click.argument("scene", type=click.Path(dir_okay=False, path_type=Path))
@click.option(
    "-o",
    "--out",
    "out",
    type=click.Path(file_okay=False, path_type=Path),
    default=None,
    help="Output folder (overrides output.dir).",
)
@click.option(
    "--set",
    "sets",
    multiple=True,
    metavar="KEY=VALUE",
    help="Override a scene key by dotted path (list items by index); value parsed as YAML. Repeatable.",
)
@click.option(
    "--backend",
    type=click.Choice(["auto", "cpu", "gpu", "cuda", "vulkan", "metal"]),
    default=None,
    help="Compute backend (overrides sim.backend).",
)
@click.option("--resume", is_flag=True, help="Continue from the newest checkpoint in the output folder.")
@click.option(
    "--overwrite",
    is_flag=True,
    help="Replace a previous run in the output folder (its frames, checkpoints, run.json); without it "
    "(or --resume) such a folder is refused with exit 2.",
)
@click.option("--quiet", "-q", is_flag=True, help="No progress output.")
@click.option("--json", "as_json", is_flag=True, help="Print run.json to stdout at the end.")
def run(
    scene: Path,
    out: Path | None,
    sets: tuple[str, ...],
    backend: str | None,
    resume: bool,
    overwrite: bool,
    quiet: bool,
    as_json: bool,
) -> None:
    """Run SCENE and write frames, run.json and checkpoints to the output folder."""
    # first of all: a SIGTERM/SIGINT/SIGUSR1 from now on is recorded and honoured (run.json says
    # interrupted, exit 75), also while the scene loads and Taichi starts
    from simcli.runsignals import RunSignals

    signals = RunSignals().install()
    if resume and overwrite:
        _err(
            "simcli: error: --resume continues the run in the output folder, --overwrite replaces it: "
            "give one"
        )
        sys.exit(EXIT_USAGE)
    from simcli.scene.loader import load_scene

    try:
        loaded = load_scene(scene, sets)
    except SceneError as e:
        for line in e.lines:
            _err(line)
        sys.exit(EXIT_INVALID_SCENE)
    _print_warnings(loaded)
    from simcli.runner import run_scene

    code, info = run_scene(
        loaded,
        out_dir=out,
        backend=backend,
        resume=resume,
        quiet=quiet,
        sets=list(sets),
        t_process=_T0,
        restore_signals=False,
        overwrite=overwrite,
        signals=signals,
    )
    # the run is over: a SIGTERM/SIGUSR1 from now on (Slurm's, during Taichi's clean-up and the
    # interpreter's shut-down, which puts Python-level handlers back to the default) must not turn
    # this exit code into a death by signal. SIG_IGN survives the shut-down.
    import signal

    for name in ("SIGTERM", "SIGUSR1"):
        if hasattr(signal, name):
            signal.signal(getattr(signal, name), signal.SIG_IGN)
    if as_json and info is not None:
        click.echo(json.dumps(info, indent=2))
    sys.exit(code)


@cli.command()
@click.argument("scenes", nargs=-1, required=True, type=click.Path(dir_okay=False, path_type=Path))
@click.option("--set", "sets", multiple=True, metavar="KEY=VALUE", help="Override a scene key (as in run).")
@click.option("--quiet", "-q", is_flag=True, help="Print errors only.")
def validate(scenes: tuple[Path, ...], sets: tuple[str, ...], quiet: bool) -> None:
    """Check scene files without starting any solver; every problem is reported, one line each."""
    from simcli.scene.loader import load_scene

    bad = 0
    for path in scenes:
        if _is_sweep(path):
            bad += _validate_sweep(path, quiet)
            continue
        if path.name.endswith(".case.yaml"):  # a validation case: its own fields, then its scene
            bad += _validate_case(path, quiet)
            continue
        try:
            loaded = load_scene(path, sets)
        except SceneError as e:
            bad += 1
            for line in e.lines:
                _err(line)
            continue
        _print_warnings(loaded)
        if not quiet:
            s = loaded.scene
            _err(
                f"{path}: ok ({plural(len(s.entities), 'entity')}, dim {s.sim.dim}, "
                f"{plural(s.sim.n_steps, 'step')})"
            )
    sys.exit(EXIT_INVALID_SCENE if bad else EXIT_OK)


def _print_warnings(loaded) -> None:
    """What does not stop a run but should be said (docs/LIMITS.md): overlaps, threads clamped."""
    from simcli.scene.limits import scene_warnings

    for line in scene_warnings(loaded):
        _err(line)


def _is_sweep(path: Path) -> bool:
    try:
        from simcli.sweep.model import looks_like_sweep
    except ImportError:
        return False
    return looks_like_sweep(path)


def _validate_case(path: Path, quiet: bool) -> int:
    from simcli.scene.loader import load_scene
    from simcli.verify.cases import load_case

    try:
        case = load_case(path)
        load_scene(case.scene_path)
    except SceneError as e:
        for line in e.lines:
            _err(line)
        return 1
    if not quiet:
        _err(f"{path}: ok (validation case of {case.scene})")
    return 0


def _validate_sweep(path: Path, quiet: bool) -> int:
    """A sweep file given to `validate`: check it and every scene it expands to."""
    from simcli.sweep.model import load_sweep, validate_runs

    try:
        ls = load_sweep(path)
        lines = validate_runs(ls)
    except SceneError as e:
        lines = e.lines
    for line in lines:
        _err(line)
    if not lines and not quiet:
        _err(f"{path}: ok (sweep of {plural(len(ls.runs), 'run')})")
    return 1 if lines else 0


@cli.command()
@click.option(
    "-o",
    "--out",
    "out",
    type=click.Path(file_okay=False, path_type=Path),
    default=None,
    help="Folder to write scene.schema.json (and sweep.schema.json) into; without it the scene "
    "schema goes to stdout.",
)
def schema(out: Path | None) -> None:
    """Write the JSON Schema of scene files (generated from the same models as validation)."""
    from simcli.scene.schema import schema_text
    from simcli.sweep.schema import write_schemas

    if out is None:
        sys.stdout.write(schema_text())
        return
    for p in write_schemas(out):
        _err(f"wrote {p}")


@cli.command()
@click.argument("out", type=click.Path(path_type=Path))
def repair(out: Path) -> None:
    """Make OUT/sim.h5 of a killed run openable by every HDF5 tool (ParaView, h5py without SWMR).

    A run killed with SIGKILL leaves every completed frame in sim.h5, but HDF5 keeps its
    "open for writing" flag set; SWMR readers read it as it is, other tools refuse it until
    the flag is cleared (what `h5clear -s` does). `simcli run --resume` clears it too. A file cut short
    by a failed write (file-size limit, disk full) is made openable again. Every frame is read back
    before it is counted; anything that is not a repairable sim.h5 is exit 74 saying what was found."""
    from simcli.errors import OutputError
    from simcli.io.repair import repair as _repair

    try:
        msg = _repair(out)
    except OutputError as e:
        _err(f"simcli: error: {e}")
        sys.exit(e.exit_code)
    except Exception as e:  # noqa: BLE001 - whatever else the file system or HDF5 says: no traceback
        _err(f"simcli: error: {out / 'sim.h5'}: cannot repair it ({type(e).__name__}: {e})")
        sys.exit(EXIT_OUTPUT)
    _err(msg)


@cli.command()
@click.option("--json", "as_json", is_flag=True, help="Machine-readable output on stdout.")
def info(as_json: bool) -> None:
    """Versions, backends and devices found (GPU backends are probed in a child process)."""
    from simcli.backend import machine_facts

    facts = machine_facts()
    if as_json:
        click.echo(json.dumps(facts, indent=2))
        return
    for k, v in facts.items():
        if isinstance(v, dict):
            v = ", ".join(
                f"{name}: {'yes' if x is True else 'no' if x is False else x}" for name, x in v.items()
            )
        elif isinstance(v, list):
            v = "; ".join(v) if v else "none found"
        _err(f"{k}: {v}")


@cli.command()
@click.argument("out", type=click.Path(exists=True, file_okay=False, path_type=Path))
@click.option(
    "-o",
    "--output",
    "dest",
    type=click.Path(dir_okay=False, path_type=Path),
    default=None,
    help="picture.png, or movie.mp4 / movie.gif for every frame (default: OUT/render.png).",
)
@click.option(
    "--frame", type=int, default=None, help="Frame of a picture (default: the last; -1 counts from the end)."
)
@click.option(
    "--every", type=click.IntRange(min=1), default=1, show_default=True, help="Movies: use every N-th frame."
)
@click.option(
    "--fps", type=click.IntRange(min=1), default=20, show_default=True, help="Movies: frames per second."
)
@click.option(
    "--color",
    type=click.Choice(["auto", "speed", "entity", "height"]),
    default="auto",
    show_default=True,
    help="Particles' colour; auto: speed (height once at rest), or entity when there are several.",
)
@click.option(
    "--width", type=click.IntRange(min=160), default=800, show_default=True, help="Width in pixels."
)
def render(
    out: Path, dest: Path | None, frame: int | None, every: int, fps: int, color: str, width: int
) -> None:
    """A quick-look picture (.png) or movie (.mp4, .gif) of the run in OUT, drawn off-screen from OUT/sim.h5
    and the colliders of OUT/scene.yaml (needs matplotlib; .mp4 needs imageio-ffmpeg: simcli[render])."""
    from simcli.render import RenderError, render_movie, render_picture

    dest = dest if dest is not None else out / "render.png"
    try:
        if dest.suffix.lower() in (".mp4", ".gif"):
            p, n = render_movie(out, dest, every=every, fps=fps, color=color, width=width)
            _err(f"wrote {p} ({n} frames)")
        elif dest.suffix.lower() == ".png":
            _err(f"wrote {render_picture(out, dest, frame=frame, color=color, width=width)}")
        else:
            raise RenderError(f"{dest}: give a .png (picture), .mp4 or .gif (movie)")
    except RenderError as e:
        _err(f"simcli render: {e}")
        sys.exit(EXIT_USAGE)
    except OSError as e:  # the picture or movie could not be written
        _err(f"simcli render: {dest}: {e.strerror or e}")
        sys.exit(EXIT_OUTPUT)


@cli.command()
@click.argument("out", type=click.Path(exists=True, file_okay=False, path_type=Path))
@click.option(
    "-o",
    "--output",
    "dest",
    type=click.Path(dir_okay=False, path_type=Path),
    default=None,
    help="Where to write the plot (default: OUT/plot.png).",
)
def plot(out: Path, dest: Path | None) -> None:
    """Time series of the run in OUT: speeds, kinetic energy, height per frame (sim.h5), probes.csv,
    and run.json's substeps, throughput and wall times."""
    from simcli.render import RenderError, plot_run

    try:
        _err(f"wrote {plot_run(out, dest if dest is not None else out / 'plot.png')}")
    except RenderError as e:
        _err(f"simcli plot: {e}")
        sys.exit(EXIT_USAGE)
    except OSError as e:
        _err(f"simcli plot: {e}")
        sys.exit(EXIT_OUTPUT)


def _register_optional() -> None:
    """Sub-command groups that live in their own packages."""
    for mod, attr in (("simcli.verify.cli", "verify"), ("simcli.sweep.cli", "sweep")):
        try:
            m = __import__(mod, fromlist=[attr])
        except ImportError:
            continue
        cli.add_command(getattr(m, attr))


_register_optional()


def main() -> None:
    # click's standalone mode maps usage errors to exit 2, as the contract says
    cli(prog_name="simcli")
