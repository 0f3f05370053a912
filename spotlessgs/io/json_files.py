"""Reading the project's own JSON files (run.json, config.json, model_selection.json, ...) with errors that name them.

``json.loads(path.read_text())`` says "Expecting value: line 1 column 1" without the file, and a missing entry
surfaces as a ``KeyError`` (shown as a bug). :func:`read_json` and :func:`require_keys` raise
:class:`~spotlessgs.io.errors.InputError` naming the file and the problem in one line instead.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any, Iterable

from spotlessgs.io.errors import InputError


def read_json(path: str | os.PathLike, what: str, required: Iterable[str] = ()) -> dict[str, Any]:
    """The JSON object in ``path``.

    Args:
        path: the file.
        what: what the file is, for messages (``"the run's settings"``).
        required: top-level keys the object must have (see :func:`require_keys`).

    Raises:
        InputError: the file is missing, not UTF-8 text, not valid JSON, not a JSON object, or lacks a required key
            (names the file and the problem).
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise InputError(f"{path}: no such file ({what})") from None
    except IsADirectoryError:
        raise InputError(f"{path}: is a folder, expected {what} (a JSON file)") from None
    except UnicodeDecodeError as exc:
        raise InputError(f"{path}: damaged {what}: not UTF-8 text ({exc.reason} at byte {exc.start})") from None
    try:
        data = json.loads(text)
    except RecursionError:
        raise InputError(f"{path}: damaged {what}: not valid JSON (nested too deeply)") from None
    except ValueError as exc:
        raise InputError(f"{path}: damaged {what}: not valid JSON ({exc})") from None
    if not isinstance(data, dict):
        raise InputError(f"{path}: damaged {what}: expected a JSON object, found {_json_type(data)}")
    require_keys(data, path, what, required)
    return data


def require_keys(data: dict[str, Any], path: str | os.PathLike, what: str, keys: Iterable[str]) -> None:
    """Raise :class:`InputError` naming ``path`` and the first of ``keys`` that ``data`` (read from it) lacks."""
    for key in keys:
        if key not in data:
            raise InputError(f"{os.fspath(path)}: damaged {what}: missing key {key!r}")


def _json_type(value: Any) -> str:
    """The JSON name of a decoded value's type (``an array``, ``a string``, ...)."""
    if isinstance(value, list):
        return "an array"
    if isinstance(value, str):
        return "a string"
    if isinstance(value, bool):
        return "a boolean"
    if isinstance(value, (int, float)):
        return "a number"
    return "null" if value is None else type(value).__name__
