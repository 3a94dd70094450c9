"""The packaged parameter files state no default of their own: they are what the nodes' specs
generate (katana_bringup.config_files), every value read back is its spec's default or a named
deliberate choice, the graph-wide geometry is set once, and rcl reads them as katana-run does."""

from __future__ import annotations

import pytest
import rclpy
import yaml
from hypothesis import given
from hypothesis import strategies as st
from katana_bringup import config_files
from katana_bringup.run import default_params_files, load_params, overrides_for
from katana_common.param_spec import yaml_value
from katana_curiosity.core.predictors import THETA_ROBOT
from katana_manipulation.core.pick_place import MIN_SEGMENT_TIME_S, SIM_MIN_SEGMENT_TIME_S
from rclpy.context import Context

GRAPH_WIDE = {p.name for p in config_files.GRAPH_WIDE}


def _files() -> list:
    return [config_files.path_of("hardware.yaml"), *default_params_files("sim"),
            *default_params_files("hardware")]


def _specs() -> dict:
    """node section -> {name: spec}, from the generator's table."""
    out: dict = {}
    for _, sections in config_files.FILES.values():
        for section in sections:
            out.setdefault(section.node, {}).update({p.name: p for p in section.specs})
    return out


def test_the_packaged_parameter_files_are_what_the_specs_generate():
    assert config_files.stale() == [], "run python -m katana_bringup.config_files --write"
    assert config_files.main([]) == 0


def test_a_value_edited_by_hand_makes_its_file_stale(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(config_files, "path_of", lambda name: tmp_path / name)
    assert sorted(config_files.stale()) == sorted(config_files.FILES)  # none written yet
    assert config_files.main(["--write"]) == 0 and config_files.stale() == []
    graph = tmp_path / "graph.yaml"
    graph.write_text(graph.read_text().replace("theta: 0.1\n", "theta: 0.01\n"))
    assert config_files.stale() == ["graph.yaml"]
    assert config_files.main([]) == 1 and "graph.yaml" in capsys.readouterr().out


def test_every_packaged_value_is_its_specs_default_or_a_named_choice():
    specs = _specs()
    chosen = {("pick_place_executor", "min_segment_time_s"): SIM_MIN_SEGMENT_TIME_S}
    seen = 0
    for path in _files():
        for node, values in load_params([path]).items():
            for name, value in values.items():
                if name == "use_sim_time":  # rclpy's own: the backends' clocks
                    continue
                spec = specs[node][name]
                expected = chosen.get((node, name), spec.default) if path.name == "sim.yaml" \
                    else spec.default
                assert value == expected and type(value) is type(expected), (path, node, name)
                seen += 1
    assert seen > 100
    graph = load_params(default_params_files("sim"))
    assert graph["curiosity_node"]["theta"] == THETA_ROBOT  # paper section 3.3
    assert graph["pick_place_executor"]["min_segment_time_s"] == SIM_MIN_SEGMENT_TIME_S
    hardware = load_params(default_params_files("hardware"))
    assert hardware["pick_place_executor"]["min_segment_time_s"] == MIN_SEGMENT_TIME_S


def test_the_graph_wide_geometry_and_scene_are_set_once_for_every_node():
    for path in _files():
        for node, values in load_params([path]).items():
            if node != "/**":
                assert not GRAPH_WIDE & set(values), (path, node)
    wildcard = load_params([default_params_files("sim")[0]])["/**"]
    assert GRAPH_WIDE == set(wildcard)
    assert {"approach_height", "grasp_offset"} <= GRAPH_WIDE


@pytest.mark.parametrize("node", ["pick_place_executor", "fovea_node", "curiosity_node",
                                  "sim_node", "katana_driver_node", "camera_node"])
def test_rcl_reads_the_packaged_files_as_katana_run_does(node):
    """launch passes the files to rcl's parser; katana-run reads them with PyYAML: both must
    give every node the same values with the same types."""
    files = [str(f) for f in (config_files.path_of("hardware.yaml"),
                              *default_params_files("sim"))]
    args = ["test", "--ros-args"] + [a for f in files for a in ("--params-file", f)]
    ctx = Context()
    rclpy.init(context=ctx, args=args)
    try:
        probe = rclpy.create_node(node, context=ctx)
        got = {name: p.value for name, p in probe._parameter_overrides.items()}
        got = {k: list(v) if isinstance(v, tuple | list) or type(v).__name__ == "array" else v
               for k, v in got.items()}
        expected = {p.name: p.value for p in overrides_for(node, load_params(files))}
        assert got == expected
        assert {k: type(v) for k, v in got.items()} == {k: type(v) for k, v in expected.items()}
        probe.destroy_node()
    finally:
        rclpy.try_shutdown(context=ctx)


_scalars = (st.booleans() | st.integers(-2**31, 2**31)
            | st.floats(allow_nan=False, allow_infinity=False) | st.text(max_size=12))


@given(value=_scalars | st.lists(st.floats(allow_nan=False, allow_infinity=False), min_size=1,
                                 max_size=4))
def test_a_rendered_value_reads_back_with_its_type(value):
    back = yaml.safe_load(f"key: {yaml_value(value)}")["key"]
    assert back == value
    if isinstance(value, list):
        assert [type(v) for v in back] == [float] * len(value)
    else:
        assert type(back) is type(value)
