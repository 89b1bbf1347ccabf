"""The warm planner's messages: a 4-byte length, then that many bytes of UTF-8 JSON.

JSON, never pickle: a message is data, and reading one runs no code. A plan request crosses in
two messages, `{"kind": "plan"}` and then its body, so that the server's long-lived process
reads only the kind and the child forked for the request reads the body (the keys in it).
"""

from __future__ import annotations

import dataclasses
import json
import socket
import struct
from typing import TYPE_CHECKING, Any

import numpy as np

from keymps.types import BackendAnswer, PlanObject, PlanRequest

if TYPE_CHECKING:
    import asyncio

PROTOCOL = 1
"""Raised when a message changes meaning; a server of another protocol is not used."""
MAX_MESSAGE_BYTES = 64 * 1024 * 1024
"""A request carries the image sent (a few MB at most); an answer at most 8 MB of text."""
_HEADER = struct.Struct("!I")
_NOT_SENT = ("crop", "crop_mask", "objects")
"""PlanRequest fields that do not cross as they are: the pixels (the messages carry the
image the model sees) and the objects' masks."""


class WireError(Exception):
    """The other end closed the connection, or sent something that is no message."""


def encode(message: dict[str, Any]) -> bytes:
    """The message as it crosses: its length, then its JSON."""
    data = json.dumps(message, separators=(",", ":")).encode()
    if len(data) > MAX_MESSAGE_BYTES:
        raise WireError(f"a message of {len(data)} bytes is over the limit")
    return _HEADER.pack(len(data)) + data


def send(connection: socket.socket, message: dict[str, Any]) -> None:
    connection.sendall(encode(message))


def receive(connection: socket.socket) -> dict[str, Any]:
    """The next message; WireError when the connection ends first or it is malformed."""
    size = _size(_exactly(connection, _HEADER.size))
    return _decode(_exactly(connection, size))


async def areceive(reader: asyncio.StreamReader) -> dict[str, Any]:
    """receive() from an asyncio stream."""
    import asyncio

    try:
        size = _size(await reader.readexactly(_HEADER.size))
        return _decode(await reader.readexactly(size))
    except asyncio.IncompleteReadError:
        raise WireError("the connection closed mid-message") from None


def _size(header: bytes) -> int:
    (size,) = _HEADER.unpack(header)
    if size > MAX_MESSAGE_BYTES:
        raise WireError(f"a message of {size} bytes announced: over the limit")
    return int(size)


def _decode(data: bytes) -> dict[str, Any]:
    try:
        message = json.loads(data)
    except (UnicodeDecodeError, ValueError):
        raise WireError("a message that is not JSON") from None
    if not isinstance(message, dict):
        raise WireError("a message that is not a JSON object")
    return message


def _exactly(connection: socket.socket, size: int) -> bytes:
    buffer = bytearray(size)
    view = memoryview(buffer)
    done = 0
    while done < size:
        count = connection.recv_into(view[done:])
        if count == 0:
            raise WireError("the connection closed mid-message")
        done += count
    return bytes(buffer)


def request_to_wire(request: PlanRequest) -> dict[str, Any]:
    """The request as JSON: every field but the pixel arrays (the messages hold the image)."""
    data = {
        field.name: getattr(request, field.name)
        for field in dataclasses.fields(request)
        if field.name not in _NOT_SENT
    }
    data["primitives"] = dict(request.primitives)
    data["crop_size_px"] = list(request.crop_size_px)
    data["objects"] = [
        {
            "id": o.id,
            "name": o.name,
            "height": o.height,
            "bbox_px": list(o.bbox_px),
            "size_m": list(o.size_m),
        }
        for o in request.objects
    ]
    return data


def request_from_wire(data: dict[str, Any]) -> PlanRequest:
    """The request again; its crop is a zero-cost black image of the size sent."""
    data = dict(data)
    width, height = (int(v) for v in data.pop("crop_size_px"))
    objects = tuple(
        PlanObject(
            id=int(o["id"]),
            name=o["name"],
            height=float(o["height"]),
            bbox_px=tuple(int(v) for v in o["bbox_px"]),  # type: ignore[arg-type]
            mask=None,
            size_m=tuple(float(v) for v in o["size_m"]),  # type: ignore[arg-type]
        )
        for o in data.pop("objects")
    )
    return PlanRequest(
        **{
            **data,
            "metres_per_px": tuple(data["metres_per_px"]),
            "previous_errors": tuple(data["previous_errors"]),
        },
        crop=np.broadcast_to(np.zeros((1, 1, 3), np.uint8), (height, width, 3)),
        crop_mask=None,
        objects=objects,
    )


def answer_to_wire(answer: BackendAnswer) -> dict[str, Any]:
    return dataclasses.asdict(answer)


def answer_from_wire(data: dict[str, Any]) -> BackendAnswer:
    return BackendAnswer(**{**data, "retries": tuple(data.get("retries", ()))})
