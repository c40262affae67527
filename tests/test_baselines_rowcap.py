"""Large datasets: the costly models train on an even draw over the positions, the physics inversion waits to be
named; small ones (the paper's campaign) are untouched."""

from __future__ import annotations

import numpy as np
import pytest

from neatskin.baselines.evaluate import even_draw, fit_tasks
from neatskin.baselines.models import TRAIN_ROW_CAP, make_models
from neatskin.baselines.splits import Repeat


def test_even_draw_takes_every_positions_kth_row_before_any_k_plus_first():
    groups = np.repeat(np.arange(10), [1, 2, 3, 4, 5, 6, 7, 8, 9, 10])  # 55 rows, positions of 1..10 rows
    rows = np.arange(55)
    drawn = even_draw(rows, groups, 25, seed=3)
    counts = np.bincount(groups[drawn], minlength=10)
    # 25 rows over 10 positions: turns 0 and 1 take 10 + 9 = 19, turn 2 takes 6 of the 8 positions left
    assert len(drawn) == 25 and len(set(drawn.tolist())) == 25
    assert counts[0] == 1 and counts[1] == 2
    assert counts[2:].min() >= 2 and counts[2:].max() <= 3 and int((counts[2:] == 3).sum()) == 6
    assert np.all(np.diff(drawn) > 0)
    np.testing.assert_array_equal(drawn, even_draw(rows, groups, 25, seed=3))  # keyed by the seed
    assert not np.array_equal(drawn, even_draw(rows, groups, 25, seed=4))


def test_even_draw_keeps_rows_at_or_under_the_cap():
    rows = np.array([7, 3, 9])
    assert even_draw(rows, np.arange(10), 3, seed=0) is rows


def test_fit_tasks_give_a_capped_model_its_draw_and_every_test_row():
    rng = np.random.default_rng(0)
    groups = np.repeat(np.arange(30), 10)
    X, y = rng.normal(size=(300, 4)), rng.normal(size=(300, 2))
    rep = Repeat(0, 11, np.arange(0, 250), np.arange(250, 300))
    models = make_models(("ridge", "knn"), n_features=4)
    tasks = {t.key: t for t in fit_tasks(models, X, y, groups, {"grouped": [rep]}, row_caps={"knn": 50})}
    knn_train, knn_test = tasks[("grouped", "knn", 0)].args[4:6]
    ridge_train = tasks[("grouped", "ridge", 0)].args[4]
    np.testing.assert_array_equal(knn_train, even_draw(rep.train, groups, 50, 11))
    assert np.bincount(groups[knn_train]).max() == 2  # 25 positions in training, 2 rows each
    np.testing.assert_array_equal(knn_test, rep.test)
    np.testing.assert_array_equal(ridge_train, rep.train)


@pytest.mark.parametrize("name", sorted(TRAIN_ROW_CAP))
def test_the_papers_training_rows_are_never_capped(name):
    assert TRAIN_ROW_CAP[name] > 2 * 2240  # 2,800 presses, a fifth held out


def test_the_inversion_waits_to_be_named_on_a_large_dataset(monkeypatch):
    from types import SimpleNamespace

    import neatskin.baselines.report as report

    monkeypatch.setattr(report, "INVERSION_MAX_PRESSES", 40)
    data = SimpleNamespace(y=np.zeros((50, 2)), layout=object())
    _, _, physics, notes, _ = report._resolve("grouped", None, data)
    assert physics == () and notes and notes[0].startswith("inversion skipped: 50 presses")
    _, _, physics, notes, _ = report._resolve("grouped", ["ridge", "inversion"], data)
    assert physics == ("inversion",) and notes == []
    monkeypatch.setattr(report, "INVERSION_MAX_PRESSES", 50)
    assert report._resolve("grouped", None, data)[2] == ("inversion",)
