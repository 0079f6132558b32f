"""Genomes (ubf_async.runs.evolve.genome): every individual any operator makes, from any
parents, is a robot file the loader takes, within the SPEC's bounds; and its canonical text
is one text.

No run here: the operators and the loader only (a few seconds of CPU).
"""

from __future__ import annotations

import random

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from tests.conftest import REPOSITORY
from ubf_async.assembly.robotfile import load_robot_text
from ubf_async.runs.evolve import genome
from ubf_async.runs.evolve.loop import Individual
from ubf_async.runs.evolve.spec import EvolvePlan, load_evolve

SPEC = REPOSITORY / "examples" / "evolve" / "mini-whegs.yaml"
PLAN: EvolvePlan = load_evolve(SPEC, probe=False)


def individual(rng: random.Random) -> genome.Node:
    """The seed tree, a random tree, or one of them changed by a few operators."""
    space = PLAN.space
    tree = PLAN.seed_tree if rng.random() < 0.4 else space.tree(rng, min(space.max_depth, 3))
    for _ in range(rng.randint(0, 4)):
        step = genome.OPERATORS[rng.choice(sorted(genome.OPERATORS))](space, rng, tree, tree)
        if step is not None and space.fits(step) and genome.is_composite(step):
            tree = step
    return tree


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2**32 - 1), operator=st.sampled_from(sorted(genome.OPERATORS)))
def test_every_operators_child_loads_as_a_robot_file(seed: int, operator: str) -> None:
    rng = random.Random(seed)
    a, b = individual(rng), individual(rng)
    child = genome.OPERATORS[operator](PLAN.space, rng, a, b)
    if child is None:  # the operator does not apply to this tree: nothing made
        return
    made = Individual.of(PLAN, child)
    robot = load_robot_text(made.text, source=f"{operator}-{seed}.yaml")  # raises if not one
    assert robot.root.name == PLAN.seed_tree["name"] or not genome.is_composite(child)
    # The canonical form is a fixed point: the text read back is the same text.
    again = Individual.of(PLAN, made.tree)
    assert again.text == made.text and again.hash == made.hash
    # Every Conditional keeps exactly its two children.
    for _, node in genome.walk(made.tree):
        if genome.is_composite(node) and genome.arbiter_kind(node) == genome.CONDITIONAL:
            assert len(node["children"]) == 2, made.text


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**32 - 1))
def test_drawn_and_mutated_values_stay_in_the_specs_ranges(seed: int) -> None:
    rng = random.Random(seed)
    tree = individual(rng)
    for _ in range(5):
        tree = genome.mutate_parameter(PLAN.space, rng, tree, tree) or tree
    for _, node in genome.walk(tree):
        genes = PLAN.space.behaviors.get(node.get("behavior", ""), {})
        for name, value in (node.get("params") or {}).items():
            gene = genes.get(name)
            if isinstance(gene, genome.Range):
                assert gene.low <= value <= gene.high, (name, value)
                assert isinstance(value, int) == gene.integer or not gene.integer


def test_the_seed_robot_is_the_shipped_tree_without_its_remote_slots() -> None:
    shipped = load_robot_text(PLAN.seed_text(), source="seed")
    assert [c.behavior.name for c in shipped.root.children] == ["search", "chase", "flee"]
    assert shipped.remotes == []
    assert PLAN.seed_tree["arbiter"] == "PriorityMerge"
