"""One way the commands print a table of results (rich), so that they read alike."""

from __future__ import annotations


def print_table(title: str, columns: list[str], rows: list[list[str]]) -> None:
    """``rows`` of already formatted cells under ``columns`` (the first column left-aligned, the
    others right-aligned, as numbers are); plain text when standard output is not a terminal."""
    from rich.console import Console
    from rich.table import Table

    table = Table(title=title)
    for i, col in enumerate(columns):
        table.add_column(col, justify="left" if i == 0 else "right")
    for row in rows:
        table.add_row(*row)
    Console().print(table)
