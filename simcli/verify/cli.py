"""``simcli verify``: run validation cases, print and write the report."""

from __future__ import annotations

import sys
import time
from pathlib import Path

import click

from simcli.errors import EXIT_INVALID_SCENE, SceneError


@click.command()
@click.argument("cases", nargs=-1)
@click.option("--all", "all_", is_flag=True, help="Every case (default: the fast set, tag 'fast').")
@click.option("--tag", default=None, help="Only cases with this tag.")
@click.option(
    "--refine",
    type=click.IntRange(1, 8),
    default=1,
    help="Run each case at N successive resolutions (each level applies the case's refine factors) "
    "and report the observed order of convergence and the work-precision diagram.",
)
@click.option(
    "--root",
    type=click.Path(file_okay=False, path_type=Path),
    default=None,
    help="Folder holding *.case.yaml files (default configs/validation).",
)
@click.option(
    "-o",
    "--out",
    "out",
    type=click.Path(file_okay=False, path_type=Path),
    default=Path("out/verify"),
    help="Where runs, CSV, Markdown and plots go.",
)
@click.option(
    "--report",
    type=click.Path(dir_okay=False, path_type=Path),
    default=None,
    help="Also write the Markdown report here (e.g. docs/VALIDATION.md).",
)
@click.option("--backend", default=None, help="Compute backend for the runs.")
@click.option(
    "--list", "list_", is_flag=True, help="List the cases (name, kind, tags, description) and exit."
)
@click.option(
    "--reuse",
    is_flag=True,
    help="Reuse finished runs in OUT whose resolved scene is unchanged "
    "(regenerate a report without rerunning).",
)
@click.option(
    "--variant",
    "variants",
    multiple=True,
    help="'LABEL: key=value key=value': run each chosen case once per variant with these scene overrides "
    "(as --set) on top of its own, as case [LABEL], each judged against the case's tolerance; with --refine "
    "the variants share one work-precision plot. benchmarks/work_precision.py keeps the published studies.",
)
def verify(cases, all_, tag, refine, root, out, report, backend, list_, reuse, variants):
    """Run validation cases against their references; exit 1 when a case fails."""
    from simcli.verify.cases import discover, select
    from simcli.verify.report import markdown_table, plot_refinement, write_csv
    from simcli.verify.run import run_case, run_refinement

    try:
        chosen = select(discover(root), list(cases), all_, tag)
        if variants:
            from simcli.verify.variants import parse_variant, variant_case

            vs = [parse_variant(v) for v in variants]
            chosen = [variant_case(c, v) for c in chosen for v in vs]
    except SceneError as e:
        for line in e.lines:
            click.echo(line, err=True)
        sys.exit(EXIT_INVALID_SCENE)
    if list_:
        for c in chosen:
            click.echo(f"{c.name}\t{c.kind}\t{','.join(c.tags)}\t{c.description}")
        return
    if not chosen:
        click.echo("no cases selected", err=True)
        sys.exit(2)
    results = []
    t0 = time.perf_counter()
    for c in chosen:
        click.echo(f"verify: {c.name} ...", err=True)
        rs = (
            run_refinement(c, refine, out, backend, reuse=reuse)
            if refine > 1
            else [run_case(c, 0, out, backend, reuse=reuse)]
        )
        for r in rs:
            state = r.status
            click.echo(
                f"verify:   level {r.level} ({r.resolution}): error "
                f"{r.error if r.error is None else f'{r.error:.4g}'} tol {r.tolerance:g} {state} "
                f"[{r.wall_s:.1f} s] {r.message}",
                err=True,
            )
        results.extend(rs)
    table = markdown_table(results)
    click.echo(table, err=True)
    out.mkdir(parents=True, exist_ok=True)
    write_csv(results, out / "verify.csv")
    (out / "verify.md").write_text(table)
    plot = plot_refinement(results, out / "work_precision.png") if refine > 1 else None
    if report is not None:
        report.parent.mkdir(parents=True, exist_ok=True)
        img = ""
        if plot is not None:
            dest = report.parent / "img" / "work_precision.png"
            dest.parent.mkdir(parents=True, exist_ok=True)
            dest.write_bytes(plot.read_bytes())
            img = f"\n![convergence and work-precision](img/{dest.name})\n"
        cmd = "simcli verify " + " ".join(sys.argv[2:]) if len(sys.argv) > 2 else "simcli verify"
        report.write_text(
            "# Validation\n"
            "\n"
            f"Regenerate with `{cmd}`. Generated {time.strftime('%Y-%m-%d')}; total wall time "
            f"{time.perf_counter() - t0:.0f} s. Each case is a scene plus a `.case.yaml` in "
            "configs/validation/ (measurement, reference, tolerance). With --refine, only the finest level "
            "(or the case's refine_tolerance_level) is judged against the tolerance; order = observed order "
            "of convergence between successive levels. A case of kind measurement characterises rather than "
            "validates: its result reads 'measured' (its error shown against the tolerance, not judged).\n"
            "\n" + table + img
        )
        click.echo(f"wrote {report}", err=True)
    failed = [r for r in results if r.passed is False]
    sys.exit(1 if failed else 0)
