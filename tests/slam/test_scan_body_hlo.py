"""The compiled ``run`` of PF-SLAM and PS-SLAM: the scan body touches only the detected rows of the tag table.

[W] §3.3.1: a step gathers the ``K`` detected rows, updates them and scatters them back, so
its cost does not depend on the number of tags in the map. Inside ``run`` (one ``lax.scan``,
the state donated) that holds only if the loop body of the compiled program does nothing
to the whole table: no copy of it, no select or elementwise op over it, no layout change of
a loop-carried table, no fusion that rewrites all of its rows. This module reads the
optimised HLO text of ``run`` with a small parser, walks the while loop's body and every
computation it calls (fusions, reducers, nested loops, branches), and lists each
instruction with an operand or a result whose shape has a dimension that is a multiple of
the table size. Allowed are only the loop's plumbing (parameters, tuples,
get-tuple-element, bitcasts), in-place row writes (``dynamic-update-slice`` and
``scatter`` with a small update) and row reads (``gather`` and ``dynamic-slice`` with a
small result). The table size is a prime far from every per-step size, so no per-step
array can be mistaken for a table-shaped one.

Toy scans show that the analysis can fail: a body that rewrites the whole table
(``table * 1.0 + 0``, a ``where`` over every row, a ``roll``) is flagged, and so is a row
write that does not depend on its read (XLA copies the table to keep the read valid); one
that writes a row with a ``dynamic_update_slice`` or a scatter is not. On the real programs,
the copy of the initial table that ``run`` makes without donation is found outside the
loop, and none with donation. Both filters are checked with kidnapping recovery on and off,
and so is the public ``step`` (state donated): no table copy, nothing over the whole table.

What the compiled body of both filters holds (XLA:CPU): per table field one fused
``gather`` of the ``K`` detected rows (``op_name=".../while/body/closed_call/gather"``)
and one ``scatter`` of the updated rows (``".../closed_call/scatter"``), plus the loop's
tuple plumbing; nothing else touches the table or PS-SLAM's rings.
"""

from __future__ import annotations

import functools
import re
from dataclasses import dataclass
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxnav.models import hf_rfid
from jaxnav.models.motion import OmniNoise
from jaxnav.slam import pf_slam, ps_slam

NUM_TAGS = 1009  # prime: no per-step array (K slots, I or J particles, lag, T steps) has such a dimension
STEPS = 3
SLOTS = 4
MOTION = OmniNoise(jnp.asarray([0.02, 0.02, 0.01], jnp.float32))
SENSOR = hf_rfid.reader_params(0.06)

# ---------------------------------------------------------------------------
# a small parser of optimised HLO text

_PLUMBING = {"parameter", "get-tuple-element", "tuple", "bitcast", "constant", "opt-barrier"}
_CALLERS = {"fusion", "while", "conditional", "call", "async-start", "async-done", "async-update"}
_OUTER_CALLERS = {"call", "conditional", "async-start", "async-done", "async-update"}
_CALLED_ATTRS = ("calls", "to_apply", "body", "condition", "true_computation", "false_computation")
_ARRAY = re.compile(r"\b([a-z]+[0-9]*)\[([0-9,]*)\]")
_HEADER = re.compile(r"^(ENTRY\s+)?%?([\w.\-]+)\s*\(.*\)\s*->\s*.*\{\s*$")


@dataclass(frozen=True)
class Instruction:
    """One HLO instruction: its name, result shapes, opcode, operand names, called computations and text."""

    name: str
    shapes: tuple[tuple[int, ...], ...]
    opcode: str
    operands: tuple[str, ...]
    called: tuple[str, ...]
    text: str

    @property
    def op_name(self) -> str:
        m = re.search(r'op_name="([^"]*)"', self.text)
        return m.group(1) if m else ""


def _shapes(text: str) -> tuple[tuple[int, ...], ...]:
    """The dimensions of every array type in ``text`` (``f32[3,2]{1,0}`` → ``(3, 2)``)."""
    return tuple(tuple(int(d) for d in dims.split(",") if d) for _, dims in _ARRAY.findall(text))


def _closing(text: str, start: int) -> int:
    """Index of the parenthesis that closes the one at ``text[start]``."""
    depth = 0
    for i in range(start, len(text)):
        if text[i] == "(":
            depth += 1
        elif text[i] == ")":
            depth -= 1
            if depth == 0:
                return i
    raise ValueError(f"unbalanced parentheses in {text[:200]!r}")


def _instruction(line: str) -> Instruction | None:
    body = re.sub(r"^\s*(ROOT\s+)?", "", line)
    m = re.match(r"%?([\w.\-]+)\s*=\s*", body)
    if m is None:
        return None
    name, rest = m.group(1), body[m.end() :]
    if rest.startswith("("):  # a tuple type
        end = _closing(rest, 0)
        type_text, rest = rest[: end + 1], rest[end + 1 :].lstrip()
    else:
        type_text, _, rest = rest.partition(" ")
    m = re.match(r"([\w\-]+)\(", rest)
    if m is None:
        return None
    opcode = m.group(1)
    end = _closing(rest, m.end() - 1)
    operand_text, attrs = rest[m.end() : end], rest[end + 1 :]
    operand_text = re.sub(r"/\*.*?\*/", "", operand_text)
    operands = tuple(
        re.findall(r"%?([\w.\-]+)\s*$", o.strip())[0]
        for o in _split_top(operand_text)
        if o.strip() and opcode not in ("constant", "parameter")
    )
    called = [c for attr in _CALLED_ATTRS for c in re.findall(rf"\b{attr}=%?([\w.\-]+)", attrs)]
    for group in re.findall(r"\b(?:branch_computations|called_computations)=\{([^}]*)\}", attrs):
        called += [c.strip().lstrip("%") for c in group.split(",") if c.strip()]
    return Instruction(name, _shapes(type_text), opcode, operands, tuple(called), line.strip())


def _split_top(text: str) -> list[str]:
    """``text`` split at the commas outside brackets and braces."""
    parts, depth, cur = [], 0, []
    for ch in text:
        if ch in "([{":
            depth += 1
        elif ch in ")]}":
            depth -= 1
        if ch == "," and depth == 0:
            parts.append("".join(cur))
            cur = []
        else:
            cur.append(ch)
    parts.append("".join(cur))
    return parts


def parse_hlo(text: str) -> tuple[dict[str, list[Instruction]], str]:
    """``({computation name: instructions}, entry computation name)`` of an HLO module's text."""
    computations: dict[str, list[Instruction]] = {}
    entry, current = "", None
    for line in text.splitlines():
        if current is None:
            m = _HEADER.match(line)
            if m:
                current = m.group(2)
                computations[current] = []
                if m.group(1):
                    entry = current
            continue
        if line.strip() == "}":
            current = None
            continue
        ins = _instruction(line)
        if ins is not None:
            computations[current].append(ins)
    if not entry:
        raise ValueError("no ENTRY computation in the HLO text")
    return computations, entry


# ---------------------------------------------------------------------------
# the analysis


def _table_sized(shape: tuple[int, ...], rows: int) -> bool:
    return any(d >= rows and d % rows == 0 for d in shape)


def _any_table_sized(shapes, rows: int) -> bool:
    return any(_table_sized(s, rows) for s in shapes)


def _outside_loops(computations: dict[str, list[Instruction]], entry: str) -> list[str]:
    """The entry computation and what it calls outside any loop (XLA:CPU may wrap a loop in a ``call``)."""
    seen: list[str] = []
    stack = [entry]
    while stack:
        name = stack.pop()
        if name in seen or name not in computations:
            continue
        seen.append(name)
        stack.extend(c for ins in computations[name] if ins.opcode in _OUTER_CALLERS for c in ins.called)
    return seen


def scan_loops(computations: dict[str, list[Instruction]], entry: str, rows: int) -> list[Instruction]:
    """The outermost while loops that carry a table-sized array (the scan)."""
    return [
        ins
        for comp in _outside_loops(computations, entry)
        for ins in computations[comp]
        if ins.opcode == "while" and _any_table_sized(ins.shapes, rows)
    ]


def _reachable(computations: dict[str, list[Instruction]], roots) -> list[str]:
    seen: list[str] = []
    stack = list(roots)
    while stack:
        name = stack.pop()
        if name in seen or name not in computations:
            continue
        seen.append(name)
        stack.extend(c for ins in computations[name] for c in ins.called)
    return seen


def whole_table_work(computations: dict[str, list[Instruction]], loop: Instruction, rows: int) -> list[Instruction]:
    """Every instruction in the body (and condition) of ``loop``, and in what they call, that touches
    an array with a table-sized dimension other than by plumbing, in-place row writes or row reads."""
    return table_work(computations, loop.called, rows)


def table_work(computations: dict[str, list[Instruction]], roots, rows: int) -> list[Instruction]:
    """:func:`whole_table_work` in the computations ``roots`` and in everything they call."""
    found = []
    for comp in _reachable(computations, roots):
        shapes = {ins.name: ins.shapes for ins in computations[comp]}
        for ins in computations[comp]:
            operand_shapes = [shapes.get(o, ()) for o in ins.operands]
            if not (_any_table_sized(ins.shapes, rows) or any(_any_table_sized(s, rows) for s in operand_shapes)):
                continue
            if ins.opcode in _PLUMBING or ins.opcode in _CALLERS:  # a caller's content is walked
                continue
            if ins.opcode in ("gather", "dynamic-slice") and not _any_table_sized(ins.shapes, rows):
                continue
            if ins.opcode == "dynamic-update-slice" and not _any_table_sized(operand_shapes[1], rows):
                continue
            if ins.opcode == "scatter":
                n = (len(ins.operands) - 1) // 2  # operands..., indices, updates...
                if not any(_any_table_sized(s, rows) for s in operand_shapes[n:]):
                    continue
            found.append(ins)
    return found


def table_copies(computations: dict[str, list[Instruction]], entry: str, loop: Instruction, rows: int):
    """``copy`` instructions of a table-sized array outside any loop and inside the scan loop."""
    comps = [*_outside_loops(computations, entry), *_reachable(computations, loop.called)]
    return [
        ins
        for comp in comps
        for ins in computations[comp]
        if ins.opcode in ("copy", "copy-start") and _any_table_sized(ins.shapes, rows)
    ]


@dataclass(frozen=True)
class Analysis:
    """What :func:`analyse` found in a compiled program."""

    text: str
    computations: dict[str, list[Instruction]]
    loops: list[Instruction]
    work: list[Instruction]  # whole-table instructions in the loop
    copies: list[Instruction]  # table copies in the entry computation or in the loop
    body_copies: list[Instruction]  # table copies in the loop only


def analyse(jitted, *args, rows: int) -> Analysis:
    """The scan loops of ``jitted(*args)`` compiled, their whole-table work and the table copies."""
    text = jitted.lower(*args).compile().as_text()
    computations, entry = parse_hlo(text)
    loops = scan_loops(computations, entry, rows)
    work = [i for loop in loops for i in whole_table_work(computations, loop, rows)]
    copies = [i for loop in loops for i in table_copies(computations, entry, loop, rows)]
    in_loop = {i.name for loop in loops for c in _reachable(computations, loop.called) for i in computations[c]}
    return Analysis(text, computations, loops, work, copies, [c for c in copies if c.name in in_loop])


def unresolved_operands(computations: dict[str, list[Instruction]]) -> list[tuple[str, str]]:
    """``(instruction, operand)`` pairs whose operand names no instruction of the same computation
    (a parser that misreads a line would leave some: its shapes would be missed)."""
    out = []
    for instructions in computations.values():
        names = {i.name for i in instructions}
        out += [(i.name, o) for i in instructions for o in i.operands if o not in names]
    return out


def describe(instructions) -> str:
    return "\n".join(f"{i.opcode} {i.name} {list(i.shapes)} op_name={i.op_name!r}" for i in instructions)


# ---------------------------------------------------------------------------
# the parser and the analysis on toy scans


def _toy_args():
    table = jnp.zeros((NUM_TAGS, 8), jnp.float32)
    return table, jnp.arange(STEPS, dtype=jnp.int32) * 7


def _toy_scan(update):
    def run(table, ids):
        def body(t, i):
            return update(t, i), None  # a read of ``t`` returned here would not feed the write: a copy

        return jax.lax.scan(body, table, ids)

    return jax.jit(run, donate_argnums=(0,))


def test_parser_reads_instructions_types_and_called_computations():
    text = """HloModule m, entry_computation_layout={(f32[5,2]{1,0})->f32[5,2]{1,0}}

%add (a: f32[], b: f32[]) -> f32[] {
  %a = f32[] parameter(0)
  %b = f32[] parameter(1)
  ROOT %s = f32[] add(%a, %b)
}

ENTRY %main (p: f32[5,2]) -> (f32[5,2], f32[]) {
  %p = f32[5,2]{1,0} parameter(0)
  %z = f32[] constant(0)
  %r = f32[] reduce(%p, %z), dimensions={0,1}, to_apply=%add, metadata={op_name="jit(f)/reduce_sum"}
  ROOT %t = (f32[5,2]{1,0}, /*index=1*/f32[]) tuple(%p, %r)
}
"""
    computations, entry = parse_hlo(text)
    assert entry == "main" and set(computations) == {"add", "main"}
    by_name = {i.name: i for i in computations["main"]}
    assert by_name["r"].opcode == "reduce" and by_name["r"].operands == ("p", "z")
    assert by_name["r"].called == ("add",) and by_name["r"].op_name == "jit(f)/reduce_sum"
    assert by_name["t"].shapes == ((5, 2), ()) and by_name["t"].opcode == "tuple"
    assert by_name["z"].operands == ()


@pytest.mark.parametrize(
    "update",
    [
        pytest.param(lambda t, i: t * 1.0 + 0.0 * i, id="elementwise"),
        pytest.param(lambda t, i: jnp.where(jnp.arange(NUM_TAGS)[:, None] != i, t, t + 1.0), id="where-all-rows"),
        pytest.param(lambda t, i: t.at[i].add(1.0) + jnp.roll(t, 1, axis=0) * 0.0, id="roll"),
    ],
)
def test_analysis_flags_a_scan_that_touches_every_row(update):
    found = analyse(_toy_scan(update), *_toy_args(), rows=NUM_TAGS)
    assert len(found.loops) == 1
    assert found.work, "a body that rewrites the whole table must be flagged"


@pytest.mark.parametrize(
    "update",
    [
        pytest.param(
            lambda t, i: jax.lax.dynamic_update_slice(t, jnp.full((1, 8), 1.0) + t[i], (i, 0)),
            id="dynamic-update-slice",
        ),
        pytest.param(lambda t, i: t.at[jnp.stack([i, i + 1])].set(t[jnp.stack([i, i + 1])] * 2.0), id="scatter"),
    ],
)
def test_analysis_passes_a_scan_that_writes_one_row(update):
    found = analyse(_toy_scan(update), *_toy_args(), rows=NUM_TAGS)
    assert len(found.loops) == 1
    assert found.work == [], describe(found.work)
    assert found.copies == [], describe(found.copies)


def test_analysis_flags_a_table_copy_in_the_loop():
    """A row write that does not depend on its row read lets XLA schedule the write first and copy
    the table to keep the read valid: a whole-table copy per iteration."""

    def run(table, ids):
        def body(t, i):
            row = t[(i + 1) % NUM_TAGS]
            return t.at[i].set(jnp.ones(8)), row

        return jax.lax.scan(body, table, ids)

    found = analyse(jax.jit(run, donate_argnums=(0,)), *_toy_args(), rows=NUM_TAGS)
    assert len(found.loops) == 1
    assert found.body_copies, found.text
    assert found.work  # a copy is whole-table work too


# ---------------------------------------------------------------------------
# PF-SLAM and PS-SLAM


def _slam(method: str, recovery: bool = True):
    if method == "pf":
        config = pf_slam.PFSLAMConfig(num_particles=64, num_tag_particles=16, max_tags=NUM_TAGS, recovery=recovery)
        return pf_slam, config, pf_slam.PFSLAMParams(MOTION, SENSOR)
    config = ps_slam.PSSLAMConfig(num_particles=64, num_tag_particles=16, max_tags=NUM_TAGS, lag=5, recovery=recovery)
    return ps_slam, config, ps_slam.PSSLAMParams(MOTION, SENSOR, ps_slam.default_jitter(SENSOR))


def _slam_inputs():
    rng = np.random.default_rng(0)
    ids = rng.integers(0, NUM_TAGS, (STEPS, SLOTS))
    readers = np.broadcast_to(np.asarray([0, 3, 4, 7]), (STEPS, SLOTS))
    det = hf_rfid.TagDetections(
        jnp.asarray(ids, jnp.int32), jnp.asarray(readers, jnp.int32), jnp.ones((STEPS, SLOTS), bool)
    )
    controls = jnp.asarray(np.tile([0.1, 0.0, 0.0, 0.1], (STEPS, 1)), jnp.float32)
    return controls, det


@functools.cache
def _slam_analysis(method: str, donated: bool = True, recovery: bool = True) -> tuple[Any, Analysis]:
    """The state's shapes and the analysis of ``run`` (``donate_state=donated``) as the S2 benchmark compiles it."""
    module, config, params = _slam(method, recovery)
    state = jax.eval_shape(lambda: module.init(jax.random.key(0), config, params, jnp.zeros(3)))
    controls, det = _slam_inputs()
    jitted = module.run.jitted_donated if donated else module.run.jitted
    return state, analyse(jitted, jax.random.key(1), state, config, params, controls, det, rows=NUM_TAGS)


@pytest.mark.parametrize("recovery", [True, False])
@pytest.mark.parametrize("method", ["pf", "ps"])
def test_scan_body_touches_only_the_detected_rows(method, recovery):
    _, found = _slam_analysis(method, recovery=recovery)
    assert unresolved_operands(found.computations) == []
    assert sum(len(v) for v in found.computations.values()) == len(
        re.findall(r"(?m)^\s+(?:ROOT )?%?\S+ = ", found.text)
    )
    assert len(found.loops) == 1, "run must compile to one while loop carrying the tag table"
    assert found.work == [], "whole-table work in the scan body:\n" + describe(found.work)


@pytest.mark.parametrize("recovery", [True, False])
@pytest.mark.parametrize("method", ["pf", "ps"])
def test_donated_scan_carries_the_table_without_copying_it(method, recovery):
    state, found = _slam_analysis(method, recovery=recovery)
    assert len(found.loops) == 1
    assert found.copies == [], "table copies outside or inside the scan:\n" + describe(found.copies)
    header = found.text.splitlines()[0]
    assert header.count("may-alias") + header.count("must-alias") >= 2 + len(state.tags)


@pytest.mark.parametrize("method", ["pf", "ps"])
def test_undonated_scan_copies_the_table_once_outside_the_loop(method):
    """Without donation XLA copies the initial table into the loop once per call: the analysis sees
    these copies in the real program (one per table field), and none in the loop."""
    state, found = _slam_analysis(method, donated=False)
    assert len(found.loops) == 1
    assert len(found.copies) == len(state.tags), describe(found.copies)
    assert found.body_copies == []
    assert found.work == [], describe(found.work)


@pytest.mark.parametrize("recovery", [True, False])
@pytest.mark.parametrize("method", ["pf", "ps"])
def test_donated_step_writes_the_table_in_place(method, recovery):
    """The public ``step`` (state donated): no copy of a table field and nothing over its rows but the
    gather of the detected rows and the scatter of their updates, with kidnapping recovery on or off.
    Without recovery no written row used to depend on its gathered estimate (the robot is not checked
    against the previous estimates), so XLA copied the estimate table twice per step to keep the gather
    valid; every field written is now selected with its gathered row."""
    module, config, params = _slam(method, recovery)
    state = jax.eval_shape(lambda: module.init(jax.random.key(0), config, params, jnp.zeros(3)))
    controls, det = _slam_inputs()
    args = (jax.random.key(1), state, config, params, controls[0], jax.tree_util.tree_map(lambda a: a[0], det))
    text = module.step.jitted.lower(*args).compile().as_text()
    computations, entry = parse_hlo(text)
    assert unresolved_operands(computations) == []
    every = [i for c in _reachable(computations, [entry]) for i in computations[c]]
    copies = [i for i in every if i.opcode in ("copy", "copy-start") and _any_table_sized(i.shapes, NUM_TAGS)]
    assert copies == [], "table copies in the step:\n" + describe(copies)
    work = table_work(computations, [entry], NUM_TAGS)
    assert work == [], "whole-table work in the step:\n" + describe(work)
    # the analysis saw the write (a scatter, or a loop of row writes where XLA expands the scatter)
    assert any(i.opcode in ("scatter", "dynamic-update-slice") and _any_table_sized(i.shapes, NUM_TAGS) for i in every)
    header = text.splitlines()[0]
    assert header.count("may-alias") + header.count("must-alias") >= 2 + len(state.tags)


def _range_only_analysis(method: str) -> tuple[Any, Analysis]:
    """The analysis of ``run`` (state donated) with range-only beacons weighted as mixtures."""
    from jaxnav.models import range_only as ro

    noise = ro.range_noise(0.1, 0.1)
    common = dict(
        num_particles=64,
        num_tag_particles=16,
        max_tags=NUM_TAGS,
        sensor=ro.RANGE_ONLY_LANDMARK_SENSOR,
        robot_likelihood="mixture",
    )
    if method == "pf":
        module, config, params = pf_slam, pf_slam.PFSLAMConfig(**common), pf_slam.PFSLAMParams(MOTION, noise)
    else:
        config = ps_slam.PSSLAMConfig(lag=5, **common)
        module, params = ps_slam, ps_slam.PSSLAMParams(MOTION, noise, jnp.float32(0.01))
    state = jax.eval_shape(lambda: module.init(jax.random.key(0), config, params, jnp.zeros(3)))
    controls, det = _slam_inputs()
    obs = ro.RangeObs(det.ids, jnp.full((STEPS, SLOTS, 1), 2.0), det.mask)
    jitted = module.run.jitted_donated
    return state, analyse(jitted, jax.random.key(1), state, config, params, controls, obs, rows=NUM_TAGS)


@pytest.mark.parametrize("method", ["pf", "ps"])
def test_any_landmark_sensor_keeps_the_step_to_the_detected_rows(method):
    """The table properties do not depend on the sensor: with range-only beacons, the robot weighted
    against each beacon's particle set (``robot_likelihood="mixture"``) and the recovery on, the scan
    body gathers and scatters the detected rows only and the donated table is not copied."""
    state, found = _range_only_analysis(method)
    assert len(found.loops) == 1
    assert found.work == [], "whole-table work in the scan body:\n" + describe(found.work)
    assert found.copies == [], "table copies outside or inside the scan:\n" + describe(found.copies)
