"""Experiments built on the library: the paper reproduction (``reproduce``), the method benchmark (``benchmark``) and
the model-selection benchmark (``selection_benchmark``).

They sit above everything else (io -> rasterizer -> models -> training -> rendering / evaluation -> experiments ->
CLIs; enforced by the import-linter contracts in pyproject.toml): they train, relight and score through the library's
own calls and may import any of it, and nothing in the library imports them.
"""
