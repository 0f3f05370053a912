"""What an execution of a :class:`~spotlessgs.jobs.graph.StageGraph` has to do, and what it did.

Shared by every executor (:mod:`spotlessgs.jobs.local`, :mod:`spotlessgs.jobs.ray_cluster`), so that both skip, redo
and report stages by the same rules.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from spotlessgs.jobs.graph import StageGraph, is_done, marker_path


class StageFailedError(RuntimeError):
    """One or more stages raised; their dependents were not run (finished stages keep their markers)."""


@dataclass
class RunReport:
    """What one execution did."""

    ran: list[str] = field(default_factory=list)  # stages run now, in completion order
    skipped: list[str] = field(default_factory=list)  # stages already done before this run
    failed: dict[str, str] = field(default_factory=dict)  # stage -> error message
    blocked: list[str] = field(default_factory=list)  # stages not run because a dependency failed
    retried: list[str] = field(default_factory=list)  # interrupted stages whose partial output was deleted

    def raise_if_failed(self, root: Path) -> None:
        """StageFailedError naming each failed stage with its error, and the stages it blocked."""
        if not self.failed:
            return
        lines = [f"{name}: {msg}" for name, msg in self.failed.items()]
        blocked = f"; not run because of them: {self.blocked}" if self.blocked else ""
        raise StageFailedError(f"{len(self.failed)} stage(s) failed under {root}: " + " | ".join(lines) + blocked)


def plan_run(graph: StageGraph, root: Path) -> tuple[list[str], RunReport]:
    """The stages to run now, in dependency order, and a report that lists the finished ones as skipped.

    A stage runs when it has no done-marker under ``root``, and so does every stage that depends on one that runs
    (results built on work that is redone are redone too): their stale markers are deleted here.
    """
    stale: set[str] = set()
    for name in graph.order:
        if not is_done(root, name):
            stale.add(name)
            stale |= graph.dependents(name)
    pending = [name for name in graph.order if name in stale]
    report = RunReport(skipped=[name for name in graph.order if name not in stale])
    for name in pending:
        marker_path(root, name).unlink(missing_ok=True)
    return pending, report
