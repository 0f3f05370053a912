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


def pytest_configure(config):
    """Torch gives some warnings once per process only; give them every time, so that the warning filter in
    pyproject.toml fails every test that converts a tensor with a gradient to a number, not only the first."""
    import torch

    torch.set_warn_always(True)


def pytest_collection_modifyitems(config, items):
    """Skip `blender` tests without bpy and `gpu` tests without CUDA, with a clear reason."""
    has_bpy = importlib.util.find_spec("bpy") is not None
    has_gpu = _has_cuda()
    for item in items:
        if "blender" in item.keywords and not has_bpy:
            item.add_marker(pytest.mark.skip(reason="bpy is not installed (pip install -e '.[sim]')"))
        if "gpu" in item.keywords and not has_gpu:
            item.add_marker(pytest.mark.skip(reason="no CUDA GPU"))


@pytest.fixture(scope="module")
def one_torch_thread():
    """One torch thread for a test module: the test machines are shared, and contended OpenMP threads slow small
    ops up to 100x. Modules opt in with ``pytestmark = pytest.mark.usefixtures("one_torch_thread")``."""
    import torch

    old = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(old)


def synthetic_box_dataset(tmp_path_factory, name: str, seed: int):
    """A tiny ray-cast posed dataset (14 frames, 40x30, no Blender) in a fresh folder; returns its path."""
    from evaluation.synthetic import render_room_sequence, write_dataset_folder

    root = tmp_path_factory.mktemp(name) / "box"
    write_dataset_folder(render_room_sequence(num_frames=14, width=40, height=30, seed=seed), root, with_depth=False)
    return root
