"""README's results table is the one its published results give (experiments.readme_table)."""

import pytest

from experiments import readme_table


def test_readme_table_matches_its_results():
    text = readme_table.README.read_text()
    assert readme_table.regenerate(text) == text, "run: python -m experiments.readme_table"


def test_a_changed_number_is_caught_and_rewritten(tmp_path, monkeypatch):
    readme = tmp_path / "README.md"
    text = readme_table.README.read_text()
    block = text.index("<!-- results-table:")
    row = text.index("| validation, training sensor |", block)
    readme.write_text(text[:row] + "| validation, training sensor | 0.0 " + text[text.index("|", row + 31):])
    monkeypatch.setattr(readme_table, "README", readme)
    assert readme_table.main(["--check"]) == 1
    assert readme_table.main([]) == 0
    assert readme.read_text() == text


def test_a_block_naming_a_missing_folder_is_refused():
    with pytest.raises(FileNotFoundError, match="no-such-folder"):
        readme_table.regenerate("<!-- results-table: docs/results/no-such-folder -->\nx\n<!-- /results-table -->")
    with pytest.raises(ValueError, match="no <!-- results-table"):
        readme_table.regenerate("no table here")
