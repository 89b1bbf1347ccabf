"""The one redactor: every secret a run could send is removed from everything written or printed.

Secrets are matched by value, not by the name of the field they sit in:

- every key a backend sent or may send (`remember`): redacted whatever its length or the name
  of the variable it came from;
- the value of every credential-like environment variable (a name with a word KEY, TOKEN,
  SECRET, PASSWORD or CREDENTIALS) of at least MIN_ENV_SECRET characters, as servers may quote
  any of them back;
- the userinfo of any URL (`https://user:key@host`) and key-like query parameters
  (`?api_key=`, `?key=`, `&token=` ...);
- each of those secrets however a server quotes it back: encoded (base64, hex, %XX, \\uXXXX,
  reversed) or, for a key that is sent, in pieces (keymps.planning.secret_forms).

run.json, vlm/ records, cassettes, the answer cache, the Rerun recording, the console and eval
outputs all pass through `redact` (docs/security.md).
"""

from __future__ import annotations

import functools
import os
import re
import threading
from collections.abc import Iterable, Iterator
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


Form = str | re.Pattern[str]
"""A secret as written somewhere: a literal, or a pattern (its \\uXXXX escapes)."""


def known_secrets(extra: Iterable[str] = ()) -> list[Form]:
    """Every form of every secret to remove: each value as it is, JSON-escaped and encoded
    (base64, hex, %XX, reversed; its \\uXXXX escapes as a pattern), and the pieces of every
    key that is sent or may be (`remember`, `extra`) however a server splits it
    (keymps.planning.secret_forms)."""
    with _lock:
        sent = set(_remembered)
    sent.update(s for s in extra if s)
    sent -= NOT_SECRETS
    return list(_forms_of(frozenset(sent | set(environment_secrets())), frozenset(sent)))


@functools.lru_cache(maxsize=32)
def _forms_of(values: frozenset[str], sent: frozenset[str]) -> tuple[Form, ...]:
    """`known_secrets` for these values (`sent`: those whose pieces count too), longest first;
    cached, since every write redacts and the secrets rarely change."""
    from keymps.planning.secret_forms import encoded_forms, escape_pattern, fragments

    forms: set[str] = set()
    for value in values:
        forms |= encoded_forms(value)
    for value in sent:
        forms |= fragments(value)
    escaped = escape_pattern(values)
    return (*sorted(forms - NOT_SECRETS, key=len, reverse=True), *([escaped] if escaped else []))


def redact_text(text: str, secrets: Iterable[Form] | None = None) -> str:
    """`text` with every secret (`known_secrets`, or the forms given), URL userinfo and
    key-like URL parameter replaced; overlapping or adjoining pieces of a secret become one
    `[redacted]`."""
    forms = known_secrets() if secrets is None else secrets
    text = _replace_runs([form for form in forms if form and form not in NOT_SECRETS], text)
    text = _URL_USERINFO.sub(lambda m: m.group("scheme") + REDACTED + "@", text)
    return _KEY_QUERY.sub(lambda m: m.group("name") + REDACTED, text)


def _replace_runs(forms: list[Form], text: str) -> str:
    """`text` with every stretch that occurrences of `forms` cover, overlapping ones joined,
    replaced by one REDACTED (the pieces of a split key overlap). str.find per form: a few
    hundred forms cost milliseconds per megabyte, where one regular expression of them all
    tried every alternative at every character."""
    spans = sorted(span for form in forms for span in _occurrences(form, text))
    merged: list[list[int]] = []
    for start, end in spans:
        if merged and start < merged[-1][1]:
            merged[-1][1] = max(merged[-1][1], end)
        else:
            merged.append([start, end])
    pieces, done = [], 0
    for start, end in merged:
        pieces += [text[done:start], REDACTED]
        done = end
    return "".join([*pieces, text[done:]])


def _occurrences(form: Form, text: str) -> Iterator[tuple[int, int]]:
    """(start, end) of every occurrence of `form` in `text`, overlapping literals included."""
    if isinstance(form, re.Pattern):
        yield from (found.span() for found in form.finditer(text))
        return
    at = text.find(form)
    while at >= 0:
        yield at, at + len(form)
        at = text.find(form, at + 1)


def redact(value: Any, extra: Iterable[str] = ()) -> Any:
    """A copy of `value` (JSON-like data or text) with every secret removed: the values of
    credential-like mapping keys blanked whole, secrets replaced inside every string value."""
    secrets = known_secrets(extra)
    return _redact(value, secrets)


def _redact(value: Any, secrets: list[Form]) -> Any:
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
