"""`skin fit` reads the campaign's manifest once: the handler reads it for its model-mismatch warning and hands it to
the fit, which does not read it again; with no readable manifest the fit reads it itself and names the problem."""

import pytest
from test_skin_fit_mismatch import _dry_run

import neatskin.campaignread
import neatskin.skin.fit


@pytest.fixture()
def counted_reads(monkeypatch):
    """Every read_manifest call of the handler (it imports it from campaignread) and of the fit, by folder."""
    reads = []
    original = neatskin.campaignread.read_manifest

    def counting(folder):
        reads.append(str(folder))
        return original(folder)

    monkeypatch.setattr(neatskin.campaignread, "read_manifest", counting)
    monkeypatch.setattr(neatskin.skin.fit, "read_manifest", counting)
    return reads


def test_the_fit_reads_the_manifest_once_and_uses_that_one(tmp_path, capsys, counted_reads):
    from neatskin.cli import main

    folder = _dry_run(tmp_path, 'preset = "paper-like"\ndeformation = "parametric"')
    profile = tmp_path / "fitted.toml"
    assert main(["skin", "fit", str(folder), "--out", str(profile)]) == 0
    assert counted_reads == [str(folder)]  # before: the handler's read, then load_campaign's
    assert "skin fitted to" in capsys.readouterr().out and profile.is_file()


def test_without_a_readable_manifest_the_fit_names_it(tmp_path, capsys, counted_reads):
    from neatskin.cli import main

    folder = _dry_run(tmp_path, 'preset = "ideal"')
    (folder / "manifest.json").write_text("{ not json")
    assert main(["skin", "fit", str(folder), "--out", str(tmp_path / "fitted.toml")]) == 5
    err = capsys.readouterr().err
    assert "manifest.json" in err and "Traceback" not in err
    assert counted_reads == [str(folder), str(folder)]  # the handler's failed read, then the fit's, which names it
