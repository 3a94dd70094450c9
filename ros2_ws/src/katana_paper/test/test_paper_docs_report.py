"""docs_report: the committed pages are what the committed results make, and the rendering of
small constructed results, checked against expectations written out by hand."""

import json
import re
from pathlib import Path

import pytest
from katana_paper import docs_report as dr

ROOT = Path(__file__).resolve().parents[4]


def test_the_committed_pages_are_what_the_committed_results_make() -> None:
    for path, text in dr.render_all(ROOT).items():
        assert path.read_text(encoding="utf-8") == text, (
            f"{path.relative_to(ROOT)} is not what docs/results/ makes: run "
            "`python -m katana_paper.docs_report` (and edit the generator, not the page)")


def test_the_pages_hold_no_development_history() -> None:
    # wording about the project's own working history: a tracker number, a work period
    period = "|".join(("stop", "session", "round"))
    history = re.compile(rf"\b(issue|round) \d|\b(this|earlier) ({period})\b", re.IGNORECASE)
    for path, text in dr.render_all(ROOT).items():
        assert not history.search(text), f"{path.name}: {history.search(text).group(0)!r}"


# -- formatting ----------------------------------------------------------------------------


def test_numbers_ratios_and_targets() -> None:
    assert dr.num(1234567.8) == "1,234,568"
    assert dr.num(42) == "42"
    assert dr.num(0.012345) == "0.012"
    assert dr.num(0.012345, 4) == "0.0123"
    assert dr.num(None) == dr.num(float("nan")) == dr.num(True) == "not recorded"
    assert dr.ratio(3.0, 2.0) == "1.50x"
    assert dr.ratio(100, 8, 1) == "12.5x"
    assert dr.ratio(1.0, 0) == dr.ratio(None, 1.0) == "-"
    assert dr.met_text(5.0, 10.0) == "10 (met)"
    assert dr.met_text(12.0, 10.0) == "10 (not met)"
    assert dr.met_text(0.99, 0.98, at_most=False) == "0.98 (met)"
    assert dr.met_text(150_000, 100_000, at_most=False) == "100,000 (met)"
    assert dr.met_text(1.0, None) == "-"
    assert dr.count_of(0.7, 10) == "7 / 10"


def test_the_cpu_comes_from_the_file_or_its_provenance() -> None:
    bench = {"machine": {"cpu_model": "Test CPU 9000", "cpus": 4}}
    collected = {"provenance": {"machine": {"cpu_model": "Other CPU", "cpus": 2}}}
    assert dr.made_by("python bench/run.py core", bench) == (
        "Made by `python bench/run.py core` on Test CPU 9000, 4 CPUs.")
    assert dr.cpu_text(collected) == "Other CPU, 2 CPUs"
    assert dr.cpu_text({}) == "CPU not recorded"


def test_commands_are_rebuilt_from_what_the_files_record() -> None:
    paper = {"experiments": 500, "seeds": [3, 4], "strategies": {"q1": {}, "random": {}},
             "parameters": {"alpha": 1.0, "theta": 0.01, "gamma": 0.95}}
    assert dr.paper_command(paper) == (
        "katana-curiosity paper --experiments 500 --seeds 2 --first-seed 3 "
        "--strategies q1,random --alpha 1 --theta 0.01 --gamma 0.95")
    older = {"steps": 500, "seeds": [0], "methods": {"q1": {}}, "parameters": {}}
    assert dr.paper_command(older) == (
        "katana-curiosity paper --experiments 500 --seeds 1 --strategies q1")
    robot = {"experiments": 60, "seeds": [0, 1], "truth": "docs/robot_truth.json", "jobs": 2,
             "strategies": {"q1": {}, "random": {}}}
    assert dr.robot_paper_command(robot) == (
        "katana-robot paper --seeds 2 --experiments 60 --strategies q1,random --jobs 2 "
        "--truth docs/robot_truth.json")
    skill = {"goal_height": 3, "trials": 10, "seed": 100, "max_placements": 12,
             "models": [{"model": "runs/x/q1-s0"}, {"model": "untrained"}]}
    assert dr.skill_command(skill) == (
        "katana-robot skill --goal-height 3 --trials 10 --seed 100 --max-placements 12 "
        "--model runs/x/q1-s0")


# -- BENCHMARKS.md -------------------------------------------------------------------------


def test_every_missing_bench_is_reported_with_its_command() -> None:
    text = dr.render_benchmarks({})
    for name in dr.BENCHES:
        assert f"*Not measured*: there is no `docs/results/bench/{name}.json`. Make it with " \
               f"`python bench/run.py {name}`" in text
    assert text.startswith(dr.GENERATED)


def test_core_speed_stands_beside_its_baseline_and_floor() -> None:
    data = {"bench": "core", "machine": {"cpu_model": "Test CPU", "cpus": 2},
            "steps_per_s": {"q1": 200_000}, "steps_per_s_floor": {"q1": 150_000},
            "reference_steps_per_s": {"q1": 10_000},
            "paper_default_wall_s": 3.0, "paper_default_cpu_s": 4.0,
            "targets": {"q1_steps_per_s": 100_000, "paper_default_wall_s": 10}}
    text = dr.render_benchmarks({"core": data})
    assert "Made by `python bench/run.py core` on Test CPU, 2 CPUs." in text
    q1 = next(line for line in text.splitlines() if line.startswith("| Q1 steps per second, c"))
    assert q1 == ("| Q1 steps per second, compiled path, median of 3 runs (slowest 150,000) | "
                  "200,000 | NumPy reference: 10,000 | 20.0x | 100,000 (met), by the slowest "
                  "run |")
    wall = next(line for line in text.splitlines() if line.startswith("| `katana-curiosity"))
    assert "| 3.00 | its CPU time over the 2 CPUs: 4.00 / 2 = 2.00 | 1.50x | 10 (met) |" in wall


def test_the_loop_and_the_arm_against_their_floors() -> None:
    loop = {"bench": "loop", "experiments": 18, "s_per_experiment": 0.9,
            "experiment_floor_s": 0.3, "experiment_floor_two_images_s": 0.25,
            "dropped_experiments": {"no_usable_instance": 2},
            "targets": {"s_per_experiment": 1.0, "dropped_fraction": 0.1}}
    text = dr.bench_loop(loop)
    assert "| 0.90 | physics, renders, segmentation, judge and fovea in the same windows: " \
           "0.30 | 3.00x | 1 (met) |" in text
    assert "attempts dropped: 2 no_usable_instance (a share of 0.10; target at most 0.10)" in text
    loop["dropped_experiments"] = {"total": 2, "by_reason": {"no_usable_instance": 1,
                                                             "grasp_missed": 1},
                                   "fraction_of_attempts": 0.1}
    assert "attempts dropped: 1 no_usable_instance, 1 grasp_missed (a share of 0.10;" \
           in dr.bench_loop(loop)
    arm = {"bench": "arm", "runs": 4, "pick_place_s": 0.3, "physics_only_s": 0.2,
           "placement_error_mm": {"p95": 1.0, "median": 0.1, "max": 5.0},
           "pick_success": 1.0, "action6_stable": {"1": 1.0, "2": 0.5},
           "physics_only": {"placement_error_mm": {"p95": 0.9, "median": 0.1, "max": 4.0},
                            "pick_success": 1.0, "action6_stable": {"1": 1.0, "2": 1.0}},
           "targets": {"placement_error_mm.p95": 4.0, "action6_stable": 0.98,
                       "pick_success": 0.98, "pick_place_s": 0.5}}
    text = dr.bench_arm(arm)
    assert "| 0.300 | the same motions stepped without ROS: 0.200 | 1.50x | 0.5 (met) |" in text
    assert "| placement error p95, mm | 1.00 | 0.90 | 4 (met) |" in text
    assert "| action-6 placements that stayed, height 2 | 0.500 | 1.000 | 0.98 (not met) |" \
           in text


def test_recording_against_the_loop_without_it() -> None:
    record = {"s_per_experiment_without_recording": 0.8, "s_per_experiment_with_recording": 0.82,
              "overhead_fraction": 0.025, "record_s_per_experiment": 0.016,
              "runs": 4, "experiments_per_run": 16, "recorded_messages_per_run": [570, 580],
              "recorded_mib_per_run": [0.22, 0.23], "targets": {"overhead_fraction": 0.05}}
    text = dr.bench_record(record)
    assert "| 0.820 | the same loop without recording: 0.800 | 1.025x | overhead 0.025; " \
           "under 0.05 (met) |" in text
    assert "| 0.0160 | the experiment with recording: 0.820 | 0.0195x | - |" in text
    assert "held 570, 580 messages in 0.22, 0.23 MiB" in text


def test_the_driver_and_the_sim_against_their_floors_and_targets() -> None:
    driver = {"request_ms": 0.2, "request_p95_ms": 0.4, "serial_request_ms": 0.5,
              "emulator_handle_ms": 0.05, "poll_rate_hz": 25.0, "state_hz": 24.0,
              "shutdown_s": {"driver_idle_SIGINT": 0.6},
              "faults": {"crc_5pct": {"duplicated_segments": 0, "max_speed_ratio": 0.9,
                                      "outcome": "succeeded", "next_goal": "succeeded"}}}
    text = dr.bench_driver(driver)
    assert "| 0.2000 | the emulator's handling of it alone: 0.0500 | 4.0x | below 1 |" in text
    assert "| joint_states rate, idle, by arrival, Hz | 24.00 | the configured poll rate: 25.0 " \
           "| 0.96x | at least 25.0 |" in text
    assert "| driver_idle_SIGINT | 0.600 |" in text
    assert "| crc_5pct | 0 | 0.900 | succeeded | succeeded |" in text
    sim = {"render_ms": 12.0, "pick_place_s": 0.25, "pick_place_succeeded": 5,
           "pick_place_runs": 5, "targets": {"render_ms": 30.0, "pick_place_s": 0.5}}
    text = dr.bench_sim(sim)
    assert "| render one 640x480 frame, ms | 12.0 | none measured | - | 30 (met) |" in text
    assert "(succeeded: 5 of 5) | 0.250 |" in text


def test_a_bench_file_without_its_figures_does_not_break_the_page() -> None:
    results = {name: {"bench": name} for name in dr.BENCHES}
    text = dr.render_benchmarks(results)
    for name in dr.BENCHES:
        assert f"Made by `python bench/run.py {name}` (the file does not record the CPU)." in text
    assert "not recorded" in text


# -- REPRODUCING.md ------------------------------------------------------------------------


def _strategy(overall, kl, direct=None, planned=None):
    return {"final_kl_overall": overall, "final_kl": {str(h): v for h, v in kl.items()},
            "direct_experience": direct or {}, "planned_experience": planned or {}}


def _paper(q1=0.03, q10=0.031):
    heights = range(1, 5)
    return {
        "experiments": 1000, "seeds": [0, 1], "parameters": {"n_blocks": 5, "n_features": 21,
                                                             "alpha": 1.0, "theta": 0.01,
                                                             "gamma": 0.95},
        "strategies": {
            "q1": _strategy(q1, {h: 0.01 * h for h in heights},
                            direct={"0": 0, "1": 400, "2": 300, "3": 200, "4": 100},
                            planned={"0": 30, "1": 50, "2": 20, "3": 0, "4": 0}),
            "q10": _strategy(q10, {h: 0.011 * h for h in heights}),
            "conf": _strategy(0.05, {h: 0.02 * h for h in heights}),
            "random": _strategy(0.08, {1: 0.001, 2: 0.002, 3: 0.5, 4: 0.6}),
        }}


def test_the_kl_table_marks_the_best_overall() -> None:
    text = dr.kl_table(_paper())
    assert text.splitlines()[0] == ("| strategy | height 1 | height 2 | height 3 | height 4 "
                                    "| overall |")
    assert "| Q1 | 0.010 | 0.020 | 0.030 | 0.040 | **0.0300** |" in text
    assert "| Random | 0.001 | 0.002 | 0.500 | 0.600 | 0.0800 |" in text


TRUTH = {
    "p_stable": {"0": {"1": 1.0}, "1": {"1": 0.0, "2": 0.1, "3": None},
                 "2": {"1": 0.0, "2": 0.0, "3": 1.0}, "3": {"1": 0.0, "2": 0.9, "3": 1.0}},
    "trials": {"0": {"1": 30}, "1": {"1": 30, "2": 30, "3": 0}, "2": {"1": 30, "2": 30, "3": 30},
               "3": {"1": 30, "2": 30, "3": 30}},
    "impossible": [[0, 2], [0, 3]],
    "never_realised_by_the_fovea": [[1, 3]],
    "measurement": {"trials_per_pair": 30, "seed": 0, "placements": 400, "resets": 100},
}


def test_the_truth_table_names_every_kind_of_cell() -> None:
    text = dr.truth_table(TRUTH)
    assert text.splitlines()[2] == "| 0 (table) | 1.00 (30) | cannot occur | cannot occur |"
    assert text.splitlines()[3] == "| 1 | 0.00 (30) | 0.10 (30) | not realised |"
    assert dr.uncertain_pairs(TRUTH) == [(1, 2, 0.1), (3, 2, 0.9)]
    assert dr.parallax_actions(TRUTH) == [2]
    section = dr.truth_section(TRUTH)
    assert section.startswith("Made by `katana-robot truth --trials 30 --seed 0 --max-height "
                              "3` (the file does not record the CPU). 400 pick-and-places and "
                              "100 resets.")
    assert "(a2 here)" in section


def test_the_robot_runs_table_lists_every_strategy() -> None:
    runs = {"experiments": 60, "seeds": [0, 1], "strategies": {
        "q1": {"final_kl": {"0": 0.02, "1": 0.3}, "final_kl_overall": 0.16,
               "kl_overall_after_30": 0.2, "wasted_share": 0.0, "wasted_experiments": 0,
               "experiments_done": [60, 60], "highest_stack": 3,
               "highest_stack_per_seed": [3, 2],
               "actions_tried": {"1": {"2": 10, "3": 5}, "3": {"2": 5}, "2": {"1": 80}}},
        "random": {"final_kl": {"0": 0.05, "1": 0.2}, "final_kl_overall": 0.125,
                   "wasted_share": 0.25, "wasted_experiments": 30,
                   "experiments_done": [60, 60], "actions_tried": {"2": {"1": 120}}}}}
    table = dr.robot_runs_table(runs)
    assert "| q1 | 0.020 | 0.300 | 0.160 | 0.200 | 3 (3, 2) | 0 of 120 (0 %) |" in table
    assert "| random | 0.050 | 0.200 | 0.125 | not recorded | None () | 30 of 120 (25 %) |" \
           in table


def test_the_skill_counts_stacks_built() -> None:
    data = {"goal_height": 3, "trials": 10, "seed": 100, "max_placements": 12, "models": [
        {"model": "runs/r/q1-s0", "trials": 10, "success_rate": 0.7,
         "placements_per_success": 2.0, "falls": 1},
        {"model": "untrained", "trials": 10, "success_rate": 0.0,
         "placements_per_success": None, "falls": 30}]}
    text = dr.skill_section(data)
    assert "| `runs/r/q1-s0` | 7 / 10 | 2.0 | 1 |" in text
    assert "| `untrained` | 0 / 10 | - | 30 |" in text
    block = dr.render_readme_block({"robot-skill": data})
    assert "learned 7 / 10, untrained 0 / 10" in block


def test_missing_results_read_not_measured_everywhere() -> None:
    text = dr.render_reproducing({})
    for name in ("paper", "robot-truth", "robot-paper", "robot-skill", "baselines"):
        assert f"`python -m katana_paper.docs_report collect {name}`" in text
    block = dr.render_readme_block({})
    assert block.count("not measured") == 2


# -- README.md, collect and the command ----------------------------------------------------


def test_the_readme_block_is_replaced_between_its_markers() -> None:
    text = f"intro\n{dr.README_BEGIN}\nold\n{dr.README_END}\nrest\n"
    assert dr.splice_readme(text, "NEW") == "intro\nNEW\nrest\n"
    with pytest.raises(ValueError, match="no results block"):
        dr.splice_readme("no markers", "NEW")


def _repo(tmp_path: Path) -> Path:
    (tmp_path / "docs").mkdir()
    (tmp_path / "ros2_ws").mkdir()
    (tmp_path / "README.md").write_text(f"# x\n{dr.README_BEGIN}\n{dr.README_END}\n")
    return tmp_path


def test_collect_copies_and_records_the_machine_only_where_missing(tmp_path: Path) -> None:
    root = _repo(tmp_path)
    (root / "runs/paper").mkdir(parents=True)
    (root / "runs/paper/summary.json").write_text(json.dumps(_paper()))
    (root / "bench/results").mkdir(parents=True)
    bench = {"bench": "core", "machine": {"cpu_model": "Bench CPU", "cpus": 2}}
    (root / "bench/results/core.json").write_text(json.dumps(bench))
    dr.collect(root, ["paper", "core"])
    paper = json.loads((root / "docs/results/paper/summary.json").read_text())
    assert paper["provenance"]["collected_from"] == "runs/paper/summary.json"
    assert paper["provenance"]["machine"]["cpu_model"]
    assert json.loads((root / "docs/results/bench/core.json").read_text()) == bench
    with pytest.raises(FileNotFoundError, match="make it with `make robot-paper`"):
        dr.collect(root, ["robot-paper"])
    with pytest.raises(ValueError, match="unknown result"):
        dr.collect(root, ["nonsense"])


def test_check_fails_on_a_stale_page_and_passes_once_written(tmp_path: Path, capsys) -> None:
    root = _repo(tmp_path)
    assert dr.main(["--root", str(root), "--check"]) == 1
    assert "not up to date" in capsys.readouterr().err
    assert dr.main(["--root", str(root)]) == 0
    assert dr.main(["--root", str(root), "--check"]) == 0
    (root / "docs/BENCHMARKS.md").write_text("edited by hand\n")
    assert dr.main(["--root", str(root), "--check"]) == 1
