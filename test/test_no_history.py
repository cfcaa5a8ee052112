"""The docs, comments and docstrings say what is true now; development history belongs in git.

Scanned: README.md, docs/*.md, msg_docs/ (Markdown and the .msg/.srv files),
benchmarks/RESULTS.md and the docstrings of benchmarks/*.py, the comments and docstrings of
rbc_registration/**/*.py and launch/*.py, and scripts/*. Each phrase below is how a change's
story gets told ("a review found", "stop 32", "previously", a commit hash as evidence); the
failure names every hit as file:line.
"""

import ast
import io
import pathlib
import re
import tokenize

ROOT = pathlib.Path(__file__).resolve().parents[1]

#: History phrasing, case-insensitive. "used to" only where it tells a past habit ("it used to
#: fail"), not the participle ("the seed used to draw", "is used to"); "no longer" not in "no
#: longer than"; "before" alone is a normal word and not searched.
PATTERNS = {
    "a review": r"\ba review\b",
    "review found": r"\breviews? found\b",
    "found by a review": r"\bfound (?:by|in) (?:an? |the |two |three )?reviews?\b",
    "independent review": r"\bindependent review\b",
    "reviewer": r"\breviewers?\b",
    "stop N": r"\bstop \d+\b",
    "this stop": r"\bthis stop\b",
    "before stop": r"\bbefore stop\b",
    "previously": r"\bpreviously\b",
    "used to": r"\b(?:it|they|we|this|that|which|who|one|node|code|test|tests)\s+used to\b",
    "no longer": r"\bno longer\b(?! than)",
    "was fixed": r"\bwas fixed\b",
    "regression of": r"\ba regression (?:of|in|from|since)\b|\bregression of (?:issue|stop|#)",
    "commit hash": r"\bcommits?\W{1,3}[0-9a-f]{7,40}\b|\b[0-9a-f]{7,40}\W{1,3}commit",
    "an earlier session": r"\ban earlier session\b",
}
COMPILED = {name: re.compile(rx, re.IGNORECASE) for name, rx in PATTERNS.items()}


def whole_text(path: pathlib.Path) -> list[tuple[int, str]]:
    """Every line of a document, numbered from 1."""
    return list(enumerate(path.read_text(encoding="utf-8").splitlines(), start=1))


def python_prose(path: pathlib.Path) -> list[tuple[int, str]]:
    """The comment and string-statement (docstring) lines of a Python file, numbered from 1."""
    source = path.read_text(encoding="utf-8")
    lines = source.splitlines()
    picked: dict[int, str] = {}
    for token in tokenize.generate_tokens(io.StringIO(source).readline):
        if token.type == tokenize.COMMENT:
            picked[token.start[0]] = token.string
    for node in ast.walk(ast.parse(source, filename=str(path))):
        if (isinstance(node, ast.Expr) and isinstance(node.value, ast.Constant)
                and isinstance(node.value.value, str)):
            for number in range(node.lineno, node.end_lineno + 1):
                picked[number] = lines[number - 1]
    return sorted(picked.items())


def scanned() -> list[tuple[pathlib.Path, list[tuple[int, str]]]]:
    """Each scanned file with the lines of it that are prose."""
    documents = [ROOT / "README.md", ROOT / "benchmarks" / "RESULTS.md"]
    documents += sorted((ROOT / "docs").glob("*.md"))
    documents += sorted(p for p in (ROOT / "msg_docs").rglob("*")
                        if p.suffix in (".md", ".msg", ".srv"))
    documents += sorted(p for p in (ROOT / "scripts").iterdir() if p.is_file())
    code = sorted((ROOT / "rbc_registration").rglob("*.py"))
    code += sorted((ROOT / "launch").glob("*.py"))
    code += sorted((ROOT / "benchmarks").glob("*.py"))
    return ([(p, whole_text(p)) for p in documents if p.is_file()]
            + [(p, python_prose(p)) for p in code])


def hits_in(lines: list[tuple[int, str]]) -> list[tuple[int, str, str]]:
    """(line number, phrase name, the line) for every history phrase in the lines."""
    found = []
    for number, text in lines:
        for name, rx in COMPILED.items():
            if rx.search(text):
                found.append((number, name, text.strip()))
    return found


def test_the_patterns_find_history_and_pass_plain_words():
    history = ["A review found the bound too small.", "Since stop 32 the node batches.",
               "measured in this stop", "The reviewer's cells", "previously 2.1 ms",
               "it used to fail on NaN", "The node no longer logs it.", "This was fixed.",
               "a regression of issue 9", "a regression since the split",
               "see commit 7e53f70", "(9b81d46 commit)",
               "as an earlier session measured", "before stop 30",
               "(found in review, a bag)", "an independent review of the cells"]
    plain = ["before the rebuild", "the seed used to draw the cell", "is used to scale",
             "no longer than 80 lines", "stop the spin thread", "stops at 10 fiducials",
             "the decision reviews nothing", "code 9b81d46, 2 cores",
             "Gaussian-process regression of each component"]
    assert all(hits_in([(1, text)]) for text in history), [
        text for text in history if not hits_in([(1, text)])]
    assert not any(hits_in([(1, text)]) for text in plain), [
        text for text in plain if hits_in([(1, text)])]


def test_python_prose_is_comments_and_docstrings_only(tmp_path):
    source = ('"""Module: previously nothing."""\n'
              'x = "previously"  # a review\n'
              'def f():\n'
              '    """Used.\n\n    no longer\n    """\n')
    path = tmp_path / "probe.py"
    path.write_text(source, encoding="utf-8")
    picked = dict(python_prose(path))
    assert sorted(picked) == [1, 2, 4, 5, 6, 7]
    assert picked[2] == "# a review"


def test_no_development_history_in_docs_comments_or_docstrings():
    report = []
    for path, lines in scanned():
        for number, name, text in hits_in(lines):
            report.append(f"{path.relative_to(ROOT)}:{number}: {name}: {text[:120]}")
    assert not report, "development history (say what is true now):\n" + "\n".join(report)
