"""The command line's value types for argparse: each turns one argument's text into
a value, or raises ArgumentTypeError with a line that says what was expected."""

from __future__ import annotations

import argparse


def _count(text: str) -> int:
    try:
        n = int(text)
    except ValueError:
        n = 0
    if n < 1:
        raise argparse.ArgumentTypeError(f"expected a whole number >= 1, got {text!r}")
    return n


def _non_negative(text: str) -> float:
    try:
        x = float(text)
    except ValueError:
        x = -1.0
    if not (x >= 0 and x < float("inf")):
        raise argparse.ArgumentTypeError(f"expected a finite number >= 0, got {text!r}")
    return x


def _positive_seconds(text: str) -> float:
    x = _non_negative(text)
    if x == 0:
        raise argparse.ArgumentTypeError(f"expected a number of seconds > 0, got {text!r}")
    return x


def _positive(text: str, expected: str = "a finite number > 0") -> float:
    """A finite number > 0 (--loss-scale: 0, -1, nan and inf failed later, in the
    Problem's words)."""
    try:
        x = float(text)
    except ValueError:
        x = float("nan")
    if not 0 < x < float("inf"):
        raise argparse.ArgumentTypeError(f"expected {expected}, got {text!r}")
    return x


def _sample_time(text: str) -> float:
    """--ts: a finite sampling time > 0 (argparse's float took 0, -1, nan and inf, and
    the error came later without the flag's name)."""
    return _positive(text, "a positive sampling time in seconds (a finite number > 0)")


def _level(text: str) -> float:
    x = _non_negative(text)
    if not 0 < x < 1:
        raise argparse.ArgumentTypeError(f"expected a level between 0 and 1, got {text!r}")
    return x


def _mapping(text: str) -> dict[str, str]:
    """NAME=COLUMN,NAME=COLUMN (a number for COLUMN: a constant signal)"""
    out: dict[str, str] = {}
    for item in text.split(","):
        name, eq, column = item.partition("=")
        if not eq or not name.strip() or not column.strip():
            raise argparse.ArgumentTypeError(
                f"expected NAME=COLUMN pairs separated by commas (u=uEst,y=yEst), got {text!r}"
            )
        if name.strip() in out:  # the last would win silently
            raise argparse.ArgumentTypeError(
                f"{name.strip()!r} is mapped twice ({name.strip()}={out[name.strip()]} and "
                f"{name.strip()}={column.strip()}); give each name once"
            )
        out[name.strip()] = column.strip()
    return out


def _samples(text: str) -> tuple[int, int]:
    try:
        a, b = text.split(":")
        return int(a), int(b)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected START:STOP sample indices, got {text!r}"
        ) from None


def _value(text: str) -> tuple[str, float]:
    """NAME=VALUE"""
    name, eq, value = text.partition("=")
    try:
        number = float(value)
    except ValueError:
        number = float("nan")
    if not eq or not name.strip() or not abs(number) < float("inf"):
        raise argparse.ArgumentTypeError(f"expected NAME=VALUE with a finite number, got {text!r}")
    return name.strip(), number


def _range(text: str) -> tuple[str, tuple[float, float]]:
    """NAME=LO:HI (either end may be empty or inf: no bound on that side)"""
    name, eq, rest = text.partition("=")
    lo, colon, hi = rest.partition(":")
    try:
        ends = tuple(float(v) if v.strip() else float("inf") * s for v, s in ((lo, -1), (hi, 1)))
    except ValueError:
        ends = ()
    if not eq or not colon or not name.strip() or len(ends) != 2:
        raise argparse.ArgumentTypeError(f"expected NAME=LO:HI (e.g. M=50:150), got {text!r}")
    return name.strip(), (ends[0], ends[1])


def tolerances_as_flags(message: str) -> str:
    """The integration's refusal of rtol=/atol= as the flags that gave them ("need
    rtol > 0 ...; got rtol=0.0" named no flag)."""
    import re

    message = re.sub(r"(?<![\w-])(rtol|atol|substeps)\b", r"--\1", message)
    return re.sub(r"; '([\w-]+)' takes", r"; --scheme \1 takes", message)
