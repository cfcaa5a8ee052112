"""The planner's stopping rules and their verdict in one sentence (:func:`.planner.plan`).

Two rules, either of which says ``enough`` (lengths in the unit of the points):

- ``within`` (default 10 %): the expected median target error now is within ``within`` of what
  measuring every candidate is expected to give, ``now <= (1 + within) * with_all``: how close
  to the best the candidates allow. It needs ``with_all`` (computed up to
  :data:`.planner.ALL_CANDIDATES_MAX` fiducials + candidates).
- ``gain`` (default off): the best next unit (candidate, or group of candidates measured
  together) is expected to reduce the median by less than ``min_gain_fraction`` of it or by
  less than ``min_gain_length``. A myopic rule: many small gains can still add up.

Neither rule is applied while the plan is held back (the error model not yet trustworthy,
:mod:`.model_check`; the decision unsure whether to correct; the bias unresolved): the verdict
is then ``measure more`` with the reasons and what to measure, and nothing else.
"""

from __future__ import annotations

from typing import NamedTuple, Optional, Sequence

#: The rules, in the order ``enough_rule`` names them when both hold.
ENOUGH_RULES = ("within", "gain")


class Verdict(NamedTuple):
    """:ivar enough: a rule holds now (and nothing holds the plan back).
    :ivar rule: ``within``, ``gain``, ``within+gain`` (both), or None when not enough.
    :ivar reason: the verdict and why, one sentence that starts ``enough`` or ``measure more``.
    :ivar enough_after: how many suggestions to measure before a rule is expected to hold (0
        when ``enough``); None when not within the suggestions, or while held back.
    """

    enough: bool
    rule: Optional[str]
    reason: str
    enough_after: Optional[int]


def _pct(v: float) -> str:
    return f"{100 * v:g} %"


def rules_holding(before: float, gain: float, with_all: Optional[float], within: float,
                  min_gain_fraction: float, min_gain_length: float) -> list[str]:
    """The rules of :data:`ENOUGH_RULES` that hold at expected error ``before`` when the best
    next unit gains ``gain`` (None: no next unit)."""
    out = []
    if within > 0 and with_all is not None and before <= (1 + within) * with_all:
        out.append("within")
    threshold = max(min_gain_fraction * before, min_gain_length)
    if threshold > 0 and gain < threshold:
        out.append("gain")
    return out


def verdict(now: float, with_all: Optional[float], n_candidates: int, best: str, gain: float,
            after: Sequence[float], step_gains: Sequence[float], within: float,
            min_gain_fraction: float, min_gain_length: float, holds: Sequence[str],
            to_measure: str = "") -> Verdict:
    """The verdict of the rules (module docstring) on a plan.

    :param now: expected median target error now; ``with_all``: with every candidate measured.
    :param best: how to name the best next unit (e.g. ``candidate #3``, ``group 'pose07'``).
    :param gain: its expected gain.
    :param after: the expected error after each suggestion; ``step_gains``: the gain of the
        best unit at each step (``step_gains[0] == gain``).
    :param holds: why the plan is held back (empty: it is not).
    :param to_measure: what to measure to lift the holds (appended to their sentence).
    """
    if holds:
        what = f"; {to_measure}" if to_measure else ""
        return Verdict(False, None, f"measure more: {'; '.join(holds)}{what}; the stopping "
                                    f"rules apply once it is", None)
    rules = rules_holding(now, gain, with_all, within, min_gain_fraction, min_gain_length)
    above = (f"the expected median target error {now:.4g} is {100 * (now / with_all - 1):.1f} % "
             f"above the {with_all:.4g} expected with all {n_candidates} candidates measured"
             if with_all is not None and with_all > 0 else "")
    frac = gain / now if now > 0 else 0.0
    gained = (f"the best next {best} is expected to reduce it by {100 * frac:.2f} % "
              f"({gain:.4g})")
    if rules:
        parts = []
        if "within" in rules:
            parts.append(f"{above}, within {_pct(within)}")
        if "gain" in rules:
            limits = [_pct(min_gain_fraction)] if min_gain_fraction > 0 else []
            limits += [f"{min_gain_length:g}"] if min_gain_length > 0 else []
            parts.append(f"{gained}, less than {' or '.join(limits)}")
        return Verdict(True, "+".join(rules), "enough: " + "; and ".join(parts), 0)
    parts = []
    if within > 0 and above:
        parts.append(f"{above}, more than {_pct(within)}")
    elif within > 0:
        parts.append("the error with every candidate measured is not computed, so the within "
                     "rule cannot hold")
    parts.append(gained + (f", at least {_pct(min_gain_fraction)}"
                           if min_gain_fraction > 0 else ""))
    enough_after = None
    for i, value in enumerate(after, start=1):
        nxt = step_gains[i] if i < len(step_gains) else float("inf")
        if rules_holding(value, nxt, with_all, within, min_gain_fraction, min_gain_length):
            enough_after = i
            break
    tail = (f"; after the first {enough_after} suggestion(s) a rule is expected to hold"
            if enough_after is not None else "")
    return Verdict(False, None, "measure more: " + "; ".join(parts) + tail, enough_after)
