"""The order the suite starts its tests in under `--dist worksteal` (pyproject's addopts): the longest first, spread
over the workers so that each starts with its share of them (longest processing time first), the rest after in
collection order. Without it the longest tests (real-time firmware replays, fine finite-element solves) were
collected last and could leave one core idle at the end while the other finished them.

`LONG_S`: seconds each took in the full suite with `-n 2` on 2 cores, measured on 9929020 (2026-11-26, each
test's setup, call and teardown, wall clock) with other work on the machine: load 8 to 15, the suite 25 min.
Loaded, the CPU-bound tests take 3 to 5 times their idle time and the real-firmware ones (real time) little more than
theirs. Every test of 12 s or more there, and the real-firmware ones of 5 s or more; two of TOGETHER's replays took
their own length only as the first's (35 and 37 s, their docstrings' and the earlier table's figures), and the
shipped kernel's check, whose work starts early (tests/early.py), is listed so that it starts first in its block
and is not stolen by the other worker, which would compute it again. Only the order uses them: a test renamed or
removed here is simply started in its collection order, and no test is skipped or changed."""

from __future__ import annotations

from collections.abc import Sequence
from typing import TypeVar

T = TypeVar("T")

LONG_S: dict[str, float] = {
    "tests/test_hil.py::test_real_firmware_with_the_simulated_daq": 63,
    "tests/test_marlin_real_vs_sim.py::test_homing_and_soft_endstops_answer_as_the_real_firmware": 50,
    "tests/test_datasets_damaged.py::test_a_part_without_read_permission_is_named_by_validate_info_resume_and_finish": 42,
    "tests/test_design_validate.py::test_the_negative_controls_power_is_about_the_studys_own_pinch": 40,
    "tests/test_wheel.py::test_skin_maps_from_root": 38,
    "tests/test_skin_kernel.py::test_skin_mechanics_cli_writes_the_kernel_with_provenance_and_a_plot": 38,
    "tests/test_marlin_real_settings.py::test_m206_applies_at_homing_as_on_the_real_firmware": 37,
    "tests/test_marlin_real_vs_sim.py::test_g28_with_an_r_word_answers_as_the_real_firmware": 35,
    "tests/test_dry_worker.py::test_sigkill_of_the_campaign_leaves_no_worker_and_resume_equals_inline": 35,
    "tests/test_datasets_damaged.py::test_a_lost_waveform_part_is_named_and_the_campaign_is_not_completed_without_it": 35,
    "tests/test_skin_maps.py::test_cli_maps_writes_pngs_and_parquet": 30,
    "tests/test_dry_worker.py::test_ctrl_c_to_the_group_stops_cleanly_and_resume_equals_inline[SIGHUP]": 29,
    "tests/test_gcode_blocks.py::test_a_28000_press_plan_does_not_hold_its_gcode_text": 28,
    "tests/test_datasets_split_export_manifest.py::test_split_and_export_stop_on_a_manifest_without_read_permission": 28,
    "tests/test_skin_quasi3d.py::test_the_transfer_is_mesh_converged_on_the_host_side": 28,
    "tests/test_faults_kill.py::test_kill_during_the_report_then_resume_writes_the_report": 28,
    "tests/test_datasets_damaged.py::test_a_presses_parquet_without_read_permission_is_named_by_resume_and_finish": 27,
    "tests/test_baselines_inversion.py::test_on_dry_run_rows_the_batched_solver_ends_at_bounded_minima_no_worse_than_the_reference": 26,
    "tests/test_baselines_tasks.py::test_a_report_in_processes_equals_one_in_this_process": 26,
    "tests/test_design_study.py::test_resume_after_sigkill_of_the_cli_gives_the_same_results_without_duplicates": 25,
    "tests/test_design_validate.py::test_the_study_agrees_with_campaigns_and_the_negative_control_disagrees": 25,
    "tests/test_dry_worker.py::test_ctrl_c_to_the_group_stops_cleanly_and_resume_equals_inline[SIGTERM]": 24,
    "tests/test_skin_fit.py::test_intervals_hold_the_truth_as_often_as_they_claim_over_seeds": 23,
    "tests/test_resume_rails_warning.py::test_a_real_resume_warns_from_the_forecast_child_before_the_rig_opens": 23,
    "tests/test_report_after_campaign.py::test_the_report_starts_with_no_campaign_process_or_thread_left_and_leaves_none": 22,
    "tests/test_marlin_pipelined.py::test_pipelined_presses_over_a_noisy_line_run_every_command_once_in_order[extreme]": 22,
    "tests/test_skin_fit.py::test_placement_and_noise_intervals_hold_the_truth_with_a_placement_error": 22,
    "tests/test_monitor_browser.py::test_page_follows_a_dry_run_and_pauses_and_continues_it": 21,
    "tests/test_dry_worker.py::test_ctrl_c_to_the_group_stops_cleanly_and_resume_equals_inline[SIGINT]": 21,
    "tests/test_campaign_scenes.py::test_ctrl_c_stops_after_the_press_in_flight_and_resumes[SIGINT]": 21,
    "tests/test_cli_warnings.py::test_a_command_that_warns_prints_one_line_per_warning": 21,
    "tests/test_resume_rails_warning.py::test_a_dry_resume_past_the_rails_warns_once_for_the_presses_left_and_loses_none": 21,
    "tests/test_campaign_scenes.py::test_a_lost_terminal_stops_the_campaign_as_ctrl_c_does": 20,
    "tests/test_baselines_inversion.py::test_the_batched_solver_lands_where_the_reference_does[0.0-0.0]": 20,
    "tests/test_campaign_scenes.py::test_ctrl_c_stops_after_the_press_in_flight_and_resumes[SIGTERM]": 20,
    "tests/test_campaign_scenes.py::test_ctrl_c_stops_after_the_press_in_flight_and_resumes[SIGHUP]": 20,
    "tests/test_resume_rails_warning.py::test_a_dry_resume_at_the_protocols_current_prints_no_rails_line": 20,
    "tests/test_campaign_kill.py::test_a_noisy_serial_line_changes_nothing_recorded[realistic]": 19,
    "tests/test_skin_mechanics.py::test_mesh_convergence_of_the_area_ratio[5.0-1.5]": 19,
    "tests/test_campaign_scenes.py::test_sigterm_during_resume_stops_it_as_ctrl_c_does": 19,
    "tests/test_faults_concurrency.py::test_a_killed_campaigns_lock_is_taken_over_and_merge_needs_to_be_asked": 19,
    "tests/test_baselines_inversion.py::test_over_campaign_seeds_the_batched_solver_places_presses_as_the_reference_does": 18,
    "tests/test_monitor.py::test_campaign_run_with_monitor_starts_and_stops_the_page[port-0]": 17,
    "tests/test_faults_concurrency.py::test_second_run_and_resume_are_refused_while_a_campaign_runs": 17,
    "tests/test_datasets_damaged.py::test_a_manifest_without_read_permission_is_one_error_naming_it": 16,
    "tests/test_campaign_kill.py::test_sigkill_then_resume_equals_uninterrupted[1]": 16,
    "tests/test_marlin_faults.py::test_extreme_rates_every_command_exactly_once_in_order[variant0-800]": 16,
    "tests/test_monitor_page.py::test_the_finished_page_reads_as_text_with_links_named_lines_and_one_clock": 16,
    "tests/test_faults_io.py::test_resume_into_a_parts_folder_it_cannot_write_is_refused_before_any_motion[presses]": 16,
    "tests/test_faults_io.py::test_resume_into_a_parts_folder_it_cannot_write_is_refused_before_any_motion[waveforms]": 16,
    "tests/test_marlin_cli.py::test_sim_printer_then_printer_send": 15,
    "tests/test_dry_worker.py::test_the_worker_records_the_inline_rows_bit_for_bit": 14,
    "tests/test_campaign_kill.py::test_sigkill_then_resume_equals_uninterrupted[2]": 14,
    "tests/test_datasets_cli.py::test_real_command_exit_status": 14,
    "tests/test_datasets_damaged.py::test_a_waveform_part_lost_after_completion_is_named_by_validate": 14,
    "tests/test_design_dask.py::test_nothing_outside_a_dask_run_imports_dask": 14,
    "tests/test_faults_io.py::test_read_only_file_system_is_one_clear_error_then_resume_completes": 14,
    "tests/test_baselines_report.py::test_the_inversion_model_is_chosen_by_name_and_a_missing_kernel_is_refused_before_any_fit": 13,
    "tests/test_campaign_batches.py::test_a_limit_leaves_every_press_on_disk": 13,
    "tests/test_campaign_batches.py::test_sigkill_mid_batch_then_resume_equals_uninterrupted[9]": 13,
    "tests/test_campaign_kill.py::test_sigkill_then_resume_equals_uninterrupted[0]": 13,
    "tests/test_console.py::test_console_over_the_simulated_printer": 13,
    "tests/test_marlin_real.py::test_ctrl_c_at_depth_lifts_to_the_travel_height[SIGTERM]": 12,
    "tests/test_marlin_real.py::test_printer_send_exits_0_with_noise": 12,
    "tests/test_baselines_lm.py::test_restarts_in_processes_give_the_same_network": 12,
    "tests/test_campaign_edges.py::test_resume_restores_a_damaged_presses_parquet_from_its_copy[truncated-complete]": 12,
    "tests/test_design_physics.py::test_model_inversion_attains_the_bound_where_the_bound_is_small": 12,
    "tests/test_marlin_real.py::test_ctrl_c_at_depth_lifts_to_the_travel_height[SIGINT]": 12,
    "tests/test_monitor.py::test_campaign_run_with_monitor_starts_and_stops_the_page[port-given]": 12,
    "tests/test_faults_io.py::test_resumed_fsr_waveform_is_bit_identical": 12,
    "tests/test_marlin_real.py::test_a_short_press_program[marlin-native]": 11,
    "tests/test_marlin_real_vs_sim.py::test_host_text_and_housekeeping_answer_as_the_real_firmware": 9,
    "tests/test_marlin_real.py::test_a_short_press_program[marlin-native-advok]": 8,
    "tests/test_marlin_real_settings.py::test_m114_rounding_and_cold_extrusion_answer_as_the_real_firmware": 8,
    "tests/test_marlin_real_vs_sim.py::test_the_simulator_answers_the_script_as_the_real_firmware[marlin-native-advok]": 6,
    "tests/test_marlin_real_settings.py::test_a_new_host_does_not_inherit_the_last_ones_auto_reports": 6,
    "tests/test_marlin_real_vs_sim.py::test_the_simulator_answers_the_script_as_the_real_firmware[marlin-native]": 6,
    "tests/test_skin_quasi3d.py::test_the_shipped_kernel_is_what_its_sources_give": 1,
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
