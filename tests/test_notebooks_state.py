"""experiments.notebooks: a notebook's outputs are a result: stale when never executed, when its cells or the
results it shows changed since they ran, or when the code it imports did (experiments.status lists them)."""

import nbformat

from experiments import common, notebooks


def _book(tmp_path, monkeypatch):
    monkeypatch.setattr(common, "ROOT", tmp_path)
    (tmp_path / "r").mkdir()
    (tmp_path / "r" / "results.json").write_text('{"x": 1}')
    nb = nbformat.v4.new_notebook(cells=[nbformat.v4.new_code_cell("print(1)")])
    path = tmp_path / "n.ipynb"
    nbformat.write(nb, path)
    return notebooks.Notebook("n.ipynb", ("r/*.json",), ()), nb, path


def _unchanged(commit, paths, certificates=False):
    return []


def test_a_notebook_never_executed_is_stale(tmp_path, monkeypatch):
    book, _, _ = _book(tmp_path, monkeypatch)
    state, why = notebooks.state(book, _unchanged)
    assert state == "stale" and "never executed" in why[0]


def test_changed_cells_or_shown_results_make_it_stale(tmp_path, monkeypatch):
    book, nb, path = _book(tmp_path, monkeypatch)
    nb.metadata["ffjax"] = {"commit": "abc", "cells_sha256": notebooks.cells_digest(nb),
                            "shows_sha256": notebooks.shown(book)}
    nbformat.write(nb, path)
    assert notebooks.state(book, _unchanged) == ("current", [])
    (tmp_path / "r" / "results.json").write_text('{"x": 2}')
    assert notebooks.state(book, _unchanged)[1] == ["the results it shows changed since it ran"]
    (tmp_path / "r" / "results.json").write_text('{"x": 1}')
    nb.cells[0].source = "print(2)"
    nbformat.write(nb, path)
    assert notebooks.state(book, _unchanged)[1] == ["its cells changed since they ran"]


def test_a_notebook_run_on_uncommitted_code_or_older_code_is_stale(tmp_path, monkeypatch):
    book, nb, path = _book(tmp_path, monkeypatch)
    meta = {"cells_sha256": notebooks.cells_digest(nb), "shows_sha256": notebooks.shown(book)}
    nb.metadata["ffjax"] = {**meta, "commit": "abc-dirty"}
    nbformat.write(nb, path)
    assert "uncommitted" in notebooks.state(book, _unchanged)[1][0]
    nb.metadata["ffjax"] = {**meta, "commit": "abc"}
    nbformat.write(nb, path)
    assert notebooks.state(book, lambda commit, paths, certificates=False: ["a.py"]) == ("stale", ["a.py"])


def test_the_published_notebooks_are_known_to_status():
    assert {n.path for n in notebooks.NOTEBOOKS} == {"notebooks/results.ipynb", "notebooks/simulator.ipynb"}
    for n in notebooks.NOTEBOOKS:
        assert (common.ROOT / n.path).is_file()
