"""Every protocols-page anchor cited in the code names a real section of docs/protocols.md."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CITATION = re.compile(r"docs/protocols\.md#([a-z0-9-]+)")


def _anchors(markdown: str) -> set[str]:
    """GitHub's heading anchors: lower case, punctuation dropped, spaces to hyphens."""
    out = set()
    for line in markdown.splitlines():
        if line.startswith("#"):
            title = line.lstrip("#").strip().lower()
            out.add(re.sub(r"\s", "-", re.sub(r"[^\w\s-]", "", title)))
    return out


def test_protocol_citations_resolve() -> None:
    anchors = _anchors((ROOT / "docs" / "protocols.md").read_text())
    cited: dict[str, list[str]] = {}
    for path in [*ROOT.glob("morality_gym/**/*.py"), *ROOT.glob("runners/**/*.py"), *ROOT.glob("leaderboard/**/*.py"),
                 *ROOT.glob("conf/**/*.yaml"), *ROOT.glob("tests/test_[!d]*.py"), ROOT / "README.md"]:
        for anchor in CITATION.findall(path.read_text()):
            cited.setdefault(anchor, []).append(str(path.relative_to(ROOT)))
    assert len(cited) >= 10
    missing = {a: files for a, files in cited.items() if a not in anchors}
    assert not missing, f"cited sections that docs/protocols.md does not have: {missing}"


def test_code_cites_no_private_spec_quirks() -> None:
    """Users do not have the evaluation spec: the code cites docs/protocols.md, not 'spec Qn'."""
    offenders = []
    for path in [*ROOT.glob("morality_gym/**/*.py"), *ROOT.glob("runners/**/*.py"), *ROOT.glob("leaderboard/**/*.py"),
                 *ROOT.glob("conf/**/*.yaml"), *ROOT.glob("benchmarks/*.py"), ROOT / "README.md"]:
        for number, line in enumerate(path.read_text().splitlines(), 1):
            if re.search(r"\bspec,? Q\d+|\(Q\d+[):,]|quirks? Q\d+", line):
                offenders.append(f"{path.relative_to(ROOT)}:{number}: {line.strip()}")
    assert not offenders, "\n".join(offenders)


def test_files_cite_docs_that_exist() -> None:
    """A ``docs/...`` page named in a shipped data file exists (eleven scenario files pointed at a
    docs/scenario-format.md that did not)."""
    root = Path(__file__).resolve().parents[1]
    cited = {(path.relative_to(root), page) for path in (root / "morality_gym" / "data").rglob("*.yaml")
             for page in re.findall(r"docs/[\w./-]+\.md", path.read_text())}
    assert cited, "no data file cites a docs page: the test checks nothing"
    missing = sorted((str(path), page) for path, page in cited if not (root / page).is_file())
    assert not missing, f"data files cite pages that do not exist: {missing}"
