"""`campaign resume` and `campaign finish` on a folder `dataset merge` wrote: one error saying it is a merged dataset,
not a campaign, with the fix (resume each source, merge again), exit 5, and the folder left as it was (no lock file,
the presses file's bytes unchanged). Before, resume failed on the merge's extra source column, telling the user to
resume "with the layout the campaign started with"."""

from __future__ import annotations

import hashlib
from pathlib import Path

from test_hil import dry_run, small_protocol

from neatskin.cli import main


def _files(folder: Path) -> dict[str, str]:
    return {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(folder.iterdir()) if p.is_file()}


def test_resume_and_finish_of_a_merged_dataset_refuse_naming_it_and_change_nothing(tmp_path, capsys):
    for name in ("a", "b"):
        (tmp_path / name).mkdir()
        dry_run(small_protocol(tmp_path / name, count=2, repeats=1), tmp_path / name / "run")
    merged = tmp_path / "merged"
    assert main(["dataset", "merge", str(tmp_path / "a" / "run"), str(tmp_path / "b" / "run"), "-o", str(merged)]) == 0
    before = _files(merged)
    capsys.readouterr()
    for command in ("resume", "finish"):
        assert main(["campaign", command, str(merged)]) == 5
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "Traceback" not in err
        assert f"{merged / 'manifest.json'}" in err and "merged dataset" in err and "[kind]" in err
        assert "resume or finish each campaign it merged" in err
        assert _files(merged) == before  # no campaign.lock, nothing rewritten


def test_a_campaign_folder_is_not_taken_for_a_merge(tmp_path, capsys):
    # the negative control: a campaign's own folder passes the same check (complete without its report: resume makes
    # the report, here skipped with its note as too few presses, and ends 0)
    (tmp_path / "a").mkdir()
    dry_run(small_protocol(tmp_path / "a", count=2, repeats=1), tmp_path / "a" / "run")
    capsys.readouterr()
    assert main(["campaign", "resume", str(tmp_path / "a" / "run")]) == 0
    assert "merged dataset" not in capsys.readouterr().err
