"""The built-in layouts: forward-facing scenes with objects spread over about 1:4 in depth.

World frame: y up, ground at y = 0 (where there is one), cameras near the origin looking down -z,
so scene depth grows towards -z. Each builder returns a :class:`~.render.Layout`; the scene
content is fixed per layout (the seed only moves the cameras). Colours are linear RGB.

Content is split: ``tabletop``, ``orchard`` and ``gallery`` (the default training scenes) use only
:data:`~.textures.TRAIN_SOURCES`; ``courtyard``, ``observatory``, ``harbour``, ``greenhouse``, ``workshop``
and ``library`` (evaluation: six, as the findings take the scene as the unit and need six for a
verdict) only :data:`~.textures.EVAL_SOURCES` (``LAYOUT_ROLES``; a test keeps it so). Each scene has
its own geometry, not another's re-skinned: scattered objects before a wall (courtyard), planets
under a sky (observatory), a quay edge running into the distance (harbour), tiers rising away from
the cameras (greenhouse), open shelving beside a bench (workshop), an aisle between walls that run
in depth (library).
"""

from __future__ import annotations

import numpy as np

from spc3d.inputs.scenes.primitives import Box, Sphere, backdrop, ground, quad, yaw_matrix
from spc3d.inputs.scenes.render import Layout, Lighting, Rig
from spc3d.inputs.scenes.textures import Texture, solid, texture


def framed(
    tex: Texture, centre, height: float, yaw: float = 0.0, border: float = 0.04, frame=(0.05, 0.035, 0.02)
) -> list:
    """A picture of ``height`` (width from the image aspect) in a plain frame just behind it."""
    h, w = tex.shape
    width = height * w / h
    centre = np.asarray(centre, float)
    behind = centre - 0.01 * yaw_matrix(yaw)[:, 2]
    return [
        quad(centre, width, height, tex, yaw, shading=0.6, casts_shadow=True),
        quad(behind, width + 2 * border, height + 2 * border, solid(frame), yaw, shading=0.8, casts_shadow=True),
    ]


def box(centre, size, tex: Texture, tile: float, yaw: float = 0.0, top: Texture | None = None) -> Box:
    """A box resting on its bottom face: ``centre`` is (x, bottom y, z), ``size`` the full (w, h, d)."""
    half = np.asarray(size, float) / 2
    c = np.asarray(centre, float) + np.array([0.0, half[1], 0.0])
    return Box(c, half, tex, tile, yaw, top)


def ball(x: float, z: float, radius: float, tex: Texture, y0: float = 0.0, **kw) -> Sphere:
    """A sphere resting on the plane y = y0."""
    return Sphere(np.array([x, y0 + radius, z]), radius, tex, **kw)


def tabletop() -> Layout:
    prims = [
        ground(0.0, texture("proc:marble", (0.95, 0.92, 0.88)), tile=2.5, shading=0.8),
        backdrop(-5.5, texture("brick", (0.85, 0.72, 0.55), base=(0.12, 0.08, 0.06), gain=1.4), (8.0, 8.0)),
        ball(-0.75, -2.1, 0.32, texture("gravel", (0.1, 0.25, 0.85), base=(0.01, 0.02, 0.1), gain=1.3), spin=30),
        ball(0.5, -1.75, 0.2, texture("clock", (0.9, 0.55, 0.25), base=(0.05, 0.02, 0.01)), spin=-60),
        ball(1.05, -4.0, 0.42, texture("cell", (0.95, 0.45, 0.2), base=(0.2, 0.03, 0.01), gain=1.3), spin=90),
        box(
            (-0.15, 0.0, -2.9),
            (0.9, 0.22, 0.62),
            texture("proc:weave", (1.0, 0.6, 0.55)),
            0.6,
            yaw=18,
            top=texture("text", (0.9, 0.85, 0.7)),
        ),
        box(
            (1.35, 0.0, -3.1),
            (0.5, 0.5, 0.5),
            texture("coins", (0.95, 0.7, 0.25), base=(0.05, 0.03, 0.0)),
            0.5,
            yaw=-30,
        ),
    ]
    prims += framed(texture("astronaut"), (-1.45, 0.55, -3.7), 0.9, yaw=25)
    prims += framed(
        texture("horse", (0.9, 0.85, 0.6), base=(0.1, 0.05, 0.2)),
        (0.25, 0.42, -4.7),
        0.7,
        yaw=-8,
        frame=(0.6, 0.6, 0.58),
    )
    return Layout(
        "tabletop",
        "objects on a marble table before a painted brick wall: a blue pebble ball, a "
        "clock-face sphere, an orange cell ball, a cloth-bound book, a gold box, two framed pictures "
        "(astronaut, horse)",
        tuple(prims),
        Rig((0.0, 0.9, 0.0), (0.0, 0.35, -3.2), (0.6, 0.45)),
        Lighting((-0.6, 0.75, 0.25)),
    )


def orchard() -> Layout:
    bark = texture("proc:wood", (0.7, 0.6, 0.5))
    leaves = texture("grass", (0.2, 0.45, 0.08), base=(0.01, 0.04, 0.0), gain=1.3)
    prims = [
        ground(0.0, texture("grass", (0.35, 0.55, 0.12), base=(0.02, 0.05, 0.0), gain=1.2), tile=1.2, shading=0.6),
        backdrop(
            -11.0,
            texture("proc:marble", (0.8, 0.9, 1.0), base=(0.35, 0.5, 0.8), gain=1.1),
            (14.0, 14.0),
            centre_y=3.0,
            shading=0.0,
        ),
        quad(
            (0.0, 1.1, -8.0),
            40.0,
            2.2,
            texture("gravel", (0.12, 0.3, 0.06), base=(0.0, 0.03, 0.0)),
            tile=(2.2, 2.2),
            shading=0.3,
        ),
        box((-1.6, 0.0, -5.2), (0.2, 1.6, 0.2), bark, 0.8),
        ball(-1.6, -5.2, 0.85, leaves, y0=1.2, spin=10),
        box((1.9, 0.0, -6.3), (0.22, 1.5, 0.22), bark, 0.8),
        ball(1.9, -6.3, 0.95, leaves, y0=1.1, spin=70),
        ball(-0.55, -2.0, 0.22, texture("gravel", (0.95, 0.35, 0.1), base=(0.25, 0.05, 0.01), gain=1.2), spin=40),
        ball(0.2, -2.4, 0.24, texture("cell", (0.75, 0.06, 0.04), base=(0.15, 0.01, 0.0), gain=1.2)),
        box((0.75, 0.0, -3.2), (0.7, 0.45, 0.5), texture("proc:wood"), 0.7, yaw=-22),
        box((-0.45, 0.0, -4.2), (0.06, 0.9, 0.06), bark, 0.5),
        box((0.55, 0.0, -4.35), (0.06, 0.9, 0.06), bark, 0.5),
        quad((0.05, 1.15, -4.25), 1.1, 0.69, texture("astronaut"), yaw=-5, shading=0.6, casts_shadow=True),
    ]
    return Layout(
        "orchard",
        "an orchard lawn: two trees before a hedge and a cloudy sky, fruit on the grass, a "
        "wooden crate and a photo sign on posts (astronaut)",
        tuple(prims),
        Rig((0.0, 1.0, 0.0), (0.0, 0.6, -4.0), (0.8, 0.55)),
        Lighting((0.55, 0.85, 0.35), colour=(0.85, 0.8, 0.7), ambient=(0.22, 0.26, 0.34)),
    )


def gallery() -> Layout:
    wall_z = -6.0
    prims = [
        ground(0.0, texture("proc:wood", (0.9, 0.8, 0.7)), tile=0.9, shading=0.5),
        backdrop(wall_z, texture("cell", (0.82, 0.8, 0.72), base=(0.55, 0.55, 0.5)), (3.0, 3.0), shading=0.3),
        box((-0.9, 0.0, -2.6), (0.5, 0.75, 0.5), texture("proc:marble", (0.95, 0.93, 0.88)), 0.6, yaw=12),
        ball(-0.9, -2.6, 0.24, texture("coins", (0.7, 0.4, 0.15), base=(0.06, 0.03, 0.01), gain=1.2), y0=0.75),
        box(
            (1.0, 0.0, -3.6),
            (0.45, 1.0, 0.45),
            texture("gravel", (0.25, 0.25, 0.27), base=(0.02, 0.02, 0.02)),
            0.6,
            yaw=-20,
        ),
        ball(1.0, -3.6, 0.3, texture("text", (0.3, 0.45, 0.9), base=(0.02, 0.03, 0.1), gain=1.2), y0=1.0, spin=120),
    ]
    prims += framed(texture("astronaut", (0.9, 0.85, 0.8)), (-1.3, 1.5, wall_z + 0.02), 1.0)
    prims += framed(texture("camera"), (0.35, 1.45, wall_z + 0.02), 1.2)
    prims += framed(texture("horse", (0.85, 0.75, 0.2), base=(0.05, 0.1, 0.3)), (0.1, 0.62, -1.9), 0.55, yaw=-15)
    return Layout(
        "gallery",
        "a gallery room: plaster wall with two framed photos (astronaut, cameraman), a marble "
        "pedestal with a bronze ball, a dark plinth with an engraved blue globe, a small horse print on "
        "the wooden floor",
        tuple(prims),
        Rig((0.0, 1.1, 0.0), (0.0, 0.8, -3.6), (0.7, 0.5)),
        Lighting((-0.3, 0.75, 0.6), colour=(0.8, 0.76, 0.68), ambient=(0.27, 0.27, 0.28)),
    )


def courtyard() -> Layout:
    stone = texture("moon", (0.85, 0.7, 0.5), base=(0.2, 0.15, 0.1), gain=1.1)
    prims = [
        ground(0.0, texture("proc:cobbles", (1.3, 1.25, 1.2)), tile=1.0, shading=0.6),
        backdrop(-7.0, texture("proc:masonry", (0.95, 0.45, 0.3), gain=1.1), (2.4, 1.6)),
        box((-1.3, 0.0, -3.0), (0.9, 0.6, 0.6), stone, 0.9, yaw=-15),
        box((1.5, 0.0, -5.0), (1.2, 1.3, 0.8), stone, 0.9, yaw=25),
        box(
            (0.2, 0.0, -4.2),
            (0.9, 0.35, 0.9),
            texture("proc:tiles"),
            0.45,
            top=texture("moon", (0.15, 0.4, 0.06), base=(0.01, 0.03, 0.0), gain=1.3),
        ),
        ball(-1.3, -3.0, 0.3, texture("immunohistochemistry", (0.6, 0.7, 0.95)), y0=0.6, spin=15),
        ball(0.45, -1.9, 0.26, texture("colorwheel"), spin=-80),
        ball(0.2, -4.2, 0.3, texture("coffee"), y0=0.35, spin=200),
    ]
    prims += framed(texture("page", (0.95, 0.92, 0.8)), (-0.6, 1.6, -6.98), 0.8, frame=(0.1, 0.1, 0.12))
    prims += framed(texture("chelsea", (0.95, 0.9, 0.9)), (0.9, 0.45, -2.5), 0.5, yaw=-20)
    return Layout(
        "courtyard",
        "a walled courtyard on cobbles: a red ashlar wall with a notice, sandstone blocks, "
        "a tiled planter with moss, a blue marbled ball, a colour ball, a coffee-cup globe and a small cat "
        "picture",
        tuple(prims),
        Rig((0.0, 1.2, 0.0), (0.0, 0.6, -4.0), (0.75, 0.55)),
        Lighting((0.6, 0.7, 0.5), colour=(0.85, 0.78, 0.65), ambient=(0.2, 0.24, 0.32)),
    )


def observatory() -> Layout:
    prims = [
        ground(0.0, texture("moon", (0.55, 0.52, 0.5), base=(0.03, 0.03, 0.03), gain=1.2), tile=2.0, shading=0.7),
        backdrop(-9.0, texture("hubble_deep_field", gain=1.5), (6.0, 6.0), centre_y=2.0, shading=0.0),
        ball(-1.0, -3.4, 0.55, texture("retina", (1.0, 0.7, 0.5), base=(0.12, 0.03, 0.01), gain=1.3), spin=-30),
        ball(0.9, -2.3, 0.3, texture("moon", (0.9, 0.9, 0.95), base=(0.1, 0.1, 0.12)), y0=0.0),
        ball(1.6, -5.4, 0.8, texture("immunohistochemistry", (0.55, 0.65, 1.0), gain=1.2), spin=60),
        box((0.05, 0.0, -4.3), (0.6, 0.9, 0.6), texture("proc:tiles", (0.7, 0.75, 0.9)), 0.3, yaw=35),
        box((-0.35, 0.0, -1.8), (0.35, 0.2, 0.35), texture("page", (0.75, 0.75, 0.8)), 0.35, yaw=10),
    ]
    prims += framed(texture("rocket"), (-1.9, 0.75, -5.5), 1.2, yaw=30, frame=(0.5, 0.5, 0.5))
    return Layout(
        "observatory",
        "a night landscape under the Hubble deep field: a red planet, a moon, a blue "
        "gas giant, a panelled instrument block, a paper-covered case and a rocket poster",
        tuple(prims),
        Rig((0.0, 0.9, 0.0), (0.0, 0.6, -3.8), (0.7, 0.5)),
        Lighting((-0.6, 0.6, 0.5), colour=(0.9, 0.85, 0.8), ambient=(0.12, 0.13, 0.18)),
    )


def harbour() -> Layout:
    iron = texture("hubble_deep_field", (0.3, 0.3, 0.32), base=(0.05, 0.05, 0.06), gain=2.0)
    kraft = texture("page", (0.8, 0.6, 0.38), base=(0.2, 0.11, 0.05))
    prims = [
        # water 0.5 below the quay, glinting (the deep field's galaxies)
        ground(-0.5, texture("hubble_deep_field", (0.7, 0.9, 1.0), base=(0.03, 0.1, 0.14), gain=3.0), 3.0, shading=0.3),
        backdrop(
            -9.0,
            texture("colorwheel", (0.8, 0.88, 1.0), base=(0.3, 0.5, 0.85), gain=0.8),
            (40.0, 40.0),
            centre_y=1.5,
            shading=0.0,
        ),
        quad((0.0, 0.7, -8.6), 40.0, 2.4, texture("proc:tiles", (0.95, 0.9, 0.85)), tile=(1.6, 1.6), shading=0.4),
        # the quay: its edge runs into the distance along x = 0.1, water to the right
        box(
            (-9.9, -0.5, -3.3),
            (20.0, 0.5, 10.6),
            texture("proc:masonry", (0.45, 0.5, 0.42), base=(0.03, 0.04, 0.03)),
            0.9,
            top=texture("proc:masonry", (0.7, 0.74, 0.8)),
        ),
        box((-2.0, 0.0, -6.3), (1.6, 1.0, 0.9), texture("retina", gain=0.9), 1.8, yaw=12),
        box((-1.1, 0.0, -2.7), (0.6, 0.45, 0.5), kraft, 0.6, yaw=15),
        box((-1.05, 0.45, -2.75), (0.38, 0.3, 0.38), kraft, 0.45, yaw=-8),
        box((-0.2, 0.0, -3.6), (0.16, 0.3, 0.16), iron, 0.3),
        box(
            (1.6, -0.75, -5.0),
            (0.8, 0.5, 1.9),
            texture("immunohistochemistry", (0.15, 0.3, 0.75), base=(0.9, 0.9, 0.88), gain=2.0),
            1.0,
            yaw=8,
        ),
        ball(-0.4, -1.9, 0.2, texture("chelsea", (1.0, 0.8, 0.25), gain=1.3), spin=200),
        ball(
            -1.5,
            -4.2,
            0.26,
            texture("immunohistochemistry", (0.85, 0.08, 0.05), base=(0.95, 0.92, 0.85), gain=2.0),
            spin=-70,
        ),
        ball(0.9, -2.9, 0.25, texture("colorwheel", (1.0, 0.6, 0.3)), y0=-0.62, spin=100),
        ball(2.2, -6.8, 0.35, texture("colorwheel", (1.0, 0.6, 0.3)), y0=-0.65, spin=-20),
    ]
    prims += framed(texture("coffee"), (-0.5, 0.39, -5.0), 0.7, yaw=-10, border=0.06, frame=(0.12, 0.1, 0.08))
    return Layout(
        "harbour",
        "a granite quayside above sparkling water: a rust-streaked container, a stack of kraft-paper "
        "crates, an iron bollard, a yellow and a red buoy, a cafe board (coffee), a blue boat "
        "and two marker buoys afloat, tiled harbour houses under a pastel sky",
        tuple(prims),
        Rig((0.5, 1.2, 0.0), (-0.1, 0.35, -4.5), (0.75, 0.5)),
        Lighting((0.5, 0.8, 0.45), colour=(0.85, 0.8, 0.7), ambient=(0.22, 0.25, 0.32)),
    )


def greenhouse() -> Layout:
    soil = texture("moon", (0.5, 0.36, 0.24), base=(0.05, 0.03, 0.02), gain=1.3)
    clay = texture("moon", (0.8, 0.4, 0.22), base=(0.3, 0.1, 0.05), gain=1.2)
    leaves = texture("proc:foliage")
    brick = texture("proc:masonry", (0.8, 0.45, 0.35), base=(0.1, 0.05, 0.04))
    prims = [
        ground(0.0, soil, tile=1.5, shading=0.7),
        backdrop(-7.5, texture("proc:glazing"), (3.0, 2.0), centre_y=1.0, shading=0.0),
        # three-tier brick staging on the left, rising away from the cameras
        box((-1.1, 0.0, -4.3), (2.0, 0.35, 0.6), brick, 1.0),
        box((-1.1, 0.0, -4.9), (2.0, 0.7, 0.6), brick, 1.0),
        box((-1.1, 0.0, -5.5), (2.0, 1.05, 0.6), brick, 1.0),
    ]
    for x, y0, z, pot, plant in (
        (-1.6, 0.35, -4.3, 0.22, 0.24),
        (-0.6, 0.7, -4.9, 0.25, 0.3),
        (-1.35, 1.05, -5.5, 0.28, 0.36),
    ):  # a clay pot on each tier, its plant a ball of leaves
        prims += [box((x, y0, z), (pot,) * 3, clay, 0.5, yaw=20), ball(x, z, plant, leaves, y0=y0 + pot, spin=90 * x)]
    prims += [
        # a large potted plant on the floor at the front right, a hanging basket above the aisle
        box((1.05, 0.0, -2.5), (0.42, 0.4, 0.42), texture("proc:tiles", (0.9, 0.95, 1.0)), 0.42, yaw=-25),
        ball(1.05, -2.5, 0.45, leaves, y0=0.4, spin=-40),
        ball(0.35, -3.6, 0.28, texture("coffee", (0.75, 0.6, 0.4), base=(0.12, 0.08, 0.04)), y0=1.55, spin=30),
        box((0.35, 2.08, -3.6), (0.04, 1.5, 0.04), solid((0.3, 0.3, 0.28)), 0.1),  # its chain
        # a watering-can-blue tub and a flowering ball (the colour wheel) on the path
        box((0.15, 0.0, -1.9), (0.3, 0.22, 0.3), solid((0.08, 0.2, 0.45)), 0.3, yaw=10),
        ball(1.7, -5.4, 0.35, texture("colorwheel", (1.0, 0.85, 0.9)), spin=150),
    ]
    prims += framed(texture("chelsea", (0.95, 0.95, 0.85)), (0.55, 0.7, -6.2), 0.5, yaw=-12, frame=(0.85, 0.85, 0.8))
    return Layout(
        "greenhouse",
        "inside a glasshouse: three-tier brick staging with clay pots and leafy plants rising to the "
        "glazing, a big plant in a tiled pot, a hanging basket, a blue tub, a flowering ball and a "
        "seed-catalogue cat picture on an easel",
        tuple(prims),
        Rig((0.0, 1.1, 0.0), (0.0, 0.7, -4.2), (0.7, 0.5)),
        Lighting((0.3, 0.9, 0.35), colour=(0.85, 0.85, 0.75), ambient=(0.24, 0.28, 0.26)),
    )


def workshop() -> Layout:
    steel = texture("moon", (0.6, 0.62, 0.66), base=(0.15, 0.15, 0.17), gain=1.1)
    plywood = texture("page", (0.85, 0.7, 0.48), base=(0.45, 0.32, 0.18), gain=0.8)
    terrazzo = texture("hubble_deep_field", (0.95, 0.9, 0.85), base=(0.3, 0.29, 0.27), gain=2.5)
    drum = texture("moon", (0.3, 0.5, 0.9), base=(0.03, 0.08, 0.25))
    prims = [
        # speckled terrazzo floor (the deep field's stars) and a pegboard tool wall
        ground(0.0, terrazzo, 1.5, shading=0.7),
        backdrop(-6.8, texture("proc:pegboard"), (1.6, 1.6), shading=0.5),
        # workbench on the right: a thick top on a drawer cabinet and a trestle
        box((0.6, 0.85, -5.2), (2.2, 0.08, 0.8), plywood, 0.8),
        box((1.3, 0.0, -5.2), (0.7, 0.85, 0.7), texture("proc:tiles", (0.6, 0.65, 0.7)), 0.85),
        box((-0.3, 0.0, -5.2), (0.1, 0.85, 0.6), steel, 0.5),
        box((-0.05, 0.93, -5.05), (0.22, 0.2, 0.3), solid((0.5, 0.04, 0.03)), 0.3, yaw=15),  # vice
        box((0.75, 0.93, -5.15), (0.55, 0.28, 0.3), texture("retina", (1.0, 0.4, 0.2), gain=1.1), 0.55, yaw=-8),
        ball(1.3, -5.3, 0.16, texture("coffee"), y0=0.93, spin=80),
        # tall open shelving at the front left: two uprights, three shelves, jars and a ball of twine
        box((-0.9, 0.0, -2.5), (0.05, 1.7, 0.45), steel, 0.5),
        box((-1.7, 0.0, -2.5), (0.05, 1.7, 0.45), steel, 0.5),
    ]
    prims += [box((-1.3, y, -2.5), (0.8, 0.04, 0.45), plywood, 0.8) for y in (0.25, 0.8, 1.35)]
    prims += [
        box((-1.45, 0.29, -2.45), (0.25, 0.3, 0.25), texture("immunohistochemistry", (0.95, 0.9, 0.8)), 0.3),
        box((-1.15, 0.84, -2.5), (0.3, 0.22, 0.28), texture("page", (0.8, 0.75, 0.6)), 0.3, yaw=-12),
        ball(-1.3, -2.5, 0.15, texture("chelsea", (0.8, 0.6, 0.35)), y0=1.39, spin=-45),
        # an oil drum in the middle distance
        box((-0.2, 0.0, -3.5), (0.45, 0.75, 0.45), drum, 0.5, yaw=30),
    ]
    prims += framed(texture("rocket"), (-1.2, 1.6, -6.78), 1.0, frame=(0.15, 0.15, 0.15))
    return Layout(
        "workshop",
        "a workshop before a pegboard wall with a rocket poster: a workbench with a red vice, an "
        "orange toolbox and a tin on a tiled drawer cabinet, open steel shelving with jars and a "
        "ball of twine, a blue oil drum on a terrazzo floor",
        tuple(prims),
        Rig((0.0, 1.3, 0.0), (0.0, 0.75, -4.3), (0.7, 0.5)),
        Lighting((-0.4, 0.85, 0.45), colour=(0.85, 0.82, 0.75), ambient=(0.22, 0.23, 0.26)),
    )


def library() -> Layout:
    shelves = texture("proc:books")
    oak = texture("retina", (0.45, 0.25, 0.1), base=(0.12, 0.06, 0.02), gain=1.0)
    globe = texture("immunohistochemistry", (0.3, 0.5, 0.95), base=(0.9, 0.85, 0.6))
    leather = texture("coffee", (0.55, 0.2, 0.12))
    prims = [
        ground(0.0, texture("proc:carpet"), tile=1.6, shading=0.6),
        backdrop(-8.5, texture("page", (0.9, 0.85, 0.7), base=(0.3, 0.25, 0.18)), (1.2, 1.2), shading=0.4),
        # an aisle between two bookcases that run away from the cameras (their ends stagger)
        box((-1.9, 0.0, -5.0), (1.2, 2.6, 6.0), shelves, 1.4),
        box((1.9, 0.0, -5.6), (1.2, 2.6, 5.6), shelves, 1.4),
        # a reading table with a globe on a stand, a stack of books and a reading chair
        box((0.15, 0.7, -3.1), (0.9, 0.06, 0.55), oak, 0.6, yaw=-10),
        box((0.15, 0.0, -3.1), (0.14, 0.7, 0.14), oak, 0.6),
        box((0.4, 0.76, -3.1), (0.06, 0.18, 0.06), solid((0.6, 0.45, 0.15)), 0.2),
        ball(0.4, -3.1, 0.17, globe, y0=0.94, spin=20),
        box((-0.15, 0.76, -3.05), (0.3, 0.07, 0.22), solid((0.35, 0.05, 0.05)), 0.3, yaw=5),
        box((-0.15, 0.83, -3.05), (0.26, 0.06, 0.2), solid((0.06, 0.12, 0.35)), 0.3, yaw=-12, top=texture("page")),
        box((-0.5, 0.0, -4.6), (0.55, 0.42, 0.5), leather, 0.5, yaw=25),
        box((-0.55, 0.42, -4.85), (0.55, 0.5, 0.1), leather, 0.5, yaw=25),
        # a standard lamp further down the aisle
        box((0.65, 0.0, -6.0), (0.05, 1.3, 0.05), solid((0.1, 0.1, 0.1)), 0.2),
        ball(0.65, -6.0, 0.2, texture("moon", (1.0, 0.9, 0.6), base=(0.6, 0.45, 0.2)), y0=1.3, shading=0.2),
    ]
    prims += framed(texture("hubble_deep_field", gain=1.4), (0.0, 1.5, -8.45), 1.2, frame=(0.25, 0.15, 0.08))
    return Layout(
        "library",
        "a library aisle between two tall bookcases on an oriental runner: a reading table with a "
        "blue globe and a stack of books, a leather reading chair, a standard lamp, a night-sky window "
        "in a printed end wall",
        tuple(prims),
        Rig((0.0, 1.2, 0.0), (0.0, 0.8, -4.5), (0.6, 0.45)),
        Lighting((0.25, 0.9, 0.4), colour=(0.8, 0.75, 0.62), ambient=(0.24, 0.23, 0.22)),
    )


# Which pool of content each layout draws from (spc3d.inputs.scenes.textures).
LAYOUT_ROLES = {
    "tabletop": "train",
    "orchard": "train",
    "gallery": "train",
    "courtyard": "eval",
    "observatory": "eval",
    "harbour": "eval",
    "greenhouse": "eval",
    "workshop": "eval",
    "library": "eval",
}

LAYOUT_BUILDERS = {
    "tabletop": tabletop,
    "orchard": orchard,
    "gallery": gallery,
    "courtyard": courtyard,
    "observatory": observatory,
    "harbour": harbour,
    "greenhouse": greenhouse,
    "workshop": workshop,
    "library": library,
}
