"""What a task file may make keymps do with the user's secrets and files (docs/security.md).

A task file is shared between labs, so it is not trusted with anything the user did not give:

- `planner.api_key_env` may name only a provider-style key variable (KEY_ENV_PATTERN, a few
  known names, or a name the user lists in their own config): never AWS_SECRET_ACCESS_KEY;
- an `api_base` only a task file names receives no key (keymps.planning.backend_choice);
- files a task makes keymps read and send (prompts, primitives, a cassette) must be regular
  files inside the task's folder or the documented search folders, and small.
"""

from __future__ import annotations

import errno
import os
import re
import stat
from collections.abc import Sequence
from pathlib import Path
from urllib.parse import urlsplit

KEY_ENV_PATTERN = re.compile(r"[A-Z][A-Z0-9_]*_API_(KEY|TOKEN)")
"""Names a task's planner.api_key_env may use: OPENAI_API_KEY, LAB_VLM_API_KEY, ... Matched
whole (`fullmatch`: a `$` also matches before a final newline, which let "X_API_KEY\n" pass)."""
KNOWN_KEY_ENVS = frozenset({"HF_TOKEN", "WATSONX_APIKEY", "AZURE_AD_TOKEN"})
"""Provider variables litellm documents that do not follow KEY_ENV_PATTERN."""
NEVER_READ = (Path("/proc"), Path("/sys"), Path("/dev"))
"""Kernel and device files: a task never makes keymps read one, whatever folder it names."""
MAX_PROMPT_BYTES = 256 * 1024
"""A prompt template is a few kilobytes of Markdown."""
MAX_PRIMITIVE_BYTES = 4 * 1024 * 1024
"""A primitive file is a few kilobytes of YAML (DMP weights)."""
MAX_CASSETTE_BYTES = 256 * 1024 * 1024
"""A cassette holds text answers: tens of thousands of them fit in far less."""


def api_key_env_problem(name: str, allowed: Sequence[str] = ()) -> str | None:
    """Why a task file may not name the variable `name` (None when it may)."""
    if KEY_ENV_PATTERN.fullmatch(name) or name in KNOWN_KEY_ENVS or name in allowed:
        return None
    return (
        f"{name!r} is not a provider key variable: a task file may name only NAME_API_KEY "
        "(or NAME_API_TOKEN) variables; list others under api_key_envs in your user config "
        "(docs/security.md)"
    )


def shown_path(path: Path) -> str:
    """A path for a one-line message: as it is, or quoted with escapes when it holds a newline
    or another character that is not printable (a task file can write any)."""
    text = str(path)
    return text if text.isprintable() else repr(text)


def readable_file_problem(path: Path, roots: Sequence[Path], max_bytes: int) -> str | None:
    """Why `path` may not be read on a task's behalf (None when it may): it must be a regular
    file, at most `max_bytes`, whose real path (symlinks followed) is inside one of `roots` and
    in no hidden file or folder of it (`.ssh`, `.env`: a task saved in your home folder is no
    reason to read those). A root that is itself a link is not followed (`anchored`), and a path
    outside every root gets the same answer whether a file is there or not."""
    shown = shown_path(path)
    try:
        real = path.resolve()  # links followed as far as they lead; no file needed
    except ValueError:  # a NUL character: no file can have this name
        return f"not a valid file name: {shown}"
    except RuntimeError:  # a symlink loop (an OSError from Python 3.13)
        return f"cannot resolve {shown}: a symlink loop"
    except OSError as error:
        why = "a symlink loop" if error.errno == errno.ELOOP else error.strerror or error
        return f"cannot resolve {shown}: {why}"
    if any(real == p or p in real.parents for p in NEVER_READ):
        return f"{shown} is a kernel or device file ({real}); not read"
    real_roots = [anchored(root) for root in roots]
    holding = [root for root in real_roots if root in real.parents]
    if not holding:
        searched = ", ".join(str(r) for r in real_roots)
        return (
            f"{shown} is outside the task's folder and the search folders ({searched}); "
            "copy it next to the task"
        )
    innermost = max(holding, key=lambda root: len(root.parts))
    hidden = next((part for part in real.relative_to(innermost).parts if part[:1] == "."), None)
    if hidden is not None:
        return f"{shown} is in the hidden file or folder {hidden!r} of {innermost}; not read"
    try:
        info = real.stat()
    except FileNotFoundError:
        return f"file not found: {shown}"
    except OSError as error:
        return f"cannot read {shown}: {error.strerror or error}"
    if not stat.S_ISREG(info.st_mode):
        return f"{shown} is not a regular file (a folder, device, pipe or socket)"
    if info.st_size > max_bytes:
        return (
            f"{shown}: {info.st_size} bytes, more than the {max_bytes} a file of its kind may have"
        )
    return None


def anchored(folder: Path) -> Path:
    """`folder` made absolute with the links above it followed, but not a link that `folder`
    itself is: a shared task folder's `prompts -> /` stays `<task>/prompts`, inside which no
    file under `/` lies. Pass a folder the user chose (`$KEYMPS_PROMPTS_PATH`) resolved: its
    own link is theirs to follow."""
    absolute = Path(os.path.abspath(folder))
    if absolute.name in ("", ".", ".."):  # the root folder
        return real_path(absolute)
    return real_path(absolute.parent) / absolute.name


def others_may_write(folder: Path) -> bool:
    """Whether another user could have put files in `folder`: it is world-writable (like /tmp)
    or owned by someone other than this user or root. Such a folder outside the task's own
    tree (a task in /tmp/x looks in /tmp/primitives) is not searched: a planted primitive
    would change the arm's motion."""
    try:
        info = folder.stat()
    except OSError:
        return False
    return bool(info.st_mode & stat.S_IWOTH) or info.st_uid not in (os.getuid(), 0)


def shared_folders_left_out(folders: Sequence[Path]) -> list[Path]:
    """`folders` without those `others_may_write`."""
    return [folder for folder in folders if not others_may_write(folder)]


def prompt_search_dirs(task_folder: Path) -> list[Path]:
    """Where prompt templates are looked for, first match wins: the task folder's prompts/ and
    ../prompts, each folder in KEYMPS_PROMPTS_PATH, ./prompts, the bundled prompts. The user's
    folders come resolved; the others as written, so that a link which one of them is does
    not lead the check elsewhere (`anchored`)."""
    *chosen, bundled = user_prompt_dirs()
    own = [task_folder / "prompts", *shared_folders_left_out([task_folder.parent / "prompts"])]
    return [*own, *chosen, *shared_folders_left_out([Path.cwd() / "prompts"]), bundled]


def user_prompt_dirs() -> list[Path]:
    """The prompt folders the user chose (KEYMPS_PROMPTS_PATH) and the bundled one, resolved:
    what is in them is the user's, not a shared task's."""
    from keymps.bundled import bundled_dir

    chosen = [Path(p) for p in os.environ.get("KEYMPS_PROMPTS_PATH", "").split(os.pathsep) if p]
    return [real_path(folder) for folder in [*chosen, bundled_dir("prompts")]]


def prompt_roots(task_folder: Path) -> list[Path]:
    """Folders a prompt file may be in: the task's folder tree and the prompt search folders."""
    return [real_path(task_folder), *prompt_search_dirs(task_folder)]


def real_path(folder: Path) -> Path:
    """`folder` with links followed (as written, made absolute, for a link loop)."""
    try:
        return folder.resolve()
    except (OSError, RuntimeError):
        return Path(os.path.abspath(folder))


PROVIDER_HOSTS: dict[str, tuple[str, ...]] = {
    "openai": ("api.openai.com",),
    "anthropic": ("api.anthropic.com",),
    "gemini": ("generativelanguage.googleapis.com",),
    "mistral": ("api.mistral.ai",),
    "groq": ("api.groq.com",),
    "openrouter": ("openrouter.ai",),
    "together_ai": ("api.together.xyz",),
    "xai": ("api.x.ai",),
    "deepseek": ("api.deepseek.com",),
}
"""The providers' own endpoints (https only): a task naming one still sends the key there."""


def is_provider_endpoint(api_base: str, provider: str) -> bool:
    """True when `api_base` is the provider's own https endpoint."""
    parts = urlsplit(api_base)
    return parts.scheme == "https" and (parts.hostname or "") in PROVIDER_HOSTS.get(provider, ())


def same_server(api_base: str, trusted: str) -> bool:
    """True when `api_base` is `trusted` or a path below it (scheme, host and port equal)."""
    a, b = urlsplit(api_base.strip()), urlsplit(trusted.strip())
    try:
        ports = (a.port or _default_port(a.scheme), b.port or _default_port(b.scheme))
    except ValueError:  # a port that is not a number
        return False
    if (a.scheme.lower(), (a.hostname or "").lower()) != (b.scheme.lower(), (b.hostname or "")):
        return False
    if ports[0] != ports[1]:
        return False
    # "/v1/../other" is below "/v1" as text, and a sibling once the server resolves it: a path
    # with dot segments (or an encoded dot) is never the trusted one
    if any(step in (".", "..") for step in a.path.split("/")) or "%2e" in a.path.lower():
        return False
    path, prefix = a.path.rstrip("/"), b.path.rstrip("/")
    return path == prefix or path.startswith(prefix + "/")


def _default_port(scheme: str) -> int | None:
    return {"http": 80, "https": 443}.get(scheme.lower())
