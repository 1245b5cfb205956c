"""The two ways a task can be refused, shared by the protocol and the stage contracts."""

from __future__ import annotations


class ProtocolError(Exception):
    """The byte stream or message sequence broke the protocol; the engine must exit."""


class BadInput(ValueError):
    """The task's parameters or inputs make it impossible; a retry cannot help."""
