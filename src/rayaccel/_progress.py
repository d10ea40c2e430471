"""Progress display for long operations (rich), silent when not on a terminal or when disabled."""

from __future__ import annotations

import contextlib

__all__ = ["progress_bar", "status"]


@contextlib.contextmanager
def progress_bar(description: str, total: int, enabled: bool = True):
    """Yield ``advance(done)``: report ``done`` of ``total`` units finished."""
    if not enabled:
        yield lambda done, total_=None: None
        return
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    with Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(),
                  TimeElapsedColumn(), transient=True) as progress:
        task = progress.add_task(description, total=total)
        yield lambda done, total_=None: progress.update(task, completed=done)


@contextlib.contextmanager
def status(message: str, enabled: bool = True):
    """A spinner with ``message`` while the block runs."""
    if not enabled:
        yield
        return
    from rich.console import Console

    with Console(stderr=True).status(message):
        yield
