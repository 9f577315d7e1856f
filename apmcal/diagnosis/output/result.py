"""The diagnosis result: a plain object that saves itself as JSON and loads back.

Schema 1 (every gap in nats per sample, see :mod:`apmcal.diagnosis.scoring.gap`)::

    {"schema": 1, "source": ..., "session": {...},
     "gap": {"total": in-sample, "heldout": held-out, "breakdown": {...},
             "breakdown_heldout": {...},
             "noise_ratio_heldout": {sensor: {band: real RMS / twin RMS}}},
     "effects": [{"name", "shrink_heldout", "shrink_in_sample", "gap_heldout", "evidence_nats",
                  "supported_alone", "significant", "evidence_when_selected_nats",
                  "evidence_beyond_selection_nats", "params", "not_tested",
                  "implausible", "parameters_p_value", "null_p_value", "null_threshold_nats",
                  "null_sessions", "scored_at_hz", "confounded_with", "stands_in_for",
                  "chance_on_top_p_value"}, ...]
                 (best first),
     "selected": [names], "after": {"total", "heldout", "breakdown", "breakdown_heldout",
                                    "noise_ratio_heldout"},
     "white_noise": {...}, "noise_structure": {...}, "notes": [...]}

"shrink_*", "gap_*" and "evidence_nats" score the effect alone on the nominal model;
"supported_alone" is that evidence ≥ 15 nats with plausible parameters ("implausible" says why
not, :mod:`apmcal.diagnosis.model.plausible`), away from "off" ("parameters_p_value", the Wald
test's, below 0.001) and, where the selection needed to know, beyond chance on this session:
"null_p_value" is the probability of that much evidence on sessions drawn from the nominal
model ("null_sessions" of them, :mod:`apmcal.diagnosis.scoring.null`), below 0.05 / the number
of candidates tested, "null_threshold_nats" the evidence that reaches it; they are null when no
decision turned on them (the other tests refuse the effect, or the effects selected explain it
before it could join); "significant" means selected, or still supported
on top of the selected combination (see :mod:`apmcal.diagnosis.scoring.select`);
"confounded_with" (only when so) names the effect that explains this one where their shapes
part (:func:`apmcal.diagnosis.scoring.select.confounded_effects`); "stands_in_for" (only when
so) the deterministic effect whose place a stochastic one took (removed from the selection);
"chance_on_top_p_value" (only when so) the p-value of an effect left out of the combination
because sessions drawn from the combination it was to join gave it as much evidence by chance
(:func:`apmcal.diagnosis.scoring.null.on_top`). "scored_at_hz" is
the sample rate the effect was scored at: the recording's, or for a slow effect in a recording
faster than 200 Hz the block means' (:mod:`apmcal.diagnosis.session.decimate`), whose gaps are per
averaged sample; there a slow effect is scored "alone" on top of the low-pass filter when the
recorded rate showed one.
"""
from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

from apmcal.core.errors import ApmcalError
from apmcal.core.json_file import jsonable

SCHEMA = 1
UNITS = {"gap": "nats per residual sample (Kullback-Leibler divergence, real vs twin)",
         "shrink": "1 - gap_after / gap_before, held-out", "acc": "m/s²", "gyr": "rad/s",
         "mag": "mGauss", "time": "s", "temperature": "°C"}


@dataclass
class GapResult:
    """What ``apmcal gap`` found (see the module docstring for the JSON layout).

    Attributes
    ----------
    source : str
        The log file.
    session : dict
        What the session holds (duration [s], rate [Hz], holds, moves, ...).
    gap : dict
        The nominal model's gap, in-sample ("total") and held-out [nats per sample], with
        the breakdowns.
    effects : list of dict
        Every candidate, best first.
    selected : list of str
        The selected combination.
    after : dict
        The gap of the nominal model plus the selection, as ``gap``.
    white_noise : dict
        Per-sample white noise of each sensor.
    noise_structure : dict
        Noise terms of the hold residuals, real against twin.
    notes : list of str
    """

    source: str
    session: dict
    gap: dict
    effects: list
    selected: list
    after: dict
    white_noise: dict = field(default_factory=dict)
    noise_structure: dict = field(default_factory=dict)
    notes: list = field(default_factory=list)

    def effect(self, name: str) -> dict | None:
        """The entry of effect ``name``, or None when it is not among the candidates."""
        return next((e for e in self.effects if e["name"] == name), None)

    @property
    def top(self) -> str | None:
        """The effect ranked first when it is significant, else None."""
        first = self.effects[0] if self.effects else None
        return first["name"] if first and first["significant"] else None

    def to_dict(self) -> dict:
        """The result as JSON-ready data (schema and units included, NaN as null)."""
        return jsonable({"schema": SCHEMA, "units": UNITS, "source": self.source,
                         "session": self.session, "gap": self.gap, "effects": self.effects,
                         "selected": self.selected, "after": self.after,
                         "white_noise": self.white_noise,
                         "noise_structure": self.noise_structure, "notes": self.notes},
                        nan_as_null=True)

    def save(self, path) -> None:
        """Write the result as JSON.

        Raises
        ------
        ApmcalError
            When the file cannot be written.
        """
        try:
            Path(path).write_text(json.dumps(self.to_dict(), indent=1) + "\n")
        except OSError as exc:
            raise ApmcalError(f"cannot write JSON file ({exc.strerror or exc})", str(path)) \
                from None

    @classmethod
    def load(cls, path) -> "GapResult":
        """Read a result saved by :meth:`save`.

        Raises
        ------
        ApmcalError
            When the file cannot be read or is not a result of this schema.
        """
        try:
            d = json.loads(Path(path).read_text())
            if d.get("schema") != SCHEMA:
                raise ValueError(f"schema {d.get('schema')!r}, expected {SCHEMA}")
            return cls(d["source"], d["session"], d["gap"], d["effects"], d["selected"],
                       d["after"], d.get("white_noise", {}), d.get("noise_structure", {}),
                       d.get("notes", []))
        except (OSError, ValueError, KeyError, TypeError) as exc:
            raise ApmcalError(f"not an apmcal gap result ({exc})", str(path)) from None

