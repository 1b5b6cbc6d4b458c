"""Random maps and move streams for the planner tests: the differential check
(test_e2e_bkcore.py, the firmware core against RefPlanner), the property
test (test_planner_properties.py, RefPlanner on its own) and the cross-target
vectors (tools/vectors/gen_vectors.py, test/test_planner_streams)."""
from bulgekit.bulge.fallback import Settings
from bulgekit.gcode import Move


def random_stream(rng):
    """A map of 1-4 layers of points near the origin, and moves that wander
    through them: wall-like runs aimed at points and corners, moves a few
    hundredths of a millimetre long, retractions, layer changes up and back
    down. Mode 2 (every extruding move); (layers, settings, moves, layer height)
    with moves as (x, y, z, e) targets."""
    lh = rng.choice([0.2, 0.25, 0.3])
    zs = [round(lh * (k + 1) + rng.choice([0.0, 0.0, -0.07, 0.07]), 2) for k in range(rng.randint(1, 4))]
    zs = sorted(set(zs))
    layers = []
    for z in zs:
        n = rng.randint(1, 20)
        span = rng.choice([2.0, 20.0])
        layers.append((z, [(round(rng.uniform(-span, span), 1), round(rng.uniform(-span, span), 1))
                           for _ in range(n)]))
    moves = []
    z = zs[0]
    for _ in range(rng.randint(5, 60)):
        r = rng.random()
        if r < 0.1:
            z = rng.choice(zs) + rng.choice([0.0, 0.0, 0.01, -0.01])
        lz, pts = min(layers, key=lambda l: abs(l[0] - z))
        px, py = rng.choice(pts)
        if r < 0.6:      # at a point, or just off it
            x, y = px + rng.uniform(-0.3, 0.3), py + rng.uniform(-0.3, 0.3)
        elif r < 0.8:    # anywhere around
            x, y = rng.uniform(-25, 25), rng.uniform(-25, 25)
        else:            # a very short move from the last end
            x0, y0 = (moves[-1][0], moves[-1][1]) if moves else (0.0, 0.0)
            x, y = x0 + rng.uniform(-0.05, 0.05), y0 + rng.uniform(-0.05, 0.05)
        e = -round(rng.uniform(0.5, 2.0), 3) if rng.random() < 0.1 else round(rng.uniform(0.0, 1.0), 4)
        moves.append((round(x, 3), round(y, 3), round(z, 3), e))
    settings = Settings(2, rng.choice([0, 60, 100, 250]), rng.choice([0.0, 0.05, 0.1, 0.4]),
                        rng.choice([0.1, 0.25, 0.5]))
    return layers, settings, moves, lh


def m720_line(settings):
    """The M720 line a stream's settings are sent to the firmware core as."""
    return f"M720 S2 P{settings.dwell_ms} E{settings.extra_e} T{settings.tolerance}"


def move_lines(moves):
    """The moves as the G1 lines the firmware core is sent (M83 in force)."""
    return [f"G1 X{x1} Y{y1} Z{z1} E{e} F1800" for x1, y1, z1, e in moves]


def mirror_plan(ref, moves):
    """RefPlanner's actions for each move in turn, from the origin: one list
    per move, all of them on the outer wall."""
    out = []
    x = y = z = 0.0
    for k, (x1, y1, z1, e) in enumerate(moves):
        out.append(ref.plan(Move(k, k + 1, x, y, z, x1, y1, z1, e, 0.0, 1800.0, True, None), True))
        x, y, z = x1, y1, z1
    return out
