"""Where a site may be written: a directory that is absent, empty, or a site this package built.

Apart from :mod:`leaderboard.web.site` so that ``python -m leaderboard.build`` can refuse a wrong
``--site`` in its first second, before it loads the site's Jinja, matplotlib and SciPy.
"""

from __future__ import annotations

from pathlib import Path

#: The file that marks a directory as a site built here (and so safe to replace).
SITE_MARKER = ".leaderboard-site"


class SiteError(RuntimeError):
    """The site cannot be built where asked (e.g. the target is a directory we did not create)."""


def check_target(site_dir: Path) -> None:
    """Raise :class:`SiteError` unless ``site_dir`` is absent, empty, or a previous build of this package.

    Called before anything is built, so that a wrong ``--site`` costs nothing and deletes nothing.
    """
    if site_dir.exists():
        if not site_dir.is_dir():
            raise SiteError(f"{site_dir} exists and is not a directory")
        if any(site_dir.iterdir()) and not (site_dir / SITE_MARKER).is_file():
            raise SiteError(f"{site_dir} is not empty and was not built by leaderboard.web.site (no {SITE_MARKER}); "
                            "refusing to replace it: choose another --site or remove it yourself")
