"""A server that quotes a key back encoded leaves nothing of it in any byte keymps writes.

The key a run sends, and the password of a userinfo URL, come back from a hostile server as
base64 (alone, inside longer base64 at any alignment, URL-safe, the `Basic user:pass` form),
hex, %XX, reversed, `\\uXXXX` escapes, split in pieces, and JSON-escaped forms of those. The
check does not trust the redactor's own list of forms: it decodes whatever the output holds
every way a reader could (base64 and hex from every offset, %XX, unicode escapes, reversed) and
looks for any 8 characters of the key. 600 generated keys and echoes in memory, then a real
`keymps run` against a server on 127.0.0.1 whose answers quote every form: run.json, vlm/,
the cache, the cassette and run.rrd hold none of it.
"""

from __future__ import annotations

import base64
import binascii
import json
import random
import re
import secrets
import string
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any
from urllib.parse import quote, unquote

import pytest
from click.testing import CliRunner
from helpers.fuzz_support import task_copy
from helpers.vlm_server import Recorded, Reply, VlmServer

from keymps.cli.app import cli

PIECE = 8
"""No 8 characters of a key may be recoverable from what is written."""


def _b64(data: bytes) -> str:
    return base64.b64encode(data).decode()


ECHOES: dict[str, Callable[[str, random.Random], str]] = {
    "base64": lambda key, rng: _b64(key.encode()),
    "base64 inside": lambda key, rng: _b64(rng.randbytes(rng.randint(1, 5)) + key.encode() + b"}"),
    "url-safe base64": lambda key, rng: base64.urlsafe_b64encode(b"k=" + key.encode()).decode(),
    "Basic": lambda key, rng: "Basic " + _b64(b"lab:" + key.encode()),
    "hex": lambda key, rng: key.encode().hex(),
    "HEX inside": lambda key, rng: (b"\x00" + key.encode()).hex().upper(),
    "%XX": lambda key, rng: "".join(f"%{b:02X}" for b in key.encode()),
    "quoted": lambda key, rng: quote(key, safe=""),
    "reversed": lambda key, rng: key[::-1],
    "\\uXXXX": lambda key, rng: "".join(f"\\u{ord(c):04x}" for c in key),
    "split": lambda key, rng: " / ".join(_pieces(key, rng)),
    "JSON of \\uXXXX": lambda key, rng: json.dumps("".join(f"\\u{ord(c):04X}" for c in key)),
}


def _pieces(key: str, rng: random.Random) -> list[str]:
    """The key cut in 2 to 4 pieces of at least 8 characters."""
    cuts = sorted(rng.sample(range(PIECE, len(key) - PIECE + 1), min(3, len(key) // 20 + 1)))
    cuts = [c for i, c in enumerate(cuts) if c - ([0, *cuts][i]) >= PIECE]
    return [key[a:b] for a, b in zip([0, *cuts], [*cuts, len(key)], strict=True)]


def readings(text: str) -> Iterator[str]:
    """Every way a reader could decode what is written (between the [redacted] marks)."""
    for part in text.split("[redacted]"):
        yield part
        yield part[::-1]
        yield unquote(part)
        yield re.sub(r"\\+u([0-9a-fA-F]{4})", lambda m: chr(int(m.group(1), 16)), part)
        for run in re.findall(r"[A-Za-z0-9+/_-]{8,}", part):
            for skip in range(4):
                yield _decoded(run[skip:].replace("-", "+").replace("_", "/"))
        for run in re.findall(r"[0-9A-Fa-f]{16,}", part):
            for skip in range(2):
                usable = run[skip:][: (len(run) - skip) // 2 * 2]
                yield bytes.fromhex(usable).decode("latin-1")


def _decoded(run: str) -> str:
    usable = run[: len(run) // 4 * 4]
    try:
        return base64.b64decode(usable).decode("latin-1")
    except (binascii.Error, ValueError):
        return ""


def recoverable(key: str, text: str) -> list[str]:
    """The 8-character pieces of `key` some reading of `text` gives back."""
    pieces = {key[i : i + PIECE] for i in range(len(key) - PIECE + 1)}
    return sorted({p for reading in readings(text) for p in pieces if p in reading})


KEY_ALPHABET = string.ascii_letters + string.digits + "-_"


def _key(rng: random.Random) -> str:
    prefix = rng.choice(["sk-", "sk-proj-", "AIza", "", "ghp_"])
    return prefix + "".join(rng.choice(KEY_ALPHABET) for _ in range(rng.randint(16, 90)))


@pytest.mark.parametrize("echo", sorted(ECHOES))
def test_every_encoded_echo_of_a_sent_key_is_redacted(echo: str, fuzz_counter: Any) -> None:
    from keymps.planning import redaction

    rng = random.Random(f"echoes {echo}")
    saved = set(redaction._remembered)
    try:
        for _case in range(50):
            key = _key(rng)
            redaction._remembered.intersection_update(saved)  # each case with its own key
            redaction.remember(key)
            said = f"you sent {ECHOES[echo](key, rng)}, thanks"
            for written in (redaction.redact_text(said), json.dumps(redaction.redact(said))):
                assert recoverable(key, written) == [], (echo, key, said, written)
            fuzz_counter.add("secrets/encoded echoes", (echo, key), "no leak")
    finally:
        redaction._remembered.clear()
        redaction._remembered.update(saved)


def test_the_check_sees_what_the_redactor_would_miss() -> None:
    """The reading check finds each echo when nothing is redacted: it can fail."""
    rng = random.Random(7)
    key = _key(rng)
    for echo, make in ECHOES.items():
        assert recoverable(key, make(key, rng)), echo


def test_redaction_keeps_innocent_text_and_stays_fast(fuzz_counter: Any) -> None:
    """The new forms blank no word of an ordinary answer, and 2 MB of answer stay cheap."""
    import time

    from keymps.planning.redaction import redact_text, remember

    remember("sk-" + secrets.token_hex(20))
    answer = json.dumps(
        {"keyword": "line", "pairs": [[[130, 130], [131, 129]]] * 40, "rationale": "one dot"}
    )
    assert redact_text(answer) == answer
    started = time.perf_counter()
    redact_text(answer * (2_000_000 // len(answer)))
    assert time.perf_counter() - started < 3.0
    fuzz_counter.add("secrets/encoded echoes", "innocent answer", "unchanged")


# --------------------------------------------------------------------------- a real run

KEY = "sk-echo-" + secrets.token_hex(16)
PASSWORD = "pw" + secrets.token_hex(12)


def _echoing(request: Recorded) -> str:
    rng = random.Random(1)
    said = "; ".join(make(KEY, rng) for make in ECHOES.values())
    said += "; " + _b64(f"lab:{PASSWORD}".encode()) + "; " + PASSWORD[::-1]
    answer = {"keyword": "line", "pairs": [[[130, 130], [130, 130]]], "rationale": said}
    return json.dumps(answer)


def test_a_real_run_writes_no_echo_of_the_key(
    tmp_path: Path, monkeypatch: Any, fuzz_counter: Any
) -> None:
    monkeypatch.setenv("LAB_VLM_API_KEY", KEY)
    monkeypatch.setenv("KEYMPS_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.setenv("KEYMPS_CONFIG", str(tmp_path / "config.yaml"))
    written = tmp_path / "written"
    task = task_copy(
        written / "task",
        **{
            "model: openai/gpt-4o": "model: openai/test-vlm\n  api_key_env: LAB_VLM_API_KEY",
            "Put 15 icing dots": "Put 1 icing dot",
        },
    )
    with VlmServer(responder=_echoing) as server:
        rng = random.Random(2)
        server.script(Reply.text_answer("no JSON, but " + ECHOES["base64 inside"](KEY, rng)))
        base = f"http://lab:{PASSWORD}@127.0.0.1:{server.port}/v1"
        result = CliRunner().invoke(
            cli,
            ["run", str(task), "--api-base", base, "--executor", "file",
             "--record", str(written / "cassette.jsonl"), "--out", str(written / "run")],
        )  # fmt: skip
        assert result.exit_code == 0, result.output
        assert len(server.chat_requests) == 2  # the invalid answer was repaired
    files = [p for p in [*written.rglob("*"), *(tmp_path / "cache").rglob("*")] if p.is_file()]
    assert {"run.json", "run.rrd", "cassette.jsonl"} <= {p.name for p in files}
    for path in files:
        text = path.read_bytes().decode("latin-1")
        for secret in (KEY, PASSWORD):
            assert recoverable(secret, text) == [], path
    assert recoverable(KEY, result.output) == []
    fuzz_counter.add("secrets/encoded echoes", "real run", f"{len(files)} files, no leak")
