"""The time loop: build, substeps, per-frame guard, output, checkpoints, signals, progress
and run.json. Knows nothing of any solver's physics."""

from __future__ import annotations

import json
import math
import os
import platform
import resource
import sys
import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml

from simcli import __version__
from simcli.errors import (
    EXIT_INTERRUPTED,
    EXIT_INVALID_SCENE,
    EXIT_OK,
    EXIT_OTHER,
    EXIT_USAGE,
    NumericalError,
    OutputError,
    SceneError,
    SimcliError,
)
from simcli.geometry.mesh import MeshError
from simcli.progress import Progress, plural
from simcli.runsignals import RunSignals
from simcli.scene.loader import LoadedScene
from simcli.scene.models import resolved_scene_dict
from simcli.substeps import SubstepPolicy


def _atomic_write(path: Path, text: str) -> None:
    tmp = path.with_name(path.name + ".tmp")
    try:
        with open(tmp, "w", encoding="utf-8") as f:
            f.write(text)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except OSError as e:
        raise OutputError(f"cannot write {path}: {e.strerror or e}") from None


def _peak_memory_mb() -> float:
    # ru_maxrss is in KiB on Linux
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def _versions(ti_info: dict | None) -> dict:
    import h5py
    import meshio
    import pydantic

    v = {
        "simcli": __version__,
        "python": platform.python_version(),
        "numpy": np.__version__,
        "h5py": h5py.__version__,
        "meshio": meshio.__version__,
        "pydantic": pydantic.__version__,
    }
    if ti_info:
        t = ti_info.get("taichi")
        v["taichi"] = ".".join(map(str, t)) if isinstance(t, (tuple, list)) else t
    return v


@dataclass
class _Loop:
    """What the time loop carries from step to step (a checkpoint saves it; a resumed run starts from it)."""

    step: int = 0
    frame: int = 0
    substeps_now: int | None = None  # substeps of the current step (None: substeps: auto, not chosen yet)
    sub_hist: list[int] = field(default_factory=list)  # substeps of every step (the checkpoint keeps 10,000)
    substeps_done: int = 0  # substeps taken by this process
    stable: float = math.inf  # the stable substep at the start (frame 0's check, the fixed-substep warning)
    stepping0: float = 0.0  # timings["stepping_s"] when this process's loop started
    first: bool = True  # the first substep (its time is the kernels' compile time)
    last_sub: float | None = (
        None  # the last substep taken [s] (the policy's horizon with auto_check: substep)
    )


class _StartupInterrupted(SimcliError):
    exit_code = EXIT_INTERRUPTED


# SIGTERM, SIGINT, SIGUSR1: finish the current step, checkpoint, exit 75 (installed by `simcli run` first)
_Signals = RunSignals


def run_scene(
    loaded: LoadedScene,
    out_dir: Path | None = None,
    backend: str | None = None,
    resume: bool = False,
    quiet: bool = False,
    sets: list[str] | None = None,
    t_process: float | None = None,
    solver_factory=None,
    restore_signals: bool = True,
    overwrite: bool = False,
    signals: RunSignals | None = None,
) -> tuple[int, dict | None]:
    """Run a validated scene. Returns (exit code, run.json dict).

    restore_signals: put the caller's SIGTERM/SIGINT/SIGUSR1 handlers back when the run ends. The
    command line passes False: a signal that arrives after the run has finished, while the process
    shuts down (Taichi's clean-up takes a moment), must not kill it with the default action and
    turn a finished run's exit 0 into 143.
    overwrite: replace a previous run in the output folder (without it, or resume, such a folder is refused).
    signals: handlers the caller installed before loading the scene (a signal during start-up is honoured)."""
    runner = Runner(loaded, out_dir, backend, resume, quiet, sets or [], t_process)
    runner.restore_signals = restore_signals
    runner.overwrite = overwrite
    if signals is not None:
        runner.signals = signals
    return runner.run(solver_factory)


class Runner:
    def __init__(self, loaded, out_dir, backend, resume, quiet, sets, t_process):
        self._load_sums: dict = {}  # named collider -> [force x time, torque x time, time] (run.json means)
        self.loaded = loaded
        self.scene = loaded.scene
        self.name = loaded.name
        res = resolved_scene_dict(self.scene, self.name)
        self.out = Path(out_dir) if out_dir is not None else Path(res["output"]["dir"])
        res["output"]["dir"] = str(self.out)
        self.resolved = res
        self.backend = backend or self.scene.sim.backend
        self.resume = resume
        self.quiet = quiet
        self.sets = sets
        self.t_process = t_process if t_process is not None else time.perf_counter()
        self.warnings: list[str] = []
        self.info: dict = {}
        # set while the run builds and steps (None/empty until then: the closing summary reads them
        # whether or not the run got that far)
        self._solvers: list = []
        self._rigid = None  # simcli.rigid.run.RigidRun, with rigid_bodies
        self._sources = None  # simcli.solvers.sources.SourceRun, with emitters or sinks
        self._resume_from: str | None = None
        self._dt_range = (math.inf, 0.0)
        self._step0 = 0
        self._last_loads: dict = {}
        self._coupler = None  # simcli.coupling.Coupler, when two coupled families meet
        self._probes = None  # simcli.probes.recorder, with probes
        self._cvtk = None  # named and moving colliders' surfaces per frame (vtk/<name>.pvd)
        self._progress = None
        self._n_particles = 0
        self._n_fixed = 0
        self._particle_substeps = 0.0
        self._entity_fields: dict = {}
        self._t_loop = 0.0
        self._load_step = 0
        self._policy = SubstepPolicy.of(self.scene)  # every substep size (simcli/substeps.py)
        self.timings = {
            "startup_s": 0.0,
            "setup_s": 0.0,
            "taichi_init_s": 0.0,
            "build_s": 0.0,
            "compile_s": 0.0,
            "stepping_s": 0.0,
            "output_s": 0.0,
            "checkpoint_s": 0.0,
        }
        self.signals = _Signals()
        self.restore_signals = True  # see run_scene
        self.overwrite = False  # see run_scene
        self._lock = None  # the output folder's lock (simcli.io.outdir), held for the whole run
        self._owns_out = False  # run.json is written only once the folder is this run's (lock + policy)
        self._sink = None

    # ------------------------------------------------------------------ helpers
    def log(self, msg: str) -> None:
        if not self.quiet:
            print(f"simcli: {msg}", file=sys.stderr, flush=True)

    def warn(self, msg: str) -> None:
        self.warnings.append(msg)
        print(f"simcli: warning: {msg}", file=sys.stderr, flush=True)

    def write_run_json(self, status: str, exit_code: int | None) -> dict:
        self.info.update(
            status=status,
            exit_code=exit_code,
            warnings=self.warnings,
            timings={k: round(v, 4) for k, v in self.timings.items()},
            peak_memory_mb=round(_peak_memory_mb(), 1),
            updated=time.strftime("%Y-%m-%dT%H:%M:%S%z"),
        )
        if self._owns_out and self.out.is_dir():  # never another run's run.json
            try:
                _atomic_write(self.out / "run.json", json.dumps(self.info, indent=2) + "\n")
            except OutputError as e:
                print(f"simcli: error: {e}", file=sys.stderr)
        return self.info

    # ------------------------------------------------------------------ main
    def run(self, solver_factory=None) -> tuple[int, dict | None]:
        self.signals.install()
        try:
            try:
                return self._run(solver_factory)
            except BaseException:
                # sim.h5 closed now (or abandoned if it cannot be), not at interpreter exit
                self._abort_sink()
                raise
        except _StartupInterrupted as e:
            print(f"simcli: {e}", file=sys.stderr, flush=True)
            self.info["error"] = str(e)
            return EXIT_INTERRUPTED, self.write_run_json("interrupted", EXIT_INTERRUPTED)
        except NumericalError as e:
            print(f"simcli: error: {e}", file=sys.stderr, flush=True)
            self.info["error"] = str(e)
            return e.exit_code, self.write_run_json("failed", e.exit_code)
        except OutputError as e:
            print(f"simcli: error: {e}", file=sys.stderr, flush=True)
            self.info["error"] = str(e)
            return e.exit_code, self.write_run_json("failed", e.exit_code)
        except SimcliError as e:
            print(f"simcli: error: {e}", file=sys.stderr, flush=True)
            self.info["error"] = str(e)
            return e.exit_code, self.write_run_json("failed", e.exit_code)
        except MeshError as e:  # a mesh that cannot be meshed or sampled (found at build): the input's fault
            print(f"simcli: error: {e}", file=sys.stderr, flush=True)
            self.info["error"] = str(e)
            return EXIT_INVALID_SCENE, self.write_run_json("failed", EXIT_INVALID_SCENE)
        except KeyboardInterrupt:
            print("simcli: interrupted twice; stopped without a checkpoint", file=sys.stderr)
            return 130, self.write_run_json("killed", 130)
        except Exception as e:  # an internal error: short message, details in run.json
            tb = traceback.format_exc()
            print(
                f"simcli: internal error: {type(e).__name__}: {e} (details in {self.out / 'run.json'})",
                file=sys.stderr,
                flush=True,
            )
            self.info["error"] = f"{type(e).__name__}: {e}"
            self.info["traceback"] = tb
            return EXIT_OTHER, self.write_run_json("failed", EXIT_OTHER)
        finally:
            if self.restore_signals:
                self.signals.restore()
            if self._lock is not None:
                self._lock.release()
            if self._rigid is not None:
                self._rigid.close()

    def _abort_sink(self) -> None:
        sink, self._sink = self._sink, None
        if sink is not None:
            sink.abort()

    def _startup_point(self, phase: str) -> None:
        """A signal received during start-up (recorded by the handlers `simcli run` installs first) stops
        the run here, before the next phase: there is no checkpoint of this run to resume from yet."""
        sig = self.signals.received
        if sig is None:
            return
        if self.resume and self._resume_from:
            rest = f"the checkpoint it started from ({self._resume_from}) is untouched: --resume again"
        else:
            rest = "nothing to resume yet: run the same command again to start afresh"
        raise _StartupInterrupted(
            f"{sig} received during start-up ({phase}): stopped before the first step; {rest}"
        )

    def _prepare_out(self) -> None:
        """Create the output folder, take its lock (one run per folder at a time) and apply the
        previous-run policy: a folder holding another run is written only with --resume or --overwrite."""
        from simcli.io.outdir import OutputLock, refuse_previous_run, remove_previous_run

        try:
            self.out.mkdir(parents=True, exist_ok=True)
            probe = self.out / ".write_test"
            probe.write_text("ok")
            probe.unlink()
        except OSError as e:
            raise OutputError(
                f"cannot write to output folder {self.out}: {e.strerror or e}; choose another with "
                f"-o or output.dir"
            ) from None
        lock = OutputLock(self.out).acquire()
        self._lock = lock
        self._owns_out = False
        if not self.resume:
            if self.overwrite:
                gone = remove_previous_run(self.out)
                if gone:
                    self.log(f"--overwrite: removed the previous run's {', '.join(gone)} from {self.out}")
            else:
                refuse_previous_run(self.out)
            self._owns_out = True

    def _run(self, solver_factory) -> tuple[int, dict]:
        """A run's phases, in order (docs/ARCHITECTURE.md, "A run"): open the output folder (and the
        checkpoint to resume from), sample the bodies, start Taichi, build the solvers, open the output and
        write frame 0, step to the end (frames, checkpoints, signals), close with the summary."""
        opened = self._open_run()
        if opened is None:  # a refused --resume (said why on stderr)
            return EXIT_USAGE, None
        ckpt, scene_text = opened
        self.write_run_json("starting", None)
        self._startup_point("loading the scene")
        bodies = self._sample_bodies()
        self._startup_point("sampling the bodies")
        self._start_taichi()
        self._startup_point("starting Taichi")
        solvers = self._build_solvers(solver_factory, bodies)
        self._startup_point("building the solvers")
        loop = self._open_output(solvers, ckpt, scene_text)
        self.timings["startup_s"] = time.perf_counter() - self.t_process
        self._warn_fixed_substep(loop)
        interrupted = self._step_loop(solvers, loop)
        if interrupted is not None:
            return interrupted
        return self._close_run(loop)

    # ------------------------------------------------------------------ phases of a run
    def _open_run(self):
        """The output folder taken (lock, previous-run policy), the checkpoint to resume from read, the disk
        space checked, scene.yaml written and run.json's fixed facts set. Returns (checkpoint or None,
        the resolved scene's text), or None when --resume finds nothing to resume."""
        import warnings

        from simcli.io.checkpoint import CheckpointWarning, load_latest_checkpoint

        scene = self.scene
        ckpt = None
        if self.resume and not self.out.is_dir():
            print(
                f"simcli: error: --resume: no checkpoint in {self.out / 'checkpoints'} (no such folder); run "
                "without --resume",
                file=sys.stderr,
            )
            return None
        self._prepare_out()
        if self.resume:
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always", CheckpointWarning)
                found = load_latest_checkpoint(self.out / "checkpoints") if self.out.is_dir() else None
            for w in caught:
                self.warnings.append(str(w.message))
                print(f"simcli: warning: {w.message}", file=sys.stderr)
            if found is None:
                self._owns_out = False
                print(
                    f"simcli: error: --resume: no checkpoint in {self.out / 'checkpoints'}; run without "
                    "--resume",
                    file=sys.stderr,
                )
                return None
            path, state, meta = found
            meta = dict(meta, path=str(path))
            ckpt = (state, meta)
            self._resume_from = str(path)
            self._check_resume_scene(meta, path)
        self._owns_out = True  # (a refused --resume leaves the previous run's run.json as it was)
        from simcli.scene.resources import disk_problem  # the output's size against the folder's free space

        found = disk_problem(scene, self.loaded.scene_dir, self.out, int(ckpt[1]["frame"]) + 1 if ckpt else 0)
        if found and found[0]:
            raise SceneError(
                [f"{self.loaded.located.where(('output', 'every'), prefer_key=True)}: {found[1]}"]
            )
        if found:
            self.warn(found[1])
        scene_text = yaml.safe_dump(self.resolved, sort_keys=False)
        _atomic_write(self.out / "scene.yaml", "# resolved scene: every default filled in\n" + scene_text)

        self.info = {
            "simcli_version": __version__,
            "scene": str(self.loaded.path),
            "name": self.name,
            "out": str(self.out),
            "overrides": self.sets,
            "resumed": bool(self.resume),
            "command": " ".join(sys.argv),
            "pid": os.getpid(),
            "host": platform.node(),
            "lock": self._lock.info,
        }
        return ckpt, scene_text

    def _sample_bodies(self) -> list:
        """Every entity's (and emitter's) particles, in numpy: no Taichi yet."""
        scene = self.scene
        t0 = time.perf_counter()
        from simcli.geometry.sampling import family_spacing, sample_scene

        bodies = sample_scene(scene, self.loaded.scene_dir, scene.sim.seed)
        if scene.emitters:  # each emitter's reserved slots (simcli/solvers/sources.py)
            from simcli.scene.sources import emitter_bodies

            bodies += emitter_bodies(scene)
        for b in bodies:
            for w in b.warnings:
                self.warn(f"{b.name}: {w}")
            if len(b.x) == 0:
                fam = b.entity.family
                opt = f"solvers.{fam.lower()}.particle_size"
                raise SimcliError(
                    f"entity '{b.name}' got no particles: its morph is thinner than the "
                    f"{fam} particle spacing {opt} = {family_spacing(scene, fam):g} m; lower it"
                )
        self.timings["setup_s"] = time.perf_counter() - t0
        return bodies

    def _start_taichi(self) -> None:
        from simcli.backend import init_taichi

        sim = self.scene.sim
        ti_info = init_taichi(self.backend, sim.precision, sim.threads, quiet=self.quiet)
        self.signals.install()  # Taichi installs handlers of its own in ti.init: ours must win
        self.timings["taichi_init_s"] = ti_info["import_s"] + ti_info["init_s"]
        self.info.update(
            backend=ti_info["arch"],
            requested_backend=self.backend,
            threads=ti_info["threads"],
            precision=sim.precision,
            kernel_cache=ti_info["cache"],
            versions=_versions(ti_info),
        )

    def _build_solvers(self, solver_factory, bodies) -> list:
        """One solver per family, the rigid bodies, the coupling phase, and the emitters and sinks: fields
        allocated and the initial state uploaded (kernels compile at the first substep)."""
        scene = self.scene
        t0 = time.perf_counter()
        from simcli.rigid.run import rigid_run  # free rigid bodies (None without rigid_bodies)

        self._rigid = rigid_run(scene, self.loaded.scene_dir)
        if solver_factory is None:
            from simcli.solvers import make_solvers

            solvers = make_solvers(scene, bodies, scene_dir=self.loaded.scene_dir)
        else:
            solvers = solver_factory(scene, bodies)
        self._solvers = solvers
        from simcli.coupling import make_coupler  # None unless two coupled families meet (docs/COUPLING.md)

        coupler = self._coupler = make_coupler(scene, solvers, self.warn)
        if coupler is not None:
            coupler.prepare()
        for s in solvers:
            s.build()
        if coupler is not None:
            coupler.build()
            self.info["coupling"] = coupler.names
            self.info["coupling_methods"] = coupler.methods
        for s in solvers:  # what a solver changed of the scene as given (e.g. SPH particles in a collider)
            for w in s.warnings:
                self.warn(w)
        self.timings["build_s"] = time.perf_counter() - t0
        from simcli.solvers.sources import make_source_run  # emitters and sinks (None without any)

        self._sources = make_source_run(scene, solvers)
        self.info["counts"] = {s.family: s.counts() for s in solvers}
        self._n_particles = sum(int(s.counts().get("particles", 0)) for s in solvers)
        self.info["particles"] = self._n_particles
        # emitters and sinks: the live count changes; run.json's counts and rates follow it (_finish_stats)
        self._n_fixed = sum(int(s.counts().get("particles", 0)) for s in solvers if s.active_set is None)
        self._particle_substeps = 0.0
        self.info["families"] = [s.family for s in solvers]
        return solvers

    def _open_output(self, solvers, ckpt, scene_text) -> _Loop:
        """The frame sink opened (sim.h5, XDMF, VTK; a resumed run appends after its checkpoint's frame), the
        solvers' state set from the checkpoint, the probes opened, and frame 0 checked and written (a fresh
        run). Returns the time loop's state."""
        from simcli.io.frames import FrameSink

        scene, sim = self.scene, self.scene.sim
        entity_meta = self._entity_meta(solvers)
        sink = self._sink = FrameSink(self.out, list(scene.output.formats))
        loop = _Loop(substeps_now=sim.substeps if sim.substeps != "auto" else None)
        if ckpt is not None:
            state, meta = ckpt
            self._check_resume_meta(meta)
            for s in solvers:
                try:
                    s.set_state(
                        {k.split("/", 1)[1]: v for k, v in state.items() if k.startswith(s.family + "/")}
                    )
                except (KeyError, ValueError) as e:  # a checkpoint of another scene: say so, not a traceback
                    what = f"missing {e}" if isinstance(e, KeyError) else str(e)
                    msg = (
                        f"--resume: the checkpoint in {self.out / 'checkpoints'} does not fit this scene "
                        f"({s.family}: {what}). Resume with the scene that wrote it, or start afresh "
                        "(another -o, or without --resume after removing the folder)"
                    )
                    raise SceneError([msg]) from None
            if self._rigid is not None:
                self._rigid.set_state(state)
            loop.step = int(meta["step"])
            loop.frame = int(meta["frame"])
            loop.substeps_now = meta.get("substeps_now", loop.substeps_now)
            loop.sub_hist = list(meta.get("substeps_hist", []))
            loop.last_sub = meta.get("last_substep")
            self.timings.update(
                {k: float(v) for k, v in meta.get("timings", {}).items() if k == "stepping_s"}
            )
            self.log(
                f"resuming from {meta['path'] if 'path' in meta else 'checkpoint'} at step {loop.step} "
                f"(t = {loop.step * sim.dt:.6g} s)"
            )
        t0 = time.perf_counter()
        attrs = {"name": self.name, "dt": sim.dt, "dim": sim.dim}
        from simcli.probes.recorder import make_recorder  # probes: (None without any)

        probes = self._probes = make_recorder(scene, solvers, self.out, self.timings)
        resume_frame = (loop.frame + 1) if ckpt is not None else None
        sink.open(
            entity_meta,
            scene_text,
            attrs,
            resume_frame=resume_frame,
            **(probes.open(loop.step if ckpt is not None else None) if probes else {}),
            colliders=self._collider_meta(),
            frame_series=self._frame_series(),
        )
        self._cvtk = self._collider_vtk(resume_frame)
        if self._rigid is not None:
            self._rigid.open(sink, resume_frame)
        # the stable substep for the frame-0 check and the fixed-substep warning (not asked again on a resumed
        # auto run, whose check counts then match an uninterrupted run's)
        h = self._policy.horizon(loop.last_sub)
        loop.stable = (
            self._stable_dt(solvers, sim.dt, h) if ckpt is None or sim.substeps != "auto" else sim.dt
        )
        if ckpt is None:
            # the first substep: the fixed one, or with substeps: auto the stable one (not sim.dt: a long step
            # with auto_check: substep would make any initial speed look like a runaway)
            self._check_frame(
                solvers, 0, sim.dt / loop.substeps_now if loop.substeps_now else min(sim.dt, loop.stable)
            )
            if self._rigid is not None:
                self._rigid.write_frame(0)
            sink.write_frame(
                0,
                0,
                0.0,
                self._frame_data(),
                colliders=self._collider_loads(solvers, 0.0),
                **self._frame_vals(),
            )
            if self._cvtk is not None:
                self._cvtk.write_frame(0, 0.0)
            if probes:
                probes.sample(0, sink)
        self.timings["output_s"] += time.perf_counter() - t0
        # smallest and largest substep taken [s] (over the whole run: a resumed run continues the
        # checkpoint's)
        saved = ckpt[1].get("dt_range") if ckpt is not None else None
        self._dt_range = [float(x) for x in saved] if saved else [math.inf, 0.0]
        return loop

    def _warn_fixed_substep(self, loop: _Loop) -> None:
        sim = self.scene.sim
        if sim.substeps != "auto" and sim.dt / loop.substeps_now > loop.stable:
            need = int(math.ceil(sim.dt / loop.stable))
            self.warn(
                f"substep {sim.dt / loop.substeps_now:.3g} s exceeds the stability limit {loop.stable:.3g} s "
                f"(CFL / elastic wave speed); suggest sim.substeps >= {need} or sim.substeps: auto"
            )

    def _step_loop(self, solvers, loop: _Loop):
        """Steps to sim.n_steps (or a solver's steady state): each step's substeps, then the frame, the
        checkpoint and the progress line when due. Returns (exit code, run.json) when a signal stopped the
        run after its checkpoint, None at the end."""
        scene, sim = self.scene, self.scene.sim
        every, n_steps = scene.output.every, sim.n_steps
        sink, probes = self._sink, self._probes
        progress = self._progress = Progress(
            total_steps=n_steps, start_step=loop.step, dt=sim.dt, quiet=self.quiet, warmup_steps=every
        )
        self.write_run_json("running", None)
        ckpt_every = scene.checkpoint.every
        last_json = time.perf_counter()
        self._t_loop = time.perf_counter()
        loop.stepping0 = self.timings["stepping_s"]
        self._step0 = loop.step  # steps of this process are counted from here (a resumed run: its checkpoint)
        self._load_step = loop.step  # collider loads are summed from here to the next frame
        while loop.step < n_steps:
            sub_dt = self._advance_step(solvers, loop)
            loop.step += 1
            step = loop.step
            if "time_to_first_step_s" not in self.timings:
                self.timings["time_to_first_step_s"] = time.perf_counter() - self.t_process
            if probes:
                probes.sample(step, sink)
            if step % every == 0 or step == n_steps:
                if self._write_frame(solvers, loop, sub_dt):
                    break  # a solver's steady-state criterion met
            interrupted = self.signals.received is not None
            if interrupted or (ckpt_every and step % ckpt_every == 0 and step < n_steps):
                p = self._write_checkpoint(solvers, loop)
                if interrupted:
                    if probes:
                        probes.flush(sink)  # the samples since the last frame, up to the checkpoint's step
                    self._sink = None
                    sink.close()
                    self._finish_stats(
                        step, self._n_particles, loop.sub_hist, loop.stepping0, loop.substeps_done
                    )
                    print(
                        f"simcli: {self.signals.received} received: checkpoint written at step {step} "
                        f"({p}); resume with --resume",
                        file=sys.stderr,
                        flush=True,
                    )
                    return EXIT_INTERRUPTED, self.write_run_json("interrupted", EXIT_INTERRUPTED)
            progress.update(step, self.timings["stepping_s"] - loop.stepping0)
            if time.perf_counter() - last_json > 10.0:
                self._finish_stats(step, self._n_particles, loop.sub_hist, loop.stepping0, loop.substeps_done)
                self.write_run_json("running", None)
                last_json = time.perf_counter()
        return None

    def _advance_step(self, solvers, loop: _Loop) -> float:
        """One step of sim.dt in substeps (the substep policy: fixed, auto per frame, or auto per substep),
        each: the emitters' entries, every solver's substep (or the coupling phase), the rigid bodies. Returns
        the last substep [s]."""
        sim, policy = self.scene.sim, self._policy
        sources, coupler, dt_range = self._sources, self._coupler, self._dt_range
        step = loop.step

        def stable(fallback: float) -> float:  # (the horizon: how long the policy will keep the answer)
            return self._stable_dt(solvers, fallback, policy.horizon(loop.last_sub))

        loop.substeps_now = policy.step_substeps(step, loop.substeps_now, stable)
        ts = time.perf_counter()
        k, done_t, sub_dt = 0, 0.0, sim.dt
        while True:
            sub_dt, n_left = policy.next_substep(k, done_t, loop.substeps_now, sub_dt, stable)
            if sources:  # the layers due by this substep's start enter (no host sync)
                sources.before_substep(step * sim.dt + done_t)
            if coupler is None:
                for s in solvers:
                    if s.splits_substep():  # a family under its own limit inside the common substep
                        n = policy.split(sub_dt, s.stable_dt())
                        for _ in range(n):
                            s.substep(sub_dt / n)
                    else:
                        s.substep(sub_dt)
            else:  # pre_couple -> coupling phase -> post_couple
                coupler.substep(sub_dt)
            if self._rigid is not None:  # the bodies take the substep's loads and move
                self._rigid.step(solvers, sub_dt)
            k += 1
            done_t += sub_dt
            loop.last_sub = sub_dt
            dt_range[0], dt_range[1] = min(dt_range[0], sub_dt), max(dt_range[1], sub_dt)
            if loop.first:
                for s in solvers:
                    s.sync()
                self.timings["compile_s"] = time.perf_counter() - ts
                loop.first = False
                ts = time.perf_counter()
            if n_left == 1:
                break
        loop.substeps_now = k
        for s in solvers:
            s.sync()
        if sources:  # sinks remove what entered them (one small read)
            for w in sources.after_step():
                self.warn(w)
        self.timings["stepping_s"] += time.perf_counter() - ts
        loop.substeps_done += loop.substeps_now
        self._particle_substeps += loop.substeps_now * self._live_particles(solvers, self._n_particles)
        loop.sub_hist.append(loop.substeps_now)
        return sub_dt

    def _write_frame(self, solvers, loop: _Loop, sub_dt: float) -> bool:
        """The frame check at a frame's step (and at the last step), and the frame itself when due: sim.h5,
        VTK, collider loads, rigid bodies. True when a solver says the state has stopped changing."""
        sim = self.scene.sim
        step, sink = loop.step, self._sink
        t0 = time.perf_counter()
        self._check_frame(solvers, loop.frame + 1, sub_dt, step=step)
        if step % self.scene.output.every == 0:
            loop.frame += 1
            frame = loop.frame
            loads = self._collider_loads(solvers, (step - self._load_step) * sim.dt)
            self._load_step = step
            if self._rigid is not None:
                self._rigid.write_frame(frame)
            sink.write_frame(
                frame, step, step * sim.dt, self._frame_data(), colliders=loads, **self._frame_vals()
            )
            if self._cvtk is not None:
                self._cvtk.write_frame(frame, step * sim.dt)
            stop = next((r for r in (s.steady() for s in solvers) if r), None)
            if stop:  # a solver's steady-state criterion met (e.g. solvers.sf.steady_tolerance)
                self.info["stopped_steady"] = {"step": step, "time": step * sim.dt, **stop}
                self.timings["output_s"] += time.perf_counter() - t0
                return True
        self.timings["output_s"] += time.perf_counter() - t0
        return False

    def _write_checkpoint(self, solvers, loop: _Loop):
        """Every solver's and rigid body's state, with what the loop needs to go on bit for bit."""
        from simcli.io.checkpoint import write_checkpoint

        sim, step = self.scene.sim, loop.step
        t0 = time.perf_counter()
        meta = {
            "step": step,
            "frame": loop.frame,
            "time": step * sim.dt,
            "substeps_now": loop.substeps_now,
            "dt_range": list(self._dt_range),
            "substeps_hist": loop.sub_hist[-10000:],
            "last_substep": loop.last_sub,
            "scene_name": self.name,
            "timings": {"stepping_s": self.timings["stepping_s"]},
            "particles": self._n_particles,
            "scene": self.resolved,  # what --resume compares the scene with (simcli.resume_check)
        }
        state = {}
        for s in solvers:
            state.update({f"{s.family}/{k}": v for k, v in s.get_state().items()})
        if self._rigid is not None:
            state.update(self._rigid.get_state())
        p = write_checkpoint(self.out / "checkpoints", step, state, meta, self.scene.checkpoint.keep)
        self.info["checkpoint"] = str(p)
        self.timings["checkpoint_s"] += time.perf_counter() - t0
        return p

    def _close_run(self, loop: _Loop) -> tuple[int, dict]:
        """sim.h5 closed, run.json written as done, and the closing lines (throughput, bodies, loads)."""
        sink, self._sink = self._sink, None
        sink.close()
        self._progress.close()
        step, frame = loop.step, loop.frame
        self._finish_stats(step, self._n_particles, loop.sub_hist, loop.stepping0, loop.substeps_done)
        self.info["loop_wall_s"] = round(time.perf_counter() - self._t_loop, 4)
        info = self.write_run_json("done", EXIT_OK)
        tp = info["throughput"]
        rates = [
            f"{tp[k]:.3g} {what}-substeps/s"
            for k, what in (
                ("particle_substeps_per_s", "particle"),
                ("vertex_substeps_per_s", "vertex"),
                ("cell_substeps_per_s", "cell"),
            )
            if tp.get(k)
        ]
        if not rates:
            rates = [f"{tp.get('steps_per_s') or 0:.3g} steps/s"]
        live = ""
        if "particles_capacity" in info:  # emitters, sinks: the rate is over the live particles
            live = f"; {info['particles']:,} particles live of {info['particles_capacity']:,} reserved"
        self.log(
            f"done: {plural(step, 'step')}, {plural(frame + 1, 'frame')} in {self.out} ({', '.join(rates)})"
            + live
        )
        for line in self._rigid.log_lines() if self._rigid is not None else []:
            self.log(line)
        for name, d in info.get("colliders", {}).items():

            def fmt(v):
                return "(" + ", ".join(f"{x:.4g}" for x in v) + ")"

            self.log(
                f"collider '{name}': force {fmt(d['force_N'])} N, torque {fmt(d['torque_Nm'])} N m "
                f"at the last "
                f"frame; mean over the run {fmt(d['mean_force_N'])} N, {fmt(d['mean_torque_Nm'])} N m"
            )
        return EXIT_OK, info

    # ------------------------------------------------------------------ pieces
    def _live_particles(self, solvers, n_particles: int) -> int:
        """Particles in the simulation now (host, no sync): the build's count without emitters and sinks."""
        if self._sources is None:
            return n_particles
        return self._n_fixed + sum(s.active_set.live_particles() for s in solvers if s.active_set is not None)

    def _particle_counts(self) -> dict:
        """run.json particle_counts: per particle entity whose count varies, its capacity (rows reserved in
        sim.h5) and its live particles now."""
        out = {}
        for name, (s, _fields) in self._entity_fields.items():
            if s.active_set is None or s.entity_kind(name) != "particles":
                continue
            cap = s.entity_size(name) - (1 if any(em.name == name for em in self.scene.emitters) else 0)
            live = len(s.entity_arrays(name, ["position"])["position"])
            out[name] = {"capacity": int(cap), "live": int(live)}
        return out

    def _frame_series(self) -> dict[str, str] | None:
        """sim.h5 per-frame scalars: emitted and removed mass, and the live count of each entity whose count
        varies (emitters, sinks)."""
        if self._sources is None:
            return None
        unit = "kg" if self.scene.sim.dim == 3 else "kg/m"
        out = {k: unit for k in self._sources.frame_values()}
        return out

    def _frame_vals(self) -> dict:
        if self._sources is None:
            return {}
        return {"values": self._sources.frame_values()}

    def _finish_stats(self, step, n_particles, sub_hist, stepping0, substeps_done):
        sim = self.scene.sim
        if self._sources is not None:
            self.info["sources"] = self._sources.info()
            # live counts now, not the build's: the total, per family and per entity (with its capacity)
            solvers = self._solvers
            self.info["particles"] = self._live_particles(solvers, n_particles)
            self.info["counts"] = {s.family: s.counts() for s in solvers}
            pc = self._particle_counts()
            self.info["particle_counts"] = pc
            self.info["particles_capacity"] = self._n_fixed + sum(d["capacity"] for d in pc.values())
        for s in self._solvers:
            try:
                self.info.setdefault("solvers", {})[s.family] = s.info()
            except Exception as e:  # reporting must never fail a run
                self.info.setdefault("solvers", {})[s.family] = {"info_error": str(e)}
        if self._rigid is not None:
            self.info["rigid_bodies"] = self._rigid.summary()
        t = self.timings["stepping_s"] - stepping0
        # the first substep carries the kernel compilation: leave it out of throughput
        steady = max(t, 1e-12)
        dt_lo, dt_hi = self._dt_range
        sps = substeps_done / steady if substeps_done else 0.0
        self.info.update(
            steps_done=step,
            sim_time=step * sim.dt,
            substeps={
                "fixed": sim.substeps if sim.substeps != "auto" else None,
                "auto": sim.substeps == "auto",
                "auto_check": sim.auto_check if sim.substeps == "auto" else None,
                "min": min(sub_hist) if sub_hist else None,
                "max": max(sub_hist) if sub_hist else None,
                "mean": float(np.mean(sub_hist)) if sub_hist else None,
                "total": int(sum(sub_hist)),
                "dt_min_s": dt_lo if math.isfinite(dt_lo) else None,
                "dt_max_s": dt_hi if dt_hi > 0 else None,
            },
            throughput={
                "steps_per_s": ((step - self._step0) / steady) if step else 0.0,
                "substeps_per_s": sps,
                # particle substeps over the live counts (emitters, sinks), per substep
                "particle_substeps_per_s": (
                    sps * n_particles if self._sources is None else self._particle_substeps / steady
                ),
                "cell_substeps_per_s": sps * sum(int(s.counts().get("cells", 0)) for s in self._solvers),
                "vertex_substeps_per_s": sps * sum(int(s.counts().get("vertices", 0)) for s in self._solvers),
            },
        )

    @staticmethod
    def _stable_dt(solvers, fallback: float, horizon: float) -> float:
        """The smallest stable substep the solvers report [s]. A NaN (a solver whose state is no longer
        finite: the frame check at the end of the frame reports it, with advice) gives ``fallback`` instead of
        an
        unreadable error here."""
        vals = [float(s.stable_dt(horizon)) for s in solvers]
        return fallback if any(math.isnan(v) for v in vals) else min(vals)

    def _check_resume_scene(self, meta: dict, path) -> None:
        """--resume: the checkpoint's metadata is consistent and its scene matches this one in everything
        that changes the physics or the time axis (simcli.resume_check); exit 65 naming what differs."""
        from simcli.resume_check import meta_problems, scene_differences

        saved = meta.get("scene")
        if not isinstance(saved, dict):
            self.warn(
                f"checkpoint {path} does not record its scene (written by an older simcli): the scene "
                "could not be compared with it"
            )
        diffs = scene_differences(saved, self.resolved) if isinstance(saved, dict) else []
        if diffs:
            raise SceneError(
                [
                    f"--resume: the checkpoint {path} does not fit this scene: "
                    f"{len(diffs)} key(s) that change the physics or the time axis differ:"
                ]
                + [f"  {d}" for d in diffs]
                + [
                    "  resume with the values the run was started with, or start a new run with the new ones "
                    "(--overwrite, or another -o)"
                ]
            )
        sim = self.scene.sim
        bad = meta_problems(meta, sim.dt, self.scene.output.every, sim.n_steps)
        if bad:
            raise SceneError(
                [f"--resume: checkpoint {path} has inconsistent metadata (edited or damaged?):"]
                + [f"  {b}" for b in bad]
                + [
                    "  remove it to resume from an older checkpoint, or start afresh with --overwrite "
                    "(or another -o)"
                ]
            )

    def _check_resume_meta(self, meta: dict) -> None:
        if meta.get("scene_name") not in (None, self.name):
            self.warn(f"checkpoint was written by scene '{meta.get('scene_name')}', resuming '{self.name}'")

    def _fields(self, solver, name: str) -> list[str]:
        f = self.scene.output.fields
        if f == "default":
            return list(solver.default_fields(name))
        out = list(f)
        if solver.entity_kind(name) != "grid" and "position" not in out:
            out.insert(0, "position")
        return out

    def _entity_meta(self, solvers):
        """Output metadata of every entity, from the solver that owns it (particles, meshes, grids)."""
        from simcli.io.frames import EntityMeta

        metas, self._entity_fields = [], {}
        from simcli.scene.sources import EmitterEntity

        for e in list(self.scene.entities) + [EmitterEntity(em) for em in self.scene.emitters]:
            s = next(s for s in solvers if s.owns(e.name))
            fields = self._fields(s, e.name)
            avail = s.output_fields()
            unknown = [f for f in fields if f not in avail]
            if unknown:
                raise SimcliError(
                    f"output.fields: unknown field(s) {', '.join(unknown)} for entity '{e.name}' "
                    f"({s.family}; available: {', '.join(avail)})"
                )
            grid = s.entity_grid(e.name)
            kw = {} if grid is None else {"grid_shape": grid[0], "origin": grid[1], "spacing": grid[2]}
            # a reusing emitter's particles carry their emission number and birth time (solvers/sources.py)
            extra = {}
            if s.active_set is not None and s.active_set.reusing(e.name) is not None:
                extra = {"emission": (1, "1", "int64"), "birth_time": (1, "s", "float64")}
            metas.append(
                EntityMeta(
                    name=e.name,
                    kind=s.entity_kind(e.name),
                    n=s.entity_size(e.name) - (1 if getattr(e, "is_emitter", False) else 0),
                    variable=s.active_set is not None,
                    dim=self.scene.sim.dim,
                    fields={**{f: avail[f] for f in fields}, **extra},
                    cells=s.entity_cells(e.name),
                    cell_fields=tuple(f for f in fields if f in s.cell_fields),
                    **kw,
                )
            )
            self._entity_fields[e.name] = (s, fields)
        return metas

    def _collider_vtk(self, resume_frame):
        """Surface meshes of the named and moving colliders per frame (vtk/<name>.pvd), when vtk is
        written."""
        if "vtk" not in self.scene.output.formats:
            return None
        from simcli.colliders import collider_vtk_items
        from simcli.io.collider_vtk import ColliderVtkWriter

        items = collider_vtk_items(self.scene, self.loaded.scene_dir)
        if not items:
            return None
        lo, hi = self.scene.domain.bounds(self.scene.sim.dim)
        size = float(np.linalg.norm(np.subtract(hi, lo)))
        w = ColliderVtkWriter(self.out / "vtk", items, self.scene.sim.dim, size)
        w.open(resume_frame)
        return w

    def _collider_meta(self) -> dict[str, int]:
        """Named collider -> dimension (sim.h5 /colliders/<name>/force has dim components, torque 3 or 1)."""
        return {c.name: self.scene.sim.dim for c in self.scene.colliders if c.name is not None}

    def _collider_loads(self, solvers, span: float) -> dict[str, dict[str, np.ndarray]]:
        """Force [N] and torque [N m] on each named collider, averaged over the last ``span`` seconds of
        simulated time (the impulses of every solver's contacts over the substeps, divided by span)."""
        meta = self._collider_meta()
        if not meta:
            return {}
        dim = self.scene.sim.dim
        tot = {name: np.zeros(dim + 3) for name in meta}
        for s in solvers:
            for name, a in s.collider_loads().items():
                if name in tot:  # (rigid bodies are named colliders too: simcli.rigid reads theirs)
                    tot[name] += a
        out = {}
        for name, a in tot.items():
            a = a / span if span > 0 else np.zeros_like(a)
            torque = a[dim + 2 : dim + 3] if dim == 2 else a[dim:]
            out[name] = {"force": a[:dim], "torque": torque}
            if span > 0:
                h = self._load_sums.setdefault(name, [np.zeros(dim), np.zeros(len(torque)), 0.0])
                h[0] += a[:dim] * span
                h[1] += torque * span
                h[2] += span
        self._last_loads = out
        self.info["colliders"] = self._loads_summary()
        return out

    def _loads_summary(self) -> dict:
        """run.json colliders: per named collider, the last frame's force and torque and their means over
        the run (time-weighted)."""
        out = {}
        for name, a in self._last_loads.items():
            h = self._load_sums.get(name)
            mean = (h[0] / h[2], h[1] / h[2]) if h and h[2] > 0 else (a["force"] * 0, a["torque"] * 0)
            out[name] = {
                "force_N": [float(x) for x in a["force"]],
                "torque_Nm": [float(x) for x in a["torque"]],
                "mean_force_N": [float(x) for x in mean[0]],
                "mean_torque_Nm": [float(x) for x in mean[1]],
            }
        return out

    def _frame_data(self):
        out = {}
        for name, (s, fields) in self._entity_fields.items():
            out[name] = s.entity_arrays(name, fields)
            if s.active_set is not None:  # a reusing emitter's emission numbers and birth times
                out[name].update(s.active_set.emitter_arrays(name))
        return out

    def _check_frame(self, solvers, frame: int, sub_dt: float, step: int = 0) -> None:
        """Once per frame: NaN/Inf and runaway speeds; fail with advice, keeping every earlier frame."""
        sim = self.scene.sim
        for s in solvers:
            stats = s.frame_check()
            dx = s.length_scale()
            for name, st in stats.items():
                cfl = st.max_speed * sub_dt / dx if math.isfinite(st.max_speed) else math.inf
                if st.finite and cfl <= s.runaway_cfl():
                    continue
                subs = sim.substeps if sim.substeps != "auto" else "auto"
                what = (
                    f"{st.n_bad} particle(s) with NaN/Inf"
                    if not st.finite
                    else f"a particle speed of {st.max_speed:.3g} m/s (it crosses {cfl:.1f} cells per "
                    "substep)"
                )
                advice = s.runaway_advice(name, sim)  # the family's own (the runner knows no family)
                if isinstance(subs, int) and math.isfinite(cfl) and cfl > 0:
                    advice += (
                        f"; substeps >= {int(math.ceil(subs * cfl / 0.5))} would keep the CFL number "
                        "below 0.5"
                    )
                if subs == "auto" and sim.auto_check == "frame":
                    advice += (
                        "; or set sim.auto_check: substep (the substep is chosen once per output frame now, "
                        "so a collision or splash within a frame can outrun it)"
                    )
                raise NumericalError(
                    f"numerical failure in entity '{name}' before frame {frame} (step {step}, "
                    f"t = {step * sim.dt:.6g} s): {what}. Every earlier frame is kept. "
                    f"To fix: {advice}."
                )
