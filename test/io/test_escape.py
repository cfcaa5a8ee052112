"""Issue 11, report injection: the escaping of untrusted text (ids, paths, units) per output kind
(rbc_registration.io.escape), and every text output of the CLI fed hostile ids, paths and units:
the text report and the terminal, ``report.md`` of ``evaluate --out``."""

import re
import unicodedata

import pytest

from rbc_registration import cli
from rbc_registration.core.synthetic.cells import make_cell
from rbc_registration.io import escape
from rbc_registration.io.bag.synthetic import cell_messages
from rbc_registration.io.bag.writer import write_bag
from rbc_registration.io.csv_io import write_fiducials, write_targets

#: HTML, a table-breaking pipe, a line break and a Markdown heading, a link, an image, a code span,
#: ANSI colour, a carriage return, a bell, a C1 CSI and a right-to-left override.
HOSTILE = ("<img src=x onerror=alert(1)>|x\n# pwned [link](http://evil) ![i](http://evil/i.png) "
           "`code` *em* \x1b[31mred\x1b[0m\rover\x07\x9b2J\u202egnp.exe")
CONTROLS = re.compile("[\x00-\x08\x0b-\x1f\x7f-\x9f\u200b-\u200f\u202a-\u202e\u2066-\u2069]")


def unescaped_pipes(line: str) -> int:
    """Table-cell delimiters of a Markdown line (a backslash escapes the next character)."""
    return len(re.findall(r"\|", re.sub(r"\\.", "", line)))


def test_terminal_escapes_every_control_and_format_character():
    for code in list(range(0x20)) + list(range(0x7f, 0xa0)) + [0x200b, 0x202e, 0x2066, 0xfeff,
                                                                0x2028, 0x2029]:
        out = escape.terminal(f"a{chr(code)}b")
        assert out.isprintable() and out.startswith("a\\") and out.endswith("b"), (code, out)
    assert escape.terminal("\x1b[31m") == "\\x1b[31m"
    assert escape.terminal("a\nb\tc\rd") == "a\\nb\\tc\\rd"
    assert escape.terminal("\u202e") == "\\u202e"
    plain = "Zürich/mm ø µm 東京 C:\\data\\x.csv"
    assert escape.terminal(plain) == plain          # printable text is left alone


def test_markdown_gives_one_literal_line():
    out = escape.markdown(HOSTILE)
    assert "\n" not in out and not CONTROLS.search(out) and "<" not in out and ">" not in out
    bare = re.sub(r"\\.", "", out)                  # what is left when escapes are removed
    for special in "[]()`*|#!_~":
        assert special not in bare, special
    assert "&lt;img src=x onerror=alert\\(1\\)&gt;\\|x\\\\n\\# pwned" in out
    assert escape.markdown("ok id-1.2") == "ok id-1.2"


@pytest.mark.parametrize("value", ["plain", "a`b", "``x``", "`", "a ``` b", " ", "x\ny`"])
def test_markdown_code_fence_is_longer_than_any_backtick_run(value):
    out = escape.markdown_code(value)
    fence = re.match("`+", out).group(0)
    inner = out[len(fence):-len(fence)]
    assert out.endswith(fence)
    assert max((len(r) for r in re.findall("`+", inner)), default=0) < len(fence)
    assert "\n" not in out
    assert inner.strip(" ") == escape.terminal(value).strip(" ") or inner == escape.terminal(value)


@pytest.fixture(scope="module")
def hostile_files(tmp_path_factory):
    """RA with hostile fiducial and target ids (CSV, mm) and a bag in a hostile directory."""
    d = tmp_path_factory.mktemp("hostile")
    cell = make_cell("RA", seed=0)
    fids = [HOSTILE + str(k) if k < 3 else f for k, f in enumerate(cell.fiducial_ids)]
    tids = [HOSTILE + str(k) if k < 3 else t for k, t in enumerate(cell.target_ids)]
    write_fiducials(d / "f.csv", fids, cell.fiducial_measurements,
                    [t[None] for t in cell.fiducial_truth])
    write_targets(d / "t.csv", tids, cell.target_means, cell.target_truth)
    write_targets(d / "t_m.csv", tids, cell.target_means * 1e-3, cell.target_truth * 1e-3)
    bag = d / "bag |<b>x<i> `#[l](u) \x1b[2J"  # a name, no "/"
    write_bag(bag, cell_messages(cell), "mcap", progress=False)
    return d, bag, len(cell.target_ids)


def _clean_terminal(text: str) -> None:
    assert not CONTROLS.search(text), repr(CONTROLS.search(text).group(0))
    assert "\r" not in text and "\t" not in text


def test_register_text_report_escapes_ids_and_unit(hostile_files, capsys):
    d, _, n_targets = hostile_files
    with pytest.raises(SystemExit):      # a unit is one of METRES_PER_UNIT: refused, escaped
        cli.main(["register", str(d / "f.csv"), "--unit", "mm\x1b[8m\n# unit"])
    err = capsys.readouterr().err
    _clean_terminal(err)
    assert len(err.strip().splitlines()) == 1 and "mm\\x1b[8m\\n# unit" in err
    assert cli.main(["register", str(d / "f.csv"), "--targets", str(d / "t.csv")]) == 0
    out = capsys.readouterr().out
    _clean_terminal(out)
    assert escape.terminal(HOSTILE + "0") in out
    rows = [line for line in out.splitlines() if "onerror" in line]
    assert len(rows) == 3                            # one line per hostile target, none split


def test_evaluate_report_md_and_terminal_escape_ids_and_paths(hostile_files, tmp_path, capsys):
    d, bag, n_targets = hostile_files
    out_dir = tmp_path / "report"
    assert cli.main(["evaluate", str(bag), "--targets", str(d / "t_m.csv"), "--quiet",
                     "--out", str(out_dir)]) == 0
    _clean_terminal(capsys.readouterr().out)
    md = (out_dir / "report.md").read_text()
    assert not CONTROLS.search(md)
    lines = md.splitlines()
    # the bag path is a code span (literal in CommonMark, HTML included); no "<" anywhere else
    assert all("<" not in line for line in lines if not line.startswith("Bag "))
    assert [line for line in lines if line.startswith("#")] == [
        "# Evaluation of " + escape.markdown(bag.name), "## Table 1 values", "## Decision",
        "## Targets"]
    assert any(line.startswith("Bag " + escape.markdown_code(bag) + ":") for line in lines)
    head = lines.index("| target | TRE | expected TRE | 95 % bound | TRE_u | TRE_c | dTRE "
                       "| inside hull |")
    rows = lines[head + 2:head + 2 + n_targets]
    assert all(unescaped_pipes(r) == 9 for r in rows) and lines[head + 2 + n_targets] == ""
    assert rows[0].startswith("| " + escape.markdown(HOSTILE + "0") + " |")
    prose = [line for line in lines if not line.startswith(("Bag ", "!["))]
    bare = re.sub(r"\\.", "", "\n".join(prose))
    assert "[" not in bare and "`" not in bare and "](" not in bare


def test_error_lines_escape_paths(tmp_path, capsys):
    assert cli.main(["register", str(tmp_path / "x\x1b[2J\n.csv")]) == 2
    err = capsys.readouterr().err
    _clean_terminal(err)
    assert len(err.strip().splitlines()) == 1 and "x\\x1b[2J\\n.csv" in err


def test_the_unicode_categories_escaped_are_the_invisible_ones():
    for ch in ("\u00a0", "é", " "):
        assert escape.terminal(ch) == ch
    assert unicodedata.category("\u202e") == "Cf" and escape.terminal("\u202e") != "\u202e"
