"""One object-class vocabulary across datasets (docs/design.md §3, "Ids and classes").

Every loader names a tracked object's class with one of :data:`CLASSES`; the dataset's own name
(Waymo ``Vehicle``, nuScenes ``vehicle.car``, PandaSet ``Car``, ...) is an *alias* of that class,
so ``class=Car``, ``class=vehicle.car``, ``class=Vehicle`` and ``class=vehicle`` select the same
objects on any scene. The grouping follows drivestudio's own per-dataset class lists (its rigid,
human and deformable groups): buses, trucks, trailers, trams and motorcycles are vehicles;
bicycles (with or without rider) and personal mobility devices are cyclists; animals are animals.
A name outside the table keeps itself, lower-cased, as its class.
"""

from __future__ import annotations

#: The shared classes, in the order ``wcbench scenes show`` lists them.
CLASSES = ("vehicle", "pedestrian", "cyclist", "animal", "sign", "other")

_VEHICLE = (
    # Waymo (label.proto TYPE_VEHICLE) and nuPlan
    "Vehicle",
    # nuScenes categories
    "vehicle.car", "vehicle.bus.bendy", "vehicle.bus.rigid", "vehicle.construction", "vehicle.emergency.ambulance",
    "vehicle.emergency.police", "vehicle.motorcycle", "vehicle.trailer", "vehicle.truck",
    # PandaSet cuboid labels
    "Car", "Bus", "Emergency Vehicle", "Medium-sized Truck", "Motorcycle", "Motorized Scooter",
    "Other Vehicle - Construction Vehicle", "Other Vehicle - Pedicab", "Other Vehicle - Uncommon", "Pickup Truck",
    "Semi-truck", "Train", "Tram / Subway", "Towed Object",
)
_PEDESTRIAN = (
    "Pedestrian",  # Waymo, PandaSet, nuPlan
    "human.pedestrian.adult", "human.pedestrian.child", "human.pedestrian.construction_worker",
    "human.pedestrian.police_officer", "human.pedestrian.wheelchair", "human.pedestrian.stroller",
    "Pedestrian with Object",
)
_CYCLIST = (
    "Cyclist",  # Waymo
    "vehicle.bicycle", "human.pedestrian.personal_mobility",  # nuScenes
    "Bicycle", "Personal Mobility Device",  # PandaSet
)
_ANIMAL = ("animal", "Animals - Other")
_SIGN = ("Sign", "Signs", "Construction Signs")
_OTHER = (
    "unknown", "movable_object.barrier", "movable_object.debris", "movable_object.pushable_pullable",
    "movable_object.trafficcone", "static_object.bicycle_rack", "Cones", "Pylons", "Road Barriers",
    "Rolling Containers", "Temporary Construction Barriers",
)

#: Dataset class name (lower-cased) -> shared class.
ALIASES: dict[str, str] = {
    name.lower(): cls
    for cls, names in (("vehicle", _VEHICLE), ("pedestrian", _PEDESTRIAN), ("cyclist", _CYCLIST),
                       ("animal", _ANIMAL), ("sign", _SIGN), ("other", _OTHER))
    for name in names
}
ALIASES.update({c: c for c in CLASSES})


def canonical_class(name: str) -> str:
    """The shared class of a dataset's class name (case-insensitive); an unknown name maps to
    itself, lower-cased and stripped."""
    key = str(name).strip().lower()
    return ALIASES.get(key, key)


def same_class(a: str, b: str) -> bool:
    """Whether two class names (shared or dataset-specific) name the same shared class."""
    return canonical_class(a) == canonical_class(b)
