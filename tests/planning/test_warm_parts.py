"""The warm planner's parts on their own: its messages, the variables a request carries, the
mode a command asks for, and the rules for its folder (tests/planning/test_warm_planner.py runs
the real processes)."""

from __future__ import annotations

import json
import os
import socket
import struct
import threading
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from keymps.errors import KeympsError
from keymps.planning.warm.client import call_environment, server_environment
from keymps.planning.warm.dispatch import mode_from
from keymps.planning.warm.place import MAX_SOCKET_PATH, Place, folder_problem
from keymps.planning.warm.wire import (
    MAX_MESSAGE_BYTES,
    WireError,
    answer_from_wire,
    answer_to_wire,
    receive,
    request_from_wire,
    request_to_wire,
    send,
)
from keymps.types import BackendAnswer, PlanObject, PlanRequest


def _request(rng: np.random.Generator) -> PlanRequest:
    width, height = (int(v) for v in rng.integers(1, 2000, size=2))
    masked = PlanObject(
        id=2,
        name="banana",
        height=0.035,
        bbox_px=(1, 2, 30, 40),
        mask=np.ones((height, width), bool),
        size_m=(0.18, 0.044),
    )
    return PlanRequest(
        instruction=f'Put {int(rng.integers(1, 99))} dots around the cake ü \u2028 "q"',
        crop=rng.integers(0, 255, size=(height, width, 3), dtype=np.uint8),
        crop_mask=rng.random((height, width)) > 0.5,
        metres_per_px=(float(rng.random()), float(rng.random())),
        primitives={"line": "icing", "straight": "soft objects"},
        object_height=float(rng.random()),
        max_pairs=int(rng.integers(1, 100)),
        messages=[
            {"role": "system", "content": "prompt"},
            {"role": "user", "content": [{"type": "image_url", "image_url": {"url": "data:x"}}]},
        ],
        schema={"name": "plan", "strict": True, "schema": {"type": "object"}},
        step="pairs",
        keyword="line",
        previous_errors=("pair 1 is off the image", "no keyword"),
        attempt=2,
        model="openai/test-vlm",
        temperature=0.3,
        timeout_s=12.5,
        task_name="cake-icing",
        line_width_mm=4.0,
        share_key="abc",
        objects=(masked,),
    )


def test_a_request_crosses_whole_but_its_pixels() -> None:
    rng = np.random.default_rng(7)
    for _ in range(50):
        request = _request(rng)
        again = request_from_wire(json.loads(json.dumps(request_to_wire(request))))
        for field in ("crop", "crop_mask", "objects"):
            assert getattr(again, field) is not getattr(request, field)
        assert again.crop_size_px == request.crop_size_px
        assert again.crop.shape == request.crop.shape and not again.crop.any()
        assert again.crop_mask is None
        assert again.objects[0].mask is None
        assert again.objects[0].bbox_px == request.objects[0].bbox_px
        assert again.objects[0].size_m == request.objects[0].size_m
        same = {
            name: getattr(request, name)
            for name in request.__dataclass_fields__
            if name not in ("crop", "crop_mask", "objects")
        }
        assert {name: getattr(again, name) for name in same} == same


def test_an_answer_crosses_whole() -> None:
    answer = BackendAnswer(
        text='{"keyword": "line"}',
        prompt_tokens=3,
        completion_tokens=None,
        latency_s=0.25,
        cost_usd=None,
        model="openai/x",
        retries=("HTTP 429, waited 1 s",),
        finish_reason="length",
        refusal="no",
        shared=False,
    )
    assert answer_from_wire(json.loads(json.dumps(answer_to_wire(answer)))) == answer


def _pair() -> tuple[socket.socket, socket.socket]:
    return socket.socketpair(socket.AF_UNIX, socket.SOCK_STREAM)


def test_messages_cross_a_socket_whole() -> None:
    one, two = _pair()
    with one, two:
        rng = np.random.default_rng(3)
        messages = [{"n": int(n), "text": "x" * int(n)} for n in rng.integers(0, 300_000, 20)]

        def write() -> None:
            for message in messages:
                send(one, message)

        writer = threading.Thread(target=write)
        writer.start()
        assert [receive(two) for _ in messages] == messages
        writer.join()


@pytest.mark.parametrize(
    ("data", "problem"),
    [
        (struct.pack("!I", MAX_MESSAGE_BYTES + 1), "over the limit"),
        (struct.pack("!I", 10) + b"{}", "closed mid-message"),
        (b"\x00\x00", "closed mid-message"),
        (struct.pack("!I", 4) + b"\xff\xfe{}", "not JSON"),
        (struct.pack("!I", 2) + b"[]", "not a JSON object"),
    ],
)
def test_what_is_no_message_is_refused(data: bytes, problem: str) -> None:
    one, two = _pair()
    with one, two:
        one.sendall(data)
        one.shutdown(socket.SHUT_WR)
        with pytest.raises(WireError, match=problem):
            receive(two)


def test_a_request_carries_the_variables_of_its_call_and_no_others(monkeypatch: Any) -> None:
    for name in list(os.environ):
        monkeypatch.delenv(name)
    planted = {
        "OPENAI_API_KEY": "sk-a",
        "OPENAI_BASE_URL": "http://proxy/v1",
        "LAB_VLM_API_KEY": "lab",
        "HTTPS_PROXY": "http://proxy:3128",
        "no_proxy": "localhost",
        "SSL_CERT_FILE": "/etc/ca.pem",
        "ANTHROPIC_API_KEY": "sk-ant",
        "GEMINI_API_KEY": "g",
        "GOOGLE_APPLICATION_CREDENTIALS": "/creds.json",
        "AWS_SECRET_ACCESS_KEY": "aws",
        "GITHUB_TOKEN": "gh",
        "HOME": "/home/me",
        "PATH": "/bin",
        "LITELLM_LOG": "ERROR",
    }
    for name, value in planted.items():
        monkeypatch.setenv(name, value)
    assert call_environment("openai/gpt-4o", None) == {
        k: planted[k]
        for k in ("OPENAI_API_KEY", "OPENAI_BASE_URL", "HTTPS_PROXY", "no_proxy", "SSL_CERT_FILE")
    }
    assert set(call_environment("gpt-4o", "LAB_VLM_API_KEY")) == {
        "OPENAI_API_KEY", "OPENAI_BASE_URL", "LAB_VLM_API_KEY", "HTTPS_PROXY", "no_proxy",
        "SSL_CERT_FILE",
    }  # fmt: skip
    assert set(call_environment("anthropic/claude-sonnet-4-5", None)) == {
        "ANTHROPIC_API_KEY", "HTTPS_PROXY", "no_proxy", "SSL_CERT_FILE",
    }  # fmt: skip
    assert set(call_environment("gemini/gemini-2.0-flash", None)) == {
        "GEMINI_API_KEY", "GOOGLE_APPLICATION_CREDENTIALS", "HTTPS_PROXY", "no_proxy",
        "SSL_CERT_FILE",
    }  # fmt: skip
    assert "AWS_SECRET_ACCESS_KEY" in call_environment("bedrock/anthropic.claude-3", None)
    # the planner itself starts with no credential at all
    assert server_environment() == {"HOME": "/home/me", "PATH": "/bin", "LITELLM_LOG": "ERROR"}


@pytest.mark.parametrize(
    ("flag", "variable", "mode"),
    [
        (None, None, "use"),
        (None, "", "use"),
        (None, "1", "start"),
        (None, " START ", "start"),
        (None, "0", "off"),
        (None, "off", "off"),
        (None, "use", "use"),
        (True, "0", "start"),
        (False, "1", "off"),
    ],
)
def test_the_mode_a_command_asks_for(
    flag: bool | None, variable: str | None, mode: str, monkeypatch: Any
) -> None:
    if variable is None:
        monkeypatch.delenv("KEYMPS_WARM_PLANNER", raising=False)
    else:
        monkeypatch.setenv("KEYMPS_WARM_PLANNER", variable)
    assert mode_from(flag) == mode


def test_an_unknown_mode_is_one_line(monkeypatch: Any) -> None:
    monkeypatch.setenv("KEYMPS_WARM_PLANNER", "yes")
    with pytest.raises(KeympsError, match=r"^\$KEYMPS_WARM_PLANNER='yes': 1 \(start") as caught:
        mode_from(None)
    assert "\n" not in str(caught.value)


def test_the_folder_must_be_the_users_alone(tmp_path: Path) -> None:
    folder = tmp_path / "keymps"
    assert "does not exist" in (folder_problem(folder) or "")
    folder.mkdir(mode=0o700)
    assert folder_problem(folder) is None
    for mode in (0o750, 0o705, 0o777, 0o710):
        folder.chmod(mode)
        assert f"has mode {mode:04o}" in (folder_problem(folder) or ""), mode
    folder.chmod(0o700)
    link = tmp_path / "link"
    link.symlink_to(folder)
    assert "is not a folder (a link or a file)" in (folder_problem(link) or "")
    plain = tmp_path / "file"
    plain.write_text("")
    assert "is not a folder" in (folder_problem(plain) or "")
    if os.getuid() == 0:  # another user's folder (only root can give one away)
        os.chown(folder, 65534, 65534)
        assert "belongs to user 65534, not to you" in (folder_problem(folder) or "")


def test_check_makes_the_folder_private_and_refuses_a_long_path(tmp_path: Path) -> None:
    place = Place(tmp_path / "keymps")
    place.check(create=True)
    assert (place.folder.stat().st_mode & 0o777) == 0o700
    deep = tmp_path / ("d" * (MAX_SOCKET_PATH - len(str(tmp_path))))
    with pytest.raises(KeympsError, match="longer than a Unix socket address allows"):
        Place(deep).check(create=True)
    place.folder.chmod(0o755)
    with pytest.raises(KeympsError, match="has mode 0755"):
        place.check(create=True)  # an existing folder is checked, never repaired
