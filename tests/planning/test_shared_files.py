"""A shared task folder tries to make keymps read and send a file of the user's (docs/security.md).

The folder ships links (`prompts -> /`, `prompts -> ../../home/you/.ssh`, a linked ../prompts),
hard links to the user's files as its prompt, its family prompt or its scene image, a
cassette at /proc/self/environ, or paths into hidden folders, and names a server of its own.
Every case is real files and real links on disk and a real server on 127.0.0.1: `keymps
validate` refuses with one located line, `keymps run` stops before its first stage, and the
server never hears the secret. A generator builds 300 link layouts (where the link sits, where
it leads, absolute or relative) and checks that every one leading out is refused and every one
staying inside is accepted. Layouts the user chose ($KEYMPS_PROMPTS_PATH, --api-base, --image,
trusted_api_bases) still work.
"""

from __future__ import annotations

import json
import os
import random
import secrets
import shutil
from pathlib import Path
from typing import Any

import pytest
from click.testing import CliRunner
from helpers.fuzz_support import REPO, RecordingExecutor, assert_clean_error, install
from helpers.vlm_server import VlmServer

import keymps
from keymps.cli.app import cli
from keymps.errors import KeympsError
from keymps.pipeline.validation import validate_task_file
from keymps.run import RunOptions, RunOverrides

DOT = {"keyword": "line", "pairs": [[[130, 130], [130, 130]]], "rationale": "one dot"}
SECRET = "-----BEGIN OPENSSH PRIVATE KEY----- " + secrets.token_hex(16)


@pytest.fixture(scope="module")
def server() -> Any:
    from keymps.default_plugins.litellm.backend import import_litellm

    import_litellm()  # seconds, once
    with VlmServer(responder=lambda request: json.dumps(DOT)) as running:
        yield running


@pytest.fixture(autouse=True)
def _isolated(keymps_plugins: Any, monkeypatch: Any, tmp_path: Path, server: Any) -> None:
    install(keymps_plugins)
    monkeypatch.setenv("OPENAI_API_KEY", "sk-" + secrets.token_hex(8))
    monkeypatch.setenv("KEYMPS_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.setenv("KEYMPS_CONFIG", str(tmp_path / "user-config.yaml"))
    monkeypatch.delenv("KEYMPS_PROMPTS_PATH", raising=False)
    server.reset()


@pytest.fixture
def victim(tmp_path: Path) -> Path:
    """The user's own secret, outside every task folder: ~/.ssh/id_rsa."""
    ssh = tmp_path / "home" / ".ssh"
    ssh.mkdir(parents=True)
    (ssh / "id_rsa").write_text(SECRET + "\n")
    return ssh / "id_rsa"


def shared_task(folder: Path, *planner: str, image: str = "scene.png") -> Path:
    """A one-dot icing task in `folder` with its own scene, and these planner lines."""
    folder.mkdir(parents=True, exist_ok=True)
    if image == "scene.png" and not (folder / "scene.png").exists():
        shutil.copy(REPO / "tasks/scenes/round_cake.png", folder / "scene.png")
    lines = ["planner:", "  model: openai/test-vlm", "  cache: false"]
    lines += [f"  {line}" for line in planner]
    text = "\n".join(
        [
            "name: shared",
            "instruction: Put 1 icing dot on the cake.",
            "scene:",
            f"  image: {image}",
            "  object_height: 0.06",
            *lines,
            "primitives: [line]",
            "robot: {model: ur3, tool: piping_bag}",
            "executor: {name: sim}",
        ]
    )
    path = folder / "task.yaml"
    path.write_text(text + "\n")
    return path


def run(task: Path, out: Path, **given: Any) -> Any:
    options = {k: given.pop(k) for k in ("record", "no_cache") if k in given}
    return keymps.run_task(
        task,
        options=RunOptions(rerun="off", **options),
        overrides=RunOverrides(executor="recording", out=out, **given),
    )


def validated(task: Path) -> list[str]:
    """`keymps validate TASK`'s lines (exit status checked: 1 with problems, else 0)."""
    result = CliRunner().invoke(cli, ["validate", str(task)])
    lines = [line for line in result.output.splitlines() if not line.startswith("note: ")]
    assert result.exit_code == (0 if lines[0].startswith("ok: ") else 1), result.output
    return lines


def refused_before_any_stage(task: Path, out: Path, server: Any) -> str:
    """The run's one-line error; nothing was sent, executed or written."""
    with pytest.raises(KeympsError) as caught:
        run(task, out)
    assert_clean_error(caught.value)
    assert server.requests == [] and RecordingExecutor.calls == []
    assert not out.exists()
    return str(caught.value)


def located(line: str, task: Path) -> bool:
    """Whether `line` starts with the task file's file:line:col (as shown: maybe relative)."""
    where, line_number, column, _ = line.split(":", 3)
    return Path(where).resolve() == task and line_number.isdigit() and column.isdigit()


def heard(server: Any, text: str) -> bool:
    return any(text in json.dumps(request.body) for request in server.requests)


# ------------------------------------------------------------------------ links pointing out


def _link_to_root(folder: Path, victim: Path) -> str:
    (folder / "prompts").symlink_to("/")
    return f"prompts{victim}"


def _relative_link(folder: Path, victim: Path) -> str:
    (folder / "prompts").symlink_to(os.path.relpath(victim.parent, folder))
    return "prompts/id_rsa"


def _linked_parent_prompts(folder: Path, victim: Path) -> str:
    (folder.parent / "prompts").symlink_to("/")
    return f"../prompts{victim}"


def _linked_working_folder_prompts(folder: Path, victim: Path) -> str:
    work = folder.parents[1] / "cloned-repo"  # the user works in a shared repository
    work.mkdir()
    os.chdir(work)  # (the test's monkeypatch.chdir puts the working folder back)
    (work / "prompts").symlink_to(victim.parent)
    return f"{work}/prompts/id_rsa"


LINKS_OUT = {
    "prompts -> /": _link_to_root,
    "prompts -> ../../home/.ssh": _relative_link,
    "../prompts -> /": _linked_parent_prompts,
    "./prompts -> ~/.ssh": _linked_working_folder_prompts,
}


@pytest.mark.parametrize("case", sorted(LINKS_OUT))
def test_a_folder_link_pointing_out_makes_no_file_a_prompt(
    case: str, victim: Path, server: Any, tmp_path: Path, fuzz_counter: Any, monkeypatch: Any
) -> None:
    """The search folders were resolved before they were trusted: a shared folder's
    `prompts -> /` made every file under / a prompt, sent to the task's own server."""
    folder = tmp_path / "shared" / "task"
    folder.mkdir(parents=True)
    monkeypatch.chdir(tmp_path)
    prompt = LINKS_OUT[case](folder, victim)
    task = shared_task(folder, f"api_base: {server.openai_base}", f"prompt: {prompt}")
    lines = validated(task)
    assert len(lines) == 1 and ": planner.prompt: " in lines[0], lines
    assert located(lines[0], task) and "outside the task's folder" in lines[0]
    refused_before_any_stage(task, tmp_path / "run", server)
    assert not heard(server, SECRET)
    fuzz_counter.add("VLM attacks/shared files", ("link out", case), "located error")


def test_found_prompts_and_primitives_in_a_linked_folder_are_refused(
    tmp_path: Path, server: Any, fuzz_counter: Any
) -> None:
    """A folder of the user's holding icing.md and line.yaml: a shared task's `prompts` and
    `primitives` links to it are no search folders."""
    mine = tmp_path / "home" / "notes"
    mine.mkdir(parents=True)
    (mine / "icing.md").write_text(f"my private notes {SECRET}\n")
    shutil.copy(REPO / "primitives" / "line.yaml", mine / "line.yaml")
    for kind, name in (("prompts", "icing.md"), ("primitives", "line.yaml")):
        folder = tmp_path / kind / "task"
        folder.mkdir(parents=True)
        (folder / kind).symlink_to(mine)
        task = shared_task(folder, f"api_base: {server.openai_base}")
        lines = validated(task)
        assert len(lines) == 1 and name in lines[0] and "outside" in lines[0], lines
        refused_before_any_stage(task, tmp_path / f"run-{kind}", server)
        fuzz_counter.add("VLM attacks/shared files", ("found in a linked folder", kind), "refused")


def test_links_that_stay_inside_and_the_users_own_links_still_work(
    tmp_path: Path, server: Any, monkeypatch: Any
) -> None:
    folder = tmp_path / "shared" / "task"
    (folder / "kept").mkdir(parents=True)
    shutil.copy(REPO / "prompts" / "icing.md", folder / "kept" / "icing.md")
    (folder / "prompts").symlink_to("kept")  # inside the task's own tree
    task = shared_task(folder, f"api_base: {server.openai_base}")
    assert validated(task) == [f"ok: {task}"]
    with pytest.warns(UserWarning, match="no API key is sent"):
        run(task, tmp_path / "inside")
    # the user's own prompt folder may be a link anywhere
    (folder / "prompts").unlink()
    real = tmp_path / "elsewhere" / "prompts"
    real.mkdir(parents=True)
    (real / "icing.md").write_text((REPO / "prompts" / "icing.md").read_text())
    (tmp_path / "mine").symlink_to(real)
    monkeypatch.setenv("KEYMPS_PROMPTS_PATH", str(tmp_path / "mine"))
    assert validated(shared_task(folder, "prompt: ../../mine/icing.md")) == [f"ok: {task}"]
    with pytest.warns(UserWarning, match="no API key is sent"):
        run(shared_task(folder, f"api_base: {server.openai_base}"), tmp_path / "mine-run")
    assert len(server.chat_requests) == 2 and len(RecordingExecutor.calls) == 2


# ------------------------------------------------------------------------ generated layouts

TARGETS = ("root", "home", "ssh", "sibling", "inside")
"""Where a generated link leads: /, the user's home, ~/.ssh, a sibling of the shared folder
(all outside the task), or a folder inside the task's own tree."""


def _layout(case: int, base: Path, victim: Path) -> tuple[Path, bool]:
    """A task folder with one link somewhere on the way to its planner.prompt, and whether
    the layout stays inside the task's tree (so must be accepted)."""
    rng = random.Random(case)
    shared = base / f"case{case}" / "shared"
    folder = shared.joinpath(*[f"d{i}" for i in range(rng.randint(0, 2))], "task")
    folder.mkdir(parents=True)
    outside = base / f"case{case}" / "sibling"
    outside.mkdir()
    (outside / "notes.md").write_text(SECRET)
    inside = folder / "own"
    inside.mkdir()
    (inside / "notes.md").write_text((REPO / "prompts" / "icing.md").read_text())
    target = rng.choice(TARGETS)
    lead = {
        "root": (Path("/"), victim.relative_to("/")),
        "home": (victim.parents[1], victim.relative_to(victim.parents[1])),
        "ssh": (victim.parent, Path(victim.name)),
        "sibling": (outside, Path("notes.md")),
        "inside": (inside, Path("notes.md")),
    }[target]
    place = rng.choice(["prompts", "sub", "sub/deeper", "../prompts", "../lib"])
    link = (folder / place).resolve().parent / Path(place).name
    link.parent.mkdir(parents=True, exist_ok=True)
    if not link.exists():
        link.symlink_to(lead[0] if rng.random() < 0.5 else os.path.relpath(lead[0], link.parent))
    prompt = os.path.relpath(link, folder) + "/" + str(lead[1])
    shared_task(folder, "api_base: http://127.0.0.1:9/v1", f"prompt: {prompt}")
    return folder / "task.yaml", target == "inside"


def test_generated_link_layouts_are_refused_exactly_when_they_lead_out(
    tmp_path: Path, victim: Path, fuzz_counter: Any
) -> None:
    outcomes = {"refused out": 0, "accepted inside": 0}
    for case in range(300):
        task, stays_inside = _layout(case, tmp_path / "layouts", victim)
        problems = validate_task_file(task)
        if stays_inside:
            assert problems == [], (case, problems)
            outcomes["accepted inside"] += 1
        else:
            assert len(problems) == 1 and ": planner.prompt: " in problems[0], (case, problems)
            assert SECRET not in problems[0]
            outcomes["refused out"] += 1
        fuzz_counter.add("VLM attacks/shared files", ("generated layout", case), "as expected")
    assert min(outcomes.values()) >= 30, outcomes  # both kinds were generated


# ------------------------------------------------------------------------------ hard links


def _hard_prompt(folder: Path, victim: Path) -> tuple[str, ...]:
    os.link(victim, folder / "notes.md")
    return ("prompt: notes.md",)


def _hard_family_prompt(folder: Path, victim: Path) -> tuple[str, ...]:
    (folder / "prompts").mkdir()
    os.link(victim, folder / "prompts" / "icing.md")
    return ()


def _hard_image(folder: Path, victim: Path) -> tuple[str, ...]:
    photo = victim.parents[1] / "photo.png"  # a private photo of the user's
    shutil.copy(REPO / "tasks/scenes/round_cake.png", photo)
    os.link(photo, folder / "scene.png")
    return ()


HARD_LINKS = {
    "planner.prompt": (_hard_prompt, ": planner.prompt notes.md is a hard link"),
    "family prompt": (_hard_family_prompt, ": prompt template icing.md ("),
    "scene.image": (_hard_image, ": scene.image scene.png is a hard link"),
}


@pytest.mark.parametrize("case", sorted(HARD_LINKS))
def test_a_hard_linked_file_is_not_sent_to_a_server_only_the_task_names(
    case: str, victim: Path, server: Any, tmp_path: Path, fuzz_counter: Any
) -> None:
    """A hard link inside the task folder is the user's file under a second name: no path
    check sees it. Sent only to a server the user named."""
    make, expected = HARD_LINKS[case]
    folder = tmp_path / "shared" / "task"
    folder.mkdir(parents=True)
    planner = make(folder, victim)
    task = shared_task(folder, f"api_base: {server.openai_base}", *planner)
    lines = validated(task)
    assert len(lines) == 1 and located(lines[0], task) and expected in lines[0], lines
    assert "is named only by the task file" in lines[0] and "--api-base" in lines[0]
    message = refused_before_any_stage(task, tmp_path / "run", server)
    assert expected in message
    fuzz_counter.add("VLM attacks/shared files", ("hard link", case), "refused")
    # the user's own server may be sent it
    run(task, tmp_path / "cli", api_base=server.openai_base)
    (tmp_path / "user-config.yaml").write_text(f"trusted_api_bases: [{server.url}]\n")
    assert validated(task) == [f"ok: {task}"]
    run(task, tmp_path / "config")
    assert len(RecordingExecutor.calls) == 2


def test_hard_links_reach_no_server_and_the_users_own_are_fine(
    victim: Path, tmp_path: Path, monkeypatch: Any, server: Any
) -> None:
    """Offline, no file leaves: a hard link is no problem. A hard-linked prompt in the user's
    own prompt folder (installers such as uv hard-link package files) is the user's."""
    folder = tmp_path / "shared" / "task"
    folder.mkdir(parents=True)
    os.link(REPO / "tasks/scenes/round_cake.png", folder / "linked.png")
    offline = shared_task(folder, "backend: offline", image="linked.png")
    assert validated(offline) == [f"ok: {offline}"]
    mine = tmp_path / "my-prompts"
    mine.mkdir()
    os.link(REPO / "prompts" / "icing.md", mine / "icing.md")
    monkeypatch.setenv("KEYMPS_PROMPTS_PATH", str(mine))
    task = shared_task(
        folder, f"api_base: {server.openai_base}", "prompt: ../../my-prompts/icing.md"
    )
    assert validated(task) == [f"ok: {task}"]


# -------------------------------------------------------------- cassettes, oracles, hidden


def _fifo(folder: Path) -> str:
    os.mkfifo(folder / "answers.fifo")
    return "answers.fifo"


CASSETTES = {
    "/proc/self/environ": (lambda folder: "/proc/self/environ", "kernel or device file"),
    "/etc/hostname": (lambda folder: "/etc/hostname", "outside the task's folder"),
    "../../ escape": (lambda folder: "../../secret.jsonl", "outside the task's folder"),
    "link out": (lambda folder: _linked(folder, "/etc/hostname"), "outside the task's folder"),
    "fifo": (_fifo, "not a regular file"),
    "hidden": (lambda folder: ".cache/answers.jsonl", "hidden file or folder '.cache'"),
}


def _linked(folder: Path, target: str) -> str:
    (folder / "answers.jsonl").symlink_to(target)
    return "answers.jsonl"


@pytest.mark.parametrize("case", sorted(CASSETTES))
def test_a_cassette_the_task_names_must_be_a_file_in_its_folder(
    case: str, tmp_path: Path, server: Any, fuzz_counter: Any
) -> None:
    """planner.cassette opened any path (/proc included) and the run's error told whether a
    file was there."""
    folder = tmp_path / "shared" / "task"
    folder.mkdir(parents=True)
    (tmp_path / "secret.jsonl").write_text("{}\n")
    make, expected = CASSETTES[case]
    task = shared_task(folder, "backend: replay", f"cassette: {make(folder)}")
    lines = validated(task)
    assert len(lines) == 1 and ": planner.cassette: " in lines[0] and expected in lines[0], lines
    refused_before_any_stage(task, tmp_path / "run", server)
    fuzz_counter.add("VLM attacks/shared files", ("cassette", case), "located error")


def test_a_cassette_in_the_task_folder_and_one_the_user_names_are_read(
    tmp_path: Path, server: Any
) -> None:
    folder = tmp_path / "shared" / "task"
    recorded = tmp_path / "recorded.jsonl"  # outside the task: recorded by the user
    task = shared_task(folder, f"api_base: {server.openai_base}")
    with pytest.warns(UserWarning, match="no API key is sent"):
        run(task, tmp_path / "record", record=str(recorded))
    shutil.copy(recorded, folder / "answers.jsonl")
    replayed = shared_task(folder, "backend: replay", "cassette: answers.jsonl")
    assert validated(replayed) == [f"ok: {replayed}"]
    run(replayed, tmp_path / "replay")
    run(shared_task(folder, "backend: replay"), tmp_path / "user", cassette=str(recorded))
    assert len(server.chat_requests) == 1 and len(RecordingExecutor.calls) == 3


@pytest.mark.parametrize("field", ["prompt", "cassette"])
def test_a_path_outside_gets_the_same_answer_whether_a_file_is_there_or_not(
    field: str, victim: Path, tmp_path: Path
) -> None:
    said = []
    for target in (victim, victim.parent / "id_ed25519"):
        lines = validated(shared_task(tmp_path / "task", f"{field}: {target}"))
        said.append(lines[0].replace(str(target), "PATH"))
    assert said[0] == said[1] and "outside the task's folder" in said[0], said


def test_a_task_saved_in_the_home_folder_reads_nothing_hidden(
    victim: Path, server: Any, tmp_path: Path, fuzz_counter: Any
) -> None:
    """A task file saved straight into ~ has the whole home folder as its tree: its hidden
    folders (.ssh, .aws, .config) stay out, for the prompt and for a task-only server's image."""
    home = victim.parents[1]
    task = shared_task(home, f"api_base: {server.openai_base}", "prompt: .ssh/id_rsa")
    lines = validated(task)
    assert len(lines) == 1 and "hidden file or folder '.ssh'" in lines[0], lines
    refused_before_any_stage(task, tmp_path / "run", server)
    (home / ".photos").mkdir()
    shutil.copy(REPO / "tasks/scenes/round_cake.png", home / ".photos" / "me.png")
    task = shared_task(home, f"api_base: {server.openai_base}", image=".photos/me.png")
    lines = validated(task)
    assert len(lines) == 1 and "is in the hidden folder '.photos'" in lines[0], lines
    refused_before_any_stage(task, tmp_path / "run", server)
    fuzz_counter.add("VLM attacks/shared files", "hidden folders of a task in ~", "refused")
