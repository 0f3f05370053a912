"""A nested structure of tensors and plain data in one file that cannot carry code: safetensors + JSON.

``torch.save`` files are pickles: loading one from a shared run folder can run any code its author put in. Here the
tensors go into a `safetensors <https://huggingface.co/docs/safetensors>`_ file and everything else (dicts, lists,
tuples, numbers, strings, None) into JSON in the same file's metadata, each tensor referenced by key. Reading parses
a JSON header and raw tensor bytes; nothing is executed. Values round-trip exactly (tensor bytes, Python floats via
``repr``), so a run resumed from such a file equals an uninterrupted one bit for bit.

Layout of the tree JSON (``metadata["tree"]``)::

    tensor                       {"__tensor__": "<key in the safetensors file>"}
    numpy array                  {"__ndarray__": "<key>"}
    dict with non-string keys    {"__items__": [[key, value], ...]}   (e.g. an optimizer's per-parameter state)
    tuple                        {"__tuple__": [...]}
    dict with string keys, list, int, float (NaN/inf allowed), bool, str, None: themselves
"""

from __future__ import annotations

import json
import os
import warnings
from pathlib import Path
from typing import Any

import numpy as np
import torch
from safetensors import SafetensorError
from safetensors.torch import load_file, safe_open, save_file

from spotlessgs.io.atomic import atomic_path
from spotlessgs.io.errors import InputError

_TAGS = ("__tensor__", "__ndarray__", "__items__", "__tuple__")


def _encode(value: Any, tensors: dict[str, torch.Tensor], where: str) -> Any:
    if isinstance(value, torch.Tensor):
        key = f"t{len(tensors)}"
        tensors[key] = value.detach().cpu().clone().contiguous()
        return {"__tensor__": key}
    if isinstance(value, np.ndarray):
        key = f"t{len(tensors)}"
        tensors[key] = torch.from_numpy(np.ascontiguousarray(value).copy())
        return {"__ndarray__": key}
    if isinstance(value, dict):
        if all(isinstance(k, str) for k in value):
            clash = [k for k in value if k in _TAGS]
            if clash:
                raise TypeError(f"{where}: key {clash[0]!r} is reserved by the file format")
            return {k: _encode(v, tensors, f"{where}.{k}") for k, v in value.items()}
        return {"__items__": [[_encode(k, tensors, f"{where}[key]"), _encode(v, tensors, f"{where}[{k!r}]")]
                              for k, v in value.items()]}
    if isinstance(value, tuple):
        return {"__tuple__": [_encode(v, tensors, f"{where}[{i}]") for i, v in enumerate(value)]}
    if isinstance(value, list):
        return [_encode(v, tensors, f"{where}[{i}]") for i, v in enumerate(value)]
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        return float(value)
    if value is None or isinstance(value, str):
        return value
    raise TypeError(f"{where}: cannot store a {type(value).__name__} (tensors and plain data only)")


def _decode(node: Any, tensors: dict[str, torch.Tensor], path: Path) -> Any:
    if isinstance(node, list):
        return [_decode(v, tensors, path) for v in node]
    if not isinstance(node, dict):
        return node
    if "__tensor__" in node or "__ndarray__" in node:
        key = node.get("__tensor__", node.get("__ndarray__"))
        if key not in tensors:
            raise InputError(f"{path}: damaged file: the structure refers to a missing tensor {key!r}")
        return tensors[key] if "__tensor__" in node else tensors[key].numpy()
    if "__items__" in node:
        return {_decode(k, tensors, path): _decode(v, tensors, path) for k, v in node["__items__"]}
    if "__tuple__" in node:
        return tuple(_decode(v, tensors, path) for v in node["__tuple__"])
    return {k: _decode(v, tensors, path) for k, v in node.items()}


def save_tree(path: str | os.PathLike, tree: dict[str, Any], kind: str) -> Path:
    """Write ``tree`` atomically to ``path`` as safetensors; ``kind`` names the content (checked on load)."""
    tensors: dict[str, torch.Tensor] = {}
    structure = _encode(tree, tensors, "checkpoint")
    metadata = {"format": kind, "tree": json.dumps(structure)}
    with atomic_path(path) as tmp:
        save_file(tensors, str(tmp), metadata=metadata)
    return Path(path)


def load_tree(path: str | os.PathLike, kind: str) -> dict[str, Any]:
    """Read a file written by :func:`save_tree` (CPU tensors).

    Raises:
        FileNotFoundError: no such file.
        InputError: not a safetensors file, damaged (also a malformed structure in its metadata), or of another
            ``kind`` (names the file and the problem, in one line).
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such file")
    try:
        with safe_open(str(path), framework="pt", device="cpu") as fh:
            metadata = fh.metadata() or {}
        tensors = load_file(str(path), device="cpu")
    except (SafetensorError, OSError, ValueError) as exc:
        raise InputError(f"{path}: not a readable safetensors file ({' '.join(str(exc).split())})") from None
    found = metadata.get("format")
    if found != kind:
        raise InputError(f"{path}: holds {found!r}, expected {kind!r}")
    try:
        structure = json.loads(metadata["tree"])
    except (KeyError, ValueError, RecursionError) as exc:
        detail = "nested too deeply" if isinstance(exc, RecursionError) else str(exc) or type(exc).__name__
        raise InputError(f"{path}: damaged file: its structure is not valid JSON ({detail})") from None
    try:
        return _decode(structure, tensors, path)
    except InputError:
        raise
    except (TypeError, ValueError, AttributeError, KeyError, RecursionError) as exc:
        # a tag whose content has the wrong shape ({"__items__": 5}, a list as a key, ...) or absurd nesting
        detail = "nested too deeply" if isinstance(exc, RecursionError) else " ".join(str(exc).split())
        raise InputError(f"{path}: damaged file: its structure is malformed ({type(exc).__name__}: {detail})") \
            from None


def load_plain_torch_file(path: str | os.PathLike, what: str) -> Any:
    """Read an older ``torch.save`` file with ``weights_only=True``: tensors and plain containers only.

    Anything else in the pickle (which could run code) is refused with one line naming the file.

    Raises:
        InputError: the file holds other objects, or is not a torch file.
    """
    try:
        with warnings.catch_warnings():  # torch warns about pickle protocols it reads fine
            warnings.simplefilter("ignore", UserWarning)
            return torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # noqa: BLE001 - torch raises UnpicklingError, RuntimeError, EOFError, ...
        detail = str(exc).split("WeightsUnpickler error:")[-1].split("Check the documentation")[0]
        reason = " ".join(detail.split()[:20])
        raise InputError(f"{path}: cannot read {what} safely ({reason}): it is damaged or holds objects other than "
                         "tensors and plain data, and unpickling those could run code; it was not loaded") from None
