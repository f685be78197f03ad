"""Recordings (MCAP): what a file holds (:mod:`common.record.info`)."""

from pathlib import Path


def split_path(path: str, part: int) -> str:
    """The ``part``-th file after ``path`` of a recording split by size, duration or frames
    (``NAME.splitK.EXT``; part 0 is ``path`` itself): the recorder's MCAP and the viewer's .rrd."""
    p = Path(path)
    return str(p.with_name(f"{p.stem}.split{part}{p.suffix}")) if part else str(path)
