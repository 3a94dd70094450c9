"""Parameter YAML files checked before any node exists, by the rules the nodes apply.

A file is standard ROS 2 parameter YAML (`node_name: {ros__parameters: {...}}`, `/**` for
every node, nested mappings as dotted names). `ParamSet.read` keeps where each entry came from
(file and line, or the option that set it); `check_node` checks a node's entries as the node
will at start-up (katana_common.params): an undeclared name is refused, a value must have the
ROS type of the spec's default (rclpy's rule: 1 is not a double, [] is not a list of strings)
and pass the spec (`Param.problem`), then the node's cross-parameter rule. A refusal is a
`ParamFileError` naming the file, the line and the key, so a console tool can refuse a bad
file before it creates anything (katana_bringup.graph_params). No rclpy here.
"""

from __future__ import annotations

import difflib
import re
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from .param_spec import Param
from .scene import SCENE_PARAMS

WILDCARD = "/**"
#: the pick-and-place geometry graph.yaml sets for every node under `/**`: the executor plans
#: with it and the nodes that offer placements compute the arm's reach from it (the specs are
#: katana_manipulation.reach_params.REACH_PARAMS; a test there checks that the names agree)
GRAPH_WIDE_GEOMETRY = ("approach_height", "grasp_offset")
#: rclpy's own parameters, which every node declares (their types are checked like ours)
RCLPY_PARAMS = (
    Param("use_sim_time", False, "Stamp with /clock (rclpy)."),
    Param("start_type_description_service", True, "Serve type descriptions (rclpy)."),
)
#: names a node may be given without declaring them: rclpy's own, and the graph-wide facts that
#: graph.yaml sets for every node under `/**` (a node that does not use them ignores them): the
#: scene and the pick-and-place geometry
TOLERATED_UNDECLARED = frozenset(
    tuple(p.name for p in RCLPY_PARAMS) + GRAPH_WIDE_GEOMETRY + tuple(p.name for p in SCENE_PARAMS)
)
_RCLPY = {p.name: p for p in RCLPY_PARAMS}
_INT64 = (-(2**63), 2**63 - 1)

CrossCheck = Callable[[Mapping[str, Any]], "str | None"]


class ParamFileError(ValueError):
    """A parameter file (or an option that sets a parameter) a node would refuse. `option` is
    the command-line option that brought the entry in; the message starts with its place."""

    def __init__(self, where: str, message: str, option: str = "--params") -> None:
        super().__init__(f"{where}: {message}" if where else message)
        self.option = option


# -- the value rule ---------------------------------------------------------------------------
def ros_type(value: Any) -> str | None:
    """The ROS parameter type rclpy gives `value` (Parameter.Type.from_parameter_value) in
    words, "not set" for None, or None where rclpy has no type for it (a mapping, a date, a
    mixed or nested list)."""
    if value is None:
        return "not set"
    for kind, name in ((bool, "bool"), (int, "integer"), (float, "double"), (str, "string")):
        if isinstance(value, kind):
            return name
    if isinstance(value, list | tuple):
        if not value:
            return "empty list"  # rclpy: a byte array, which no parameter of ours is
        for kind, name in ((bool, "bool"), (int, "integer"), (float, "double"), (str, "string")):
            if all(isinstance(v, kind) for v in value):
                return f"list of {name}s"
    return None


def value_problem(spec: Param, value: Any) -> str | None:
    """Why the node refuses `value` for `spec` from a parameter file, or None: rclpy's type rule
    (the type of the default; ints within 64 bits), then the spec's own rule."""
    got, want = ros_type(value), _a(ros_type(spec.default))
    if got is None:
        return (f"is {value!r}: not a ROS parameter value (a bool, integer, double, string or a "
                f"list of one of them); expected {want}")
    if got == "not set":
        return f"has no value; expected {want}"
    if _a(got) != want:
        hint = ""
        if want in ("a double", "a list of doubles") and got in ("integer", "list of integers"):
            hint = " (write a double with a decimal point, e.g. 1.0)"
        return f"is {_a(got)} ({value!r}), expected {want}{hint}"
    items = value if isinstance(value, list | tuple) else [value]
    if any(isinstance(v, int) and not (_INT64[0] <= v <= _INT64[1]) for v in items):
        return f"{value!r} does not fit a 64-bit integer"
    return with_valid(spec, spec.problem(list(value) if isinstance(value, tuple) else value))


def with_valid(spec: Param, reason: str | None) -> str | None:
    """A spec's refusal with its valid values (unless the refusal lists them already)."""
    if reason is None or "is not one of" in reason:
        return reason
    return f"{reason}; valid: {spec.valid_text()}"


def _a(kind: str | None) -> str:
    return f"{'an' if str(kind)[0] in 'aeiou' else 'a'} {kind}"


# -- reading ----------------------------------------------------------------------------------
@dataclass(frozen=True)
class Entry:
    """One parameter value and where it came from: the option and, for a file, file:line."""

    value: Any
    option: str
    where: str = ""


class ParamSet:
    """Parameters per node section (`/**` for every node), later entries win, each with its
    place. The entries a later one replaced are kept too: a node never sees them, but a file
    that says something wrong is refused all the same."""

    def __init__(self) -> None:
        self.sections: dict[str, dict[str, Entry]] = {}
        self.replaced: dict[str, list[tuple[str, Entry]]] = {}
        self.headers: dict[str, Entry] = {}  # node -> where its section was last opened

    def set(self, node: str, name: str, value: Any, option: str, where: str = "") -> None:
        self._put(node, name, Entry(value, option, where))
        self.headers.setdefault(node, Entry(None, option, where))

    def _put(self, node: str, name: str, entry: Entry) -> None:
        section = self.sections.setdefault(node, {})
        if name in section:
            self.replaced.setdefault(node, []).append((name, section[name]))
        section[name] = entry

    def values(self) -> dict[str, dict[str, Any]]:
        """{node: {name: value}}, as katana_bringup.run.load_params returns them."""
        return {node: {k: e.value for k, e in entries.items()}
                for node, entries in self.sections.items()}

    def overrides(self, node: str) -> dict[str, Entry]:
        """What `node` is given: the wildcard entries, then its own."""
        return {**self.sections.get(WILDCARD, {}), **self.sections.get(node, {})}

    def read(self, path: str | Path, option: str = "--params") -> ParamSet:
        """Add one file's entries (ParamFileError naming the file and line if it is not
        parameter YAML)."""
        text = _text(path, option)
        loader = yaml.SafeLoader(text)
        try:
            root = loader.get_single_node()
            if root is None:
                return self
            if not isinstance(root, yaml.MappingNode):
                raise ParamFileError(_at(path, root), "expected a mapping of node names",
                                     option)
            for key, body in root.value:
                name = str(loader.construct_object(key))
                node = WILDCARD if name in ("/**", "**") else name.lstrip("/")
                self._read_section(loader, path, node, key, body, option)
        except yaml.MarkedYAMLError as err:
            mark = err.problem_mark or err.context_mark
            raise ParamFileError(_at(path, mark), f"not YAML: {err.problem or err.context}",
                                 option) from None
        except yaml.YAMLError as err:
            raise ParamFileError(str(path), f"not YAML: {_one_line(err)}", option) from None
        except RecursionError:
            raise ParamFileError(str(path), "nested too deeply", option) from None
        finally:
            loader.dispose()
        return self

    def _read_section(self, loader, path, node: str, key, body, option: str) -> None:
        self.headers[node] = Entry(None, option, _at(path, key))
        params = None
        if isinstance(body, yaml.MappingNode):
            for inner_key, inner in body.value:
                inner_name = loader.construct_object(inner_key)
                if inner_name != "ros__parameters":
                    raise ParamFileError(_at(path, inner_key), f"'{node}': only ros__parameters "
                                         f"belongs under a node name, got {inner_name!r}", option)
                params = inner
        if params is None:
            raise ParamFileError(_at(path, key), f"'{node}' has no ros__parameters mapping",
                                 option)
        if isinstance(params, yaml.ScalarNode) and loader.construct_object(params) is None:
            self.sections.setdefault(node, {})
            return
        if not isinstance(params, yaml.MappingNode):
            raise ParamFileError(_at(path, params),
                                 f"'{node}': ros__parameters must be a mapping", option)
        self.sections.setdefault(node, {})
        self._read_mapping(loader, path, node, params, "", option)

    def _read_mapping(self, loader, path, node: str, mapping, prefix: str, option: str) -> None:
        """Nested mappings become dotted names, as ROS 2 does with parameter YAML."""
        for key, value in mapping.value:
            name = f"{prefix}{loader.construct_object(key)}"
            if isinstance(value, yaml.MappingNode):
                self._read_mapping(loader, path, node, value, name + ".", option)
            else:
                entry = Entry(loader.construct_object(value, deep=True), option, _at(path, key))
                self._put(node, name, entry)


def read_param_files(paths: Iterable[str | Path], option: str = "--params",
                     into: ParamSet | None = None) -> ParamSet:
    """The files' entries merged in order (later files win), into a new ParamSet or `into`."""
    params = ParamSet() if into is None else into
    for path in paths:
        params.read(path, option)
    return params


def _text(path: str | Path, option: str) -> str:
    try:
        raw = Path(path).read_bytes()
    except OSError as err:
        raise ParamFileError(str(path), f"cannot read: {err.strerror or err}", option) from None
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError as err:
        line = raw[: err.start].count(b"\n") + 1
        raise ParamFileError(f"{path}:{line}", f"not a text file (byte 0x{raw[err.start]:02x} "
                             "is not UTF-8); expected parameter YAML", option) from None


def _at(path: str | Path, node_or_mark) -> str:
    mark = getattr(node_or_mark, "start_mark", node_or_mark)
    line = getattr(mark, "line", None)
    return f"{path}:{line + 1}" if line is not None else str(path)


def _one_line(err: BaseException) -> str:
    return " ".join((str(err).strip() or type(err).__name__).split())


# -- checking ---------------------------------------------------------------------------------
def check_sections(params: ParamSet, known: Iterable[str], graph: str) -> None:
    """Every section names a node of the graph (or `/**`): another name is a typo."""
    valid = [WILDCARD, *known]
    for node, header in params.headers.items():
        if node not in valid:
            raise ParamFileError(header.where, f"no node named '{node}' in {graph}"
                                 f"{_did_you_mean(node, valid)}; valid: {', '.join(valid)}",
                                 header.option)


def check_node(params: ParamSet, node: str, specs: Iterable[Param],
               cross_check: CrossCheck | None = None, base: Mapping[str, Entry] | None = None,
               started: bool = True) -> None:
    """Check what `node` is given as it will check it at start-up (ParamFileError on the first
    refusal). `base` holds entries below the wildcard (a backend's own file); a node that is
    not `started` has only its own section checked (names and values)."""
    specs = {p.name: p for p in specs}
    given = {**(base or {}), **params.overrides(node)} if started else \
        dict(params.sections.get(node, {}))
    replaced = [*(params.replaced.get(WILDCARD, []) if started else []),
                *params.replaced.get(node, [])]
    for name, entry in [*given.items(), *replaced]:
        spec = specs.get(name) or _RCLPY.get(name)
        if spec is None:
            if name in TOLERATED_UNDECLARED or name.startswith("qos_overrides."):
                continue
            raise ParamFileError(entry.where, f"unknown parameter '{name}' for node '{node}'"
                                 f"{_did_you_mean(name, specs)}; valid names: "
                                 f"{', '.join(sorted(specs))}", entry.option)
        reason = value_problem(spec, entry.value)
        if reason:
            raise ParamFileError(entry.where, f"{node}: parameter '{name}' {reason}",
                                 entry.option)
    if started and cross_check is not None:
        values = {name: spec.default for name, spec in specs.items()}
        values.update({k: list(e.value) if isinstance(e.value, tuple) else e.value
                       for k, e in given.items() if k in specs})
        try:
            reason = cross_check(values)
        except ValueError as err:  # a rule that raises (a config's validate) instead of saying
            reason = _one_line(err)
        if reason:
            named = re.search(r"parameter '([\w.]+)'", reason)
            entry = given.get(named.group(1)) if named else None
            entry = entry or _last(given.values()) or Entry(None, "--params")
            raise ParamFileError(entry.where, f"{node}: {reason}", entry.option)


def _did_you_mean(name: str, valid: Iterable[str]) -> str:
    close = difflib.get_close_matches(name, list(valid), n=1)
    return f" (did you mean '{close[0]}'?)" if close else ""


def _last(entries: Iterable[Entry]) -> Entry | None:
    """The last entry that came from a file (the likeliest place of a combination's fault)."""
    filed = [e for e in entries if e.where]
    return filed[-1] if filed else None
