"""Docs that cannot rot: the configuration reference is generated from the schema, and the
README's quick start is the two make targets CI and users run."""

from __future__ import annotations

import re

from feltool.config.docgen import render

from .conftest import ROOT


def test_configuration_reference_is_in_sync_with_the_schema():
    committed = (ROOT / "docs" / "configuration.md").read_text()
    assert committed == render(), "run: python -m feltool.config.docgen docs/configuration.md"


def test_readme_quick_start_is_make_run_and_make_test():
    readme = (ROOT / "README.md").read_text()
    block = re.search(r"## Quick start.*?```(?:sh|bash)?\n(.*?)```", readme, re.S)
    assert block, "README needs a '## Quick start' section with a code block"
    commands = [c.strip() for c in block.group(1).splitlines() if c.strip()]
    assert commands == ["make run", "make test"]
    makefile = (ROOT / "Makefile").read_text()
    assert re.search(r"^run:", makefile, re.M) and re.search(r"^test:", makefile, re.M)
    assert "make test" in (ROOT / ".ci" / "run").read_text()


def test_docs_pages_exist_and_link_figures_that_exist():
    for page in ("quickstart.md", "configuration.md", "theory.md", "robots.md", "results.md"):
        assert (ROOT / "docs" / page).is_file(), page
    for page in (ROOT / "docs").glob("*.md"):
        for target in re.findall(r"!\[[^\]]*\]\(([^)]+)\)", page.read_text()):
            assert (page.parent / target).is_file(), (page.name, target)


def test_theory_page_names_functions_that_exist():
    import importlib

    text = (ROOT / "docs" / "theory.md").read_text()
    names = re.findall(r"`(feltool(?:\.\w+)+)`", text)
    assert len(names) >= 8
    for dotted in names:
        parts = dotted.split(".")
        for cut in range(len(parts), 0, -1):
            try:
                obj = importlib.import_module(".".join(parts[:cut]))
                break
            except ModuleNotFoundError:
                continue
        for attr in parts[cut:]:
            obj = getattr(obj, attr)
