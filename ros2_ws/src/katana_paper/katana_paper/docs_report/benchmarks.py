"""docs/BENCHMARKS.md: each bench's figures beside a floor or baseline from the same run,
its command and its CPU, or "not measured" where its file is missing."""

from __future__ import annotations

from collections.abc import Mapping

from .formatting import (
    NONE_MEASURED,
    NOT_RECORDED,
    Json,
    display,
    finite,
    get,
    met_text,
    num,
    ratio,
    table,
)
from .provenance import bench_command, machine_of, made_by, not_measured
from .sources import BENCHES, GENERATED

SPEED_HEADER = ("figure", "measured", "floor or baseline, same run", "ratio", "target")


def bench_core(data: Json) -> str:
    """The curiosity core's speeds beside the NumPy reference and the CPU time of the same run."""
    rows = []
    for s in ("q1", "q10", "conf", "random"):
        rate, ref = get(data, "steps_per_s", s), get(data, "reference_steps_per_s", s)
        slowest = get(data, "steps_per_s_floor", s)
        target = "-"
        if s == "q1":
            target = met_text(slowest, get(data, "targets", "q1_steps_per_s"), at_most=False)
            target += ", by the slowest run" if target != "-" else ""
        elif finite(get(data, "targets", f"{s}_speedup_over_reference")):
            t = get(data, "targets", f"{s}_speedup_over_reference")
            ok = finite(rate) and finite(ref) and ref > 0 and rate / ref >= t
            target = f"{t:g}x ({'met' if ok else 'not met'})"
        rows.append((f"{display(s)} steps per second, compiled path, median of 3 runs "
                     f"(slowest {num(slowest)})", num(rate), f"NumPy reference: {num(ref)}",
                     ratio(rate, ref, 1), target))
    loop, end = get(data, "steps_per_s", "q1"), get(data, "run_steps_per_s", "q1")
    rows.append(("Q1 steps per second through `experiments.run` (KL every 50 steps)",
                 num(end), f"the compiled loop alone: {num(loop)}", ratio(loop, end), "-"))
    wall, cpu = get(data, "paper_default_wall_s"), get(data, "paper_default_cpu_s")
    cpus = get(machine_of(data), "cpus")
    floor = cpu / cpus if finite(cpu) and finite(cpus) and cpus else None
    rows.append((f"`katana-curiosity paper --jobs 2` with its defaults, wall s, median of 3 "
                 f"(slowest {num(get(data, 'paper_default_wall_s_max'), 2)})", num(wall, 2),
                 f"its CPU time over the {cpus} CPUs: {num(cpu, 2)} / {cpus} = {num(floor, 2)}",
                 ratio(wall, floor), met_text(wall, get(data, "targets", "paper_default_wall_s"))))
    rows.append(("one planning call after a model update (warm start), ms",
                 num(get(data, "plan_ms"), 4), NONE_MEASURED, "-", "-"))
    rows.append(("one planning call from a fresh planner, ms", num(get(data, "plan_cold_ms"), 4),
                 NONE_MEASURED, "-", "-"))
    rows.append(("first fast run after a checkout (compiles the loop into an empty cache), s",
                 num(get(data, "fast_path_cold_compile_s"), 2), NONE_MEASURED, "-", "-"))
    return table(SPEED_HEADER, rows)


def bench_perception(data: Json) -> str:
    """Segmentation beside one colour conversion of the frame, and the other vision timings."""
    floor = get(data, "perception_floor_ms")
    seg, seg8 = get(data, "perception_ms"), get(data, "perception_8_blocks_ms")
    observe, observe_ref = get(data, "observe_ms"), get(data, "observe_reference_ms")
    rows = [
        (f"segmentation of one {get(data, 'image', default='')} frame, 4 blocks, ms", num(seg),
         f"one colour conversion of the frame: {num(floor)}", ratio(seg, floor),
         met_text(seg, get(data, "perception_target_ms"))),
        ("segmentation of a frame of 8 blocks, ms", num(seg8),
         f"the same conversion: {num(floor)}", ratio(seg8, floor), "-"),
        (f"fovea/observe of a 4-block setting ({get(data, 'observe_instances')} instances, "
         f"{_identical(get(data, 'observe_identical_to_reference'))}), ms", num(observe),
         f"its reference twin (`FoveaSceneReference`): {num(observe_ref)}",
         ratio(observe, observe_ref), met_text(observe, get(data, "observe_target_ms"))),
        ("one placement judgement, ms", num(get(data, "judge_ms")), NONE_MEASURED, "-", "-"),
        ("the reach table fovea_node computes at start-up, ms",
         num(get(data, "reach_table_ms"), 1), NONE_MEASURED, "-", "-"),
        ("one camera frame written into an MCAP recording, its chunk zstd-compressed and "
         "flushed, ms",
         num(get(data, "record_frame_ms")), NONE_MEASURED, "-", "-"),
    ]
    return (table(SPEED_HEADER, rows) + "\n\nFrames from the "
            f"{get(data, 'frames', default=NOT_RECORDED)} renderer.")


def _identical(same: Json) -> str:
    if same is None:
        return "not compared with its reference"
    return "the same as its reference's" if same else "NOT the same as its reference's"


def bench_sim(data: Json) -> str:
    """Render time, physics speed and pick-and-places of the simulation, against its targets."""
    targets = get(data, "targets", default={}) or {}
    pp = get(data, "pick_place_s")
    rows = [
        ("render one 640x480 frame, ms", num(get(data, "render_ms"), 1), NONE_MEASURED, "-",
         met_text(get(data, "render_ms"), targets.get("render_ms"))),
        ("simulated seconds per wall second, arm moving, no rendering",
         num(get(data, "real_time_factor"), 1), NONE_MEASURED, "-", "-"),
        (f"one pick-and-place through the action, real_time_factor 0, s (succeeded: "
         f"{get(data, 'pick_place_succeeded')} of {get(data, 'pick_place_runs')})", num(pp),
         "none here (the arm bench measures one)", "-", met_text(pp, targets.get("pick_place_s"))),
        ("simulated seconds per wall second during those pick-and-places",
         num(get(data, "pick_place_real_time_factor"), 1), NONE_MEASURED, "-", "-"),
    ]
    return table(SPEED_HEADER, rows)


def bench_arm(data: Json) -> str:
    """Pick-and-places through ROS beside the same motions without ROS: speed and precision."""
    targets = get(data, "targets", default={}) or {}
    phys = get(data, "physics_only", default={}) or {}
    err, perr = get(data, "placement_error_mm"), get(phys, "placement_error_mm")
    pp, floor = get(data, "pick_place_s"), get(data, "physics_only_s")
    speed = table(SPEED_HEADER, [
        ("one pick-and-place through the action, real_time_factor 0, wall s (median)", num(pp),
         f"the same motions stepped without ROS: {num(floor)}", ratio(pp, floor),
         met_text(pp, targets.get("pick_place_s")))])
    rows = [
        ("placement error p95, mm", num(get(err, "p95"), 2), num(get(perr, "p95"), 2),
         met_text(get(err, "p95"), targets.get("placement_error_mm.p95"))),
        ("placement error median / max, mm",
         f"{num(get(err, 'median'), 2)} / {num(get(err, 'max'), 2)}",
         f"{num(get(perr, 'median'), 2)} / {num(get(perr, 'max'), 2)}", "-"),
        ("pick success", num(get(data, "pick_success")), num(get(phys, "pick_success")),
         met_text(get(data, "pick_success"), targets.get("pick_success"), at_most=False)),
    ]
    stable = get(data, "action6_stable", default={}) or {}
    for h in sorted(stable, key=int):
        rows.append((f"action-6 placements that stayed, height {h}", num(stable[h]),
                     num(get(phys, "action6_stable", h)),
                     met_text(stable[h], targets.get("action6_stable"), at_most=False)))
    precision = table(("figure", f"through ROS ({get(data, 'runs')} goals)",
                       "physics only, same trials", "target"), rows)
    same = get(data, "same_outcomes_as_physics_only")
    same_text = "yes" if same else "no" if same is not None else NOT_RECORDED
    lines = [speed, "", precision, "",
             f"Simulated seconds per pick-and-place: {num(get(data, 'sim_s_per_pick_place'), 2)}."
             f" The same outcome as physics only, trial by trial: {same_text}."]
    failures = get(data, "failures", default=[]) or []
    if failures:
        lines.append("Failed goals: " + "; ".join(f"`{f}`" for f in failures) + ".")
    return "\n".join(lines)


def bench_loop(data: Json) -> str:
    """Seconds per experiment beside the work it runs on, the stages and the dropped attempts."""
    targets = get(data, "targets", default={}) or {}
    spe, floor = get(data, "s_per_experiment"), get(data, "experiment_floor_s")
    two = get(data, "experiment_floor_two_images_s")
    dropped = get(data, "dropped_experiments", default={}) or {}
    if isinstance(dropped.get("by_reason"), Mapping):  # {"total", "by_reason", "fraction_..."}
        reasons = dict(dropped["by_reason"])
    else:  # a flat {reason: count}
        reasons = {k: v for k, v in dropped.items() if finite(v)}
    n_dropped = sum(v for v in reasons.values() if finite(v))
    n = get(data, "experiments")
    share = n_dropped / (n + n_dropped) if finite(n) and n + n_dropped else None
    rows = [
        ("seconds per experiment, the whole loop in one process (median)", num(spe, 2),
         f"physics, renders, segmentation, judge and fovea in the same windows: {num(floor, 2)}",
         ratio(spe, floor),
         "; ".join(t for t in (
             met_text(spe, targets.get("s_per_experiment")),
             "ratio " + met_text(spe / floor if finite(spe) and finite(floor) and floor else None,
                                 targets.get("overhead_ratio"))
             if finite(targets.get("overhead_ratio")) else "") if t and t != "-") or "-"),
        ("the same, against only the two images an experiment needs", num(spe, 2),
         num(two, 2), ratio(spe, two), "-"),
    ]
    out = [table(SPEED_HEADER, rows), ""]
    stages = get(data, "stage_median_s", default={}) or {}
    if stages:
        out += ["Stage medians as the curiosity node logs them:", "",
                table(("stage", "median s"), [(f"`{k}`", num(v)) for k, v in stages.items()]),
                ""]
    floors = get(data, "floor_median_s", default={}) or {}
    if floors:
        out += ["The floor by kind of work, median per experiment:", "",
                table(("work", "median s"), [(k, num(v)) for k, v in floors.items()]), ""]
    drop_text = ", ".join(f"{v} {k}" for k, v in reasons.items()) or "none"
    out.append(
        f"{num(n)} experiments logged; attempts dropped: {drop_text} (a share of "
        f"{num(share, 2)}; target at most {num(targets.get('dropped_fraction'), 2)}). "
        f"Camera at {num(get(data, 'camera_rate_hz'), 1)} Hz of sim time; "
        f"{num(get(data, 'renders_per_experiment'), 1)} renders and "
        f"{num(get(data, 'segmentations_per_experiment'), 1)} segmentations per experiment. "
        f"Highest stack {get(data, 'highest_stack')}; heights explored "
        f"{get(data, 'heights_explored')}.")
    physics_steps = get(data, "physics_steps_per_experiment")
    free_steps = get(data, "kinematic_steps_per_experiment")
    if finite(physics_steps) and finite(free_steps):
        out[-1] += (f" {num(physics_steps, 0)} physics steps per experiment, and "
                    f"{num(free_steps, 0)} steps the arm crossed free space without physics "
                    "(the run's mean, its start-up included).")
    return "\n".join(out)


def bench_loop_hardware(data: Json) -> str:
    """Seconds per experiment against the emulator beside the arm's motion in it, and that
    motion beside the least time its limits allow."""
    targets = get(data, "targets", default={}) or {}
    spe, motion, least = (get(data, k) for k in ("s_per_experiment", "motion_s", "motion_min_s"))
    over = targets.get("overhead_s")
    rows = [
        ("seconds per experiment, real time (median)", num(spe, 2),
         f"the arm's motion per experiment: {num(motion, 2)}", ratio(spe, motion),
         f"at most motion + {num(over, 1)} s" + ((" (met)" if spe <= motion + over else
                                                   " (not met)")
                                                  if finite(spe) and finite(motion)
                                                  and finite(over) else "")),
        ("the arm's motion per experiment, s (median)", num(motion, 2),
         f"the least its speed and acceleration limits allow on the same paths: {num(least, 2)}",
         ratio(motion, least), met_text(get(data, "motion_over_min"),
                                        targets.get("motion_over_min"))),
    ]
    out = [table(SPEED_HEADER, rows), ""]
    stages = get(data, "stage_median_s", default={}) or {}
    if stages:
        out += ["Stage medians as the curiosity node logs them:", "",
                table(("stage", "median s"), [(f"`{k}`", num(v)) for k, v in stages.items()]),
                ""]
    out.append(f"{num(get(data, 'experiments'))} gaps between logged experiments; "
               f"{num(get(data, 'moves_per_experiment'), 1)} arm moves per experiment.")
    fingers, still = get(data, "finger_motion_s"), get(data, "still_s")
    if finite(fingers) and finite(still):
        out[-1] += (f" The fingers moved {num(fingers, 2)} s per experiment (median; the arm "
                    "stands meanwhile: motor 6 holds in every spline row), and no motor moved "
                    f"for {num(still, 2)} s (median).")
    steps = get(data, "still_by_step_s", default={}) or {}
    if steps:
        out += ["", "Where the still time falls, seconds per experiment (medians):", "",
                table(("between", "median s"), [(k, num(v, 2)) for k, v in steps.items()])]
    return "\n".join(out)


SOAK_RUN = 1000  # the run the soak's targets are set for


def bench_soak(data: Json) -> str:
    """A long run's last block of experiments beside its first: speed, memory, log writes."""
    targets = get(data, "targets", default={}) or {}
    blocks = get(data, "per_block", default=[]) or []
    first = blocks[0] if blocks else {}
    last = blocks[-1] if blocks else {}
    n = get(data, "experiments")
    rows = [
        (f"seconds per experiment, experiments {last.get('experiments', '?')} (median)",
         num(last.get("s_per_experiment"), 2),
         f"experiments {first.get('experiments', '?')}: {num(first.get('s_per_experiment'), 2)}",
         ratio(last.get("s_per_experiment"), first.get("s_per_experiment")),
         "at most " + f"{targets.get('last_over_first_s_per_experiment', float('nan')):g}x"
         if finite(targets.get("last_over_first_s_per_experiment")) else "-"),
        ("overhead ratio, the last block (its seconds per experiment over its floor: the time "
         "in physics, renders, segmentation, the judge and the fovea)",
         num(last.get("overhead_ratio"), 2),
         f"experiments {first.get('experiments', '?')}: {num(first.get('overhead_ratio'), 2)}",
         ratio(last.get("overhead_ratio"), first.get("overhead_ratio")), "-"),
        ("resident memory of the process at the last block's end, MiB",
         num(last.get("rss_mib_at_end"), 1),
         f"at the first block's end: {num(first.get('rss_mib_at_end'), 1)}",
         f"+{num(get(data, 'rss_growth_mib'), 1)} MiB",
         met_text(get(data, "rss_growth_mib"), targets.get("rss_growth_mib"))
         if finite(n) and n >= SOAK_RUN else
         f"under {num(targets.get('rss_growth_mib'), 0)} MiB over {SOAK_RUN:,} experiments; "
         f"this run made {num(n)}: not judged"),
        ("the log's append (write, flush, fsync), ms (median)",
         num(last.get("log_append_ms")), f"first block: {num(first.get('log_append_ms'))}",
         ratio(last.get("log_append_ms"), first.get("log_append_ms")), "-"),
        ("the checkpoint's save, ms (median)", num(last.get("checkpoint_save_ms")),
         f"first block: {num(first.get('checkpoint_save_ms'))}",
         ratio(last.get("checkpoint_save_ms"), first.get("checkpoint_save_ms")), "-"),
    ]
    per = table(("experiments", "s per experiment", "floor s", "RSS MiB", "log append ms",
                 "log bytes", "checkpoint ms", "checkpoint bytes"),
                [(b.get("experiments"), num(b.get("s_per_experiment"), 2),
                  num(b.get("floor_s"), 2), num(b.get("rss_mib_at_end"), 1),
                  num(b.get("log_append_ms")),
                  num(b.get("log_append_bytes"), 0), num(b.get("checkpoint_save_ms")),
                  num(b.get("checkpoint_bytes"), 0)) for b in blocks])
    return "\n".join([table(SPEED_HEADER, rows), "", "Per block:", "", per])


def bench_record(data: Json) -> str:
    """The loop with a recorder beside the same loop without one, and the recorder's own time."""
    without = get(data, "s_per_experiment_without_recording")
    with_rec = get(data, "s_per_experiment_with_recording")
    target = get(data, "targets", "overhead_fraction")
    overhead = get(data, "overhead_fraction")
    own = get(data, "record_s_per_experiment")
    rows = [
        ("seconds per experiment with `--record` (median)", num(with_rec, 3),
         f"the same loop without recording: {num(without, 3)}", ratio(with_rec, without, 3),
         f"overhead {num(overhead, 3)}; under {num(target, 2)}"
         + ((" (met)" if overhead < target else " (not met)")
            if finite(overhead) and finite(target) else "")),
        ("time inside the recorder's writes and flushes, s per experiment", num(own, 4),
         f"the experiment with recording: {num(with_rec, 3)}", ratio(own, with_rec, 4),
         "-"),
    ]
    files = get(data, "recorded_messages_per_run", default=[]) or []
    mib = get(data, "recorded_mib_per_run", default=[]) or []
    return "\n".join([table(SPEED_HEADER, rows), "", (
        f"{num(get(data, 'runs'))} runs of {num(get(data, 'experiments_per_run'))} experiments, "
        f"alternately without and with recording; each recording held "
        f"{', '.join(num(n) for n in files) or NOT_RECORDED} messages in "
        f"{', '.join(num(m, 2) for m in mib) or NOT_RECORDED} MiB.")])


def bench_driver(data: Json) -> str:
    """The driver's reads and state rates beside the emulator's own share, shutdowns and faults."""
    handle = get(data, "emulator_handle_ms")
    rows = [
        ("position read over TCP, round trip, ms (median)", num(get(data, "request_ms"), 4),
         f"the emulator's handling of it alone: {num(handle, 4)}",
         ratio(get(data, "request_ms"), handle, 1), "below 1"),
        ("the same, p95, ms", num(get(data, "request_p95_ms"), 4), num(handle, 4),
         ratio(get(data, "request_p95_ms"), handle, 1), "-"),
        ("position read over a pseudo-terminal (serial transport), ms",
         num(get(data, "serial_request_ms"), 4), num(handle, 4),
         ratio(get(data, "serial_request_ms"), handle, 1), "-"),
    ]
    poll = get(data, "poll_rate_hz")
    for key, what in (("state_hz", "idle, by arrival"), ("state_hz_from_stamps", "idle, by stamp"),
                      ("state_hz_moving", "moving, by arrival"),
                      ("state_hz_moving_from_stamps", "moving, by stamp")):
        rows.append((f"joint_states rate, {what}, Hz", num(get(data, key), 2),
                     f"the configured poll rate: {num(poll, 1)}", ratio(get(data, key), poll),
                     f"at least {num(poll, 1)}" if finite(poll) else "-"))
    out = [table(SPEED_HEADER, rows)]
    shutdown = get(data, "shutdown_s", default={}) or {}
    if shutdown:
        out += ["", "Seconds from the signal to the end of the process (target at most 2):", "",
                table(("process and signal", "s"), [(k, num(v)) for k, v in shutdown.items()])]
    faults = get(data, "faults", default={}) or {}
    if faults:
        out += ["", "One trajectory goal under each fault of the emulator (targets: 0 duplicated "
                "segments and a largest speed ratio of at most 1.05):", "",
                table(("fault", "duplicated segments", "largest speed ratio", "goal ended",
                       "next goal"),
                      [(k, get(v, "duplicated_segments"), num(get(v, "max_speed_ratio")),
                        get(v, "outcome"), get(v, "next_goal")) for k, v in faults.items()])]
    return "\n".join(out)


BENCH_RENDER = {"core": bench_core, "perception": bench_perception, "sim": bench_sim,
                "arm": bench_arm, "loop": bench_loop, "soak": bench_soak,
                "record": bench_record, "driver": bench_driver,
                "loop_hardware": bench_loop_hardware}


def render_benchmarks(results: Mapping) -> str:
    """BENCHMARKS.md: every bench in order, measured or with the command that measures it."""
    parts = [GENERATED, "", BENCHMARKS_INTRO]
    for name in BENCHES:
        title, about = BENCH_ABOUT[name]
        parts += ["", f"## {name}: {title}", "", about, ""]
        data = results.get(name)
        if data is None:
            parts.append(not_measured(name))
            continue
        took = get(data, "bench_wall_s")
        parts.append(made_by(bench_command(data), data)
                     + (f" The bench took {num(took, 1)} s." if finite(took) else ""))
        parts += ["", BENCH_RENDER[name](data)]
    return "\n".join(parts).rstrip() + "\n"


BENCHMARKS_INTRO = """\
# Benchmarks

What each benchmark measures, and the figures it gave. `make bench` runs every bench;
`python bench/run.py NAME ...` runs some of them (core, perception, sim, arm, loop, soak, record,
driver, loop_hardware).
Each writes `bench/results/NAME.json`, which records the machine it ran on (`machine.cpu_model`,
`machine.cpus`). The figures below come from the committed copies of those files in
`docs/results/bench/` (`python -m katana_paper.docs_report collect NAME` copies one there and
rewrites this page).

Every speed figure stands beside a floor or a baseline measured in the same run, and their
ratio: the floor is the same work without the overhead under test, so the ratio carries over
from one machine to another better than the figure itself. Where a bench measures no floor,
the table says so. Times depend on the CPU and on what else runs at the time, so across
machines compare the ratios, and read small differences between runs as noise."""

BENCH_ABOUT: dict[str, tuple[str, str]] = {
    "core": ("the curiosity core", """\
`bench/bench_core.py`. Steps per second of Q1, Q10, Conf and Random in the abstract blocks
world, one process: on the compiled fast path (`katana_curiosity.core.fastpath`, one
numba-compiled loop over world, query scan, RLS update and LSPI, which `katana-curiosity` uses)
and on the NumPy reference (`Explorer.step`) over the same seeds. The two make identical
trajectories (a test checks queries, modes and labels at every step and the weights to 1e-9).
Also: one planning call, the default `katana-curiosity paper` run (its wall time beside its
CPU time spread over the machine's CPUs), and the one-time compilation after a checkout
(cached in `__pycache__` afterwards)."""),
    "perception": ("the vision core", """\
`bench/bench_perception.py`. Milliseconds, medians over repetitions: the segmentation of one
camera frame beside its floor (the one colour conversion every segmentation starts with),
`fovea/observe` of a 4-block setting beside its reference twin (the features computed as first
written: every pixel of each nearby stack turned into the fovea frame and OpenCV's hull of the
intersection pixels, at every location; the two are timed in alternation in the same run and
must give the same instances), one placement judgement, the reach table `fovea_node` computes
at start-up, and writing one camera frame into an MCAP recording (its chunk closed:
zstd-compressed, indexed and handed to the OS)."""),
    "sim": ("the PyBullet simulation", """\
`bench/bench_sim.py`. One 640x480 render, physics speed with the arm moving, and whole
pick-and-places through the `pick_and_place` action (`sim_node` and `pick_place_executor` in
one process, `real_time_factor` 0: the physics steps only inside the motions, as fast as it
can). The arm bench measures pick-and-places in depth, with their floor."""),
    "arm": ("the arm's precision and speed", """\
`bench/bench_arm.py`. Pick-and-places through the `pick_and_place` action on the fast sim,
drawn at random over the reach of each height (`katana_manipulation.core.reach`), onto the
table and onto stacks of 1-3, each goal an action-6 placement (all five fovea points on the
block below). Each trial is run twice: just before it goes through ROS, the same motions are
stepped in `PhysicsSim` without ROS, the floor, so both see the same load. Precision is read
from the simulator's ground truth: the placed block's distance from the commanded centre, and
whether it stayed (level h + 1, the stack below intact) one simulated second later."""),
    "loop": ("the whole experiment loop", """\
`bench/bench_loop.py`. `katana-demo` with seed 0 in the bench's own process (every node in one
process, headless, fast sim) for 31 experiments. Seconds per experiment is the median wall time
between consecutive logged experiments, dropped attempts included. The floor is measured on
the same experiments: the time spent inside the work the loop runs on (physics steps, camera
renders, segmentation, the judge and the fovea), summed per experiment; the ratio is the
loop's overhead (waits, ROS transport). Renders beyond the two images an experiment needs are
counted apart: they are work nobody uses."""),
    "soak": ("the loop over a long run", """\
`bench/bench_soak.py`. `katana-demo` with seed 0 in the bench's own process, as the loop bench
runs it, for many experiments (`SOAK_EXPERIMENTS`, 1,000 by default). Per block of 100: the
median seconds per experiment, the process's resident memory (every node is in it) when the
block's last experiment was logged, and the median time and bytes of the experience log's
append and of the checkpoint's save. The first block is the floor of the last: a loop that
slows, grows or writes more as its log grows shows it there."""),
    "record": ("what recording costs the loop", """\
`bench/bench_record.py`. `katana-demo` with seed 0 in the bench's own process, as the loop
bench runs it, four times alternately without and with `--record FILE.mcap` (the default
recorder: images at 2 Hz of the node's clock, the open chunk flushed every second). Seconds per
experiment is the median gap between logged experiments over the runs of each kind; the floor
is the loop without recording, and the ratio less one is the recording's overhead. Also the
time spent inside the recorder's writes and flushes per experiment, which the noise between
runs does not touch."""),
    "driver": ("the Katana driver against its emulator", """\
`bench/bench_driver.py`. Against `katana-emulator` on loopback, not the real arm (a request
takes about 40 ms on the arm): the round trip of one position read over TCP and over a
pseudo-terminal, framing and CRC included, beside the emulator's own handling of it;
`joint_states` rates idle and while a trajectory runs, by arrival and by stamp, against the
configured poll rate; seconds from SIGINT or SIGTERM to the end of the driver and camera
processes; and one trajectory goal under each fault of the emulator (lost, corrupt, split and
late replies, a silent or frozen controller, a dropped TCP link, a restarted emulator)."""),
    "loop_hardware": ("the whole loop against the emulator in real time", """\
`bench/bench_loop_hardware.py`. `katana-run --backend hardware` as a user runs it, against
the Katana emulator in real time (time scale 1; every request answered 40 ms late, as the
real arm answers; its gripper stalls where a 4 cm block would hold the fingers) and the
substitute camera, for at least 10 experiments. Seconds per experiment is the median wall time
between consecutive logged experiments; its floor is the arm's motion in them (the durations
of the spline segments the emulator accepted). That motion stands beside the least time the
arm's speed and acceleration limits allow on the same paths
(`katana_manipulation.core.time_optimal` through the knots the driver sent, each rest-to-rest
move on its own). From the emulator's 10 ms ticks: the time the fingers moved, the time no
motor moved, and where that still time falls: between two arm goals, between an arm goal and
a finger move, and around the logging of an experiment (from the park's end to the next
experiment's first motion)."""),
}
