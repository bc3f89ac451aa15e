"""``mttbench screenshot``: a report checked in headless chromium."""

from __future__ import annotations

import argparse
from pathlib import Path

from .usage import UsageError


def cmd_screenshot(args: argparse.Namespace) -> int:
    """Open a report folder's ``report.html`` in headless chromium; write ``screenshot.png``."""
    from .report import screenshot

    folder = Path(args.report_dir)
    if not (folder / "report.html").is_file():
        raise UsageError(f"{folder} holds no report.html")
    try:
        png = screenshot(folder / "report.html", folder / "screenshot.png")
    except (FileNotFoundError, RuntimeError) as exc:
        raise UsageError(str(exc).splitlines()[0]) from None
    print(png)
    return 0


def add_parser(sub: argparse._SubParsersAction, fmt: type[argparse.HelpFormatter]) -> None:
    """The ``screenshot`` sub-command."""
    p = sub.add_parser(
        "screenshot", help="check a report in a real browser (headless chromium)",
        description="Open REPORT_DIR/report.html in headless chromium (Debian: apt-get "
                    "install chromium), with networking off, and write "
                    "REPORT_DIR/screenshot.png.")
    p.add_argument("report_dir", metavar="REPORT_DIR", help="a folder written by compare")
    p.set_defaults(func=cmd_screenshot)
