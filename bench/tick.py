"""Cost of one UBF tick for a composite of 3, 30 and 100 children (µs per tick).

Beside it, when py_trees is installed, the cost of ticking a py_trees Selector of the same
number of failing leaves (every leaf runs, as every UBF child does), measured in the same run.

    python -m bench.tick [--ticks N] [--json FILE]
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from collections.abc import Callable
from typing import Any

from ubf_async import Action, Behavior, Composite, HighestActivation, PriorityMerge, State

SIZES = (3, 30, 100)


class Proposer(Behavior):
    """A leaf that reads the state and proposes an action, as a real behaviour would."""

    def __init__(self, index: int) -> None:
        super().__init__(name=f"leaf{index}")
        self.index = index

    def act(self, state: State) -> Action | None:
        bins = state.value("camera/front", "bins")
        if bins is None:
            return None
        return Action(speed=float(self.index % 50), turn=float(bins[self.index % 5] % 100))


class Constant(Behavior):
    """A leaf that returns a prebuilt action: the counterpart of py_trees' Failure leaf."""

    def __init__(self, index: int) -> None:
        super().__init__(name=f"leaf{index}")
        self.action = Action(speed=float(index % 50), turn=0.0)

    def act(self, state: State) -> Action | None:
        return self.action


def ubf_tree(n: int, arbiter_cls: type,
             leaf: Callable[[int], Behavior] = Proposer) -> Composite:
    return Composite(
        name="root", arbiter=arbiter_cls(), children=[leaf(i) for i in range(n)]
    )


def time_per_call(fn: Callable[[], object], ticks: int, repeats: int = 7) -> list[float]:
    """µs per call for each of ``repeats`` batches of ``ticks`` calls (after one warm-up)."""
    for _ in range(max(10, ticks // 10)):
        fn()
    out = []
    for _ in range(repeats):
        t0 = time.perf_counter_ns()
        for _ in range(ticks):
            fn()
        out.append((time.perf_counter_ns() - t0) / ticks / 1000)
    return out


def py_trees_selector(n: int) -> Callable[[], object] | None:
    try:
        import py_trees
    except ImportError:
        return None
    root = py_trees.composites.Selector(
        name="root",
        memory=False,
        children=[py_trees.behaviours.Failure(name=f"leaf{i}") for i in range(n)],
    )
    root.setup_with_descendants()
    return root.tick_once


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m bench.tick", description=__doc__.split("\n\n")[0]
    )
    parser.add_argument("--ticks", type=int, default=2000, help="ticks per timed batch")
    parser.add_argument("--json", metavar="FILE", help="also write the figures as JSON")
    args = parser.parse_args(argv)

    state = State.of(now_ns=0, camera__front={"bins": [0, 3, 140, 5, 0], "total": 148})
    rows = []
    for n in SIZES:
        row: dict[str, Any] = {"children": n}
        # Each timed call is one Python function bound to its tree by a default argument (a
        # def, not a lambda: mypy cannot type a lambda's defaults).
        tree = ubf_tree(n, HighestActivation, Constant)

        def act_constant(tree: Composite = tree) -> object:
            return tree.act(state)

        row["ubf_constant_leaves_us"] = statistics.median(time_per_call(
            act_constant, args.ticks))
        for label, arbiter in (("HighestActivation", HighestActivation),
                               ("PriorityMerge", PriorityMerge)):
            tree = ubf_tree(n, arbiter)

            def act(tree: Composite = tree) -> object:
                return tree.act(state)

            row[f"ubf_{label}_act_us"] = statistics.median(time_per_call(act, args.ticks))
        tree = ubf_tree(n, PriorityMerge)

        def render(tree: Composite = tree) -> object:
            return tree.evaluate(state).render()

        row["ubf_trace_render_us"] = statistics.median(time_per_call(
            render, max(100, args.ticks // 10)))
        tick = py_trees_selector(n)
        row["py_trees_us"] = (
            statistics.median(time_per_call(tick, args.ticks)) if tick is not None else None
        )
        rows.append(row)

    print("Tick cost, µs per tick (median of 7 batches; lower is better)")
    print("  constant: HighestActivation over leaves returning a prebuilt action")
    print("            (the like-for-like counterpart of a py_trees Selector of Failure leaves)")
    print("  working:  leaves that read the camera bins from the state and build an Action")
    print("  +render:  PriorityMerge tick plus building and rendering the full explanation")
    header = (f"{'children':>8}  {'constant':>9}  {'working HA':>10}  {'working PM':>10}  "
              f"{'+render':>8}  {'py_trees':>9}  {'py_trees/constant':>17}")
    print(header)
    for row in rows:
        pt = row["py_trees_us"]
        const = row["ubf_constant_leaves_us"]
        print(
            f"{row['children']:>8}  {const:>9.1f}  {row['ubf_HighestActivation_act_us']:>10.1f}"
            f"  {row['ubf_PriorityMerge_act_us']:>10.1f}  {row['ubf_trace_render_us']:>8.1f}  "
            + (f"{pt:>9.1f}  {pt / const:>16.1f}x" if pt is not None
               else f"{'skipped (py_trees not installed)':>28}")
        )
    if args.json:
        with open(args.json, "w", encoding="utf-8") as fh:
            json.dump({"rows": rows}, fh, indent=2)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
