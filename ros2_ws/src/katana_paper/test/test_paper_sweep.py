"""Sweeps on a local Ray (2 CPUs, started once for this module): outputs, resume, CLI."""

import csv
import json
from dataclasses import asdict

import numpy as np
import pytest
from katana_paper.curiosity_cli import main
from katana_paper.experiments import RunConfig, run
from katana_paper.ray_session import ray_session as session
from katana_paper.sweep import (
    SweepSpec,
    csv_header,
    parse_grid_axis,
    read_rows,
    run_key,
    run_row,
    run_sweep,
)


@pytest.fixture(scope="module")
def ray_session():
    """One local Ray for the module; run_sweep uses it rather than starting its own."""
    with session(None, num_cpus=2) as ray:
        yield ray


def test_grid_axes_parse_and_bad_ones_are_named() -> None:
    assert parse_grid_axis("alpha=0.5,1,2") == ("alpha", (0.5, 1.0, 2.0))
    assert parse_grid_axis("n_blocks=4,6") == ("n_blocks", (4, 6))
    for text, match in [
        ("beta=1,2", "NAME=V1"),
        ("alpha", "NAME=V1"),
        ("alpha=a,b", "must be floats"),
        ("alpha=1,1", "distinct"),
        ("n_blocks=2.5", "must be ints"),
    ]:
        with pytest.raises(ValueError, match=match):
            parse_grid_axis(text)
    with pytest.raises(ValueError, match="alpha must be"):
        SweepSpec(grid={"alpha": (0.0, 1.0)}, seeds=1, experiments=10)
    with pytest.raises(ValueError, match="unknown strategy"):
        SweepSpec(strategies=("q1", "bogus"))
    spec = SweepSpec(grid={"alpha": (1.0, 2.0), "theta": (0.01, 0.1, 0.2)}, seeds=3)
    assert len(spec.cells()) == 6 and len(spec.configs()) == 6 * 3 * 2


def test_bad_grid_on_the_command_line_is_an_argument_error(tmp_path, capsys) -> None:
    with pytest.raises(SystemExit) as stop:
        main(["sweep", "--grid", "beta=1,2", "--out", str(tmp_path)])
    assert stop.value.code == 2 and "NAME=V1" in capsys.readouterr().err
    assert not (tmp_path / "sweep.csv").exists()


def test_a_row_cut_short_by_a_crash_is_dropped_and_runs_again(tmp_path) -> None:
    spec = SweepSpec(grid={"alpha": (1.0,)}, strategies=("q1",), seeds=2, experiments=100)
    rows = [run_row(asdict(c)) for c in spec.configs()]
    path = tmp_path / "sweep.csv"
    header = csv_header(spec)
    with open(path, "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=header, extrasaction="ignore")
        writer.writeheader()
        writer.writerow(rows[0])
    text = path.read_text()
    path.write_text(text + ",".join(str(rows[1][k]) for k in header)[:25])  # killed mid-write
    kept = read_rows(path)
    assert [run_key(r) for r in kept] == [run_key(rows[0])]
    assert path.read_text() == text, "the cut line is gone, appends start on a new line"


def test_a_sweep_csv_of_before_the_renaming_is_resumed(tmp_path) -> None:
    """Columns "method" and "steps" (now "strategy" and "experiments"): its runs are reused,
    read under the names of now; nothing runs again (so no Ray is started)."""
    spec = SweepSpec(grid={"alpha": (1.0,)}, strategies=("q1",), seeds=2, experiments=100)
    rows = [run_row(asdict(c)) for c in spec.configs()]
    old = {"strategy": "method", "experiments": "steps"}
    header = [old.get(k, k) for k in csv_header(spec)]
    out = tmp_path / "old"
    out.mkdir()
    with open(out / "sweep.csv", "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=header, extrasaction="ignore")
        writer.writeheader()
        for row in rows:
            writer.writerow({old.get(k, k): v for k, v in row.items()})
    assert [run_key(r) for r in read_rows(out / "sweep.csv")] == [run_key(r) for r in rows]
    summary = run_sweep(spec, out, progress=False, figures=False)
    assert (summary["ran"], summary["reused"]) == (0, 2)
    assert summary["cells"][0]["strategies"]["q1"]["final_kl_overall"]["n"] == 2


class Interrupt(Exception):
    pass


def test_tiny_sweep_writes_its_outputs_and_resumes_after_an_interruption(
    ray_session, tmp_path
) -> None:
    spec = SweepSpec(
        grid={"alpha": (0.5, 2.0)}, strategies=("q1", "random"), seeds=2, experiments=300
    )
    out = tmp_path / "sweep"

    def stop_after_three(row, seen=[]):  # noqa: B006  (a counter across calls)
        seen.append(row)
        if len(seen) == 3:
            raise Interrupt

    with pytest.raises(Interrupt):
        run_sweep(spec, out, progress=False, on_row=stop_after_three)
    assert len(read_rows(out / "sweep.csv")) == 3, "finished runs were kept"

    summary = run_sweep(spec, out, progress=False)
    assert (summary["ran"], summary["reused"]) == (5, 3)
    rows = read_rows(out / "sweep.csv")
    assert len(rows) == 8 and len({run_key(r) for r in rows}) == 8

    # every row is the run it names, computed again here without Ray
    for row in rows[:2]:
        config = RunConfig(
            strategy=row["strategy"],
            seed=int(row["seed"]),
            experiments=300,
            alpha=float(row["alpha"]),
            theta=float(row["theta"]),
        )
        result = run(config)
        assert float(row["final_kl_overall"]) == pytest.approx(result.kl[-1].mean(), rel=1e-12)
        assert int(row["queries"]) == int(np.sum(result.modes == 0))

    saved = json.loads((out / "summary.json").read_text())
    assert saved["runs"] == 8 and saved["grid"] == {"alpha": [0.5, 2.0]}
    for strategy in ("q1", "random"):
        for alpha in ("0.5", "2.0"):
            kl = [
                float(r["final_kl_overall"])
                for r in rows
                if r["strategy"] == strategy and float(r["alpha"]) == float(alpha)
            ]
            stats = saved["by_parameter"]["alpha"][strategy][alpha]
            assert stats["n"] == 2 and stats["mean"] == pytest.approx(np.mean(kl))
            assert stats["std"] == pytest.approx(np.std(kl))
    png = (out / "sensitivity.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 10_000

    again = run_sweep(spec, out, progress=False, figures=False)
    assert (again["ran"], again["reused"]) == (0, 8)
    with open(out / "sweep.csv") as f:
        assert len(list(csv.reader(f))) == 9, "nothing appended on a complete resume"


def test_sweep_command_runs_on_the_session(ray_session, tmp_path, capsys) -> None:
    out = tmp_path / "cli"
    # --methods and --steps: the old spellings of --strategies and --experiments
    argv = ["sweep", "--grid", "theta=0.01,0.1", "--methods", "q1", "--seeds", "1"]
    assert main([*argv, "--steps", "200", "--out", str(out), "--no-figures"]) == 0
    rows = read_rows(out / "sweep.csv")
    assert sorted(float(r["theta"]) for r in rows) == [0.01, 0.1]
    assert {r["alpha"] for r in rows} == {"1.0"}, "alpha fixed at its default"
    assert "2 runs now, 0 from" in capsys.readouterr().out
    assert not (out / "sensitivity.png").exists()
