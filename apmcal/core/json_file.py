"""Results as JSON files: numpy values made plain, one-line errors."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from apmcal.core.errors import ApmcalError


def jsonable(obj, nan_as_null: bool = False):
    """numpy arrays and scalars → plain lists and numbers, recursively; with ``nan_as_null``
    NaN and infinity → None (strict JSON has neither).

    Parameters
    ----------
    obj : object
        Dicts, lists, tuples, numpy arrays and scalars, nested.
    nan_as_null : bool

    Returns
    -------
    object
        The same with plain lists, numbers and str keys.
    """
    if isinstance(obj, dict):
        return {str(k): jsonable(v, nan_as_null) for k, v in obj.items()}
    if isinstance(obj, np.ndarray):
        return jsonable(obj.tolist(), nan_as_null)
    if isinstance(obj, (list, tuple)):
        return [jsonable(v, nan_as_null) for v in obj]
    if isinstance(obj, np.generic):
        obj = obj.item()
    if nan_as_null and isinstance(obj, float) and not np.isfinite(obj):
        return None
    return obj


def write_json(path, obj) -> None:
    """``obj`` as indented JSON (numpy values made plain, :func:`jsonable`), or one line saying
    why not.

    Raises
    ------
    ApmcalError
        When the file cannot be written.
    """
    text = json.dumps(jsonable(obj), indent=2) + "\n"
    try:
        Path(path).write_text(text)
    except OSError as exc:
        raise ApmcalError(f"cannot write JSON file ({exc.strerror or exc})", str(path)) from None
