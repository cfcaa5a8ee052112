"""docs/LAYOUT.md names every module of the package in its folder's table, and nothing else.

Each folder of the package has a section ``## `rbc_registration/<folder>/``` whose table has one
row per module (``| `name.py` | what |``); ``__init__.py`` files are not listed.
"""

import pathlib
import re

ROOT = pathlib.Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "rbc_registration"
LAYOUT = ROOT / "docs" / "LAYOUT.md"
SECTION = re.compile(r"^## `(rbc_registration/(?:[a-z_]+/)*)`\s*$")
ROW = re.compile(r"^\| `([A-Za-z0-9_]+\.py)` \|(.*)\|\s*$")


def layout_modules() -> dict[str, str]:
    """Each module row of LAYOUT.md as ``rbc_registration/<folder>/<name>.py`` -> its text."""
    modules: dict[str, str] = {}
    folder = None
    for line in LAYOUT.read_text(encoding="utf-8").splitlines():
        section = SECTION.match(line)
        if section:
            folder = section.group(1)
            continue
        if line.startswith("## "):
            folder = None
        row = ROW.match(line)
        if row and folder is not None:
            path = folder + row.group(1)
            assert path not in modules, f"docs/LAYOUT.md names {path} twice"
            modules[path] = row.group(2).strip()
    return modules


def package_modules() -> set[str]:
    return {path.relative_to(ROOT).as_posix() for path in PACKAGE.rglob("*.py")
            if path.name != "__init__.py" and "__pycache__" not in path.parts}


def test_every_module_is_named_in_its_folders_table():
    missing = sorted(package_modules() - set(layout_modules()))
    assert not missing, f"docs/LAYOUT.md does not name: {missing}"


def test_every_row_names_a_module_that_exists():
    extra = sorted(set(layout_modules()) - package_modules())
    assert not extra, f"docs/LAYOUT.md names modules that do not exist: {extra}"


def test_every_row_says_what_the_module_is_in_a_sentence_or_two():
    for path, text in layout_modules().items():
        assert text, f"{path}: empty row"
        assert len(text.split()) <= 40, f"{path}: {len(text.split())} words (a sentence or two)"


def test_the_layout_is_linked_from_the_readme():
    assert "docs/LAYOUT.md" in (ROOT / "README.md").read_text(encoding="utf-8")
