"""Optimisation schedules and the parameter layout of one stage.

A schedule is a comma-separated list of stages, each a string of parameter letters: ``V`` (hfov),
``A``, ``B`` (K2, PanoTools' ``b``), ``C``, ``D``, ``E``, ``YPR`` (yaw, pitch, roll) and ``X`` (the
camera's centre, three coordinates; the bundle adjustment only). Letters after an
underscore are shared by all cameras in that stage: ``YPR,VBYPR`` first solves orientations with
the nominal lens, then everything per lens; ``YPR_VB`` solves orientations with one hfov and one K2
for the whole rig.

Per-lens letters follow the project's links: images linked in the ``.pto`` (``v=0``) share one
value; unlinked images have their own. The anchor image's yaw, pitch and roll stay fixed, which
removes the rotation of the whole rig that no control point can see; with ``X``, its centre stays
fixed too, which removes the rig's position (its scale needs a prior on the centres).
"""

from __future__ import annotations

from collections.abc import Collection, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, NamedTuple

import numpy as np

from ..errors import RigjaxError

if TYPE_CHECKING:
    from ..pto.project import Project

LENS_LETTERS = "VABCDE"
# Camera field and the internal unit of each letter: a, b, c are scaled by 100 as in libpano13
# (C_FACTOR), so every parameter moves the image by a comparable number of pixels per unit.
FIELD = {"V": "hfov", "A": "a", "B": "b", "C": "c", "D": "d", "E": "e", "Y": "yaw", "P": "pitch", "R": "roll"}
UNIT = {"V": 1.0, "A": 0.01, "B": 0.01, "C": 0.01, "D": 1.0, "E": 1.0, "Y": 1.0, "P": 1.0, "R": 1.0}
PTO_LETTER = {"V": "v", "A": "a", "B": "b", "C": "c", "D": "d", "E": "e", "Y": "y", "P": "p", "R": "r"}
# The slots of a camera's centre coordinates (letter X), beside the letters' in Layout.slot.
CENTRE_KEYS = ("cx", "cy", "cz")


class ScheduleError(RigjaxError):
    """A schedule that cannot be parsed; names the stage and the letter."""


@dataclass(frozen=True)
class Stage:
    """One stage: letters optimised per camera (lens letters per link group) and shared ones."""

    per_camera: tuple[str, ...]
    shared: tuple[str, ...] = ()

    @property
    def name(self) -> str:
        def spell(letters):
            lens = "".join(letter for letter in LENS_LETTERS if letter in letters)
            return lens + ("YPR" if "Y" in letters else "") + ("X" if "X" in letters else "")

        return spell(self.per_camera) + ("_" + spell(self.shared) if self.shared else "")


def _letters(text: str, stage: str) -> tuple[str, ...]:
    out: list[str] = []
    i = 0
    while i < len(text):
        if text.startswith("YPR", i):
            letters, i = ("Y", "P", "R"), i + 3
        elif text[i] in LENS_LETTERS + "X":
            letters, i = (text[i],), i + 1
        else:
            raise ScheduleError(
                f"stage {stage!r}: unknown parameter letter {text[i]!r} "
                f"(letters: V hfov, A, B (K2), C, D, E, YPR for yaw/pitch/roll, X for the centre)"
            )
        for letter in letters:
            if letter in out:
                raise ScheduleError(f"stage {stage!r}: {letter!r} is given twice")
            out.append(letter)
    return tuple(out)


def parse_schedule(schedule: str) -> tuple[Stage, ...]:
    """``"YPR,VBYPR"`` -> stages. Errors name the stage and the letter."""
    stages = []
    for text in schedule.replace(" ", "").split(","):
        if not text:
            raise ScheduleError(f"empty stage in schedule {schedule!r}")
        per_camera, _, shared = text.partition("_")
        if "_" in shared:
            raise ScheduleError(f"stage {text!r}: one '_' at most (per-camera letters, then shared ones)")
        pc, sh = _letters(per_camera, text), _letters(shared, text)
        for letter, what in (("Y", "yaw/pitch/roll are"), ("X", "centres are")):
            if letter in sh:
                raise ScheduleError(f"stage {text!r}: {what} per camera and cannot be shared")
        both = set(pc) & set(sh)
        if both:
            raise ScheduleError(f"stage {text!r}: {''.join(sorted(both))!r} both per camera and shared")
        if not pc and not sh:
            raise ScheduleError(f"stage {text!r} has no parameters")
        stages.append(Stage(pc, sh))
    return tuple(stages)


def has_centres(schedule: str) -> bool:
    """Whether a stage of ``schedule`` estimates camera centres (``X``)."""
    return any("X" in stage.per_camera for stage in parse_schedule(schedule))


def without_centres(schedule: str) -> str:
    """``schedule`` with its ``X`` letters left out (stages of nothing else dropped): the
    rotation-only solves that start a bundle adjustment."""
    stages = [Stage(tuple(x for x in s.per_camera if x != "X"), s.shared) for s in parse_schedule(schedule)]
    return ",".join(stage.name for stage in stages if stage.per_camera or stage.shared)


class Layout(NamedTuple):
    """Where each camera field of a stage comes from: ``slot[letter][k]`` indexes the parameter
    vector for image ``k``, or is -1 where the field keeps its value (``slot["cx"]`` ... for the
    centre's coordinates, :data:`CENTRE_KEYS`). Arrays, so that one
    compiled solve serves every rig of the same sizes."""

    slot: dict[str, np.ndarray]
    size: int
    names: tuple[str, ...]  # a readable name per parameter, e.g. "y1", "v0", "b*" (shared)


def variables_layout(variables, links: list[dict[str, int]]) -> tuple[Layout, tuple[str, ...]]:
    """The layout of a project's ``v`` lines, read as Hugin reads them (``autooptimiser -n``).

    A variable listed on an image whose letter is linked to a lower image is ignored, as Hugin
    ignores it (reference §4.5); so are photometric variables. Returns the layout and the
    variables left out, each with the reason.
    """
    letter_of = {pto: letter for letter, pto in PTO_LETTER.items()}
    n = len(links)
    slot = {key: np.full(n, -1, np.int32) for key in (*FIELD, *CENTRE_KEYS)}
    names: list[str] = []
    skipped: list[str] = []
    for var in variables:
        letter = letter_of.get(var.name)
        if letter is None:
            skipped.append(f"{var}: not a geometric variable (kept in the file, not optimised)")
            continue
        root = links[var.image].get(var.name, var.image)
        if root != var.image:
            skipped.append(f"{var}: linked to image {root}; list {var.name}{root} to optimise it (as Hugin)")
            continue
        if slot[letter][var.image] < 0:
            slot[letter][var.image] = len(names)
            names.append(str(var))
    for k in range(n):
        for pto, root in links[k].items():
            letter = letter_of.get(pto)
            if letter is not None and root != k:
                slot[letter][k] = slot[letter][root]
    return Layout(slot, len(names), tuple(names)), tuple(skipped)


def stage_layout(
    stage: Stage, links: list[dict[str, int]], anchor: int, hold_anchor: bool = True, derived: Collection[int] = ()
) -> Layout:
    """The parameter layout of ``stage`` for images with ``links`` (``Image.links``); with
    ``hold_anchor`` the anchor's yaw, pitch and roll (and those linked to them) are held; the
    ``derived`` images' yaw, pitch and roll are no parameters (they follow other images': a rig's
    camera in a later frame, :func:`rigjax.optimiser.bundle.bundle_adjust`'s ``rigid``)."""
    n = len(links)
    slot = {key: np.full(n, -1, np.int32) for key in (*FIELD, *CENTRE_KEYS)}
    names: list[str] = []
    for letter in stage.per_camera:
        if letter == "X":  # every centre but the anchor's, which fixes where the rig is
            for k in (k for k in range(n) if k != anchor):
                for key in CENTRE_KEYS:
                    slot[key][k] = len(names)
                    names.append(f"{key}{k}")
            continue
        for k in range(n):  # links point to lower images, whose slots exist already
            root = links[k].get(PTO_LETTER[letter], k)
            if letter in "YPR" and ((hold_anchor and anchor in (k, root)) or k in derived):
                continue  # the anchor, and images whose orientation is linked to it, stay fixed
            if root == k:
                slot[letter][k] = len(names)
                names.append(f"{PTO_LETTER[letter]}{k}")
            else:
                slot[letter][k] = slot[letter][root]
    for letter in stage.shared:
        slot[letter][:] = len(names)
        names.append(f"{PTO_LETTER[letter]}*")
    return Layout(slot, len(names), tuple(names))


def stage_layouts(
    project: Project,
    schedule: str,
    anchor: int,
    pto_vars: bool,
    hold_anchor: bool = True,
    derived: Collection[int] = (),
) -> tuple[list[tuple[str, Layout]], tuple[str, ...]]:
    """``(name, layout)`` of each stage of ``schedule`` for the project's images and lens links
    (:func:`stage_layout`), or with ``pto_vars`` the one stage of its ``v`` lines
    (:func:`variables_layout`); and the variables left out."""
    links = [dict(image.links) for image in project.images]
    if not pto_vars:
        stages = parse_schedule(schedule)
        return [(stage.name, stage_layout(stage, links, anchor, hold_anchor, derived)) for stage in stages], ()
    layout, not_optimised = variables_layout(project.variables, links)
    if layout.size == 0:
        raise RigjaxError("the project's v lines name no geometric variable to optimise")
    return [("v-lines", layout)], not_optimised


def reoptimised(parameters: Sequence[Sequence[str]]) -> list[list[int]]:
    """For each stage (given by its parameters), the later stages that optimise all of them again."""
    return [
        [j for j in range(k + 1, len(parameters)) if set(parameters[k]) <= set(parameters[j])]
        for k in range(len(parameters))
    ]
