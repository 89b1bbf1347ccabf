"""Names are matched whole: a `$` in a pattern also matches before a final newline.

`planner.api_key_env: "X_API_KEY\\n"` passed validation (re.match with `$`), as did such names
in the user config and primitive names; each is refused now, and the plain names still pass.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from keymps.config.trust import api_key_env_problem
from keymps.errors import KeympsError


@pytest.mark.parametrize("name", ["X_API_KEY\n", "OPENAI_API_KEY\n", "HF_TOKEN\n", "X_API_KEY\r"])
def test_a_key_variable_with_a_trailing_newline_is_refused(name: str, fuzz_counter: Any) -> None:
    assert api_key_env_problem(name) is not None
    assert api_key_env_problem(name.strip()) is None
    fuzz_counter.add("VLM attacks/whole names", ("api_key_env", name), "refused")


def test_the_user_configs_names_are_matched_whole(tmp_path: Path, monkeypatch: Any) -> None:
    from keymps.config.user import load_user_config

    config = tmp_path / "config.yaml"
    monkeypatch.setenv("KEYMPS_CONFIG", str(config))
    config.write_text('api_key_envs: ["MY_VLM_KEY\\n"]\n')
    with pytest.raises(KeympsError, match="is not an environment variable name"):
        load_user_config()
    config.write_text("api_key_envs: [MY_VLM_KEY]\n")
    assert load_user_config().api_key_envs == ("MY_VLM_KEY",)


def test_a_primitive_name_is_matched_whole() -> None:
    from keymps.primitives.dictionary import _check_name

    with pytest.raises(KeympsError):
        _check_name("line\n", "line.yaml")
    assert _check_name("line", "line.yaml") == "line"
