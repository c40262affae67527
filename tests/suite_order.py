"""The order the suite starts its tests in under `--dist worksteal` (pyproject's addopts): the longest first, spread
over the workers so that each starts with its share of them (longest processing time first), the rest after in
collection order. Without it the longest tests (real-time firmware replays, fine finite-element solves) were
collected last and could leave one core idle at the end while the other finished them.

`LONG_S`: seconds each took in the full suite with `-n 2` (2 cores, another suite running beside it: load 8 to 9;
idle they take about half, but for the firmware replays, which run in real time). Only the order uses them: a test
renamed or removed here is simply started in its collection order, and no test is skipped or changed."""

from __future__ import annotations

from collections.abc import Sequence
from typing import TypeVar

T = TypeVar("T")

LONG_S: dict[str, float] = {
    "tests/test_skin_quasi3d.py::test_the_transfer_is_mesh_converged_on_the_host_side": 172,
    "tests/test_marlin_real_vs_sim.py::test_homing_and_soft_endstops_answer_as_the_real_firmware": 60,
    "tests/test_marlin_real_vs_sim.py::test_g28_with_an_r_word_answers_as_the_real_firmware": 59,
    "tests/test_skin_quasi3d.py::test_the_shipped_kernel_is_what_its_sources_give": 56,
    "tests/test_hil.py::test_real_firmware_with_the_simulated_daq": 48,
    "tests/test_marlin_real_settings.py::test_m206_applies_at_homing_as_on_the_real_firmware": 37,
    "tests/test_design_validate.py::test_the_power_sweep_builds_the_studys_side_once_and_matches_the_full_check": 36,
    "tests/test_skin_fit.py::test_intervals_hold_the_truth_as_often_as_they_claim_over_seeds": 35,
    "tests/test_report_after_campaign.py::test_the_report_starts_with_no_campaign_process_or_thread_left_and_leaves_none": 34,
    "tests/test_marlin_pipelined.py::test_pipelined_presses_over_a_noisy_line_run_every_command_once_in_order[extreme]": 22,
    "tests/test_skin_fit.py::test_placement_and_noise_intervals_hold_the_truth_with_a_placement_error": 21,
    "tests/test_design_validate.py::test_the_study_agrees_with_campaigns_and_the_negative_control_disagrees": 21,
    "tests/test_design_dask.py::test_dask_run_agrees_with_a_local_run_and_survives_a_killed_worker": 18,
    "tests/test_datasets_kill.py::test_sigkill_at_random_points_then_resume": 18,
    "tests/test_marlin_cli.py::test_sim_printer_then_printer_send": 15,
    "tests/test_marlin_faults.py::test_extreme_rates_every_command_exactly_once_in_order[variant0-800]": 15,
    "tests/test_marlin_cli.py::test_ctrl_c_stops_after_the_line_in_flight_lifts_and_from_line_continues_once": 13,
    "tests/test_design_study.py::test_resume_after_sigkill_of_the_cli_gives_the_same_results_without_duplicates": 13,
    "tests/test_console.py::test_console_over_the_simulated_printer": 12,
    "tests/test_marlin_real.py::test_ctrl_c_at_depth_lifts_to_the_travel_height[SIGINT]": 12,
    "tests/test_gcode_blocks.py::test_a_28000_press_plan_does_not_hold_its_gcode_text": 12,
    "tests/test_dry_worker.py::test_ctrl_c_to_the_group_stops_cleanly_and_resume_equals_inline[SIGTERM]": 12,
    "tests/test_wheel.py::test_skin_maps_from_root": 12,
    "tests/test_hil.py::test_resume_keeps_the_simulated_daq": 11,
    "tests/test_marlin_real.py::test_ctrl_c_at_depth_lifts_to_the_travel_height[SIGTERM]": 11,
    "tests/test_forecast.py::test_campaign_plan_shows_its_progress_on_stderr_and_the_same_results_without_it": 11,
    "tests/test_dry_worker.py::test_sigkill_of_the_campaign_leaves_no_worker_and_resume_equals_inline": 11,
    "tests/test_monitor_browser.py::test_page_follows_a_dry_run_and_pauses_and_continues_it": 11,
    "tests/test_marlin_real_vs_sim.py::test_host_text_and_housekeeping_answer_as_the_real_firmware": 11,
    "tests/test_baselines_inversion.py::test_over_campaign_seeds_the_batched_solver_places_presses_as_the_reference_does": 11,
    "tests/test_marlin_cli.py::test_ctrl_c_at_depth_ends_at_the_programs_travel_height[SIGHUP]": 11,
    "tests/test_marlin_cli.py::test_ctrl_c_at_depth_ends_at_the_programs_travel_height[SIGTERM]": 10,
    "tests/test_marlin_cli.py::test_ctrl_c_at_depth_ends_at_the_programs_travel_height[SIGINT]": 10,
    "tests/test_marlin_real.py::test_printer_send_exits_0_with_noise": 10,
    "tests/test_baselines_inversion.py::test_on_dry_run_rows_the_batched_solver_ends_at_bounded_minima_no_worse_than_the_reference": 10,
    "tests/test_marlin_cli.py::test_printer_send_to_a_peer_acknowledging_lines_never_sent_is_one_error": 10,
    "tests/test_marlin_real_settings.py::test_m114_rounding_and_cold_extrusion_answer_as_the_real_firmware": 10,
    "tests/test_design_dask.py::test_nothing_outside_a_dask_run_imports_dask": 10,
    "tests/test_dry_worker.py::test_ctrl_c_to_the_group_stops_cleanly_and_resume_equals_inline[SIGHUP]": 10,
    "tests/test_campaign_scenes.py::test_a_lost_terminal_stops_the_campaign_as_ctrl_c_does": 9,
    "tests/test_design_validate.py::test_validate_shows_its_progress_on_stderr_and_the_same_results_without_it": 9,
    "tests/test_dry_worker.py::test_the_worker_records_the_inline_rows_bit_for_bit": 9,
    "tests/test_baselines_tasks.py::test_a_report_in_processes_equals_one_in_this_process": 8,
    "tests/test_datasets_damaged.py::test_a_manifest_without_read_permission_is_one_error_naming_it": 8,
    "tests/test_campaign_bad_input.py::test_serial_port_that_never_answers": 8,
    "tests/test_campaign_scenes.py::test_ctrl_c_stops_after_the_press_in_flight_and_resumes[SIGHUP]": 8,
    "tests/test_datasets_damaged.py::test_a_presses_parquet_without_read_permission_is_named_by_resume_and_finish": 8,
    "tests/test_campaign_kill.py::test_a_noisy_serial_line_changes_nothing_recorded[realistic]": 8,
    "tests/test_faults_kill.py::test_kill_during_the_report_then_resume_writes_the_report": 8,
    "tests/test_orphans.py::test_a_killed_runs_joblib_workers_end_with_it[busy]": 8,
    "tests/test_physlimit.py::test_a_scene_without_noise_has_a_zero_electronics_bound_and_a_report": 8,
    "tests/test_design_validate.py::test_the_negative_controls_power_is_about_the_studys_own_pinch": 8,
    "tests/test_dry_worker.py::test_ctrl_c_to_the_group_stops_cleanly_and_resume_equals_inline[SIGINT]": 7,
    "tests/test_monitor_page.py::test_the_printer_terminal_sends_a_line_and_shows_the_reply": 7,
    "tests/test_campaign_scenes.py::test_sigterm_during_resume_stops_it_as_ctrl_c_does": 7,
    "tests/test_baselines_report.py::test_the_inversion_model_is_chosen_by_name_and_a_missing_kernel_is_refused_before_any_fit": 7,
    "tests/test_monitor.py::test_campaign_run_with_monitor_starts_and_stops_the_page[port-0]": 7,
    "tests/test_baselines_inversion.py::test_the_batched_solver_lands_where_the_reference_does[0.0-0.0]": 7,
    "tests/test_marlin_real_vs_sim.py::test_moves_before_homing_answer_as_the_real_firmware": 6,
    "tests/test_marlin_real.py::test_a_short_press_program[marlin-native-advok]": 6,
    "tests/test_orphans.py::test_a_killed_runs_joblib_workers_end_with_it[idle]": 6,
    "tests/test_marlin_real_vs_sim.py::test_the_simulator_answers_the_script_as_the_real_firmware[marlin-native-advok]": 6,
    "tests/test_datasets_damaged.py::test_a_part_without_read_permission_is_named_by_validate_info_resume_and_finish": 6,
    "tests/test_skin_mechanics.py::test_mesh_convergence_of_the_area_ratio[5.0-1.5]": 11,
}


def block_sizes(n_items: int, n_workers: int) -> list[int]:
    """How xdist's worksteal scheduler first splits the collection: contiguous blocks, the i-th of
    (what is left) // (workers left)."""
    sizes, left = [], n_items
    for i in range(n_workers):
        sizes.append(left // (n_workers - i))
        left -= sizes[-1]
    return sizes


# The tests that drive the real firmware for long (shared/marlin's native build): its HAL spins three threads on
# sched_yield, so while one runs the test beside it gets about half a core. They go first on every worker, at the
# same time, so that they take that half from each other (they wait on the firmware's real-time clock anyway)
# rather than from a CPU-bound test. Seen on the idle machine: the fine FE transfer test took 133 s beside them
# against 81 s beside the short tests.
REAL_TIME_FILES = ("tests/test_marlin_real", "tests/test_hil.py::test_real_firmware", "tests/test_gcode_firmware_text")


def real_time(name: str) -> bool:
    return name.startswith(REAL_TIME_FILES)


# The homing replays to the real firmware (test_marlin_real_vs_sim.TOGETHER): the first of them to run starts the
# firmware's side of all of them at once, so they go to one worker, one after another, as one long test as long as
# the longest of them.
TOGETHER = (
    "tests/test_marlin_real_vs_sim.py::test_homing_and_soft_endstops_answer_as_the_real_firmware",
    "tests/test_marlin_real_vs_sim.py::test_g28_with_an_r_word_answers_as_the_real_firmware",
    "tests/test_marlin_real_settings.py::test_m206_applies_at_homing_as_on_the_real_firmware",
)

#: The node ids this session runs, after -k/-m deselection (conftest sets it; None: not known, take them all).
SELECTED: set[str] | None = None


def long_first(items: Sequence[T], ids: Sequence[str], n_workers: int) -> list[T]:
    """`items` reordered so that each of the worker's first blocks starts with its share of the long tests: the
    real-firmware ones first, then the others, each longest first and to the block whose long tests add up to the
    least so far (TOGETHER's tests as one, in one block); the other tests fill the blocks in their collection order.
    The same items, each once."""
    if n_workers < 2 or len(items) < n_workers:
        return list(items)
    where = {name: i for i, name in enumerate(ids)}
    group = [where[name] for name in TOGETHER if name in where]
    units = [([i], LONG_S[name]) for i, name in enumerate(ids) if name in LONG_S and i not in group]
    if group:
        units.append((group, max(LONG_S.get(ids[i], 0.0) for i in group)))
    units.sort(key=lambda unit: -unit[1])
    units = [u for u in units if real_time(ids[u[0][0]])] + [u for u in units if not real_time(ids[u[0][0]])]
    shares: list[list[int]] = [[] for _ in range(n_workers)]
    totals = [0.0] * n_workers
    sizes = block_sizes(len(items), n_workers)
    for unit, seconds in units:
        open_blocks = [k for k in range(n_workers) if len(shares[k]) + len(unit) <= sizes[k]]
        if not open_blocks:
            continue  # a block too small for it (a handful of tests selected): it keeps its collection order
        k = min(open_blocks, key=lambda b: totals[b])
        shares[k] += unit
        totals[k] += seconds
    is_long = {i for share in shares for i in share}
    rest = iter([i for i in range(len(items)) if i not in is_long])
    order: list[int] = []
    for k in range(n_workers):
        order += shares[k] + [next(rest) for _ in range(sizes[k] - len(shares[k]))]
    return [items[i] for i in order]
