"""Relight a run in a fresh process and record that process's peak memory (run by the train stage as a subprocess).

Usage: ``python -m spotlessgs.experiments.reproduce.relight_process RUN_DIR WHICH OUT_DIR SUMMARY_JSON``. The summary is
render_run's (views, fps, ...) plus ``peak_rss_mb`` (VmHWM of this process: imports, loading the run and rendering
every view; not ru_maxrss, which Linux carries over from the training process that started this one) and
``baseline_rss_mb`` (resident memory right after importing torch and the renderer, before loading the run).
Importing torch has a transient peak of its own, so for small models the peak can be the import's.
"""

from __future__ import annotations

import resource
import sys
from pathlib import Path

from spotlessgs.io.atomic import write_json


def _status_mb(field: str) -> float | None:
    """A memory field of /proc/self/status (``VmRSS``, ``VmHWM``), MiB; None where /proc is unavailable."""
    try:
        for line in Path("/proc/self/status").read_text(encoding="ascii").splitlines():
            if line.startswith(f"{field}:"):
                return int(line.split()[1]) / 1024.0
    except (OSError, ValueError, IndexError):
        pass
    return None


def _peak_rss_mb() -> float:
    """Peak resident set size of this process so far, MiB: Linux's VmHWM, which starts afresh with the process
    (ru_maxrss is carried over from the parent across fork and exec: the training process's peak); ru_maxrss
    elsewhere."""
    peak = _status_mb("VmHWM")
    return peak if peak is not None else resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def _current_rss_mb() -> float:
    """Current resident set size (Linux VmRSS), MiB; the peak so far where /proc is unavailable."""
    current = _status_mb("VmRSS")
    return current if current is not None else _peak_rss_mb()


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    if len(args) != 4:
        raise SystemExit("usage: python -m spotlessgs.experiments.reproduce.relight_process RUN_DIR WHICH OUT_DIR "
                         "SUMMARY_JSON")
    run_dir, which, out_dir, summary_path = Path(args[0]), args[1], Path(args[2]), Path(args[3])
    import torch  # noqa: F401  (part of the baseline)

    baseline = _current_rss_mb()
    from spotlessgs.rendering import render_run  # after the baseline: the renderer's modules count as relighting's

    summary = render_run(run_dir, "relit", which, out_dir, progress=False)
    summary["peak_rss_mb"] = _peak_rss_mb()
    summary["baseline_rss_mb"] = baseline
    write_json(summary_path, summary)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
