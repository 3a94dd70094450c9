"""Metrics against brute force, runs of the abstract world, and the paper command's outputs."""

import csv
import json
import subprocess
import sys

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from katana_curiosity.core.explorer import PLAN, QUERY
from katana_paper.curiosity_cli import build_parser, main
from katana_paper.experiments import RunConfig, run, summarise
from katana_paper.metrics import (
    bernoulli_kl,
    cumulative_by_state,
    direct_exploration_end,
    experience_histogram,
    model_kl,
)


@settings(max_examples=50, deadline=None)
@given(p=st.floats(0.0, 1.0), q=st.floats(0.001, 0.999))
def test_bernoulli_kl_matches_the_definition(p: float, q: float) -> None:
    expected = sum(pi * np.log(pi / qi) for pi, qi in ((p, q), (1 - p, 1 - q)) if pi > 0)
    assert bernoulli_kl(p, q) == pytest.approx(expected, abs=1e-12)
    assert bernoulli_kl(p, q) >= 0


def test_model_kl_is_zero_for_the_true_model_and_finite_outside_the_unit_interval() -> None:
    rng = np.random.default_rng(0)
    true = rng.uniform(-0.9, 0.9, (3, 21))
    assert np.allclose(model_kl(true, true), 0.0, atol=1e-12)
    learned = true + 0.2
    assert np.all(model_kl(true, learned) > 0)
    assert np.all(np.isfinite(model_kl(true, np.full((3, 21), 5.0))))


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 1000))
def test_cumulative_counts_and_histograms_match_brute_force(seed: int) -> None:
    rng = np.random.default_rng(seed)
    states = rng.integers(0, 5, 200)
    actions = rng.integers(0, 7, 200)
    modes = rng.integers(0, 3, 200)
    at = np.array([0, 1, 50, 199, 200])
    got = cumulative_by_state(states, modes == QUERY, 5, at)
    for i, t in enumerate(at):
        for s in range(5):
            assert got[i, s] == sum(1 for k in range(t) if states[k] == s and modes[k] == QUERY)
    hist = experience_histogram(states, actions, 3, 7, 120)
    assert hist.tolist() == [
        sum(1 for k in range(120) if states[k] == 3 and actions[k] == a) for a in range(7)
    ]
    end = direct_exploration_end(states, modes, 2)
    hits = [k for k in range(200) if states[k] == 2 and modes[k] == QUERY]
    assert end == (hits[-1] + 1 if hits else -1)


def test_run_records_are_consistent() -> None:
    result = run(
        RunConfig(strategy="q1", seed=1, experiments=700, record_every=100, snapshots=(200,))
    )
    assert result.record_at.tolist() == [0, 100, 200, 300, 400, 500, 600, 700]
    assert result.kl.shape == (8, 7)
    assert result.snapshot_at.tolist() == [200, 700]
    assert set(np.unique(result.labels)) <= {-1, 1}
    assert np.all(result.labels[result.states == 0] == 1), "the table is always stable"
    direct = result.cumulative(QUERY)
    planned = result.cumulative(PLAN)
    assert direct[-1].sum() + planned[-1].sum() == 700


def test_paper_command_writes_summary_csv_and_figures(tmp_path) -> None:
    out = tmp_path / "paper"
    code = main(
        [
            "paper",
            "--experiments",
            "300",
            "--seeds",
            "2",
            "--jobs",
            "2",
            "--strategies",
            "q1,random",
            "--out",
            str(out),
        ]
    )
    assert code == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["experiments"] == 300 and summary["seeds"] == [0, 1]
    for strategy in ("q1", "random"):
        m = summary["strategies"][strategy]
        assert sorted(m["final_kl"], key=int) == [str(h) for h in range(1, 8)]
        assert m["final_kl_overall"] == pytest.approx(np.mean(list(m["final_kl"].values())))
    for name in ("fig4", "fig5", "fig6", "fig7", "fig8", "fig9"):
        data = (out / f"{name}.png").read_bytes()
        assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 10_000
    with open(out / "runs" / "q1_seed1.csv") as f:
        rows = list(csv.DictReader(f))
    assert rows[-1]["experiment"] == "300"
    total = sum(int(rows[-1][f"direct_{s}"]) + int(rows[-1][f"planned_{s}"]) for s in range(8))
    assert total == 300


def test_summary_matches_the_runs() -> None:
    results = [run(RunConfig(strategy="q1", seed=s, experiments=200)) for s in (0, 1)]
    summary = summarise(results)
    final = np.mean([r.kl[-1] for r in results], axis=0)
    assert summary["strategies"]["q1"]["final_kl"]["3"] == pytest.approx(final[2])


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--strategies", "q1,bogus"], "unknown strategy"),
        (["--methods", "q1,bogus"], "unknown strategy"),
        (["--experiments", "0"], "must be >= 1"),
        (["--steps", "0"], "must be >= 1"),
        (["--theta", "1.5"], "must be in [0, 1]"),
        (["--alpha", "-1"], "must be > 0"),
        (["--gamma", "1.0"], "--gamma"),
    ],
)
def test_invalid_cli_arguments_give_a_clear_error(tmp_path, args, message) -> None:
    proc = subprocess.run(
        [sys.executable, "-m", "katana_paper", "paper", "--out", str(tmp_path), *args],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert proc.returncode == 2
    assert message in proc.stderr
    assert not (tmp_path / "summary.json").exists()


@pytest.mark.parametrize("command", ["paper", "explore", "sweep"])
@pytest.mark.parametrize(
    "args, option",
    [
        (["--first-seed", "-1"], "--first-seed"),
        (["--out", "/proc/no/such/folder"], "--out"),
        (["--gamma", "1.5"], "--gamma"),
    ],
)
def test_every_option_is_checked_before_any_work(tmp_path, capsys, command, args, option):
    """One line naming the option, the subcommand's usage, exit 2, nothing written."""
    out = ["--out", str(tmp_path / "run")] if "--out" not in args else []
    grid = ["--grid", "alpha=1"] if command == "sweep" else []
    with pytest.raises(SystemExit) as exit_info:
        main([command, *grid, *out, *args])
    assert exit_info.value.code == 2
    err = capsys.readouterr().err
    assert f"katana-curiosity {command}: error: argument {option}" in err
    assert f"usage: katana-curiosity {command}" in err
    assert not (tmp_path / "run" / "summary.json").exists()


@pytest.mark.parametrize("seed", range(6))
def test_q1_reaches_height_five_within_a_bounded_number_of_experiments(seed: int) -> None:
    result = run(RunConfig(strategy="q1", seed=seed, experiments=1000))
    assert result.states.max() >= 5


def test_planned_outcomes_also_update_the_model() -> None:
    result = run(RunConfig(strategy="conf", seed=0, experiments=300))
    assert np.all(result.modes == PLAN)
    assert np.any(result.kl[-1] < result.kl[0]), "learning happened from planned experiments alone"


@pytest.mark.parametrize("strategy", ["q1", "q10", "conf", "random"])
def test_same_seed_same_results(strategy: str) -> None:
    a = run(RunConfig(strategy=strategy, seed=4, experiments=600))
    b = run(RunConfig(strategy=strategy, seed=4, experiments=600))
    for name in ("states", "actions", "modes", "labels", "kl"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    c = run(RunConfig(strategy=strategy, seed=5, experiments=600))
    assert not np.array_equal(a.states, c.states)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"strategy": "q2"}, "unknown strategy"),
        ({"experiments": 0}, "experiments"),
        ({"alpha": -1.0}, "alpha"),
        ({"theta": 2.0}, "theta"),
        ({"gamma": 1.0}, "gamma"),
    ],
)
def test_invalid_run_arguments_give_a_clear_error(kwargs, match) -> None:
    with pytest.raises(ValueError, match=match):
        RunConfig(**kwargs)


def test_the_old_option_spellings_still_work(tmp_path) -> None:
    """--steps and --methods, the names of before "experiments" and "strategies"."""
    args = build_parser().parse_args(
        ["paper", "--steps", "5", "--methods", "q1,random", "--out", str(tmp_path)]
    )
    assert args.experiments == 5 and args.strategies == ["q1", "random"]
