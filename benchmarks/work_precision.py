"""Work-precision studies: several options of one validation case on one plot (issue 23).

Each study in benchmarks/work_precision.yaml runs one `simcli verify` case at several resolutions
(the machinery of `simcli verify --refine`) once per variant (a label plus `key=value` scene
overrides), then writes, for the docs:

- the rows to the study's CSV (docs/data/<study>.csv): rows of variants not run this time are kept,
  so a new option is added to a published plot without rerunning the old ones;
- the plot (docs/img/<study>.png): error against resolution and against stepping wall time;
- the Markdown table, between `<!-- wp:<study> -->` and `<!-- /wp:<study> -->` in the study's doc.

    PYTHONPATH=$PWD python benchmarks/work_precision.py mpm_transfers_sulsky -o /tmp/wp
    PYTHONPATH=$PWD python benchmarks/work_precision.py --list
    # add an option to a published study, running only it:
    PYTHONPATH=$PWD python benchmarks/work_precision.py fem_elements_cantilever \\
        --variant 'tet10: solvers.fem.element=tet10' --only tet10 -o /tmp/wp
    # redraw plot and table from the CSV alone (no runs):
    PYTHONPATH=$PWD python benchmarks/work_precision.py fem_elements_cantilever --replot
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _echo(*a):
    print(*a, flush=True)


def main(argv: list[str] | None = None) -> int:
    from simcli.errors import SceneError
    from simcli.verify import variants as wp
    from simcli.verify.cases import discover

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("studies", nargs="*", help="study names (default: --list)")
    ap.add_argument("--file", type=Path, default=ROOT / "benchmarks" / "work_precision.yaml")
    ap.add_argument(
        "--variant",
        action="append",
        default=[],
        help="'LABEL: key=value key=value': an extra variant (replaces one of the same label)",
    )
    ap.add_argument("--only", action="append", default=[], help="run only this variant (repeatable)")
    ap.add_argument("--levels", type=int, default=None, help="resolutions per variant (default: the study's)")
    ap.add_argument("-o", "--out", type=Path, default=ROOT / "out" / "work_precision", help="runs go here")
    ap.add_argument("--reuse", action="store_true", help="reuse finished runs in OUT with the same scene")
    ap.add_argument(
        "--repeat",
        type=int,
        default=None,
        help="run every variant N times, alternating, and keep the fastest stepping time "
        "(default: the study's repeat)",
    )
    ap.add_argument("--backend", default=None)
    ap.add_argument("--replot", action="store_true", help="no runs: redraw plot and table from the CSV")
    ap.add_argument(
        "--no-docs",
        action="store_true",
        help="write CSV, plot and table under OUT only (the published rows are still read and merged)",
    )
    ap.add_argument("--list", action="store_true")
    a = ap.parse_args(argv)

    try:
        studies = wp.load_studies(a.file)
        extra = [wp.parse_variant(s) for s in a.variant]
        if a.list or not a.studies:
            for s in studies.values():
                print(f"{s.name}\t{s.case}\t{', '.join(v.label for v in s.variants)}")
            return 0
        unknown = [n for n in a.studies if n not in studies]
        if unknown:
            raise SceneError([f"unknown study {', '.join(unknown)} (have {', '.join(studies)})"])
        cases = {c.name: c for c in discover()}
        status = 0
        for name in a.studies:
            st = studies[name]
            for v in extra:
                st.variants = [x for x in st.variants if x.label != v.label] + [v]
            out = a.out / name
            out.mkdir(parents=True, exist_ok=True)
            docs = not a.no_docs
            published = ROOT / st.csv if st.csv else out / f"{name}.csv"
            rows = wp.read_rows(published)  # the published rows: variants not run now are kept
            if not a.replot:
                new = wp.run_study(
                    st,
                    cases,
                    out,
                    a.backend,
                    a.reuse,
                    a.only or None,
                    a.levels,
                    echo=_echo,
                    repeat=a.repeat or st.repeat,
                )
                wp.write_rows(new, out / f"{name}.new.csv")
                failed = [r for r in new if r.get("exit_code")]
                if failed:  # never publish a failed run: the docs keep what they had
                    status = 1
                    docs = False
                    for r in failed:
                        print(
                            f"{name}: {r['variant']} level {r['level']} failed: {r['message']}",
                            file=sys.stderr,
                        )
                    print(
                        f"{name}: runs failed; docs left unchanged (this run's rows: {name}.new.csv in {out})"
                    )
                rows = wp.merge_rows(rows, new)
            csv_path = published if (docs and st.csv) else out / f"{name}.csv"
            if not a.replot or not docs:
                wp.write_rows(rows, csv_path)
            table = wp.markdown(rows, st)
            print(table)
            (out / f"{name}.md").write_text(table)
            png = ROOT / st.plot if (st.plot and docs) else out / f"{name}.png"
            if wp.plot(rows, png, st):
                print(f"wrote {png}")
            print(f"wrote {csv_path}")
            if st.doc and docs:
                if wp.update_doc(ROOT / st.doc, name, table):
                    print(f"updated the table in {st.doc}")
                else:
                    print(f"note: no <!-- wp:{name} --> markers in {st.doc}; table not inserted")
        return status
    except SceneError as e:
        for line in e.lines:
            print(line, file=sys.stderr)
        return 65
    return 0


if __name__ == "__main__":
    sys.exit(main())
