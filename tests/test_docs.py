"""The documentation holds together: every relative link of README.md and docs/*.md (and of the reports committed
under docs/) points at a file that exists, and at a heading of it where it names one; README.md stays a product page
(at most 300 lines); no page, report or table names a path of the machine it was written on."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
REPORTS = sorted((ROOT / "docs").glob("*/**/*.md"))
LINK = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)(?:\s+\"[^\"]*\")?\)")
FENCE = re.compile(r"^```.*?^```", re.M | re.S)


def anchors(page: Path) -> set[str]:
    """The heading anchors GitHub makes for a Markdown page: lower case, punctuation dropped, spaces to hyphens,
    a repeated heading numbered."""
    seen: dict[str, int] = {}
    out = set()
    for heading in re.findall(r"^#{1,6}\s+(.+?)\s*#*$", FENCE.sub("", page.read_text()), re.M):
        slug = re.sub(r"[^\w\- ]", "", heading.strip().lower()).replace(" ", "-")
        n = seen.get(slug, 0)
        seen[slug] = n + 1
        out.add(slug if n == 0 else f"{slug}-{n}")
    return out


def links(page: Path) -> list[str]:
    return [t for t in LINK.findall(FENCE.sub("", page.read_text())) if not re.match(r"[a-z]+:", t)]


def test_the_pages_link_somewhere():
    assert sum(len(links(p)) for p in PAGES) > 50


@pytest.mark.parametrize("page", PAGES + REPORTS, ids=lambda p: str(p.relative_to(ROOT)))
def test_every_relative_link_resolves(page):
    broken = []
    for target in links(page):
        path, _, anchor = target.partition("#")
        where = (page.parent / path).resolve() if path else page
        if not where.exists():
            broken.append(f"{target}: no such file")
        elif anchor and where.suffix == ".md" and anchor not in anchors(where):
            broken.append(f"{target}: no heading #{anchor} in {where.relative_to(ROOT)}")
    assert not broken, broken


def test_the_readme_is_a_product_page():
    text = (ROOT / "README.md").read_text()
    assert len(text.splitlines()) <= 300
    for section in ("## Install", "## Quick start", "## Using the environment", "## Train", "## Evaluate"):
        assert f"\n{section}\n" in text, section
    assert "## Reproduce the paper" in text and "## Documentation" in text


#: what docs/ publishes beside the pages: reports, their tables and benchmark files (not the raw records of runs, where
#: Hydra keeps the directory each run was started in)
PUBLISHED = sorted(
    p
    for p in (ROOT / "docs").rglob("*")
    if p.suffix in (".md", ".csv", ".json") and "record" not in p.relative_to(ROOT).parts
)


def test_published_files_are_found():
    assert ROOT / "docs" / "results" / "paper-cpu" / "report.md" in PUBLISHED


@pytest.mark.parametrize("page", PAGES + PUBLISHED, ids=lambda p: str(p.relative_to(ROOT)))
def test_no_page_names_a_path_of_the_machine_it_was_written_on(page):
    found = re.findall(r"(?<![\w.])/(?:work|root|tmp|home)/\S*", page.read_text())
    assert not found, found


def claims_table(text: str) -> list[tuple[str, str]]:
    """(claim, verdict) of each row of the first Markdown table that follows the header ``| claim | verdict |``."""
    rows = text.split("| claim | verdict |", 1)[1].split("\n\n", 1)[0].splitlines()[2:]
    return [tuple(cell.strip() for cell in row.strip("|").split(" | ")[:2]) for row in rows]


def test_the_readme_gives_the_paper_learned_report_s_verdicts_cells_and_cpu_time():
    """README's "Reproduce the paper" quotes paper_learned's report: the claims at a glance (claim and verdict, row
    by row), the cells done of all, and the CPU-hours its done cells took; remaking the report without the README
    fails here."""
    readme = (ROOT / "README.md").read_text().split("## Reproduce the paper\n", 1)[1].split("\n## ", 1)[0]
    report = (ROOT / "docs" / "results" / "paper-learned" / "report.md").read_text()
    assert claims_table(readme) == claims_table(report)
    assert [c for c, _ in claims_table(report)][0].startswith("(a)") and len(claims_table(report)) == 5
    total, done = re.search(r"(\d+) cells besides the report, (\d+) of them done", report).groups()
    hours = float(re.search(r"\| \*\*all\*\* \| \d+ \| \*\*([\d.]+)\*\*", report).group(1))
    # the report's cells besides itself, and the report: "103 of 103 cells done (102 trainings and evaluations, ...)"
    said = rf"\b{int(done) + 1} of {int(total) + 1} cells done \({done} trainings and evaluations, and the report\),"
    assert re.search(said + rf"\s+{hours:.1f} CPU-hours", readme), (done, total, hours)


def _prose(page: str) -> str:
    """A docs page's text with its line breaks as spaces, so that a phrase wrapped over two lines is found."""
    return " ".join((ROOT / "docs" / page).read_text().split())


def test_the_level_name_rule_is_where_level_files_are_documented():
    """docs/levels.md ("A level of your own") states the rule evaaa.level enforces, word for word, so the page cannot
    drift from the code (issue 65)."""
    from evaaa.level import LEVEL_NAME_RULE

    section = _prose("levels.md").split("## A level of your own", 1)[1].split("## ", 1)[0]
    assert LEVEL_NAME_RULE in section
    assert "`name:`" in section and "refused at load" in section


def test_the_checkpoint_refusals_are_where_checkpoints_are_documented():
    """docs/training.md says which crafted checkpoints are refused, with the limit the code uses, and where a refused
    latest checkpoint leaves a resume (issue 65)."""
    from baselines.checkpoint import MAX_NESTING

    text = _prose("training.md").split("Checkpoint files hold tensors and plain data only", 1)[1].split("**Ctrl-C**")[0]
    assert f"nested more than {MAX_NESTING} deep (`MAX_NESTING`)" in text
    for phrase in ("is malformed:", "NaN or infinite values", "is unusable", "falls back to `checkpoint-previous.pt`"):
        assert phrase in text, phrase
