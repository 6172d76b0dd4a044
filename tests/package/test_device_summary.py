"""scripts/device_summary.py: the JSON summary scripts/device_check.sh writes from a pytest log."""
import json

import device_summary

XDIST = """\
bringing up nodes...
[gw0] PASSED tests/plugin/test_plugin.py::test_traverse_albedo
[gw1] FAILED tests/plugin/test_plugin_materials.py::test_eval_matches_reference_table_and_model[rectangle]
[gw0] PASSED tests/plugin/test_gradients.py::test_forward_mode_render_gradient_matches_finite_differences[area_fraction texel]
[gw2] SKIPPED tests/plugin/test_sphere_kernel_layout.py::test_packed_rows_written_in_place_are_the_intervals[in-place]
[gw1] ERROR tests/apps/test_scenes.py::test_scene_renders[teaser]
=========================== short test summary info ============================
FAILED tests/plugin/test_plugin_materials.py::test_eval_matches_reference_table_and_model[rectangle] - AssertionError: eval at 550.0 nm
ERROR tests/apps/test_scenes.py::test_scene_renders[teaser] - RuntimeError: x
======= 1 failed, 2 passed, 1 skipped, 1 error in 12.31s =======
"""

SERIAL_CUT = """\
tests/plugin/test_trig.py::test_reduce_angle_is_within_an_ulp_over_a_wide_range PASSED
tests/plugin/test_sphere_gradients.py::test_radius_derivatives_match_central_differences[poisson-True-True-True] FAILED
tests/plugin/test_trig.py::test_sinc_product_matches_float64_at_large_arguments[1e-3 x] PASSED [ 40%]
tests/plugin/test_trig.py::test_no_plugin_module_calls_drjits_sin_or_cos
"""


def test_xdist_log_with_its_summary_lines(tmp_path):
    log = tmp_path / "plugin_tests.log"
    log.write_text(XDIST)
    out = tmp_path / "device_check.json"
    device_summary.main([str(log), "--variant", "cuda_ad_spectral", "--rc", "1", "--seconds", "12.3",
                         "--selection", "tests -m mitsuba", "--machine", "gpu=NVIDIA H200", "driver=580.159.04",
                         "--out", str(out)])
    s = json.loads(out.read_text())
    assert s["machine"]["gpu"] == "NVIDIA H200" and s["machine"]["driver"] == "580.159.04"
    assert s["machine"]["date"].endswith("Z") and s["variant"] == "cuda_ad_spectral"
    assert (s["passed"], s["failed"], s["skipped"], s["complete"], s["rc"]) == (2, 2, 1, True, 1)
    assert s["failing"] == ["tests/apps/test_scenes.py::test_scene_renders[teaser]",
                            "tests/plugin/test_plugin_materials.py::test_eval_matches_reference_table_and_model[rectangle]"]


def test_a_log_cut_off_by_the_time_cap_counts_what_finished():
    s = device_summary.summary(SERIAL_CUT.splitlines(True), variant="llvm_ad_spectral", selection="",
                               rc=124, seconds=400.0, machine={})
    assert (s["passed"], s["failed"], s["complete"]) == (2, 1, False)
    assert s["failing"] == ["tests/plugin/test_sphere_gradients.py::"
                            "test_radius_derivatives_match_central_differences[poisson-True-True-True]"]
