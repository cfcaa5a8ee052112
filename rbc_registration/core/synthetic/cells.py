"""Synthetic cells modelled on the paper's experiments (section 3), in millimetres.

- ``A``: 3D, 5 x 5 x 5 semi-regular grid over 3 m x 3 m x 1.8 m, 16 random targets, N repeats,
  noise sigma 0.06 mm, a smooth bias with sigma_L0 ~ 2.5 mm on averaged points (motion capture
  system A registered to a laser tracker, which is taken as truth).
- ``B``: the same geometry, sigma 0.16 mm, bias with sigma_L0 ~ 0.09 mm (system B).
- ``RA``: 2D, a 17 x 21 grid of holes 25 mm apart, 277 fiducials and 80 targets measured once by a
  robot arm with sigma 0.11 mm (52 fiducials measured 16 times to give sigma), a smooth bias with
  sigma_L0 ~ 0.28 mm on the single measurements (robot registered to the world frame).

The destination frame holds the true points. The working frame is the true points moved by a
rigid transform, plus a spatially smooth bias field (random low-frequency sinusoids scaled to the
wanted sigma_L0), plus Gaussian noise per measurement.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Optional

import numpy as np
from numpy.typing import NDArray

from ..constants import CELLS, MAX_REPEATS
from ..rigid.mismatch import sigma_l


@dataclass(frozen=True)
class CellSpec:
    """Parameters of a synthetic cell (mm)."""

    name: str
    dimension: int
    sigma: float            # noise of one measurement: RMS over all axes (per axis sigma/sqrt(d))
    sigma_l0: float         # wanted sigma_L of the fiducials as the paper computed it
    repeats: int            # N measurements of every point (A, B) or of the repeated subset (RA)
    sigma_l0_on_means: bool  # A, B: sigma_L0 of averaged points (bias only); RA: single ones


SPECS = {
    "A": CellSpec("A", 3, 0.06, 2.5, 200, True),
    "B": CellSpec("B", 3, 0.16, 0.09, 200, True),
    "RA": CellSpec("RA", 2, 0.11, 0.28, 16, False),
}


@dataclass(frozen=True)
class SyntheticCell:
    """A generated cell. Working-frame arrays hold every measurement; destination ones the truth.

    :ivar fiducial_measurements: per fiducial, (n_j, d) working-frame measurements.
    :ivar fiducial_truth: (J, d) destination-frame fiducials (noise- and bias-free).
    :ivar target_measurements: per target, (n_k, d) working-frame measurements.
    :ivar target_truth: (K, d) destination-frame targets.
    :ivar rotation, translation: the true ``destination = R @ (working - bias) + t``.
    """

    spec: CellSpec
    fiducial_ids: tuple[str, ...]
    fiducial_measurements: tuple[NDArray[np.float64], ...]
    fiducial_truth: NDArray[np.float64]
    target_ids: tuple[str, ...]
    target_measurements: tuple[NDArray[np.float64], ...]
    target_truth: NDArray[np.float64]
    rotation: NDArray[np.float64]
    translation: NDArray[np.float64]
    unit: str = "mm"
    #: (J, d) and (K, d): the points in the working frame with their bias, without noise
    fiducial_biased: Optional[NDArray[np.float64]] = None
    target_biased: Optional[NDArray[np.float64]] = None

    @property
    def fiducial_means(self) -> NDArray[np.float64]:
        return np.array([m.mean(axis=0) for m in self.fiducial_measurements])

    @property
    def fiducial_processed(self) -> NDArray[np.float64]:
        """The fiducials as the paper processed them: the means of the N measurements (A, B),
        or the single (first) measurement of every hole (RA: its repeats only give sigma)."""
        if self.spec.sigma_l0_on_means:
            return self.fiducial_means
        return np.array([m[0] for m in self.fiducial_measurements])

    @property
    def target_means(self) -> NDArray[np.float64]:
        return np.array([m.mean(axis=0) for m in self.target_measurements])


def random_rotation(rng: np.random.Generator, dim: int) -> NDArray[np.float64]:
    """A uniformly random proper rotation (dim x dim) drawn from ``rng``."""
    if dim == 2:
        a = rng.uniform(-np.pi, np.pi)
        return np.array([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]])
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q = q * np.sign(np.diag(r))
    return q if np.linalg.det(q) > 0 else -q


def _bias_field(rng: np.random.Generator, dim: int, extent: NDArray[np.float64], modes: int = 8):
    """A smooth random vector field: a sum of sinusoids with wavelengths of 1-3 cell extents."""
    scale = float(np.max(extent))
    freq = rng.normal(size=(modes, dim))
    freq /= np.linalg.norm(freq, axis=1, keepdims=True)
    freq *= 2 * np.pi / (scale * rng.uniform(1.0, 3.0, size=(modes, 1)))
    phase = rng.uniform(0, 2 * np.pi, size=modes)
    amp = rng.normal(size=(modes, dim))

    def field(p: NDArray[np.float64]) -> NDArray[np.float64]:
        return np.sin(p @ freq.T + phase) @ amp

    return field


def _layout(rng: np.random.Generator, spec: CellSpec) -> tuple:
    """The cell's extent, true fiducial and target points and their repeat counts: the A-like
    volume (a semi-regular 5 x 5 x 5 grid, 16 targets) or the RA-like plate (holes 25 mm apart,
    80 of them targets, 52 fiducial holes measured ``spec.repeats`` times)."""
    if spec.dimension == 3:
        extent = np.array([3000.0, 3000.0, 1800.0])
        axes = [np.linspace(0, e, 5) for e in extent]
        grid = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
        grid += rng.uniform(-0.08, 0.08, size=grid.shape) * extent / 4   # semi-regular
        fid_true = grid
        tgt_true = rng.uniform(0.08, 0.92, size=(16, 3)) * extent
        fid_n = np.full(len(fid_true), spec.repeats)
        tgt_n = np.full(len(tgt_true), spec.repeats)
    else:
        extent = np.array([400.0, 500.0])
        holes = np.stack(np.meshgrid(np.arange(17) * 25.0, np.arange(21) * 25.0, indexing="ij"),
                         -1).reshape(-1, 2)
        inner = np.flatnonzero((holes > 0).all(axis=1) & (holes < extent).all(axis=1))
        targets = np.sort(rng.choice(inner, size=80, replace=False))
        fiducials = np.setdiff1d(np.arange(len(holes)), targets)
        fid_true, tgt_true = holes[fiducials], holes[targets]
        fid_n = np.ones(len(fid_true), dtype=int)
        fid_n[rng.choice(len(fid_true), size=52, replace=False)] = spec.repeats
        tgt_n = np.ones(len(tgt_true), dtype=int)
    return extent, fid_true, tgt_true, fid_n, tgt_n


def make_cell(name: str, seed: int = 0, repeats: Optional[int] = None) -> SyntheticCell:
    """Generate the synthetic cell ``name`` (``"A"``, ``"B"`` or ``"RA"``).

    :param seed: random seed; the same seed gives the same cell.
    :param repeats: override the number N of repeated measurements.
    :raises ValueError: on an unknown cell name.
    """
    if name not in SPECS:
        raise ValueError(f"cell must be one of {CELLS}, got {name!r}")
    spec = SPECS[name]
    if repeats is not None:
        if not 1 <= repeats <= MAX_REPEATS:
            raise ValueError(f"repeats must be in [1, {MAX_REPEATS}], got {repeats}")
        spec = CellSpec(spec.name, spec.dimension, spec.sigma, spec.sigma_l0, repeats,
                        spec.sigma_l0_on_means)
    rng = np.random.default_rng([seed, CELLS.index(name)])
    d = spec.dimension
    extent, fid_true, tgt_true, fid_n, tgt_n = _layout(rng, spec)

    rot = random_rotation(rng, d)
    trans = rng.uniform(-1000, 1000, size=d)
    field = _bias_field(rng, d, extent)
    noise_rng = np.random.default_rng([seed, CELLS.index(name), 1])
    axis_sigma = spec.sigma / math.sqrt(d)
    fid_noise = [noise_rng.normal(0, axis_sigma, size=(n, d)) for n in fid_n]
    tgt_noise = [noise_rng.normal(0, axis_sigma, size=(n, d)) for n in tgt_n]

    def working(true: NDArray[np.float64], amp: float) -> NDArray[np.float64]:
        return (true - trans) @ rot + amp * field(true)      # R^T (Y - t) + bias

    # Scale the bias so that sigma_L0 of the fiducials as the paper computed it (on the means
    # for A and B, bias only; on the single measurements for RA, the first of a repeated hole:
    # SyntheticCell.fiducial_processed) hits the wanted value.
    if spec.sigma_l0_on_means:
        fid_noise_seen = np.zeros((len(fid_true), d))
    else:
        fid_noise_seen = np.array([nz[0] for nz in fid_noise])
    noise_part = sigma_l(working(fid_true, 0.0) + fid_noise_seen, fid_true)
    want = math.sqrt(max(spec.sigma_l0 ** 2 - noise_part ** 2, 1e-30))
    amp = 1.0
    for _ in range(30):
        got = sigma_l(working(fid_true, amp) + fid_noise_seen, fid_true)
        bias_part = math.sqrt(max(got ** 2 - noise_part ** 2, 1e-30))
        amp *= want / bias_part
        if abs(got / spec.sigma_l0 - 1) < 1e-4:
            break

    def to_working(true: NDArray[np.float64], noise: list) -> tuple[NDArray[np.float64], ...]:
        return tuple(b + nz for b, nz in zip(working(true, amp), noise))

    return SyntheticCell(
        spec,
        tuple(f"F{k:03d}" for k in range(len(fid_true))),
        to_working(fid_true, fid_noise),
        fid_true,
        tuple(f"T{k:02d}" for k in range(len(tgt_true))),
        to_working(tgt_true, tgt_noise),
        tgt_true,
        rot,
        trans,
        fiducial_biased=working(fid_true, amp),
        target_biased=working(tgt_true, amp),
    )
