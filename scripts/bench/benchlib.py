"""Shared plumbing of the benchmark scripts: their command line and their CSV output."""

import argparse
from pathlib import Path

from parefg.sweep import write_csv as _write_rows


def parser(doc: str, repeats: int) -> argparse.ArgumentParser:
    """The common options: --repeats (runs per median) and --out (CSV directory)."""
    result = argparse.ArgumentParser(description=doc.splitlines()[0])
    result.add_argument("--repeats", type=int, default=repeats, help="runs per median")
    result.add_argument("--out", default="results", help="directory of the CSV files")
    return result


def write_csv(directory: str, name: str, rows: list[dict]) -> Path:
    """Write ``rows`` (dicts with the same keys) to DIRECTORY/NAME; return the path."""
    path = Path(directory) / name
    path.parent.mkdir(parents=True, exist_ok=True)
    _write_rows(path, rows)
    return path
