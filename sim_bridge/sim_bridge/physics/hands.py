"""The hands a simulation can be built with, by name: "2f85", the paper's Robotiq 2F-85
(hand_model), and "panda", the Franka Emika hand the baselines were made for
(panda_hand). A hand is a choice of the world (world.WorldSettings.hand), not a fork of it.

Each `HandSpec` says how to add the hand to a plant and what the rest needs to know:
its opening, the links of each finger (ground truth: an object touching both is in the
hand) and the links whose contact means the object sits deep in the hand (a power grasp).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

from . import hand_model, panda_hand


@dataclass(frozen=True)
class HandSpec:
    name: str
    title: str
    max_opening_m: float
    left_links: tuple
    right_links: tuple
    inner_links: tuple  # touching these means a power grasp (palm, proximal links)
    mount_body: str  # the body a floating hand floats on
    # (plant, scene_graph, proximity_properties, floating, pad_contact_points, baselines_dir) -> hand
    add: Callable

    @property
    def finger_links(self) -> frozenset:
        return frozenset(self.left_links + self.right_links)


def _add_2f85(plant, scene_graph, props, floating, pad_contact_points, baselines_dir):
    return hand_model.add_hand(plant, scene_graph, props, floating=floating, pad_contact_points=pad_contact_points)


def _add_panda(plant, scene_graph, props, floating, pad_contact_points, baselines_dir):
    return panda_hand.add_panda_hand(plant, scene_graph, props, floating=floating,
                                     pad_contact_points=pad_contact_points, baselines_dir=baselines_dir)


HANDS = {
    "2f85": HandSpec(
        "2f85", "Robotiq 2F-85 (the paper's hand)", hand_model.MAX_STROKE_M,
        hand_model.LEFT_LINKS + ("left_silicone_pad",), hand_model.RIGHT_LINKS + ("right_silicone_pad",),
        hand_model.PALM_LINKS + hand_model.PROXIMAL_LINKS, "base_mount", _add_2f85),
    "panda": HandSpec(
        "panda", "Franka Emika (Panda) hand (the baselines' hand)", panda_hand.MAX_OPENING_M,
        panda_hand.LEFT_LINKS, panda_hand.RIGHT_LINKS, panda_hand.PALM_LINKS, panda_hand.MOUNT_BODY, _add_panda),
}


def hand_spec(name: str) -> HandSpec:
    """The HandSpec named `name`; ValueError naming the hands there are otherwise."""
    try:
        return HANDS[name]
    except (KeyError, TypeError):
        known = ", ".join(f"{n!r} ({s.title})" for n, s in HANDS.items())
        raise ValueError(f"hand {name!r} does not exist: use one of {known}") from None
