"""Progress display for long operations (rich), silent when not on a terminal or when disabled."""

from __future__ import annotations

import contextlib

__all__ = ["progress_bar", "progress_steps", "status", "table_console"]


def _terminal():
    """A rich console on standard error, or None when that is not a terminal (logs, pipes, CI)."""
    from rich.console import Console

    console = Console(stderr=True)
    return console if console.is_terminal else None


def table_console():
    """A rich console for tables on standard output, 120 columns wide when not a terminal."""
    from rich.console import Console

    console = Console()
    return console if console.is_terminal else Console(width=120)


@contextlib.contextmanager
def progress_bar(description: str, total: int, enabled: bool = True):
    """Yield ``advance(done)``: report ``done`` of ``total`` units finished (on a terminal)."""
    console = _terminal() if enabled else None
    if console is None:
        yield lambda done, total_=None: None
        return
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    with Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(),
                  TimeElapsedColumn(), transient=True, console=console) as progress:
        task = progress.add_task(description, total=total)
        yield lambda done, total_=None: progress.update(task, completed=done)


@contextlib.contextmanager
def progress_steps(description: str, steps: int, enabled: bool = True):
    """Yield ``bar(description, total)``, a context manager like :func:`progress_bar` whose bar shows
    under an overall bar of ``steps`` steps; each bar closed is one step done (on a terminal)."""
    console = _terminal() if enabled else None
    if console is None:
        yield lambda description_, total: progress_bar(description_, total, enabled=False)
        return
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    with Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(),
                  TimeElapsedColumn(), transient=True, console=console) as progress:
        overall = progress.add_task(f"[bold]{description}", total=steps)

        @contextlib.contextmanager
        def bar(step_description: str, total: int):
            task = progress.add_task(f"  {step_description}", total=total)
            try:
                yield lambda done, total_=None: progress.update(task, completed=done)
            finally:
                progress.remove_task(task)
                progress.advance(overall)

        yield bar


@contextlib.contextmanager
def status(message: str, enabled: bool = True):
    """A spinner with ``message`` while the block runs (on a terminal)."""
    console = _terminal() if enabled else None
    if console is None:
        yield
        return
    with console.status(message):
        yield
