"""`dataset merge` of campaigns recorded on different rigs: a dry run (simulated printer and DAQ) and a real-printer
run with a simulated DAQ (the simulated printer's pty behind `--port`, as a real printer's serial line). Refused with
one error naming both runs and the fix, before anything is written; merged with --allow-mixed-rigs, the manifest
records each source's rig and the card names each source's share; two dry runs merge as before, their one rig kept."""

from __future__ import annotations

import json
from pathlib import Path

import pyarrow.parquet as pq
import pytest
from test_hil import dry_run, small_protocol

from neatskin.cli import main
from neatskin.datasets.hfexport import read_card_front_matter
from neatskin.gcode.profile import load_printer_profile
from neatskin.sim.printer import SimulatedPrinter

PROTOCOLS = Path(__file__).resolve().parent.parent / "protocols"


@pytest.fixture(scope="module")
def runs(tmp_path_factory) -> dict[str, Path]:
    """Three small campaigns made by the CLI: two dry runs (3 and 2 presses) and a real-printer run (2 presses)
    against the simulated printer on a pty with --daq simulated."""
    tmp = tmp_path_factory.mktemp("rigs")
    out = {}
    for name, count in (("dry-a", 3), ("dry-b", 2)):
        (tmp / name).mkdir()
        dry_run(small_protocol(tmp / name, count=count, repeats=1), tmp / name / name)
        out[name] = tmp / name / name
    (tmp / "hil").mkdir()
    protocol = small_protocol(tmp / "hil", count=2, repeats=1)
    printer = SimulatedPrinter(load_printer_profile(PROTOCOLS / "printers" / "paper.toml"), advanced_ok=True)
    port = printer.start_pty()
    try:
        argv = [
            "campaign",
            "run",
            str(protocol),
            "--port",
            port,
            "--daq",
            "simulated",
            "--out",
            str(tmp / "hil" / "real"),
        ]
        assert main([*argv, "--no-report", "-q", "--connect-timeout-s", "2"]) == 0
    finally:
        printer.stop()
    out["real"] = tmp / "hil" / "real"
    return out


def _manifest(folder: Path) -> dict:
    return json.loads((folder / "manifest.json").read_text())


def test_a_dry_run_and_a_real_printer_run_are_refused_naming_both_and_the_flag(runs, tmp_path, capsys):
    out = tmp_path / "merged"
    code = main(["dataset", "merge", str(runs["dry-a"]), str(runs["real"]), "-o", str(out)])
    err = capsys.readouterr().err
    assert code == 5  # a DataError, no traceback
    assert "Traceback" not in err
    assert "different rigs" in err and "--allow-mixed-rigs" in err
    assert "dry-a (" in err and "real (" in err  # each run named, with its folder
    assert str(runs["dry-a"].resolve()) in err and str(runs["real"].resolve()) in err
    assert ": dry run" in err and ": real printer with a simulated DAQ" in err
    assert not out.exists()  # refused before anything is written
    # --allow-mixed (layouts, wirings) does not allow rigs to mix
    assert main(["dataset", "merge", str(runs["dry-a"]), str(runs["real"]), "-o", str(out), "--allow-mixed"]) == 5
    assert not out.exists()


def test_allowed_the_merge_records_each_sources_rig_and_the_card_each_share(runs, tmp_path, capsys):
    out = tmp_path / "merged"
    argv = ["dataset", "merge", str(runs["dry-a"]), str(runs["real"]), "-o", str(out), "--allow-mixed-rigs"]
    assert main(argv) == 0
    manifest = _manifest(out)
    assert manifest["allow_mixed_rigs"] is True
    assert manifest["rig"]["kind"] == "mixed"
    shares = [(e["presses"], e["printer"], e["daq"], e["description"]) for e in manifest["source_rigs"]]
    assert shares == [
        (3, "simulated", "simulated", "dry run"),
        (2, "real", "simulated", "real printer with a simulated DAQ"),
    ]
    assert manifest["source_rigs"][0]["rig"] == _manifest(runs["dry-a"])["rig"]
    assert manifest["source_rigs"][1]["rig"] == _manifest(runs["real"])["rig"]
    metadata = pq.read_schema(out / "presses.parquet").metadata
    assert json.loads(metadata[b"neatskin.rig"]) == "mixed"
    # the card: each source's share, and each source's own scene (not the first run's for all)
    hf = tmp_path / "hf"
    assert main(["dataset", "export", str(out), "--format", "hf", "-o", str(hf)]) == 0
    card = (hf / "README.md").read_text()
    read_card_front_matter(card)
    scene = card.split("## Scene", 1)[1].split("## Splits", 1)[0]
    assert "3 presses dry run, 2 presses real printer with a simulated DAQ" in scene
    assert "--allow-mixed-rigs" in scene
    assert "- run `dry-a` (3 presses): **Simulated (a dry run):**" in scene
    assert "- run `real` (2 presses): **A real printer with a simulated skin and DAQ**" in scene


def test_two_dry_runs_merge_with_their_one_rig_in_manifest_and_metadata(runs, tmp_path):
    out = tmp_path / "merged"
    assert main(["dataset", "merge", str(runs["dry-a"]), str(runs["dry-b"]), "-o", str(out)]) == 0
    manifest = _manifest(out)
    assert manifest["rig"] == _manifest(runs["dry-a"])["rig"]
    assert [e["description"] for e in manifest["source_rigs"]] == ["dry run", "dry run"]
    metadata = pq.read_schema(out / "presses.parquet").metadata
    assert json.loads(metadata[b"neatskin.rig"]) == "dry-run"
    assert b"neatskin.daq" not in metadata
    hf = tmp_path / "hf"
    assert main(["dataset", "export", str(out), "--format", "hf", "-o", str(hf)]) == 0
    scene = (hf / "README.md").read_text().split("## Scene", 1)[1].split("## Splits", 1)[0]
    assert "A merge of one rig's runs: 3 presses dry run, 2 presses dry run." in scene


def test_a_merge_of_a_mixed_merge_keeps_every_runs_rig_and_refuses_without_the_flag(runs, tmp_path, capsys):
    mixed = tmp_path / "mixed"
    assert (
        main(["dataset", "merge", str(runs["real"]), str(runs["dry-a"]), "-o", str(mixed), "--allow-mixed-rigs"]) == 0
    )
    # a mixed merge beside a real-printer run: still two rigs, refused without the flag
    again = tmp_path / "again"
    assert main(["dataset", "merge", str(mixed), str(runs["dry-b"]), "-o", str(again)]) == 5
    capsys.readouterr()
    assert main(["dataset", "merge", str(mixed), str(runs["dry-b"]), "-o", str(again), "--allow-mixed-rigs"]) == 0
    out = capsys.readouterr().out
    assert f"{mixed.resolve()} (complete; real printer with a simulated DAQ + dry run): 5 presses" in out
    assert f"{runs['dry-b'].resolve()} (complete; dry run): 2 presses" in out
    entries = _manifest(again)["source_rigs"]
    assert [(e["presses"], e["description"]) for e in entries] == [
        (2, "real printer with a simulated DAQ"),
        (3, "dry run"),
        (2, "dry run"),
    ]
    assert [e["source"] for e in entries] == [str(mixed.resolve())] * 2 + [str(runs["dry-b"].resolve())]
    assert [e["folder"] for e in entries] == [str(runs[k].resolve()) for k in ("real", "dry-a", "dry-b")]


def test_lone_presses_files_are_told_apart_by_their_metadata(runs, tmp_path):
    # no manifest beside a copied presses file: the rig comes from its neatskin.rig / neatskin.daq metadata
    for name in ("dry-a", "real"):
        (tmp_path / name).mkdir()
        (tmp_path / name / f"{name}.parquet").write_bytes((runs[name] / "presses.parquet").read_bytes())
    files = [str(tmp_path / n / f"{n}.parquet") for n in ("dry-a", "real")]
    assert main(["dataset", "merge", *files, "-o", str(tmp_path / "refused")]) == 5
    assert main(["dataset", "merge", *files, "-o", str(tmp_path / "m"), "--allow-mixed-rigs"]) == 0
    entries = _manifest(tmp_path / "m")["source_rigs"]
    assert [(e["run"], e["description"]) for e in entries] == [
        ("dry-a", "dry run"),
        ("real", "real printer with a simulated DAQ"),
    ]


def test_the_rig_in_words_from_what_the_runner_writes():
    from neatskin.datasets.rigkind import RigKind, rig_kind

    assert rig_kind({"rig": {"kind": "dry-run", "daq": "simulated"}}, {}) == RigKind("simulated", "simulated")
    assert rig_kind({"rig": {"kind": "real", "daq": "simulated"}}, {}).describe() == "real printer with a simulated DAQ"
    assert rig_kind({"rig": {"kind": "real", "daq": "ni"}}, {}).describe() == "real printer and DAQ"
    # the presses' metadata: the runner writes neatskin.daq only for a simulated DAQ
    assert rig_kind({}, {"rig": "real"}).describe() == "real printer and DAQ"
    assert rig_kind({}, {"rig": "real", "daq": "simulated"}) == RigKind("real", "simulated")
    assert rig_kind({}, {}).describe() == "rig not recorded" and not rig_kind({}, {}).known
    with pytest.raises(ValueError):
        RigKind("virtual", None)
