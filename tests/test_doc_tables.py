"""README's and docs' result tables are the ones their published results give (experiments.doc_tables)."""

import pytest

from experiments import common, doc_numbers, doc_tables


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


def test_a_text_block_quotes_one_value_of_a_results_file(tmp_path, monkeypatch):
    monkeypatch.setattr(common, "ROOT", tmp_path)
    (tmp_path / "r.json").write_text('{"finding": "A ties B.", "t": {"wall_s": 150.0, "0.5": [1.25, 2]}}')
    doc = ("took <!-- result-text: r.json t.wall_s/60 {:.1f} min -->old<!-- /result-text --> and "
           "<!-- result-text: r.json t.0.5.0 --><!-- /result-text -->\n- <!-- result-text: r.json finding -->x"
           "<!-- /result-text -->")
    assert doc_tables.regenerate(doc) == (
        "took <!-- result-text: r.json t.wall_s/60 {:.1f} min -->2.5 min<!-- /result-text --> and "
        "<!-- result-text: r.json t.0.5.0 -->1.25<!-- /result-text -->\n- <!-- result-text: r.json finding -->"
        "A ties B.<!-- /result-text -->")
    with pytest.raises(KeyError, match="t.nothing"):
        doc_tables.regenerate("<!-- result-text: r.json t.nothing --><!-- /result-text -->")
    with pytest.raises(FileNotFoundError, match="gone.json"):
        doc_tables.regenerate("<!-- result-text: gone.json t --><!-- /result-text -->")


@pytest.mark.parametrize("planted", ["The quick run took 12.5 min.", "DINO RD reads 5.7% here.",
                                     "it reads 4.2 ± 0.3 on DIGIT", "a 3.7x speed-up", "Fz is read 1.8 N low"])
def test_a_hand_typed_measured_number_fails_the_check(tmp_path, monkeypatch, planted):
    readme = tmp_path / "README.md"
    readme.write_text(doc_tables.README.read_text() + "\n" + planted + "\n")
    monkeypatch.setattr(doc_tables, "README", readme)
    monkeypatch.setattr(doc_tables, "DOCUMENTS", (readme,))
    assert doc_tables.main(["--check"]) == 1
    assert [n for _, _, n in doc_tables.hand_typed_numbers()] != []


def test_numbers_in_code_blocks_and_allowed_constants_are_not_measurements():
    text = ("Run `--set train.lr=1e-4 --max-s 5s` then\n```bash\npytest  # 10 min\n```\nForces up to 15 N; "
            "Python 3.11, Table II, a 10x10 grid, [link](docs/a_5%.md) <!-- 12 s -->")
    assert doc_numbers.hand_typed(text) == []
    assert doc_numbers.hand_typed("trained in 15 N minutes 16 N") == [(1, "16 N")]


@pytest.mark.parametrize("doc", doc_tables.DOCUMENTS, ids=lambda p: p.name)
def test_no_measured_number_is_typed_by_hand(doc):
    hits = doc_numbers.hand_typed(doc.read_text())
    assert not hits, f"{doc.name}: quote these through a generated block (experiments.doc_tables): {hits[:10]}"


def test_a_text_block_of_several_lines_starts_on_its_own_line(tmp_path, monkeypatch):
    monkeypatch.setattr(common, "ROOT", tmp_path)
    (tmp_path / "r.json").write_text('{"summary": "- a\\n- b"}')
    doc = "Summary: <!-- result-text: r.json summary -->old<!-- /result-text -->"
    assert doc_tables.regenerate(doc) == ("Summary: <!-- result-text: r.json summary -->\n- a\n- b\n"
                                          "<!-- /result-text -->")
    assert doc_tables.regenerate(doc_tables.regenerate(doc)) == doc_tables.regenerate(doc)
