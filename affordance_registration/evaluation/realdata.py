# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""Real Kinect tabletop scans with a label per point (mOSD's 45 *learn* scenes), the labelled
objects in them, what each one is (box, cylinder or neither, its pose, stacking and occlusion:
our annotation, :data:`OBJECTS`; ``docs/REAL_DATA.md`` tabulates it), the fixed split into
tuning and held-out scenes, where an operator clicks an object, an analytic surface distance for
the primitive kinds, a local noise estimate, the label-based score of a primitive fit, and a
driver that clicks every labelled object of a scene with a :class:`Registrar`.

Where the data is: ``$AFFORDANCE_SHARED_DATA``, else ``../shared/data`` next to the project
root (the folder that holds ``setup.py``); :func:`shared_data_dir` is None when neither exists
(tests then skip). The files are never copied into the project.

Primitive frames (the template file's convention): a **box**'s origin is the centre of its base
face, +z up out of the surface it stands on, x along the longer horizontal edge; its
``dimensions`` ``{"x", "y", "z"}`` are full edge lengths (m), so it spans
[-x/2, x/2] x [-y/2, y/2] x [0, z] in its frame. A **cylinder**'s origin is the centre of one end
face, +z along its axis; ``{"radius", "length"}``: it spans radius r about the z axis, z in
[0, length]. Both are posed by ``T_scene_model`` (4x4, model -> scene).
"""

from __future__ import annotations

import os
import re
import time
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from ..core.errors import AffordanceError, SceneError
from ..core.meshes import primitive_distance as core_primitive_distance
from ..core.pointfiles import check_header, header_lines
from .simulation import CameraIntrinsics

__all__ = [
    "DATA_ENV",
    "SKIP_REASON",
    "SCENE_KINDS",
    "ORIGINAL_SCENES",
    "HELD_OUT",
    "MIN_OBJECT_POINTS",
    "MIN_TOLERANCE",
    "NOISE_SIGMAS",
    "PASS_RECALL",
    "PASS_PRECISION",
    "shared_data_dir",
    "osd_dir",
    "osd_scene_paths",
    "scene_name",
    "scene_kind",
    "is_held_out",
    "ALL_OF_KIND",
    "uniform_kind",
    "ObjectNote",
    "OBJECTS",
    "OBJECT_KINDS",
    "object_note",
    "object_kind",
    "LabelledCloud",
    "object_ids",
    "read_labelled_pcd",
    "Intrinsics",
    "fit_intrinsics",
    "LabelledObject",
    "labelled_objects",
    "click_in_middle",
    "table_points",
    "fit_plane",
    "box_distance",
    "cylinder_distance",
    "primitive_distance",
    "inside_region",
    "local_noise",
    "PrimitiveScore",
    "score_primitive",
    "score_points",
    "fit_record",
    "evaluate_scene",
    "SENSOR_ORIGIN",
]

#: the environment variable that points at the shared real data (a folder holding osd/, pcl/)
DATA_ENV = "AFFORDANCE_SHARED_DATA"
#: the one line a test skips with when the data is absent
SKIP_REASON = "real data not found: set AFFORDANCE_SHARED_DATA or provide ../shared/data"
#: mOSD scans are in the camera's optical frame, the sensor at its origin (VIEWPOINT 0 0 0)
SENSOR_ORIGIN = (0.0, 0.0, 0.0)

#: the shared learn scenes by kind: mOSD's own grouping of its learn split (learn 0-16 boxes,
#: 17-24 stacked boxes, 25-32 occluded objects, 33-44 cylindric objects)
SCENE_KINDS = {
    "boxes": tuple(range(0, 17)),
    "stacked boxes": tuple(range(17, 25)),
    "occluded objects": tuple(range(25, 33)),
    "cylinders": tuple(range(33, 45)),
}
#: the 15 learn scenes the shared data held before it held all 45 (four of each group, five
#: boxes): the earlier rounds were tuned and measured on these, and the tests that assert their
#: figures (37 objects, 34 of them boxes or cylinders, "this code: 30 of 34") still run on them
ORIGINAL_SCENES = (0, 4, 8, 12, 16, 17, 20, 24, 25, 28, 32, 33, 37, 41, 44)
#: held out of any tuning, about a third of each group: the four held out since the first
#: round (learn12 of the boxes -- learn16 was looked at while the verdict was developed -- and
#: the last of each other group; learn44 holds a mug split into two labelled parts) and eleven
#: scenes that arrived with the whole learn split and were never tuned on: boxes 2, 6, 10, 14
#: (5 of 17), stacked 18, 22 (3 of 8), occluded 26, 30 (3 of 8), cylinders 34, 38, 42 (4 of 12)
HELD_OUT = (2, 6, 10, 12, 14, 18, 22, 24, 26, 30, 32, 34, 38, 42, 44)
#: a labelled object counts when it has at least this many valid points
MIN_OBJECT_POINTS = 1500


@dataclass(frozen=True)
class ObjectNote:
    """What one labelled object of a learn scene is, as an operator sees it in the scan's colour
    image (our annotation: mOSD labels which points are one object, not what it is).

    ``kind``: "box", "cylinder" (a closed one: tins, cans, jars, a tub upside down, mugs -- an
    open top is in the description, a mug is scored by the labels like every object) or
    "other" (a bowl, an open tub: no closed box or cylinder explains it; the product should say
    "no template fits here"). ``pose``: "standing" or "lying" -- "lying" only for a cylinder
    whose axis lies level (a box on a long face stands on it). ``stacked``: "" or "on N" /
    "under N" / "on N, under M" (N, M: object ids of the scene; leaning on another counts as
    on it). ``hidden``: roughly what share of the object's surface facing the sensor other
    objects hide (0 for none; in steps of 0.05), ``hidden_by`` their ids. ``description``: a few
    words."""

    kind: str
    pose: str
    stacked: str
    hidden: float
    description: str
    hidden_by: tuple = ()

    @property
    def on(self) -> tuple:
        """The ids of the objects this one stands on (from ``stacked``)."""
        return _stack_ids(self.stacked, "on")

    @property
    def under(self) -> tuple:
        """The ids of the objects standing on this one (from ``stacked``)."""
        return _stack_ids(self.stacked, "under")


def _stack_ids(stacked: str, word: str) -> tuple:
    return tuple(
        int(n)
        for part in stacked.split(",")
        if part.split() and part.split()[0] == word
        for n in part.split()[1:]
    )


_B, _C, _O = "box", "cylinder", "other"
_ST, _LY = "standing", "lying"

#: every labelled object (>= MIN_OBJECT_POINTS; none of the 45 scenes has a smaller one) of
#: the 45 learn scenes: {scene number: {object id: ObjectNote}}, read from each scan's colour
#: image with its objects outlined and numbered, and checked against a box and a cylinder fitted
#: to each object's labelled points (``docs/REAL_DATA.md``)
OBJECTS = {
    # ---- boxes (learn 0-16)
    0: {
        2: ObjectNote(_B, _ST, "", 0.0, "red muesli-bar box, in front"),
        3: ObjectNote(_B, _ST, "", 0.55, "red and blue cereal box behind it", (2,)),
    },
    1: {
        2: ObjectNote(_B, _ST, "", 0.0, "red muesli-bar box, in front"),
        3: ObjectNote(_B, _ST, "", 0.2, "green Kellogg's cereal box", (2,)),
    },
    2: {
        2: ObjectNote(_B, _ST, "", 0.0, "yellow and white muesli box, in front"),
        3: ObjectNote(_B, _ST, "", 0.25, "red Kellogg's cereal box", (2,)),
    },
    3: {
        2: ObjectNote(_B, _ST, "", 0.0, "yellow Gittis muesli box"),
        3: ObjectNote(_B, _ST, "", 0.15, "red Kellogg's cereal box on its side", (2,)),
    },
    4: {
        2: ObjectNote(_B, _ST, "", 0.0, "yellow Gittis muesli box"),
        3: ObjectNote(_B, _ST, "", 0.1, "red Kellogg's cereal box on its side", (2,)),
    },
    5: {
        2: ObjectNote(_B, _ST, "", 0.0, "large cereal box with a green top"),
        3: ObjectNote(_B, _ST, "", 0.35, "brown Toffifee box behind it", (2,)),
    },
    6: {
        2: ObjectNote(_B, _ST, "", 0.0, "small yellow-green tea box, in front"),
        3: ObjectNote(_B, _ST, "", 0.2, "red Kellogg's cereal box on its side", (2,)),
    },
    7: {
        2: ObjectNote(_B, _ST, "", 0.0, "red Kellogg's cereal box on its side, in front"),
        3: ObjectNote(_B, _ST, "", 0.6, "small tea box behind it, its lower part hidden", (2,)),
    },
    8: {
        2: ObjectNote(_B, _ST, "", 0.0, "red Kellogg's cereal box on its side, in front"),
        3: ObjectNote(_B, _ST, "", 0.5, "small tea box behind it, its lower part hidden", (2,)),
    },
    9: {
        2: ObjectNote(_B, _ST, "", 0.0, "small yellow tea box, in front"),
        3: ObjectNote(_B, _ST, "", 0.1, "red Kellogg's cereal box standing tall", (2,)),
    },
    10: {
        2: ObjectNote(_B, _ST, "", 0.0, "yellow-green tea box lying flat, in front"),
        3: ObjectNote(_B, _ST, "", 0.05, "red Kellogg's cereal box standing tall", (2,)),
    },
    11: {
        2: ObjectNote(_B, _ST, "", 0.0, "yellow Gittis muesli box"),
        3: ObjectNote(
            _B, _ST, "", 0.35, "tea box lying flat, one end behind the muesli box", (2,)
        ),
    },
    12: {
        2: ObjectNote(_B, _ST, "", 0.0, "yellow Gittis muesli box"),
        3: ObjectNote(_B, _ST, "", 0.2, "red cereal box lying flat, one end behind box 2", (2,)),
    },
    13: {
        2: ObjectNote(_B, _ST, "", 0.0, "yellow Gittis muesli box, in front"),
        3: ObjectNote(_B, _ST, "", 0.1, "small yellow tea box", (2,)),
        4: ObjectNote(_B, _ST, "", 0.25, "red and blue muesli-bar box behind", (2,)),
    },
    14: {
        2: ObjectNote(_B, _ST, "", 0.0, "yellow Gittis muesli box, in front"),
        3: ObjectNote(_B, _ST, "", 0.5, "cereal box on its side behind it", (2,)),
        4: ObjectNote(_B, _ST, "", 0.55, "small tea box at the back, its lower part hidden", (3,)),
    },
    15: {
        2: ObjectNote(_B, _ST, "", 0.0, "small yellow tea box, in front"),
        3: ObjectNote(_B, _ST, "", 0.2, "yellow Gittis muesli box", (2,)),
        4: ObjectNote(_B, _ST, "", 0.55, "cereal box on its side at the back", (3,)),
    },
    16: {
        2: ObjectNote(_B, _ST, "", 0.0, "small yellow tea box, in front"),
        3: ObjectNote(_B, _ST, "", 0.25, "yellow Gittis muesli box", (2,)),
        4: ObjectNote(_B, _ST, "", 0.65, "red box at the back, its lower part hidden", (3,)),
    },
    # ---- stacked boxes (learn 17-24)
    17: {
        2: ObjectNote(_B, _ST, "under 3", 0.35, "large flat yellow biscuit box", (3,)),
        3: ObjectNote(_B, _ST, "on 2", 0.0, "white biscuit box lying flat on it"),
    },
    18: {
        2: ObjectNote(_B, _ST, "on 3", 0.0, "white biscuit box lying flat on box 3"),
        3: ObjectNote(_B, _ST, "under 2", 0.45, "large flat yellow biscuit box", (2,)),
    },
    19: {
        2: ObjectNote(_B, _ST, "under 3", 0.35, "large flat yellow biscuit box", (3,)),
        3: ObjectNote(_B, _ST, "on 2", 0.0, "white biscuit box lying flat on it"),
    },
    20: {
        2: ObjectNote(_B, _ST, "under 3", 0.2, "large flat yellow biscuit box", (3,)),
        3: ObjectNote(_B, _ST, "on 2", 0.0, "yellow Gittis muesli box standing on it"),
    },
    21: {
        2: ObjectNote(_B, _ST, "under 3", 0.45, "large flat yellow biscuit box", (3,)),
        3: ObjectNote(_B, _ST, "on 2, under 4", 0.3, "red cereal box lying flat on it", (4,)),
        4: ObjectNote(_B, _ST, "on 3", 0.0, "yellow Gittis muesli box on its side on top"),
    },
    22: {
        2: ObjectNote(_B, _ST, "under 3", 0.4, "large flat yellow biscuit box", (3,)),
        3: ObjectNote(_B, _ST, "on 2, under 4", 0.35, "white biscuit box lying flat on it", (4,)),
        4: ObjectNote(_B, _ST, "on 3", 0.0, "red cereal box lying flat on top"),
    },
    23: {
        2: ObjectNote(_B, _ST, "under 3", 0.45, "large flat yellow biscuit box", (3,)),
        3: ObjectNote(_B, _ST, "on 2, under 4", 0.3, "red cereal box on its side on it", (4,)),
        4: ObjectNote(_B, _ST, "on 3", 0.0, "yellow Gittis muesli box lying flat on top"),
    },
    24: {
        2: ObjectNote(_B, _ST, "", 0.0, "yellow Gittis muesli box on its side, in front"),
        3: ObjectNote(_B, _ST, "on 4", 0.0, "red cereal box lying flat across box 4"),
        4: ObjectNote(_B, _ST, "under 3", 0.6, "yellow box behind box 2, in two parts", (2, 3)),
    },
    # ---- occluded objects (learn 25-32)
    25: {
        2: ObjectNote(_B, _ST, "under 3", 0.35, "flat white and red cereal box", (3,)),
        3: ObjectNote(_B, _ST, "on 2", 0.0, "yellow Vitalis muesli box lying flat across it"),
    },
    26: {
        2: ObjectNote(_B, _ST, "on 3", 0.0, "yellow Vitalis muesli box leaning on box 3"),
        3: ObjectNote(_B, _ST, "under 2", 0.3, "flat biscuit box lying behind it", (2,)),
    },
    27: {
        2: ObjectNote(_B, _ST, "", 0.0, "red muesli-bar box, in front"),
        3: ObjectNote(_B, _ST, "", 0.7, "flat yellow biscuit box behind it, in two parts", (2,)),
    },
    28: {
        2: ObjectNote(_B, _ST, "", 0.0, "tall narrow yellow box, in front"),
        3: ObjectNote(_B, _ST, "", 0.45, "flat cereal box behind it, in two parts", (2,)),
    },
    29: {
        2: ObjectNote(_B, _ST, "", 0.0, "yellow Gittis muesli box end-on, in front"),
        3: ObjectNote(_B, _ST, "", 0.35, "flat yellow biscuit box behind it, in two parts", (2,)),
    },
    30: {
        2: ObjectNote(_B, _ST, "", 0.0, "grey square block, in front"),
        3: ObjectNote(_C, _LY, "", 0.3, "yellow crisps can lying behind it, in two parts", (2,)),
    },
    31: {
        2: ObjectNote(_C, _ST, "", 0.0, "yellow crisps can with a white lid, in front"),
        3: ObjectNote(_B, _ST, "", 0.35, "flat cereal box behind it, in two parts", (2,)),
    },
    32: {
        2: ObjectNote(_B, _ST, "", 0.0, "red muesli-bar box, in front"),
        3: ObjectNote(_C, _LY, "", 0.45, "yellow crisps can lying behind it, in two parts", (2,)),
    },
    # ---- cylindric objects (learn 33-44)
    33: {
        2: ObjectNote(_C, _ST, "", 0.0, "round brown biscuit tin with its lid"),
        3: ObjectNote(_C, _ST, "", 0.0, "round yellow tub upside down (its bottom up)"),
        4: ObjectNote(_O, _ST, "", 0.0, "open white bowl"),
        5: ObjectNote(_C, _ST, "", 0.0, "white mug with a picture, open top"),
        6: ObjectNote(_C, _ST, "", 0.05, "white mug, open top", (5,)),
    },
    34: {
        2: ObjectNote(_C, _LY, "", 0.0, "round brown biscuit tin standing on its rim"),
        3: ObjectNote(_C, _ST, "", 0.0, "round yellow tub upside down, two lugs"),
        4: ObjectNote(_O, _ST, "", 0.0, "open white bowl"),
    },
    35: {
        2: ObjectNote(_C, _ST, "", 0.1, "round yellow tub upside down", (3,)),
        3: ObjectNote(_C, _ST, "", 0.0, "round brown biscuit tin with its lid"),
        4: ObjectNote(_O, _ST, "", 0.0, "open white bowl"),
    },
    36: {
        2: ObjectNote(_C, _ST, "", 0.0, "round brown biscuit tin with its lid"),
        3: ObjectNote(_O, _ST, "", 0.0, "open white bowl"),
        4: ObjectNote(_O, _ST, "", 0.0, "open yellow tub with two lugs"),
    },
    37: {
        2: ObjectNote(_C, _LY, "", 0.0, "round brown biscuit tin lying on its rim"),
        3: ObjectNote(_O, _ST, "", 0.0, "white bowl upside down (a dome)"),
        4: ObjectNote(_O, _ST, "", 0.0, "open yellow tub with two lugs"),
    },
    38: {
        2: ObjectNote(_C, _ST, "", 0.0, "white mug upside down"),
        3: ObjectNote(_C, _ST, "", 0.0, "white mug with a picture, upside down"),
        4: ObjectNote(_C, _LY, "", 0.0, "round brown biscuit tin lying on its rim"),
        5: ObjectNote(_O, _ST, "", 0.0, "open yellow tub with two lugs"),
    },
    39: {
        2: ObjectNote(_C, _ST, "", 0.0, "round brown biscuit tin with its lid"),
        3: ObjectNote(_C, _ST, "", 0.0, "white mug, open top"),
        4: ObjectNote(_C, _ST, "", 0.0, "white mug with a picture, open top"),
        5: ObjectNote(_C, _ST, "", 0.0, "round yellow tub upside down, two lugs"),
    },
    40: {
        2: ObjectNote(_C, _ST, "", 0.0, "round brown biscuit tin with its lid"),
        3: ObjectNote(_C, _ST, "", 0.0, "small white tin with red flowers"),
        4: ObjectNote(_C, _ST, "", 0.0, "round yellow tub upside down, two lugs"),
    },
    41: {
        2: ObjectNote(_C, _ST, "under 3", 0.5, "round brown biscuit tin", (3,)),
        3: ObjectNote(_C, _ST, "on 2", 0.0, "round yellow tub upside down on the tin"),
    },
    42: {
        2: ObjectNote(_C, _ST, "under 3", 0.15, "round brown biscuit tin", (3,)),
        3: ObjectNote(_C, _ST, "on 2", 0.0, "small white tin with red flowers on the tin"),
    },
    43: {
        2: ObjectNote(_C, _LY, "", 0.0, "yellow crisps can lying on its side"),
        3: ObjectNote(_C, _ST, "", 0.0, "round brown biscuit tin with its lid"),
        4: ObjectNote(_C, _ST, "", 0.0, "tall glass jar with a black lid"),
    },
    44: {
        2: ObjectNote(_C, _ST, "", 0.0, "round brown biscuit tin with its lid"),
        3: ObjectNote(_C, _ST, "", 0.0, "yellow crisps can with a white lid"),
        4: ObjectNote(_C, _ST, "", 0.0, "white mug with a picture, open top"),
    },
}
#: what each annotated object is, by scene: {scene: {id: "box" | "cylinder" | "other"}}
#: (:data:`OBJECTS`' kinds). The primitive rows' recall and precision count the boxes and
#: cylinders: an "other" has no right primitive.
OBJECT_KINDS = {
    scene: {k: note.kind for k, note in notes.items()} for scene, notes in OBJECTS.items()
}
#: the scenes whose objects are all of one primitive kind (from :data:`OBJECTS`): every scene
#: of learn 0-29 holds boxes only; of the cylinder scenes, learn39-44 hold closed cylinders only
#: (learn33-38 a bowl or an open tub each)
ALL_OF_KIND = {
    kind: tuple(
        n for n, notes in OBJECTS.items() if {note.kind for note in notes.values()} == {kind}
    )
    for kind in ("box", "cylinder")
}

#: the scoring rule's tolerance: max(MIN_TOLERANCE, NOISE_SIGMAS * local noise) (m)
MIN_TOLERANCE = 0.006
NOISE_SIGMAS = 3.0
#: an object passes with recall and precision at least these
PASS_RECALL = 0.9
PASS_PRECISION = 0.9


# ---------------------------------------------------------------------------- where the data is
def _project_root() -> str:
    """The repository folder holding setup.py (this file is <root>/affordance_registration/
    evaluation/realdata.py)."""
    return os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def shared_data_dir() -> str | None:
    """The shared real-data folder: ``$AFFORDANCE_SHARED_DATA`` when set (None if it is not a
    folder), else ``../shared/data`` relative to the project root; None when absent."""
    env = os.environ.get(DATA_ENV)
    if env:
        return os.path.abspath(env) if os.path.isdir(env) else None
    path = os.path.normpath(os.path.join(_project_root(), "..", "shared", "data"))
    return path if os.path.isdir(path) else None


def osd_dir(data_dir: str | None = None) -> str | None:
    """The folder of the mOSD scenes (``<data>/osd``), or None."""
    data_dir = data_dir or shared_data_dir()
    path = os.path.join(data_dir, "osd") if data_dir else None
    return path if path and os.path.isdir(path) else None


def scene_name(path: str) -> str:
    """``learn12`` for ``.../learn12.pcd``."""
    return os.path.splitext(os.path.basename(str(path)))[0]


def _scene_number(name: str) -> int:
    match = re.fullmatch(r"learn(\d+)", scene_name(name))
    if not match:
        raise AffordanceError(f"{name}: not an mOSD learn scene name (learn<N>)")
    return int(match.group(1))


def scene_kind(name: str) -> str:
    """The kind of a learn scene (a key of :data:`SCENE_KINDS`)."""
    number = _scene_number(name)
    for kind, numbers in SCENE_KINDS.items():
        if number in numbers:
            return kind
    raise AffordanceError(f"{name}: not one of the shared learn scenes")


def uniform_kind(name: str) -> str | None:
    """The primitive kind every object of a learn scene is ("box" | "cylinder"), or None
    (:data:`ALL_OF_KIND`)."""
    number = _scene_number(name)
    return next((k for k, numbers in ALL_OF_KIND.items() if number in numbers), None)


def object_note(name: str, object_id: int) -> ObjectNote:
    """The annotation of object ``object_id`` of a learn scene (:data:`OBJECTS`); raises
    :class:`AffordanceError` for an object not annotated."""
    note = OBJECTS.get(_scene_number(name), {}).get(int(object_id))
    if note is None:
        raise AffordanceError(f"{scene_name(name)}: object {object_id} is not annotated")
    return note


def object_kind(name: str, object_id: int) -> str:
    """What object ``object_id`` of a learn scene is ("box", "cylinder", "other";
    :data:`OBJECTS`); raises :class:`AffordanceError` for an object not annotated."""
    return object_note(name, object_id).kind


def is_held_out(name: str) -> bool:
    """Whether a learn scene is held out of tuning (:data:`HELD_OUT`)."""
    return _scene_number(name) in HELD_OUT


def osd_scene_paths(
    data_dir: str | None = None, held_out: bool | None = None, scenes=None
) -> list[str]:
    """The shared learn scenes in :data:`SCENE_KINDS` order that exist under ``data_dir``:
    all (``held_out`` None), the tuning ones (False) or the held-out ones (True); of the scene
    numbers ``scenes`` only where given (e.g. :data:`ORIGINAL_SCENES`)."""
    folder = osd_dir(data_dir)
    if folder is None:
        return []
    wanted = None if scenes is None else {int(n) for n in scenes}
    out = []
    for numbers in SCENE_KINDS.values():
        for n in numbers:
            if wanted is not None and n not in wanted:
                continue
            path = os.path.join(folder, f"learn{n}.pcd")
            if os.path.isfile(path) and (held_out is None or (n in HELD_OUT) == held_out):
                out.append(path)
    return out


# ---------------------------------------------------------------------------- reading a scene
@dataclass(frozen=True)
class LabelledCloud:
    """An organized labelled scan: ``points`` (H, W, 3) float64 metres, NaN where invalid;
    ``labels`` (H, W) int64 (0 invalid, 1-9 the table, 10k..10k+9 parts of object k);
    ``viewpoint`` (3,) the sensor origin (the PCD's VIEWPOINT); ``colors`` (H, W, 3) uint8 RGB,
    the registered colour image (every pixel, invalid ones too), or None where the file has no
    8-bit colour field."""

    name: str
    points: np.ndarray = field(repr=False)
    labels: np.ndarray = field(repr=False)
    viewpoint: np.ndarray = field(repr=False)
    colors: np.ndarray | None = field(default=None, repr=False)

    @property
    def shape(self) -> tuple:
        return self.labels.shape

    @property
    def valid(self) -> np.ndarray:
        """(H, W) bool: a finite point."""
        return np.all(np.isfinite(self.points), axis=-1)

    @property
    def object_ids(self) -> np.ndarray:
        """(H, W) int64: the object id of each pixel (:func:`object_ids`)."""
        return object_ids(self.labels)


def object_ids(labels: np.ndarray) -> np.ndarray:
    """The object id of each of mOSD's ``labels`` (label // 10; 0 for the table, invalid
    points and anything labelled below 10, such as a placed object's -1)."""
    return np.where(labels >= 10, labels // 10, 0)


def read_labelled_pcd(path: str) -> LabelledCloud:
    """Read an mOSD PCD (organized, any PCD DATA kind, fields including ``label x y z``).

    The header is checked by :func:`core.pointfiles.check_header` (size, POINTS, VIEWPOINT) and
    its WIDTH / HEIGHT read with the same header parser; the values by Open3D's tensor reader,
    which keeps a ``label`` field and the colour (``rgba`` / ``rgb``; ``core.pointfiles.
    read_points`` returns x, y, z only, and no organized shape for a PCD). Raises
    :class:`SceneError` naming the file."""
    path = str(path)
    if not os.path.isfile(path):
        raise SceneError(f"{path}: no such file")
    info = check_header(path)
    lines, _ = header_lines(path, SceneError)
    head = {w[0].upper(): w[1:] for w in (line.split() for line in lines) if w}
    try:
        width, height = int(head["WIDTH"][0]), int(head["HEIGHT"][0])
    except (KeyError, IndexError, ValueError):
        raise SceneError(f"{path}: no WIDTH / HEIGHT in its header") from None
    if "label" not in info["columns"]:
        raise SceneError(
            f"{path}: no 'label' field (fields: {', '.join(c for c in info['columns'] if c)})"
        )
    if width * height != info["points"] or height < 2:
        raise SceneError(
            f"{path}: not an organized cloud ({width} x {height}, {info['points']} points)"
        )
    import open3d as o3d

    level = o3d.utility.get_verbosity_level()
    o3d.utility.set_verbosity_level(o3d.utility.VerbosityLevel.Error)
    try:
        cloud = o3d.t.io.read_point_cloud(path)
    finally:
        o3d.utility.set_verbosity_level(level)
    if "label" not in cloud.point or "positions" not in cloud.point:
        raise SceneError(f"{path}: Open3D read no label or positions")
    pts = cloud.point.positions.numpy().astype(float)
    labels = cloud.point.label.numpy().reshape(-1).astype(np.int64)
    if len(pts) != width * height or len(labels) != len(pts):
        raise SceneError(f"{path}: read {len(pts)} points, its header says {width * height}")
    pts[~np.all(np.isfinite(pts), axis=1)] = np.nan
    viewpoint = np.asarray((info.get("viewpoint") or [0.0, 0.0, 0.0])[:3], dtype=float)
    colors = cloud.point.colors.numpy() if "colors" in cloud.point else None
    if colors is not None and (colors.dtype != np.uint8 or colors.shape != (len(pts), 3)):
        colors = None  # not an 8-bit colour per point: no colour image
    if colors is not None:
        colors = colors.reshape(height, width, 3)
    return LabelledCloud(
        scene_name(path),
        pts.reshape(height, width, 3),
        labels.reshape(height, width),
        viewpoint,
        colors,
    )


# ---------------------------------------------------------------------------- camera model
@dataclass(frozen=True)
class Intrinsics(CameraIntrinsics):
    """The pinhole intrinsics (pixels) an organized cloud's pixels obey, as fitted to it;
    ``rms_px`` the fit's RMS residual over the valid pixels."""

    rms_px: float = 0.0

    def project(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(u, v) float pixel coordinates of ``points`` (N, 3) in the optical frame: column
        u = fx x / z + cx, row v = fy y / z + cy."""
        z = points[:, 2]
        return self.fx * points[:, 0] / z + self.cx, self.fy * points[:, 1] / z + self.cy


def fit_intrinsics(points: np.ndarray) -> Intrinsics:
    """The pinhole model an organized cloud ``points`` (H, W, 3) obeys, by least squares over
    its own valid pixels (u against x/z, v against y/z)."""
    H, W = points.shape[:2]
    v, u = np.mgrid[0:H, 0:W]
    ok = np.all(np.isfinite(points), axis=-1) & (points[..., 2] > 0)
    if ok.sum() < 10:
        raise SceneError("too few valid pixels to fit a camera model")
    p = points[ok]
    out, res = [], []
    for coord, ratio in ((u[ok], p[:, 0] / p[:, 2]), (v[ok], p[:, 1] / p[:, 2])):
        A = np.stack([ratio, np.ones_like(ratio)], axis=1)
        sol = np.linalg.lstsq(A, coord.astype(float), rcond=None)[0]
        out.append(sol)
        res.append(coord - A @ sol)
    rms = float(np.sqrt(np.mean(np.concatenate(res) ** 2)))
    return Intrinsics(
        W, H, float(out[0][0]), float(out[1][0]), float(out[0][1]), float(out[1][1]), rms
    )


# ---------------------------------------------------------------------------- objects, clicks
@dataclass(frozen=True)
class LabelledObject:
    """One labelled object of a scene: its ``id`` (label // 10), ``indices`` of its valid
    points in the flattened image (row * W + column), ``click`` (3,) and the click's
    ``pixel`` (row, column)."""

    id: int
    indices: np.ndarray = field(repr=False)
    click: np.ndarray = field(repr=False)
    pixel: tuple

    @property
    def n_points(self) -> int:
        return len(self.indices)


def click_in_middle(points: np.ndarray, mask: np.ndarray | None = None) -> tuple:
    """Where an operator clicks an object "in its middle": ``points`` (H, W, 3) organized with
    the object's ``mask`` (H, W) bool -- the valid object point whose pixel is nearest the
    median pixel of the mask -- or ``points`` (N, 3) unorganized (``mask`` None) -- the point
    nearest the centroid. Returns (point (3,), pixel (row, column) or None)."""
    if mask is None:
        pts = np.asarray(points, float)
        pts = pts[np.all(np.isfinite(pts), axis=1)]
        if len(pts) == 0:
            raise AffordanceError("no valid point to click")
        i = int(np.argmin(np.linalg.norm(pts - pts.mean(axis=0), axis=1)))
        return pts[i].copy(), None
    mask = mask & np.all(np.isfinite(points), axis=-1)
    rows, cols = np.nonzero(mask)
    if len(rows) == 0:
        raise AffordanceError("no valid point to click")
    r, c = np.median(rows), np.median(cols)
    i = int(np.argmin((rows - r) ** 2 + (cols - c) ** 2))
    return points[rows[i], cols[i]].astype(float).copy(), (int(rows[i]), int(cols[i]))


def labelled_objects(
    cloud: LabelledCloud, min_points: int = MIN_OBJECT_POINTS
) -> list[LabelledObject]:
    """The objects of ``cloud`` with at least ``min_points`` valid points, by id, each with
    its click (:func:`click_in_middle` on its mask)."""
    ids = cloud.object_ids
    valid = cloud.valid
    flat_ids = np.where(valid, ids, 0).reshape(-1)
    out = []
    for k, n in zip(*np.unique(flat_ids[flat_ids > 0], return_counts=True)):
        if n < min_points:
            continue
        mask = (ids == k) & valid
        click, pixel = click_in_middle(cloud.points, mask)
        out.append(LabelledObject(int(k), np.flatnonzero(mask.reshape(-1)), click, pixel))
    return out


def table_points(cloud: LabelledCloud) -> np.ndarray:
    """The valid points labelled as the table (labels 1-9), (N, 3)."""
    lab = cloud.labels
    ok = cloud.valid & (lab >= 1) & (lab <= 9)
    return cloud.points[ok]


def fit_plane(
    points: np.ndarray, towards=SENSOR_ORIGIN, trim: float = 0.01, rounds: int = 3
) -> tuple[np.ndarray, float]:
    """A plane through ``points`` (N, 3): least squares, refitted ``rounds`` times on the
    points within ``trim`` m of the last plane. Returns (unit normal (3,) pointing towards
    ``towards``, offset d) with n . p + d = 0 on the plane."""
    pts = np.asarray(points, float)
    use = pts
    for _ in range(max(1, rounds)):
        if len(use) < 3:
            raise AffordanceError("too few points to fit a plane")
        centre = use.mean(axis=0)
        normal = np.linalg.eigh(np.cov((use - centre).T))[1][:, 0]
        d = -float(normal @ centre)
        use = pts[np.abs(pts @ normal + d) <= trim]
    if normal @ np.asarray(towards, float) + d < 0:
        normal, d = -normal, -d
    return normal, d


# ---------------------------------------------------------------------------- analytic distance
def _in_model(points: np.ndarray, T_scene_model: np.ndarray) -> np.ndarray:
    T = np.asarray(T_scene_model, float)
    R, t = T[:3, :3], T[:3, 3]
    return (np.asarray(points, float) - t) @ R  # R^T (p - t), row-wise


def _box_half(dims) -> np.ndarray:
    return 0.5 * np.array([float(dims["x"]), float(dims["y"]), float(dims["z"])])


def box_distance(points: np.ndarray, T_scene_model: np.ndarray, dims) -> np.ndarray:
    """Distance (N,) of ``points`` (N, 3) to the closed surface of the box ``dims``
    ({"x", "y", "z"} full edge lengths, m) posed by ``T_scene_model`` (origin at the centre of
    its base face, +z up): zero on a face, positive inside and outside."""
    return core_primitive_distance("box", dims, _in_model(points, T_scene_model))


def cylinder_distance(points: np.ndarray, T_scene_model: np.ndarray, dims) -> np.ndarray:
    """Distance (N,) of ``points`` (N, 3) to the closed surface of the cylinder ``dims``
    ({"radius", "length"}, m) posed by ``T_scene_model`` (origin at the centre of one end
    face, +z along the axis): the mantle and both end discs."""
    return core_primitive_distance("cylinder", dims, _in_model(points, T_scene_model))


def primitive_distance(
    kind: str, points: np.ndarray, T_scene_model: np.ndarray, dims
) -> np.ndarray:
    """:func:`box_distance` or :func:`cylinder_distance` by ``kind`` ("box" | "cylinder")."""
    if kind == "box":
        return box_distance(points, T_scene_model, dims)
    if kind == "cylinder":
        return cylinder_distance(points, T_scene_model, dims)
    raise AffordanceError(f"unknown primitive kind {kind!r} (box or cylinder)")


def inside_region(
    kind: str, points: np.ndarray, T_scene_model: np.ndarray, dims, margin: float
) -> np.ndarray:
    """(N,) bool: ``points`` within the primitive's bounding region grown by ``margin`` m (a
    box: its box; a cylinder: its radius and length, in its frame)."""
    q = _in_model(points, T_scene_model)
    if kind == "box":
        half = _box_half(dims)
        return (
            (np.abs(q[:, 0]) <= half[0] + margin)
            & (np.abs(q[:, 1]) <= half[1] + margin)
            & (q[:, 2] >= -margin)
            & (q[:, 2] <= 2 * half[2] + margin)
        )
    if kind == "cylinder":
        r, length = float(dims["radius"]), float(dims["length"])
        return (
            (np.hypot(q[:, 0], q[:, 1]) <= r + margin)
            & (q[:, 2] >= -margin)
            & (q[:, 2] <= length + margin)
        )
    raise AffordanceError(f"unknown primitive kind {kind!r} (box or cylinder)")


# ---------------------------------------------------------------------------- noise
def local_noise(points: np.ndarray, k: int = 50, max_centres: int = 400, seed: int = 0) -> float:
    """The scan's noise on a surface (m): the median, over up to ``max_centres`` seeded
    points of ``points`` (N, 3), of the RMS distance of each one's ``k`` nearest neighbours
    (among ``points``) to their least-squares plane (the square root of the smallest
    eigenvalue of their covariance). The median keeps edges and corners (curved
    neighbourhoods) out of it.

    The neighbourhood's size matters on a Kinect: its depth comes in disparity steps, so a
    few pixels often lie on one step and look noiseless. At k = 50 (about 7 x 7 pixels) the
    shared mOSD table reads 0.7 mm at 0.9 m and 1.1 mm at 1.4 m (k = 20: 0.5 and 0.9 mm;
    k = 400: 1.0 and 1.6 mm; the table's RMS about one plane over 0.8-1.0 m: 1.5 mm); a
    cylinder's curvature adds less than 0.3 mm at this size for the mugs (radius 36 mm)."""
    pts = np.asarray(points, float)
    pts = pts[np.all(np.isfinite(pts), axis=1)]
    if len(pts) < max(k, 4):
        raise AffordanceError(f"{len(pts)} points are too few for a noise estimate")
    rng = np.random.default_rng(seed)
    centres = pts[rng.choice(len(pts), size=min(max_centres, len(pts)), replace=False)]
    _, idx = cKDTree(pts).query(centres, k=k)
    nb = pts[idx]
    nb = nb - nb.mean(axis=1, keepdims=True)
    smallest = np.linalg.eigvalsh(np.einsum("mki,mkj->mij", nb, nb) / k)[:, 0]
    return float(np.median(np.sqrt(np.maximum(smallest, 0.0))))


# ---------------------------------------------------------------------------- the scoring rule
@dataclass(frozen=True)
class PrimitiveScore:
    """The label-based score of one primitive fit of one object: ``recall`` (share of the
    object's points within ``tolerance`` of the fitted surface), ``precision`` (of the scan
    points within ``tolerance`` of it and inside its bounding region grown by ``tolerance``,
    the share labelled as the object), ``noise`` (m, :func:`local_noise` of the object's
    points) and ``passes`` (recall >= 0.9 and precision >= 0.9)."""

    recall: float
    precision: float
    tolerance: float
    noise: float
    on_surface: int

    @property
    def passes(self) -> bool:
        return self.recall >= PASS_RECALL and self.precision >= PASS_PRECISION

    def to_dict(self) -> dict:
        return {
            "recall": round(self.recall, 4),
            "precision": round(self.precision, 4),
            "tolerance": round(self.tolerance, 6),
            "noise": round(self.noise, 6),
            "on_surface": self.on_surface,
            "passes": self.passes,
        }


def score_primitive(
    cloud: LabelledCloud,
    obj: LabelledObject | int,
    kind: str,
    T_scene_model: np.ndarray,
    dims,
    noise: float | None = None,
) -> PrimitiveScore:
    """Score a primitive fit (``kind``, ``T_scene_model``, ``dims``) of the object ``obj``
    (a :class:`LabelledObject` or its id) of ``cloud`` against the labels: tolerance
    max(6 mm, 3 x the object's local noise) (``noise`` given, or :func:`local_noise` of its
    points)."""
    flat = cloud.points.reshape(-1, 3)
    valid = cloud.valid.reshape(-1)
    k = obj.id if isinstance(obj, LabelledObject) else int(obj)
    own = valid & (cloud.object_ids.reshape(-1) == k)
    if not own.any():
        raise AffordanceError(f"{cloud.name}: no object {k}")
    return score_points(flat[valid], own[valid], kind, T_scene_model, dims, noise)


def score_points(
    points: np.ndarray,
    own: np.ndarray,
    kind: str,
    T_scene_model: np.ndarray,
    dims,
    noise: float | None = None,
) -> PrimitiveScore:
    """The label rule of :func:`score_primitive` on a scan's finite ``points`` (N, 3), of
    which ``own`` (N,) bool are the object's (a simulated scene's, from its truth)."""
    points = np.asarray(points, float)
    own = np.asarray(own, bool)
    sigma = local_noise(points[own]) if noise is None else float(noise)
    tol = max(MIN_TOLERANCE, NOISE_SIGMAS * sigma)
    recall = float(np.mean(primitive_distance(kind, points[own], T_scene_model, dims) <= tol))
    near = inside_region(kind, points, T_scene_model, dims, tol)
    on = np.zeros_like(near)
    on[near] = primitive_distance(kind, points[near], T_scene_model, dims) <= tol
    n_on = int(on.sum())
    precision = float(np.mean(own[on])) if n_on else 0.0
    return PrimitiveScore(recall, precision, tol, sigma, n_on)


# ---------------------------------------------------------------------------- the driver
def _dims_dict(dims) -> dict | None:
    if dims is None:
        return None
    try:
        return {str(k): float(v) for k, v in dict(dims).items()}
    except (TypeError, ValueError):
        return None


def _annotated_kind(name: str, object_id: int) -> str | None:
    """:func:`object_kind`, None for an object or scene not annotated."""
    try:
        return object_kind(name, object_id)
    except AffordanceError:
        return None


def fit_record(
    cloud: LabelledCloud,
    obj: LabelledObject,
    best,
    object_kind: str | None = None,
    refined: bool = False,
) -> dict:
    """What :func:`evaluate_scene` records of the shown candidate ``best`` (a
    ``core.registration.FitResult``) of a click on ``obj`` of ``cloud``: ``template``,
    ``fits``, ``primitive``, ``dimensions``, ``explained``, ``reason`` (these four read with
    getattr: None where the registrar does not give them), ``T_scene_model`` (4 rows),
    ``score`` (:meth:`PrimitiveScore.to_dict` when it is a box or cylinder with dimensions,
    else None), ``refined_score`` (with ``refined``, where it is of ``object_kind``: the score
    of the fit refined on the object's labelled points, :func:`.label_ceiling.refined_score`)
    and ``error`` (a scoring that failed: its message; else None)."""
    primitive = getattr(best, "primitive", None)
    dims = _dims_dict(getattr(best, "dimensions", None))
    T = np.asarray(best.T_scene_model, float)
    rec = {
        "template": best.template,
        "fits": best.fits,
        "primitive": primitive,
        "dimensions": dims,
        "explained": getattr(best, "explained", None),
        "reason": getattr(best, "reason", None),
        "T_scene_model": [[round(float(v), 6) for v in row] for row in T],
        "score": None,
        "refined_score": None,
        "error": None,
    }
    if primitive in ("box", "cylinder") and dims:
        try:
            rec["score"] = score_primitive(cloud, obj, primitive, T, dims).to_dict()
            if refined and primitive == object_kind:
                from .label_ceiling import refined_score

                rec["refined_score"] = refined_score(cloud, obj, primitive, T, dims).to_dict()
        except (AffordanceError, KeyError, ValueError) as exc:
            rec["error"] = f"scoring: {exc}"
    return rec


def evaluate_scene(
    registrar,
    scene_path: str | LabelledCloud,
    min_points: int = MIN_OBJECT_POINTS,
    refined: bool = False,
    object_kinds: dict | None = None,
) -> list[dict]:
    """Click the middle of every labelled object (>= ``min_points``) of an mOSD scene with
    ``registrar`` (a :class:`core.registration.Registrar`) -- the sensor at the origin -- and
    return one record per object:

    ``scene``, ``kind``, ``uniform_kind`` (:func:`uniform_kind`), ``held_out``, ``object``
    (id), ``object_kind`` (:func:`object_kind`; for a scene that is not a learn scene, such as
    a composite of several, ``object_kinds`` {id: kind} gives it), ``n_points``, ``click`` (3
    floats), ``pixel`` (row, column), what :func:`fit_record` records of the best candidate
    (``template``, ``fits``, ``primitive``, ``dimensions``, ``explained``, ``reason``,
    ``T_scene_model``, ``score``, with ``refined`` ``refined_score``), ``time_s`` (the fit's
    wall time) and ``error`` (a fit that raised: its one-line message, the other fields
    None)."""
    from ..core.scene import Scene

    cloud = scene_path if isinstance(scene_path, LabelledCloud) else read_labelled_pcd(scene_path)
    scene = Scene(cloud.points.reshape(-1, 3), sensor_origin=cloud.viewpoint)
    try:
        kind, held = scene_kind(cloud.name), is_held_out(cloud.name)
        uniform = uniform_kind(cloud.name)
    except AffordanceError:
        kind, held, uniform = None, None, None
    records = []
    for obj in labelled_objects(cloud, min_points):
        if object_kinds is not None:
            what = object_kinds.get(obj.id)
        else:
            what = _annotated_kind(cloud.name, obj.id)
        rec = {
            "scene": cloud.name,
            "kind": kind,
            "uniform_kind": uniform,
            "held_out": held,
            "object": obj.id,
            "object_kind": what,
            "n_points": obj.n_points,
            "click": [round(float(v), 6) for v in obj.click],
            "pixel": list(obj.pixel) if obj.pixel is not None else None,
            "template": None,
            "fits": None,
            "primitive": None,
            "dimensions": None,
            "explained": None,
            "reason": None,
            "T_scene_model": None,
            "score": None,
            "refined_score": None,
            "time_s": None,
            "error": None,
        }
        t0 = time.perf_counter()
        try:
            best = registrar.fit(scene, obj.click).candidates[0]
        except AffordanceError as exc:
            rec["time_s"] = time.perf_counter() - t0
            rec["error"] = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
            records.append(rec)
            continue
        rec["time_s"] = time.perf_counter() - t0
        rec.update(fit_record(cloud, obj, best, what, refined))
        records.append(rec)
    return records
