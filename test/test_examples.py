"""examples/: the committed files are what make_examples.py writes, the figure script draws the
README's figure, and node_client.py converts the files' millimetres into the node's metres."""

import filecmp
import importlib.util
import pathlib

import numpy as np
import pytest

from rbc_registration.io.csv_io import read_fiducials, read_targets

ROOT = pathlib.Path(__file__).resolve().parents[1]
EXAMPLES = ROOT / "examples"
CELLS = ("cell3d", "plate2d")
FILES = ("fiducials.csv", "candidates.csv", "targets.csv")


def _module(name):
    spec = importlib.util.spec_from_file_location(f"examples_{name}", EXAMPLES / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_committed_files_are_what_make_examples_writes(tmp_path):
    assert _module("make_examples").main(["--out", str(tmp_path)]) == 0
    for cell in CELLS:
        for name in FILES:
            assert filecmp.cmp(tmp_path / cell / name, EXAMPLES / cell / name, shallow=False), \
                f"examples/{cell}/{name} differs from what make_examples.py writes"


@pytest.mark.parametrize("cell, dim, fiducials, targets", [("cell3d", 3, 63, 16),
                                                           ("plate2d", 2, 81, 20)])
def test_the_cells_are_what_the_readme_says(cell, dim, fiducials, targets):
    data = read_fiducials(EXAMPLES / cell / "fiducials.csv")
    assert data.dimension == dim and len(data.ids) == fiducials
    truth = read_targets(EXAMPLES / cell / "targets.csv", dim)
    assert len(truth.ids) == targets and truth.destination is not None
    candidates = read_targets(EXAMPLES / cell / "candidates.csv", dim, kind="candidate")
    assert not set(candidates.ids) & set(data.ids)
    if cell == "cell3d":
        assert {len(w) for w in data.working_repeats} == {3}   # measured 3 times each


def test_make_figure_draws_the_readme_figure(tmp_path):
    out = tmp_path / "figure.png"
    assert _module("make_figure").main(["--out", str(out)]) == 0
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert "docs/figures/cell3d_tre.png" in (ROOT / "README.md").read_text(encoding="utf-8")
    assert (ROOT / "docs" / "figures" / "cell3d_tre.png").is_file()


@pytest.mark.ros
def test_node_client_sends_every_row_in_metres():
    pytest.importorskip("rbc_registration_interfaces")
    client = _module("node_client")
    for cell in CELLS:
        path = EXAMPLES / cell / "fiducials.csv"
        data = read_fiducials(path)
        messages = client.pair_messages(str(path), 1e-3)
        assert len(messages) == sum(len(w) for w in data.working_repeats)
        first = messages[0]
        assert first.fiducial_id == data.ids[0]
        working = np.array([first.working_point.x, first.working_point.y,
                            first.working_point.z])
        expected = np.zeros(3)
        expected[:data.dimension] = np.asarray(data.working_repeats[0])[0] * 1e-3
        np.testing.assert_allclose(working, expected, rtol=0, atol=1e-15)
