"""No function of the package runs past 80 lines, unless its first lines say why: a comment
``# long: <the reason>`` within its first three lines."""

import ast
from pathlib import Path

PKG = Path(__file__).resolve().parents[1] / "rbc_registration"
LIMIT = 80


def _long_functions() -> list[str]:
    out = []
    for path in sorted(PKG.rglob("*.py")):
        lines = path.read_text(encoding="utf-8").splitlines()
        for node in ast.walk(ast.parse("\n".join(lines), str(path))):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                length = node.end_lineno - node.lineno + 1
                head = lines[node.lineno - 1:node.lineno + 2]
                if length > LIMIT and not any("# long:" in line for line in head):
                    out.append(f"{path.relative_to(PKG.parent)}:{node.lineno} {node.name} "
                               f"({length} lines)")
    return out


def test_no_function_runs_past_80_lines_without_saying_why():
    assert _long_functions() == []
