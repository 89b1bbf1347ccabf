"""Request digests, the on-disk answer cache, and cassettes (JSONL records of answers)."""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import stat
import time
from pathlib import Path
from typing import Any

from keymps.config.trust import MAX_CASSETTE_BYTES
from keymps.errors import KeympsError


def _canonical(value: Any) -> bytes:
    return json.dumps(value, sort_keys=True, separators=(",", ":"), ensure_ascii=False).encode()


def request_digest(messages: Any, schema: Any, model: str | None = None) -> str:
    """sha256 of the messages (image included) and schema, and the model when given."""
    payload: dict[str, Any] = {"messages": messages, "schema": schema}
    if model is not None:
        payload["model"] = model
    return hashlib.sha256(_canonical(payload)).hexdigest()


def cache_dir() -> Path:
    """KEYMPS_CACHE_DIR, else the user's cache folder (platformdirs) / keymps / vlm."""
    configured = os.environ.get("KEYMPS_CACHE_DIR")
    if configured:
        return Path(configured).expanduser()
    import platformdirs

    return Path(platformdirs.user_cache_dir("keymps")) / "vlm"


class AnswerCache:
    """Answers by cache key: one small JSON file each, written atomically."""

    def __init__(self, folder: Path | None = None):
        self.folder = folder or cache_dir()

    def _path(self, key: str) -> Path:
        return self.folder / key[:2] / f"{key}.json"

    def get(self, key: str) -> dict[str, Any] | None:
        path = self._path(key)
        try:
            data = json.loads(path.read_text(encoding="utf-8"))
        except (OSError, ValueError, RecursionError):  # unreadable, not UTF-8, not JSON: a miss
            return None
        if not isinstance(data, dict) or not isinstance(data.get("text"), str):
            return None
        return data if _counts_are_valid(data) else None

    def put(self, key: str, entry: dict[str, Any]) -> None:
        path = self._path(key)
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            temporary = path.with_suffix(f".{os.getpid()}.tmp")
            temporary.write_text(json.dumps({**entry, "saved": time.time()}), encoding="utf-8")
            temporary.replace(path)
        except OSError:
            # a read-only or full cache costs a future call, never the run
            with contextlib.suppress(OSError):
                temporary.unlink()


def append_to_cassette(path: Path, entry: dict[str, Any]) -> None:
    """Add one request digest and its answer to a JSONL cassette."""
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with path.open("a", encoding="utf-8") as handle:
            handle.write(json.dumps(entry, sort_keys=True) + "\n")
    except OSError as error:
        raise KeympsError(f"--record: cannot write the cassette {path}: {error.strerror}") from None


def read_cassette(path: Path) -> dict[str, dict[str, Any]]:
    """digest -> entry; a later entry for the same digest wins."""
    try:
        info = path.stat()
        if not stat.S_ISREG(info.st_mode):  # /dev/zero or a FIFO named as planner.cassette
            raise KeympsError(f"cassette {path} is not a regular file")
        if info.st_size > MAX_CASSETTE_BYTES:
            raise KeympsError(
                f"cassette {path}: {info.st_size} bytes, more than {MAX_CASSETTE_BYTES}"
            )
        lines = path.read_text(encoding="utf-8").splitlines()
    except FileNotFoundError:
        raise KeympsError(f"cassette not found: {path}") from None
    except OSError as error:
        raise KeympsError(f"cannot read the cassette {path}: {error.strerror}") from None
    except UnicodeDecodeError:
        raise KeympsError(f"cassette {path} is not a UTF-8 text (JSONL) file") from None
    entries: dict[str, dict[str, Any]] = {}
    for number, line in enumerate(lines, start=1):
        if not line.strip():
            continue
        try:
            entry = json.loads(line)
        except json.JSONDecodeError as error:
            raise KeympsError(f"{path}:{number}: not a JSON line ({error.msg})") from None
        except (ValueError, RecursionError):  # a 5000-digit number, nesting 100,000 deep
            raise KeympsError(f"{path}:{number}: not a JSON line keymps can read") from None
        if not isinstance(entry, dict) or "digest" not in entry or "answer" not in entry:
            raise KeympsError(f"{path}:{number}: a cassette line needs 'digest' and 'answer'")
        if not isinstance(entry["answer"], str) or not _counts_are_valid(entry):
            raise KeympsError(
                f"{path}:{number}: 'answer' must be text and the token counts whole numbers"
            )
        entries[str(entry["digest"])] = entry
    return entries


def _counts_are_valid(entry: dict[str, Any]) -> bool:
    """Token counts are whole numbers or missing (run.json adds them up)."""
    return all(
        entry.get(name) is None or (type(entry[name]) is int and entry[name] >= 0)
        for name in ("prompt_tokens", "completion_tokens")
    )
