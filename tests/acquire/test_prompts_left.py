"""`estimate.prompts_left` (after every reading, for the remaining-time estimate) counts the
prompts still to ask from the plan's per-prompt key sets: the same count as walking the plan."""

from __future__ import annotations

import random

import pytest

from normbox_lab.acquire.engine import build_plan
from normbox_lab.acquire.estimate import prompts_left


def walked(plan, committed) -> int:
    """The count by walking the steps after each prompt (the definition)."""
    done = set(committed)
    count = 0
    for i, s in enumerate(plan.steps):
        if s.kind != "prompt":
            continue
        for later in plan.steps[i + 1:]:
            if later.kind == "prompt" and set(s.sets) & set(later.sets):
                break
            if later.commits and later.key not in done:
                count += 1
                break
    return count


PLANS = [("brdf-inplane", {"materials": [1, 2, 3, "wall"]}),
         ("reference-sweep", {"angles_deg": [30, 60, 90], "patches": [19, 13, 7, 24]}),
         ("repeatability", None), ("light-map", None)]


@pytest.mark.parametrize("protocol,params", PLANS)
def test_prompts_left_is_the_walked_count_for_every_prefix_and_random_sets(protocol, params):
    plan = build_plan(protocol, params)
    keys = plan.commit_keys
    for n in range(len(keys) + 1):
        assert prompts_left(plan, keys[:n]) == walked(plan, keys[:n]), (protocol, n)
    rng = random.Random(7)
    for _ in range(50):
        subset = [k for k in keys if rng.random() < 0.8]
        assert prompts_left(plan, subset) == walked(plan, subset)
        assert prompts_left(plan, set(subset)) == walked(plan, subset)


def test_prompts_left_counts_one_per_material_and_one_per_sweep_reading():
    brdf = build_plan("brdf-inplane", {"materials": [1, 2, 3, "wall"]})
    keys = brdf.commit_keys
    per_material = len(keys) // 4
    assert prompts_left(brdf, []) == 4
    assert prompts_left(brdf, keys[:per_material - 1]) == 4     # the first still has one left
    assert prompts_left(brdf, keys[:per_material]) == 3
    assert prompts_left(brdf, keys) == 0
    sweep = build_plan("reference-sweep", {"angles_deg": [30, 60], "patches": [19, 13]})
    assert prompts_left(sweep, []) == 4
    assert prompts_left(sweep, sweep.commit_keys[:3]) == 1
