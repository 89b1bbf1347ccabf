"""A tiny rosbridge-protocol server for the tests (no ROS here): a websocket on 127.0.0.1 that
publishes sensor_msgs/JointState to subscribers and plays a joint_trajectory_controller for
FollowJointTrajectory goals (it takes the goal's own duration, then moves the joints to its last
point and answers SUCCEEDED, or ABORTED in mode `abort`; a cancel answers CANCELED).

Run as `python fake_rosbridge.py PORT LOG JOINTS_JSON NAMES_JSON MODE`; it prints `ready` once
it listens. Every message it receives is appended to LOG, one JSON per line.
"""

from __future__ import annotations

import asyncio
import json
import sys
from typing import Any

from websockets.asyncio.server import ServerConnection, serve


class Controller:
    def __init__(self, log: str, joints: list[float], names: list[str], mode: str):
        self.log, self.joints, self.names, self.mode = log, joints, names, mode
        self.goals: dict[str, asyncio.Task[None]] = {}

    async def handle(self, socket: ServerConnection) -> None:
        async for text in socket:
            message = json.loads(text)
            with open(self.log, "a") as log:
                log.write(json.dumps(message) + "\n")
            op = message.get("op")
            if op == "subscribe" and message["topic"] == "/joint_states":
                asyncio.ensure_future(self.publish(socket, message["topic"]))
            elif op == "send_action_goal":
                self.goals[message["id"]] = asyncio.ensure_future(self.execute(socket, message))
            elif op == "cancel_action_goal" and message["id"] in self.goals:
                self.goals.pop(message["id"]).cancel()
                await self.result(socket, message, 5, {"error_code": 0, "error_string": ""})

    async def publish(self, socket: ServerConnection, topic: str) -> None:
        while True:
            state = {"name": self.names, "position": self.joints, "velocity": [], "effort": []}
            state["header"] = {"stamp": {"sec": 0, "nanosec": 0}, "frame_id": ""}
            try:
                await socket.send(json.dumps({"op": "publish", "topic": topic, "msg": state}))
            except Exception:
                return
            await asyncio.sleep(0.02)

    async def execute(self, socket: ServerConnection, message: dict[str, Any]) -> None:
        points = message["args"]["trajectory"]["points"]
        last = points[-1]["time_from_start"]
        await asyncio.sleep(last["sec"] + last["nanosec"] * 1e-9)
        if self.mode == "abort":
            values = {"error_code": -4, "error_string": "path tolerance violated"}
            await self.result(socket, message, 6, values)
            return
        self.joints = points[-1]["positions"]
        await self.result(socket, message, 4, {"error_code": 0, "error_string": ""})
        self.goals.pop(message["id"], None)

    async def result(
        self, socket: ServerConnection, goal: dict[str, Any], status: int, values: dict[str, Any]
    ) -> None:
        answer = {
            "op": "action_result", "id": goal["id"], "action": goal.get("action", ""),
            "values": values, "status": status, "result": status == 4,
        }  # fmt: skip
        await socket.send(json.dumps(answer))


async def main() -> None:
    port, log, joints, names, mode = sys.argv[1:6]
    controller = Controller(log, json.loads(joints), json.loads(names), mode)
    async with serve(controller.handle, "127.0.0.1", int(port)):
        print("ready", flush=True)
        await asyncio.Future()


if __name__ == "__main__":
    asyncio.run(main())
