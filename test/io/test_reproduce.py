"""Named regression case: the paper's findings on the synthetic cells (reduced N for speed)."""

import json

import pytest

from rbc_registration.io.reproduce import reproduce


@pytest.fixture(scope="module")
def doc(tmp_path_factory):
    out = tmp_path_factory.mktemp("reproduce")
    return reproduce(out, seed=0, repeats=20, log=lambda s: None), out


def test_all_findings_hold(doc):
    found, _ = doc
    failed = [f for f in found["findings"] if not f["holds"]]
    assert not failed, failed
    assert len(found["findings"]) == 11


def test_table1_orders_of_magnitude(doc):
    found, _ = doc
    cells = found["cells"]
    for name, s_l0, rho in (("A", 2.5, 41.7), ("B", 0.09, 0.56), ("RA", 0.28, 2.54)):
        sl = cells[name]["sigma_L"]
        assert sl[0] == pytest.approx(s_l0, rel=0.1)
        assert cells[name]["rho"] == pytest.approx(rho, rel=0.15)
        assert sl[1] / sl[0] < 2e-3 and sl[2] / sl[0] < 1e-6
    assert cells["A"]["recommendation"] == "apply"
    assert cells["B"]["recommendation"] == "do_not_apply"


def test_outputs_written(doc):
    found, out = doc
    assert (out / "table1.md").read_text().startswith("| cell |")
    on_disk = json.loads((out / "reproduce.json").read_text())
    assert on_disk["findings"] == found["findings"]
    for name in found["figures"]:
        assert (out / name).stat().st_size > 5000          # a real PNG, not an empty file
    figures = found["figures"]
    assert sum("kriging" in n for n in figures) == sum("paper" in n for n in figures)


def test_table1_reports_the_decision(doc):
    found, out = doc
    table = (out / "table1.md").read_text()
    assert "| rho rule | decision (cv) |" in table.splitlines()[0]
    for name, cell in found["cells"].items():
        dec = cell["decision"]
        assert dec["mode"] == "cv" and dec["method"] in ("uncorrected", "paper", "kriging")
        row = [line for line in table.splitlines() if line.startswith(f"| {name} | ")][0]
        assert f"| {cell['recommendation']} | {dec['method']}" in row
        assert f"| {cell['tre_destination_median']:.3g} |" in row
    a = found["cells"]["A"]   # strong smooth bias: the decision corrects, TRE drops sharply
    assert a["decision"]["apply"]
    tre_u = a["interpolations"]["paper"]["summary"]["tre_u_median"]
    assert a["tre_destination_median"] < 0.5 * tre_u
