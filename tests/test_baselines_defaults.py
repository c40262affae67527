"""Which models the report runs: the default set, the full matrix one word away, and unknown names refused."""

from types import SimpleNamespace

import numpy as np
import pytest

from neatskin.baselines.models import MODEL_NAMES
from neatskin.baselines.report import DEFAULT_MODELS, _resolve
from neatskin.errors import DataError


def _data(n_rows: int = 100, layout: object | None = "a layout"):
    return SimpleNamespace(layout=layout, y=np.zeros((n_rows, 2)))


def _models(models, data=None):
    _, learned, physics, notes, _ = _resolve("both", models, data or _data())
    return (*learned, *physics), notes


def test_the_default_is_the_models_that_answer_both_questions():
    names, notes = _models(None)
    assert names == ("ridge", "knn", "extra_trees", "lm_network", "inversion") == DEFAULT_MODELS
    assert notes == []


@pytest.mark.parametrize("spelled", ["all", ["all"], ("all",)])
def test_all_is_the_full_matrix(spelled):
    names, _ = _models(spelled)
    assert names == (*MODEL_NAMES, "inversion")


def test_named_models_run_as_named_and_unknown_ones_are_refused():
    assert _models(["mlp", "ridge"])[0] == ("mlp", "ridge")
    with pytest.raises(DataError, match="unknown model 'forest'"):
        _models(["forest"])


def test_the_inversions_guards_hold_for_the_default_and_all():
    # no layout: the inversion drops out silently unless named
    for models in (None, "all"):
        names, notes = _models(models, _data(layout=None))
        assert "inversion" not in names and notes == []
    assert _models(["inversion"], _data(layout=None))[1] == [
        "inversion skipped: the dataset names no layout (manifest.json), so there is no forward model"
    ]
    # a huge dataset: only a named inversion runs
    for models in (None, "all"):
        names, notes = _models(models, _data(n_rows=30_000))
        assert "inversion" not in names and "inversion skipped" in notes[0]
    assert "inversion" in _models(["inversion"], _data(n_rows=30_000))[0]
