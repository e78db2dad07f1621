"""Terminal output shared by every command: consoles, progress bars and tables."""

from __future__ import annotations

import sys
from contextlib import contextmanager
from typing import Iterator

from rich.console import Console
from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn
from rich.table import Table

console = Console(stderr=True)
out_console = Console(width=None if sys.stdout.isatty() else 160)


def progress_bar() -> Progress:
    return Progress(
        TextColumn("[bold]{task.description}"), BarColumn(), TextColumn("{task.percentage:>3.0f}%"),
        TimeElapsedColumn(), TimeRemainingColumn(), console=console, transient=False,
    )


@contextmanager
def progress_task(progress: Progress, description: str) -> Iterator:
    task = progress.add_task(description, total=1.0)

    def update(done: float, total: float) -> None:
        progress.update(task, completed=min(done / total, 1.0) if total else 1.0)

    yield update
    progress.update(task, completed=1.0)


def print_table(df, title: str, columns: list[str] | None = None) -> None:
    cols = columns or list(df.columns)
    table = Table(title=title, show_lines=False)
    for c in cols:
        table.add_column(c, justify="right" if df[c].dtype.kind in "fi" else "left")
    for _, row in df[cols].iterrows():
        table.add_row(*[f"{v:.2f}" if isinstance(v, float) else str(v) for v in row])
    out_console.print(table)
