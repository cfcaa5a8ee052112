"""Cross-validation of the candidates on the fiducials, needing no sigma and no targets.

The fiducials are split into folds (:func:`fold_scheme`): leave-one-out up to
:data:`LOO_MAX_FIDUCIALS` fiducials, :data:`K_FOLDS`-fold above (the cost grows with the number of
folds: every fold repeats the restoration and the interpolation). Each fold's fiducials are held
out and predicted as targets from a model built without them: their working-frame points are
mapped into the destination frame and compared with their destination-frame points (eq. 3). Per
fold, everything the prediction uses is refitted on the kept fiducials only:

- ``uncorrected``: the rigid registration {R_u, tau_u} (eq. 2);
- ``paper`` and ``kriging``: the restoration (eq. 4), the corrected registration {R_c, tau_c} and
  the interpolation of the fold's own corrections to the held-out points (eq. 5-6).

Kriging conditions the Gaussian process exactly on the kept fiducials' corrections (the closed-form
GP prediction from the precision matrix, :meth:`KrigingInterpolator.held_out`; above
:data:`~.kriging.EXACT_MAX_FIDUCIALS` the summary's predictor, :mod:`.kriging_summary`), with the
hyper-parameters of the fit to all fiducials. That is the only information that leaks from a
held-out fiducial into its prediction: three scalars (s, l, sigma) fitted to J d correction values,
on which one fiducial has an influence of order 1/J, and which enter the prediction smoothly (the
posterior mean is flat near the likelihood's optimum). The optimism this causes is of the order of
3 / (J d) of the squared error, below 1 % in RMS for J >= 50 in 2D; `test_crossval.py` checks it
against hyper-parameters refitted in every fold.

Subsets of fiducials for the registrations (``uncorrected_subset``, ``corrected_subset``) are kept
as far as they are in the fold; a fold that leaves too few of them to fix a registration uses all
kept fiducials.
"""

from __future__ import annotations

from concurrent.futures import Future, ThreadPoolExecutor
from typing import Callable, Mapping, NamedTuple, Optional, Sequence, TypeVar, Union

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..constants import CANDIDATES, INTERPOLATIONS, UNCORRECTED, FoldKind
from ..interpolation.paper import PaperInterpolator
from ..interpolation.kriging import KrigingInterpolator
from .groups import first_members, merge_labels
from ..rigid.registration import Registration, rigid_fit
from ..repeats import twin_groups
from ..rigid.restoration import restore_rigid_body
from ..validation import as_point_pairs, rounding

T = TypeVar("T")

#: Leave-one-out up to this many fiducials (J folds: at J = 277 in 2D about a second for all
#: candidates); above it, :data:`K_FOLDS` folds.
LOO_MAX_FIDUCIALS = 300
#: Number of folds above :data:`LOO_MAX_FIDUCIALS`.
K_FOLDS = 10


class FoldScheme(NamedTuple):
    """How the fiducials are split: ``kind`` one of :class:`~.constants.FoldKind` and the number
    of folds (J for leave-one-out)."""

    kind: str
    n_folds: int
    #: whether groups of fiducials are held out whole (:mod:`.groups`)
    grouped: bool = False

    def describe(self) -> str:
        """E.g. ``leave-one-out (277 folds)``, ``leave-one-group-out (36 folds)`` or
        ``10-fold``."""
        if self.kind == FoldKind.LEAVE_ONE_OUT.value:
            kind = "leave-one-group-out" if self.grouped else self.kind
            return f"{kind} ({self.n_folds} folds)"
        return f"{self.n_folds}-fold" + (" (whole groups)" if self.grouped else "")


def fold_scheme(count: int) -> FoldScheme:
    """The size rule: leave-one-out for ``count`` <= :data:`LOO_MAX_FIDUCIALS` fiducials,
    else :data:`K_FOLDS`-fold."""
    if count <= LOO_MAX_FIDUCIALS:
        return FoldScheme(FoldKind.LEAVE_ONE_OUT.value, count)
    return FoldScheme(FoldKind.K_FOLD.value, K_FOLDS)


def held_out_units(working: NDArray[np.float64], destination: Optional[NDArray[np.float64]],
                   groups: Optional[NDArray[np.intp]] = None) -> Optional[NDArray[np.intp]]:
    """The units held out together, as labels (J,): the given ``groups``
    (:func:`~.groups.group_labels`) joined with one point under several ids
    (:func:`~.repeats.twin_groups`, with ``destination``); ``None`` when every fiducial is its
    own unit."""
    twins = twin_groups(working, destination) if destination is not None else []
    return merge_labels(groups, twins, len(working))


def fold_groups(working: NDArray[np.float64], scheme: FoldScheme,
                destination: Optional[NDArray[np.float64]] = None,
                groups: Optional[NDArray[np.intp]] = None) -> list[NDArray[np.intp]]:
    """The index sets held out together. k-fold: the fiducials ranked by distance from their
    centroid (stable for ties), rank r in fold r mod k, so every fold spans the cell and the split
    does not depend on the order of the fiducials nor on a rigid motion of either frame.

    A unit of :func:`held_out_units` (a given group, one point under several ids) is held out
    together: leave-one-out leaves the unit out (leave-one-group-out), k-fold puts it in the
    fold of its first fiducial.
    """
    j = len(working)
    units = held_out_units(working, destination, groups)
    first = np.arange(j) if units is None else first_members(units)
    if scheme.kind == FoldKind.LEAVE_ONE_OUT.value:
        return [np.flatnonzero(first == k) for k in range(j) if first[k] == k]
    radius = np.linalg.norm(working - working.mean(axis=0), axis=1)
    rank = np.empty(j, dtype=np.intp)
    rank[np.argsort(radius, kind="stable")] = np.arange(j)
    fold = (rank % scheme.n_folds)[first]
    return [np.flatnonzero(fold == f) for f in range(scheme.n_folds)]


class CrossValidation(NamedTuple):
    """Held-out errors per fiducial (unit of the points).

    :ivar scheme: the :class:`FoldScheme` used.
    :ivar errors: per candidate evaluated, (J,) distance in the destination frame between the
        prediction of each held-out fiducial and its destination point (eq. 3).
    :ivar scale: (J,) kriging's predictive standard deviation per axis of each held-out fiducial
        (:meth:`KrigingInterpolator.held_out`), when a kriging model was given; else None.
    :ivar unavailable: candidates that could not be cross-validated, with the reason.
    :ivar resolution: :data:`.validation.RESOLUTION` x the largest coordinate: differences of
        held-out errors below it are rounding, not accuracy (0: unknown).
    :ivar units: (J,) labels of the units held out together (:func:`held_out_units`: given
        groups, one point under several ids); ``None`` when every fiducial is its own unit. The
        paired test compares one mean error per unit, the bound weighs every unit alike.
    """

    scheme: FoldScheme
    errors: Mapping[str, NDArray[np.float64]]
    scale: Optional[NDArray[np.float64]]
    unavailable: Mapping[str, str]
    resolution: float = 0.0
    units: Optional[NDArray[np.intp]] = None

    @property
    def n_units(self) -> int:
        """The number of units held out (groups; fiducials without groups)."""
        if self.units is None:
            return max((len(e) for e in self.errors.values()), default=0)
        return int(self.units.max()) + 1 if self.units.size else 0


def minimum_fiducials(dimension: int) -> int:
    """Fewest fiducials to cross-validate: every fold keeps d + 1 to restore the RBC (eq. 4)."""
    return dimension + 2


def _fit(x: NDArray[np.float64], y: NDArray[np.float64], kept: NDArray[np.intp],
         subset: Optional[Sequence[int]]) -> Registration:
    if subset is not None:
        local = np.flatnonzero(np.isin(kept, np.asarray(subset)))
        try:
            return rigid_fit(x[local], y[local])
        except ValueError:
            pass                            # the fold left too few of the subset
    return rigid_fit(x, y)


def loo_rigid_errors(working: NDArray[np.float64], destination: NDArray[np.float64]
                     ) -> Optional[NDArray[np.float64]]:
    """Leave-one-out errors of the rigid registration (eq. 2, 3) for all fiducials at once.

    The fit without fiducial j follows from the moments of all fiducials minus j's own
    (centroids and cross-covariance, Arun eq. 11), one batched SVD for all J fits. Same result
    as :func:`~.registration.rigid_fit` on each fold; ``None`` when a fold is degenerate (then
    the caller fits fold by fold and gets the reason).
    """
    j, d = working.shape
    x = working - working.mean(axis=0)          # centred: the downdates stay well conditioned
    y = destination - destination.mean(axis=0)
    n = j - 1
    cx = -x / n                                  # centroids of the others (the sums are 0)
    cy = -y / n
    h = (x.T @ y)[None] - x[:, :, None] * y[:, None, :] - n * cx[:, :, None] * cy[:, None, :]
    u, sv, vt = np.linalg.svd(h)
    if (sv[:, d - 2] <= 1e-9 * sv[:, 0]).any() or (sv[:, 0] <= 0).any():
        return None
    flip = np.sign(np.linalg.det(np.transpose(vt, (0, 2, 1)) @ np.transpose(u, (0, 2, 1))))
    flip[flip == 0] = 1.0
    s = np.broadcast_to(np.eye(d), (j, d, d)).copy()
    s[:, -1, -1] = flip
    r = np.transpose(vt, (0, 2, 1)) @ s @ np.transpose(u, (0, 2, 1))   # Umeyama: det(R) = +1
    pred = np.einsum("jkl,jl->jk", r, x - cx) + cy
    return np.linalg.norm(pred - y, axis=1)


def in_thread(work: Callable[[], T], name: str) -> "Future[T]":
    """``work()`` started in a thread of its own (named ``name``); its ``Future``."""
    pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix=name)
    job = pool.submit(work)
    pool.shutdown(wait=False)
    return job


def _held_out(kriging: Union[None, KrigingInterpolator, Future],
              groups: Sequence[NDArray[np.intp]]) -> Optional[Callable[[], list]]:
    """``kriging.held_out(groups)`` as a call that returns it. A kriging model above the exact
    threshold (the summary's held-out predictions, ~1 s of GIL-free numpy at J = 5,000), or one
    still being built (a ``Future``, :func:`~.model.build_model`), is worked on in a thread beside
    the folds' restorations and paper interpolations, which need none of it."""
    if kriging is None:
        return None
    if isinstance(kriging, KrigingInterpolator) and kriging.summary is None:
        result = kriging.held_out(groups)
        return lambda: result
    model = kriging.result if isinstance(kriging, Future) else lambda: kriging
    return in_thread(lambda: model().held_out(groups), "rbc_held_out").result


def cross_validate(working: ArrayLike, destination: ArrayLike,
                   candidates: Sequence[str] = CANDIDATES, *, restoration: str = "iterative",
                   steps: int = 2, uncorrected_subset: Optional[Sequence[int]] = None,
                   corrected_subset: Optional[Sequence[int]] = None,
                   kriging: Union[None, KrigingInterpolator, Future] = None,
                   scheme: Optional[FoldScheme] = None,
                   groups: Optional[NDArray[np.intp]] = None) -> CrossValidation:
    """Held-out errors of each candidate (module docstring).

    :param working: fiducials in the working frame X (J, d).
    :param destination: the same fiducials in the destination frame Y (J, d).
    :param candidates: among :data:`~.constants.CANDIDATES`.
    :param restoration: restoration method of every fold (``iterative`` or ``closed-form``).
    :param steps: iterative steps.
    :param uncorrected_subset: indices the uncorrected registration is fitted to (None: all).
    :param corrected_subset: indices the corrected registration is fitted to (None: all).
    :param kriging: the kriging interpolator fitted to all fiducials (its hyper-parameters and
        covariance); needed for the ``kriging`` candidate and for ``scale``. Or a ``Future`` of
        it (:func:`~.model.build_model` builds one above the exact threshold in a thread beside
        the folds); when it fails with ValueError, kriging is unavailable with that reason.
    :param scheme: the folds; default :func:`fold_scheme` of the number of units.
    :param groups: (J,) group labels (:func:`~.groups.group_labels`): a group is held out
        whole (leave-one-group-out, or k folds of groups); ``None``: no groups.
    :return: :class:`CrossValidation`; a candidate that fails (too few fiducials, degenerate
        geometry in a fold) is listed in ``unavailable`` with the reason.
    :raises ValueError: on bad input or an unknown candidate.
    """
    x, y = as_point_pairs(working, destination)
    j, d = x.shape
    unknown = [c for c in candidates if c not in CANDIDATES]
    if unknown:
        raise ValueError(f"candidates must be among {CANDIDATES}, got {unknown}")
    if groups is not None and len(groups) != j:
        raise ValueError(f"got {len(groups)} group labels for {j} fiducials")
    # without groups, twins are held out together but each fiducial stays a unit of the tests
    units = held_out_units(x, y, groups) if groups is not None else None
    n_units = j if units is None else int(units.max()) + 1
    scheme = (scheme or fold_scheme(n_units))._replace(grouped=units is not None)
    unavailable: dict[str, str] = {}
    if j < minimum_fiducials(d):
        why = f"cross-validation needs at least {minimum_fiducials(d)} fiducials, got {j}"
        return CrossValidation(scheme, {}, None, {c: why for c in candidates})
    if units is not None and n_units < 3:
        why = f"cross-validation needs at least 3 groups, got {n_units}"
        return CrossValidation(scheme, {}, None, {c: why for c in candidates}, units=units)
    if "kriging" in candidates and kriging is None:
        unavailable["kriging"] = "no kriging model"
    groups = fold_groups(x, scheme, y, groups)
    if scheme.kind == FoldKind.LEAVE_ONE_OUT:   # units held out together: fewer folds than J
        scheme = scheme._replace(n_folds=len(groups))
    held_out = _held_out(kriging, groups)
    errors = {c: np.full(j, np.nan) for c in candidates if c not in unavailable}
    fast_u = None
    if (UNCORRECTED in errors and uncorrected_subset is None
            and scheme.kind == FoldKind.LEAVE_ONE_OUT and len(groups) == j):  # one per fold
        fast_u = loo_rigid_errors(x, y)
        if fast_u is not None:
            errors[UNCORRECTED][:] = fast_u
    kriging_folds, reached = _fold_errors(x, y, groups, errors, unavailable, fast_u is None,
                                          restoration, steps, uncorrected_subset,
                                          corrected_subset)
    scale = None if held_out is None else _kriging_errors(x, y, groups[:reached], held_out,
                                                          kriging_folds, errors, unavailable)
    for c in unavailable:
        errors.pop(c, None)
    for e in errors.values():
        e.setflags(write=False)
    if scale is not None:
        scale.setflags(write=False)
    return CrossValidation(scheme, errors, scale, unavailable, rounding(x, y), units)


def _fold_errors(x: NDArray[np.float64], y: NDArray[np.float64], groups: list,
                 errors: dict[str, NDArray[np.float64]], unavailable: dict[str, str],
                 fit_uncorrected: bool, restoration: str, steps: int,
                 uncorrected_subset: Optional[Sequence[int]],
                 corrected_subset: Optional[Sequence[int]]) -> tuple[list, int]:
    """Each fold's held-out errors of ``uncorrected`` (when ``fit_uncorrected``) and ``paper``
    into ``errors``; a candidate that fails goes to ``unavailable``. Returns the kriging folds
    still to evaluate, (fold, eps of the kept fiducials, R_c), and the folds reached."""
    j = len(x)
    corrected = [c for c in errors if c in INTERPOLATIONS]
    kriging_folds = []
    reached = 0
    for f, held in enumerate(groups):
        reached = f + 1
        kept = np.setdiff1d(np.arange(j), held)
        xk, yk, xs, ys = x[kept], y[kept], x[held], y[held]
        if UNCORRECTED in errors and fit_uncorrected:
            try:
                reg = _fit(xk, yk, kept, uncorrected_subset)
            except ValueError as exc:          # the kept fiducials cannot fix a registration
                unavailable.update({c: f"fold {f + 1}: {exc}" for c in errors})
                break
            errors[UNCORRECTED][held] = np.linalg.norm(reg.apply(xs) - ys, axis=1)
        if not corrected:
            continue
        try:
            eps = restore_rigid_body(xk, yk, restoration, steps, compute_sigma_l=False).corrections
            reg_c = _fit(xk - eps, yk, kept, corrected_subset)
        except (ValueError, np.linalg.LinAlgError) as exc:
            unavailable.update({c: f"fold {f + 1}: {exc}" for c in corrected})
            corrected = []
            continue
        if "kriging" in corrected:
            kriging_folds.append((f, eps, reg_c))
        if "paper" in corrected:
            try:
                eps_s = PaperInterpolator(xk, eps)(xs).correction
            except (ValueError, np.linalg.LinAlgError) as exc:
                unavailable["paper"] = f"fold {f + 1}: {exc}"
                corrected.remove("paper")
                continue
            errors["paper"][held] = np.linalg.norm(reg_c.apply(xs - eps_s) - ys, axis=1)
    return kriging_folds, reached


def _kriging_errors(x: NDArray[np.float64], y: NDArray[np.float64], groups: list,
                    held_out: Callable[[], list], kriging_folds: list,
                    errors: dict[str, NDArray[np.float64]],
                    unavailable: dict[str, str]) -> Optional[NDArray[np.float64]]:
    """The kriging folds' held-out errors into ``errors`` from the held-out predictors, and the
    kriging scale per fiducial of the folds in ``groups`` (NaN elsewhere); None when the
    kriging model could not be built (its reason in ``unavailable``)."""
    try:
        predictors = held_out()
    except ValueError as exc:          # a kriging model built in a thread could not be
        unavailable["kriging"] = str(exc)
        return None
    scale = np.full(len(x), np.nan)
    for f, held in enumerate(groups):
        scale[held] = predictors[f][1]
    for f, eps, reg_c in kriging_folds:
        held = groups[f]
        try:
            eps_s = predictors[f][0] @ eps
        except (ValueError, np.linalg.LinAlgError) as exc:
            unavailable["kriging"] = f"fold {f + 1}: {exc}"
            break
        errors["kriging"][held] = np.linalg.norm(reg_c.apply(x[held] - eps_s) - y[held], axis=1)
    return scale
