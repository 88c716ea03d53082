"""JSON codec between the schemas and the text of a ``std_msgs/String``.

``decode`` never raises anything but :class:`DecodeError`, which names the
topic, the field and the reason, so a node can log one clear line, count the
drop and keep running (RELIABILITY.md).
"""
from __future__ import annotations

from typing import TypeVar

from pydantic import ValidationError

from lmpc_msgs_py.messages import LmpcMessage

MAX_PAYLOAD_BYTES = 1 << 20
"""Larger payloads are refused before parsing (a map of a big city is ~200 kB)."""

M = TypeVar("M", bound=LmpcMessage)


class DecodeError(Exception):
    """A payload that failed validation: names the topic, the field and the reason."""

    def __init__(self, topic: str, field: str, reason: str) -> None:
        super().__init__(f"dropped message on {topic}: field '{field}': {reason}")
        self.topic = topic
        self.field = field
        self.reason = reason


def encode(msg: LmpcMessage) -> str:
    """Serialise a message to compact JSON (with its ``schema`` field)."""
    return msg.model_dump_json(by_alias=True)


def decode(text: str, cls: type[M], *, topic: str = "?") -> M:
    """Parse and validate ``text`` as ``cls``; raise :class:`DecodeError` on any fault."""
    if not isinstance(text, str):
        raise DecodeError(topic, "<payload>", f"expected text, got {type(text).__name__}")
    if not text.strip():
        raise DecodeError(topic, "<payload>", "empty string")
    if len(text) > MAX_PAYLOAD_BYTES:
        raise DecodeError(topic, "<payload>", f"{len(text)} bytes exceeds {MAX_PAYLOAD_BYTES}")
    try:
        msg = cls.model_validate_json(text)
    except ValidationError as exc:
        err = exc.errors(include_url=False)[0]
        loc = ".".join(str(p) for p in err["loc"]) or "<payload>"
        kind = err["type"]
        if kind == "json_invalid":
            reason = f"not valid JSON ({err['msg']})"
            loc = "<payload>"
        elif kind == "literal_error" and loc == "schema":
            reason = f"wrong schema {err.get('input')!r}, expected {cls.SCHEMA!r}"
        else:
            reason = err["msg"]
            if "input" in err and kind != "missing":
                reason += f" (got {_short(err['input'])})"
        more = exc.error_count() - 1
        if more:
            reason += f" (+{more} more error{'s' if more > 1 else ''})"
        raise DecodeError(topic, loc, reason) from None
    # Python code may omit the schema (it defaults); a message on the wire must name it.
    if "schema_id" not in msg.model_fields_set:
        raise DecodeError(topic, "schema", f"missing, expected {cls.SCHEMA!r}")
    return msg


def _short(value: object, limit: int = 60) -> str:
    text = repr(value)
    return text if len(text) <= limit else text[: limit - 3] + "..."
