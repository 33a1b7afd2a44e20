"""README's and docs' result tables are the ones their published results give (experiments.doc_tables)."""

import pytest

from experiments import common, doc_tables


@pytest.mark.parametrize("doc", doc_tables.DOCUMENTS, ids=lambda p: p.name)
def test_every_generated_table_matches_its_results(doc):
    text = doc.read_text()
    assert doc_tables.regenerate(text) == text, "run: python -m experiments.doc_tables"


def test_a_changed_number_is_caught_and_rewritten(tmp_path, monkeypatch):
    readme = tmp_path / "README.md"
    text = doc_tables.README.read_text()
    block = text.index("<!-- results-table:")
    row = text.index("| validation, training sensor |", block)
    readme.write_text(text[:row] + "| validation, training sensor | 0.0 " + text[text.index("|", row + 31):])
    monkeypatch.setattr(doc_tables, "README", readme)
    monkeypatch.setattr(doc_tables, "DOCUMENTS", (readme,))
    assert doc_tables.main(["--check"]) == 1
    assert doc_tables.main([]) == 0
    assert readme.read_text() == text


def test_an_include_block_copies_the_first_table_of_its_file(tmp_path, monkeypatch):
    monkeypatch.setattr(common, "ROOT", tmp_path)
    (tmp_path / "r").mkdir()
    (tmp_path / "r" / "sweep.md").write_text("# title\n\n| a | b |\n|---|---|\n| 1 | 2 |\n\nprose\n\n| c |\n|---|\n")
    doc = "before\n<!-- result-include: r/sweep.md -->\nold\n<!-- /result-include -->\nafter\n"
    assert doc_tables.regenerate(doc) == ("before\n<!-- result-include: r/sweep.md -->\n| a | b |\n|---|---|\n"
                                          "| 1 | 2 |\n<!-- /result-include -->\nafter\n")
    with pytest.raises(FileNotFoundError, match="gone.md"):
        doc_tables.regenerate("<!-- result-include: r/gone.md -->\n<!-- /result-include -->")
    (tmp_path / "r" / "prose.md").write_text("no table\n")
    with pytest.raises(ValueError, match="no Markdown table"):
        doc_tables.regenerate("<!-- result-include: r/prose.md -->\n<!-- /result-include -->")
    # FILE.md#TEXT: the first table after the line holding TEXT
    doc = "<!-- result-include: r/sweep.md#prose -->\n<!-- /result-include -->"
    assert doc_tables.regenerate(doc) == ("<!-- result-include: r/sweep.md#prose -->\n| c |\n|---|\n"
                                          "<!-- /result-include -->")
    with pytest.raises(ValueError, match="no 'elsewhere'"):
        doc_tables.regenerate("<!-- result-include: r/sweep.md#elsewhere -->\n<!-- /result-include -->")


def test_a_block_naming_a_missing_folder_is_refused():
    with pytest.raises(FileNotFoundError, match="no-such-folder"):
        doc_tables.regenerate("<!-- results-table: docs/results/no-such-folder -->\nx\n<!-- /results-table -->")
