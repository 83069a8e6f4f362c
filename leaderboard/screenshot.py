"""``python -m leaderboard.screenshot``: a PNG of the leaderboard's index page, for READMEs and reviews.

Uses Playwright with the system's (Debian) Chromium rather than a downloaded browser, and the
flags that keep Chromium from reaching for the network on a machine without one (its background
services would otherwise stall or log errors). Each launch gets a fresh, empty profile.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from collections.abc import Sequence
from pathlib import Path

from morality_gym.clitools import OneLineParser, UserError, add_debug_flag, run_cli

CHROMIUM = Path("/usr/bin/chromium")
CHROMIUM_ARGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
]
DEFAULT_SITE = Path(__file__).resolve().parent / "site"
DEFAULT_OUT = Path(__file__).resolve().parent / "index.png"


def launch_browser(playwright: object, profile: Path, chromium: Path = CHROMIUM) -> object:
    """A persistent Chromium context on an empty profile (``--user-data-dir`` must be fresh)."""
    return playwright.chromium.launch_persistent_context(  # type: ignore[attr-defined]
        str(profile),
        executable_path=str(chromium),
        headless=True,
        args=CHROMIUM_ARGS,
        viewport={"width": 1360, "height": 900},
        device_scale_factor=1,
    )


def screenshot(site: Path, out: Path, page_name: str = "index.html", full_page: bool = True,
               chromium: Path = CHROMIUM) -> Path:
    """Open ``site/page_name`` from ``file://`` and save a screenshot to ``out``."""
    # Playwright waits: importing leaderboard.screenshot (its --help too) must not load it
    from playwright.sync_api import sync_playwright

    target = (site / page_name).resolve()
    if not target.is_file():
        raise FileNotFoundError(f"{target} does not exist; build the site first (make leaderboard, or "
                                f"python -m leaderboard.build --site {site}) or pass --site DIR")
    if not chromium.is_file():
        raise FileNotFoundError(f"{chromium} not found; install Debian's chromium (apt-get install chromium)")
    out.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="leaderboard-chromium-") as profile, sync_playwright() as pw:
        context = launch_browser(pw, Path(profile), chromium)
        try:
            page = context.new_page()  # type: ignore[attr-defined]
            page.goto(target.as_uri(), wait_until="load")
            page.wait_for_function("Array.from(document.images).every(i => i.complete)", timeout=15_000)
            page.screenshot(path=str(out), full_page=full_page)
        finally:
            context.close()  # type: ignore[attr-defined]
    return out


def build_parser() -> argparse.ArgumentParser:
    """The command's parser, apart from parsing: the docs' command-line reference is generated from it."""
    parser = OneLineParser(prog="python -m leaderboard.screenshot", description=__doc__.splitlines()[0])
    parser.add_argument("--site", type=Path, default=DEFAULT_SITE, help=f"built site (default: {DEFAULT_SITE})")
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT, help=f"PNG to write (default: {DEFAULT_OUT})")
    parser.add_argument("--page", default="index.html", help="page relative to the site root (default: index.html)")
    parser.add_argument("--viewport-only", action="store_true", help="only the first screen, not the full page")
    add_debug_flag(parser)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    parser = build_parser()

    def body() -> int:
        args = parser.parse_args(argv)
        try:
            path = screenshot(args.site, args.out, args.page, full_page=not args.viewport_only)
        except PermissionError as exc:
            raise UserError(f"cannot write {exc.filename or args.out} ({exc.strerror}); pass --out PNG elsewhere") from exc
        print(f"wrote {path}")
        return 0

    return run_cli(body, (FileNotFoundError,), argv)


if __name__ == "__main__":
    sys.exit(main())
