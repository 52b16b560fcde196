"""The result of calibrating one channel: every calibration's scores, and which to write.

Every calibration a channel can be written with (the physical model, the paper's line, a
monotone lookup, every static curve with every drift form) is scored the way the gateway will
read it (``Score``): held-out force RMS against the reference the channel will be compared with
(F_ref), and the held-out hold drift in two groups (``holds.hold_drifts``: right after a higher
load, and the others; % of full scale). ``Calibration.best`` is the best on held-out force among
the *writable* ones: the static lookup (a user's own table, the reference), a static curve whose
hold drift in neither group exceeds the lookup's, and a dynamic one whose hold drift in neither
group exceeds the best static rival's or the lookup's. The comparison is strict: a calibration
that holds a load worse than the lookup would, by any amount, is never written, and a drift
correction that makes holds worse than a static curve would is never written either.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from ..keys import Choice
from .calibration_range import model_force_range, widened_range_n
from .candidates import Candidate
from .fitting import FitResult
from .holds import DriftGroups
from .measurement import NoiseModel
from .objectives import OFFSET, Objective
from .rivals import Rivals

__all__ = [
    "OBJECTIVE_OPTIONS",
    "OBJECTIVE_WORDS",
    "STATIC_RIVALS",
    "Calibration",
    "CalibrationModel",
    "Objective",
    "OffsetMode",
    "Score",
]


class CalibrationModel(Choice):
    """What a calibration file gives a channel: the physical model, the conductance line, a
    monotone lookup, the best static curve with drift correction, or whichever of them reads
    held-out force best."""

    PHYSICS = "physics"
    LINE = "line"
    LOOKUP = "lookup"
    CURVE = "curve"
    AUTO = "auto"


class OffsetMode(Choice):
    """The reference-force zero offset: fit it and keep it only if it helps, fit it, or none."""

    AUTO = "auto"
    FIT = "fit"
    NONE = "none"


#: an objective by its command-line spelling (``log-r``)
OBJECTIVE_OPTIONS = {o.option: o for o in Objective}
OBJECTIVE_WORDS: dict[str, str] = {Objective.LOG_R: "log-R", Objective.FORCE: "force"}


#: The names of the static rivals every report compares with (besides static curves).
STATIC_RIVALS = ("line", "lookup")


def _pct(value: float) -> str:
    return "-" if not math.isfinite(value) else f"{value:.2f}"


def _none_if_nan(value: float) -> float | None:
    return None if not math.isfinite(value) else value


@dataclass(frozen=True)
class Score:
    """One calibration as the gateway will read it: held-out force RMS (N, against F_ref),
    held-out hold drift in two groups (% FS), its parameters, whether it carries dynamics."""

    name: str
    held_out_force_rms_n: float
    drift: DriftGroups
    n_parameters: int
    dynamic: bool

    def as_dict(self, writable: bool) -> dict[str, Any]:
        return {
            "name": self.name,
            "held_out_force_rms_n": _none_if_nan(self.held_out_force_rms_n),
            "hold_drift_pct_fs": _none_if_nan(self.drift.worst_pct_fs),
            "hold_drift_after_higher_pct_fs": _none_if_nan(self.drift.after_higher_pct_fs),
            "hold_drift_others_pct_fs": _none_if_nan(self.drift.others_pct_fs),
            "holds": {"after_higher": self.drift.after_higher_holds, "others": self.drift.other_holds},
            "parameters": self.n_parameters,
            "dynamic": self.dynamic,
            "writable": writable,
        }


def _key(value: float) -> float:
    return value if math.isfinite(value) else math.inf


@dataclass(frozen=True)
class Calibration:
    """Result of calibrating one channel."""

    channel: str
    record: str
    fit: FitResult
    rivals: Rivals
    unusable: dict[str, int]
    noise: NoiseModel
    noise_floor_log: float
    noise_floor_force_n: float
    force_range_n: tuple[float, float]  # the physical model's: the record's range + offset
    configured_range_n: tuple[float, float]
    rows_outside_configured: int
    fit_before: FitResult | None = None  # the fit without hysteresis, when hysteresis was tried
    #: the other objective's best fit (None when only one objective was fitted)
    other: FitResult | None = None
    objective_mode: str = "log_r"
    offset_mode: str = "none"
    record_range_n: tuple[float, float] = (math.nan, math.nan)  # the record's loaded range, as F_ref
    notes: tuple[str, ...] = field(default=())
    warnings: tuple[str, ...] = field(default=())
    #: every static curve with every drift form (``candidates``), best held-out force first
    candidates: tuple[Candidate, ...] = field(default=())
    #: every calibration scored as the gateway reads it (physics, line, lookup, every curve)
    scores: tuple[Score, ...] = field(default=())
    #: how far beyond the record's lowest and highest force the model reads the record's own
    #: end loads (N, ``end_noise_margin_n``: bias + 3 sigma): the calibrated range reaches this
    #: far beyond the record's, so that a reading of an end load is not flagged extrapolated
    #: for its noise alone
    range_margin_n: tuple[float, float] = (0.0, 0.0)
    #: the load the record starts at (N; 0 when it starts at rest)
    starting_load_n: float = 0.0
    #: the held-out rows every calibration is scored on (the physical model may be fitted on fewer)
    held_out_rows: int = 0

    def calibrated_range_n(self, kind: str = "physics") -> tuple[float, float]:
        """The range written as ``calibrated_min_n``/``calibrated_max_n`` (N) for a channel
        read with ``kind``: the physical model's range (the record's + the zero offset) or,
        for a rival (which reads F_ref), the record's, widened at each end by
        ``range_margin_n`` (the low end never below half of itself)."""
        return widened_range_n(
            self.force_range_n if kind == "physics" else self.record_range_n, self.range_margin_n
        )

    @property
    def line_force_rms_n(self) -> float:
        return self.rivals.line_force_rms_n

    def score(self, name: str) -> Score | None:
        return next((s for s in self.scores if s.name == name), None)

    @property
    def hold_drift_pct_fs(self) -> Mapping[str, float]:
        """Per calibration name: the larger of its two held-out hold drifts (% FS)."""
        return {s.name: s.drift.worst_pct_fs for s in self.scores}

    def force_rms(self) -> dict[str, float]:
        """Held-out force RMS (N) of every calibration, by name."""
        return {s.name: s.held_out_force_rms_n for s in self.scores}

    def n_parameters(self) -> dict[str, int]:
        return {s.name: s.n_parameters for s in self.scores}

    def ranking(self) -> list[Score]:
        """Every calibration, best held-out force first (the fewer parameters on a tie)."""
        return sorted(self.scores, key=lambda s: (_key(s.held_out_force_rms_n), s.n_parameters))

    def static_drift_reference(self, dynamic: bool = True) -> tuple[float, float]:
        """The held-out hold drift a calibration must not exceed, per group (% FS): for a dynamic
        one the smaller of the best static rival's (best held-out force among the static
        calibrations) and the static lookup's; for a static one the lookup's. NaN where none has
        a hold in that group."""
        rivals = [self.score("lookup")] + ([self.best_static()] if dynamic else [])
        out = []
        for group in (0, 1):
            finite = [v for s in rivals if s is not None and math.isfinite(v := s.drift.all_pct_fs[group])]
            out.append(min(finite) if finite else math.nan)
        return out[0], out[1]

    def drifts_more(self, score: Score) -> bool:
        """Whether ``score``'s held-out hold drift exceeds its ``static_drift_reference`` in
        either group, by any amount (never the lookup's own: it is the reference)."""
        if score.name == "lookup":
            return False
        reference = self.static_drift_reference(score.dynamic)
        return any(
            math.isfinite(ref) and math.isfinite(mine) and mine > ref
            for mine, ref in zip(score.drift.all_pct_fs, reference, strict=True)
        )

    def writable(self) -> list[Score]:
        """The calibrations ``--model auto`` may write, best held-out force first: the lookup, and
        every other one that does not drift more than its static reference (``drifts_more``)."""
        return [s for s in self.ranking() if not self.drifts_more(s)]

    @property
    def best(self) -> str:
        """The writable calibration that reads held-out force best (``writable``)."""
        options = self.writable() or self.ranking()
        return options[0].name

    def best_static(self) -> Score | None:
        """The static calibration that reads held-out force best (line, lookup, a static curve)."""
        static = [s for s in self.ranking() if not s.dynamic]
        return static[0] if static else None

    def candidate(self, name: str) -> Candidate | None:
        return next((c for c in self.candidates if c.name == name), None)

    @property
    def verdict(self) -> str:
        """Plain words: the calibration written against the best static rival, on held-out force."""
        best = self.score(self.best)
        rival = self.best_static()
        if best is None or rival is None or not math.isfinite(rival.held_out_force_rms_n):
            return "the calibrations cannot be compared on these rows"
        if best.name == rival.name:
            return (
                f"the best static rival is written: {rival.name}, {rival.held_out_force_rms_n:.4g} N "
                "on held-out force"
            )
        a, b = best.held_out_force_rms_n, rival.held_out_force_rms_n
        words = (
            f"{best.name} reads held-out force at {a:.4g} N against the best static rival "
            f"({rival.name}) at {b:.4g} N"
        )
        if a > b and self.drifts_more(rival):
            after, others = rival.drift.all_pct_fs
            ref_after, ref_others = self.static_drift_reference(dynamic=False)
            words += (
                f", not written: its held-out holds drift more than the lookup's ({_pct(after)} "
                f"against {_pct(ref_after)} % FS after a higher load, {_pct(others)} against "
                f"{_pct(ref_others)} elsewhere)"
            )
        return words

    def offset_dict(self) -> dict[str, Any]:
        """The reference zero offset: fitted or not, value and 95 % interval."""
        out: dict[str, Any] = {"mode": self.offset_mode, "fitted": False, "value_n": self.fit.force_offset_n}
        try:
            e = self.fit.estimate(OFFSET)
        except KeyError:
            return out
        out.update(fitted=e.fitted, value_n=e.value, ci95_low=e.low, ci95_high=e.high)
        out["held_out_against"] = "the offset-corrected reference F_ref + force_offset_n"
        return out

    def offset_words(self) -> str:
        """The fitted zero offset with its interval in words ('' when there is none)."""
        o = self.offset_dict()
        interval = f"[{o.get('ci95_low', 0.0):+.4g}, {o.get('ci95_high', 0.0):+.4g}]"
        return f"{o['value_n']:+.4g} N, 95 % {interval}" if o["fitted"] else ""

    def as_dict(self) -> dict[str, Any]:
        fit = self.fit
        writable = {s.name for s in self.writable()}
        out: dict[str, Any] = {
            "record": self.record,
            "channel": self.channel,
            "effects": list(fit.effects),
            "parameters": [
                {
                    "name": e.name,
                    "value": e.value,
                    "ci95_low": e.low,
                    "ci95_high": e.high,
                    "fitted": e.fitted,
                    "note": e.note,
                }
                for e in fit.estimates
            ],
            "correlation": {
                "names": list(fit.correlation_names),
                "matrix": [[round(float(v), 4) for v in row] for row in fit.correlation],
            },
            "fit_quality": {"train": fit.gap_train.as_dict(), "held_out": fit.gap_test.as_dict()},
            "rows": {"train": fit.n_train, "held_out": fit.n_test, "unusable": self.unusable},
            "conductance_line": {
                "slope_s_per_n": self.rivals.line_curve.slope_s_per_n,
                "intercept_s": self.rivals.line_curve.intercept_s,
                "held_out_force_rms_n": self.rivals.line_force_rms_n,
            },
            "lookup": {"held_out_force_rms_n": self.rivals.lookup_force_rms_n},
            "held_out_force_rms_n": self.force_rms(),
            "best": self.best,
            "ranking": [score.as_dict(score.name in writable) for score in self.ranking()],
            "drift_reference_pct_fs": {
                "after_higher": _none_if_nan(self.static_drift_reference()[0]),
                "others": _none_if_nan(self.static_drift_reference()[1]),
            },
            "verdict": self.verdict,
            "noise": {
                "estimated": self.noise.estimated,
                "description": self.noise.describe(),
                "rel_noise": self.noise.rel_noise,
                "floor_log_resistance": self.noise_floor_log,
                "floor_force_n": self.noise_floor_force_n,
            },
            "force_range_n": list(self.force_range_n),
            "calibrated_range_n": list(self.calibrated_range_n()),
            "range_margin_n": list(self.range_margin_n),
            "model_force_range_n": list(model_force_range(self.calibrated_range_n())),
            "configured_force_range_n": list(self.configured_range_n),
            "rows_outside_configured_range": self.rows_outside_configured,
            "notes": list(self.notes),
            "warnings": list(self.warnings),
        }
        other = self.other
        out["objective"] = {
            "used": fit.objective,
            "requested": self.objective_mode,
            "held_out_force_rms_n": {f.objective: f.gap_test.force_rms_n for f in (fit, other) if f},
            "other": other and {"objective": other.objective, "effects": list(other.effects)},
        }
        out["force_offset"] = self.offset_dict()
        out["record_force_range_n"] = list(self.record_range_n)
        if self.fit_before is not None:
            out["without_hysteresis"] = {
                "effects": list(self.fit_before.effects),
                "held_out": self.fit_before.gap_test.as_dict(),
            }
        return out
