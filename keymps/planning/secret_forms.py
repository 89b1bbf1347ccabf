"""The forms in which a server may quote a secret back, each redacted like the secret itself.

A server that quotes the key it was sent need not quote it verbatim. `encoded_forms` gives a
value as base64 (standard and URL-safe, from each of the three byte alignments, so that the key
inside `Basic base64(user:pass)` or any longer encoded text is found too), hex, %XX, reversed,
and each of those JSON-escaped; `escape_pattern` finds it written as `\\uXXXX` escapes behind
any number of backslashes (JSON inside JSON doubles them at each level). `fragments` cuts a key
that is sent into every piece of FRAGMENT characters: a key split in two, or quoted in parts,
is found piece by piece, and redaction joins overlapping pieces into one
(keymps.planning.redaction).
"""

from __future__ import annotations

import base64
import functools
import json
import re
from collections.abc import Iterable
from urllib.parse import quote

MIN_ENCODED = 8
"""Encoded forms shorter than this are left out: a 3-character key's hex or base64 would
match innocent text."""
FRAGMENT = 8
"""Pieces of a sent key this long are redacted wherever they stand (half a key shorter than
16 characters, at least 4)."""


@functools.lru_cache(maxsize=512)
def encoded_forms(value: str) -> frozenset[str]:
    """`value`, its JSON-escaped forms, and every encoding of it (module docstring)."""
    data = value.encode("utf-8")
    encoded = {
        data.hex(),
        data.hex().upper(),
        quote(value, safe=""),
        "".join(f"%{byte:02X}" for byte in data),
        "".join(f"%{byte:02x}" for byte in data),
        *_base64_cores(data),
    }
    forms = {value, value[::-1], *(form for form in encoded if len(form) >= MIN_ENCODED)}
    return frozenset(forms | {escaped for form in forms for escaped in _json_escaped(form)})


@functools.lru_cache(maxsize=512)
def fragments(value: str) -> frozenset[str]:
    """Every piece of `value` of FRAGMENT characters (half of it when it is shorter than twice
    that, at least 4); none for a value shorter than 8."""
    if len(value) < MIN_ENCODED:
        return frozenset()
    size = FRAGMENT if len(value) >= 2 * FRAGMENT else max(4, -(-len(value) // 2))
    return frozenset(value[i : i + size] for i in range(len(value) - size + 1))


def _base64_cores(data: bytes) -> set[str]:
    """The characters of `data`'s base64 that depend on `data` alone, for each of the three
    alignments it may have inside longer encoded bytes, standard and URL-safe."""
    cores = set()
    for shift in range(3):
        start = -(-8 * shift // 6)  # the first character with no bit of the bytes before
        end = 8 * (shift + len(data)) // 6  # the last with no bit of the bytes after
        for encode in (base64.b64encode, base64.urlsafe_b64encode):
            cores.add(encode(bytes(shift) + data).decode("ascii")[start:end])
    return cores


def escape_pattern(values: Iterable[str]) -> re.Pattern[str] | None:
    """One pattern for all `values`, each with every UTF-16 code unit written as a \\uXXXX
    escape (hex digits in either case) behind one or more backslashes; None for no values."""
    return _compiled(tuple(sorted(set(values))))


@functools.lru_cache(maxsize=16)
def _compiled(values: tuple[str, ...]) -> re.Pattern[str] | None:
    sources = sorted({_escaped_source(value) for value in values}, key=len, reverse=True)
    return re.compile("|".join(sources)) if sources else None


@functools.lru_cache(maxsize=256)
def _escaped_source(value: str) -> str:
    units = value.encode("utf-16-be")
    codes = (int.from_bytes(units[i : i + 2], "big") for i in range(0, len(units), 2))
    # a backslash first, then any more: the search skips to backslashes (a literal start)
    return "".join(r"\\\\*u" + "".join(_either_case(c) for c in f"{code:04x}") for code in codes)


def _either_case(digit: str) -> str:
    return f"[{digit}{digit.upper()}]" if digit.isalpha() else digit


def _json_escaped(form: str) -> set[str]:
    """`form` as it appears inside a JSON string (quotes, backslashes, non-ASCII escaped)."""
    return {json.dumps(form)[1:-1], json.dumps(form, ensure_ascii=False)[1:-1]}
