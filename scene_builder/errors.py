"""The one error type users of the asset pipeline see."""

from __future__ import annotations


class AssetError(Exception):
    """A problem with the user's input, not a bug: the message is one line, `<file>: <problem>`.

    The CLI prints it as is (no traceback) and exits with code 2; any other exception raised
    by the pipeline is a bug and keeps its traceback.
    """
