"""Input checks at the public boundary: one clear error naming the parameter,
the value and the allowed range."""
from __future__ import annotations

import math
import re

import numpy as np


class CoronaError(ValueError):
    """A parameter outside its allowed range (subclass of ValueError)."""


class CoronaWarning(UserWarning):
    """Input that is computable but where the physics becomes questionable
    (e.g. scatterers smaller than about two wavelengths)."""


def check_positive(name: str, value, unit: str = "") -> float:
    if isinstance(value, (bool, np.bool_)):          # float(True) would be 1.0
        raise CoronaError(f"{name}={value!r} is not a number; expected a finite value > 0"
                          + (f" {unit}" if unit else ""))
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise CoronaError(f"{name}={value!r} is not a number; expected a finite value > 0"
                          + (f" {unit}" if unit else "")) from None
    if not math.isfinite(v) or v <= 0.0:
        raise CoronaError(f"{name}={value!r} is out of range; expected a finite value > 0"
                          + (f" {unit}" if unit else ""))
    return v


def check_range(name: str, value, lo: float, hi: float, *, lo_open: bool = False,
                hi_open: bool = False, unit: str = "") -> float:
    if isinstance(value, (bool, np.bool_)):          # float(True) would be 1.0
        raise CoronaError(f"{name}={value!r} is not a number")
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise CoronaError(f"{name}={value!r} is not a number") from None
    ok = math.isfinite(v)
    ok = ok and (v > lo if lo_open else v >= lo) and (v < hi if hi_open else v <= hi)
    if not ok:
        lb = "(" if lo_open else "["
        rb = ")" if hi_open else "]"
        raise CoronaError(f"{name}={value!r} is out of range; allowed {lb}{lo:g}, {hi:g}{rb}"
                          + (f" {unit}" if unit else ""))
    return v


def check_choice(name: str, value, choices) -> str:
    if value not in choices:
        raise CoronaError(f"{name}={value!r} is not one of {', '.join(map(repr, choices))}")
    return value


def check_wavelength(wavelength) -> np.ndarray:
    """Wavelengths in nm, finite and > 0 (broadcastable float64 array)."""
    w = np.asarray(wavelength, dtype=np.float64)
    if not np.all(np.isfinite(w)) or np.any(w <= 0):
        raise CoronaError(f"wavelength={wavelength!r} is out of range; expected finite values > 0 nm")
    return w


def check_finite_array(name: str, value, unit: str = "") -> np.ndarray:
    """A float64 array with only finite entries (else one clear error)."""
    try:
        a = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise CoronaError(f"{name}={short_repr(value)} is not a numeric array") from None
    if not np.all(np.isfinite(a)):
        bad = float(a[~np.isfinite(a)].ravel()[0])
        raise CoronaError(f"{name} contains {bad!r}; expected finite values" + (f" {unit}" if unit else ""))
    return a


def short_repr(value, limit: int = 80) -> str:
    """``repr(value)`` on one line, shortened (arrays can be long)."""
    r = " ".join(repr(value).split())
    return r if len(r) <= limit else r[:limit - 3] + "..."


def one_line_error(err) -> str:
    """A one-line message for ``err``, however deep Mitsuba wrapped it.

    Mitsuba reports a plugin's exception as ``[parser.cpp:N] At FILE (line L,
    col C): failed to instantiate ... Traceback ...  CoronaError: <message>``;
    this keeps ``FILE (line L, col C): <message>``.  Lists (``Found unused
    parameters:`` followed by ``- $x=1`` lines) are joined on one line.
    """
    while "(see above)" in str(err) and (err.__cause__ or err.__context__) is not None:
        err = err.__cause__ or err.__context__          # Dr.Jit wraps the real error
    text = str(err).strip()
    if not text:
        return repr(err)
    lines = [ln.strip() for ln in text.splitlines() if ln.strip()]
    first = re.sub(r"^\[[\w.]+:\d+\]\s*", "", lines[0])
    if len(lines) == 1:
        return first
    if any(ln.startswith("Traceback") or "Traceback (most recent call last)" in ln for ln in lines):
        last = re.sub(r"^[\w.]*(Error|Exception|Warning)\s*:\s*", "", lines[-1])
        where = re.match(r"^(?:At|Error while loading)\s+(.*?\(line \d+(?:, col \d+)?\))", first)
        return f"{where.group(1)}: {last}" if where else last
    if first.endswith(":"):
        return first + " " + ", ".join(ln.lstrip("- ").strip() for ln in lines[1:])
    return first
