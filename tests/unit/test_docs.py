"""The docs a newcomer reads: every page exists, every relative link resolves, the index and the README
link every family page, and the tutorial's scene and sweep files are valid."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
DOCS = ROOT / "docs"
FAMILY_PAGES = ("MPM.md", "SPH.md", "FEM.md", "PBD.md", "SF.md")
USER_PAGES = ("TUTORIAL.md", "SCENE_FORMAT.md", "RESOLUTION.md")


def _links(md: Path) -> list[str]:
    return [m.group(1) for m in re.finditer(r"\]\(([^)#\s]+)(?:#[^)]*)?\)", md.read_text())]


def test_every_relative_link_in_the_readme_and_docs_resolves():
    broken = []
    for md in [ROOT / "README.md", *sorted(DOCS.glob("*.md"))]:
        for target in _links(md):
            if re.match(r"[a-z]+:", target):
                continue  # http:, https:, mailto:
            if not (md.parent / target).exists():
                broken.append(f"{md.relative_to(ROOT)} -> {target}")
    assert not broken, broken


def test_readme_and_docs_index_link_every_family_and_user_page():
    for page in FAMILY_PAGES + USER_PAGES:
        assert (DOCS / page).is_file(), page
    readme = set(_links(ROOT / "README.md"))
    index = set(_links(DOCS / "README.md"))
    assert "docs/README.md" in readme
    for page in FAMILY_PAGES + USER_PAGES:
        assert f"docs/{page}" in readme, f"README.md does not link docs/{page}"
        assert page in index, f"docs/README.md does not link {page}"


def test_user_pages_say_units_are_si():
    for page in ("README.md", "TUTORIAL.md", "SCENE_FORMAT.md", "MPM.md", "RESOLUTION.md"):
        head = (DOCS / page).read_text()[:1500]
        assert "SI" in head, f"docs/{page} does not say up front that units are SI"


def test_tutorial_files_are_valid():
    files = [str(DOCS / "tutorial" / "first.yaml"), str(DOCS / "tutorial" / "first_sweep.yaml")]
    r = subprocess.run(
        [sys.executable, "-m", "simcli", "validate", *files], capture_output=True, text=True, timeout=300
    )
    assert r.returncode == 0, r.stdout + r.stderr


def test_tutorial_shows_its_files_as_they_are():
    """The scene and sweep printed in TUTORIAL.md are the files the tutorial's commands run."""
    blocks = re.findall(r"```yaml\n(.*?)```", (DOCS / "TUTORIAL.md").read_text(), re.S)
    for name in ("first.yaml", "first_sweep.yaml"):
        assert (DOCS / "tutorial" / name).read_text() in blocks, (
            f"docs/tutorial/{name} differs from TUTORIAL.md"
        )
