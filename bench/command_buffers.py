"""What of a GPU program runs outside XLA's command buffers (CUDA graphs)? Read from XLA's HLO dump.

A steady loop at >= 90 % of the raw env's rate needs the update to run beside the rollout on one GPU. XLA runs
two loops of one program side by side only when both are nodes of one command buffer (docs/performance.md,
2026-11-27 to 2026-11-28: two chains of matmuls did, the trainer's rollout and update did not, even with no
library call left in the physics step). This script says what keeps a program's instructions out of a command
buffer.

Older XLA formed command buffers in a late HLO pass (``command-buffer-scheduling``) that outlines each
run of recordable instructions into a computation named ``command_buffer...``; what is left at the top
level of the entry computation, of a while loop's body or condition, or of a conditional's branch runs op
by op from the host. jaxlib 0.10 and later form them from thunks after the HLO
(``command_buffer_conversion_pass``; the switch between the two is among their removed ``DebugOptions``),
so their HLO holds no such computation: there this report only gives the loops and what runs in them, and
XLA's own log says what it recorded (``TF_CPP_VMODULE``, VLOG 2). For each dumped
module this prints:

- the command buffers: how many, and the instructions (and while loops) recorded in them;
- the while loops outside any command buffer (each iteration returns to the host), with their trip
  counts when XLA knows them;
- every other instruction outside a command buffer that launches work, by kind (``custom-call`` by its
  target, ``fusion`` by its kind), with where it is (the entry, or which loop).

Structural instructions (parameters, tuples, constants, bitcasts, ...) launch nothing and are not counted.
If a module holds no ``command_buffer`` computation at all, XLA formed its command buffers after the HLO
(from thunks) or formed none; the report says so rather than guessing.

Usage (on the GPU machine, after the pip prefix of shared/gpu/README.md)::

    XLA_FLAGS="--xla_dump_to=/tmp/dump --xla_dump_hlo_as_text --xla_dump_hlo_module_re=jit_rollout" \\
      python3 bench/train_breakdown.py --no-compile-cache
    python3 bench/command_buffers.py /tmp/dump --out $OUT/command_buffers.md
"""

from __future__ import annotations

import argparse
import collections
import re
import sys
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

from report import emit

STRUCTURAL = frozenset(
    {
        "parameter",
        "get-tuple-element",
        "tuple",
        "constant",
        "bitcast",
        "after-all",
        "opt-barrier",
        "add-dependency",
        "partition-id",
        "replica-id",
    }
)
"""Opcodes that launch no work on the device."""

_COMPUTATION = re.compile(r"^(ENTRY\s+)?%?([\w.\-]+)\s*\(.*\)\s*->\s*.*\{\s*$")
_INSTRUCTION = re.compile(r"^\s*(?:ROOT\s+)?%?([\w.\-]+)\s*=\s*(.*?)\s([a-z][a-z0-9\-]*)\((.*)$")
_CALLEE = re.compile(r"\b(calls|to_apply|condition|body|true_computation|false_computation)=%?([\w.\-]+)")
_BRANCHES = re.compile(r"branch_computations=\{([^}]*)\}")
_TARGET = re.compile(r'custom_call_target="([^"]+)"')
_KIND = re.compile(r"\bkind=(k\w+)")
_TRIP = re.compile(r'"known_trip_count":\{"n":"(\d+)"\}')


@dataclass
class Instruction:
    """One HLO instruction: its name, opcode and the rest of its line (operands and attributes)."""

    name: str
    opcode: str
    rest: str

    def callees(self) -> dict[str, list[str]]:
        """``{attribute: [computation names]}``: calls, to_apply, condition, body, the branches."""
        out: dict[str, list[str]] = collections.defaultdict(list)
        for attr, name in _CALLEE.findall(self.rest):
            out[attr].append(name)
        for group in _BRANCHES.findall(self.rest):
            out["branch_computations"] += [b.strip().lstrip("%") for b in group.split(",") if b.strip()]
        return dict(out)

    def kind(self) -> str:
        """``custom-call <target>``, ``fusion <kind>`` or the opcode."""
        if self.opcode == "custom-call":
            target = _TARGET.search(self.rest)
            return f"custom-call {target.group(1) if target else '?'}"
        if self.opcode == "fusion":
            kind = _KIND.search(self.rest)
            return f"fusion {kind.group(1) if kind else '?'}"
        return self.opcode


@dataclass
class Module:
    """A parsed HLO module: its computations' instructions and the entry's name."""

    computations: dict[str, list[Instruction]] = field(default_factory=dict)
    entry: str = ""


def parse(text: str) -> Module:
    """Parse HLO text (XLA's ``--xla_dump_hlo_as_text`` format) into computations and instructions."""
    mod = Module()
    current: list[Instruction] | None = None
    for line in text.splitlines():
        head = _COMPUTATION.match(line)
        if head and current is None:
            current = mod.computations.setdefault(head.group(2), [])
            if head.group(1):
                mod.entry = head.group(2)
            continue
        if line.strip() == "}":
            current = None
            continue
        if current is not None:
            ins = _INSTRUCTION.match(line)
            if ins:
                current.append(Instruction(ins.group(1), ins.group(3), ins.group(4)))
    return mod


def is_command_buffer(name: str) -> bool:
    """XLA names the computations it outlines into command buffers ``command_buffer...``."""
    return name.startswith("command_buffer")


@dataclass
class Report:
    """What ``analyse`` found in one module."""

    graphs: int = 0
    in_graphs: collections.Counter = field(default_factory=collections.Counter)
    host_loops: list[tuple[str, str]] = field(default_factory=list)  # (where, trip count or "unknown")
    outside: collections.Counter = field(default_factory=collections.Counter)  # (kind, where) -> count


def _launching(mod: Module, name: str, seen: set[str]) -> Iterator[Instruction]:
    """The instructions of computation ``name`` that launch work; none if it was seen already."""
    if name in seen or name not in mod.computations:
        return
    seen.add(name)
    yield from (ins for ins in mod.computations[name] if ins.opcode not in STRUCTURAL)


def _count_graph(mod: Module, name: str, rep: Report, seen: set[str]) -> None:
    """Count the launching instructions of a command buffer and of the computations it calls."""
    for ins in _launching(mod, name, seen):
        rep.in_graphs[ins.kind()] += 1
        if ins.opcode in ("while", "conditional", "call"):
            for names in ins.callees().values():
                for callee in names:
                    _count_graph(mod, callee, rep, seen)


def _walk(mod: Module, name: str, where: str, rep: Report, seen: set[str]) -> None:
    """Classify the instructions at the host's level of computation ``name`` (entry, loop or branch)."""
    for ins in _launching(mod, name, seen):
        callees = ins.callees()
        if ins.opcode == "call" and any(is_command_buffer(c) for c in callees.get("to_apply", [])):
            rep.graphs += 1
            for c in callees["to_apply"]:
                _count_graph(mod, c, rep, set())
        elif ins.opcode == "while":
            trip = _TRIP.search(ins.rest)
            rep.host_loops.append((f"{where} / {ins.name}", trip.group(1) if trip else "unknown"))
            for c in callees.get("condition", []) + callees.get("body", []):
                _walk(mod, c, f"{where} / {ins.name}", rep, seen)
        elif ins.opcode in ("call", "conditional"):
            if ins.opcode == "conditional":
                rep.outside[("conditional", where)] += 1
            for names in callees.values():
                for c in names:
                    _walk(mod, c, where, rep, seen)
        else:
            rep.outside[(ins.kind(), where)] += 1


def analyse(mod: Module) -> Report:
    """The command buffers of ``mod`` and what runs outside them (module docstring)."""
    rep = Report()
    _walk(mod, mod.entry, "entry", rep, set())
    return rep


def render(name: str, rep: Report, has_graph_computations: bool) -> list[str]:
    """Markdown lines for one module."""
    lines = [f"## {name}", ""]
    if not has_graph_computations:
        lines += [
            "No `command_buffer` computation in this HLO: XLA formed its command buffers after the HLO "
            "(from thunks) or formed none. Everything below counts as outside.",
            "",
        ]
    in_total = sum(rep.in_graphs.values())
    loops_in = rep.in_graphs.get("while", 0)
    lines.append(
        f"command buffers: {rep.graphs}, recording {in_total} instructions ({loops_in} of them while loops); "
        f"while loops run from the host: {len(rep.host_loops)}; "
        f"other instructions outside a command buffer: {sum(rep.outside.values())}"
    )
    if rep.host_loops:
        lines += ["", "| while loop outside a command buffer | known trip count |", "|---|---:|"]
        lines += [f"| {w} | {t} |" for w, t in rep.host_loops]
    if rep.outside:
        lines += ["", "| outside a command buffer | where | count |", "|---|---|---:|"]
        for (kind, where), count in rep.outside.most_common(30):
            lines.append(f"| {kind} | {where} | {count} |")
    if rep.in_graphs:
        top = ", ".join(f"{k} {v}" for k, v in rep.in_graphs.most_common(8))
        lines += ["", f"recorded, by kind (largest first): {top}"]
    return [*lines, ""]


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("dump", help="XLA's --xla_dump_to directory (or one *after_optimizations.txt file)")
    p.add_argument("--module", default="", help="only modules whose file name matches this regex")
    p.add_argument("--out", default="")
    args = p.parse_args(argv)
    src = Path(args.dump)
    files = [src] if src.is_file() else sorted(src.glob("*after_optimizations.txt"))
    files = [f for f in files if re.search(args.module, f.name)]
    if not files:
        print(f"no *after_optimizations.txt under {src} matching {args.module!r}", file=sys.stderr)
        return 2
    lines = [f"command buffers in {len(files)} module(s) from {src}", ""]
    for f in files:
        mod = parse(f.read_text())
        has = any(is_command_buffer(c) for c in mod.computations)
        lines += render(f.name.split(".")[1] if "." in f.name else f.name, analyse(mod), has)
    emit("\n".join(lines), args.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
