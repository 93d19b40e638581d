"""The results tables in the README and on docs/results/index.md are what
``benchmarks/results_tables.py`` writes from the records under results/: a figure edited by hand,
or records changed without rewriting the pages, fails here."""

from __future__ import annotations

import importlib.util
import json
import shutil
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _results_tables():
    spec = importlib.util.spec_from_file_location(
        "results_tables", ROOT / "benchmarks" / "results_tables.py"
    )
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up while the class is built
    spec.loader.exec_module(module)
    return module


def test_the_pages_are_written_from_the_kept_records(tmp_path, monkeypatch):
    tables = _results_tables()
    readme, page = tmp_path / "README.md", tmp_path / "index.md"
    shutil.copyfile(ROOT / "README.md", readme)
    monkeypatch.setattr(tables, "README", readme)
    monkeypatch.setattr(tables, "PAGE", page)
    tables.write_page()
    tables.write_readme()
    assert page.read_text(encoding="utf-8") == (ROOT / "docs/results/index.md").read_text(
        encoding="utf-8"
    )
    assert readme.read_text(encoding="utf-8") == (ROOT / "README.md").read_text(encoding="utf-8")


def test_every_table_is_measured_and_stamped():
    tables = _results_tables()
    page = (ROOT / "docs/results/index.md").read_text(encoding="utf-8")
    for table in tables.TABLES:
        kept = ROOT / "results" / table.name
        stamp = json.loads((kept / tables.STAMP).read_text(encoding="utf-8"))
        assert (
            len(stamp["commit"]) == 40
            and stamp["date"]
            and stamp["command"].startswith("packlab bench")
        )
        assert f"{{#{table.name}}}" in page
        assert f"`{stamp['command']}` at commit `{stamp['commit'][:12]}`" in page


def test_the_readme_table_is_the_main_tables(tmp_path):
    tables = _results_tables()
    compact, stamp = tables.compact_markdown(tables.TABLES[0])
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    assert compact in readme and compact in (ROOT / "docs/results/index.md").read_text(
        encoding="utf-8"
    )
    assert stamp["commit"][:12] in readme
