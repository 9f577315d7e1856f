"""Which calibration parameters a set of poses can determine, told in plain words.

Measurement model ([Oppong] eqs. 1-2, the same for accelerometer, gyroscope, magnetometer)::

    y = b + F·u        y: sensor output (3), u: true input (3) in the sensor frame

with parameters b (3) and F (9 full, 6 upper-triangular as [Oppong]'s F/E, 6 symmetric as seed
000's W, or 3 diagonal as ArduPilot's INS_ACCSCAL). ``design`` lists the inputs u of the poses
(specific-force vectors, Earth-rate vectors, field vectors). The Jacobian ∂y/∂θ is linear in θ, so
its rank, singular values and null space tell exactly what the poses can and cannot separate.
A second, practical test compares each parameter's effect on the output with the sensor's
resolution (e.g. RAW_IMU steps, ardupilot-facts.md: 1 mG, 1 mrad/s).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from apmcal.core.constants import STANDARD_GRAVITY
from apmcal.core.errors import ApmcalError

AXES = "xyz"
UNITS = {"acc": "m/s²", "gyr": "rad/s", "mag": "mGauss"}
MATRIX_CELLS = {
    "full": [((i, j),) for i in range(3) for j in range(3)],
    "upper": [((0, 0),), ((0, 1),), ((0, 2),), ((1, 1),), ((1, 2),), ((2, 2),)],
    "symmetric": [((0, 0),), ((1, 1),), ((2, 2),), ((0, 1), (1, 0)), ((0, 2), (2, 0)),
                  ((1, 2), (2, 1))],
    "diagonal": [((0, 0),), ((1, 1),), ((2, 2),)],
}


@dataclass
class IdentifiabilityReport:
    """Outcome of :func:`identifiability`.

    Attributes
    ----------
    model : str
        "acc", "gyr" or "mag".
    names : list of str
        Parameter names ("b_x", ..., "F_xz", ...).
    jacobian : (3·poses, p) array
        ∂y/∂θ.
    rank : int
    singular_values : (p,) array
    condition : float
        Of the Jacobian (condition = inf when rank-deficient).
    determinable : dict
        name → bool, separable from the others by these poses (exact algebra).
    resolvable : dict
        name → bool, determinable and its plausible effect (a ``plausible`` matrix
        error, or a bias confounded only with matrix terms whose effect is below the resolution)
        shows at the given resolution; equals ``determinable`` when no resolution is given.
    lines : list of str
        Plain-words findings for the user.
    """

    model: str
    names: list[str]
    jacobian: np.ndarray
    rank: int
    singular_values: np.ndarray
    condition: float
    determinable: dict[str, bool]
    resolvable: dict[str, bool]
    lines: list[str] = field(default_factory=list)

    @property
    def n_params(self) -> int:
        """Number of parameters p."""
        return len(self.names)


def six_faces(magnitude: float = STANDARD_GRAVITY) -> np.ndarray:
    """Inputs of the six Ferraris faces (each axis parallel and anti-parallel to the field).

    Parameters
    ----------
    magnitude : float
        Field magnitude [sensor units] (default standard gravity [m/s²]).

    Returns
    -------
    (6, 3) array
        +x, +y, +z, −x, −y, −z times ``magnitude``.
    """
    return magnitude * np.vstack([np.eye(3), -np.eye(3)])


def _names(matrix: str) -> list[str]:
    return [f"b_{a}" for a in AXES] + [f"F_{AXES[c[0][0]]}{AXES[c[0][1]]}"
                                       for c in MATRIX_CELLS[matrix]]


def jacobian(design: np.ndarray, matrix: str = "full") -> np.ndarray:
    """∂y/∂θ for ``y_k = b + F·u_k`` stacked over the poses u_k (rows of ``design``).

    Parameters
    ----------
    design : (k, 3) array
        Inputs u_k [sensor units].
    matrix : {"full", "upper", "symmetric", "diagonal"}
        Parameterisation of F.

    Returns
    -------
    (3·k, 3 + m) array
        Bias columns, then one column per free matrix term.
    """
    cells = MATRIX_CELLS[matrix]
    J = np.zeros((3 * len(design), 3 + len(cells)))
    for k, u in enumerate(design):
        J[3 * k:3 * k + 3, :3] = np.eye(3)
        for p, cell in enumerate(cells):
            for i, j in cell:
                J[3 * k + i, 3 + p] += u[j]
    return J


def _groups(P: np.ndarray, idx: list[int], tol: float) -> list[list[int]]:
    """Connected components of parameters coupled through the null-space projector P."""
    left, out = set(idx), []
    while left:
        stack, comp = [left.pop()], []
        while stack:
            p = stack.pop()
            comp.append(p)
            linked = [q for q in left if abs(P[p, q]) > tol]
            left -= set(linked)
            stack += linked
        out.append(sorted(comp))
    return out


def _combination_lines(J: np.ndarray, comp: list[int], names: list[str]) -> list[str]:
    """The distinct combinations of the parameters in ``comp`` that the poses do see."""
    rows = J[:, comp]
    combos = []
    for r in rows:
        nz = np.flatnonzero(np.abs(r) > 1e-12)
        if nz.size == 0:
            continue
        r = r / r[nz[0]]
        if not any(np.allclose(r, c, atol=1e-9) for c in combos):
            combos.append(r)
    terms = [" + ".join(("" if abs(c - 1) < 1e-12 else f"({c:.4g})·") + names[comp[i]]
                        for i, c in enumerate(r) if abs(c) > 1e-12) for r in combos]
    return terms


def identifiability(model: str, design, *, matrix: str = "full", resolution: float | None = None,
                    plausible: float = 0.1) -> IdentifiabilityReport:
    """Rank, singular values, condition and per-parameter determinability of ``y = b + F·u``.

    Parameters
    ----------
    model : {"acc", "gyr", "mag"}
        Only names the units in the text.
    design : (k, 3) array
        True inputs u of the k poses in the sensor frame, in sensor units (a level ArduPilot
        accelerometer: (0, 0, −g) m/s²; a gyro at rest: the Earth rate in rad/s).
    matrix : {"full", "upper", "symmetric", "diagonal"}
        Parameterisation of F ([Oppong] uses "upper", [Niespodziany] "symmetric").
    resolution : float, optional
        Smallest output change the data can show (RAW_IMU: 1 mG = 0.00981 m/s², 1 mrad/s).
    plausible : float
        Size of a plausible matrix error (0.1 = 10 % scale or cross-axis), used with resolution.

    Returns
    -------
    IdentifiabilityReport

    Raises
    ------
    ApmcalError
        For an unknown model or matrix form, or a design that is not finite (k, 3).
    """
    if model not in UNITS:
        raise ApmcalError(f"identifiability: unknown model {model!r} (acc, gyr, mag)")
    if matrix not in MATRIX_CELLS:
        raise ApmcalError(f"identifiability: unknown matrix form {matrix!r}")
    u = np.atleast_2d(np.asarray(design, dtype=float))
    if u.shape[1] != 3 or not np.all(np.isfinite(u)):
        raise ApmcalError(f"identifiability: design must be finite (k, 3), got {u.shape}")
    names, unit = _names(matrix), UNITS[model]
    J = jacobian(u, matrix)
    _, s, Vt = np.linalg.svd(J)
    p = J.shape[1]
    s_full = np.zeros(p)
    s_full[:len(s)] = s
    rank = int(np.sum(s_full > 1e-10 * s_full[0]))
    cond = float(s_full[0] / s_full[-1]) if rank == p else float("inf")
    N = Vt[rank:].T if rank < p else np.zeros((p, 0))
    P = N @ N.T
    det = {n: bool(np.linalg.norm(N[i]) < 1e-8) for i, n in enumerate(names)}
    lines = [f"{model}: {len(u)} pose(s), {p} parameters (bias 3 + {matrix} matrix "
             f"{p - 3}): Jacobian rank {rank} of {p}, condition number "
             f"{'inf' if rank < p else f'{cond:.3g}'}"]
    if rank == p:
        lines.append(f"{model}: every parameter is determinable from these poses")
    groups = _groups(P, [i for i, n in enumerate(names) if not det[n]], 1e-8)
    for comp in groups:
        if not np.any(J[:, comp]):
            for i in comp:
                lines.append(f"{model}: {names[i]} NOT determinable — no effect on any pose "
                             "(its input component is zero in every pose)")
            continue
        terms = _combination_lines(J, comp, names)
        lines.append(f"{model}: {', '.join(names[i] for i in comp)} cannot be separated: the "
                     f"poses only see {'; '.join(terms)}")
    res = dict(det)
    if resolution is not None:
        for i, n in enumerate(names):
            effect = np.max(np.abs(J[:, i])) * (1.0 if i < 3 else plausible)
            if np.any(J[:, i]) and effect < resolution:
                res[n] = False      # even where the algebra separates it, the data cannot
                lines.append(f"{model}: {n} not determinable at {resolution:.3g} {unit} "
                             f"resolution — a {100 * plausible:.0f}% error moves the output by "
                             f"only {effect:.3g} {unit}")
        for comp in groups:     # bias confounded only with matrix terms too small to matter
            biases = [i for i in comp if i < 3]
            mats = [i for i in comp if i >= 3]
            blur = plausible * sum(np.max(np.abs(J[:, i])) for i in mats)
            if biases and mats and blur < resolution:
                for i in biases:
                    res[names[i]] = True
                    lines.append(f"{model}: {names[i]} determinable to ±{blur:.3g} {unit} (below "
                                 "the resolution) when the matrix terms are held at nominal")
    return IdentifiabilityReport(model=model, names=names, jacobian=J, rank=rank,
                                 singular_values=s_full, condition=cond, determinable=det,
                                 resolvable=res, lines=lines)
