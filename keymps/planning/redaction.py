"""The one redactor: every secret a run could send is removed from everything written or printed.

Secrets are matched by value, not by the name of the field they sit in:

- every key a backend sent or may send (`remember`): redacted whatever its length or the name
  of the variable it came from;
- the value of every credential-like environment variable (a name with a word KEY, TOKEN,
  SECRET, PASSWORD or CREDENTIALS) of at least MIN_ENV_SECRET characters, as servers may quote
  any of them back;
- the userinfo of any URL (`https://user:key@host`) and key-like query parameters
  (`?api_key=`, `?key=`, `&token=` ...).

run.json, vlm/ records, cassettes, the answer cache, the Rerun recording, the console and eval
outputs all pass through `redact` (docs/security.md).
"""

from __future__ import annotations

import functools
import json
import os
import re
import threading
from collections.abc import Iterable
from typing import Any

REDACTED = "[redacted]"
MIN_ENV_SECRET = 8
"""Environment values shorter than this are redacted only when a backend actually uses them
(`remember`): blanking every 'x' of a FOO_TOKEN=x would make every record unreadable."""
NOT_SECRETS = frozenset({"", "no-key-needed"})
"""Placeholders sent to keyless local servers."""

SECRET_FIELD = re.compile(
    r"^(api[_-]?key|x-api-key|authorization|proxy-authorization|secret|password|"
    r"access[_-]?token|token|\w*_secret)$",
    re.IGNORECASE,
)
"""Mapping keys whose values are dropped whole, whatever they hold."""
SECRET_ENV_NAME = re.compile(
    r"(?:^|_)(?:[A-Z]*KEYS?|[A-Z]*TOKENS?|SECRETS?|PASSWORDS?|PASSWD|PASS|CREDENTIALS?|PAT)(?:_|$)",
    re.IGNORECASE,
)
"""Names of credential-like environment variables (OPENAI_API_KEY, MY_VLM_KEY, GITHUB_TOKEN,
AWS_SECRET_ACCESS_KEY ...), matched by whole words so that KEYMPS_CACHE_DIR is not one."""
# The scheme is matched from the start of its run of scheme characters only: tried from every
# letter of a long word, the search was quadratic (a 2 MB answer took minutes to redact).
_URL_USERINFO = re.compile(r"(?<![a-zA-Z0-9+.-])(?P<scheme>[a-zA-Z0-9+.-]*://)[^/\s@\"'<>]+@")
_KEY_QUERY = re.compile(
    r"(?P<name>[?&;](?:[\w.-]*api[_-]?key|key|token|access[_-]?token|auth|secret|password|"
    r"sig|signature|x-goog-api-key)=)[^&#\s\"'<>]+?(?=[:,;.)\]]?(?:[&#\s\"'<>]|$))",
    re.IGNORECASE,
)

_lock = threading.Lock()
_remembered: set[str] = set()


def remember(*secrets: str | None) -> None:
    """Values this process sends or may send as credentials: redacted from now on, any length."""
    with _lock:
        _remembered.update(s for s in secrets if s and s not in NOT_SECRETS)


def url_secrets(url: str | None) -> list[str]:
    """The credentials inside a URL: its userinfo (user, password) and key-like parameters."""
    if not url:
        return []
    from urllib.parse import parse_qsl, unquote, urlsplit

    try:
        parts = urlsplit(url)
    except ValueError:
        return []
    found = []
    if "@" in parts.netloc:  # the password; a user name alone is often the token itself
        found.append(unquote(parts.password or parts.username or ""))
        found.append(parts.netloc.rsplit("@", 1)[0])
    query = _KEY_QUERY.findall("?" + parts.query) and parse_qsl(parts.query)
    for name, value in query or ():
        if _KEY_QUERY.match(f"?{name}=x"):
            found.append(value)
    return [value for value in found if value]


def secret_variables() -> dict[str, str]:
    """Credential-like environment variables (name -> value), values at least MIN_ENV_SECRET
    long."""
    return {
        name: value
        for name, value in os.environ.items()
        if SECRET_ENV_NAME.search(name) and len(value) >= MIN_ENV_SECRET
    }


def environment_secrets() -> list[str]:
    """Values of credential-like environment variables, at least MIN_ENV_SECRET long."""
    return list(secret_variables().values())


def known_secrets(extra: Iterable[str] = ()) -> list[str]:
    """Every secret value to remove, longest first (a key containing another goes whole)."""
    with _lock:
        values = set(_remembered)
    values.update(environment_secrets())
    values.update(s for s in extra if s and s not in NOT_SECRETS)
    values -= NOT_SECRETS
    forms = set(values)
    for value in values:  # as it appears inside JSON text (escaped quotes, slashes, unicode)
        forms.add(json.dumps(value)[1:-1])
        forms.add(json.dumps(value, ensure_ascii=False)[1:-1])
    return sorted(forms, key=len, reverse=True)


def redact_text(text: str, secrets: Iterable[str] | None = None) -> str:
    """`text` with every secret, URL userinfo and key-like URL parameter replaced."""
    pattern = _pattern(tuple(known_secrets() if secrets is None else secrets))
    if pattern is not None:  # one pass: a replacement is never searched again
        text = pattern.sub(REDACTED, text)
    text = _URL_USERINFO.sub(lambda m: m.group("scheme") + REDACTED + "@", text)
    return _KEY_QUERY.sub(lambda m: m.group("name") + REDACTED, text)


@functools.lru_cache(maxsize=16)
def _pattern(secrets: tuple[str, ...]) -> re.Pattern[str] | None:
    """One regular expression matching any of `secrets`, the longest first."""
    ordered = sorted(set(secrets) - NOT_SECRETS, key=len, reverse=True)
    return re.compile("|".join(map(re.escape, ordered))) if ordered else None


def redact(value: Any, extra: Iterable[str] = ()) -> Any:
    """A copy of `value` (JSON-like data or text) with every secret removed: the values of
    credential-like mapping keys blanked whole, secrets replaced inside every string value."""
    secrets = known_secrets(extra)
    return _redact(value, secrets)


def _redact(value: Any, secrets: list[str]) -> Any:
    if isinstance(value, str):
        return redact_text(value, secrets)
    if isinstance(value, dict):
        return {
            k: REDACTED if SECRET_FIELD.match(str(k)) else _redact(v, secrets)
            for k, v in value.items()
        }
    if isinstance(value, list | tuple):
        return [_redact(v, secrets) for v in value]
    return value
