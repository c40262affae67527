"""`dataset export --format hf`: the Hub's layout (parquet per split, a card with license, configs and features),
the protocol, skin, scene and citation in the card's text, and nothing that names the recording machine."""

from __future__ import annotations

import os
import socket
from pathlib import Path

import pandas as pd
import pyarrow.parquet as pq
import pytest
from test_datasets_curate import campaign

from neatskin.cli import main
from neatskin.datasets.curate import export, merge
from neatskin.datasets.hfexport import read_card_front_matter, to_yaml
from neatskin.datasets.manifest import update_manifest
from neatskin.datasets.privacy import scrub, scrub_text

yaml = pytest.importorskip("yaml")  # PyYAML reads the card back as the Hub would; the export does not need it

FAKE_HOST = "lab-pc-7.example.org"


def _recorded(tmp_path: Path, paper_layout, name: str = "run-a", seed: int = 1) -> Path:
    folder = tmp_path / name
    campaign(folder, paper_layout, 10, 3, seed=seed, name="paper")
    # as a real run writes it: the host, and absolute paths of the files it read
    update_manifest(
        folder,
        fsync=False,
        host=FAKE_HOST,
        protocol={"path": "inputs/protocol.toml", "source": str(tmp_path.resolve() / "mine" / "paper.toml")},
        rig={"kind": "dry-run", "printer": "simulated Marlin on /dev/pts/3", "skin": {"preset": "paper-like"}},
    )
    return folder


def _roots() -> list[str]:
    """'/' + every top-level folder of this machine: an absolute local path starts with one of them."""
    return [f"/{name}" for name in os.listdir("/") if len(name) >= 3]


def _metadata_bytes(path: Path) -> bytes:
    """Every byte of a parquet file's metadata: its key-value pairs (arrow's schema copy included)."""
    meta = pq.ParquetFile(path).metadata.metadata or {}
    return b"\n".join(k + b"=" + v for k, v in meta.items())


def _leaks(blob: bytes) -> list[str]:
    text = blob.decode("utf-8", errors="replace")
    found = [h for h in (FAKE_HOST, "lab-pc-7", socket.gethostname()) if len(h) >= 3 and h in text]
    return found + [r for r in _roots() if r + "/" in text or text.endswith(r) or f'{r}"' in text]


def test_hf_export_writes_the_hub_layout_and_a_card_that_parses(paper_layout, tmp_path):
    folder = _recorded(tmp_path, paper_layout)
    assert main(["dataset", "export", str(folder), "--format", "hf", "--out", str(tmp_path / "hf")]) == 0
    out = tmp_path / "hf"
    card = (out / "README.md").read_text()
    assert card.startswith("---\nlicense: cc-by-4.0\n")
    front = yaml.safe_load(read_card_front_matter(card))
    assert front["license"] == "cc-by-4.0"
    (presses,) = [c for c in front["configs"] if c["config_name"] == "presses"]
    files = {d["split"]: sorted(out.glob(d["path"])) for d in presses["data_files"]}
    assert set(files) == {"train", "test"} and all(len(f) == 1 for f in files.values())
    train, test = (pd.read_parquet(files[s][0]) for s in ("train", "test"))
    assert len(train) + len(test) == 30
    assert not set(train["position_id"]) & set(test["position_id"])  # split by position
    (info,) = [i for i in front["dataset_info"] if i["config_name"] == "presses"]
    assert [f["name"] for f in info["features"]] == list(train.columns)
    feature = {f["name"]: f for f in info["features"]}
    assert feature["flags"] == {"name": "flags", "sequence": "string"}
    assert feature["x_mm"]["dtype"] == "float64" and feature["press_id"]["dtype"] == "int64"
    assert {s["name"]: s["num_examples"] for s in info["splits"]} == {"train": len(train), "test": len(test)}
    for heading in ("## Protocol", "## Skin", "## Scene", "## Citation"):
        assert heading in card
    assert "NeatSkin: A Discrete Impedance Tomography Skin Sensor" in card and "Judd, Euan" in card
    assert "neatskin-paper" in card and "Simulated (a dry run)" in card and "paper-like" in card
    assert 'df["flags"]' in card


def test_nothing_in_the_export_names_the_recording_machine(paper_layout, tmp_path):
    a = _recorded(tmp_path, paper_layout, "run-a", 1)
    b = _recorded(tmp_path, paper_layout, "run-b", 2)
    merged = merge([a, b], tmp_path / "merged")  # merged_from holds absolute folders and both manifests
    assert FAKE_HOST in (merged / "presses.parquet").read_bytes().decode("latin-1")  # the local copy keeps them
    assert main(["dataset", "export", str(merged), "--format", "hf", "--out", str(tmp_path / "hf")]) == 0
    files = [p for p in (tmp_path / "hf").rglob("*") if p.is_file()]
    assert any(p.suffix == ".parquet" for p in files) and any(p.name == "neatskin_manifest.json" for p in files)
    for path in files:
        blob = _metadata_bytes(path) if path.suffix == ".parquet" else path.read_bytes()
        assert _leaks(blob) == [], path
    df = pd.read_parquet(tmp_path / "hf" / "data")
    assert sorted(df["source_run"].unique()) == ["run-a", "run-b"]


def test_plain_exports_strip_host_and_paths_too(paper_layout, tmp_path):
    folder = _recorded(tmp_path, paper_layout)
    parquet = export(folder, tmp_path / "x.parquet")
    assert _leaks(_metadata_bytes(parquet)) == []
    csv = export(folder, tmp_path / "x.csv", "csv")
    assert _leaks(Path(str(csv) + ".metadata.json").read_bytes()) == []


def test_scrub_drops_local_keys_and_rewrites_paths_and_hosts_in_any_string():
    value = {
        "host": "h1",
        "layout": {"path": "inputs/layout.toml", "source": "/home/ann/skins/paper.toml"},
        "note": "ran on h1 from /home/ann/x.toml; split 3/98; see https://example.org/a/b",
        "list": ["C:\\Users\\ann\\p.toml", "relative/p.toml"],
    }
    assert scrub(value, {"h1"}) == {
        "layout": {"path": "inputs/layout.toml"},
        "note": "ran on <host> from <local path>; split 3/98; see https://example.org/a/b",
        "list": ["<local path>", "relative/p.toml"],
    }
    assert scrub_text("h1x and h1", {"h1"}) == "h1x and <host>"  # whole names only


def test_to_yaml_round_trips_through_a_yaml_parser():
    value = {
        "license": "cc-by-4.0",
        "configs": [{"config_name": "presses", "default": True, "data_files": [{"split": "train", "path": "d/*.pq"}]}],
        "odd": ["yes", "a: b", "timestamp[us, tz=UTC]", 1.5, 3, "#x", ""],
        "empty": [],
    }
    assert yaml.safe_load(to_yaml(value)) == value


def test_an_existing_output_is_refused(paper_layout, tmp_path):
    folder = _recorded(tmp_path, paper_layout)
    (tmp_path / "hf").mkdir()
    (tmp_path / "hf" / "x").write_text("keep")
    assert (
        main(["dataset", "export", str(folder), "--format", "hf", "--out", str(tmp_path / "hf")]) == 5
    )  # a data error (neatskin.errors.ExitCode)
    assert (tmp_path / "hf" / "x").read_text() == "keep"  # nothing overwritten


def test_the_leak_scan_finds_what_a_campaign_folder_keeps(paper_layout, tmp_path):
    """Negative control: the same scan on the recorded folder (not an export) finds the host and the paths."""
    folder = _recorded(tmp_path, paper_layout)
    leaks = _leaks((folder / "manifest.json").read_bytes()) + _leaks(_metadata_bytes(folder / "presses.parquet"))
    assert FAKE_HOST in leaks and any(root in leaks for root in _roots())


def test_the_card_of_a_merged_dataset_gives_the_runs_protocol_and_scene(paper_layout, tmp_path):
    folders = []
    for name, seed in (("run-a", 1), ("run-b", 2)):
        folder = _recorded(tmp_path, paper_layout, name, seed)
        update_manifest(
            folder,
            fsync=False,
            protocol_as_run={"campaign": {"name": "paper", "seed": seed}, "press": {"repeats": 3, "depth_mm": 3.5}},
        )
        folders.append(folder)
    merged = merge(folders, tmp_path / "merged")
    assert main(["dataset", "export", str(merged), "--format", "hf", "--out", str(tmp_path / "hf")]) == 0
    card = (tmp_path / "hf" / "README.md").read_text()
    assert "A merge of 2 runs" in card and "campaign `paper`, seed 1" in card and "Simulated (a dry run)" in card
