"""The baseline report at the end of a campaign: made, skipped with one note when the campaign is too small for its
splits (recorded as the manifest's `report.skipped`), or its error after one line saying the data is whole."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from neatskin.datasets.manifest import update_manifest, utc_now_iso
from neatskin.errors import ConfigError, DataError, Problem
from neatskin.rig.folder import skipped_report


def make_report(folder: Path, progress: bool, presses: int) -> str:
    from neatskin.baselines.report import run_baselines  # scikit-learn: only a report needs it
    from neatskin.baselines.summary import report_summary

    try:
        made = run_baselines(folder, split="both", progress=progress)
    except DataError as exc:
        if exc.problems and exc.problems[0].field == "rows":  # too few presses for a split: a note, not a failure
            return _skip_report(folder, presses, exc.problems[0])
        raise _report_failed(folder, presses, exc) from exc
    except ConfigError as exc:
        raise _report_failed(folder, presses, exc) from exc
    except KeyboardInterrupt:
        raise KeyboardInterrupt(
            f"the campaign's data is complete in {folder}; only its baseline report was "
            f"stopped: make it with neatskin campaign finish {folder}"
        ) from None
    update_manifest(folder, report={"path": "report.md", "written_at": utc_now_iso()})
    return report_summary(made)


def _report_failed(folder: Path, presses: int, exc: ConfigError | DataError) -> ConfigError | DataError:
    """The report's error, its kind kept, after one line saying the data is whole."""
    intact = Problem(
        f"the campaign's data is complete and intact ({presses} of {presses} presses in {folder}); only its baseline "
        "report failed, for the reason below",
        str(folder),
    )
    return type(exc)(problems=(intact, *exc.problems))


def _skip_report(folder: Path, presses: int, why: Problem) -> str:
    """A campaign too small for the baseline report's splits (a short test campaign) ends without one: one note,
    recorded in the manifest (`report.skipped`) so that resume and finish do not retry it."""
    reason = f"{why.message}; {why.fix}" if why.fix else why.message
    update_manifest(folder, report={"skipped": reason, "written_at": utc_now_iso()})
    return _skip_note(presses, reason)


def _skip_note(presses: int, reason: str) -> str:
    return f"note: no baseline report: {presses} presses are too few for its splits ({reason})"


def report_or_note(folder: Path, manifest: dict[str, Any], progress: bool, presses: int) -> str | None:
    """finish's report: made when report.md is missing, but not again for a campaign too small for one (its note)."""
    skipped = skipped_report(manifest)
    if skipped is not None:
        return _skip_note(presses, skipped)
    return None if (folder / "report.md").is_file() else make_report(folder, progress, presses)
