"""Canaries: secrets planted every way a run could leak them never appear in a byte it writes.

`keymps run` against tests/helpers/vlm_server.py on 127.0.0.1, a successful run in its own process
(python -m keymps.cli.app) and a failing one in this process (click's streams and the file
descriptors both captured), with canaries as

- a key under an odd variable name (planner.api_key_env: MY_ODD_VLM_KEY, allowed by the user
  config), which the server quotes back into the answer's rationale and into a first, invalid
  answer (so a repair turn is recorded too);
- a key of 7 characters (SHORT_API_KEY), which a failing server quotes in its error message;
- a key-like query parameter and the userinfo of --api-base (`?api_key=`, `user:key@`);
- a credential-like variable the run does not use (OPENAI_API_KEY), which the server quotes.

Every byte under the run folders, the answer cache and the cassette, and the captured stdout
and stderr of both runs, is then searched for every canary (raw, JSON-escaped and
URL-encoded), and a marker that must be there shows the search sees inside run.rrd.
"""

from __future__ import annotations

import json
import os
import secrets
import string
import subprocess
import sys
from pathlib import Path
from typing import Any
from urllib.parse import quote

from click.testing import CliRunner
from helpers.fuzz_support import task_copy
from helpers.vlm_server import Recorded, Reply, VlmServer

from keymps.cli.app import cli

ODD = "odd-" + secrets.token_hex(10)
SHORT = "".join(secrets.choice(string.ascii_letters) for _ in range(6)) + "7"
QUERY = "qk" + secrets.token_hex(10)
USERINFO = "pw" + secrets.token_hex(10)
UNUSED = "sk-unused-" + secrets.token_hex(10)
CANARIES = {"odd name": ODD, "short": SHORT, "query": QUERY, "userinfo": USERINFO, "env": UNUSED}
MARKER = "MARKER" + secrets.token_hex(6)


def _quoting(request: Recorded) -> str:
    """A valid answer whose rationale quotes the credentials the request carried."""
    heard = request.headers.get("authorization", "")
    return json.dumps(
        {
            "keyword": "line",
            "pairs": [[[130, 130], [130, 130]]],
            "rationale": f"you sent '{heard}'; also {UNUSED} and {ODD[:-1]}{ODD[-1]}",
        }
    )


def _keymps(env: dict[str, str], *args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "keymps.cli.app", *args],
        env=env,
        capture_output=True,
        text=True,
        timeout=240,
    )


def _leaks(data: bytes, where: str) -> list[str]:
    found = []
    for name, canary in CANARIES.items():
        for form in {canary, json.dumps(canary)[1:-1], quote(canary, safe="")}:
            if form.encode() in data:
                found.append(f"{where} contains the {name} canary")
    return found


def test_no_canary_in_any_byte_written_or_printed(
    tmp_path: Path, monkeypatch: Any, capfd: Any, fuzz_counter: Any
) -> None:
    config = tmp_path / "config.yaml"
    config.write_text("api_key_envs: [MY_ODD_VLM_KEY]\n")
    planted = {
        "MY_ODD_VLM_KEY": ODD,
        "SHORT_API_KEY": SHORT,
        "OPENAI_API_KEY": UNUSED,
        "KEYMPS_CACHE_DIR": str(tmp_path / "cache"),
        "KEYMPS_CONFIG": str(config),
    }
    for name, value in planted.items():
        monkeypatch.setenv(name, value)
    env = {**os.environ, **planted}
    written = tmp_path / "written"
    printed: dict[str, str] = {}
    with VlmServer(responder=_quoting) as server:
        task = task_copy(
            written / "task",
            **{
                "model: openai/gpt-4o": "model: openai/test-vlm\n  api_key_env: MY_ODD_VLM_KEY",
                "Put 15 icing dots around the cake": f"Put 1 icing dot on the cake {MARKER}",
            },
        )
        server.script(Reply.text_answer(f"no JSON today, {ODD}"))
        good = _keymps(
            env, "run", str(task), "--api-base", f"{server.openai_base}?api_key={QUERY}",
            "--record", str(written / "cassette.jsonl"), "--executor", "file",
            "--out", str(written / "run"),
        )  # fmt: skip
        printed["good run"] = good.stdout + good.stderr
        assert good.returncode == 0, printed["good run"]
        chats = [r for r in server.requests if r.path.endswith("chat/completions")]
        assert [r.headers["authorization"] for r in chats] == [f"Bearer {ODD}"] * 2
        short_task = task_copy(
            written / "short",
            **{"model: openai/gpt-4o": "model: openai/test-vlm\n  api_key_env: SHORT_API_KEY"},
        )
        server.script(Reply.error(400, message=f"bad key {SHORT} at lab:{USERINFO}, {UNUSED}"))
        userinfo_base = f"http://lab:{USERINFO}@127.0.0.1:{server.port}/v1"
        failed = CliRunner().invoke(
            cli, ["run", str(short_task), "--api-base", userinfo_base, "--no-cache",
                  "--out", str(written / "failed")],
        )  # fmt: skip
        descriptors = capfd.readouterr()
        printed["failed run"] = failed.output + descriptors.out + descriptors.err
        assert failed.exit_code == 1 and "refused the request" in failed.output, failed.output
    files = [p for p in written.rglob("*") if p.is_file()]
    files += [p for p in (tmp_path / "cache").rglob("*") if p.is_file()]
    names = {p.relative_to(tmp_path).as_posix() for p in files}
    for expected in ("written/run/run.json", "written/run/run.rrd", "written/cassette.jsonl"):
        assert expected in names
    assert any(n.startswith("written/run/vlm/") for n in names)
    assert any(n.startswith("cache/") for n in names), "the valid answer was cached"
    assert "written/failed/run.json" in names
    assert MARKER.encode() in (written / "run" / "run.rrd").read_bytes(), "the search sees it"
    rationale = json.loads((written / "run" / "run.json").read_text())["rationale"]
    assert "[redacted]" in rationale, "the server did quote the key"
    leaks = [leak for path in files for leak in _leaks(path.read_bytes(), str(path))]
    leaks += [leak for name, text in printed.items() for leak in _leaks(text.encode(), name)]
    assert leaks == []
    fuzz_counter.add("secrets/canaries", tuple(CANARIES), f"{len(files)} files, no leak")
