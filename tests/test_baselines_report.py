"""Baselines on datasets: clear DataErrors, extreme-but-legal data, the report files, the CLI."""

import json
import warnings
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow.parquet as pq
import pytest

from neatskin.baselines.dataset import load_baseline_data
from neatskin.baselines.evaluate import evaluate_model
from neatskin.baselines.models import MODEL_NAMES, make_model, make_models
from neatskin.baselines.report import run_baselines
from neatskin.baselines.summary import report_summary
from neatskin.baselines.tabletext import sig3
from neatskin.cli import main
from neatskin.errors import ConfigError, DataError
from neatskin.layout import load_layout
from neatskin.skin.synthetic import synthetic_presses

REPO = Path(__file__).resolve().parent.parent


def write_dataset(
    folder: Path,
    df: pd.DataFrame,
    layout: bool = False,
    crb_mm: float | np.ndarray | None = None,
    crb_nuisance_mm: float | np.ndarray | None = None,
) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    df.to_parquet(folder / "presses.parquet", index=False)
    if layout:
        (folder / "manifest.json").write_text(
            json.dumps({"layout": {"path": str(REPO / "protocols" / "skins" / "paper.toml")}, "status": "complete"})
        )
    if crb_mm is not None:
        pos = df.drop_duplicates("position_id")
        limit = pd.DataFrame(
            {
                "position_id": pos["position_id"],
                "x_mm": pos["x_mm"],
                "y_mm": pos["y_mm"],
                "crb_mm": np.broadcast_to(np.asarray(crb_mm, float), len(pos)),
            }
        )
        if crb_nuisance_mm is not None:
            limit["crb_nuisance_mm"] = crb_nuisance_mm
        limit.to_parquet(folder / "physical_limit.parquet")
    return folder


def small_table(n_positions=12, repeats=4, seed=0) -> pd.DataFrame:
    df = synthetic_presses(load_layout(REPO / "protocols" / "skins" / "paper.toml"), n_positions, repeats, seed=seed)
    df.insert(0, "campaign", "synthetic")
    return df


# ---------------------------------------------------------------- refusals


def test_nan_in_a_pair_column_is_one_data_error_naming_file_column_and_fix(tmp_path):
    df = small_table()
    df.loc[5, "dR_ohm_2_6"] = np.nan
    folder = write_dataset(tmp_path / "ds", df)
    with pytest.raises(DataError) as info:
        run_baselines(folder, models=["ridge"], progress=False)
    err = info.value
    assert len(err.problems) == 1
    assert err.field == "dR_ohm_2_6"
    assert str(folder) in err.file
    assert "press_id [5]" in str(err) and "fix:" in str(err)
    assert not (folder / "report.md").exists()


def test_missing_pair_column_against_the_manifest_layout_is_a_data_error(tmp_path):
    df = small_table().drop(columns=["dR_ohm_3_7"])
    folder = write_dataset(tmp_path / "ds", df, layout=True)
    with pytest.raises(DataError) as info:
        load_baseline_data(folder)
    assert info.value.field == "dR_ohm_3_7"
    assert "1 of 28 missing" in str(info.value)


def test_missing_position_column_is_a_data_error(tmp_path):
    folder = write_dataset(tmp_path / "ds", small_table().drop(columns=["y_mm"]))
    with pytest.raises(DataError) as info:
        load_baseline_data(folder)
    assert info.value.field == "y_mm"


def test_flagged_presses_are_dropped_refused_or_kept(tmp_path):
    df = small_table()
    df.at[3, "dR_ohm_1_2"] = np.inf  # a cut-off pair, flagged by the campaign
    df.at[3, "flags"] = ["open_circuit"]
    folder = write_dataset(tmp_path / "ds", df)
    data = load_baseline_data(folder)
    assert data.n_flagged_dropped == 1 and len(data.y) == len(df) - 1
    with pytest.raises(DataError, match="1 flagged presses"):
        load_baseline_data(folder, flagged="refuse")
    with pytest.raises(DataError) as info:
        load_baseline_data(folder, flagged="keep")
    assert info.value.field == "dR_ohm_1_2"


def test_merged_datasets_group_positions_per_campaign(tmp_path):
    a, b = small_table(seed=1), small_table(seed=2)
    b["campaign"] = "second"
    b["press_id"] += len(a)
    data = load_baseline_data(write_dataset(tmp_path / "ds", pd.concat([a, b], ignore_index=True)))
    assert len(np.unique(data.groups)) == 24  # same position ids, different campaigns


# ---------------------------------------------------------------- extreme but legal


def extreme(kind: str):
    df = small_table(n_positions=3 if kind == "few_positions" else 12, repeats=4)
    X = df.filter(like="dR_ohm").to_numpy().copy()
    y = df[["x_mm", "y_mm"]].to_numpy()
    if kind == "dead_electrode":
        X[:, [0, 1, 2, 3, 4, 5, 6]] = 0.0  # electrode 1 never conducts: all its pairs constant
    if kind == "scales_1e6_apart":
        X[:, ::2] *= 1e6
        X[:, 1::2] *= 1e-6
    return X, y, df["position_id"].to_numpy()


@pytest.mark.parametrize("kind", ["dead_electrode", "scales_1e6_apart", "few_positions"])
@pytest.mark.parametrize("name", MODEL_NAMES)
def test_extreme_but_legal_data_gives_finite_predictions(kind, name):
    X, y, groups = extreme(kind)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # convergence warnings on 12 rows are expected
        model = make_model(name, random_state=0)
        if name == "lm_network":
            model.set_params(n_restarts=2)
        result = evaluate_model(name, model, X, y, groups, "grouped")
    assert np.isfinite(result.y_pred_mm).all()
    assert result.errors.n == len(y)
    assert np.isfinite(result.errors.mean_error_mm)


def test_too_few_training_rows_is_refused_clearly():
    X, y = np.random.rand(4, 28), np.random.rand(4, 2)
    with pytest.raises(DataError, match="training presses"):
        evaluate_model("knn", make_model("knn"), X, y, np.array([0, 0, 1, 1]), "grouped")


def test_make_models_names_and_unknown_model():
    assert tuple(make_models()) == MODEL_NAMES
    with pytest.raises(DataError, match="unknown model"):
        make_models(["ridge", "svm"])


# ---------------------------------------------------------------- the report


def test_report_writes_table_files_and_plots(tmp_path):
    folder = write_dataset(tmp_path / "ds", small_table(10, 4), layout=True, crb_mm=0.5)
    with pytest.warns(UserWarning):
        report = run_baselines(folder, split="both", models=["ridge", "knn", "lm_network"], progress=False, n_repeats=3)
    table = report.table
    assert table[["model", "split"]].values.tolist() == [
        ["ridge", "grouped"],
        ["knn", "grouped"],
        ["lm_network", "grouped"],
        ["ridge", "random"],
        ["knn", "random"],
        ["lm_network", "random"],
    ]
    assert (table["n_repeats"] == 3).all()
    assert (table.loc[table.split == "grouped", "n_test"] == 8).all()  # one fold of 5 over 10 positions x 4
    assert (table.loc[table.split == "random", "n_test"] == 1).all()  # 2 % of 40 rounds to 1
    np.testing.assert_allclose(table["mse_per_coordinate_mm2"], table["mse_mm2"] / 2)
    np.testing.assert_allclose(table["rms_over_crb"], table["rms_error_mm"] / 0.5)
    assert (table["mean_error_mm_lo"] <= table["mean_error_mm"]).all()
    assert (table["mean_error_mm"] <= table["mean_error_mm_hi"]).all()
    assert (table["within_probe_pct_lo"] >= 0).all() and (table["within_probe_pct_hi"] <= 100).all()
    assert report.bound_rms_mm == pytest.approx(0.5)
    assert report.bound_nuisance_rms_mm is None and "rms_over_crb_nuisance" not in table.columns  # an older file
    assert (table["fit_time_s"] > 0).all() and (table["predict_time_per_sample_us"] > 0).all()
    back = pq.read_table(folder / "baselines.parquet").to_pandas()
    pd.testing.assert_frame_equal(back, table)
    assert pd.read_csv(folder / "baselines.csv")["model"].tolist() == table["model"].tolist()
    for name in ("baselines_error_vs_time.png", "baselines_ellipses_grouped.png"):
        assert (folder / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert not (folder / "baselines_ellipses_random.png").exists()  # one prediction per position: degenerate
    text = (folder / "report.md").read_text()
    assert "2.03 ± 0.26" in text and "| 81.8 (54 of 66) |" in text and "3.32" in text
    # not the paper's protocol: said so, and no claim of a fitted scene
    assert "not the paper's 100 x 28" in text and "was fitted to the paper's figures" not in text
    assert "95 % train / 3 % validation / 2 % test" in text and "Cramér-Rao" in text
    # 4 presses per position cannot give the 11 x 6 design; 1 test press per random repeat is too few
    assert any("design split skipped" in w for w in report.warnings)
    assert any("only 1 test presses per repeat" in w for w in report.warnings)
    assert text.index("## Warnings") < text.index("## The paper beside")


def test_the_report_shows_both_bounds_and_flags_memorisation_by_the_electronics_one(tmp_path):
    folder = write_dataset(tmp_path / "ds", small_table(10, 4), layout=True, crb_mm=0.5, crb_nuisance_mm=3.0)
    with pytest.warns(UserWarning):
        report = run_baselines(folder, split="both", models=["ridge", "knn"], progress=False, n_repeats=2)
    table = report.table
    assert report.bound_rms_mm == pytest.approx(0.5) and report.bound_nuisance_rms_mm == pytest.approx(3.0)
    np.testing.assert_allclose(table["rms_over_crb_nuisance"], table["rms_error_mm"] / 3.0)
    np.testing.assert_allclose(table["crb_nuisance_rms_mm"], 3.0)
    # the flag keeps the electronics-only bound: a result between the two bounds is not memorisation
    expected = (table["rms_error_mm"] < 0.5) | (table["median_error_mm"] < 0.25)
    assert table["below_bound"].tolist() == expected.tolist()
    text = (folder / "report.md").read_text()
    assert "## Physical limit (`physical_limit.parquet`)" in text
    assert (
        "| electronics only (`crb_mm`): depth, fluid drift and landing point known | 0.500 |" in text
    )  # 3 significant figures
    assert "as nuisances (`crb_nuisance_mm`; priors in the file's metadata) | 3.00 |" in text
    assert "cannot beat it on average for presses at new positions" in text
    ratio = table["rms_over_crb_nuisance"].min()
    assert f"at {sig3(ratio)} times the bound with nuisances" in text  # 3 significant figures, as every cell
    summary = report_summary(report)
    assert "electronics only: 0.500 mm" in summary and "nuisances: 3.00 mm" in summary  # report.md's sig3
    assert "RMS/CRB " in summary and "RMS/CRBn" in summary
    assert report.files["bound map"] == folder / "baselines_bound_map.png"
    assert (folder / "baselines_bound_map.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert "`baselines_bound_map.png`" in text


def test_report_is_deterministic_for_a_seed(tmp_path):
    folder = write_dataset(tmp_path / "ds", small_table(8, 3))
    a = run_baselines(folder, models=["lm_network", "extra_trees"], out=tmp_path / "a", progress=False)
    b = run_baselines(folder, models=["lm_network", "extra_trees"], out=tmp_path / "b", progress=False)
    cols = ["mean_error_mm", "mse_mm2", "within_probe_pct"]
    pd.testing.assert_frame_equal(a.table[cols], b.table[cols])


def test_cli_baselines_prints_the_table_and_writes_into_out(tmp_path, capsys):
    folder = write_dataset(tmp_path / "ds", small_table(8, 3))
    rc = main(
        [
            "baselines",
            str(folder),
            "--models",
            "ridge,knn",
            "--split",
            "random",
            "--out",
            str(tmp_path / "o"),
            "--no-progress",
        ]
    )
    assert rc == 0
    out = capsys.readouterr().out
    assert "ridge" in out and "knn" in out and "random" in out
    assert (tmp_path / "o" / "report.md").is_file()
    assert not (folder / "report.md").exists()


def test_cli_errors_are_one_line_and_exit_with_the_data_code(tmp_path, capsys):
    df = small_table(8, 3)
    df.loc[0, "x_mm"] = np.nan
    folder = write_dataset(tmp_path / "ds", df)
    assert main(["baselines", str(folder), "--models", "ridge", "--no-progress"]) == 5
    err = capsys.readouterr().err
    assert "[x_mm]" in err and str(folder) in err
    assert main(["baselines", str(folder), "--models", "ridge,svm"]) == 5


@pytest.fixture(scope="module")
def smoke_dry_run(tmp_path_factory):
    folder = tmp_path_factory.mktemp("smoke") / "run"
    rc = main(
        [
            "campaign",
            "run",
            str(REPO / "protocols" / "smoke.toml"),
            "--dry-run",
            "--out",
            str(folder),
            "--quiet",
            "--no-report",
        ]
    )
    assert rc == 0
    return folder


def test_on_a_dry_run_dataset_the_grouped_folds_keep_positions_apart(smoke_dry_run):
    from neatskin.baselines.splits import grouped_folds

    data = load_baseline_data(smoke_dry_run)
    assert data.X.shape == (12, 28) and data.layout is not None and data.physical_limit is not None
    for train, test in grouped_folds(data.groups):
        assert not set(data.groups[train]) & set(data.groups[test])
    report = run_baselines(smoke_dry_run, models=["ridge", "lm_network"], progress=False)
    assert report.bound_rms_mm is not None and np.isfinite(report.table["mean_error_mm"]).all()
    # the smoke protocol's ideal scene has no nuisance: both bounds are the same
    assert report.bound_nuisance_rms_mm == report.bound_rms_mm
    assert (smoke_dry_run / "baselines_bound_map.png").is_file()


def test_an_infinite_nuisance_bound_notes_no_model_and_says_why(tmp_path):
    """On the FE skin the bound is infinite at positions on a channel the probe shuts, so the pooled bound is
    infinite: rms / inf = 0 had noted every model "below the nuisance bound (0×)". No ratio, no note, a reason."""
    folder = write_dataset(tmp_path / "ds", small_table(10, 4), layout=True, crb_mm=0.5, crb_nuisance_mm=np.inf)
    with pytest.warns(UserWarning):
        report = run_baselines(folder, split="both", models=["ridge", "knn"], progress=False, n_repeats=2)
    assert report.bound_nuisance_rms_mm == np.inf
    assert report.table["rms_over_crb_nuisance"].isna().all()
    text = (folder / "report.md").read_text()
    assert "below the nuisance bound (" not in text and "Closest to it" not in text  # no row noted
    assert "Here the bound with nuisances exceeds the skin (30 mm) at some positions" in text


def test_an_infinite_bound_is_summarised_by_its_median_and_compared_with_nothing(tmp_path):
    """Positions whose bound is infinite (a channel shut under the probe) make the pooled bound infinite: no ratio
    (rms / inf = 0 read as "0x the bound"), no flag; the report and the terminal give each bound's median over
    positions and how many exceed the probe radius."""
    crb = np.array([0.3, 0.4, np.inf, 9.0, 0.3, np.inf, 0.2, 0.4, 0.1, np.inf])  # sorted, the 5th and 6th: 0.4
    folder = write_dataset(tmp_path / "ds", small_table(10, 4), layout=True, crb_mm=crb, crb_nuisance_mm=crb * 2)
    with pytest.warns(UserWarning):
        report = run_baselines(folder, split="both", models=["ridge", "knn"], progress=False, n_repeats=2)
    assert report.bound_rms_mm == np.inf and report.table["rms_over_crb"].isna().all()
    assert not report.table["below_bound"].any()
    assert report.spreads == ((0.4, 4, 10), (0.8, 4, 10))  # above 2.75 mm: 9 and inf x 3; 18 and inf x 3
    text = (folder / "report.md").read_text()
    assert "| the same, median over the 10 positions (above the probe radius at 4 of them) | 0.400 |" in text
    assert "| the same, median over the 10 positions (above the probe radius at 4 of them) | 0.800 |" in text
    assert "Here the electronics-only bound exceeds the skin (30 mm) at some positions" in text
    # the same reason is not given twice: the nuisance bound's paragraph points to it
    assert "Here the bound with nuisances exceeds the skin at some positions too, for the same reason" in text
    assert "Here the bound with nuisances exceeds the skin (30 mm)" not in text
    # the full table has no all-NaN ratio column, and one line says why nothing is compared with either bound
    full = text.split("## All figures")[1]
    assert "RMS / bound" not in full and "RMS / nuisance bound" not in full and "| nan |" not in full
    assert (
        "No result is compared with the electronics-only bound (no column for it): it is infinite at 3 of 10 "
        "positions (unresolvable: a channel the probe shuts), so its pooled value says nothing."
    ) in full
    assert "No result is compared with the bound with nuisances (no column for it): it is infinite at 3 of 10" in full
    assert "each bound it is compared with" in text
    summary = report_summary(report)
    # the figures as report.md writes them (sig3); an infinite pooled bound is not printed as a figure ("inf mm"),
    # its median is, with why nothing is compared with it; no all-NaN ratio columns
    assert (
        "Cramér-Rao bound, electronics only: median 0.400 mm over 10 positions, above the probe radius at 4; "
        "beyond the skin at some positions (a channel shut under the probe), so no result is compared with it"
    ) in summary
    assert "as nuisances: median 0.800 mm over 10 positions" in summary
    assert "inf mm" not in summary and "RMS/CRB" not in summary and " nan" not in summary
    # every position within the probe radius: no such row
    finite = write_dataset(tmp_path / "f", small_table(10, 4), layout=True, crb_mm=0.5)
    with pytest.warns(UserWarning):
        plain = run_baselines(finite, split="both", models=["ridge"], progress=False, n_repeats=2)
    assert "median over the" not in plain.text and "(median" not in report_summary(plain)


def test_a_huge_finite_bound_is_no_more_compared_than_an_infinite_one(tmp_path):
    """One position whose nuisance bound is 1.1e6 mm (just off a shut channel) holds the pooled RMS (3.5e5 mm)
    without making it infinite: rms / 3.5e5 had noted every model "below the nuisance bound (0.000141x)". A bound
    that exceeds the skin (30 mm) anywhere is compared with nothing (no estimator answering on the skin is unbiased
    there); one within it everywhere still is."""
    nuisance = np.r_[1.1e6, np.full(9, 1.0)]
    folder = write_dataset(tmp_path / "ds", small_table(10, 4), layout=True, crb_mm=0.5, crb_nuisance_mm=nuisance)
    with pytest.warns(UserWarning):
        report = run_baselines(folder, split="both", models=["ridge", "knn"], progress=False, n_repeats=2)
    assert report.bound_nuisance_rms_mm == pytest.approx(np.sqrt((1.1e6**2 + 9) / 10))
    assert report.table["rms_over_crb_nuisance"].isna().all()
    np.testing.assert_allclose(report.table["rms_over_crb"], report.table["rms_error_mm"] / 0.5)  # compared
    text = (folder / "report.md").read_text()
    assert "below the nuisance bound (" not in text and "Closest to it" not in text
    assert "| the same, median over the 10 positions (above the probe radius at 1 of them) | 1.00 |" in text
    assert "Here the bound with nuisances exceeds the skin (30 mm) at some positions" in text
    assert "Here the electronics-only bound" not in text
    assert "| 348,000 |" in text  # sig3, not 3.48e+05
    full = text.split("## All figures")[1]  # the electronics-only ratio is there, the all-NaN one is not
    assert "`RMS / bound` = RMS error over the pooled electronics-only bound." in full
    assert "| RMS / bound |" in full and "RMS / nuisance bound" not in full and "| nan |" not in full
    assert "with nuisances (no column for it): it is beyond the skin (30 mm) at 1 of 10, so its pooled" in full
    summary = report_summary(report)  # the huge pooled bound is not compared: the terminal gives its median
    assert "as nuisances: median 1.00 mm over 10 positions, above the probe radius at 1; beyond the skin" in summary
    assert "electronics only: 0.500 mm" in summary and summary.splitlines()[0].split()[-1] == "RMS/CRB"  # no CRBn
    # a bound past the probe radius but within the skin at every position (3 mm here) is still compared
    wide = write_dataset(tmp_path / "w", small_table(10, 4), layout=True, crb_mm=0.5, crb_nuisance_mm=3.0)
    with pytest.warns(UserWarning):
        within = run_baselines(wide, split="both", models=["ridge"], progress=False, n_repeats=2)
    np.testing.assert_allclose(within.table["rms_over_crb_nuisance"], within.table["rms_error_mm"] / 3.0)


def test_a_nan_in_the_physical_limit_is_one_data_error_naming_the_column(tmp_path):
    """A bound is a number or +inf (unobservable), never NaN: a NaN (a hand-edited or merged file) would pool to
    NaN and print "median nan mm"; it is refused on load, naming the file, the column, the positions and the fix."""
    crb = np.r_[0.3, np.nan, np.full(8, 0.4)]
    folder = write_dataset(tmp_path / "ds", small_table(10, 4), layout=True, crb_mm=crb)
    with pytest.raises(DataError) as info:
        load_baseline_data(folder)
    err = info.value
    assert err.field == "crb_mm" and err.file.endswith("physical_limit.parquet")
    assert "1 NaN values (position_id [1])" in str(err) and "neatskin campaign finish" in err.problems[0].fix


def test_the_inversion_model_is_chosen_by_name_and_a_missing_kernel_is_refused_before_any_fit(
    smoke_dry_run, tmp_path, monkeypatch, capsys
):
    """--inversion-model fe-kernel inverts with the packaged FE pinch kernel's forward model (other positions than
    the parametric pinch's, and a note says which); an unknown name, or a layout and probe with no kernel packaged
    or cached, is one ConfigError naming the option and the fix, before any fit."""
    parametric = run_baselines(smoke_dry_run, models=["inversion"], out=tmp_path / "p", progress=False)
    fe = run_baselines(
        smoke_dry_run, models=["inversion"], out=tmp_path / "fe", progress=False, inversion_model="fe-kernel"
    )
    assert "(--inversion-model fe-kernel)" in fe.text and "fe-kernel" not in parametric.text
    p_err = parametric.table["mean_error_mm"].to_numpy()
    fe_err = fe.table["mean_error_mm"].to_numpy()
    assert np.isfinite(fe_err).all() and not np.allclose(p_err, fe_err)
    with pytest.raises(ConfigError, match="unknown") as unknown:
        run_baselines(smoke_dry_run, models=["inversion"], out=tmp_path / "x", progress=False, inversion_model="fe")
    assert unknown.value.problems[0].field == "--inversion-model"

    import neatskin.skin.kernel as kernel

    monkeypatch.setattr(kernel, "packaged_kernel_path", lambda: tmp_path / "none.parquet")
    monkeypatch.setattr(kernel, "cache_dir", lambda: tmp_path / "empty-cache")
    fits = []
    monkeypatch.setattr("neatskin.baselines.report.run_tasks", lambda *a, **k: fits.append(a))
    rc = main(
        [
            "baselines",
            str(smoke_dry_run),
            "--models",
            "inversion",
            "--inversion-model",
            "fe-kernel",
            "--out",
            str(tmp_path / "cli"),
            "--quiet",
        ]
    )
    err = capsys.readouterr().err
    assert rc == 3 and fits == [] and "--inversion-model" in err and "neatskin skin mechanics" in err
    assert len([line for line in err.splitlines() if line.strip()]) <= 2


def test_an_output_folder_the_report_cannot_write_is_refused_before_any_fit(tmp_path, capsys, monkeypatch):
    """A report into a folder it cannot write (here under a file: no folder can be made there; a read-only dataset
    folder is the common case) ran every fit, then failed on baselines.csv with a traceback (hostile-input audit)."""
    folder = write_dataset(tmp_path / "ds", small_table(10, 4))
    blocker = tmp_path / "a-file"
    blocker.write_text("")

    def no_fits(*args, **kwargs):
        raise AssertionError("the fits ran before the output folder was checked")

    monkeypatch.setattr("neatskin.baselines.report.run_tasks", no_fits)
    out = blocker / "report"
    assert main(["baselines", str(folder), "-o", str(out), "--models", "ridge", "--no-progress"]) == 5
    err = capsys.readouterr().err
    assert f"neatskin: error: {out}: [--out]: cannot write the report there: Not a directory" in err
    assert "fix: give a folder you can write with -o/--out" in err and "Traceback" not in err


def test_an_os_error_no_check_named_is_one_error_with_the_path_and_a_fix(capsys, monkeypatch):
    """The CLI's last line of defence: an OSError from a path no command-level check named is one DataError line
    (exit 5) naming the path, the system's reason and a fix for that reason, not a traceback."""
    import argparse
    import errno

    import neatskin.cli as cli

    name = "x" * 300

    def handler(args):
        raise OSError(errno.ENAMETOOLONG, "File name too long", name)

    parser = argparse.ArgumentParser()
    parser.set_defaults(handler=handler)
    monkeypatch.setattr(cli, "build_parser", lambda: parser)
    assert cli.main([]) == 5
    assert capsys.readouterr().err == (
        f"neatskin: error: {name}: cannot use the path: File name too long (fix: give a shorter path)\n"
    )
