"""Import graph of simcli/ from the source (ast, nothing imported) and its cycles.

    python tools/import_graph.py            # cycles among module-level imports, then among all imports
    python tools/import_graph.py --edges    # every edge, module-level and function-level marked

Module-level imports are those executed when the module is imported (top level, also inside
`if`/`try` at top level); function-level imports are those inside a function or method body (run
later, so they break no import-time cycle, but they still tie the modules together); type-only
imports are those under `if TYPE_CHECKING:` (never run, but they still say who knows whom). A cycle
among module-level imports is an error (tests/unit/test_architecture.py); the other two views are
reported so that a cycle hidden in a function body is seen too.
"""

from __future__ import annotations

import ast
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = "simcli"


def module_name(path: Path, root: Path = ROOT) -> str:
    parts = list(path.relative_to(root).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


def modules(root: Path = ROOT) -> dict[str, Path]:
    return {module_name(p, root): p for p in sorted((root / PACKAGE).rglob("*.py"))}


def _resolve(mod: str, is_pkg: bool, node: ast.ImportFrom) -> str:
    if node.level == 0:
        return node.module or ""
    base = mod.split(".")
    if not is_pkg:
        base = base[:-1]
    base = base[: len(base) - (node.level - 1)]
    return ".".join(base + ([node.module] if node.module else []))


def _is_type_checking(test: ast.expr) -> bool:
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING"
    )


MODULE, FUNCTION, TYPE_ONLY = "module", "function", "type-only"


def imports(mod: str, path: Path, known: set[str]) -> list[tuple[str, str]]:
    """(target module, kind) for every simcli import in `path`; kind is MODULE, FUNCTION or TYPE_ONLY."""
    tree = ast.parse(path.read_text(), str(path))
    is_pkg = path.name == "__init__.py"
    out: list[tuple[str, str]] = []

    def target(name: str) -> str | None:
        while name:
            if name in known:
                return name
            name = name.rpartition(".")[0]
        return None

    def visit(node: ast.AST, kind: str) -> None:
        if isinstance(node, ast.If) and _is_type_checking(node.test):
            for child in node.body:
                visit(child, TYPE_ONLY)
            for child in node.orelse:
                visit(child, kind)
            return
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)) and kind == MODULE:
            kind = FUNCTION
        if isinstance(node, ast.Import):
            for alias in node.names:
                t = target(alias.name)
                if t:
                    out.append((t, kind))
        elif isinstance(node, ast.ImportFrom):
            base = _resolve(mod, is_pkg, node)
            for alias in node.names:
                t = target(f"{base}.{alias.name}") or target(base)
                if t:
                    out.append((t, kind))
        for child in ast.iter_child_nodes(node):
            visit(child, kind)

    visit(tree, MODULE)
    return out


def graph(kinds: tuple[str, ...] = (MODULE,), root: Path = ROOT) -> dict[str, set[str]]:
    """module -> the simcli modules it imports with an import of one of `kinds`."""
    mods = modules(root)
    known = set(mods)
    g: dict[str, set[str]] = {m: set() for m in mods}
    for m, p in mods.items():
        for t, kind in imports(m, p, known):
            if t != m and kind in kinds:
                g[m].add(t)
    return g


def cycles(g: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan), each sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    out: list[list[str]] = []
    counter = [0]
    sys.setrecursionlimit(10000)

    def strong(v: str) -> None:
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in sorted(g[v]):
            if w not in index:
                strong(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(g):
        if v not in index:
            strong(v)
    return sorted(out)


def main(argv: list[str]) -> int:
    if "--edges" in argv:
        mods = modules()
        for m, p in mods.items():
            for t, kind in sorted(set(imports(m, p, set(mods)))):
                if t != m:
                    print(f"{m} -> {t}{'' if kind == MODULE else f'  ({kind})'}")
        return 0
    status = 0
    views = (
        ("module-level imports", (MODULE,)),
        ("module- and function-level imports", (MODULE, FUNCTION)),
        ("all imports, type-only included", (MODULE, FUNCTION, TYPE_ONLY)),
    )
    for label, kinds in views:
        found = cycles(graph(kinds))
        print(f"{label}: {len(found)} cycle(s)")
        for comp in found:
            print("  " + " <-> ".join(comp))
        if kinds == (MODULE,) and found:
            status = 1
    return status


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
