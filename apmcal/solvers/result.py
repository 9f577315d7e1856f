"""Calibration results that apply themselves to samples and save/load themselves.

Convention (the same for every sensor, every solver, the CLI's JSON and sitl's --truth file)::

    calibrated = matrix @ (measured - offset - drift * (t - t_ref) - g_sensitivity @ f)

in SI units after conversion (accelerometer m/s², gyroscope rad/s, magnetometer mGauss), in the
frame of the measured samples. ``drift`` is only non-zero for a gyroscope with a bias linear in
time ([Oppong] eq. 5); ``g_sensitivity`` [rad/s per m/s²] only for a gyroscope whose
sensitivity to the specific force f (the CALIBRATED accelerometer, m/s²) was estimated
([Oppong]'s K_ga, [Chow]'s G_ω).

The JSON file (:meth:`Calibration.save`) carries ``"schema": "apmcal.calibration/2"`` and a
``"units"`` block; :meth:`Calibration.load` also reads the schema-less files of version 1.
"""
from __future__ import annotations

import json
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from apmcal.core.errors import ApmcalError
from apmcal.solvers.misfit import HoldMisfit
from apmcal.solvers.report_types import (
    CalibrationReport,
    Hold,
    MagneticField,
    SixFaceFit,
    Turn,
)

SCHEMA = "apmcal.calibration/2"
UNITS = {"acc": "m/s²", "gyr": "rad/s", "mag": "mGauss", "matrix": "1",
         "drift": "sensor unit per s", "t_ref": "s", "g_sensitivity": "rad/s per m/s²",
         "sigma": "one sigma, in the unit of its value"}
SENSOR_NAMES = ("acc", "gyr", "mag")


@dataclass
class SensorCalibration:
    """Offset, matrix (and gyro drift, g-sensitivity) of one sensor, with one-sigma figures.

    Attributes
    ----------
    offset : (3,) array, sensor units
    matrix : (3, 3) array, dimensionless
    drift : (3,) array, sensor units per second
        Gyro bias drift, zeros otherwise.
    t_ref : float
        Time [s] at which ``offset`` holds.
    sigma : dict of name -> array
        One-sigma uncertainties ("offset", "matrix", "drift", "g_sensitivity").
    g_sensitivity : (3, 3) array, rad/s per m/s²
        Of calibrated specific force (gyro), zeros when not estimated.
    """

    offset: np.ndarray = field(default_factory=lambda: np.zeros(3))
    matrix: np.ndarray = field(default_factory=lambda: np.eye(3))
    drift: np.ndarray = field(default_factory=lambda: np.zeros(3))
    t_ref: float = 0.0
    sigma: dict = field(default_factory=dict)
    g_sensitivity: np.ndarray = field(default_factory=lambda: np.zeros((3, 3)))

    def __post_init__(self):
        self.offset = np.asarray(self.offset, dtype=float).reshape(3)
        self.matrix = np.asarray(self.matrix, dtype=float).reshape(3, 3)
        self.drift = np.asarray(self.drift, dtype=float).reshape(3)
        self.g_sensitivity = np.asarray(self.g_sensitivity, dtype=float).reshape(3, 3)
        self.sigma = {k: np.asarray(v, dtype=float) for k, v in self.sigma.items()}

    def _bias(self, n: int, t, force) -> np.ndarray:
        """offset + drift·(t − t_ref) + G·force for n samples, (n, 3) (or (3,) when constant)."""
        bias = self.offset
        if np.any(self.drift):
            if t is None:
                raise ValueError("this calibration has a bias drift: pass the sample times t")
            bias = bias + np.outer(np.asarray(t, dtype=float) - self.t_ref, self.drift)
        if np.any(self.g_sensitivity):
            if force is None:
                raise ValueError("this calibration has a gyro g-sensitivity: pass the "
                                 "calibrated specific force (force=, m/s²)")
            bias = bias + np.asarray(force, dtype=float).reshape(n, 3) @ self.g_sensitivity.T
        return bias

    def apply(self, samples: np.ndarray, t: np.ndarray | None = None,
              force: np.ndarray | None = None) -> np.ndarray:
        """Calibrate (n, 3) ``samples``.

        ``t`` (n,) [s] is needed only when drift is non-zero, ``force`` (n, 3) — the CALIBRATED
        specific force [m/s²] at the same times — only when g_sensitivity is non-zero.

        Parameters
        ----------
        samples : (n, 3) or (3,) array
            Raw sensor-frame samples [sensor units].
        t : (n,) array, optional
            Sample times [s].
        force : (n, 3) array, optional
            Calibrated specific force [m/s²] (the calibrated accelerometer, not its raw samples:
            :meth:`Calibration.apply` takes the raw ones as ``acc``).

        Returns
        -------
        (n, 3) or (3,) array
            ``matrix @ (samples − offset − drift·(t − t_ref) − G·force)`` [sensor units].

        Raises
        ------
        ValueError
            When the drift needs ``t`` or the g-sensitivity needs ``force`` and it is missing.
        """
        x = np.asarray(samples, dtype=float)
        return (x - self._bias(len(np.atleast_2d(x)), t, force)) @ self.matrix.T

    def invert(self, calibrated: np.ndarray, t: np.ndarray | None = None,
               force: np.ndarray | None = None) -> np.ndarray:
        """The measured samples that :meth:`apply` maps to ``calibrated`` (used by the simulator).

        Parameters
        ----------
        calibrated : (n, 3) or (3,) array
            Calibrated samples [sensor units].
        t, force
            As for :meth:`apply`.

        Returns
        -------
        (n, 3) or (3,) array
            Raw samples [sensor units].
        """
        c = np.asarray(calibrated, dtype=float)
        x = np.linalg.solve(self.matrix, c.T).T
        return x + self._bias(len(np.atleast_2d(c)), t, force)

    def to_dict(self) -> dict:
        """Offset, matrix and sigmas as plain lists; drift and t_ref, g_sensitivity when non-zero."""
        d = {"offset": self.offset.tolist(), "matrix": self.matrix.tolist(),
             "sigma": {k: np.asarray(v).tolist() for k, v in self.sigma.items()}}
        if np.any(self.drift):
            d["drift"] = self.drift.tolist()
            d["t_ref"] = self.t_ref
        if np.any(self.g_sensitivity):
            d["g_sensitivity"] = self.g_sensitivity.tolist()
        return d

    @classmethod
    def from_dict(cls, d: dict) -> "SensorCalibration":
        """Read :meth:`to_dict`'s output (missing drift, g-sensitivity: zeros)."""
        return cls(offset=d["offset"], matrix=d["matrix"], drift=d.get("drift", np.zeros(3)),
                   t_ref=d.get("t_ref", 0.0), sigma=d.get("sigma", {}),
                   g_sensitivity=d.get("g_sensitivity", np.zeros((3, 3))))


@dataclass
class Calibration:
    """The result of one calibration run: per-sensor corrections plus what produced them.

    ``sensors`` maps "acc", "gyr", "mag" to :class:`SensorCalibration`. ``params`` holds the
    ArduPilot parameters proposed for this result (filled by :mod:`apmcal.ardupilot.params`),
    ``report`` what the run found (:class:`~apmcal.solvers.report_types.CalibrationReport`).

    Attributes
    ----------
    method : str
        The method that produced it ("ferraris", "ellipsoid", "static", "joint", ...).
    sensors : dict
        "acc", "gyr", "mag" → :class:`SensorCalibration`.
    params : dict
        ArduPilot parameter name → proposed value.
    report : CalibrationReport
    """

    method: str
    sensors: dict[str, SensorCalibration] = field(default_factory=dict)
    params: dict[str, float] = field(default_factory=dict)
    report: CalibrationReport = field(default_factory=CalibrationReport)

    def apply(self, data, samples: np.ndarray | None = None, t: np.ndarray | None = None,
              acc: np.ndarray | None = None):
        """Calibrated samples of one sensor, or a calibrated copy of a whole table.

        ``apply("gyr", samples, t, acc)``: (n, 3) samples of that sensor; ``t`` (n,) [s] for a
        drift, ``acc`` (n, 3) the RAW accelerometer samples at the same times for a gyro
        g-sensitivity (calibrated here with this result's "acc" when it has one).
        ``apply(recording)`` / ``apply(dataframe)``: a copy of the same type with every sensor
        this result calibrates replaced by its calibrated values (columns of
        :data:`apmcal.core.recording.SENSOR_COLUMNS`, times from "t"). The samples must be raw and in
        the sensor frame (:func:`apmcal.preprocessing.prepare.prepare` undoes a firmware correction).

        Parameters
        ----------
        data : str, Recording or pandas.DataFrame
            Sensor name ("acc", "gyr", "mag"), or a table of raw sensor-frame samples.
        samples : (n, 3) array, optional
            With a sensor name: its raw samples [sensor units].
        t : (n,) array, optional
            Sample times [s].
        acc : (n, 3) array, optional
            RAW accelerometer samples, for a gyro g-sensitivity.

        Returns
        -------
        (n, 3) array, or Recording / DataFrame
            Calibrated samples [m/s², rad/s, mGauss], or a calibrated copy of ``data``.

        Raises
        ------
        KeyError
            For a sensor name this result does not calibrate.
        ValueError
            For a firmware-corrected or body-frame Recording, or a missing ``t``/``acc``.
        """
        if isinstance(data, str):
            force = None if acc is None else self.specific_force(acc, t)
            return self.sensors[data].apply(samples, t, force=force)
        return _apply_to_table(self, data)

    def specific_force(self, acc: np.ndarray, t: np.ndarray | None = None) -> np.ndarray:
        """Raw accelerometer samples (n, 3) → calibrated specific force [m/s²] (raw when this
        result has no accelerometer calibration).

        Parameters
        ----------
        acc : (n, 3) array
            Raw accelerometer samples [m/s²].
        t : (n,) array, optional
            Sample times [s], for a drift.

        Returns
        -------
        (n, 3) array, m/s²
        """
        if "acc" in self.sensors:
            return self.sensors["acc"].apply(acc, t)
        return np.asarray(acc, dtype=float)

    # ---- JSON ------------------------------------------------------------------------------
    def to_dict(self) -> dict:
        """The whole result as plain JSON values, schema and units first."""
        d = {"schema": SCHEMA, "units": dict(UNITS), "method": self.method}
        d.update({name: cal.to_dict() for name, cal in self.sensors.items()})
        d["params"] = dict(self.params)
        d["report"] = self.report.to_dict()
        return d

    @classmethod
    def from_dict(cls, d: dict, path: str | Path | None = None) -> "Calibration":
        """Read :meth:`to_dict`'s output (or a version-1 file, which has no "schema").

        Parameters
        ----------
        d : dict
            The JSON values.
        path : str or Path, optional
            The file they came from, for the error message.

        Returns
        -------
        Calibration

        Raises
        ------
        ApmcalError
            For a schema this version does not know.
        """
        schema = d.get("schema")
        if schema is not None and schema != SCHEMA:
            raise ApmcalError(f"unknown calibration schema {schema!r}: this apmcal reads "
                              f"{SCHEMA} (and version 1, without a schema); update apmcal",
                              None if path is None else str(path))
        sensors = {k: SensorCalibration.from_dict(d[k]) for k in SENSOR_NAMES if k in d}
        if schema is None:
            report = report_from_v1(d.get("report", {}), sensors)
        else:
            report = CalibrationReport.from_dict(d.get("report", {}))
        return cls(method=d.get("method", ""), sensors=sensors, params=d.get("params", {}),
                   report=report)

    def save(self, path: str | Path, extra: dict | None = None) -> None:
        """Write the result as JSON (schema, units, sensors, params, report); ``extra`` adds
        the caller's own top-level fields (the CLI's summary and verdict), which :meth:`load`
        ignores. An OSError becomes a one-line ApmcalError.

        Parameters
        ----------
        path : str or Path
        extra : dict, optional
            Further top-level fields.

        Raises
        ------
        ApmcalError
            When the file cannot be written.
        ValueError
            When ``extra`` would overwrite one of the calibration's fields.
        """
        d = self.to_dict()
        clash = set(d) & set(extra or {})
        if clash:
            raise ValueError(f"extra fields {sorted(clash)} would overwrite the calibration's")
        d.update(extra or {})
        try:
            Path(path).write_text(json.dumps(d, indent=2) + "\n")
        except OSError as exc:
            raise ApmcalError(f"cannot write JSON file ({exc.strerror or exc})", str(path)) from None

    @classmethod
    def load(cls, path: str | Path) -> "Calibration":
        """Read a file written by :meth:`save` (or a version-1 file); one-line ApmcalError when
        it is not a calibration or has a schema this version does not know.

        Parameters
        ----------
        path : str or Path

        Returns
        -------
        Calibration

        Raises
        ------
        ApmcalError
            When the file cannot be read, is not a calibration or has an unknown schema.
        """
        try:
            d = json.loads(Path(path).read_text())
            return cls.from_dict(d, path)
        except ApmcalError:
            raise
        except (OSError, ValueError, KeyError, TypeError, AttributeError) as exc:
            raise ApmcalError(f"not a calibration file ({exc})", str(path)) from None


def _apply_to_table(cal: Calibration, data):
    """:meth:`Calibration.apply` on a Recording or a DataFrame (a copy of the same type)."""
    from apmcal.core.recording import SENSOR_COLUMNS, Recording

    if isinstance(data, Recording):
        if data.corrected or data.frame != "sensor":
            raise ValueError("apply needs raw sensor-frame samples; this recording is "
                             "firmware-corrected or in the body frame (see pipeline.prepare)")
        return replace(data, data=_apply_to_table(cal, data.data))
    df = data.copy()
    t = df["t"].to_numpy(dtype=float) if "t" in df.columns else None
    has = {s: all(c in df.columns for c in cols) for s, cols in SENSOR_COLUMNS.items()}
    raw = {s: df[cols].to_numpy(dtype=float) for s, cols in SENSOR_COLUMNS.items() if has[s]}
    for sensor, sc in cal.sensors.items():
        if not has.get(sensor):
            continue
        force = cal.specific_force(raw["acc"], t) if has["acc"] and sensor == "gyr" else None
        df[SENSOR_COLUMNS[sensor]] = sc.apply(raw[sensor], t, force=force)
    return df


def report_from_v1(old: dict, sensors: dict[str, SensorCalibration]) -> CalibrationReport:
    """What a version-1 file's free-form report still says, in the typed report; its gyro
    g-sensitivity moves into the gyro's SensorCalibration (it is part of the applied model).

    Parameters
    ----------
    old : dict
        The version-1 file's "report".
    sensors : dict
        sensor → SensorCalibration read from the same file; the gyro's is changed in place.

    Returns
    -------
    CalibrationReport
    """
    rep = CalibrationReport(recording=old.get("recording"),
                            warnings=list(old.get("warnings", [])),
                            undetermined=dict(old.get("undetermined", {})),
                            not_calibrated=dict(old.get("not_calibrated", {})))
    rep.holds.count = old.get("static_segments")
    rep.holds.used = {k: Hold(*v) for k, v in old.get("poses", {}).items()}
    if "static_segment_s" in old:
        rep.holds.used["level"] = Hold(*old["static_segment_s"])
    rep.rotations = {k: Turn(*v) for k, v in old.get("rotations", {}).items()}
    if old.get("mag_field_mgauss") is not None:
        cover = old.get("mag_coverage", {})
        rep.magnetic_field = MagneticField(old["mag_field_mgauss"], "version-1 file",
                                           cover.get("fraction"), cover.get("min_eig"))
    if "acc_misfit" in old and "U_plus" in old:
        rep.six_face = _six_face_from_v1(old)
    g_sens = old.get("gyr_g_sensitivity")
    if g_sens is not None and "gyr" in sensors:
        gyr = sensors["gyr"]
        gyr.g_sensitivity = np.asarray(g_sens, dtype=float).reshape(3, 3)
        if old.get("gyr_g_sensitivity_sigma") is not None:
            gyr.sigma["g_sensitivity"] = np.asarray(old["gyr_g_sensitivity_sigma"], dtype=float)
    return rep


def _six_face_from_v1(old: dict) -> SixFaceFit:
    m = old["acc_misfit"]
    misfit = HoldMisfit(tau=np.asarray(m["tau"], float),
                        offset_spread=np.asarray(m["offset_spread"], float), chi2=m["chi2"],
                        dof=m["dof"], n_holds=m["n_holds"], worst=m["worst_residual"])
    noise = {k: np.asarray(v, float) for k, v in old.get("acc_sigma_noise_only", {}).items()}
    return SixFaceFit(u_plus=np.asarray(old["U_plus"], float),
                      u_minus=np.asarray(old["U_minus"], float), q=old["Q"],
                      gravity=old["gravity"], gravity_source=old["gravity_source"],
                      misfit=misfit, sigma_noise_only=noise)
