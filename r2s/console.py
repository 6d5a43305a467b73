"""The one module that imports rich: a shared console, a progress factory, error printing.

Core code never imports rich; it accepts a :data:`ProgressFn` callback instead, so it runs
silently in tests and with a progress bar on the terminal.
"""

from __future__ import annotations

import contextlib
from typing import Callable, Iterator

from rich.console import Console
from rich.progress import BarColumn, Progress, SpinnerColumn, TextColumn, TimeElapsedColumn
from rich.table import Table

console = Console(stderr=False, highlight=False)
err_console = Console(stderr=True, highlight=False)

ProgressFn = Callable[[str, float], None]
"""``progress(message, fraction_done)``: fraction in [0, 1], or a negative value for "unknown"."""


def silent_progress(message: str, fraction: float) -> None:  # noqa: ARG001
    """A progress callback that does nothing (tests, batch jobs)."""


@contextlib.contextmanager
def stage_progress(title: str) -> Iterator[ProgressFn]:
    """A rich progress bar for one stage; yields the callback core code calls."""
    with Progress(
        SpinnerColumn(),
        TextColumn("[bold]{task.fields[title]}[/bold] {task.description}"),
        BarColumn(),
        TimeElapsedColumn(),
        console=console,
        transient=True,
    ) as bar:
        task = bar.add_task("", total=1.0, title=title)

        def update(message: str, fraction: float) -> None:
            if fraction >= 0:
                bar.update(task, description=message, completed=min(max(fraction, 0.0), 1.0))
            else:
                bar.update(task, description=message)

        yield update


def print_error(message: str) -> None:
    """One red line on stderr."""
    err_console.print(f"[bold red]error:[/bold red] {message}", soft_wrap=True, markup=True,
                      highlight=False)


def print_table(title: str, columns: list[str], rows: list[list[str]]) -> None:
    """Print a simple table of already formatted strings."""
    table = Table(title=title)
    for col in columns:
        table.add_column(col)
    for row in rows:
        table.add_row(*row)
    console.print(table)


def print_warning(message: str) -> None:
    """One yellow line on stderr (input warnings)."""
    err_console.print(f"[yellow]warning:[/yellow] {message}", soft_wrap=True, markup=True,
                      highlight=False)
