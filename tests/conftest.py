"""Shared pytest fixtures and marker handling."""

from __future__ import annotations

import importlib.util

import pytest


def _has_cuda() -> bool:
    try:
        import torch
    except ImportError:
        return False
    return torch.cuda.is_available()


def pytest_collection_modifyitems(config, items):
    """Skip `blender` tests without bpy and `gpu` tests without CUDA, with a clear reason."""
    has_bpy = importlib.util.find_spec("bpy") is not None
    has_gpu = _has_cuda()
    for item in items:
        if "blender" in item.keywords and not has_bpy:
            item.add_marker(pytest.mark.skip(reason="bpy is not installed (pip install -e '.[sim]')"))
        if "gpu" in item.keywords and not has_gpu:
            item.add_marker(pytest.mark.skip(reason="no CUDA GPU"))
