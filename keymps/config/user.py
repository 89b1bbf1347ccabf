"""The user's own configuration file: what a shared task file cannot grant itself.

    # ~/.config/keymps/config.yaml (platformdirs.user_config_dir("keymps"), or $KEYMPS_CONFIG)
    trusted_api_bases:      # servers that receive your API keys even when only a task names them
      - https://vlm.mylab.example.org/v1
    api_key_envs:           # further variables a task's planner.api_key_env may name
      - MY_VLM_KEY

A missing file is an empty configuration; a broken one is an error naming file:line:col
(docs/security.md).
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass
from pathlib import Path
from urllib.parse import urlsplit

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator

from keymps.errors import KeympsError

MAX_CONFIG_BYTES = 64 * 1024
ENV_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")


class _ConfigFile(BaseModel):
    # built when a configuration file is first read: most runs have none (about 4 ms)
    model_config = ConfigDict(extra="forbid", frozen=True, defer_build=True)
    trusted_api_bases: list[str] = Field(default_factory=list, max_length=100)
    api_key_envs: list[str] = Field(default_factory=list, max_length=100)

    @field_validator("trusted_api_bases")
    @classmethod
    def _urls(cls, values: list[str]) -> list[str]:
        for value in values:
            parts = urlsplit(value)
            if parts.scheme not in ("http", "https") or not parts.hostname:
                raise ValueError(f"{value!r} is not an http(s) URL with a host")
        return values

    @field_validator("api_key_envs")
    @classmethod
    def _names(cls, values: list[str]) -> list[str]:
        for value in values:
            if not ENV_NAME.fullmatch(value):
                raise ValueError(f"{value!r} is not an environment variable name")
        return values


@dataclass(frozen=True)
class UserConfig:
    """What the user allows beyond the defaults (docs/security.md)."""

    path: Path
    trusted_api_bases: tuple[str, ...] = ()
    api_key_envs: tuple[str, ...] = ()


def config_path() -> Path:
    """$KEYMPS_CONFIG, else config.yaml in the user's config folder (~/.config/keymps)."""
    configured = os.environ.get("KEYMPS_CONFIG")
    if configured:
        return Path(configured).expanduser()
    import platformdirs

    return Path(platformdirs.user_config_dir("keymps")) / "config.yaml"


def load_user_config() -> UserConfig:
    """The user's configuration (empty when the file does not exist)."""
    from keymps.config.yaml_positions import YamlSyntaxError, load_yaml_with_positions

    path = config_path()
    try:
        if not path.is_file():
            if path.exists():
                raise KeympsError(f"{path}: the user configuration is not a regular file")
            return UserConfig(path)
        if path.stat().st_size > MAX_CONFIG_BYTES:
            raise KeympsError(f"{path}: more than {MAX_CONFIG_BYTES} bytes; not a keymps config")
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as error:
        raise KeympsError(f"{path}: cannot read the user configuration ({error})") from None
    try:
        parsed = load_yaml_with_positions(text)
    except YamlSyntaxError as error:
        line, column = error.location
        raise KeympsError(f"{path}:{line}:{column}: invalid YAML: {error}") from None
    if parsed.data is None:
        return UserConfig(path)
    if not isinstance(parsed.data, dict):
        raise KeympsError(f"{path}:1:1: expected a mapping (trusted_api_bases, api_key_envs)")
    try:
        data = _ConfigFile.model_validate(parsed.data)
    except ValidationError as error:
        item = error.errors(include_url=False)[0]
        loc = tuple(item["loc"])
        line, column = parsed.locate(loc, at_key=item["type"] == "extra_forbidden")
        field = ".".join(str(p) for p in loc) or "(config)"
        message = "unknown key" if item["type"] == "extra_forbidden" else item["msg"]
        message = message.removeprefix("Value error, ")
        raise KeympsError(f"{path}:{line}:{column}: {field}: {message}") from None
    return UserConfig(path, tuple(data.trusted_api_bases), tuple(data.api_key_envs))
