"""The two ways a task can be refused, shared by the protocol and the stage contracts, and how an
error message shows the value it refuses."""

from __future__ import annotations


class ProtocolError(Exception):
    """The byte stream or message sequence broke the protocol; the engine must exit."""


class BadInput(ValueError):
    """The task's parameters or inputs make it impossible; a retry cannot help."""


def shown(value: object) -> str:
    """`value` as an error message quotes it: its repr, cut to 60 characters."""
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."
