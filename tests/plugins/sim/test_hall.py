"""The hall world kind: rows of racks in a tall open hall, and an open bay to take off in."""

from __future__ import annotations

import numpy as np
import pytest

from amslam.interfaces import FieldError
from amslam.plugins.sim.hall import HallWorldParams, generate_hall
from amslam.plugins.sim.platform import SimPlatform
from amslam.plugins.sim.world import World


def test_racks_stand_in_rows_inside_the_hall_and_the_take_off_column_is_clear() -> None:
    p = HallWorldParams(size=(20.0, 30.0), height=10.0)
    spec = generate_hall(p, np.random.default_rng(3))
    racks = [o for o in spec.objects if o.class_name == "shelf" and o.hi[2] - o.lo[2] > 3.0]
    # four rows of seven bays (eight bays less the cross aisle) in a 20 x 30 m hall
    assert len(racks) == 28
    assert len({round(float(o.centroid[0]), 3) for o in racks}) == 4
    for o in spec.objects:
        assert np.all(o.lo >= [0.0, 0.0, -1e-9]) and np.all(o.hi <= [20.0, 30.0, 10.0])
    # racks are behind the open bay; the bay holds the office furniture
    assert min(o.lo[1] for o in racks) >= p.open_bay - 1e-9
    assert any(o.class_name in ("chair", "table", "sofa") for o in spec.objects)
    world = World(spec)
    column = np.array([[*spec.start_xy, z] for z in np.linspace(1.0, 3.0, 9)])
    assert world.distance(column).min() > 0.9  # the south wall, 1 m behind
    assert world.ground_below(np.array([*spec.start_xy, 1.0])) == pytest.approx(0.0, abs=1e-6)


def test_the_same_seed_gives_the_same_hall() -> None:
    a = generate_hall(HallWorldParams(), np.random.default_rng(5))
    b = generate_hall(HallWorldParams(), np.random.default_rng(5))
    c = generate_hall(HallWorldParams(), np.random.default_rng(6))
    assert [o.name for o in a.objects] == [o.name for o in b.objects]
    assert all(np.allclose(x.centroid, y.centroid) for x, y in zip(a.objects, b.objects, strict=True))
    assert [tuple(o.hi) for o in a.objects] != [tuple(o.hi) for o in c.objects]


def test_hall_kind_is_a_platform_world() -> None:
    params = SimPlatform.Params(world={"kind": "hall", "size": [24, 40], "height": 12})
    assert isinstance(params.world, HallWorldParams)
    assert params.world.size == (24.0, 40.0)


@pytest.mark.parametrize(
    ("fields", "field", "says"),
    [
        ({"rack_height": (5.0, 4.0)}, "rack_height", "lowest row"),
        ({"rack_height": (4.0, 12.0)}, "rack_height", "lower than the hall"),
        ({"size": (6.0, 30.0)}, "size", "too small"),
        ({"size": (20.0, 9.0)}, "size", "too small"),
    ],
)
def test_a_hall_that_cannot_be_built_is_refused_naming_the_field(fields, field, says) -> None:
    with pytest.raises(ValueError) as info:
        HallWorldParams(**fields)
    assert says in str(info.value)
    assert field in str(info.value) or isinstance(info.value.__cause__, FieldError)
