"""Noise sigma from repeated measurements (paper section 4) and the rho decision rule (section 6).

Two conventions for the noise of one measurement, both reported by the model:

- ``sigma`` (the project's, used by rho): the RMS distance of one measurement from the true point,
  all axes together, sigma^2 = E||X - X_true||^2 (:func:`estimate_sigma`);
- ``sigma_axis``: the standard deviation per axis, sigma / sqrt(d) for isotropic noise.

rho = sigma_L0 / sigma (paper Table 1). Pure noise makes every pairwise mismatch L_ij (eq. 1) the
difference of two points' noise along the pair, of standard deviation sqrt(2) sigma_axis, so it
gives rho = sqrt(2 / d): 1 in 2D (0.82 in 3D), the paper's threshold below which correcting makes
registration worse. Taking sigma_axis for sigma instead inflates rho by sqrt(d) (pure noise then
gives 1.41): the paper does not say which convention its sigma uses, and the rho rule's answer
depends on it (an RA-like cell with 0.11 mm per axis has rho 1.8, "uncertain", in the point
convention, 2.5, "apply", if 0.11 mm were taken per point). The cross-validated decision
(:mod:`.decision`) needs neither.
"""

from __future__ import annotations

import math
from typing import NamedTuple, Optional, Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..constants import SigmaSource, check_rho_thresholds
from ..validation import as_points


class RepeatStats(NamedTuple):
    """What repeated measurements tell the model, per fiducial: ``counts`` n_j and
    ``variances`` sigma_j^2 = sum over axes of the sample variance (ddof = 1) of its working-frame
    measurements, NaN where n_j < 2. O(J) memory, however many repeats were taken."""

    counts: NDArray[np.int64]
    variances: NDArray[np.float64]

    def subset(self, index: ArrayLike) -> "RepeatStats":
        """The statistics of the fiducials ``index`` (indices or a boolean mask)."""
        return RepeatStats(self.counts[index], self.variances[index])


def axis_sigma(sigma: Optional[float], dim: int) -> Optional[float]:
    """sigma_axis = sigma / sqrt(d) (module docstring); None stays None."""
    return None if sigma is None else sigma / math.sqrt(dim)


def point_sigma(sigma_axis: Optional[float], dim: int) -> Optional[float]:
    """sigma = sigma_axis * sqrt(d) (module docstring); None stays None."""
    return None if sigma_axis is None else sigma_axis * math.sqrt(dim)


def repeat_stats(repeats: Sequence[ArrayLike], dim: Optional[int] = None) -> RepeatStats:
    """:class:`RepeatStats` of one (n_j, d) array of working-frame measurements per fiducial.

    :raises ValueError: on an empty group, NaN/inf or inconsistent dimensions.
    """
    counts, variances = [], []
    for k, group in enumerate(repeats):
        g = as_points(group, f"repeats of fiducial {k}", dim, 1)
        dim = g.shape[1]
        counts.append(len(g))
        # about the first measurement: identical repeats give exactly 0 (np.var's mean of equal
        # values can be off by an ulp: sigma 7e-14 mm, rho 9e11), and far from the origin the
        # differences keep their digits
        variances.append(float(np.sum(np.var(g - g[0], axis=0, ddof=1))) if len(g) >= 2
                         else np.nan)
    return RepeatStats(np.array(counts, dtype=np.int64), np.array(variances, dtype=np.float64))


def resolve_repeat_stats(count: int, dim: int, working_repeats: Optional[Sequence[ArrayLike]],
                         repeat_statistics: Optional[RepeatStats]
                         ) -> tuple[RepeatStats, Optional[float]]:
    """The :class:`RepeatStats` of ``count`` fiducials from their repeats, or as given, or one
    measurement each when neither is given; and sigma from them (None without repeats).

    :raises ValueError: when both are given or they do not match ``count`` fiducials.
    """
    if working_repeats is not None and repeat_statistics is not None:
        raise ValueError("give working_repeats or repeat_statistics, not both")
    if working_repeats is not None:
        if len(working_repeats) != count:
            raise ValueError(f"got repeats for {len(working_repeats)} fiducials, expected {count}")
        stats = repeat_stats(working_repeats, dim)
    elif repeat_statistics is not None:
        stats = RepeatStats(np.asarray(repeat_statistics.counts, dtype=np.int64),
                            np.asarray(repeat_statistics.variances, dtype=np.float64))
        if (stats.counts.shape != (count,) or stats.variances.shape != (count,)
                or (stats.counts < 1).any()):
            raise ValueError(f"repeat statistics must hold {count} counts >= 1 and {count} "
                             f"variances")
    else:
        stats = RepeatStats(np.ones(count, dtype=np.int64), np.full(count, np.nan))
    return stats, sigma_from_stats(stats)


#: When at least this share of the fiducials measured more than once have repeats identical to
#: their first measurement (a spread of exactly 0), :func:`identical_repeats` names them: copies,
#: or coordinates rounded coarser than the noise. By chance (rounding finer than the noise) a few
#: fiducials' repeats coincide, not half. sigma keeps them: with coarse rounding their zeros are
#: data (leaving them out made sigma 45 % too high on repeats rounded to 0.01 mm with 0.0035 mm
#: of noise), and which of the two causes it is, the statistics cannot tell.
COPIED_SHARE = 0.5


def copied_repeats(stats: RepeatStats) -> NDArray[np.bool_]:
    """Mask of the fiducials whose repeats are identical to their first measurement, when at
    least :data:`COPIED_SHARE` of the fiducials measured more than once are (all False
    otherwise: a few coincidences of rounded coordinates are noise)."""
    measured = stats.counts >= 2
    same = measured & (stats.variances == 0)
    if not same.any() or same.sum() < COPIED_SHARE * measured.sum():
        return np.zeros(len(stats.counts), dtype=bool)
    return same


def sigma_from_stats(stats: RepeatStats) -> Optional[float]:
    """sigma (see :func:`estimate_sigma`) from per-fiducial statistics; None without repeats
    (0 when every repeat is identical: :func:`~.model.build_model` then takes sigma as unknown,
    :func:`identical_repeats`)."""
    measured = stats.variances[stats.counts >= 2]
    if measured.size == 0:
        return None
    if not np.all(np.isfinite(measured)) or (measured < 0).any():
        raise ValueError("repeat variances must be finite and >= 0")
    return math.sqrt(float(np.mean(measured)))


#: A fiducial whose repeats scatter more than this many times the median fiducial's does is
#: named (:func:`scattered_repeats`): by chance a per-point scatter ten times the median is
#: below 1e-10 likely even for two measurements; one bad repeat makes it and dominates sigma.
SCATTER_FACTOR = 10.0
#: Fewer fiducials measured more than once give no median to compare with.
SCATTER_MIN_FIDUCIALS = 5


def scattered_repeats(ids: Sequence[str], stats: RepeatStats, unit: str) -> Optional[str]:
    """The warning for fiducials whose repeats scatter far more than the others' (a bad repeat
    within the outlier limit, e.g. 5 mm off on a 200 mm spacing), which raises sigma and so
    lowers rho; ``None`` when none stands out (:data:`SCATTER_FACTOR`).

    :param ids: the fiducials' ids; :param stats: their repeat statistics; :param unit: of the
        lengths, for the text.
    """
    measured = np.flatnonzero(stats.counts >= 2)
    if len(measured) < SCATTER_MIN_FIDUCIALS:
        return None
    variances = stats.variances[measured]
    spread = np.sqrt(np.maximum(variances, 0.0))
    median = float(np.median(spread))
    wide = spread > SCATTER_FACTOR * median
    if median <= 0 or not wide.any():
        return None
    order = np.argsort(-spread[wide])
    named = ", ".join(f"{ids[k]!r} ({s:.4g} {unit})" for k, s in
                      zip(measured[wide][order][:5], spread[wide][order][:5]))
    more = f" and {int(wide.sum()) - 5} more" if wide.sum() > 5 else ""
    with_them = sigma_from_stats(stats)
    without = sigma_from_stats(stats.subset(np.setdiff1d(np.arange(len(stats.counts)),
                                                         measured[wide])))
    return (f"fiducial(s) {named}{more}: their repeats scatter over {SCATTER_FACTOR:g}x the "
            f"median of the {len(measured)} fiducials measured more than once ({median:.4g} "
            f"{unit}, root of the summed per-axis variances): a bad repeat? sigma is "
            f"{with_them:.4g} {unit} with them, {without:.4g} {unit} without, and rho follows "
            f"it: remove the bad measurement, or set the outlier distance below its offset")


def identical_repeats(stats: RepeatStats, sigma_source: str = SigmaSource.REPEATS.value) -> Optional[str]:
    """The warning when the repeats of fiducials are identical to their first measurement
    (:func:`copied_repeats`: at least :data:`COPIED_SHARE` of the fiducials measured more than
    once): a copied measurement or coordinates rounded coarser than the noise. With every
    fiducial's repeats identical :func:`~.model.build_model` takes sigma as unknown (a sigma of
    0 is refused when given); with most, sigma from the repeats is too small. ``None`` otherwise
    (or without repeats).

    :param sigma_source: the model's (:class:`~.constants.SigmaSource`): when sigma was given
        the text says it is used, not that it is unknown or too small.
    """
    copied = int(copied_repeats(stats).sum())
    if not copied:
        return None
    measured = int((stats.counts >= 2).sum())
    given = sigma_source == SigmaSource.GIVEN.value
    cause = "one measurement copied, or coordinates rounded coarser than the noise?"
    if copied == measured:
        head = (f"the repeats of all {measured} fiducial(s) measured more than once are "
                f"identical to their first measurement: no noise estimate ({cause})")
        return head + ("; the given sigma is used" if given
                       else ", sigma is taken as unknown; give the noise as sigma")
    return (f"the repeats of {copied} of the {measured} fiducials measured more than once are "
            f"identical to their first measurement ({cause}): "
            + ("the given sigma is used" if given else
               "sigma from these repeats is no noise estimate (too small if they are copies, "
               "mostly rounding if rounded); give the noise as sigma if it is known"))


def estimate_sigma(repeats: Sequence[ArrayLike]) -> Optional[float]:
    """Noise sigma from repeated measurements of fiducials (paper section 4).

    For every fiducial with n_j >= 2 measurements, sigma_j^2 is the sample variance of the point,
    1/(n_j - 1) sum_n ||X_j^(n) - mean_j||^2 (the trace of its covariance, all axes together);
    sigma^2 is the mean of sigma_j^2 over those fiducials. sigma is thus the RMS distance of one
    measurement from the true point; the noise per axis is sigma / sqrt(d). With this definition
    pure noise gives rho = sigma_L0 / sigma = 1 in 2D (0.82 in 3D), the paper's threshold.

    :param repeats: one array (n_j, d) of the working-frame measurements of each fiducial.
    :return: sigma (same unit as the points), or ``None`` when no fiducial was measured twice.
    :raises ValueError: on NaN/inf or inconsistent dimensions.
    """
    return sigma_from_stats(repeat_stats(repeats))


class Assessment(NamedTuple):
    """The rho rule: ``rho = sigma_L0 / sigma``; ``recommendation`` is one of
    ``apply`` (rho >= rho_apply), ``uncertain``, ``do_not_apply`` (rho < rho_reject) or
    ``unknown`` (no sigma)."""

    rho: Optional[float]
    recommendation: str


def assess(sigma_l0: float, sigma: Optional[float], rho_reject: float = 1.0,
           rho_apply: float = 2.5) -> Assessment:
    """Decide whether correcting is expected to help (paper section 6).

    :param sigma_l0: sigma_L of the uncorrected fiducials (eq. 7).
    :param sigma: noise sigma (:func:`estimate_sigma`), or ``None`` when unknown. A sigma of exactly 0 (identical
        repeats, which :func:`~.model.build_model` takes as no estimate) gives rho = inf.
    :param rho_reject: below this rho correcting makes registration worse (paper: 1).
    :param rho_apply: from this rho on correcting helps (paper: 2.5).
    :raises ValueError: on negative or non-finite values, or ``rho_reject > rho_apply``.
    """
    if not math.isfinite(sigma_l0) or sigma_l0 < 0:
        raise ValueError(f"sigma_L0 must be finite and >= 0, got {sigma_l0}")
    if not (math.isfinite(rho_reject) and math.isfinite(rho_apply)) or rho_reject < 0:
        raise ValueError(f"rho thresholds must be finite and >= 0, got {rho_reject}, {rho_apply}")
    check_rho_thresholds(rho_reject, rho_apply)
    if sigma is None:
        return Assessment(None, "unknown")
    if not math.isfinite(sigma) or sigma < 0:
        raise ValueError(f"sigma must be finite and >= 0, got {sigma}")
    rho = math.inf if sigma == 0 else sigma_l0 / sigma
    if rho >= rho_apply:
        return Assessment(rho, "apply")
    if rho < rho_reject:
        return Assessment(rho, "do_not_apply")
    return Assessment(rho, "uncertain")


def format_against(value: float, thresholds: Sequence[float], digits: int = 3) -> str:
    """``value`` to ``digits`` significant digits, or more when the rounded number would lie on
    the other side of a threshold than the value (``>=``, as the rho rule compares): 2.496
    against 2.5 shows as ``2.496``, not ``2.5``; the number shown agrees with the verdict."""
    text = f"{value:.{digits}g}"
    while math.isfinite(value) and digits < 17 and any(
            (float(text) >= t) != (value >= t) for t in thresholds):
        digits += 1
        text = f"{value:.{digits}g}"
    return text


def format_rho(rho: float, rho_reject: float = 1.0, rho_apply: float = 2.5,
               digits: int = 3) -> str:
    """rho as every report shows it: :func:`format_against` its rule's thresholds."""
    return format_against(rho, (rho_reject, rho_apply), digits)
