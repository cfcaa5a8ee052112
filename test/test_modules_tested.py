"""Every module of rbc_registration.core (its root and its parts) is imported by at least one test
(by its dotted name or ``from rbc_registration.core.<part> import <module>``), so no part of the
method goes untested."""

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CORE = ROOT / "rbc_registration" / "core"


def _core_modules() -> list[str]:
    return sorted(".".join(p.relative_to(CORE).with_suffix("").parts)
                  for p in CORE.rglob("*.py") if p.name != "__init__.py")


def test_every_core_module_is_imported_by_a_test():
    text = "\n".join(p.read_text(encoding="utf-8") for p in (ROOT / "test").rglob("test_*.py"))
    modules = _core_modules()
    assert len(modules) > 30
    def imported(module: str) -> bool:
        package, _, name = f"core.{module}".rpartition(".")
        return bool(re.search(rf"rbc_registration\.core\.{re.escape(module)}\b", text)
                    or re.search(rf"from rbc_registration\.{re.escape(package)} import "
                                 rf"[^\n]*\b{name}\b", text))

    untested = [m for m in modules if not imported(m)]
    assert untested == [], f"core modules no test imports: {untested}"
