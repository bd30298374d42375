"""Procedural grid city, the ego path and the moving actors, per scenario and seed.

Roads (10 m wide, lane markings) lie on grid lines; each block is a raised sidewalk slab with a ring of
textured buildings, trees, poles and signs along its edges; parked cars line the kerbs; moving cars
drive in lanes (never in the ego's lane against it) and pedestrians walk the sidewalks. The city
extends at least 150 m beyond the ego path so long-range bins are populated.

The `traffic` scenario adds the movers that break photometric self-supervision (`_hard_traffic`):
cars ahead in the ego's lane at the ego's speed (near-zero flow), oncoming cars, crossing traffic at
the intersections ahead and pedestrians crossing the road, all within the first seconds of the drive.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from leovr.sim.meshes import Mat, Mesh, MeshBuilder, car_template, person_template
from leovr.sim.paths import Path2D, rounded_rectangle

ROAD_HALF = 5.0
LANE = 2.0
SIDEWALK = 3.0
KERB = 0.15
PARK_OFFSET = 4.1
SCENARIOS = ("city_loop", "straight", "dynamic", "traffic")  # append only: the index seeds each world


@dataclass
class Mover:
    """A moving actor: a mesh template carried along a path."""

    template: Mesh
    path: Path2D
    s0: float
    speed: float
    z: float
    kind: str
    pingpong: bool = False

    def pose(self, t: float) -> tuple[np.ndarray, float]:
        s = self.s0 + self.speed * t
        if not self.path.closed and not self.pingpong:
            s = np.mod(s, self.path.length)
        xy, yaw = self.path.pose(np.array([s]), self.pingpong)
        return xy[0], float(yaw[0])


@dataclass
class World:
    scenario: str
    seed: int
    static: Mesh
    movers: list[Mover]
    ego_path: Path2D
    extent: tuple[float, float, float, float]
    ego_roads: list[tuple[int, float, int]] = field(default_factory=list)  # (axis, centre, direction)

    def dynamic_mesh(self, t: float) -> Mesh:
        """All movers at time t as one mesh."""
        b = MeshBuilder()
        for m in self.movers:
            xy, yaw = m.pose(t)
            b.add_mesh(m.template, yaw, (xy[0], xy[1], m.z))
        return b.build()


def _pastel(rng: np.random.Generator) -> tuple[float, float, float]:
    base = rng.uniform(0.35, 0.85)
    tint = rng.uniform(-0.12, 0.12, 3)
    return tuple(np.clip(base + tint, 0.1, 0.95))


def _car_color(rng: np.random.Generator) -> tuple[float, float, float]:
    palette = [(0.8, 0.1, 0.1), (0.1, 0.2, 0.6), (0.9, 0.9, 0.9), (0.1, 0.1, 0.1), (0.5, 0.5, 0.55), (0.7, 0.6, 0.1)]
    return palette[int(rng.integers(len(palette)))]


def _lines(extent, xs, ys):
    x0, x1, y0, y1 = extent
    return [x0] + list(xs) + [x1], [y0] + list(ys) + [y1]


def _add_block(
    b: MeshBuilder,
    rng: np.random.Generator,
    bx: tuple[float, float],
    by: tuple[float, float],
    road_sides: dict[str, bool],
) -> None:
    """Sidewalk slab, buildings along its edges, street furniture along the edges that face roads."""
    (xa, xb), (ya, yb) = bx, by
    if xb - xa < 6 or yb - ya < 6:
        return
    b.box(((xa + xb) / 2, (ya + yb) / 2, 0.0), (xb - xa, yb - ya, KERB), Mat.SIDEWALK, (0.6, 0.6, 0.58))
    # each side: (start, end, fixed coordinate, inward normal, axis of travel)
    sides = {
        "south": ((xa, xb), ya, (0, 1), 0),
        "north": ((xa, xb), yb, (0, -1), 0),
        "west": ((ya, yb), xa, (1, 0), 1),
        "east": ((ya, yb), xb, (-1, 0), 1),
    }
    for name, ((a, e), fixed, inward, axis) in sides.items():
        margin = SIDEWALK + (16.0 if axis == 1 else 0.0)  # east/west rows stop short of the corners
        pos = a + margin
        while pos < e - margin - 6:
            w = rng.uniform(8, 22)
            w = min(w, e - margin - pos)
            d = rng.uniform(8, 15)
            h = rng.uniform(6, 30) if rng.random() > 0.15 else rng.uniform(30, 60)
            off = SIDEWALK + d / 2
            c_along = pos + w / 2
            c_across = fixed + inward[0 if axis == 1 else 1] * off
            center = (c_along, c_across) if axis == 0 else (c_across, c_along)
            size = (w, d) if axis == 0 else (d, w)
            col = _pastel(rng)
            b.box(
                (center[0], center[1], KERB),
                (size[0], size[1], h),
                Mat.FACADE,
                col,
                param=(rng.uniform(2.2, 3.6), axis),
            )
            b.box((center[0], center[1], KERB + h), (size[0] + 0.4, size[1] + 0.4, 0.4), Mat.ROOF, (0.3, 0.3, 0.32))
            pos += w + rng.uniform(0.0, 3.0)
        if not road_sides.get(name):
            continue
        pos = a + rng.uniform(3, 8)
        while pos < e - 3:
            edge = fixed + inward[0 if axis == 1 else 1] * 1.2
            xy = (pos, edge) if axis == 0 else (edge, pos)
            r = rng.random()
            if r < 0.55:
                h = rng.uniform(2.0, 3.5)
                b.prism((xy[0], xy[1], KERB), 0.18, h, Mat.TRUNK, (0.35, 0.25, 0.15), sides=6)
                b.blob(
                    (xy[0], xy[1], KERB + h + 1.2),
                    rng.uniform(1.4, 2.4),
                    Mat.FOLIAGE,
                    (0.2, rng.uniform(0.4, 0.6), 0.15),
                )
            elif r < 0.8:
                b.prism((xy[0], xy[1], KERB), 0.09, rng.uniform(5.5, 7.5), Mat.METAL, (0.55, 0.55, 0.6), sides=6)
            elif r < 0.92:
                b.prism((xy[0], xy[1], KERB), 0.05, 2.2, Mat.METAL, (0.55, 0.55, 0.6), sides=5)
                col = [(0.8, 0.1, 0.1), (0.1, 0.3, 0.8), (0.9, 0.8, 0.1)][int(rng.integers(3))]
                yaw = 0.0 if axis == 1 else np.pi / 2
                b.box((xy[0], xy[1], KERB + 2.2), (0.06, 0.7, 0.7), Mat.SIGN, col, yaw=yaw)
            pos += rng.uniform(8, 16)


def _road_paths(extent, xs, ys) -> list[tuple[int, float, Path2D]]:
    x0, x1, y0, y1 = extent
    out = [(1, x, Path2D(np.array([[x, y0], [x, y1]]))) for x in xs]
    out += [(0, y, Path2D(np.array([[x0, y], [x1, y]]))) for y in ys]
    return out


def _build_city(rng, extent, xs, ys) -> MeshBuilder:
    b = MeshBuilder()
    x0, x1, y0, y1 = extent
    m = 400.0
    b.quad(x0 - m, y0 - m, x1 + m, y1 + m, 0.0, Mat.GROUND, (0.3, 0.45, 0.2))
    for x in xs:
        b.quad(x - ROAD_HALF, y0, x + ROAD_HALF, y1, 0.012, Mat.ROAD, (0.28, 0.28, 0.3), param=(1, x))
    for y in ys:
        b.quad(x0, y - ROAD_HALF, x1, y + ROAD_HALF, 0.01, Mat.ROAD, (0.28, 0.28, 0.3), param=(0, y))
    lx, ly = _lines(extent, xs, ys)
    for i in range(len(lx) - 1):
        for j in range(len(ly) - 1):
            xa = lx[i] + (ROAD_HALF if lx[i] in xs else 0.0)
            xb = lx[i + 1] - (ROAD_HALF if lx[i + 1] in xs else 0.0)
            ya = ly[j] + (ROAD_HALF if ly[j] in ys else 0.0)
            yb = ly[j + 1] - (ROAD_HALF if ly[j + 1] in ys else 0.0)
            sides = {"west": lx[i] in xs, "east": lx[i + 1] in xs, "south": ly[j] in ys, "north": ly[j + 1] in ys}
            _add_block(b, rng, (xa, xb), (ya, yb), sides)
    # parked cars along kerbs, away from intersections
    for axis, c, path in _road_paths(extent, xs, ys):
        cross = np.array(xs if axis == 0 else ys)
        lo, hi = (x0, x1) if axis == 0 else (y0, y1)
        for side in (-1, 1):
            pos = lo + rng.uniform(2, 8)
            while pos < hi - 3:
                if np.min(np.abs(cross - pos)) > 14 and rng.random() < 0.3:
                    xy = (pos, c + side * PARK_OFFSET) if axis == 0 else (c + side * PARK_OFFSET, pos)
                    yaw = (0.0 if side < 0 else np.pi) if axis == 0 else (np.pi / 2 if side > 0 else -np.pi / 2)
                    b.add_mesh(car_template(_car_color(rng)), yaw, (xy[0], xy[1], 0.02))
                pos += 6.5
    return b


def _traffic(rng, extent, xs, ys, ego_roads, centre: Path2D, n_cars: int, n_people: int, near: float) -> list[Mover]:
    """Cars in lanes and pedestrians on sidewalks. A share `near` of them use the ego's own road
    (cars in the oncoming lane) within the stretch the ego drives first; the rest roam the grid, on
    an ego road only against the ego's direction so nobody drives through the ego car."""
    movers: list[Mover] = []
    roads = _road_paths(extent, xs, ys)
    oncoming = centre.offset(LANE).reversed()
    reach = min(centre.length, 500.0)
    for _ in range(n_cars):
        color = _car_color(rng)
        if rng.random() < near:
            s0 = oncoming.length - rng.uniform(0, reach) if not centre.closed else rng.uniform(0, oncoming.length)
            movers.append(Mover(car_template(color), oncoming, s0, rng.uniform(5, 12), 0.02, "car"))
            continue
        axis, c, path = roads[int(rng.integers(len(roads)))]
        direction = 1 if rng.random() < 0.5 else -1
        for ax, cc, d in ego_roads:
            if ax == axis and abs(cc - c) < 1e-6 and d == direction:
                direction = -d
        # right-hand traffic: travelling +axis keeps to the right (negative lateral for x roads)
        lateral = -LANE * direction if axis == 0 else LANE * direction
        p = path.offset(lateral)
        if direction < 0:
            p = p.reversed()
        movers.append(Mover(car_template(color), p, rng.uniform(0, p.length), rng.uniform(5, 12), 0.02, "car"))
    for _ in range(n_people):
        side = 1 if rng.random() < 0.5 else -1
        if rng.random() < near:
            p, start = centre.offset(side * (ROAD_HALF + 1.8)), rng.uniform(0, reach)
        else:
            axis, c, path = roads[int(rng.integers(len(roads)))]
            p = path.offset(side * (ROAD_HALF + 1.8))
            start = rng.uniform(0, max(p.length - 60, 1))
        seg = Path2D(p.pose(np.array([start, start + rng.uniform(20, 60)]))[0])
        col = tuple(rng.uniform(0.1, 0.9, 3))
        movers.append(
            Mover(person_template(col), seg, rng.uniform(0, seg.length), rng.uniform(1.0, 1.6), KERB, "person", True)
        )
    return movers


def build_world(scenario: str, seed: int, ego_speed: float) -> World:
    """The world for a scenario and seed; the same arguments always give the same world."""
    if scenario not in SCENARIOS:
        raise ValueError(f"unknown scenario '{scenario}' (choose {', '.join(SCENARIOS)})")
    rng = np.random.default_rng([seed, SCENARIOS.index(scenario)])
    if scenario == "city_loop":
        B = 60.0
        xs = ys = [k * B for k in range(-3, 5)]
        extent = (-200.0, 260.0, -200.0, 260.0)
        centre = Path2D(rounded_rectangle(0, 0, B, B, 8.0), closed=True)
        ego_roads = [(0, 0.0, 1), (1, B, 1), (0, B, -1), (1, 0.0, -1)]
        n_cars, n_people = 14, 12
    else:
        B = 80.0
        xs = [k * B for k in range(-1, 19)]
        ys = [-B, 0.0, B]
        extent = (-160.0, 1560.0, -140.0, 140.0)
        centre = Path2D(np.array([[-20.0, 0.0], [1500.0, 0.0]]))
        ego_roads = [(0, 0.0, 1)]
        n_cars, n_people = {"straight": (12, 10), "dynamic": (45, 40), "traffic": (20, 16)}[scenario]
    ego = centre.offset(-LANE)
    static = _build_city(rng, extent, xs, ys).build()
    near = 0.8 if scenario == "dynamic" else 0.5
    movers = _traffic(rng, extent, xs, ys, ego_roads, centre, n_cars, n_people, near)
    # traffic ahead in the ego's own lane, at the ego's speed so the gap stays constant
    for k in range({"city_loop": 1, "straight": 1, "dynamic": 4}.get(scenario, 0)):
        movers.append(
            Mover(car_template(_car_color(rng)), ego, 18.0 + 25.0 * k + rng.uniform(0, 8), ego_speed, 0.02, "car")
        )
    if scenario == "traffic":
        movers += _hard_traffic(rng, xs, centre, ego, ego_speed)
    return World(scenario, seed, static, movers, ego, extent, ego_roads)


def _hard_traffic(
    rng: np.random.Generator, xs: list[float], centre: Path2D, ego: Path2D, ego_speed: float, horizon_s: float = 4.0
) -> list[Mover]:
    """Movers timed to be in view during the first `horizon_s` seconds (a 40-frame sequence), on the
    straight drive along y = 0 that starts at x = -20: a car close ahead in the ego lane at exactly
    the ego speed and one further ahead at about it; oncoming cars passing the ego; cars crossing
    the ego road at the intersections ahead (only while the ego is at least 12 m away from them);
    pedestrians crossing the oncoming half of the road (the ego lane stays clear). Movers do not
    avoid each other (the renderer has no physics)."""
    movers: list[Mover] = []
    x_start = float(centre.pose(np.array([0.0]))[0][0, 0])
    car = lambda: car_template(_car_color(rng))  # noqa: E731
    movers.append(Mover(car(), ego, rng.uniform(9.0, 14.0), ego_speed, 0.02, "car"))
    movers.append(Mover(car(), ego, rng.uniform(35.0, 50.0), ego_speed * rng.uniform(0.9, 1.1), 0.02, "car"))
    oncoming = centre.offset(LANE).reversed()
    for _ in range(4):  # meets the ego at t_meet: starts speed * t_meet beyond where the ego will be then
        speed, t_meet = rng.uniform(7.0, 12.0), rng.uniform(0.5, horizon_s)
        x_meet = x_start + ego_speed * t_meet
        s_meet = oncoming.length - (x_meet - x_start)
        movers.append(Mover(car(), oncoming, s_meet - speed * t_meet, speed, 0.02, "car"))
    ahead = [x for x in xs if x_start < x < x_start + ego_speed * horizon_s + 120.0]
    for x in ahead:
        for _ in range(2):
            speed = rng.uniform(6.0, 11.0)
            for _try in range(20):  # a crossing time when the ego is clear of the intersection
                t_c = rng.uniform(0.0, horizon_s)
                t = np.linspace(t_c - 14.0 / speed, t_c + 14.0 / speed, 9)
                if np.all(np.abs(x_start + ego_speed * np.clip(t, 0, None) - x) > 12.0):
                    break
            else:
                continue
            direction = 1 if rng.random() < 0.5 else -1
            lane = Path2D(
                np.array([[x + LANE * direction, -140.0 * direction], [x + LANE * direction, 140.0 * direction]])
            )
            movers.append(Mover(car(), lane, 140.0 - speed * t_c, speed, 0.02, "car"))
    for _ in range(5):  # from the kerb of the oncoming half across it, then along the far sidewalk
        x = x_start + rng.uniform(10.0, 45.0) + ego_speed * rng.uniform(0.0, horizon_s)
        y0, speed = rng.uniform(-0.5, 4.0), rng.uniform(1.1, 1.7)
        walk = Path2D(np.array([[x, y0], [x, ROAD_HALF + 1.8], [x + 300.0, ROAD_HALF + 1.8]]), smooth=0.2)
        movers.append(Mover(person_template(tuple(rng.uniform(0.1, 0.9, 3))), walk, 0.0, speed, 0.0, "person"))
    return movers
