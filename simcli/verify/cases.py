"""Validation cases as data: ``configs/validation/<name>.case.yaml`` next to its scene file.

A case names a scene, a measurement (a quantity extracted from the run's ``sim.h5``), a
reference (an analytic formula, a value, or a published table shipped in
``simcli/verify/reference_data/`` and named ``${REFERENCE}/<file>``) and a tolerance. A case of
``kind: measurement`` characterises (reported as "measured", not judged against its tolerance).
Adding a case means adding files; nothing here lists cases.

    # configs/validation/free_fall.case.yaml
    scene: free_fall.yaml
    description: Elastic block in free fall; centre of mass against z0 - g t^2 / 2.
    measure: {quantity: com, entity: block, axis: 2}
    reference: {analytic: "z0 - 0.5 * 9.81 * t**2", constants: {z0: 0.5}}
    error: {metric: max_rel, window: [0.0, 0.25]}
    tolerance: 0.01
    refine: {solvers.mpm.grid_density: 2, solvers.mpm.particle_size: 0.5}
    tags: [fast, mpm]
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Literal, Union

from pydantic import BaseModel, ConfigDict, Field, model_validator

from simcli.errors import SceneError

REFERENCE_VAR = "${REFERENCE}"
"""In ``reference.table``: the folder of the tables shipped with simcli
(``simcli/verify/reference_data/``)."""


class _M(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class Measure(_M):
    quantity: str = Field(description="Name of a measurement in simcli.verify.measure (com, gap, tip, ...).")
    entity: str | None = Field(None, description="Entity the measurement reads (default: the first).")
    params: dict[str, Any] = Field(default_factory=dict, description="Extra parameters of the measurement.")
    axis: int | None = Field(None, description="Axis index (0 = x) for vector quantities.")


class Reference(_M):
    analytic: str | None = Field(
        None, description="Formula in t (time [s]) and the constants; numpy functions as np.*."
    )
    table: str | None = Field(
        None,
        description="CSV file: ${REFERENCE}/<file> for a table shipped in simcli/verify/reference_data/, "
        "else a path relative to the case file; first column is time.",
    )
    column: int = Field(1, ge=1, description="Column of the table holding the reference value.")
    value: float | None = Field(None, description="A single reference value.")
    constants: dict[str, float] = Field(default_factory=dict, description="Named constants of the formula.")
    scale_t: str | None = Field(None, description="Formula converting the table's time column to seconds.")
    scale_v: str | None = Field(
        None, description="Formula converting the table's value column to the measure's unit."
    )
    note: str = Field("", description="Where the reference comes from.")

    @model_validator(mode="after")
    def _one(self):
        if sum(x is not None for x in (self.analytic, self.table, self.value)) != 1:
            raise ValueError("give exactly one of analytic, table, value")
        if self.table is not None and "${" in self.table.replace(REFERENCE_VAR, ""):
            raise ValueError(
                f"table: only {REFERENCE_VAR} may be substituted (got {self.table!r}); copy the file into "
                f"simcli/verify/reference_data/ (with its source in the README there) and write "
                f"{REFERENCE_VAR}/<file>, or give a path relative to the case file"
            )
        return self


class ErrorSpec(_M):
    metric: Literal[
        "max_abs",
        "max_rel",
        "rms",
        "rms_rel",
        "final_abs",
        "final_rel",
        "mean_abs",
        "mean_rel",
        "mean_value_rel",
        "mean_value_abs",
        "midrange_rel",
        "period_mean_rel",
        "nmae",
        "arrival_rel",
        "impulse_rel",
    ] = Field(
        "max_rel",
        description="How measured and reference series are compared. mean_value_*: compare the time averages "
        "over the window (an oscillation about a static state); midrange_rel: (max + min) / 2 over the "
        "window; period_mean_rel: the time average over the largest whole number of oscillation periods in "
        "the window (the static state of an undamped oscillation). nmae: the normalised mean absolute error, "
        "mean |measured - reference| over the window / max |reference| over the window (a measured series "
        "against an experiment's time series). arrival_rel: |t_m - t_r| / t_r, the first times each series "
        "reaches `threshold` (an impact's arrival). impulse_rel: |I_m - I_r| / I_r, I the time integral "
        "of each series over the window on its own samples (an impact's pressure impulse; NaN samples, a "
        "dry probe, count as 0).",
    )
    window: list[float] | None = Field(None, description="Time window [t0, t1] compared [s].")
    scale: float | None = Field(None, description="Normalisation for *_rel metrics (default |reference|).")
    threshold: float | None = Field(
        None, description="arrival_rel: the value whose first crossing (from below) is the arrival."
    )

    @model_validator(mode="after")
    def _threshold(self):
        if (self.metric == "arrival_rel") != (self.threshold is not None):
            raise ValueError("threshold is required by metric arrival_rel and used by no other metric")
        if self.metric == "impulse_rel" and self.window is None:
            raise ValueError("metric impulse_rel integrates over a window: give window: [t0, t1]")
        return self


class Case(_M):
    scene: str = Field(description="Scene file, relative to the case file.")
    description: str = ""
    measure: Measure
    reference: Reference
    error: ErrorSpec = Field(default_factory=ErrorSpec)
    tolerance: float = Field(
        gt=0,
        description="Pass when error <= tolerance (kind: measurement: the band the error is shown against, "
        "not judged).",
    )
    kind: Literal["validation", "measurement"] = Field(
        "validation",
        description="validation: judged against the tolerance (pass / FAIL; verify exits 1 on a FAIL). "
        "measurement: a case that characterises rather than validates (its reference is for comparison, "
        "the description says why it is not a pass/fail check): reported as 'measured' with its error, "
        "never as a failure of the physics; a run that fails or a measure that is not finite still FAILs.",
    )
    refine: dict[str, float] = Field(
        default_factory=dict,
        description="Per refinement level, multiply these scene keys (dotted paths) by these factors.",
    )
    refine_tolerance_level: int | None = Field(
        None,
        description="With --refine, the level (0 = coarsest) whose error must meet the tolerance "
        "(default: the finest).",
    )
    overrides: dict[str, Any] = Field(
        default_factory=dict, description="--set overrides applied to the scene."
    )
    tags: list[str] = Field(default_factory=list, description="'fast' marks the CI default set.")
    timeout_s: float = Field(1800, gt=0)

    # filled in by discover()
    name: str = ""
    path: Path = Path()

    model_config = ConfigDict(extra="forbid", frozen=False, arbitrary_types_allowed=True)

    @property
    def scene_path(self) -> Path:
        return (self.path.parent / self.scene).resolve()


def reference_dir() -> Path:
    """The published tables the cases compare against, shipped with simcli as package data
    (``simcli/verify/reference_data/``, each file's source in its README); ``${REFERENCE}`` in a
    case's ``reference.table``."""
    return Path(__file__).resolve().parent / "reference_data"


def table_path(case: Case) -> Path:
    """The file a case's ``reference.table`` names: ``${REFERENCE}/<file>`` (the shipped tables), or
    a path relative to the case file."""
    p = case.reference.table.replace(REFERENCE_VAR, str(reference_dir()))
    return Path(p) if Path(p).is_absolute() else case.path.parent / p


def default_root() -> Path:
    return Path(__file__).resolve().parents[2] / "configs" / "validation"


def load_case(path: Path) -> Case:
    from pydantic import ValidationError

    from simcli.scene.loader import _clean_loc, parse_yaml

    loc = parse_yaml(path.read_text(), str(path))
    try:
        case = Case.model_validate(loc.data)
    except ValidationError as e:
        lines = []
        for err in e.errors(include_url=False):
            p = _clean_loc(err["loc"], loc.data)
            lines.append(f"{loc.where(p)}: {'.'.join(map(str, p))}: {err['msg']}")
        raise SceneError(lines) from None
    case.name = path.name.removesuffix(".case.yaml")
    case.path = path.resolve()
    if not case.scene_path.exists():
        raise SceneError([f"{path}:1:1: scene: file not found: {case.scene_path}"])
    if case.reference.table is not None:
        table = table_path(case)
        if not table.is_file():
            where = loc.where(("reference", "table"))
            raise SceneError([f"{where}: reference.table: file not found: {table}"])
    return case


def discover(root: Path | None = None) -> list[Case]:
    root = root or default_root()
    return [load_case(p) for p in sorted(root.rglob("*.case.yaml"))]


def select(cases: list[Case], names: list[str], all_: bool, tag: str | None) -> list[Case]:
    if names:
        by = {c.name: c for c in cases}
        missing = [n for n in names if n not in by]
        if missing:
            raise SceneError([f"unknown case(s): {', '.join(missing)} (known: {', '.join(sorted(by))})"])
        return [by[n] for n in names]
    if tag:
        return [c for c in cases if tag in c.tags]
    return cases if all_ else [c for c in cases if "fast" in c.tags]


Number = Union[int, float]
