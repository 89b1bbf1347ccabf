"""Task files for generated scenes, written one way so the tests differ only in what they vary."""

from __future__ import annotations

from pathlib import Path

KNIFE = "primitives: [straight, sawing]\nrobot: {tool: knife}\nheight: {mode: start}\n"
ICING = "primitives: [line]\nrobot: {tool: piping_bag}\nheight: {mode: both}\n"
OFFLINE = "backend: offline"


def vlm_planner(key_variable: str, attempts: int = 1) -> str:
    """The planner block for the tests' local VLM server (helpers.vlm_server), uncached."""
    return (
        f"backend: litellm, model: openai/test-vlm, api_key_env: {key_variable}, "
        f"cache: false, attempts: {attempts}"
    )


def write_task(
    folder: Path,
    *,
    sentence: str,
    image: Path,
    board_m: tuple[float, float],
    planner: str = OFFLINE,
    tools: str = KNIFE,
    object_height_m: float = 0.05,
    name: str = "generated",
) -> Path:
    """Write `folder`/task.yaml for one scene image on a board of `board_m` (width, height) metres.

    Args:
        planner: the planner mapping's body, e.g. OFFLINE or vlm_planner(...).
        tools: the primitives, robot and height lines, e.g. KNIFE or ICING.

    Returns:
        The task file's path; the sim executor runs it.
    """
    task = folder / "task.yaml"
    task.write_text(
        f"name: {name}\ninstruction: {sentence}\n"
        f"scene: {{image: {image}, object_height: {object_height_m}, "
        f"workspace: {{size: {list(board_m)}}}}}\n"
        f"planner: {{{planner}}}\n{tools}executor: {{name: sim}}\n"
    )
    return task
