"""A generated building floor with known ground truth: walls, halls, labelled rooms and objects.

The project's demo and core tests use these maps (the real maps in ../shared/data are optional
extras). Layout, with x to the right and y up:

    +------+------+-- ... --+------+-----+
    | room | room |         | room |  b  |
    +--  --+--  --+-- ... --+--  --+  a  |
    |           main hall             c  |   <- busy
    +--  --+--  --+-- ... --+--  --+  k  |
    | room | room |         | room |     |   <- back hall: quiet
    +------+------+-- ... --+------+-----+

and with `loop=True` (the same floor, nothing moved, on a map grown west and north):

    +----------------------------------------+
    |         north corridor (quiet)         |
    |   +------+------+-- ... --+------+     |
    | w | room | room |         | room |  b  |
    | e +--  --+--  --+-- ... --+--  --+  a  |
    | s             main hall             c  |   <- busy
    +---+--  --+--  --+-- ... --+--  --+  k  |
        | room | room |         | room |     |   <- back hall: quiet
        +------+------+-- ... --+------+-----+

Rooms open onto the main hall through doors; the back hall runs along the right end. Each room
has a semantic label (kitchen, printer_room, classroom_101 ...) and objects placed from its kind;
landmarks (water_fountain, vending_machines, ...) stand in the halls. Everything follows from
`seed`.

`loop=True` gives the floor a second way from the main hall's west end to the back hall: a
west corridor from the main hall's west end (open over the hall's width) up to a north corridor
beyond the top rooms' outer wall, which runs the floor's whole width and meets the back hall,
extended up through its north wall. Both are quiet halls (`busy` as the back hall's), so the
way round is longer but meets fewer people than the main hall at a rush. The map's origin x
becomes negative (-2.5 m with the defaults: whole 0.5 m people cells, so the people model's
cells of the old floor stay where they were); rooms, labels, objects and the main hall are
those of `loop=False`, whose floor does not change.
"""
import json
import math
import os
from dataclasses import dataclass, field, replace
from typing import Dict, List, Optional, Sequence, Tuple

import numpy as np

from robot_common.maps import FREE, OCCUPIED, GridMap, load_map

Box = Tuple[float, float, float, float]  # x0, y0, x1, y1

# Room kinds: label stem and the objects (class, count) usually found there.
ROOM_KINDS: Dict[str, Sequence[Tuple[str, int]]] = {
    "classroom": (("chair", 4), ("table", 2), ("whiteboard", 1)),
    "office": (("desk", 1), ("chair", 1), ("computer", 1)),
    "kitchen": (("fridge", 1), ("microwave", 1), ("sink", 1), ("table", 1)),
    "printer_room": (("printer", 1), ("trash_can", 1)),
    "bathroom": (("sink", 2), ("trash_can", 1)),
    "lounge": (("couch", 2), ("plant", 1), ("table", 1)),
    "bio_lab": (("sink", 1), ("table", 2), ("computer", 1)),
    "conference_room": (("table", 1), ("chair", 3), ("whiteboard", 1)),
}
# Object footprint sizes (x, y, z) in metres.
OBJECT_SIZES: Dict[str, Tuple[float, float, float]] = {
    "chair": (0.5, 0.5, 0.9), "table": (1.2, 0.8, 0.75), "whiteboard": (1.5, 0.1, 1.2),
    "desk": (1.4, 0.7, 0.75), "computer": (0.5, 0.3, 0.5), "fridge": (0.7, 0.7, 1.8),
    "microwave": (0.5, 0.4, 0.3), "sink": (0.6, 0.5, 0.9), "printer": (0.8, 0.6, 1.0),
    "trash_can": (0.4, 0.4, 0.6), "couch": (1.8, 0.8, 0.8), "plant": (0.4, 0.4, 1.2),
    "water_fountain": (0.5, 0.4, 1.0), "vending_machine": (1.0, 0.8, 1.8),
}
HALL_LANDMARKS = (("water_fountain", "water_fountain"), ("vending_machines", "vending_machine"),
                  ("elevator", ""), ("stairs", ""))
# Mostly distinct kinds first, so that small buildings still get a varied floor.
ROOM_ORDER = ("classroom", "kitchen", "office", "printer_room", "bathroom", "lounge", "bio_lab",
              "conference_room", "classroom", "office", "classroom", "office")


@dataclass(frozen=True)
class Area:
    """A hall or room: `box` is its free interior; `busy` the relative people traffic."""

    name: str
    kind: str
    label: str
    box: Box
    busy: float = 0.0

    def contains(self, x: float, y: float) -> bool:
        return self.box[0] <= x <= self.box[2] and self.box[1] <= y <= self.box[3]

    @property
    def centre(self) -> Tuple[float, float]:
        return (self.box[0] + self.box[2]) / 2.0, (self.box[1] + self.box[3]) / 2.0


@dataclass(frozen=True)
class PlacedObject:
    class_name: str
    x: float
    y: float
    size: Tuple[float, float, float]
    area: str


@dataclass
class Building:
    grid: GridMap
    areas: List[Area]
    objects: List[PlacedObject]
    labels: Dict[str, Tuple[float, float]] = field(default_factory=dict)

    @property
    def halls(self) -> List[Area]:
        return [area for area in self.areas if area.kind == "hall"]

    @property
    def rooms(self) -> List[Area]:
        return [area for area in self.areas if area.kind == "room"]

    def area_at(self, x: float, y: float) -> Optional[Area]:
        return next((area for area in self.areas if area.contains(x, y)), None)

    def objects_of(self, class_name: str) -> List[PlacedObject]:
        return [obj for obj in self.objects if obj.class_name == class_name]

    def labels_json(self) -> str:
        """The labels in the map_labelling JSON format: {name: {x, y, orientation}}."""
        return json.dumps({name: {"x": round(x, 3), "y": round(y, 3),
                                  "orientation": [0.0, 0.0, 0.0, 1.0]}
                           for name, (x, y) in sorted(self.labels.items())}, indent=2)


def generate_building(seed: int = 0, *, rooms_per_side: int = 5, room_width: float = 5.0,
                      room_depth: float = 5.0, hall_width: float = 3.0,
                      back_hall_width: float = 2.0, wall: float = 0.2,
                      resolution: float = 0.1, loop: bool = False) -> Building:
    """A floor with `2 * rooms_per_side` rooms on a main hall and a back hall at its right end;
    `loop`: plus west and north corridors `back_hall_width` wide (see the module docstring)."""
    if rooms_per_side < 1:
        raise ValueError(f"rooms_per_side must be at least 1, got {rooms_per_side}")
    rng = np.random.default_rng(seed)
    width = rooms_per_side * room_width + back_hall_width + 2 * wall
    height = 2 * room_depth + hall_width + 2 * wall
    shape = (int(round(height / resolution)), int(round(width / resolution)))
    cells = np.full(shape, OCCUPIED, dtype=np.int8)
    grid = GridMap(cells, resolution, (0.0, 0.0, 0.0), {"source": f"generated seed={seed}"})

    hall_y0 = wall + room_depth
    main_x1 = wall + rooms_per_side * room_width
    areas = [Area("main_hall", "hall", "main_hall",
                  _rounded((wall, hall_y0, main_x1, hall_y0 + hall_width)), 1.0),
             Area("back_hall", "hall", "back_hall",
                  _rounded((main_x1, wall, width - wall, height - wall)), 0.3)]
    kinds = [ROOM_ORDER[i % len(ROOM_ORDER)] for i in range(2 * rooms_per_side)]
    rng.shuffle(kinds)
    numbers = {"classroom": 101, "office": 201}
    door = 1.0
    for index, kind in enumerate(kinds):
        column, top = index % rooms_per_side, index >= rooms_per_side
        x0 = wall + column * room_width
        x1 = x0 + room_width - wall
        y0 = hall_y0 + hall_width + wall if top else wall
        y1 = y0 + room_depth - wall
        label = kind
        if kind in numbers:
            label = f"{kind}_{numbers[kind]}"
            numbers[kind] += 1
        elif any(area.label == kind for area in areas):
            label = f"{kind}_{index}"
        areas.append(Area(f"room_{index}", "room", label, _rounded((x0, y0, x1, y1))))
        door_x = (x0 + x1) / 2
        door_box = (door_x - door / 2, y0 - wall - 0.01, door_x + door / 2, y0 + 0.01) if top else \
            (door_x - door / 2, y1 - 0.01, door_x + door / 2, y1 + wall + 0.01)
        _carve(grid, door_box)
    for area in areas:
        _carve(grid, area.box)

    objects: List[PlacedObject] = []
    labels: Dict[str, Tuple[float, float]] = {}
    for area in areas[2:]:
        kind = next(k for k in ROOM_KINDS if area.label.startswith(k))
        objects += _place_objects(area, ROOM_KINDS[kind], rng)
        labels[area.label] = area.centre
    back = areas[1]
    for slot, (label, object_class) in enumerate(HALL_LANDMARKS):
        x = back.box[0] + 0.4 if slot % 2 == 0 else back.box[2] - 0.4
        y = back.box[1] + (slot + 1) * (back.box[3] - back.box[1]) / (len(HALL_LANDMARKS) + 1)
        labels[label] = (x, y)
        if object_class:
            objects.append(PlacedObject(object_class, x, y, OBJECT_SIZES[object_class], back.name))
    building = Building(grid, areas, objects, labels)
    return _with_loop(building, back_hall_width, wall) if loop else building


def _carve(grid: GridMap, box: Box, *, nearest: bool = False) -> None:
    """Frees the cells of `box` (x0, y0, x1, y1) in `grid`: from the cells holding its corners
    (the default floor's rule) or, `nearest`, between the cell edges nearest to them."""
    if nearest:
        (c0, c1), (r0, r1) = [np.round((np.asarray(v) - o) / grid.resolution).astype(int)
                              for v, o in (((box[0], box[2]), grid.origin[0]),
                                           ((box[1], box[3]), grid.origin[1]))]
    else:
        (r0, c0), (r1, c1) = [grid.world_to_cell(x, y) for x, y in ((box[0], box[1]),
                                                                      (box[2], box[3]))]
    grid.cells[max(r0, 0):r1, max(c0, 0):c1] = FREE


def _with_loop(building: Building, width: float, wall: float, cell: float = 0.5) -> Building:
    """`building` on a map grown west and north, with a west corridor from the main hall's west
    end up to a north corridor over the whole floor that meets the back hall (extended up to
    it), both `width` wide. The west growth is a whole number of `cell`s (the people model's
    cells), so those cells of the old floor stay where they were. The openings in the old
    floor's walls are carved by its own rule, so they line up with its halls' free cells."""
    old = building.grid
    res = old.resolution
    halls = {area.name: area for area in building.halls}
    main, back = halls["main_hall"], halls["back_hall"]
    x0, top = round(old.origin[0] - width, 6), round(old.origin[1] + old.height * res, 6)
    back_up = replace(back, box=_rounded(back.box[:3] + (top,)))
    opened = GridMap(old.cells.copy(), res, old.origin)
    for box in ((old.origin[0] - 0.01, main.box[1], main.box[0] + 0.01, main.box[3]),
                (back.box[0], back.box[3] - 0.01, back.box[2], top + 0.01)):
        _carve(opened, box)
    west = int(round(math.ceil((width + wall) / cell - 1e-9) * cell / res))
    north = int(round((width + wall) / res))
    cells = np.full((old.height + north, old.width + west), OCCUPIED, dtype=np.int8)
    cells[:old.height, west:] = opened.cells
    origin = (round(old.origin[0] - west * res, 6), old.origin[1], 0.0)
    grid = GridMap(cells, res, origin, dict(old.meta, source=f"{old.meta['source']} loop"))
    corridors = [Area("west_corridor", "hall", "west_corridor",
                      _rounded((x0, main.box[1], old.origin[0], top)), back.busy),
                 Area("north_corridor", "hall", "north_corridor",
                      _rounded((x0, top, back.box[2], top + width)), back.busy)]
    for area in corridors:
        _carve(grid, area.box, nearest=True)
    areas = [back_up if area is back else area for area in building.areas]
    return Building(grid, areas + corridors, list(building.objects), dict(building.labels))


def _rounded(box: Box) -> Box:
    return tuple(round(v, 6) for v in box)


def _place_objects(area: Area, contents: Sequence[Tuple[str, int]],
                   rng: np.random.Generator, spacing: float = 1.2,
                   margin: float = 0.7) -> List[PlacedObject]:
    """Objects on free slots of a `spacing` lattice inside the room (never two on one slot)."""
    x0, y0, x1, y1 = area.box
    xs = np.arange(x0 + margin, x1 - margin + 1e-9, spacing)
    ys = np.arange(y0 + margin, y1 - margin + 1e-9, spacing)
    slots = [(x, y) for x in xs for y in ys]
    order = rng.permutation(len(slots))
    wanted = [name for name, count in contents for _ in range(count)]
    if len(wanted) > len(slots):
        raise ValueError(f"room {area.name} ({area.label}) too small for {len(wanted)} objects")
    return [PlacedObject(name, round(float(slots[i][0]), 3), round(float(slots[i][1]), 3),
                         OBJECT_SIZES[name], area.name) for name, i in zip(wanted, order)]


LAYOUTS = ("hall", "loop")


def building_or_map(map_yaml: str, seed: int,
                    layout: str = "hall") -> Tuple[GridMap, Optional[Building]]:
    """The map a simulator node runs on: a map_server file (`map_yaml`, ~ expanded) or, when
    `map_yaml` is empty, the generated building of `seed` with `layout` "hall" (the default
    floor) or "loop" (`generate_building(seed, loop=True)`).

    Returns (grid, building); `building` is None for a map file (no known areas). A map file
    that cannot be read raises robot_common's MapError; an unknown layout ValueError.
    """
    if layout not in LAYOUTS:
        raise ValueError(f"layout must be one of {LAYOUTS}, got {layout!r}")
    if map_yaml:
        return load_map(os.path.expanduser(map_yaml)), None
    building = generate_building(seed, loop=layout == "loop")
    return building.grid, building
