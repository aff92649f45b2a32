"""Scenario errors as shared/scenario writes them (error.rs): the file, the
field and the reason, numbers in the reason printed as Rust prints them."""

import decimal
import math


def display(v):
    """``v`` as Rust's ``{}`` prints an f64: the shortest digits that read
    back, never in exponent form, without a trailing ``.0`` (``1``,
    ``0.0001``, ``-0``)."""
    if isinstance(v, int) and not isinstance(v, bool):
        return str(v)
    v = float(v)
    if math.isnan(v):
        return "NaN"
    if math.isinf(v):
        return "inf" if v > 0 else "-inf"
    text = repr(v)
    if "e" in text:
        text = format(decimal.Decimal(text), "f")
    if text.endswith(".0"):
        text = text[:-2]
    return text


def _lower_exp(v):
    """Rust's ``{:e}`` of a finite, non-zero f64 (``1e300``, ``1.5e-5``)."""
    sign, digits, exponent = decimal.Decimal(repr(v)).as_tuple()
    digits = "".join(map(str, digits))
    power = exponent + len(digits) - 1
    digits = digits.rstrip("0") or "0"
    mantissa = digits[0] + ("." + digits[1:] if len(digits) > 1 else "")
    return ("-" if sign else "") + f"{mantissa}e{power}"


def number(v):
    """shared/scenario's ``number``: plainly for everyday magnitudes, in
    exponent form beyond them."""
    v = float(v)
    if v == 0.0 or not math.isfinite(v) or 1e-4 <= abs(v) < 1e7:
        return display(v)
    return _lower_exp(v)


def readable_numbers(message):
    """Every run of digits longer than 20 characters in exponent form (as
    shared/scenario's ``readable_numbers``)."""
    out = []
    i, n = 0, len(message)
    while i < n:
        if not message[i].isdigit():
            out.append(message[i])
            i += 1
            continue
        j = i
        while j < n and (message[j].isdigit() or message[j] == "."):
            j += 1
        run = message[i:j]
        try:
            value = float(run)
        except ValueError:
            value = None
        out.append(number(value) if value is not None and len(run) > 20 else run)
        i = j
    return "".join(out)


class ScenarioError(Exception):
    """A scenario field this process cannot use: ``scenario FILE: field
    `FIELD`: REASON``, as shared/scenario's ``ScenarioError`` says it."""

    def __init__(self, path, field_name, reason):
        self.path = str(path)
        self.field = field_name
        self.reason = readable_numbers(str(reason))
        if field_name:
            text = f"scenario {self.path}: field `{field_name}`: {self.reason}"
        else:
            text = f"scenario {self.path}: {self.reason}"
        super().__init__(text)


class SetupError(Exception):
    """A law cannot serve this loop (another model, too many inputs, a
    parameter out of its range): raised by a law's ``__init__``, it ends
    the process with its message, as the Rust SDK's
    ``SetupError::Unsupported`` does."""
