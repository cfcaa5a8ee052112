"""README's "What is where" table names every module of the package, in its folder's row."""

import pathlib

ROOT = pathlib.Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "rbc_registration"


def layout_rows() -> dict[str, str]:
    """The table's rows by their first cell (a path such as ``rbc_registration/core/``)."""
    rows = {}
    for line in (ROOT / "README.md").read_text(encoding="utf-8").splitlines():
        if line.startswith("| `rbc_registration/"):
            first, rest = line[2:].split("|", 1)
            rows[first.strip().strip("`")] = rest
    return rows


def test_every_module_is_named_in_its_folders_row():
    rows = layout_rows()
    missing = []
    for path in sorted(PACKAGE.rglob("*.py")):
        if path.name == "__init__.py":
            continue
        relative = path.relative_to(ROOT).as_posix()
        if relative in rows:                          # a row of its own (runtime.py)
            continue
        folder = f"rbc_registration/{path.relative_to(PACKAGE).parts[0]}/"
        if f"`{path.name}`" not in rows.get(folder, ""):
            missing.append(relative)
    assert not missing, f"README.md 'What is where' does not name: {missing}"
