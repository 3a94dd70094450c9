"""Where a figure comes from: the CPU a result file records and the command that made it,
rebuilt from what the file records, so that a page shows both beside the figure."""

from __future__ import annotations

from .formatting import Json, experiments_of, finite, get, strategies_of
from .sources import SOURCES


def machine_of(data: Json) -> dict | None:
    """The machine a file records: its own (benches) or the one `collect` added."""
    return get(data, "machine") or get(data, "provenance", "machine")


def cpu_text(data: Json) -> str:
    """'<model>, <n> CPUs' of the file's machine, so that a figure names the CPU that made it."""
    machine = machine_of(data)
    if not machine or not machine.get("cpu_model"):
        return "CPU not recorded"
    cpus = machine.get("cpus")
    return f"{machine['cpu_model']}" + (f", {cpus} CPUs" if cpus else "")


def made_by(command: str, data: Json) -> str:
    """The sentence that opens every measured section: the command and the CPU behind it."""
    cpu = cpu_text(data)
    if cpu == "CPU not recorded":
        return f"Made by `{command}` (the file does not record the CPU)."
    return f"Made by `{command}` on {cpu}."


def not_measured(name: str) -> str:
    """What stands in for a missing file: the commands that make it and copy it in."""
    source = SOURCES[name]
    return (f"*Not measured*: there is no `{source.path}`. Make it with `{source.command}`, "
            f"then `python -m katana_paper.docs_report collect {name}`.")


EXPERIMENTS_FLAG = "--experiments"  # katana-curiosity's option for experiments per run
STRATEGIES_FLAG = "--strategies"  # katana-curiosity's and katana-robot's strategy list


def paper_command(data: Json) -> str:
    """The `katana-curiosity paper` command that makes a summary with this file's settings."""
    seeds = get(data, "seeds", default=[]) or []
    params = get(data, "parameters", default={}) or {}
    parts = ["katana-curiosity paper", f"{EXPERIMENTS_FLAG} {experiments_of(data)}",
             f"--seeds {len(seeds)}"]
    if seeds and seeds[0] != 0:
        parts.append(f"--first-seed {seeds[0]}")
    parts.append(f"{STRATEGIES_FLAG} {','.join(strategies_of(data))}")
    for key in ("alpha", "theta", "gamma"):
        if finite(params.get(key)):
            parts.append(f"--{key} {params[key]:g}")
    return " ".join(parts)


def robot_paper_command(data: Json) -> str:
    """The `katana-robot paper` command that makes a summary with this file's settings."""
    seeds = get(data, "seeds", default=[]) or []
    parts = ["katana-robot paper", f"--seeds {len(seeds)}"]
    if seeds and seeds[0] != 0:
        parts.append(f"--seed0 {seeds[0]}")
    parts.append(f"--experiments {get(data, 'experiments')}")
    parts.append(f"{STRATEGIES_FLAG} {','.join(strategies_of(data))}")
    if get(data, "jobs") is not None:
        parts.append(f"--jobs {get(data, 'jobs')}")
    if get(data, "truth"):
        parts.append(f"--truth {get(data, 'truth')}")
    return " ".join(parts)


def skill_command(data: Json) -> str:
    """The `katana-robot skill` command that makes skill trials with this file's settings."""
    models = [m.get("model") for m in get(data, "models", default=[]) or []]
    learned = [m for m in models if m and m != "untrained"]
    parts = ["katana-robot skill", f"--goal-height {get(data, 'goal_height')}",
             f"--trials {get(data, 'trials')}", f"--seed {get(data, 'seed')}",
             f"--max-placements {get(data, 'max_placements')}",
             f"--model {learned[0] if learned else 'RUN_FOLDER'}"]
    if "untrained" not in models:
        parts.append("--no-untrained")
    return " ".join(parts)


def truth_command(data: Json) -> str:
    """The `katana-robot truth` command that measures a truth with this file's settings."""
    m = get(data, "measurement", default={}) or {}
    heights = len(get(data, "p_stable", default={}) or {}) - 1
    parts = ["katana-robot truth", f"--trials {m.get('trials_per_pair')}",
             f"--seed {m.get('seed')}"]
    if heights > 0:
        parts.append(f"--max-height {heights}")
    return " ".join(parts)


def bench_command(data: Json) -> str:
    """The `bench/run.py` command that made this bench file."""
    return f"python bench/run.py {get(data, 'bench', default='?')}"
