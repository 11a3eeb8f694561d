"""The tests marked ``slow`` (``tests/conftest.py`` adds the marker): each took about 5 s or
more in a ``make test`` on 2 busy cores. ``pytest -m "not slow"`` runs the rest, in about a
fifth of the time; ``make test`` runs everything.

An entry is a test file (every test in it) or a test (``path::name``, every parametrization of
it). To refresh the list, run ``make test PYTEST_ARGS=--durations=0`` and compare.
"""

from __future__ import annotations

SLOW: tuple[str, ...] = (
    "tests/e2e/test_acceptance_on_mocks.py",
    "tests/e2e/test_acquire.py",
    "tests/e2e/test_adaptive.py",
    "tests/e2e/test_arm_identity.py",
    "tests/e2e/test_export_cli.py::test_exports_of_a_session_acquired_on_the_mock_rig",
    "tests/e2e/test_franka_sim.py",
    "tests/e2e/test_igtl_rig.py",
    "tests/e2e/test_mock_kinematics.py",
    "tests/e2e/test_mocks_loopback.py::test_tmscal_mock_refuses_non_loopback_endpoints",
    "tests/e2e/test_monitor.py",
    "tests/e2e/test_path_safety.py::test_denso_executes_only_paths_inside_the_envelope",
    "tests/e2e/test_path_safety.py::test_ur_executes_only_paths_inside_the_envelope",
    "tests/e2e/test_progress.py::test_run_that_skips_too_many_poses_stops_resumably_naming_the_reason",
    "tests/e2e/test_progress.py::test_track_ctrl_c_closes_the_tracker_quietly",
    "tests/e2e/test_progress.py::test_track_table_plain_and_in_place",
    "tests/e2e/test_readme.py",
    "tests/e2e/test_report_html.py",
    "tests/e2e/test_selfcal_rig.py",
    "tests/e2e/test_stream.py",
    "tests/e2e/test_ur_robot.py",
    "tests/e2e/test_ur_wrench.py::test_urrobot_wrench_reads_the_same",
    "tests/e2e/test_wheel.py",
    "tests/e2e/test_wrench_rows.py",
    "tests/interop/test_igtl_clients.py",
    "tests/interop/test_ur_rtde.py",
    "tests/property/test_adaptive_pool.py::test_every_selected_pose_is_inside_the_envelope",
    "tests/property/test_calibfile_parser.py::test_one_key_replaced_by_anything",
    "tests/property/test_igtl_parsers.py::test_assembled_frames_are_the_frames_sent",
    "tests/property/test_protocol_fuzz.py::test_fuzz_decode_tx_only_protocol_error",
    "tests/property/test_safety_envelope.py::test_nothing_outside_the_config_reaches_the_driver",
    "tests/property/test_session_truth_arm.py::test_substituted_values_in_the_truth_arm",
    "tests/unit/test_adaptive_loop.py::test_decisions_are_a_function_of_the_recorded_poses",
    "tests/unit/test_adaptive_math.py::test_chosen_poses_beat_random_poses_on_the_true_error",
    "tests/unit/test_adaptive_math.py::test_prediction_covers_the_true_error_at_about_its_confidence",
    "tests/unit/test_architecture.py::test_no_import_cycle_between_files",
    "tests/unit/test_architecture.py::test_the_graph_has_the_subpackages_it_checks",
    "tests/unit/test_calib_ml.py",
    "tests/unit/test_calibfile.py::test_yaml_bombs_and_recursion_are_refused",
    "tests/unit/test_compare.py::test_cli_json_and_plots",
    "tests/unit/test_escaping.py::test_report_device_names_and_identities_are_escaped",
    "tests/unit/test_kinematics_estimate.py::test_a_tracker_scale_and_the_arms_size_are_one_direction",
    "tests/unit/test_kinematics_estimate.py::test_auto_level_prefers_full_when_the_arm_is_in_error_and_none_when_it_is_not",
    "tests/unit/test_kinematics_summary.py",
    "tests/unit/test_kinfile.py::test_any_document_is_a_model_or_one_error",
    "tests/unit/test_kinfile.py::test_one_key_replaced_by_anything",
    "tests/unit/test_kinfile.py::test_valid_models_round_trip",
    "tests/unit/test_ndi_driver.py::test_persistent_drops_raise_device_timeout_naming_the_command",
    "tests/unit/test_output_files.py::test_every_output_kind_follows_the_umask",
    "tests/unit/test_output_files.py::test_solve_force_onto_a_session_being_recorded_is_refused",
    "tests/unit/test_path_laws.py::test_denso_moves_keep_every_tool_point_under_the_caps_on_the_mocks_profile",
    "tests/unit/test_path_laws.py::test_the_audits_coil_speed_before_and_after",
    "tests/unit/test_path_laws.py::test_ur_moves_keep_every_tool_point_under_the_caps_on_the_mocks_profile",
    "tests/unit/test_path_math.py::test_any_per_axis_monotone_motion_stays_in_a_hull_found_inside",
    "tests/unit/test_path_math.py::test_every_wall_the_fine_sampled_path_crosses_is_found",
    "tests/unit/test_path_math.py::test_the_largest_rotation_from_p0_matches_fine_sampling",
    "tests/unit/test_realistic_arm.py::test_simulate_redraws_what_the_cobotta_cannot_reach",
    "tests/unit/test_report.py::test_default_errors_are_cross_validated_and_near_the_true_hold_out",
    "tests/unit/test_report_html.py::test_stored_calibration_is_held_out_on_another_session",
    "tests/unit/test_safety_mutants.py",
    "tests/unit/test_sample.py::test_samples_by_need_reach_the_standard_error_they_were_asked_for",
    "tests/unit/test_sample.py::test_tool_translation_scatter_is_sigma_over_root_n",
    "tests/unit/test_session_integrity.py::test_racing_creators_exactly_one_wins",
    "tests/unit/test_sim_kinematics.py::test_rig_reaches_configurations_spread_over_the_joint_space",
    "tests/unit/test_solve_kinematics.py::test_true_kinematics_lower_the_truth_errors",
)


def is_slow(nodeid: str) -> bool:
    """True when the test ``nodeid`` (``path::name[params]``) is in ``SLOW``."""
    base = nodeid.split("[", 1)[0]
    return any(base == e or base.startswith(e + "::") for e in SLOW)
